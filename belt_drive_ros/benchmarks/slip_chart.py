"""Slipping belt, repeated stick-slip: the event-driven hybrid against step-end switching and regularised friction.

Scene (:func:`~belt_drive_ros.benchmarks.slip_runs.stick_slip_case`): the
``truck_compressor`` belt with a softer preload (F_0 = 300 N, mu = 0.3:
Q_max = 253 N), a constant 30 N m drive and a load of 15 +/- 10 N m at 8 Hz
on wheel 3 (peaks above r_3 Q_max = 17.7 N m), 0.3 s from rest: repeated
stick-slip (about a dozen events). A smaller, harder case than the
work-precision chart's slipping scene (``truck_compressor`` on the slipping
model), with steps down to 31 us.

Variants, reference, error and failure: :mod:`belt_drive_ros.benchmarks.slip_runs`
(hybrid ``exact``, ``etd2``, ``etd4``, ``rk4``, ``euler`` through the
package's engine; ``etd2`` without event location; regularised friction at
v_eps = 1e-2, 1e-3, 1e-4 m/s with ``rk4``, ``etd2``, ``euler``). Here a run
also counts as **failed** when its error exceeds 1.

The chart: error against CPU time (left) and against the step (middle),
failed runs on the top edge (a run stopped as diverged has no CPU time and is
only in the middle panel); and the scene's step limits (right,
``slip_stability.csv``): per variant, the largest step of the sweep that
runs and the smallest that fails. The linear model's error against the
slipping one as the load grows past the limit is the fidelity chart's third
panel (``belt-drive bench fidelity``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import slip_runs
from .common import log, pyplot, save_figure, write_csv

COLUMNS = ("family", "method", "v_eps", "dt", "cpu_s", "error", "e_speed", "e_belt", "status", "failed", "events")
STABILITY_COLUMNS = ("family", "method", "v_eps", "largest_running_dt", "smallest_failing_dt")


@dataclass(frozen=True)
class Config:
    steps: tuple = (2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4, 6.25e-5, 3.125e-5)
    hybrid_methods: tuple = ("exact", "etd2", "etd4", "rk4", "euler")
    no_location: tuple = ("etd2",)
    v_eps: tuple = (1e-2, 1e-3, 1e-4)
    regularised_methods: tuple = ("rk4", "etd2", "euler")


FULL = Config()
QUICK = Config(steps=(1e-3, 2.5e-4), hybrid_methods=("etd2",), v_eps=(1e-3,), regularised_methods=("rk4",))


def measure(cfg: Config = FULL, quiet: bool = False) -> list[dict]:
    """One row per (variant, step) with the columns of :data:`COLUMNS`."""
    case = slip_runs.stick_slip_case()
    ref = slip_runs.reference(case, min(cfg.steps))
    log(f"slip: reference DOP853 with {ref.events} events", quiet)
    variants = [("hybrid", m, 0.0) for m in cfg.hybrid_methods]
    variants += [("no_location", m, 0.0) for m in cfg.no_location]
    variants += [("regularised", m, v) for v in cfg.v_eps for m in cfg.regularised_methods]
    rows = []
    for family, method, v_eps in variants:
        for dt in cfg.steps:
            r = slip_runs.run(case, family, method, dt, v_eps, repeats=1)
            row = dict(family=family, method=method, v_eps=v_eps, dt=dt, cpu_s=r.cpu_s, status=r.status, events=r.events,
                       error=math.inf, e_speed=math.inf, e_belt=math.inf)  # fmt: skip
            if r.status == "ok":
                row.update(slip_runs.errors(ref, r))
            row["failed"] = not row["error"] <= 1.0
            rows.append(row)
            log(f"slip: {slip_runs.variant_label(family, method, v_eps):<26} dt={dt:<9g} error={row['error']:.3g} "
                f"cpu={r.cpu_s:.3f} s {r.status}", quiet)  # fmt: skip
    return rows


def run(out_dir: Path, quick: bool = False, quiet: bool = False) -> dict:
    out_dir = Path(out_dir)
    rows = measure(QUICK if quick else FULL, quiet)
    stable = slip_runs.summarise_failures(rows)
    for r in stable:
        log(f"slip: stability {slip_runs.variant_label(r['family'], r['method'], r['v_eps']):<26} runs up to "
            f"dt={r['largest_running_dt']:g}, fails from {r['smallest_failing_dt']:g}", quiet)  # fmt: skip
    csv_path = write_csv(out_dir / "slip.csv", rows, COLUMNS)
    stab_path = write_csv(out_dir / "slip_stability.csv", stable, STABILITY_COLUMNS)
    png = _plot(rows, stable, out_dir / "slip.png")
    return {"csv": [csv_path, stab_path], "png": png, "rows": rows, "stability": stable}


def _plot(rows, stable, path):
    plt = pyplot()
    fig, (ax_cost, ax_dt, ax_stab) = plt.subplots(1, 3, figsize=(19, 5.5))
    series: dict = {}
    for r in rows:
        series.setdefault(slip_runs.variant_label(r["family"], r["method"], r["v_eps"]), []).append(r)
    top = 3.0
    for label, rs in series.items():
        family = rs[0]["family"]
        ls = "-" if family == "hybrid" else ":" if family == "no_location" else "--"
        err = np.array([top if r["failed"] else r["error"] for r in rs])
        timed = [(max(r["cpu_s"], 1e-4), e) for r, e in zip(rs, err) if math.isfinite(r["cpu_s"])]  # diverged: no time
        line = ax_dt.loglog([r["dt"] for r in rs], err, ls, marker="o", ms=3, label=label)[0]
        if timed:
            ax_cost.loglog(*zip(*timed), ls, marker="o", ms=3, color=line.get_color())
    for ax in (ax_cost, ax_dt):
        ax.axhline(1.0, color="k", lw=0.6)
        ax.grid(True, which="both", alpha=0.3)
        ax.set_ylabel("error: max rel. error of omega_M, belt torque (failed: top edge)")
    ax_cost.set_xlabel("CPU time [s] (0.3 s simulated)")
    ax_dt.set_xlabel("step dt [s]")
    ax_dt.legend(fontsize=6, loc="lower right")
    labels = [slip_runs.variant_label(r["family"], r["method"], r["v_eps"]) for r in stable]
    y = np.arange(len(stable))
    steps = [r["dt"] for r in rows]
    floor = min(steps) / 2.0
    ran = [r["largest_running_dt"] if math.isfinite(r["largest_running_dt"]) else floor for r in stable]
    colors = {"hybrid": "C0", "no_location": "C1", "regularised": "C3"}
    ax_stab.barh(y, ran, color=[colors[r["family"]] for r in stable])
    for j, r in enumerate(stable):
        if math.isfinite(r["smallest_failing_dt"]):
            ax_stab.plot(r["smallest_failing_dt"], j, "kx")
    ax_stab.set_xscale("log")
    ax_stab.set_xlim(floor, 2.0 * max(steps))
    ax_stab.set_yticks(y)
    ax_stab.set_yticklabels(labels, fontsize=6)
    ax_stab.set_xlabel("dt [s]: bar = largest that runs, x = smallest that fails (diverged, or error > 1)")
    ax_stab.set_title("step limits of the stick-slip scene", fontsize=9)
    ax_stab.grid(True, which="both", axis="x", alpha=0.3)
    fig.suptitle("slipping belt, repeated stick-slip: event-driven hybrid vs step-end switching vs regularised friction")
    fig.tight_layout()
    return save_figure(fig, path)
