"""Shared pieces of the benchmarks: scenes, reference solutions, error metric, timing, CSV, plots.

Error metric (one definition for every chart)
---------------------------------------------
For a run on its output grid ``t_n`` and the reference solution at the same
times (same model, same scene)::

    e_speed = max_n |omega_M(t_n) - omega_M_ref(t_n)| / max_n |omega_M_ref(t_n)|
    e_belt  = max_n |T_b(t_n)     - T_b_ref(t_n)|     / max_n |T_b_ref(t_n)|
    e_load  = same for the load torque at wheel 3 (0 when the load is constant)
    error   = max(e_speed, e_belt)

``T_b`` is the belt torque at wheel 3 (the flexible model's spring-damper
torque; the rigid model's from wheel 3's equation). Relative to the peak of
the signal, so 1e-6 means "a millionth of the largest value in the run".

Reference
---------
* Open-loop (time-only torques, linear ODE): the ``exact`` method (matrix
  exponential, zero-order hold) at a step 2^-16 s on a binary time grid that
  contains every run's grid exactly; for piecewise-constant torques switching
  on that grid it is exact to rounding. Cross-checked against DOP853.
* Closed loop: ``scipy.integrate.solve_ivp`` DOP853 at rtol 1e-13, atol 1e-12,
  restarted at every time at which a torque jumps or kinks (schedule periods,
  steps, ramps, soft starts) and evaluated from the left/right on each
  piece, with its dense output read at each run's grid.

Timing
------
CPU time (:func:`time.process_time`) of ``Simulator.run`` only (not building
the model, the outputs or the energy terms), the minimum over repeats; quoted
as CPU seconds per simulated second, and its inverse "x real time".
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
import scipy.integrate

from ..core.fidelity import choose_model
from ..core.model import make_model
from ..core.scene import Scene
from ..io.scenes import load_scene
from ..core.simulate import Plant, Simulator
from ..io.atomic import atomic_output
from ..core.sources import Constant, Step

#: shipped scenes every study covers.
SHIPPED_SCENES = ("paper", "truck_compressor", "e_motor_start")
#: name of the open-loop linear variant of ``paper`` (see :func:`linear_scene`).
LINEAR_SCENE = "paper_open_loop"
#: name of ``truck_compressor`` on the slipping model (see :func:`slip_scene`).
SLIP_SCENE = "truck_compressor_slipping"
#: step of the open-loop reference [s] (binary: every 2^-j grid is a subgrid).
LINEAR_REFERENCE_DT = 2.0**-16
#: DOP853 tolerances of the closed-loop reference.
REFERENCE_RTOL, REFERENCE_ATOL = 1e-13, 1e-12
#: figures: small PNGs for the repository.
DPI = 100
#: floor used only to draw errors of exactly 0 on a log axis.
PLOT_FLOOR = 1e-17


# ------------------------------------------------------------------ scenes
def linear_scene() -> Scene:
    """``paper`` parameters with open-loop torques: the model is linear and time-invariant.

    Drive: a step from 0 to 8 N m at t = 0.25 s; load: a constant 2 N m. Both
    are piecewise constant and switch at a binary time, so every grid with a
    step 2^-j contains the switch and the ``exact`` method is exact on it to
    rounding. Step 2^-10 s (~1 ms, the paper scene's) is the scene default.
    """
    base = load_scene("paper")
    return base.with_overrides(
        name=LINEAR_SCENE,
        description="paper parameters, drive step 0 -> 8 N m at 0.25 s, constant 2 N m load (open loop, linear)",
        drive=Step(initial=0.0, final=8.0, time=0.25),
        load=Constant(2.0),
        duration=2.0,
        dt=2.0**-10,
        method="exact",  # exact for piecewise-constant torque: this scene's default
        model="flexible",
    )


def slip_scene() -> Scene:
    """``truck_compressor`` on the slipping model: what ``auto`` picks for it (112 stick/slip events in 3 s)."""
    return load_scene("truck_compressor").with_overrides(
        name=SLIP_SCENE,
        description="truck_compressor on the slipping model (auto's choice: the belt slips after the load switch)",
        model="slipping",
    )


def get_scene(name: str) -> Scene:
    """A shipped scene, the linear variant or the slipping variant by name."""
    if name == LINEAR_SCENE:
        return linear_scene()
    if name == SLIP_SCENE:
        return slip_scene()
    return load_scene(name)


def resolved_model(scene: Scene) -> str:
    """The linear model ``auto`` picks for ``scene`` by the frequency rule (or the scene's explicit one).

    The integrator studies compare methods on that model; where ``auto`` goes
    on to slipping, the studies' slipping scene (:data:`SLIP_SCENE`,
    :mod:`.slip_runs`) compares the hybrid methods.
    """
    return choose_model(scene, check_slip=False).model if scene.model == "auto" else scene.model


def is_open_loop(scene: Scene) -> bool:
    return not (scene.drive.state_dependent or scene.load.state_dependent)


# --------------------------------------------------------------- reference
@dataclass
class Reference:
    """Reference states of one scene and model, readable at any run's grid."""

    scene: Scene
    model: str
    kind: str  # "exact 2^-16 s" or "DOP853 rtol 1e-13"
    evaluate: Callable[[np.ndarray], np.ndarray]
    cpu_seconds: float
    _cache: dict = field(default_factory=dict)

    def states(self, times: np.ndarray) -> np.ndarray:
        key = (times.size, float(times[0]), float(times[-1]))
        if key not in self._cache:
            self._cache[key] = self.evaluate(times)
        return self._cache[key]


def _plant(scene: Scene, model: str):
    mdl = make_model(model, scene.params)
    return mdl, Plant(mdl, scene.drive, scene.load), scene.initial_state.vector(model, scene.params.ratio)


def dop853_reference(scene: Scene, model: str, rtol: float = REFERENCE_RTOL, atol: float = REFERENCE_ATOL) -> Reference:
    """DOP853 at ``rtol``, restarted at every torque breakpoint (see module docstring)."""
    mdl, plant, x0 = _plant(scene, model)
    A, B, inputs = mdl.A, mdl.B, plant.inputs
    cuts = sorted({0.0, scene.duration} | {b for b in plant.breakpoints if 0 < b < scene.duration})
    pieces = []
    start = time.process_time()
    x = x0
    for a, b in zip(cuts[:-1], cuts[1:]):
        left_of_b = plant.left_of(b)  # a torque that jumps at b is read from the left inside [a, b]

        def rhs(t, y, lo=a, hi=left_of_b):
            return A @ y + B @ inputs(min(max(t, lo), hi), y)

        sol = scipy.integrate.solve_ivp(rhs, (a, b), x, method="DOP853", rtol=rtol, atol=atol, dense_output=True)
        if sol.status != 0:
            raise RuntimeError(f"reference DOP853 failed on {scene.name} in [{a}, {b}]: {sol.message}")
        pieces.append(sol.sol)
        x = sol.y[:, -1]
    cpu = time.process_time() - start
    edges = np.array(cuts)

    def evaluate(times):
        out = np.empty((times.size, x0.size))
        idx = np.clip(np.searchsorted(edges, times, side="right") - 1, 0, len(pieces) - 1)
        for j, sol in enumerate(pieces):
            sel = idx == j
            if np.any(sel):
                out[sel] = sol(times[sel]).T
        return out

    return Reference(scene, model, f"DOP853 rtol {rtol:g}", evaluate, cpu)


def exact_reference(scene: Scene, model: str, dt: float = LINEAR_REFERENCE_DT) -> Reference:
    """The ``exact`` method at step ``dt`` on the grid k dt (open-loop scenes only)."""
    mdl, plant, x0 = _plant(scene, model)
    sim = Simulator(mdl, scene.drive, scene.load, "exact", dt, check_stability=False)
    start = time.process_time()
    grid, states = sim.run(scene.duration, x0)
    cpu = time.process_time() - start

    def evaluate(times):
        k = np.rint(times / dt).astype(np.int64)
        if not np.allclose(k * dt, times, rtol=0, atol=1e-15 * max(1.0, scene.duration)):
            raise ValueError("run grid is not a subgrid of the reference grid (use steps 2^-j s)")
        return states[k]

    return Reference(scene, model, f"exact dt 2^{int(round(math.log2(dt)))} s", evaluate, cpu)


def reference_for(scene: Scene, model: str) -> Reference:
    """Exact-method reference for open-loop scenes, DOP853 otherwise (as the issue asks)."""
    return exact_reference(scene, model) if is_open_loop(scene) else dop853_reference(scene, model)


# ------------------------------------------------------------------ errors
def signals(scene: Scene, model: str, times: np.ndarray, states: np.ndarray) -> dict[str, np.ndarray]:
    """omega_M, belt torque and load torque of states on ``times``."""
    mdl, plant, _ = _plant(scene, model)
    u = plant.input_array(times, states)
    out = mdl.outputs(states, u)
    return {"omega_M": out["omega_M"], "belt_torque": out["belt_torque"], "load_torque": out["load_torque"]}


def relative_error(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| / max |b| (max |a - b| when b is all zero): the error of every chart."""
    scale = float(np.max(np.abs(b)))
    diff = float(np.max(np.abs(a - b)))
    return diff / scale if scale > 0 else diff


def run_errors(reference: Reference, times: np.ndarray, states: np.ndarray) -> dict[str, float]:
    """The module's error metric of one run against ``reference``."""
    run = signals(reference.scene, reference.model, times, states)
    ref = signals(reference.scene, reference.model, times, reference.states(times))
    e = {
        "e_speed": relative_error(run["omega_M"], ref["omega_M"]),
        "e_belt": relative_error(run["belt_torque"], ref["belt_torque"]),
        "e_load": relative_error(run["load_torque"], ref["load_torque"]),
    }
    e["error"] = max(e["e_speed"], e["e_belt"])
    return e


# ------------------------------------------------------------------ timing
def cpu_time(fn: Callable[[], object], repeats: int | None = None, budget: float = 0.5) -> tuple[float, object]:
    """Minimum CPU time [s] of ``fn()`` over repeats, and its last result.

    Without ``repeats``: 3 runs, more (up to 9) while their total stays under
    ``budget`` seconds; a run longer than 0.3 s is repeated once, one longer
    than 1 s not at all. The minimum is the least disturbed by other
    processes on a shared machine (measured spread of single runs: up to 2x).
    """
    best, result, total, n = math.inf, None, 0.0, 0
    while True:
        start = time.process_time()
        result = fn()
        elapsed = time.process_time() - start
        best, total, n = min(best, elapsed), total + elapsed, n + 1
        if repeats is not None:
            if n >= repeats:
                break
        elif elapsed > 1.0 or (elapsed > 0.3 and n >= 2) or n >= 9 or (n >= 3 and total > budget):
            break
    return best, result


def save_figure(fig, path: Path) -> Path:
    """PNG at :data:`DPI`, quantized to a 256-colour palette (a third of the size, same look)."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, dpi=DPI, format="png")
    buf.seek(0)
    image = Image.open(buf).convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path, force=True) as f:  # whole or not at all (an interrupted study keeps the old chart)
        image.save(f, format="PNG", optimize=True)
    return path


# ------------------------------------------------------------------ pareto
def pareto_mask(cost: Sequence[float], error: Sequence[float]) -> np.ndarray:
    """True for points no other point beats in both cost and error (ties: both kept)."""
    cost, error = np.asarray(cost, dtype=float), np.asarray(error, dtype=float)
    mask = np.ones(cost.size, dtype=bool)
    for i in range(cost.size):
        better = (cost <= cost[i]) & (error <= error[i]) & ((cost < cost[i]) | (error < error[i]))
        mask[i] = not np.any(better)
    return mask


# --------------------------------------------------------------------- I/O
def write_csv(path: Path, rows: Iterable[dict], columns: Sequence[str]) -> Path:
    """CSV with a header line; floats with 6 significant digits (timings are not better than that)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path, force=True, mode="w") as fh:  # whole or not at all
        writer = csv.DictWriter(fh, fieldnames=list(columns), extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    return path


def read_csv(path: Path) -> list[dict]:
    """Rows of a benchmark CSV, numbers converted to float where they parse."""
    out = []
    with Path(path).open() as fh:
        for row in csv.DictReader(fh):
            conv = {}
            for k, v in row.items():
                try:
                    conv[k] = float(v)
                except (TypeError, ValueError):
                    conv[k] = v
            out.append(conv)
    return out


def pyplot():
    """matplotlib.pyplot on the Agg backend (imported only when a chart is drawn)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def log(message: str, quiet: bool = False) -> None:
    if not quiet:
        print(message, flush=True)


def tree_python(root: Path) -> str:
    """The interpreter of a checkout (its own ``.venv``, else this one)."""
    own = root / ".venv" / "bin" / "python"
    return str(own) if own.exists() else sys.executable


def alternate_trees(baseline: Path, code: str, args: Sequence[str], rounds: int, study: str):
    """``(j, figures)`` of ``python -c code *args`` run by this tree (j = 0) and the ``baseline`` checkout (j = 1)
    alternately, ``rounds`` times, each in its own child process (``PYTHONPATH`` = the checkout, the cwd none):
    ``figures`` the JSON of the child's last line; its line before names the file it ran, checked to be the tree's."""
    trees = (Path(__file__).resolve().parents[2], Path(baseline).resolve())
    with tempfile.TemporaryDirectory() as tmp:  # cwd: not a checkout (``-c`` imports from the cwd first)
        for _ in range(rounds):
            for j, root in enumerate(trees):
                env = dict(os.environ, PYTHONPATH=str(root), MPLBACKEND="Agg")
                done = subprocess.run([tree_python(root), "-c", code, *args], cwd=tmp, env=env, capture_output=True,
                                      text=True, check=True)  # fmt: skip
                lines = done.stdout.strip().splitlines()
                if not Path(lines[-2]).resolve().is_relative_to(root):
                    raise RuntimeError(f"bench {study} --baseline: {root} ran {lines[-2]}")
                yield j, json.loads(lines[-1])
