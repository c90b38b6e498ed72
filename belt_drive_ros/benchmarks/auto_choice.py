"""``method: auto`` against a sweep: is the automatic choice the fastest accurate fixed-step option?

For each shipped scene, on the model ``auto`` runs it on (rigid or flexible
by the frequency rule; slipping where that run passes the capstan limit):

* the choice :func:`~belt_drive_ros.core.method_choice.choose_for_scene`
  makes with the scene's tolerance (default 1e-4 of the peak);
* a sweep of every fixed-step method at ``scene.dt * 2^j``, j = -3 .. 2
  (steps the stability guard refuses are not run), each run's error
  against the module's reference (:mod:`.common`: DOP853 rtol 1e-13;
  slipping: :mod:`.slip_runs`, DOP853 with located events) and its CPU
  time (minimum of repeats, :func:`.common.cpu_time`);
* the fastest run of the sweep within the tolerance, and the choice's own
  error and CPU time measured the same way.

``python -m belt_drive_ros.benchmarks.auto_choice [--out DIR] [--quick]``
prints the markdown table of docs/performance.md ("The automatic choice
against a sweep") and writes ``auto_choice.csv``; ``--quick`` sweeps j = -1 .. 1
on a shortened run (seconds, for a smoke test). ``--varied N``: instead, the
figures over N time-varying scenes that name no method (:func:`varied_scene`,
the family ``tests/test_method_choice.py`` checks).
"""

from __future__ import annotations

import argparse
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..core import sources as S
from ..core.integrators import FIXED_STEP_METHODS
from ..core.simulate import simulate
from ..core.model import make_model
from ..io.scenes import load_scene
from ..core.simulate import Simulator
from ..core.stability import check_step
from . import slip_runs
from .common import cpu_time, dop853_reference, resolved_model, run_errors, write_csv

#: shipped scenes in the table
SCENES = ("paper", "truck_compressor", "e_motor_start", "bsg_start")
#: which scenes run on the slipping model under auto (from their own runs: docs/slip.md)
SLIPPING = ("truck_compressor", "bsg_start")
COLUMNS = ("scene", "model", "kind", "method", "dt", "error", "cpu_per_s", "estimate", "scene_dt")


def _linear_run(scene, kind, method, dt, ref):
    model = make_model(kind, scene.params)
    x0 = scene.initial_state.vector(kind, scene.params.ratio)
    sim = Simulator(model, scene.drive, scene.load, method, dt, check_stability=False)
    try:
        with np.errstate(all="ignore"):
            cpu, (t, x) = cpu_time(lambda: sim.run(scene.duration, x0))
    except Exception:  # diverged, or an implicit stage did not converge
        return math.nan, math.inf
    if not np.all(np.isfinite(x)):
        return cpu, math.inf
    return cpu / scene.duration, run_errors(ref, t, x)["error"]


def _slipping_run(case, method, dt, ref):
    r = slip_runs.run(case, "hybrid", method, dt)
    if r.status != "ok":
        return math.nan, math.inf
    return r.cpu_s / case.duration, slip_runs.errors(ref, r)["error"]


def study(scenes=SCENES, exponents=range(-3, 3), duration: float | None = None) -> list[dict]:
    """Rows of :data:`COLUMNS`: per scene the choice (kind ``auto``) and every sweep run (kind ``sweep``)."""
    rows = []
    for name in scenes:
        scene = load_scene(name).with_overrides(method="auto", duration=duration)
        slipping = name in SLIPPING
        kind = "slipping" if slipping else resolved_model(scene)
        result = simulate(scene)  # what auto does: the choice, the run, the guard's verdict on it (slipping: after it)
        choice = replace(result.method_choice, method=result.method, dt=result.dt,
                         error=result.accuracy.error if result.accuracy is not None else math.nan)  # fmt: skip
        steps = sorted({scene.dt * 2.0**j for j in exponents} | {choice.dt})
        if slipping:
            case = slip_runs.case_from_scene(scene.with_overrides(method=choice.method, dt=choice.dt))
            ref = slip_runs.reference(case, min(steps))  # every step a multiple of the finest (substeps 1 here)

            def measure(method, dt):
                return _slipping_run(case, method, dt, ref)
        else:
            ref = dop853_reference(scene.with_overrides(method="etd2"), kind)

            def measure(method, dt):
                return _linear_run(scene, kind, method, dt, ref)

        model = make_model("flexible" if slipping else kind, scene.params)
        cpu, err = measure(choice.method, choice.dt)
        rows.append(dict(scene=name, model=kind, kind="auto", method=choice.method, dt=choice.dt, error=err,
                         cpu_per_s=cpu, estimate=choice.error, scene_dt=scene.dt))  # fmt: skip
        for method in FIXED_STEP_METHODS:
            for dt in steps:
                if not check_step(model.A, model.B, method, dt).stable:
                    continue
                cpu, err = measure(method, dt)
                rows.append(dict(scene=name, model=kind, kind="sweep", method=method, dt=dt, error=err, cpu_per_s=cpu,
                                 estimate=math.nan, scene_dt=scene.dt))  # fmt: skip
    return rows


def _fastest(rows, name, tolerance, largest=math.inf):
    ok = [r for r in rows if r["scene"] == name and r["kind"] == "sweep" and r["error"] <= tolerance
          and math.isfinite(r["cpu_per_s"]) and r["dt"] <= largest * (1 + 1e-9)]  # fmt: skip
    return min(ok, key=lambda r: r["cpu_per_s"]) if ok else None


def table(rows, tolerance: float = 1e-4) -> str:
    """The markdown table: per scene the choice against the fastest sweep run within ``tolerance``, on the scene's
    output grid (steps up to its dt, which auto keeps) and at any step."""
    lines = [
        "| scene (model) | `method: auto` | error measured / rated | CPU s per sim. s | fastest accurate, dt <= scene's "
        "| error | CPU s per sim. s | auto / it | fastest accurate, any step | error | auto / it |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in dict.fromkeys(r["scene"] for r in rows):
        auto = next(r for r in rows if r["scene"] == name and r["kind"] == "auto")
        cells = [f"`{name}` ({auto['model']})", f"`{auto['method']}` {auto['dt'] * 1e3:.4g} ms",
                 f"{auto['error']:.2g} / {auto['estimate']:.2g}", f"{auto['cpu_per_s']:.3g}"]  # fmt: skip
        grid = _fastest(rows, name, tolerance, auto["scene_dt"])
        cells += ([f"`{grid['method']}` {grid['dt'] * 1e3:.4g} ms", f"{grid['error']:.2g}", f"{grid['cpu_per_s']:.3g}",
                   f"{auto['cpu_per_s'] / grid['cpu_per_s']:.2f}"] if grid else ["none", "", "", ""])  # fmt: skip
        best = _fastest(rows, name, tolerance)
        cells += ([f"`{best['method']}` {best['dt'] * 1e3:.4g} ms", f"{best['error']:.2g}",
                   f"{auto['cpu_per_s'] / best['cpu_per_s']:.2f}"] if best else ["none", "", ""])  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def varied_scene(k: int):
    """Scene k of a family with time-varying torques: sine drives from 0.7 to 3.5 times the belt mode, an engine,
    a compressor load by angle, a sine load; truck and paper belts; 0.4 s, dt 0.5 or 1 ms, no method named."""
    rng = np.random.default_rng(100 + k)
    base = load_scene("truck_compressor" if k % 3 else "paper")
    p = replace(base.params, c=float(base.params.c * rng.choice([0.1, 0.5, 1.0, 2.0])))
    f_n = p.belt_natural_frequency / (2.0 * math.pi)
    kind = k % 4
    start = base.initial_state
    if kind == 0:
        drive = S.Sine(mean=float(rng.uniform(5, 30)), amplitude=float(rng.uniform(2, 20)),
                       frequency=float(rng.uniform(0.7, 3.5) * f_n))  # fmt: skip
        load = S.Polynomial(0.0, float(rng.uniform(0.02, 0.3)))
    elif kind == 1:
        drive = S.Engine(mean_torque=float(rng.uniform(5, 40)), cylinders=int(rng.choice([3, 4, 6])),
                         harmonics=(float(rng.uniform(10, 200)), float(rng.uniform(3, 60))),
                         speed_setpoint=float(rng.uniform(40, 120)), governor_gain=float(rng.uniform(2, 15)), max_torque=400.0)
        load = S.Compressor(mean_torque=float(rng.uniform(2, 15)), c1=float(rng.uniform(0.001, 0.2)), cylinders=2,
                            harmonics=(float(rng.uniform(1, 10)),))  # fmt: skip
        start = replace(start, omega_M=0.9 * drive.speed_setpoint)
    elif kind == 2:
        drive = S.Constant(float(rng.uniform(5, 30)))
        load = S.Sine(mean=float(rng.uniform(1, 5)), amplitude=float(rng.uniform(1, 5)),
                      frequency=float(rng.uniform(0.7, 3.5) * f_n))  # fmt: skip
    else:
        drive = S.Sine(mean=0.0, amplitude=float(rng.uniform(2, 20)), frequency=float(rng.uniform(0.7, 1.3) * f_n))
        load = S.Compressor(mean_torque=float(rng.uniform(1, 5)), c1=float(rng.uniform(0.01, 0.2)), cylinders=1,
                            harmonics=(float(rng.uniform(1, 5)),))  # fmt: skip
    dt = float(rng.choice([5e-4, 1e-3]))
    return replace(base, name=f"varied_{k}", params=p, drive=drive, load=load, initial_state=start, duration=0.4,
                   model="flexible", method="auto", dt=dt)  # fmt: skip


def varied(count: int, tolerance: float = 1e-4) -> dict:
    """Figures over :func:`varied_scene` 0 .. count - 1 against DOP853 (rtol 1e-13): the default run's worst
    error / tolerance and choices; with each stated method, the guard's verdicts and the worst measured error
    among its "accurate" ones; estimate / measured over the runs (measured > 1e-8)."""
    from collections import Counter

    worst, choices, verdicts, worst_ok, ratios = 0.0, Counter(), Counter(), 0.0, []
    for k in range(count):
        scene = varied_scene(k)
        ref = dop853_reference(scene.with_overrides(method="etd2"), "flexible")
        result = simulate(scene)
        worst = max(worst, run_errors(ref, result.time, result.states)["error"] / tolerance)
        choices[f"{result.method} x{result.method_choice.substeps}"] += 1
        for method in ("exact", "etd2", "etd4", "lawson5", "rk4"):
            try:
                run = simulate(scene.with_overrides(method=method))
            except Exception:  # refused (unstable): a verdict too
                verdicts[f"{method} refused"] += 1
                continue
            error = run_errors(ref, run.time, run.states)["error"]
            verdicts[f"{method} {'accurate' if run.accuracy.accurate else 'inaccurate'}"] += 1
            if run.accuracy.accurate:
                worst_ok = max(worst_ok, error / tolerance)
            if error > 1e-8:
                ratios.append(run.accuracy.error / error)
    return dict(cases=count, worst_default=worst, choices=dict(choices), verdicts=dict(verdicts),
                worst_accurate=worst_ok, ratio_min=min(ratios), ratio_median=float(np.median(ratios)),
                ratio_max=max(ratios))  # fmt: skip


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="folder for auto_choice.csv")
    parser.add_argument("--quick", action="store_true", help="j = -1..1 on 0.3 s runs (a smoke test)")
    parser.add_argument("--scene", action="append", help="only these scenes (repeatable)")
    parser.add_argument("--varied", type=int, metavar="N", help="instead: figures over N scenes that name no method")
    args = parser.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if args.varied:
        for key, value in varied(args.varied).items():
            print(f"{key:16s} {value}")
        return 0
    rows = study(tuple(args.scene or SCENES), range(-1, 2) if args.quick else range(-3, 3), 0.3 if args.quick else None)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        write_csv(args.out / "auto_choice.csv", rows, COLUMNS)
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
