"""``belt-drive bench slip-kernel``: the slipping belt's compiled hybrid loop beside the phase-by-phase Python path.

Side by side in one run, on ``truck_compressor`` (the slipping default: 112
stick/slip events in 3 s at etd4, 0.5 ms):

1. **Whole warm simulate()** (guards, model choice, the slipping run, the
   accuracy check, outputs): x real time and CPU, with the compiled loop
   (:func:`~belt_drive_ros.core.kernel_slip.hybrid_steps`) and with the
   Python path that remains for torques given as functions and methods
   without a compiled event step (each phase through its stepper, each event
   located by the hybrid stepper on the method's flow), minimum of repeats;
2. **the slipping run alone** (:meth:`SlippingSimulator.run`) and **the
   accuracy check's rerun** (:func:`~belt_drive_ros.core.accuracy.slip_run_error`), both ways;
3. **the node's tick**: :meth:`SlippingSimulator.advance` of one 1 ms tick
   over the whole scene (median, p99 and the worst tick, an event tick), both ways.

Prints a table and writes ``slip_kernel.csv`` into ``--out``. Timings only;
``tests/test_kernel_slip.py`` and ``tests/test_slip.py`` assert what each way computes.
"""

from __future__ import annotations

import math
import statistics
import time
from contextlib import contextmanager
from pathlib import Path

from ..core import kernel_slip
from ..core.accuracy import slip_run_error
from ..core.scene import load_scene
from ..core.simulate import simulate
from ..core.slip_run import SlippingSimulator
from .common import write_csv

SCENE = "truck_compressor"


@contextmanager
def _python_path(on: bool):
    """Within: every slipping simulator steps phase by phase in Python (events located on the method's flow)."""
    if not on:
        yield
        return
    compiled, pack = SlippingSimulator._compiled, kernel_slip.pack
    SlippingSimulator._compiled = lambda self: None
    kernel_slip.pack = lambda *args: None
    try:
        yield
    finally:
        SlippingSimulator._compiled, kernel_slip.pack = compiled, pack


def _best(fn, repeats: int) -> float:
    fn()  # warm
    best = math.inf
    for _ in range(repeats):
        start = time.process_time()
        fn()
        best = min(best, time.process_time() - start)
    return best


def _ticks(scene) -> tuple[float, float, float]:
    """(median, p99, max) [us] of one 1 ms tick's advance over the scene."""
    sim = SlippingSimulator(scene.params, scene.drive, scene.load, scene.method, scene.dt, scene.method_options, False)
    state = sim.initial(scene.initial_state.vector("slipping", scene.params.ratio))
    clock, samples = time.perf_counter_ns, []
    for k in range(round(scene.duration / 1e-3)):
        start = clock()
        state = sim.advance(state, k * 1e-3, (k + 1) * 1e-3)
        samples.append(clock() - start)
    samples = sorted(samples[10:])
    return statistics.median(samples) / 1e3, samples[int(0.99 * len(samples))] / 1e3, samples[-1] / 1e3


def run(out: Path, quick: bool = False, quiet: bool = False) -> dict:
    scene = load_scene(SCENE)
    repeats = 2 if quick else 5
    rows = []

    def report(what: str, value: float, unit: str, note: str = "") -> None:
        rows.append({"measure": what, "value": value, "unit": unit, "note": note})
        print(f"  {what:<58s} {value:>10.4g} {unit:<5s} {note}")

    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    print(f"bench slip-kernel: {SCENE} ({scene.method}, dt {scene.dt:g} s, {scene.duration:g} s), CPU time, best of {repeats}")
    for label, python in (("compiled hybrid loop", False), ("Python phase-by-phase path", True)):
        with _python_path(python):
            cpu = _best(lambda: simulate(scene), repeats)
            report(f"simulate() whole, warm: {label}", scene.duration / cpu, "x rt", f"{cpu * 1e3:.1f} ms CPU")

            def one_run():
                sim = SlippingSimulator(scene.params, scene.drive, scene.load, scene.method, scene.dt, scene.method_options,
                                        False, lazy=True)  # fmt: skip
                return sim, sim.run(scene.duration, y0)

            cpu = _best(one_run, repeats)
            report(f"  the slipping run alone: {label}", cpu * 1e3, "ms", f"{scene.duration / cpu:.0f} x rt")
            sim, (t, y, m, s) = one_run()
            events = [e.time for e in sim.events]
            cpu = _best(lambda: slip_run_error(scene.params, scene.drive, scene.load, scene.method, scene.dt, t, y, m, s, events),
                        repeats)  # fmt: skip
            report(f"  accuracy check's rerun (slip_run_error): {label}", cpu * 1e3, "ms", f"{len(events)} events")
            median, p99, worst = _ticks(scene)
            report(f"  node tick advance (1 ms): {label}", median, "us", f"median; p99 {p99:.1f} us, worst {worst:.0f} us")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "slip_kernel.csv"
    write_csv(path, rows, ("measure", "value", "unit", "note"))
    return {"csv": path, "rows": rows}
