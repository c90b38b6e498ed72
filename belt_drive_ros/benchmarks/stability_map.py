"""Stability map: where fixed-step methods diverge, measured, against the guard's prediction.

Measured
--------
The flexible model of the ``paper`` parameters without bearing damping
(proportional damping: the belt mode has exactly the damping ratio
``zeta = c omega_n / (2k)``, set through the span damping c) rings freely from
a belt deflection of 1 mrad (zero torques, zero momentum). A run of
:data:`PERIODS` belt periods with the package's own stepping code
(``Simulator``, the compiled time loop) is **diverged** when

    max E over the last 10 % of the steps  >  FACTOR * max E over the first 10 %

with ``E`` the model's total (kinetic + potential) energy, or when the
simulator stops it as non-finite or beyond 1e5 rad/s. Comparing windowed
maxima keeps bounded energy oscillations (symplectic Euler's energy
breathes by up to 1/(1 - (h omega_n/2)^2)) from counting as growth. A mode
growing by |R| per step is caught once |R|^(2 * 0.9 * steps) > FACTOR, so the
measured boundary lies above the exact one by a margin that shrinks with
more periods (for RK4 at h omega_n ~ 2.83, 2.2 steps per period: ~0.2 %).

Predicted
---------
:func:`belt_drive_ros.core.stability.max_stable_step` times omega_n: the guard's
bisection on max |R(h lambda)| over the eigenvalues of A.

The accuracy guard's regions (:func:`guarantees`, ``guarantees.csv`` and a
printed table): per method and scene (``paper``, ``truck_compressor``), the
largest ``h omega_n`` up to which the guard rates the method accurate to 1e-4
on the scene's closed loop and torques, and the first it rates unstable.

Slipping scene
--------------
``truck_compressor`` on the slipping model (the first second: the load
switches at 0.5 s and the belt sticks and slips 38 times), run by every
variant of :mod:`belt_drive_ros.benchmarks.slip_runs` (event-driven hybrid,
regularised friction at each ``v_eps``) over the work-precision chart's steps
``scene.dt * 2^j``; a run **fails** when it diverges (non-finite, beyond
1e5 rad/s) or cannot make progress. The measured boundary is bisected between
the largest step of the grid that runs and the smallest that fails. Predicted
(:mod:`~belt_drive_ros.benchmarks.slip_runs`): the stability guard (stick
mode = the flexible belt), the slip mode's matrix (the span element's
relaxation ``k / c``, which the accuracy guard checks on slipping runs), and for regularised friction the method's one-step map
on the ODE linearized along the run (where ``v_eps`` would bring its
stiffness).

Three charts in one PNG: the (h omega_n, zeta) plane for each method (grid of
measured runs, measured boundary by bisection, predicted boundary), the
``truck_compressor`` parameters in the (belt stiffness k, dt) plane for RK4
and symplectic Euler with the scene's own (k, dt) marked, and the slipping
scene's steps (bottom row).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import SimulationDivergedError
from ..core.model import FlexibleBeltModel
from ..core.params import BeltDriveParams
from ..core.scene import InitialState
from ..io.scenes import load_scene
from ..core.simulate import Simulator
from ..core.sources import Constant
from ..core.stability import max_stable_step
from . import slip_runs
from .common import SLIP_SCENE, get_scene, log, pyplot, save_figure, write_csv

#: belt periods per run.
PERIODS = 60
#: energy growth factor (last 10 % of the run against the first 10 %) that counts as diverged.
FACTOR = 10.0
#: initial relative deflection [rad].
DEFLECTION = 1e-3

COLUMNS = ("study", "method", "zeta", "k", "omega_n", "dt", "h_omega_n", "diverged", "growth", "kind", "family", "v_eps", "status")


@dataclass(frozen=True)
class Config:
    methods: tuple = ("euler", "symplectic_euler", "rk4", "exact", "etd2", "trapezoidal")
    zetas: tuple = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5)
    grid: tuple = tuple(np.round(np.logspace(-2, math.log10(5.0), 48), 6))
    contrast_grid: tuple = tuple(np.round(np.logspace(-2, math.log10(5.0), 12), 6))
    bisection_steps: int = 14
    periods: int = PERIODS
    stiffness_study: bool = True
    stiffnesses: tuple = tuple(np.logspace(4.5, 7.0, 11))
    slip_study: bool = True
    slip_duration: float = 1.0
    slip_exponents: tuple = (-4, -3, -2, -1, 0, 1, 2, 3)  # dt = scene.dt * 2^j
    slip_methods: tuple = ("exact", "etd2", "etd4", "lawson5", "trapezoidal", "rk4", "euler")
    slip_regularised: tuple = ("rk4", "etd2", "euler")
    slip_v_eps: tuple = (1e-2, 1e-3, 1e-4)
    slip_bisection_steps: int = 8
    slip_probes: int = 40


FULL = Config()
QUICK = Config(
    methods=("rk4", "symplectic_euler"),
    zetas=(0.0, 0.05),
    grid=(0.5, 1.5, 2.5, 3.5),
    contrast_grid=(1.0,),
    bisection_steps=12,
    periods=40,
    stiffness_study=False,
    slip_duration=0.7,
    slip_exponents=(-2, 0, 2),
    slip_methods=("etd2", "rk4"),
    slip_regularised=("rk4",),
    slip_v_eps=(1e-3,),
    slip_bisection_steps=2,
    slip_probes=8,
)

_CONTRAST = ("exact", "etd2", "trapezoidal")


def _paper_params(zeta: float) -> BeltDriveParams:
    base = load_scene("paper").params.replace(b_M=0.0, b_1=0.0, b_2=0.0, b_3=0.0, c=0.0)
    return base.replace(c=2.0 * base.k * zeta / base.belt_natural_frequency)


def growth(params: BeltDriveParams, method: str, dt: float, periods: int = PERIODS) -> float:
    """Energy growth ratio of a free belt vibration (module docstring); inf when the run blew up."""
    model = FlexibleBeltModel(params)
    omega_n = params.belt_natural_frequency
    zeta = params.belt_damping_ratio
    omega_d = omega_n * math.sqrt(max(1.0 - zeta**2, 1e-6))
    n_steps = max(40, int(math.ceil(periods * 2.0 * math.pi / omega_d / dt)))
    zero = Constant(0.0)
    sim = Simulator(model, zero, zero, method, dt, check_stability=False)
    x0 = InitialState(relative_deflection=DEFLECTION).vector("flexible", params.ratio)
    try:
        with np.errstate(all="ignore"):
            _, states = sim.run(n_steps * dt, x0)
    except SimulationDivergedError:
        return math.inf
    energy = model.total_energy(states)
    window = max(1, energy.size // 10)
    first, last = np.max(energy[:window]), np.max(energy[-window:])
    if not np.isfinite(last):
        return math.inf
    return float(last / first)


def measured_boundary(params, method, lo, hi, steps, periods) -> float:
    """Bisection on dt between a stable ``lo`` and a diverged ``hi`` [s]; returns the midpoint of the last bracket."""
    for _ in range(steps):
        mid = math.sqrt(lo * hi)
        if growth(params, method, mid, periods) > FACTOR:
            hi = mid
        else:
            lo = mid
    return math.sqrt(lo * hi)


def _plane(config: Config, quiet: bool) -> list[dict]:
    rows = []
    for method in config.methods:
        grid = config.contrast_grid if method in _CONTRAST else config.grid
        for zeta in config.zetas:
            params = _paper_params(zeta)
            omega_n = params.belt_natural_frequency
            model = FlexibleBeltModel(params)
            pred_dt = max_stable_step(model.A, model.B, method, upper=10.0 / omega_n)
            base = dict(study="plane", method=method, zeta=zeta, k=params.k, omega_n=omega_n)
            results = []
            for y in grid:
                g = growth(params, method, y / omega_n, config.periods)
                results.append((y, g > FACTOR))
                rows.append(dict(base, dt=y / omega_n, h_omega_n=y, diverged=int(g > FACTOR), growth=g, kind="grid"))
            diverged = sorted(y for y, d in results if d)
            if not diverged:
                boundary = math.inf  # stable on the whole grid
            else:
                below = [y for y, d in results if not d and y < diverged[0]]
                lo = max(below) if below else grid[0] / 4.0
                if not below and growth(params, method, lo / omega_n, config.periods) > FACTOR:
                    boundary = 0.0  # diverged down to h*omega_n = grid[0]/4
                else:
                    boundary = omega_n * measured_boundary(
                        params, method, lo / omega_n, diverged[0] / omega_n, config.bisection_steps, config.periods
                    )
            predicted = pred_dt * omega_n
            rows.append(dict(base, dt=boundary / omega_n, h_omega_n=boundary, diverged="", growth="", kind="measured boundary"))
            rows.append(dict(base, dt=pred_dt, h_omega_n=predicted, diverged="", growth="", kind="predicted boundary"))
            log(f"[stability] {method:16s} zeta={zeta:<5g} boundary h*omega_n: measured {boundary:.4g}, "
                f"predicted {predicted:.4g}", quiet)  # fmt: skip
    return rows


def _stiffness(config: Config, quiet: bool) -> list[dict]:
    rows = []
    scene = load_scene("truck_compressor")
    for method in ("rk4", "symplectic_euler"):
        for k in config.stiffnesses:
            params = scene.params.replace(k=float(k))
            model = FlexibleBeltModel(params)
            omega_n = params.belt_natural_frequency
            pred = max_stable_step(model.A, model.B, method, upper=10.0 / omega_n)
            # bracket around the prediction, then bisect on the measurement
            lo, hi = 0.5 * pred, 2.0 * pred
            if growth(params, method, lo, config.periods) > FACTOR or growth(params, method, hi, config.periods) <= FACTOR:
                meas = math.nan  # bracket failed: recorded as NaN in the CSV, not plotted
            else:
                meas = measured_boundary(params, method, lo, hi, config.bisection_steps, config.periods)
            base = dict(study="stiffness", method=method, zeta=params.belt_damping_ratio, k=float(k), omega_n=omega_n,
                        diverged="", growth="")  # fmt: skip
            rows.append(dict(base, dt=meas, h_omega_n=meas * omega_n, kind="measured boundary"))
            rows.append(dict(base, dt=pred, h_omega_n=pred * omega_n, kind="predicted boundary"))
            log(f"[stability] truck {method:16s} k={k:.3g} N/m: max stable dt measured {meas:.4g} s, predicted {pred:.4g} s", quiet)
    return rows


def _slipping(config: Config, quiet: bool) -> list[dict]:
    """Measured and predicted step limits of the slipping scene's variants (module docstring)."""
    scene = get_scene(SLIP_SCENE)
    case = slip_runs.case_from_scene(scene).with_duration(min(config.slip_duration, scene.duration))
    m = case.model
    rate = float(np.max(np.abs(np.linalg.eigvals(m.A_slip))))  # the slip mode's fastest rate (k / c)
    steps = [scene.dt * 2.0**j for j in config.slip_exponents]
    variants = [("hybrid", mt, 0.0) for mt in config.slip_methods]
    variants += [("regularised", mt, v) for mt in config.slip_regularised for v in config.slip_v_eps]
    probes = {v: slip_runs.probe_states(case, v, config.slip_probes) for v in config.slip_v_eps}
    rows = []
    for family, method, v_eps in variants:
        label = slip_runs.variant_label(family, method, v_eps)
        base = dict(study="slipping", method=label, zeta="", k=case.params.k, omega_n=rate, diverged="", growth="",
                    family=family, v_eps=v_eps)  # fmt: skip
        status = {dt: slip_runs.run(case, family, method, dt, v_eps, repeats=1).status for dt in steps}
        for dt, st in status.items():
            rows.append(dict(base, dt=dt, h_omega_n=dt * rate, kind="grid", status=st, diverged=int(st != "ok")))
        failing = [dt for dt in steps if status[dt] != "ok"]
        if not failing:
            boundary = math.inf  # runs at every step of the grid
        else:
            running = [dt for dt in steps if status[dt] == "ok" and dt < min(failing)]
            boundary = 0.0 if not running else slip_runs.failure_boundary(
                case, family, method, v_eps, max(running), min(failing), config.slip_bisection_steps)  # fmt: skip
        rows.append(dict(base, dt=boundary, h_omega_n=boundary * rate, kind="measured boundary"))
        predicted = {"guard (stick mode)": slip_runs.guard_step(case, method)}
        if family == "hybrid":
            predicted["slip mode"] = slip_runs.slip_mode_step(case, method)
        else:
            times, states = probes[v_eps]
            predicted["regularised, linearized"] = slip_runs.regularised_step(case, method, v_eps, states, times)
        for kind, dt in predicted.items():
            rows.append(dict(base, dt=dt, h_omega_n=dt * rate, kind=kind))
        log(f"[stability] slipping {label:24s} fails from dt {boundary:.3g} s (measured); predicted: "
            + ", ".join(f"{k} {v:.3g} s" for k, v in predicted.items()), quiet)  # fmt: skip
    return rows


def measure(config: Config = FULL, quiet: bool = False) -> list[dict]:
    rows = _plane(config, quiet)
    if config.stiffness_study:
        rows += _stiffness(config, quiet)
    if config.slip_study:
        rows += _slipping(config, quiet)
    return rows


def boundaries(rows: list[dict], method: str) -> list[tuple[float, float, float]]:
    """(zeta, measured, predicted) h*omega_n boundaries of ``method`` in the plane study."""
    out = {}
    for r in rows:
        if r["study"] == "plane" and r["method"] == method and r["kind"] != "grid":
            out.setdefault(float(r["zeta"]), {})[r["kind"]] = float(r["h_omega_n"])
    return [(z, v["measured boundary"], v["predicted boundary"]) for z, v in sorted(out.items())]


def plot(rows: list[dict], path: Path, stiffness_scene_dt: float | None = None) -> Path:
    plt = pyplot()
    methods = list(dict.fromkeys(r["method"] for r in rows if r["study"] == "plane"))
    has_k = any(r["study"] == "stiffness" for r in rows)
    has_slip = any(r["study"] == "slipping" for r in rows)
    ncol = 4 if has_k else min(3, len(methods))
    nrow = math.ceil((len(methods) + (2 if has_k else 0)) / ncol) + int(has_slip)
    ratios = [1.0] * nrow
    if has_slip:
        ratios[-1] = 1.6
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 3.2 * sum(ratios)), squeeze=False,
                             gridspec_kw=dict(height_ratios=ratios))  # fmt: skip
    if has_slip:
        for ax in axes[-1]:
            ax.remove()
        _plot_slipping(fig.add_subplot(axes[-1, 0].get_gridspec()[-1, :]), rows)
        axes = axes[:-1]
    flat = list(axes.flat)
    for ax, method in zip(flat, methods):
        grid = [r for r in rows if r["study"] == "plane" and r["method"] == method and r["kind"] == "grid"]
        st = [r for r in grid if not r["diverged"]]
        dv = [r for r in grid if r["diverged"]]
        ax.plot([r["h_omega_n"] for r in st], [r["zeta"] for r in st], ".", color="tab:green", ms=3, label="measured stable")
        ax.plot([r["h_omega_n"] for r in dv], [r["zeta"] for r in dv], "x", color="tab:red", ms=3, label="measured diverged")
        b = boundaries(rows, method)
        meas = [(m, z) for z, m, p in b if math.isfinite(m) and m > 0]
        pred = [(p, z) for z, m, p in b if math.isfinite(p) and p > 0]
        if pred:
            ax.plot(*zip(*pred), "-", color="k", lw=1.5, label="guard: predicted")
        if meas:
            ax.plot(*zip(*meas), "o--", color="tab:blue", ms=4, lw=1, mfc="none", label="measured boundary")
        if not pred and not meas:
            ax.text(0.5, 0.5, "no boundary:\nstable at every step", transform=ax.transAxes, ha="center", fontsize=8)
        ax.set_xscale("log")
        ax.set_title(method, fontsize=9)
        ax.set_xlabel("h * omega_n")
        ax.set_ylabel("belt damping ratio zeta")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6, loc="upper left")
    if has_k:
        ax = flat[len(methods)]
        scene = load_scene("truck_compressor")
        colors = {"rk4": "tab:green", "symplectic_euler": "tab:olive"}
        for method in ("rk4", "symplectic_euler"):
            sel = [r for r in rows if r["study"] == "stiffness" and r["method"] == method]
            pred = [(r["k"], r["dt"]) for r in sel if r["kind"] == "predicted boundary"]
            meas = [(r["k"], r["dt"]) for r in sel if r["kind"] == "measured boundary" and math.isfinite(r["dt"])]
            ax.plot(*zip(*pred), "-", color=colors[method], lw=1.5, label=f"{method}: predicted")
            if meas:
                ax.plot(*zip(*meas), "o", color=colors[method], mfc="none", ms=5, label=f"{method}: measured")
        ax.plot(scene.params.k, scene.dt, "k*", ms=10, label=f"scene: k={scene.params.k:.3g} N/m, dt={scene.dt:g} s")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("belt span stiffness k [N/m]")
        ax.set_ylabel("largest stable dt [s]")
        ax.set_title("truck_compressor: stable below the lines", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, loc="upper right")
        used = len(methods) + 1
    else:
        used = len(methods)
    for ax in flat[used:]:
        ax.set_visible(False)
    fig.suptitle(f"Stability: diverged = energy grows > {FACTOR:g}x over the run's {PERIODS}-period span", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return Path(path)


#: scenes of the guarantee table and the h*omega_n grid it scans (quarter octaves)
GUARANTEE_SCENES = ("paper", "truck_compressor")
GUARANTEE_GRID = tuple(2.0 ** (k / 4.0) for k in range(-28, 25))
GUARANTEE_COLUMNS = ("scene", "method", "accurate_h_omega_n", "unstable_h_omega_n", "tolerance", "grid_start")


def guarantees(scenes=GUARANTEE_SCENES, methods=None, grid=GUARANTEE_GRID, quiet: bool = False) -> list[dict]:
    """Each fixed-step method's accuracy region as the accuracy guard states it, per scene (flexible model).

    Scanning ``h omega_n`` upward on ``grid``: ``accurate_h_omega_n`` is the
    largest value up to which every grid step is rated stable and accurate to
    :data:`~belt_drive_ros.core.accuracy.ACCURACY_TOLERANCE` on the scene's own
    closed loop and torques (:func:`~belt_drive_ros.core.accuracy.check_accuracy`,
    belt mode, slopes and forcing windows; 0: not even at ``grid_start``); ``unstable_h_omega_n`` the
    first value rated unstable (inf: none on the grid).
    """
    from ..core.accuracy import ACCURACY_TOLERANCE, check_accuracy
    from ..core.integrators import FIXED_STEP_METHODS
    from ..core.model import make_model
    from ..core.stepper import Plant

    rows = []
    for name in scenes:
        scene = load_scene(name)
        model = make_model("flexible", scene.params)
        plant = Plant(model, scene.drive, scene.load)
        x0 = scene.initial_state.vector("flexible", scene.params.ratio)
        w_n = scene.params.belt_natural_frequency
        for method in methods or FIXED_STEP_METHODS:
            accurate, unstable, region = 0.0, math.inf, True
            for hw in grid:
                r = check_accuracy(plant, method, hw / w_n, scene.duration, x0, suggest=False)
                if not r.stable:
                    unstable = hw
                    break
                region = region and r.accurate
                if region:
                    accurate = hw
            rows.append({"scene": name, "method": method, "accurate_h_omega_n": accurate,
                         "unstable_h_omega_n": unstable, "tolerance": ACCURACY_TOLERANCE, "grid_start": grid[0]})  # fmt: skip
            log(f"[guarantee] {name:16s} {method:16s} accurate to {ACCURACY_TOLERANCE:g} up to h*omega_n "
                f"{accurate:.3g}; first unstable {unstable:.3g}", quiet)  # fmt: skip
    return rows


def guarantee_table(rows: list[dict]) -> str:
    """Markdown table: method x scene, ``accurate up to / first unstable`` h*omega_n."""
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cell = {(r["scene"], r["method"]): r for r in rows}
    lines = ["| method | " + " | ".join(f"{s}: accurate to 1e-4 up to / first unstable h*omega_n" for s in scenes) + " |",
             "|---|" + "---|" * len(scenes)]  # fmt: skip
    for m in methods:
        parts = []
        for s in scenes:
            r = cell[(s, m)]
            acc = f"{r['accurate_h_omega_n']:.3g}" if r["accurate_h_omega_n"] > 0 else f"< {r['grid_start']:.3g}"
            parts.append(f"{acc} / {r['unstable_h_omega_n']:.3g}")
        lines.append(f"| {m} | " + " | ".join(parts) + " |")
    return "\n".join(lines)


_PREDICTED_STYLE = {
    "guard (stick mode)": dict(marker="|", color="k", ms=14, mew=2),
    "slip mode": dict(marker="x", color="tab:red", ms=8, mew=2),
    "regularised, linearized": dict(marker="x", color="tab:purple", ms=8, mew=2),
}


def _plot_slipping(ax, rows: list[dict]) -> None:
    """One line per variant: grid runs (ran / failed), measured boundary, predictions (module docstring)."""
    sel = [r for r in rows if r["study"] == "slipping"]
    labels = list(dict.fromkeys(r["method"] for r in sel))
    grid = [r for r in sel if r["kind"] == "grid"]
    lo, hi = min(r["dt"] for r in grid) / 3.0, max(r["dt"] for r in grid) * 3.0
    seen = set()

    def once(name):
        seen_before = name in seen
        seen.add(name)
        return None if seen_before else name

    for y, label in enumerate(labels):
        rs = [r for r in sel if r["method"] == label]
        for r in rs:
            if r["kind"] == "grid":
                ok = not r["diverged"]
                ax.plot(r["dt"], y, "." if ok else "x", color="tab:green" if ok else "tab:red", ms=6 if ok else 5,
                        label=once("grid: runs" if ok else "grid: diverged / failed"))  # fmt: skip
            elif r["kind"] == "measured boundary":
                dt = r["dt"]
                if math.isfinite(dt) and dt > 0:
                    ax.plot(dt, y, "o", mfc="none", mec="tab:blue", ms=9, mew=1.5, label=once("measured boundary"))
                else:
                    ax.annotate("runs at every step" if dt == math.inf else "fails at every step", (hi if dt else lo, y),
                                fontsize=6, va="center", ha="right" if dt else "left", color="tab:blue")  # fmt: skip
            elif math.isfinite(r["dt"]):  # an infinite prediction (any step is stable) is not drawn
                style = dict(_PREDICTED_STYLE.get(r["kind"], dict(marker="+", color="k")))
                ax.plot(max(r["dt"], lo), y, ls="none", label=once(f"predicted: {r['kind']}"), **style)
    scene = get_scene(SLIP_SCENE)
    ax.axvline(scene.dt, color="0.5", ls=":", lw=1)
    ax.text(scene.dt, 1.0, f" scene dt {scene.dt * 1e3:g} ms", transform=ax.get_xaxis_transform(), fontsize=7, color="0.4", va="bottom")
    ax.set_xscale("log")
    ax.set_xlim(lo, hi)
    ax.set_yticks(range(len(labels)))
    ax.set_yticklabels(labels, fontsize=7)
    ax.set_ylim(-0.7, len(labels) - 0.3)
    ax.set_xlabel("step dt [s]")
    ax.set_title("truck_compressor on the slipping model: where each variant fails, measured and predicted "
                 "(no marker: no predicted limit)", fontsize=9)  # fmt: skip
    ax.grid(True, which="major", axis="x", alpha=0.3)
    ax.legend(fontsize=6.5, loc="center left", bbox_to_anchor=(1.0, 0.5))


def run(out_dir: Path, quick: bool = False, quiet: bool = False) -> dict:
    rows = measure(QUICK if quick else FULL, quiet=quiet)
    out_dir = Path(out_dir)
    csv_path = write_csv(out_dir / "stability_map.csv", rows, COLUMNS)
    png_path = plot(rows, out_dir / "stability_map.png")
    table = guarantees(methods=("etd2", "rk4") if quick else None, grid=GUARANTEE_GRID[::4] if quick else GUARANTEE_GRID,
                       quiet=quiet)  # fmt: skip
    table_csv = write_csv(out_dir / "guarantees.csv", table, GUARANTEE_COLUMNS)
    log("[guarantee] the accuracy guard's regions (scene's own torques, flexible model):\n" + guarantee_table(table), quiet)
    return {"rows": rows, "csv": csv_path, "png": png_path, "guarantees": table, "guarantees_csv": table_csv}
