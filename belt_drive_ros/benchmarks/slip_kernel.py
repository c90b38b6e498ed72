"""``belt-drive bench slip-kernel``: the slipping belt's compiled hybrid loop.

On ``truck_compressor`` (the slipping default: 112 stick/slip events in 3 s
at etd4, 0.5 ms), in one run:

1. **Whole warm simulate()** (guards, model choice, the slipping run, the
   accuracy check, outputs): x real time and CPU with the compiled loop
   (:func:`~belt_drive_ros.core.kernel_slip.hybrid_steps`), minimum of repeats;
2. **the slipping run alone** (:meth:`SlippingSimulator.run`) and **the
   accuracy check's rerun** (:func:`~belt_drive_ros.core.accuracy.slip_run_error`);
3. **the node's tick**: :meth:`SlippingSimulator.advance` of one 1 ms tick
   over the whole scene (median, p99 and the worst tick, an event tick).

The phase-by-phase Python path these were once measured beside is gone
(every slipping run steps in the compiled kernels); ``docs/performance.md``
keeps its last figures. Prints a table and writes ``slip_kernel.csv`` into
``--out``. Timings only; ``tests/test_kernel_slip.py`` and
``tests/test_slip.py`` assert what the loop computes.
"""

from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

from ..core.accuracy import slip_run_error
from ..io.scenes import load_scene
from ..core.simulate import simulate
from ..core.slip_run import SlippingSimulator
from .common import write_csv

SCENE = "truck_compressor"


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
    cpu = _best(lambda: simulate(scene), repeats)
    report("simulate() whole, warm", scene.duration / cpu, "x rt", f"{cpu * 1e3:.1f} ms CPU")

    def one_run():
        sim = SlippingSimulator(scene.params, scene.drive, scene.load, scene.method, scene.dt, scene.method_options,
                                False, lazy=True)  # fmt: skip
        return sim, sim.run(scene.duration, y0)

    cpu = _best(one_run, repeats)
    report("  the slipping run alone", cpu * 1e3, "ms", f"{scene.duration / cpu:.0f} x rt")
    sim, (t, y, m, s) = one_run()
    events = [e.time for e in sim.events]
    cpu = _best(lambda: slip_run_error(scene.params, scene.drive, scene.load, scene.method, scene.dt, t, y, m, s, events),
                repeats)  # fmt: skip
    report("  accuracy check's rerun (slip_run_error)", cpu * 1e3, "ms", f"{len(events)} events")
    median, p99, worst = _ticks(scene)
    report("  node tick advance (1 ms)", median, "us", f"median; p99 {p99:.1f} us, worst {worst:.0f} us")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "slip_kernel.csv"
    write_csv(path, rows, ("measure", "value", "unit", "note"))
    return {"csv": path, "rows": rows}
