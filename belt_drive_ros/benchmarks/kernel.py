"""``belt-drive bench kernel``: the compiled time loop's figures, side by side in one run.

1. **ns per step**, closed-loop ``paper`` (flexible model, motor line with soft
   start on the drive, speed-dependent load) with ``exact`` at 1 ms, through
   the kernel (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`), beside
   the same step written as a plain CPython float loop (what the generated
   loop of the previous design did: ~1,500 ns) and a C loop compiled here with
   ``cc -O2`` where a C compiler exists; the three final speeds printed to 12
   digits, and the kernel's figure before its 4-state loops (recorded, not
   re-measured: :data:`BEFORE_NS`). Then ``etd2``, ``etd4``, ``lawson5``,
   ``rk4`` and ``trapezoidal`` through the kernel, as a multiple of ``exact``.
   With ``--baseline DIR`` every method's ns per step is measured again in
   a child process of each tree, alternately, and both figures print.
2. **The node's tick**: :meth:`Stepper.advance` of one 1 ms step with the
   held drive torque set before each (the call the tick makes), median and p99.
3. **Whole warm simulate()** (guards, model choice, accuracy check, outputs
   included): x real time of ``paper``, ``e_motor_start``, ``bsg_start``,
   ``truck_compressor`` (process CPU time, minimum of repeats).
   With ``--baseline DIR`` (another checkout, its numba cache warm) each tree
   runs them in its own child process, alternately, and both figures print.
4. **Start-up**: ``belt-drive sim paper --quiet`` process CPU time (children's
   rusage, median of 5, caches warm).

Prints a table and writes ``kernel.csv`` into ``--out``. Timings only; the
tests assert correctness, never time.
"""

from __future__ import annotations

import math
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core.model import make_model
from ..core.simulate import Simulator, simulate

try:
    from ..io.scenes import load_scene
except ImportError:  # a --baseline checkout from before the scene files moved to io/ (its children load this file)
    from ..core.scene import load_scene
from .common import write_csv

STEPS = 1_000_000
QUICK_STEPS = 50_000
SCENES = ("paper", "e_motor_start", "bsg_start", "truck_compressor")
METHODS = ("exact", "etd2", "etd4", "lawson5", "rk4", "trapezoidal")
#: ns per step of the general loop before the 4-state loops (commit f2d9424, `bench kernel` on this 2-core
#: machine while busy): printed beside today's figure as the old one, not re-measured (that loop now runs
#: only where no 4-state loop applies)
BEFORE_NS = {"exact": 74.0, "etd4": 264.0, "lawson5": 402.0}


def _cpu() -> float:
    return time.process_time()


#: the step figures beside paper's methods: (scene, model, method, constant torques) by label (the rigid 2-state
#: loop with a motor curve; the truck's engine and compressor harmonics, and its plant with constant torques;
#: bsg_start's motor curve and compressor: the linear phases of both slipping scenes)
STEP_CASES = {
    "e_motor_start rigid etd2": ("e_motor_start", "rigid", "etd2", False),
    "truck_compressor flexible etd4": ("truck_compressor", "flexible", "etd4", False),
    "truck_compressor etd4, constant torques": ("truck_compressor", "flexible", "etd4", True),
    "bsg_start flexible etd2": ("bsg_start", "flexible", "etd2", False),
}


def _kernel_ns(method: str, steps: int, scene_name: str = "paper", model: str = "flexible",
               constant: bool = False) -> tuple[float, float]:  # fmt: skip
    """(ns per step, final drive speed) of ``scene_name``'s drive (default: paper, flexible), ``method`` at the
    scene's step, through the kernel (``constant``: its drive and load replaced by constant torques)."""
    from ..core.sources import Constant

    scene = load_scene(scene_name)
    drive, load = (Constant(15.0), Constant(18.0)) if constant else (scene.drive, scene.load)
    dt = 1e-3 if scene_name == "paper" else scene.dt
    sim = Simulator(make_model(model, scene.params), drive, load, method, dt, check_stability=False)
    loop = sim.stepper.loop
    x0 = np.ascontiguousarray(scene.initial_state.vector(model, scene.params.ratio), dtype=float)
    times = dt * np.arange(steps + 1, dtype=float)
    out = np.empty((steps, x0.size))
    loop(times[:3], x0, out[:2])  # compiled or loaded from the cache before timing
    best = math.inf
    for _ in range(3):
        start = _cpu()
        done, status, _ = loop(times, x0, out)
        best = min(best, _cpu() - start)
    assert done == steps and status == 0, (method, scene_name, done, status)
    return best / steps * 1e9, float(out[-1, x0.size // 2])


def _matrices():
    scene = load_scene("paper")
    sim = Simulator(make_model("flexible", scene.params), scene.drive, scene.load, "exact", 1e-3, check_stability=False)
    integrator = sim.integrator
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    drive, load = scene.drive, scene.load
    # motor line stall (1 - w / w0) faded in over T; load c1 w + c2 w |w| (the paper scene's profiles)
    constants = (drive.stall_torque, drive.no_load_speed, drive.soft_start_time, load.c1, load.c2)
    return integrator.Phi, integrator.Gamma, x0, constants, sim.plant.wheel_map


def _cpython_ns(steps: int) -> tuple[float, float]:
    """The same exact step as a plain CPython float loop (matrix entries as locals, torques inline)."""
    Phi, G, x0, (stall, w0, soft, c1, c2), W = _matrices()
    P = Phi.tolist()
    Gm = G.tolist()
    x = list(map(float, x0))
    start = _cpu()
    for k in range(steps):
        t = k * 1e-3
        wM, w3 = x[2], x[3]  # flexible state [phi_M, theta, omega_M, omega_3]
        d = stall * (1.0 - wM / w0) * (0.0 if t < 0.0 else 1.0 if t > soft else t / soft)
        lo = c1 * w3 + c2 * w3 * abs(w3)
        x = [P[r][0] * x[0] + P[r][1] * x[1] + P[r][2] * x[2] + P[r][3] * x[3] + Gm[r][0] * d + Gm[r][1] * lo
             for r in range(4)]
    return (_cpu() - start) / steps * 1e9, x[2]


C_SOURCE = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
int main(int argc, char **argv) {
    long steps = atol(argv[1]);
    double P[4][4], G[4][2], x[4], y[4], c[5];
    for (int r = 0; r < 4; r++) for (int j = 0; j < 4; j++) P[r][j] = atof(argv[2 + 4 * r + j]);
    for (int r = 0; r < 4; r++) for (int j = 0; j < 2; j++) G[r][j] = atof(argv[18 + 2 * r + j]);
    for (int r = 0; r < 4; r++) x[r] = atof(argv[26 + r]);
    for (int j = 0; j < 5; j++) c[j] = atof(argv[30 + j]);
    struct timespec a, b;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &a);
    for (long k = 0; k < steps; k++) {
        double t = k * 1e-3, wM = x[2], w3 = x[3];
        double fade = t < 0.0 ? 0.0 : t > c[2] ? 1.0 : t / c[2];
        double d = c[0] * (1.0 - wM / c[1]) * fade;
        double l = c[3] * w3 + c[4] * w3 * (w3 < 0 ? -w3 : w3);
        for (int r = 0; r < 4; r++)
            y[r] = P[r][0] * x[0] + P[r][1] * x[1] + P[r][2] * x[2] + P[r][3] * x[3] + G[r][0] * d + G[r][1] * l;
        for (int r = 0; r < 4; r++) x[r] = y[r];
    }
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &b);
    double s = (b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec);
    printf("%.3f %.17g\n", s / steps * 1e9, x[2]);
    return 0;
}
"""


def _c_ns(steps: int) -> tuple[float, float] | None:
    """The same loop in C (-O2), or None without a C compiler."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    Phi, G, x0, constants, _ = _matrices()
    with tempfile.TemporaryDirectory() as tmp:
        src, exe = Path(tmp) / "loop.c", Path(tmp) / "loop"
        src.write_text(C_SOURCE)
        built = subprocess.run([cc, "-O2", "-o", str(exe), str(src)], capture_output=True, text=True)
        if built.returncode != 0:
            return None
        args = [str(steps)] + [repr(float(v)) for v in (*Phi.ravel(), *G.ravel(), *x0, *constants)]
        best = None
        for _ in range(3):
            out = subprocess.run([str(exe), *args], capture_output=True, text=True, check=True).stdout.split()
            ns, speed = float(out[0]), float(out[1])
            best = (ns, speed) if best is None or ns < best[0] else best
        return best


def _tick_us(ticks: int) -> tuple[float, float]:
    """(median, p99) [us] of one node tick's advance: ``paper``, flexible, ``exact`` at 1 ms, held drive torque
    set before every tick (:meth:`~belt_drive_ros.core.stepper.Stepper.advance`, the call the node's tick makes)."""
    from ..core.sources import HeldTorque
    from ..core.stepper import Plant, Stepper

    scene = load_scene("paper")
    held = HeldTorque(0.0)
    stepper = Stepper(Plant(make_model("flexible", scene.params), held, scene.load), "exact", 1e-3)
    x = np.ascontiguousarray(scene.initial_state.vector("flexible", scene.params.ratio), dtype=float)
    samples = []
    clock = time.perf_counter_ns
    for k in range(ticks):
        held.value = 5.0 + math.sin(1e-3 * k)
        start = clock()
        x = stepper.advance(x, k * 1e-3, (k + 1) * 1e-3)
        samples.append(clock() - start)
    samples = sorted(samples[ticks // 10 :])
    return statistics.median(samples) / 1e3, samples[int(0.99 * len(samples))] / 1e3


def _simulate_rtf(name: str, repeats: int) -> tuple[float, float]:
    """(x real time, CPU s) of the whole warm simulate() of scene ``name`` (minimum of ``repeats``)."""
    scene = load_scene(name)
    simulate(scene)  # warm: caches, compiled kernel
    best = math.inf
    for _ in range(repeats):
        start = _cpu()
        simulate(scene)
        best = min(best, _cpu() - start)
    return scene.duration / best, best


#: what a child process of one tree runs: each scene's whole warm simulate(), minimum CPU of argv[1] repeats
_CHILD = r"""
import json, sys, time
try:
    from belt_drive_ros.io.scenes import load_scene
except ImportError:  # a baseline from before the scene files moved to io/
    from belt_drive_ros.core.scene import load_scene
from belt_drive_ros.core.simulate import simulate
out = {}
for name in sys.argv[2:]:
    scene = load_scene(name)
    simulate(scene)
    best = float("inf")
    for _ in range(int(sys.argv[1])):
        start = time.process_time()
        simulate(scene)
        best = min(best, time.process_time() - start)
    out[name] = [best, scene.duration]
print(json.dumps(out))
"""


def _simulate_side_by_side(baseline: Path, repeats: int, rounds: int) -> dict:
    """``{scene: (this tree's CPU s, the baseline's CPU s, duration s)}``: whole warm simulate() per scene, each
    tree in its own child process (``PYTHONPATH`` = the checkout), alternating ``rounds`` times, minimum kept."""
    import json

    from .common import tree_python

    trees = (Path(__file__).resolve().parents[2], Path(baseline).resolve())
    best: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(rounds):
            for j, root in enumerate(trees):
                env = dict(os.environ, PYTHONPATH=str(root), MPLBACKEND="Agg")
                done = subprocess.run([tree_python(root), "-c", _CHILD, str(repeats), *SCENES], cwd=tmp, env=env,
                                      capture_output=True, text=True, check=True)  # fmt: skip
                for name, (cpu, duration) in json.loads(done.stdout.strip().splitlines()[-1]).items():
                    row = best.setdefault(name, [math.inf, math.inf, duration])
                    row[j] = min(row[j], cpu)
    return {name: tuple(row) for name, row in best.items()}


#: what a child process of one tree runs for the step figures: ns per step of each of paper's methods and of
#: :data:`STEP_CASES` (argv[1] steps), timed by this tree's :func:`_kernel_ns` (argv[2], loaded as a module of the
#: tree's package: both trees timed by the same code); the first line names the kernel that ran
_STEP_CHILD = r"""
import importlib.util, json, sys
from belt_drive_ros.core import kernel
spec = importlib.util.spec_from_file_location("belt_drive_ros.benchmarks._kernel_timing", sys.argv[2])
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)
print(kernel.__file__)
steps = int(sys.argv[1])
figures = {m: bench._kernel_ns(m, steps)[0] for m in bench.METHODS}
figures.update({label: bench._kernel_ns(case[2], steps, *case[:2], case[3])[0] for label, case in bench.STEP_CASES.items()})
print(json.dumps(figures))
"""


def _steps_side_by_side(baseline: Path, steps: int, rounds: int) -> dict:
    """``{method: (this tree's ns per step, the baseline's)}``: each tree in its own child process, alternating
    ``rounds`` times, minimum kept (both trees measured the same way, on the same load)."""
    from .common import alternate_trees

    best: dict = {}
    for j, figures in alternate_trees(baseline, _STEP_CHILD, (str(steps), __file__), rounds, "kernel"):
        for method, ns in figures.items():
            row = best.setdefault(method, [math.inf, math.inf])
            row[j] = min(row[j], ns)
    return {method: tuple(row) for method, row in best.items()}


def _startup_cpu(repeats: int) -> float | None:
    """Median process CPU [s] of ``belt-drive sim paper --quiet`` (children's rusage)."""
    exe = Path(sys.executable).with_name("belt-drive")
    if not exe.exists():
        return None
    samples = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            subprocess.run([str(exe), "sim", "paper", "--quiet"], check=True, cwd=tmp,
                           capture_output=True, env=dict(os.environ, MPLBACKEND="Agg"))
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            samples.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return statistics.median(samples)


def run(out: Path, quick: bool = False, quiet: bool = False, baseline: Path | None = None) -> dict:
    steps = QUICK_STEPS if quick else STEPS
    rows = []

    def report(what: str, value: float, unit: str, note: str = "") -> None:
        rows.append({"measure": what, "value": value, "unit": unit, "note": note})
        print(f"  {what:<46s} {value:>12.4g} {unit:<6s} {note}")

    print(f"bench kernel: closed-loop paper, flexible, 1 ms, {steps} steps (CPU time, best of 3)")
    exact_ns, exact_speed = _kernel_ns("exact", steps)
    report("exact, kernel", exact_ns, "ns", f"final omega_M {exact_speed:.12g}")
    report("exact, kernel before the 4-state loops (recorded)", BEFORE_NS["exact"], "ns", "commit f2d9424; target <= 30 ns")
    py_ns, py_speed = _cpython_ns(min(steps, 200_000))
    report("exact, plain CPython loop (old design ~1,500)", py_ns, "ns", f"final omega_M {py_speed:.12g}")
    c = _c_ns(steps)
    if c is None:
        print("  exact, C -O2: no C compiler found")
    else:
        report("exact, C -O2 reference", c[0], "ns", f"final omega_M {c[1]:.12g}")
    for method in METHODS[1:]:
        ns, _ = _kernel_ns(method, steps)
        before = f"; before {BEFORE_NS[method]:.0f} ns = {BEFORE_NS[method] / BEFORE_NS['exact']:.2f} x" if method in BEFORE_NS else ""
        report(f"{method}, kernel", ns, "ns", f"{ns / exact_ns:.2f} x exact{before}")
    for label, (scene_name, model, method, constant) in STEP_CASES.items():
        ns, _ = _kernel_ns(method, steps, scene_name, model, constant)
        report(f"{label}, kernel", ns, "ns")
    if baseline is not None:  # this tree and the baseline checkout alternately, each in its own process
        side = _steps_side_by_side(baseline, steps, 2 if quick else 3)
        for method, (ns, old) in side.items():
            ratio = f"; {ns / side['exact'][0]:.2f} x exact here, {old / side['exact'][1]:.2f} x in the baseline"
            report(f"{method}, kernel side by side", ns, "ns",
                   f"baseline {Path(baseline).name} {old:.1f} ns{ratio if method in METHODS[1:] else ''}")
    median, p99 = _tick_us(2_000 if quick else 20_000)
    report("node tick: Stepper.advance one 1 ms step", median, "us", f"median (p99 {p99:.2f} us), held torque set each tick")
    print("bench kernel: whole warm simulate() (guards, model choice, accuracy check, outputs)")
    if baseline is None:
        for name in SCENES:
            rtf, cpu = _simulate_rtf(name, 2 if quick else 5)
            report(f"simulate({name})", rtf, "x rt", f"{cpu * 1e3:.1f} ms CPU")
    else:  # this tree and the baseline checkout alternately, each in its own process
        for name, (cpu, old, duration) in _simulate_side_by_side(baseline, 3 if quick else 7, 2 if quick else 4).items():
            report(f"simulate({name})", duration / cpu, "x rt", f"{cpu * 1e3:.2f} ms CPU")
            report(f"simulate({name}), baseline {Path(baseline).name}", duration / old, "x rt",
                   f"{old * 1e3:.2f} ms CPU; this tree {old / cpu:.2f} x faster")
    startup = _startup_cpu(2 if quick else 5)
    if startup is not None:
        report("belt-drive sim paper --quiet", startup, "s CPU", "median, caches warm")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "kernel.csv"
    write_csv(path, rows, ("measure", "value", "unit", "note"))
    return {"csv": path, "rows": rows}
