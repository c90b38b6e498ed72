"""``belt-drive bench slip-kernel``: the slipping belt's compiled hybrid loop.

On ``truck_compressor`` (the slipping default: 112 stick/slip events in 3 s
at etd4, 0.5 ms), in one run:

1. **Whole warm simulate()** (guards, model choice, the slipping run, the
   accuracy check, outputs): x real time and CPU with the compiled loop
   (:func:`~belt_drive_ros.core.kernel_hybrid.hybrid_steps`), minimum of repeats;
2. **the slipping run alone** (:meth:`SlippingSimulator.run`) and **the
   accuracy check's rerun** (:func:`~belt_drive_ros.core.accuracy.slip_run_error`);
3. **the node's tick**: :meth:`SlippingSimulator.advance` of one 1 ms tick
   over the whole scene (median, p99 and the worst tick, an event tick);
4. **the compiled loop alone**: the :func:`~belt_drive_ros.core.kernel_hybrid.hybrid_steps` calls of one warm
   simulate() (the run's and the rerun's) replayed on copies of their arguments, thread CPU time: per grid step,
   and beside it the phases' linear loop over the same grid without its guard (no event: what the steps cost
   without the events and the hybrid loop's own work). The run's and the rerun's calls hold the same events over
   different numbers of steps, so their two times give a step's cost between events and an event's.

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


def hybrid_calls(scene) -> list:
    """Copies of the arguments of every :func:`~belt_drive_ros.core.kernel_hybrid.hybrid_steps` call of one
    ``simulate(scene)`` (before the call: the outputs and the state it writes are fresh)."""
    import numpy as np

    from ..core import kernel_hybrid

    calls, compiled = [], kernel_hybrid.hybrid_steps

    def spy(*args):
        calls.append(tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args))
        return compiled(*args)

    kernel_hybrid.hybrid_steps = spy
    try:
        simulate(scene)
    finally:
        kernel_hybrid.hybrid_steps = compiled
    return calls


def loop_alone(scene, repeats: int) -> dict:
    """Thread CPU [ns] of the replayed hybrid_steps calls of one simulate() (fastest of ``repeats``) per grid step,
    their steps and events, and the flexible phase's linear loop over the first call's grid unguarded, per step."""
    import numpy as np

    from ..core import kernel_hybrid
    from ..core.kernel import HEADER, linear_steps

    calls = hybrid_calls(scene)
    written = (7, 10, 11, 12, 13, 34)  # x, out_y, out_mode, out_sigma, out_native, events: fresh copies per call
    best, steps, events = math.inf, 0, 0
    each = [math.inf] * len(calls)  # each call's fastest [ns]
    counts = [(0, 0)] * len(calls)  # each call's (steps, events)
    for _ in range(repeats):
        total, steps, events = 0, 0, 0
        for c, args in enumerate(calls):
            args = list(args)
            for i in written:
                args[i] = args[i].copy()
            start = time.thread_time_ns()
            done = kernel_hybrid.hybrid_steps(*args)
            spent = time.thread_time_ns() - start
            total += spent
            each[c] = min(each[c], spent)
            counts[c] = (done[0] - args[5], done[4])
            steps, events = steps + done[0] - args[5], events + done[4]
        best = min(best, total)
    # the run's and the rerun's calls hold the same events over different numbers of steps: their two times give
    # a step's cost and an event's (the event step, the phases' entries, the step the guard fired in redone)
    per_event = per_plain = math.nan
    if len(calls) == 2 and counts[0][1] == counts[1][1] and counts[0][0] != counts[1][0] and counts[0][1] > 0:
        per_plain = (each[0] - each[1]) / (counts[0][0] - counts[1][0])
        per_event = (each[1] - per_plain * counts[1][0]) / counts[1][1]
    grid, reals, ints, offsets, dp, lp = (calls[0][i] for i in (0, 14, 15, 16, 27, 31))
    r0, r1, i0, i1 = offsets[kernel_hybrid.FLEXIBLE]
    loop, codes = reals[r0:r1].copy(), ints[i0:i1]
    loop[codes[HEADER + 6]] = 0.0  # the guard's section: off
    x, states, linear = calls[0][7][:4].copy(), np.empty((grid.size - 1, 4)), math.inf
    for _ in range(repeats):
        start = time.thread_time_ns()
        linear_steps(grid, x.copy(), states, -math.inf, math.inf, 1e9, loop, codes, dp, lp)
        linear = min(linear, time.thread_time_ns() - start)
    return {"per_step": best / steps, "steps": steps, "events": events, "linear_per_step": linear / (grid.size - 1),
            "per_plain_step": per_plain, "per_event": per_event}


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
    alone = loop_alone(scene, 5 if quick else 20)
    report("  hybrid_steps alone, per grid step (thread CPU)", alone["per_step"], "ns",
           f"{alone['steps']} steps, {alone['events']} events (run and rerun)")  # fmt: skip
    report("    of which per step between events", alone["per_plain_step"], "ns", "the run's and rerun's call solved")
    report("    and per event", alone["per_event"] / 1e3, "us", "event step, phase entries, the fired step")
    report("  the flexible phase's linear loop alone, unguarded", alone["linear_per_step"], "ns", "per step, same grid")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "slip_kernel.csv"
    write_csv(path, rows, ("measure", "value", "unit", "note"))
    return {"csv": path, "rows": rows}
