"""``belt-drive bench network``: belt network runs, the compiled loop beside the Python step loop it replaced.

1. **Whole warm simulate()** of the shipped FEAD (``fead_i4``, default
   method and step, ``model: auto``: tier choice, stability guard, run,
   step-doubling accuracy check, outputs): x real time (process CPU, minimum
   of repeats), beside the previous design's loop written here as it was
   (the method's ``Integrator.step`` per step with the torques from Python
   floats; 0.1 s simulated, scaled), both on the same machine in one run.
2. **ns per step** (process CPU) of the network kernel per method on ``fead_i4`` (16 states, 5 profiles),
   and on the paper's drive beside the paper model's own compiled loop.
3. **The paper's drive as a network**: ``paper_network`` against the paper
   model's flexible run (etd2, 1 ms), max difference / peak of omega_3,
   omega_2 and the belt torque.

Prints a table and writes ``network.csv`` into ``--out``. Timings only; the tests assert correctness.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from .common import write_csv

#: trapezoidal is left out: its fixed point (tol 1e-13) meets a rounding 2-cycle of the crank governor (gain 20 N m s/rad)
METHODS = ("exact", "etd2", "etd4", "lawson5", "rk4")


def _python_step_loop(scene, dt: float, duration: float) -> float:
    """CPU seconds of the previous design's network run (a Python loop over ``Integrator.step``), absolute angles."""
    from ..core.integrators import method_class
    from ..core.network.model import NetworkModel

    model = NetworkModel.build(scene)
    A, B = model.state_space()
    integ = method_class(scene.method)(A, B, dt)
    n, m = len(scene.pulleys), model.M.shape[0]
    active = [(i, p.sign, p.torque.scalar_torque()) for i, p in enumerate(scene.pulleys) if p.sign]

    def inputs(t, x):
        xs = x.tolist()
        u = [0.0] * n
        for i, s, f in active:
            u[i] = s * f(t, xs[i], xs[m + i])
        return np.array(u)

    steps = int(round(duration / dt))
    x = np.zeros(2 * m)
    x[m : m + n] = model.speeds_at(scene.initial_speed)
    out = np.empty((steps + 1, 2 * m))
    start = time.process_time()
    for k in range(steps):
        x = integ.step(k * dt, x, inputs)
        if not math.isfinite(x.sum()):
            break
        out[k + 1] = x
    return time.process_time() - start


def run(out: Path, quick: bool = False, quiet: bool = False) -> dict:
    from ..io.scenes import load_network
    from ..core.network.simulate import model_of, network_loop, run_loop, simulate

    rows = []
    scene = load_network("fead_i4")
    simulate(scene)  # warm: compiled loop loaded, matrices built
    repeats = 3 if quick else 10
    best = math.inf
    for _ in range(repeats):
        start = time.process_time()
        result = simulate(scene)
        best = min(best, time.process_time() - start)
    old_span = 0.02 if quick else 0.1
    old = _python_step_loop(scene, scene.dt, old_span) / old_span
    rows.append({"figure": "fead_i4 whole simulate x real time", "new": scene.duration / best, "old": 1.0 / old,
                 "note": f"{result.tier} tier, {result.method} at dt = {scene.dt:g} s; {result.accuracy.split(':')[0]}; "
                         "old: the Python step loop at the same step"})
    old = _python_step_loop(scene, 1e-4, old_span) / old_span
    rows.append({"figure": "fead_i4 previous default (Python loop, 0.1 ms) x real time", "new": math.nan, "old": 1.0 / old,
                 "note": "the scene's step before it moved to 1 ms"})
    steps = 2000 if quick else 20000
    for method in METHODS:
        dt = 2.5e-4 if method == "rk4" else scene.dt  # inside its stability bound
        loop = network_loop(model_of(scene), "flexible", method, dt)
        run_loop(loop, 10)
        start = time.process_time()
        run_loop(loop, steps)
        rows.append({"figure": f"fead_i4 {method} ns/step (dt {dt:g} s)", "new": (time.process_time() - start) / steps * 1e9,
                     "old": math.nan, "note": f"{loop.args[3].size + loop.args[4].size} matrix entries"})
    from ..io.scenes import load_scene
    from ..core.simulate import simulate as simulate_paper
    from .kernel import _kernel_ns

    paper_loop = network_loop(model_of(load_network("paper_network")), "flexible", "exact", 1e-3)
    run_loop(paper_loop, 10)
    start = time.process_time()
    run_loop(paper_loop, 10 * steps)
    rows.append({"figure": "paper drive exact ns/step: network loop (new) vs linear loop (old)",
                 "new": (time.process_time() - start) / (10 * steps) * 1e9, "old": _kernel_ns("exact", 10 * steps)[0],
                 "note": "the same 4-state drive in both compiled loops (old column: the paper model's loop, wall time)"})

    paper = load_scene("paper")
    today = simulate_paper(paper, model="flexible", method="etd2", dt=1e-3)
    net = simulate(load_network("paper_network"), model="flexible", method="etd2", dt=1e-3)
    g = paper.params.gear_ratio
    for name, ours, theirs in (("omega_3", net.speed[:, 1], today["omega_3"]), ("omega_2", net.speed[:, 0], g * today["omega_M"]),
                               ("belt torque", net.belt_torque[:, 1], today["belt_torque"])):
        rows.append({"figure": f"paper_network vs paper flexible: {name} max diff / peak",
                     "new": float(np.max(np.abs(ours - theirs)) / np.max(np.abs(theirs))), "old": 2e-11 if name == "belt torque" else math.nan,
                     "note": "old: the previous network coordinates (absolute pulley angles)"})
    print(f"{'figure':58s} {'new':>12s} {'old':>12s}  note")
    for r in rows:
        print(f"{r['figure']:58s} {r['new']:12.4g} {r['old']:12.4g}  {r['note']}")
    csv_path = out / "network.csv"
    write_csv(csv_path, rows, ("figure", "new", "old", "note"))
    return {"csv": csv_path, "rows": rows}
