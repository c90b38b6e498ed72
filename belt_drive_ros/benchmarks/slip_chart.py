"""Slipping belt: work-precision and failure of the event-driven hybrid against fixed-step and regularised runs.

Scene: the ``truck_compressor`` parameters with a softer preload (F_0 = 300 N,
mu = 0.3: Q_max = 253 N), a constant 30 N m drive and a load of
15 +/- 10 N m at 8 Hz on wheel 3 (peaks above r_3 Q_max = 17.7 N m), 0.3 s:
repeated stick-slip (about a dozen events). Reference: scipy DOP853 per mode
with located events (rtol = atol = 1e-12, :func:`~belt_drive_ros.core.slip_reference.reference_hybrid`).
Error: max |omega - omega_ref| / max |omega_ref| over both speeds on a 2 ms grid.

Runs, each over a sweep of steps:

* hybrid (Coulomb friction, events located): ``exact``, ``etd2``, ``etd4``, ``rk4``;
* hybrid without event location (mode switched at the step end): ``etd2``;
* regularised friction ``Q = Q_max tanh(s'/v_eps)`` at v_eps = 1e-2, 1e-3,
  1e-4 m/s with ``rk4`` and ``etd2`` (its error includes the modelling error
  of the regularisation against Coulomb friction).

Fidelity (third panel): the flexible (linear) model against the slipping
one on ``truck_compressor`` (engine drive with a tenth of its firing
ripple, F_0 = 300 N, mu = 0.3) with a load
``L (1 + 0.3 sin(2 pi 8 t))`` whose mean ``L`` is swept through the belt's
capacity ``r_3 Q_max``; error of the flexible model's wheel-3 speed, max
over 1 s relative to the speed's maximum.

A run is **failed** when it diverges (non-finite or beyond 1e5 rad/s), a
chattering error stops it, or its error exceeds 1. The chart: error against
CPU time (left) and against the step (second), failed runs on the top edge;
the fidelity panel (third); and the slipping scene's stability map (fourth,
``slip_stability.csv``): per method and friction law, the largest step of
the sweep that runs and the smallest that fails (explicit ``euler`` and
``rk4`` against the exponential methods, the regularised contact at each
``v_eps``).
"""

from __future__ import annotations

import dataclasses
import math
import time as _time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import BeltDriveError
from ..core.params import BeltDriveParams
from ..core.slip import HybridStepper, SlippingBeltModel
from ..core.slip_reference import RegularisedFriction, reference_hybrid
from .common import log, pyplot, save_figure, write_csv

COLUMNS = ("family", "method", "v_eps", "dt", "cpu_s", "error", "failed", "events")
FIDELITY_COLUMNS = ("load_ratio", "peak_force_ratio", "flexible_error", "slip_fraction", "events")
STABILITY_COLUMNS = ("family", "method", "v_eps", "largest_running_dt", "smallest_failing_dt")
DURATION = 0.3


@dataclass(frozen=True)
class Config:
    steps: tuple = (2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4, 6.25e-5, 3.125e-5)
    hybrid_methods: tuple = ("exact", "etd2", "etd4", "rk4", "euler")
    v_eps: tuple = (1e-2, 1e-3, 1e-4)
    regularised_methods: tuple = ("rk4", "etd2", "euler")
    load_ratios: tuple = (0.3, 0.5, 0.7, 0.8, 0.9, 1.0, 1.1, 1.25, 1.5, 2.0)


FULL = Config()
QUICK = Config(steps=(1e-3, 2.5e-4), hybrid_methods=("etd2",), v_eps=(1e-3,), regularised_methods=("rk4",), load_ratios=(0.5, 1.5))


def fidelity(cfg) -> list:
    """Flexible-model error against the slipping model as the load grows past the capacity (see the module docstring)."""
    from ..core.scene import load_scene
    from ..core.simulate import simulate
    from ..core.fidelity import limit_exceedance
    from ..core.sources import Sine

    base = load_scene("truck_compressor")
    params = base.params.replace(F_0=300.0, mu=0.3)
    capacity = params.r_3 * params.friction_limit(0.0)
    rows = []
    for ratio in cfg.load_ratios:
        mean = ratio * capacity
        drive = dataclasses.replace(base.drive, harmonics=tuple(0.1 * a for a in base.drive.harmonics))  # smoother engine
        scene = base.with_overrides(params=params, drive=drive, load=Sine(mean=mean, amplitude=0.3 * mean, frequency=8.0), duration=1.0)
        flex = simulate(scene, model="flexible")
        slip = simulate(scene, model="slipping")
        w_f, w_s = flex.outputs["omega_3"], slip.outputs["omega_3"]
        peak, _ = limit_exceedance(params, flex.time, flex.outputs)
        rows.append(dict(
            load_ratio=ratio, peak_force_ratio=peak,
            flexible_error=float(np.max(np.abs(w_f - w_s)) / np.max(np.abs(w_s))),
            slip_fraction=float(np.mean(slip.outputs["slip"])), events=len(slip.events),
        ))
    return rows


def scene():
    """(model, drive, load) of the stick-slip study (see the module docstring)."""
    p = BeltDriveParams(mu=0.3, F_0=300.0)
    return SlippingBeltModel(p), (lambda t, a, w: 30.0), (lambda t, a, w: 15.0 + 10.0 * math.sin(2.0 * math.pi * 8.0 * t))


def _error(states, ref, stride):
    w = states[::stride, 2:4]
    if w.shape != ref.shape or not np.all(np.isfinite(w)):
        return math.inf
    return float(np.max(np.abs(w - ref)) / np.max(np.abs(ref)))


def run(out_dir: Path, quick: bool = False, quiet: bool = False) -> dict:
    cfg = QUICK if quick else FULL
    out_dir = Path(out_dir)
    m, drive, load = scene()
    grid = np.linspace(0.0, DURATION, int(round(DURATION / 2e-3)) + 1)
    ref = reference_hybrid(m, drive, load, grid, np.zeros(5), rtol=1e-12, atol=1e-12)
    ref_w = ref.states[:, 2:4]
    log(f"slip: reference DOP853 with {len(ref.events)} events", quiet)
    rows = []

    def record(family, method, v_eps, dt, fn):
        stride = int(round(2e-3 / dt))
        start = _time.process_time()
        try:
            with np.errstate(all="ignore"):  # divergence shows as non-finite states: counted, not warned
                states, events = fn()
            failed = False
        except (BeltDriveError, FloatingPointError, OverflowError, ValueError):
            states, events, failed = None, 0, True
        cpu = _time.process_time() - start
        err = math.inf if states is None else _error(states, ref_w, stride)
        failed = failed or not err <= 1.0
        rows.append(dict(family=family, method=method, v_eps=v_eps, dt=dt, cpu_s=cpu, error=err, failed=failed, events=events))
        log(f"slip: {family:<12} {method:<6} v_eps={v_eps:<6g} dt={dt:<9g} error={err:.3g} cpu={cpu:.3f} s", quiet)

    for dt in cfg.steps:
        n = int(round(DURATION / dt))
        time = np.linspace(0.0, DURATION, n + 1)
        for method in cfg.hybrid_methods:
            def hybrid(method=method, time=time):
                r = HybridStepper(m, drive, load, method).run(time, np.zeros(5))
                return r.states, len(r.events)

            record("hybrid", method, 0.0, dt, hybrid)
        def sampled(time=time):
            r = HybridStepper(m, drive, load, "etd2", locate=False).run(time, np.zeros(5))
            return r.states, len(r.events)

        record("no_location", "etd2", 0.0, dt, sampled)
        for v_eps in cfg.v_eps:
            for method in cfg.regularised_methods:
                def regularised(method=method, v_eps=v_eps, time=time):
                    return RegularisedFriction(m, v_eps).run(time, np.zeros(5), drive, load, method), 0

                record("regularised", method, v_eps, dt, regularised)
    fid = fidelity(cfg)
    for r in fid:
        log(f"slip: fidelity load {r['load_ratio']:.2f} x capacity: peak force {r['peak_force_ratio']:.2f} x Q_max, "
            f"flexible error {r['flexible_error']:.3g}, slips {100 * r['slip_fraction']:.1f} %", quiet)
    stable = stability(rows)
    for r in stable:
        log(f"slip: stability {r['family']:<12} {r['method']:<6} v_eps={r['v_eps']:<6g} runs up to dt={r['largest_running_dt']:g}, "
            f"fails from {r['smallest_failing_dt']:g}", quiet)
    csv_path = write_csv(out_dir / "slip.csv", rows, COLUMNS)
    fid_path = write_csv(out_dir / "slip_fidelity.csv", fid, FIDELITY_COLUMNS)
    stab_path = write_csv(out_dir / "slip_stability.csv", stable, STABILITY_COLUMNS)
    png = _plot(rows, fid, stable, out_dir / "slip.png")
    return {"csv": [csv_path, fid_path, stab_path], "png": png, "rows": rows, "fidelity": fid, "stability": stable}


def stability(rows) -> list:
    """Per (family, method, v_eps): the largest step of the sweep that ran and the smallest that failed (nan: none)."""
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["family"], r["method"], r["v_eps"]), []).append(r)
    out = []
    for (family, method, v_eps), rs in groups.items():
        ran = [r["dt"] for r in rs if not r["failed"]]
        failed = [r["dt"] for r in rs if r["failed"]]
        out.append(dict(family=family, method=method, v_eps=v_eps,
                        largest_running_dt=max(ran) if ran else math.nan,
                        smallest_failing_dt=min(failed) if failed else math.nan))
    return out


def _plot(rows, fid, stable, path):
    plt = pyplot()
    fig, (ax_cost, ax_dt, ax_fid, ax_stab) = plt.subplots(1, 4, figsize=(24, 5.5))
    series: dict = {}
    for r in rows:
        label = f"{r['family']} {r['method']}" + (f" v_eps={r['v_eps']:g}" if r["family"] == "regularised" else "")
        series.setdefault(label, []).append(r)
    top = 3.0
    for label, rs in series.items():
        ls = "-" if label.startswith("hybrid") else ":" if label.startswith("no_location") else "--"
        err = np.array([min(r["error"], top) if not r["failed"] else top for r in rs])
        ax_cost.loglog([max(r["cpu_s"], 1e-4) for r in rs], err, ls, marker="o", ms=3, label=label)
        ax_dt.loglog([r["dt"] for r in rs], err, ls, marker="o", ms=3, label=label)
    for ax in (ax_cost, ax_dt):
        ax.axhline(1.0, color="k", lw=0.6)
        ax.grid(True, which="both", alpha=0.3)
        ax.set_ylabel("max speed error / max speed (failed: top edge)")
    ax_cost.set_xlabel("CPU time [s] (0.3 s simulated)")
    ax_dt.set_xlabel("step dt [s]")
    ax_dt.legend(fontsize=6, loc="lower right")
    ratio = [r["peak_force_ratio"] for r in fid]
    ax_fid.semilogy(ratio, [max(r["flexible_error"], 1e-16) for r in fid], "o-", label="flexible vs slipping: wheel-3 speed")
    ax_fid.axvline(1.0, color="k", lw=0.6)
    ax_fid.set_xlabel("peak transmitted force of the flexible run / Q_max (auto: slipping beyond 1)")
    ax_fid.set_ylabel("relative error of the linear (flexible) model")
    ax_fid.grid(True, which="both", alpha=0.3)
    ax_fid.legend(fontsize=7)
    labels = [f"{r['family']} {r['method']}" + (f" v_eps={r['v_eps']:g}" if r["family"] == "regularised" else "") for r in stable]
    y = np.arange(len(stable))
    steps = [r["dt"] for r in rows]
    floor = min(steps) / 2.0
    ran = [r["largest_running_dt"] if math.isfinite(r["largest_running_dt"]) else floor for r in stable]
    ax_stab.barh(y, ran, color=["C0" if lab.startswith("hybrid") else "C1" if lab.startswith("no_location") else "C3" for lab in labels])
    for j, r in enumerate(stable):
        if math.isfinite(r["smallest_failing_dt"]):
            ax_stab.plot(r["smallest_failing_dt"], j, "kx")
    ax_stab.set_xscale("log")
    ax_stab.set_xlim(floor, 2.0 * max(steps))
    ax_stab.set_yticks(y)
    ax_stab.set_yticklabels(labels, fontsize=6)
    ax_stab.set_xlabel("dt [s]: bar = largest that runs, x = smallest that fails")
    ax_stab.set_title("stability map of the slipping scene", fontsize=9)
    ax_stab.grid(True, which="both", axis="x", alpha=0.3)
    fig.suptitle("slipping belt, repeated stick-slip: event-driven hybrid vs step-end switching vs regularised friction")
    fig.tight_layout()
    return save_figure(fig, path)
