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
on a shortened run (seconds, for a smoke test).
"""

from __future__ import annotations

import argparse
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..core.integrators import FIXED_STEP_METHODS
from ..core.simulate import simulate
from ..core.model import make_model
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
        from ..core.scene import load_scene

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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="folder for auto_choice.csv")
    parser.add_argument("--quick", action="store_true", help="j = -1..1 on 0.3 s runs (a smoke test)")
    parser.add_argument("--scene", action="append", help="only these scenes (repeatable)")
    args = parser.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    rows = study(tuple(args.scene or SCENES), range(-1, 2) if args.quick else range(-3, 3), 0.3 if args.quick else None)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        write_csv(args.out / "auto_choice.csv", rows, COLUMNS)
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
