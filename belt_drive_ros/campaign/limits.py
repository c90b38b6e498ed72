"""Up-front limits of a campaign, checked against the machine before anything runs, and its estimate.

A campaign's size is known from its file alone (:attr:`~belt_drive_ros.campaign.spec.Campaign.size`:
grid points x profiles x samples, or the recordings of a fleet), so a campaign
that cannot fit is refused in one line, with what it would have cost, before
its variant table is built or a worker started:

* **variants**: at most :data:`MAX_VARIANTS` per campaign (a larger study is
  several campaigns, each with its own ``--out``);
* **memory**: the client holds the variant table and the result table
  (~:data:`ROW_BYTES` per variant and column, twice while the parts are joined);
  they must fit in half the memory the machine has available;
* **workers** of the local cluster: at most :data:`WORKERS_PER_CPU` per CPU
  (more only take turns on the same CPUs), each ~:data:`WORKER_BYTES` of
  memory, all within the memory available.

The time estimate is the ensemble's measured cost (``belt-drive bench
campaign``: ~1.3 ms of worker wall time per 1000-step run of ``paper``,
taken as ~1 us per variant and step plus ~0.2 ms per variant) over the
workers; a machine busy with other work is slower, and runs that go singly
(slipping, adaptive methods, fleets) take longer: it is a lower bound for those.
"""

from __future__ import annotations

import math
import os

from .spec import MAX_VARIANTS, Campaign, CampaignError  # noqa: F401 (MAX_VARIANTS: most variants one campaign may hold)
#: client memory per variant and table column [bytes] (numbers; strings ~60 bytes, counted as such)
ROW_BYTES = 8
#: memory of one worker process with numpy, scipy, pandas and the package loaded [bytes]
WORKER_BYTES = 200 * 2**20
#: most local worker processes per CPU
WORKERS_PER_CPU = 2
#: worker CPU per variant and step of an ensemble [s], and per variant [s] (scene, metrics, table row)
STEP_SECONDS, VARIANT_SECONDS = 1.0e-6, 2.0e-4
#: worker memory per step of one variant's run [bytes]: its step plan is held whole (grid times, clamps, flags), and a
#: run that goes singly (slipping, adaptive, fleets) holds its whole trajectory (states, inputs, outputs)
RUN_BYTES_PER_STEP = 256


def available_memory() -> int:
    """Memory the machine has available now [bytes] (``MemAvailable`` of /proc/meminfo, else free pages)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return 2**40  # unknown: no memory limit


def _size(n: float) -> str:
    for unit, scale in (("TB", 2**40), ("GB", 2**30), ("MB", 2**20), ("kB", 2**10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n:.0f} bytes"


def _duration(s: float) -> str:
    if s >= 2 * 86400:
        return f"{s / 86400:.3g} days"
    if s >= 2 * 3600:
        return f"{s / 3600:.3g} h"
    if s >= 120:
        return f"{s / 60:.3g} min"
    return f"{s:.2g} s" if s >= 1 else "<1 s"


def table_bytes(campaign: Campaign, n: int) -> int:
    """Client memory of the variant and result tables of ``n`` variants [bytes] (peak: while the parts are joined)."""
    varied = len(campaign.grid) + len(campaign.vary) + (1 if campaign.profiles else 0) + 1
    strings = 4 + (4 if campaign.golden_folder is not None else 0) + (1 if campaign.fleet_folder else 0)
    per_row = ROW_BYTES * (2 * varied + len(campaign.metrics) + 2) + 60 * strings
    return 2 * n * per_row


def run_steps(campaign: Campaign):
    """Each variant's steps, duration / dt (its own: the grid's or drawn by the Monte Carlo, else the base scene's), NaN
    where its scene refuses them (no positive number: text, null, NaN, 0; a run beyond the
    :data:`~belt_drive_ros.core.scene.MAX_STEPS` one run may take): that variant's row says so, its run counts for
    nothing. None where every run is the base scene's (neither varies, a fleet) or the variant table would not be
    built (beyond :data:`MAX_VARIANTS` or the memory: the campaign is refused); else the table is built for it."""
    import numpy as np

    from ..core.scene import MAX_STEPS

    if campaign.fleet_folder is not None or not any(k in campaign.grid or k in campaign.vary for k in ("duration", "dt")):
        return None
    if campaign.size > MAX_VARIANTS or table_bytes(campaign, campaign.size) > available_memory() // 2:
        return None
    table = campaign.variants()

    def column(key: str):
        if key not in table:
            return np.full(len(table), float(getattr(campaign.base, key)))
        values = table[key]
        if values.dtype.kind in "if":
            return values.to_numpy(dtype=float)
        back = campaign.decode.get(key, {})
        return np.array([float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan
                         for v in (back.get(x, x) for x in values)])  # fmt: skip

    duration, dt = column("duration"), column("dt")
    with np.errstate(all="ignore"):
        steps = duration / dt
    return np.where((duration > 0) & (dt > 0) & (steps <= MAX_STEPS), steps, math.nan)  # (NaN compares False)


def longest_run_steps(campaign: Campaign) -> float:
    """Steps of the campaign's longest variant run its scene accepts (the max of :func:`run_steps`; 0 where no
    variant's run is accepted). A refused one aborted the campaign, or its text raised ``float()``'s error."""
    import numpy as np

    steps = run_steps(campaign)
    if steps is None:
        return campaign.base.duration / campaign.base.dt
    return float(np.nanmax(steps)) if np.any(~np.isnan(steps)) else 0.0


def seconds(campaign: Campaign, n: int, workers: int) -> float:
    """Estimated wall time of ``n`` variants on ``workers`` workers [s] (a lower bound for runs that go singly): each
    run's own steps (:func:`run_steps`; a grid of dt 1e-5 s was estimated at the base scene's 5 ms, 500x short)."""
    import numpy as np

    steps = run_steps(campaign) if n == campaign.size else None
    total = n * campaign.base.duration / campaign.base.dt if steps is None else float(np.nansum(steps))
    return (n * VARIANT_SECONDS + total * STEP_SECONDS) / max(workers, 1)


def estimate(campaign: Campaign, workers: int) -> str:
    """``N variants (...): ~T on W workers, ~M of tables``: what the campaign costs, in one phrase."""
    n = campaign.size
    if campaign.fleet_folder is not None:
        shape = "recordings"
    else:
        axes = [str(len(v)) for v in campaign.grid.values()]
        axes += [f"{len(campaign.profiles)} profiles"] if campaign.profiles else []
        axes += [f"{campaign.samples} samples"] if campaign.vary else []
        shape = " x ".join(axes) if axes else "the base scene"
    return (f"{n:,} variant{'s' if n != 1 else ''} ({shape}): ~{_duration(seconds(campaign, n, workers))} on {workers} "
            f"worker{'s' if workers != 1 else ''}, ~{_size(table_bytes(campaign, n))} of tables")  # fmt: skip


def check(campaign: Campaign, workers: int | None, local: bool = True) -> int:
    """Refuse (:class:`CampaignError`, one line with the estimate) a campaign or a worker count beyond the
    machine; return the number of workers the estimate assumes (``workers``, default one per CPU)."""
    cpus = os.cpu_count() or 1
    memory = available_memory()
    if workers is not None:
        if not local:
            raise CampaignError("--workers: sizes the local cluster; with --scheduler the cluster has its own workers")
        most = max(1, min(WORKERS_PER_CPU * cpus, memory // WORKER_BYTES))
        if workers > most:
            raise CampaignError(
                f"--workers {workers}: {workers:,} worker processes need ~{_size(workers * WORKER_BYTES)} of memory "
                f"(~{_size(WORKER_BYTES)} each); this machine has {cpus} CPUs and {_size(memory)} available: "
                f"use at most {most}"
            )
    workers = workers or cpus
    n = campaign.size
    if n > MAX_VARIANTS:
        raise CampaignError(
            f"campaign: {estimate(campaign, workers)}; more than the {MAX_VARIANTS:,} variants one campaign may "
            "hold: split it into campaigns (each with its own --out) or draw fewer samples"
        )
    if table_bytes(campaign, n) > memory // 2:
        raise CampaignError(
            f"campaign: {estimate(campaign, workers)}; more than half the {_size(memory)} of memory this machine "
            "has available: split it into campaigns or vary fewer keys"
        )
    steps = longest_run_steps(campaign)  # (after the tables' check: it may build the variant table)
    if campaign.fleet_folder is None and workers * steps * RUN_BYTES_PER_STEP > memory // 2:
        raise CampaignError(
            f"campaign: a variant's run of {steps:.3g} steps (duration over dt) needs ~{_size(steps * RUN_BYTES_PER_STEP)}"
            f" on each of {workers} worker{'s' if workers != 1 else ''} (its step plan, and a run that goes singly its "
            f"trajectory, held whole: ~{RUN_BYTES_PER_STEP} bytes a step); more than half the {_size(memory)} of memory "
            "this machine has available: shorten the runs (set.duration), lengthen the step or use fewer workers"
        )
    return workers
