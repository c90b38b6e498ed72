"""Running a campaign on a Dask cluster: batches, streamed results, resume.

The variants (:meth:`~belt_drive_ros.campaign.spec.Campaign.variants`) go
out in batches, one Dask task each (Dask's per-task overhead is ~1 ms, a
run ~0.3-6 ms: one task per run would be mostly overhead). A task
(:func:`run_batch`) builds its variants' scenes, runs them with
:func:`~belt_drive_ros.campaign.ensemble_run.simulate_many` (ensembles where
variants share profiles and settings, single runs otherwise), computes the
metrics (:mod:`~belt_drive_ros.campaign.metrics`) and returns a table, one
row per variant. A variant that fails (invalid parameters, an unstable
step, a diverging run) is a row with its ``error``; the campaign goes on.

Output folder::

    OUT/manifest.json          campaign digest, variant count, batch bounds
    OUT/variants.parquet       the variant table
    OUT/parts/part-NNNNN.parquet   one per finished batch (written as it finishes)
    OUT/results.parquet        all rows by variant (pandas.read_parquet), + results.csv with csv=True
    OUT/recordings/NAME.mcap   fleet campaigns: each replayed run (compare with msg-tools compare)

An interrupted campaign resumes: the same command finds the manifest and
runs only the batches without a part file.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path


from ..core.errors import BeltDriveError, InputError, short
from ..io.atomic import write_output
from ..io.inputs import read_text
from .metrics import GROUP_REDUCTION, METRICS, group_values, run_metrics, summary_values
from .spec import Campaign, CampaignError

#: a task should compute at least this long [s] (Dask's per-task overhead is ~1 ms)
MIN_TASK_SECONDS = 0.1
#: at most this many variants per task (an ensemble holds their states: ~32 kB per variant and 1000 steps)
MAX_BATCH = 2000
#: variants of the first (sizing) batch
FIRST_BATCH = 64
#: largest manifest.json read back on resume [bytes] (its batch bounds: ~20 bytes per batch)
MANIFEST_LIMIT = 64 << 20


# ------------------------------------------------------------------ worker side
_CAMPAIGNS: dict = {}


def _campaign(portable: dict) -> Campaign:
    """The campaign of a portable mapping, parsed once per worker process."""
    key = portable["digest"]
    if key not in _CAMPAIGNS:
        _CAMPAIGNS.clear()
        _CAMPAIGNS[key] = Campaign.from_mapping(portable["data"], base_dir=portable["base_dir"], text=portable["text"])
    return _CAMPAIGNS[key]


def run_batch(portable: dict, rows, recordings_dir: str | None = None):
    """Run one batch of variants (``rows`` of the variant table: a DataFrame slice or a list of
    row mappings) and return its result table (a pandas DataFrame, one row per variant).

    Every row comes back: the variant's columns, ``model`` (the model its
    run used), ``ran`` (``ensemble`` or ``single``), ``single_reason``,
    ``error`` ("" when it ran), for a fleet ``warning`` (a recording cut off: it ran on the messages up to its last
    complete chunk; "" otherwise), the metrics (NaN on error), and for a
    fleet with goldens ``compare_passed``, ``worst_signal``,
    ``worst_rel_error``, ``worst_errors`` (JSON: signal -> worst absolute error).
    ``seconds`` is the batch's compute time (the same in every row).
    """
    import numpy as np
    import pandas as pd

    start = time.perf_counter()
    campaign = _campaign(portable)
    frame = rows if isinstance(rows, pd.DataFrame) else pd.DataFrame(list(rows))
    n = len(frame)
    # the result's columns, filled by position (a column per field, not a dict per variant)
    text = {name: np.full(n, "", dtype=object) for name in ("model", "ran", "single_reason", "error")}
    values = {name: np.full(n, math.nan) for name in METRICS}
    extra = [None] * n  # a fleet's comparison columns, per variant
    scenes, built = [], []
    notes = None
    if campaign.fleet_folder is not None:  # a recording cut off runs on what it holds, said in its row's 'warning'
        notes = np.full(n, "", dtype=object)
        found = []
        for v, row in enumerate(frame.to_dict("records")):
            said = []
            try:
                found.append(campaign.scene_of(row, warn=said.append))
            except Exception as exc:  # noqa: BLE001 - reported as that variant's error
                found.append(exc)
            notes[v] = " ".join(said)[:400]
    else:
        found = campaign.scenes_of(frame) if n else []
    for v, scene in enumerate(found):
        if isinstance(scene, BaseException):  # whatever a variant's values break, it is that variant's row
            text["ran"][v] = "none"
            text["error"][v] = f"{type(scene).__name__}: {' '.join(str(scene).split())[:400]}"
        else:
            scenes.append(scene)
            built.append(v)
    from .ensemble_run import GroupRun, GroupSummary, run_groups

    fleet = campaign.fleet_folder is not None and recordings_dir
    # without recordings to write, ensembles keep only the metrics' reductions over time (memory: one window)
    for item in run_groups(scenes, reduce=None if fleet else GROUP_REDUCTION):
        if isinstance(item, (GroupRun, GroupSummary)):  # an ensemble: metrics of all its variants at once
            rows_of = [built[i] for i in item.indices]
            text["ran"][rows_of] = "ensemble"
            text["model"][rows_of] = item.kind
            reduced = group_values(item) if isinstance(item, GroupRun) else summary_values(item.values)
            for name in METRICS:
                values[name][rows_of] = reduced[name]
            if fleet:
                for w, v in enumerate(rows_of):
                    extra[v] = _fleet_outputs(campaign, item.result(w), frame["recording"].iloc[v], Path(recordings_dir))
            continue
        v = built[item.index]
        text["ran"][v] = "ensemble" if item.ensemble else "single"
        text["single_reason"][v] = item.single_reason or ""
        if item.error:
            text["error"][v] = item.error
            continue
        result = item.result
        text["model"][v] = result.model
        for name, value in run_metrics(result).items():
            values[name][v] = value
        if fleet:
            extra[v] = _fleet_outputs(campaign, result, frame["recording"].iloc[v], Path(recordings_dir))
    columns = {name: frame[name].to_numpy() for name in frame.columns}
    columns.update(text)
    if notes is not None:
        columns["warning"] = notes
    columns.update(values)
    if any(e is not None for e in extra):  # "error" too when a golden is missing
        for v, found in enumerate(extra):
            for name, value in (found or {}).items():
                if name == "error":
                    text["error"][v] = value
                    continue
                if name not in columns:  # a list: the column's type as pandas reads the values
                    columns[name] = [math.nan] * n
                columns[name][v] = value
    columns["seconds"] = np.full(n, time.perf_counter() - start)
    return pd.DataFrame(columns)  # built here, on the worker: the client only writes it (and pickled as columns)


def _fleet_outputs(campaign: Campaign, result, name: str, recordings_dir: Path) -> dict:
    """Write the replayed run as MCAP; with goldens, compare (msg_tools.compare, the engine of ``msg-tools compare``):
    the comparison's columns of the variant's row (``error`` when its golden is missing)."""
    from msg_tools.compare import compare

    from ..io.recording import write_result_mcap

    name = str(name)
    path = recordings_dir / name
    write_result_mcap(result, path, force=True, start_time_ns=0)
    if campaign.golden_folder is None:
        return {}
    golden = campaign.golden_folder / name
    if not golden.exists():
        return dict(compare_passed=False, worst_signal="", worst_rel_error=math.inf, worst_errors="{}",
                    error=f"no golden {golden}")
    report = compare(path, golden)
    worst = report.worst
    return dict(
        compare_passed=bool(report.passed),
        worst_signal=worst.name if worst else "",
        worst_rel_error=float(worst.worst_rel_error) if worst else math.nan,
        worst_errors=json.dumps({s.name: s.worst_abs_error for s in report.signals}),
    )


# ------------------------------------------------------------------ client side
@dataclass
class CampaignRun:
    """What :func:`run_campaign` did.

    ``table``: the results (pandas DataFrame, one row per variant, by variant);
    ``wall``: seconds of this invocation; ``compute_wall``: of its batches
    (from the first task sent to the last part written: without starting
    and stopping a cluster); ``computed``: variants run now
    (the others came from an earlier, interrupted invocation); ``workers``;
    ``signum``: the signal that interrupted it (SIGINT, SIGTERM), else 0.
    """

    table: object
    out_dir: Path
    wall: float
    computed: int
    workers: int
    interrupted: bool = False
    notes: list = field(default_factory=list)
    compute_wall: float = 0.0
    signum: int = 0


class _Progress:
    """One line on stderr: runs done, rate, time left."""

    def __init__(self, total: int, done: int, enabled: bool, stream=None):
        self.total, self.done, self.enabled = total, done, enabled
        self.stream = stream or sys.stderr
        self.start, self.start_done = time.perf_counter(), done

    def update(self, n: int) -> None:
        self.done += n
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        rate = (self.done - self.start_done) / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else math.inf
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        self.stream.write(
            f"\rsweep [{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total} runs "
            f"{rate:7.0f} runs/s  {left:5.1f} s left"
        )
        if self.done >= self.total:
            self.stream.write("\n")
        self.stream.flush()


def portable_of(campaign: Campaign) -> dict:
    """What a worker needs to rebuild the campaign: the base scene inline, folders absolute (not the file's
    text: the digest names it; the mapping goes to each worker once, :func:`run_campaign` scatters it)."""
    data = yaml_safe(campaign)
    return {"data": data, "base_dir": ".", "text": "", "digest": campaign.digest()}


def yaml_safe(campaign: Campaign) -> dict:
    """The campaign as a mapping with its (overridden) base scene inline."""
    grid = {k: [campaign.decode[k][v] for v in values] if k in campaign.decode else values for k, values in campaign.grid.items()}
    data = {
        "name": campaign.name, "scene": campaign.base_mapping, "grid": grid, "profiles": campaign.profiles,
        "metrics": list(campaign.metrics), "limits": campaign.limits,
    }  # fmt: skip
    if campaign.vary:
        vary = {k: {d.kind: [d.a, d.b], "absolute": d.absolute} for k, d in campaign.vary.items()}
        data["monte_carlo"] = {"samples": campaign.samples, "seed": campaign.seed, "vary": vary}
    if campaign.fleet_folder is not None:
        data["fleet"] = {"folder": str(campaign.fleet_folder)}
        if campaign.golden_folder is not None:
            data["fleet"]["golden"] = str(campaign.golden_folder)
    return data


def _cluster(scheduler: str | None, workers: int | None):
    """(client, cluster or None): a LocalCluster on loopback sized to the machine, or the scheduler at ``scheduler``."""
    from distributed import Client

    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, ValueError, TypeError, KeyError) as exc:  # unreachable, refused, an unknown protocol
            text = " ".join(str(exc).split())[:200] or type(exc).__name__
            raise CampaignError(f"--scheduler {scheduler[:200]}: cannot connect ({text})") from None
        return client, None
    cluster = local_cluster(workers or os.cpu_count() or 1)
    return Client(cluster), cluster


def local_cluster(workers: int):
    """A ``LocalCluster`` on 127.0.0.1: ``workers`` single-threaded worker processes, BLAS single-threaded.

    The workers ignore SIGINT (:func:`dask_setup`). Without Dask's
    ``MALLOC_TRIM_THRESHOLD_=65536`` in the workers' environment (``distributed.nanny.pre-spawn-environ``; meant against
    fragmentation in long-lived workers): setting it switches off glibc's
    adaptive mmap threshold, so every array over 128 kB (a window of an
    ensemble's outputs) is a fresh mmap, faulted in page by page and
    returned on free. On the 10,000-variant Monte Carlo of ``paper`` that
    was ~1.7 million page faults and ~4 s of kernel time in the workers
    against ~0.07 million and ~0.5 s without it (docs/campaigns.md).
    """
    import logging

    import dask
    from distributed import LocalCluster

    _quiet_resource_tracker()
    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {})
    env["MALLOC_TRIM_THRESHOLD_"] = None  # None: not set (Dask's way to unset a pre-spawn variable)
    # a nanny started earlier in this process left it in os.environ (it updates the parent's environment)
    inherited = os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": env}):
            return LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL, preload=[__name__],
            )  # fmt: skip
    finally:
        if inherited is not None:
            os.environ["MALLOC_TRIM_THRESHOLD_"] = inherited


def _quiet_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (if this process has none yet) with its stderr on /dev/null.

    The worker processes' queues and locks are semaphores the tracker
    removes when this process ends; if the process is killed (SIGKILL, out
    of memory) it still removes them, but first warns of "leaked semaphore
    objects" on the terminal, after the command has gone. Nothing is
    leaked: the warning only is kept off the terminal.
    """
    from multiprocessing import resource_tracker

    try:
        saved = os.dup(2)
    except OSError:
        return
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, 2)
            resource_tracker.ensure_running()
        finally:
            os.dup2(saved, 2)
            os.close(null)
    except OSError:
        pass
    finally:
        os.close(saved)


def dask_setup(worker) -> None:
    """Dask preload hook of the local cluster's workers (``preload=[this module]``): SIGINT ignored.

    Ctrl-C in a terminal goes to the whole process group, the workers
    included; each would print a traceback of its event loop. The client
    alone handles it (the batches finished are kept, the cluster is closed,
    one line; exit 130) and closes the workers.
    """
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def write_part(path: Path, rows) -> None:
    """``rows`` (a DataFrame or row mappings) as the Parquet file ``path``, whole or not at all."""
    import pandas as pd

    write_table(path, rows if isinstance(rows, pd.DataFrame) else pd.DataFrame(rows))


def write_table(path: Path, table, csv: bool = False) -> None:
    """``table`` (a DataFrame, without its index) as the Parquet (or with ``csv`` the CSV) file ``path``, through
    :func:`~belt_drive_ros.io.atomic.atomic_output`: whole or not at all. An interrupt or a full disk while it is
    written leaves the file as it was (or none) and no temporary file a Parquet dataset reader would take for a
    part (a ``part-N.tmp`` of an interrupted write was left in ``parts/``; ``results.parquet`` was left half)."""
    from ..io.atomic import atomic_output

    with atomic_output(path, force=True, mode="w" if csv else "wb", what="campaign output") as f:
        if csv:
            table.to_csv(f, index=False)
        else:
            table.to_parquet(f, index=False)


def _read_part(path: Path):
    """The rows of the part file ``path``; one that cannot be read (damaged since, emptied) is a :class:`CampaignError`
    naming it and how to run its batch again (it was an internal error naming Arrow's exception)."""
    import pandas as pd

    try:
        return pd.read_parquet(path)
    except (OSError, ValueError) as exc:
        text = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise CampaignError(f"{path}: cannot be read ({text}); remove it and run the same command again to run its "
                            "batch again") from None


def _bounds(n: int, first: int, size: int) -> list:
    edges = [0, min(first, n)]
    while edges[-1] < n:
        edges.append(min(edges[-1] + size, n))
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


#: the files a sweep writes in its folder (run_campaign and the sweep command): name -> the option that asks for it
OUT_FILES = {"manifest.json": "--out", "variants.parquet": "--out", "results.parquet": "--out", "summary.txt": "--out",
             "results.csv": "--csv"}


def check_out_folder(campaign: Campaign, out_dir: Path, *, csv: bool = False, plots: bool = False) -> None:
    """Refuse, before anything runs or is written, an ``out_dir`` that exists and is not a folder; one that holds a
    folder where a file of :data:`OUT_FILES` goes (``results.csv`` only with ``csv``, the charts of
    :func:`~.report.plot` only with ``plots``: found only after the whole run, else), or where that file would
    replace a file the campaign was read from (its :attr:`~.spec.Campaign.sources`); and one whose
    ``recordings/`` (where a fleet's runs go, replacing files of the same name) is the fleet's folder or its golden
    folder: the runs would overwrite the recordings they replay, or the goldens they are compared with (each
    comparison then passes against itself). --force does not change this: it replaces results, never inputs."""
    from ..io.inputs import input_replaced
    from .report import FLEET_WORST, HISTOGRAMS, SCATTER

    if out_dir.exists() and not out_dir.is_dir():
        raise CampaignError(f"{out_dir}: exists and is not a folder; --out names the folder the results go to")
    if not out_dir.exists():  # (its parent must take a folder: /proc/x failed after the estimate, naming no option)
        parent = out_dir.absolute().parent
        if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
            why = "does not exist" if not parent.is_dir() else "is not writable"
            raise CampaignError(f"--out {out_dir}: the folder it goes in, {parent}, {why}")
    outputs = {name: option for name, option in OUT_FILES.items() if csv or option != "--csv"}
    if plots:
        charts = (HISTOGRAMS, SCATTER) + ((FLEET_WORST,) if campaign.golden_folder is not None else ())
        outputs.update(dict.fromkeys(charts, "--plots"))
    for name, option in outputs.items():
        if (out_dir / name).is_dir():
            raise CampaignError(f"{out_dir / name}: is a folder, where {option} writes its {name}; remove it or "
                                f"use another --out")
        source = input_replaced(out_dir / name, campaign.sources)
        if source is not None:
            raise CampaignError(f"{out_dir / name}: is {short(source, 200)}, which the campaign is read from; "
                                f"{option} would replace it with its {name}: use another --out")
    recordings = out_dir / "recordings"
    for key, folder in (("fleet.folder", campaign.fleet_folder), ("fleet.golden", campaign.golden_folder)):
        if folder is not None and recordings.is_dir() and os.path.samefile(recordings, folder):
            what = "the recordings it replays" if key == "fleet.folder" else "the goldens it compares them with"
            raise CampaignError(f"{out_dir}: its recordings/ folder, where the replayed runs go, is {key} {folder}: the "
                                f"runs would overwrite {what}; use another --out")


def _rows_of(future, table, a: int, b: int):
    """The result rows of the batch of variants ``a .. b - 1`` (a DataFrame), or, where the batch broke as a whole (a
    worker lost, a task cancelled), a row per variant with the reason in ``error`` (a list of dicts): never raised."""
    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001 - recorded in the rows, the campaign goes on
        return [dict(r, model="", ran="none", single_reason="", seconds=math.nan,
                     error=f"batch failed: {type(exc).__name__}: {exc}", **{m: math.nan for m in METRICS})
                for r in table.iloc[a:b].to_dict("records")]  # fmt: skip


def run_campaign(
    campaign: Campaign, out_dir, *, scheduler: str | None = None, workers: int | None = None,
    client=None, csv: bool = False, progress: bool | None = None, force: bool = False,
    stop_after: int | None = None, batch_size: int | None = None,
) -> CampaignRun:  # fmt: skip
    """Run ``campaign`` into ``out_dir`` (see the module docstring) and return the result table.

    Parameters
    ----------
    scheduler : address of a running ``dask.distributed`` scheduler
        (``tcp://host:8786``); default: a LocalCluster on 127.0.0.1 with
        ``workers`` worker processes (default: one per CPU), started and
        stopped here. ``client``: an existing ``distributed.Client`` instead.
    csv : also write ``results.csv``.
    progress : draw the progress line (default: when stderr is a terminal).
    force : start afresh even if ``out_dir`` holds (part of) another run.
    stop_after : stop after this many batches (an interruption on purpose; run again to resume).
    batch_size : variants per task (default: sized so a task computes >= 0.1 s).
    """
    import pandas as pd

    start = time.perf_counter()
    out_dir = Path(out_dir)
    check_out_folder(campaign, out_dir, csv=csv)
    parts_dir = out_dir / "parts"
    manifest_path = out_dir / "manifest.json"
    table = campaign.variants()
    n = len(table)
    digest = campaign.digest()
    manifest = None
    if manifest_path.exists() and not force:
        try:
            manifest = json.loads(read_text(manifest_path, "manifest", limit=MANIFEST_LIMIT))
        except (InputError, ValueError) as exc:
            raise CampaignError(f"{out_dir}: its manifest.json is unreadable ({exc}); use another --out or --force") from None
        if not isinstance(manifest, dict) or manifest.get("digest") != digest:
            raise CampaignError(
                f"{out_dir}: holds results of another campaign (or of an edited file); use another --out or --force"
            )
    own = client is None
    cluster = None
    if own:  # before anything is written: a scheduler that cannot be reached leaves no folder behind
        client, cluster = _cluster(scheduler, workers)
    n_workers = max(len(client.scheduler_info().get("workers", {})), 1)
    draw = progress if progress is not None else sys.stderr.isatty()
    interrupted = False
    signum = 0
    computed = 0
    notes = []
    compute_start = time.perf_counter()
    compute_end = compute_start
    recordings_dir = None
    futures: dict = {}
    noted: list = []
    quiet = contextlib.ExitStack()  # from the first batch on: the sizing batches' parts are written before the rest
    try:
        quiet.enter_context(_signals_noted(noted))
        if manifest is None:
            if force and out_dir.exists():  # afresh: nothing of the run before stays beside the new results
                from .report import FLEET_WORST, HISTOGRAMS, SCATTER

                for p in list(parts_dir.glob("part-*.parquet")) if parts_dir.exists() else []:
                    p.unlink()
                for name in (*OUT_FILES, HISTOGRAMS, SCATTER, FLEET_WORST):  # (never an input: check_out_folder)
                    with contextlib.suppress(FileNotFoundError):
                        (out_dir / name).unlink()
            try:
                parts_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:  # (/proc/x: named, not "[Errno 2] No such file or directory: '/proc/x'")
                raise CampaignError(f"--out {out_dir}: cannot make the folder ({exc.strerror or exc})") from None
            write_table(out_dir / "variants.parquet", table)
            manifest = {"digest": digest, "name": campaign.name, "variants": n, "bounds": None}
            write_output(manifest_path, json.dumps(manifest), force=True, what="campaign output")
        if campaign.fleet_folder is not None:
            recordings_dir = out_dir / "recordings"
            recordings_dir.mkdir(parents=True, exist_ok=True)
        portable = portable_of(campaign)
        # once per worker, not inside every task (a list: a dict would be scattered value by value)
        portable = client.scatter([portable], broadcast=True, hash=False)[0]
        bounds = manifest.get("bounds")
        if bounds is None:  # size the batches from first ones, one per worker at once (no worker idles meanwhile)
            # (parts of a run interrupted while it sized: bounds never written, so their rows are not known to match
            # this run's batches, another --batch-size or worker count making other ones; the few first batches are
            # made again. Kept, part 0 of 64 rows was taken for batch 0 of 100 and the campaign never completed)
            for p in parts_dir.glob("part-*.parquet"):
                p.unlink()
            first = batch_size or min(FIRST_BATCH, n)
            sizing = min(n_workers, n // first) if batch_size is None else 0
            if sizing and n > sizing * first:
                where = str(recordings_dir) if recordings_dir else None
                batches = [client.submit(run_batch, portable, table.iloc[k * first : (k + 1) * first], where, pure=False)
                           for k in range(sizing)]  # fmt: skip
                futures.update((future, (k, k * first, (k + 1) * first)) for k, future in enumerate(batches))
                per_variant = math.inf
                for k, future in enumerate(batches):
                    rows = _rows_of(future, table, k * first, (k + 1) * first)
                    if isinstance(rows, pd.DataFrame):  # (a batch that broke as a whole sizes nothing)
                        per_variant = min(per_variant, (float(rows["seconds"].iloc[0]) if len(rows) else 0.0) / first)
                    write_part(parts_dir / f"part-{k:05d}.parquet", rows)
                    computed += first
                    _raise_noted(noted)
                futures.clear()
                rest = n - sizing * first
                size = max(math.ceil(MIN_TASK_SECONDS / max(per_variant, 1e-9)), math.ceil(rest / (4 * n_workers)))
                size = min(size, MAX_BATCH)
                bounds = [(k * first, (k + 1) * first) for k in range(sizing)]
                bounds += [(a + sizing * first, b + sizing * first) for a, b in _bounds(rest, size, size)]
            else:
                size = batch_size or n
                bounds = _bounds(n, first, size)
            manifest["bounds"] = bounds
            write_output(manifest_path, json.dumps(manifest), force=True, what="campaign output")
        pending = [(k, a, b) for k, (a, b) in enumerate(bounds) if not (parts_dir / f"part-{k:05d}.parquet").exists()]
        done_before = n - sum(b - a for _, a, b in pending)
        bar = _Progress(n, done_before, draw)
        if stop_after is not None:
            pending = pending[: max(stop_after, 0)]
        from distributed import as_completed

        futures = {
            client.submit(run_batch, portable, table.iloc[a:b], str(recordings_dir) if recordings_dir else None, pure=False): (k, a, b)
            for k, a, b in pending
        }  # fmt: skip
        for future in as_completed(futures):
            k, a, b = futures[future]
            rows = _rows_of(future, table, a, b)
            write_part(parts_dir / f"part-{k:05d}.parquet", rows)
            computed += b - a
            bar.update(b - a)
            _raise_noted(noted)
        _raise_noted(noted)
        compute_end = time.perf_counter()
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM as io.atomic.Terminated
        from ..io.atomic import interruption_handled

        interruption_handled()  # (what follows keeps the parts and says so: not raised again at its writes)
        interrupted = True
        signum = int(getattr(exc, "signum", signal.SIGINT))
        notes.append("interrupted: run the same command again to resume")
    finally:
        for future in futures:  # released while the client is open: a future freed after the close (an
            future.release()  # interrupt's traceback can hold one) would print an error from its __del__
        if own:
            _close(client, cluster)
        quiet.close()  # after the close: an interrupt printed from a callback meanwhile is dropped too
    parts = sorted(parts_dir.glob("part-*.parquet"))
    frames = [_read_part(p) for p in parts]
    result = pd.concat(frames, ignore_index=True).sort_values("variant", kind="stable").reset_index(drop=True) if frames else table.iloc[:0]
    complete = len(result) == n
    if complete:
        from .report import column_units

        result.attrs["units"] = column_units(result.columns)  # (kept in the Parquet file: .attrs["units"] on reading)
        write_table(out_dir / "results.parquet", result)
        if csv:
            write_table(out_dir / "results.csv", result, csv=True)
    else:
        interrupted = True
    return CampaignRun(
        result, out_dir, time.perf_counter() - start, computed, n_workers, interrupted, notes, compute_end - compute_start,
        signum,
    )


def _close(client, cluster) -> None:
    """Close the client and the local cluster; a second interrupt meanwhile does not leave the workers running.

    Dask's own log lines are off meanwhile: after an interrupt its scheduler
    logs (at CRITICAL, with a traceback) messages to workers already gone,
    which says nothing about the campaign (its parts are written or not).
    """
    import logging

    with _signals_held():
        logging.disable(logging.CRITICAL)
        try:
            client.close()
            if cluster is not None:
                cluster.close()
        finally:
            logging.disable(logging.NOTSET)


@contextlib.contextmanager
def _signals_noted(noted: list):
    """SIGINT and SIGTERM appended to ``noted`` as they arrive, then handled as before (KeyboardInterrupt,
    ``io.atomic.Terminated``). Python raises a handler's exception in whatever code runs at that moment; in a
    garbage-collector callback (dask's ``distributed.gc`` installs one) or a ``__del__`` (a dask
    ``Future``'s) it can only print it ("Exception ignored in ..."), and the interrupt would be lost (seen
    in CI: the sweep went on to the end and exited 0, or exited with that print above its one line). The
    print of a noted interrupt is dropped, and the campaign loop raises what was noted after every batch
    (:func:`_raise_noted`). Main thread only."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def note(signum, frame):
        noted.append(signum)
        handler = previous[signum]
        if callable(handler):
            handler(signum, frame)
        elif handler == signal.SIG_DFL:  # the system's action (end the process), as without this block
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)

    def quiet(unraisable):  # the interrupt raised where Python can only print it: noted, raised again later
        if not (noted and isinstance(unraisable.exc_value, KeyboardInterrupt)):
            hook(unraisable)

    installed = [sig for sig, handler in previous.items() if handler is not None and handler != signal.SIG_IGN]
    for sig in installed:
        signal.signal(sig, note)
    hook, sys.unraisablehook = sys.unraisablehook, quiet
    try:
        yield
    finally:
        sys.unraisablehook = hook
        for sig in installed:
            signal.signal(sig, previous[sig])


def _raise_noted(noted: list) -> None:
    """Raise the first signal in ``noted`` again (SIGINT: KeyboardInterrupt; SIGTERM: ``Terminated``)."""
    if noted:
        from ..io.atomic import Terminated

        raise KeyboardInterrupt() if noted[0] == signal.SIGINT else Terminated(noted[0])


@contextlib.contextmanager
def _signals_held():
    """SIGINT and SIGTERM ignored in the block (main thread only): closing the cluster is not cut short."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # the handlers are read before any is changed: a signal that arrives between the two changes raises
    # out of the block with both restored (it used to leave SIGINT ignored for the rest of the process)
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        for sig in previous:
            signal.signal(sig, signal.SIG_IGN)
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def loop_of_single_runs(campaign: Campaign, rows, check_stability: bool = True) -> list:
    """The reference: each variant through ``simulate`` in a plain loop, metrics per row (tests, benchmarks)."""
    from ..core.simulate import simulate

    out = []
    for row in rows:
        record = dict(row)
        try:
            result = simulate(campaign.scene_of(row), check_stability=check_stability)
        except BeltDriveError as exc:
            record["error"] = f"{type(exc).__name__}: {exc}"
            record.update({name: math.nan for name in METRICS})
        else:
            record["error"] = ""
            record["model"] = result.model
            record.update(run_metrics(result))
        out.append(record)
    return out


__all__ = [
    "CampaignRun", "MAX_BATCH", "MIN_TASK_SECONDS", "local_cluster", "loop_of_single_runs", "portable_of", "run_batch",
    "run_campaign", "write_part", "write_table",
]  # fmt: skip
