"""Work-precision: error against CPU time for every integrator on every scene.

For each scene (the shipped ones with the model ``auto`` picks, plus the
open-loop linear variant of ``paper``) and each integrator:

* fixed-step methods (exact, etd2, etd4, lawson5, euler, symplectic_euler,
  rk4, trapezoidal): the step is swept as ``scene.dt * 2^j``; a step the stability
  guard predicts unstable is **not run** and recorded as ``unstable (guard)``;
  a run that diverges anyway is recorded as ``diverged``;
* adaptive scipy methods (RK45, DOP853, Radau, BDF, LSODA, through the
  package's registry, outputs every ``scene.dt``): ``rtol`` is swept, with
  ``atol = 1e-3 rtol``.

The slipping scene (``truck_compressor`` on the slipping model, what ``auto``
picks for it; :data:`~belt_drive_ros.benchmarks.common.SLIP_SCENE`) has its
own variants (:mod:`belt_drive_ros.benchmarks.slip_runs`): the event-driven
hybrid with every fixed-step method, the hybrid without event location, and
regularised friction at several ``v_eps``, against DOP853 with located
events. Its stability guard is the run's own (stick mode): a step it refuses
is not run; a run that diverges in the slip mode is recorded as
``diverged``.

Error and timing are defined in :mod:`belt_drive_ros.benchmarks.common`. The
chart is log-log (error against CPU seconds per simulated second) with one
panel per scene; the Pareto front (no other run is both faster and more
accurate) is drawn, the default (the scene's method at its step) is ringed,
and what ``method: auto`` picks for the scene (:mod:`belt_drive_ros.core.method_choice`;
column ``auto``) is boxed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import BeltDriveError, SimulationDivergedError
from ..core.integrators import ADAPTIVE_METHODS, FIXED_STEP_METHODS
from ..core.method_choice import choose_for_scene
from ..core.model import make_model
from ..core.simulate import Simulator
from ..core.stability import check_step
from . import slip_runs
from .common import (
    LINEAR_SCENE,
    SLIP_SCENE,
    PLOT_FLOOR,
    SHIPPED_SCENES,
    cpu_time,
    get_scene,
    log,
    pareto_mask,
    pyplot,
    save_figure,
    reference_for,
    resolved_model,
    run_errors,
    write_csv,
)

#: the package default is each scene's own ``method`` at its ``dt`` (paper: etd4, others: etd2).

COLUMNS = (
    "scene", "model", "method", "kind", "dt", "rtol", "h_omega_n", "status", "cpu_s", "cpu_per_sim_s",
    "x_realtime", "e_speed", "e_belt", "e_load", "error", "default", "pareto", "reference", "family", "v_eps", "events",
    "auto",
)  # fmt: skip


def _auto_choice(scene, kind: str) -> tuple[str, float]:
    """(method, dt) ``method: auto`` picks for ``scene`` on the model ``kind`` (:mod:`belt_drive_ros.core.method_choice`)."""
    choice = choose_for_scene(scene.with_overrides(method="auto"), kind)
    return choice.method, choice.dt


def _is(choice, method: str, dt: float) -> int:
    return int(choice[0] == method and math.isclose(choice[1], dt, rel_tol=1e-9))

#: fixed-step methods of the slipping scene (symplectic Euler needs the [angles, speeds] state form, which the
#: slip mode's stretch and slip coordinates do not have)
SLIP_METHODS = tuple(m for m in FIXED_STEP_METHODS if m != "symplectic_euler")


@dataclass(frozen=True)
class Config:
    """What to sweep. ``step_exponents`` j give dt = scene.dt * 2^j."""

    scenes: tuple = (*SHIPPED_SCENES, LINEAR_SCENE)
    fixed_methods: tuple = FIXED_STEP_METHODS
    adaptive_methods: tuple = ADAPTIVE_METHODS
    step_exponents: tuple = (-4, -3, -2, -1, 0, 1, 2, 3)
    rtols: dict = field(
        default_factory=lambda: {
            "RK45": (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10),
            "DOP853": (1e-3, 1e-5, 1e-7, 1e-9, 1e-11),
            "LSODA": (1e-3, 1e-5, 1e-7, 1e-9),
            "Radau": (1e-3, 1e-5, 1e-7),
            "BDF": (1e-3, 1e-5, 1e-7),
        }
    )
    duration: float | None = None  # None: the scene's
    repeats: int | None = None  # None: adaptive (see common.cpu_time)
    slip_scenes: tuple = ()  # scenes on the slipping model (module docstring)
    slip_methods: tuple = SLIP_METHODS
    slip_no_location: tuple = ("etd2",)
    slip_regularised: tuple = ("rk4", "etd2")
    slip_v_eps: tuple = (1e-2, 1e-3, 1e-4)
    slip_duration: float | None = None  # None: the scene's


FULL = Config(slip_scenes=(SLIP_SCENE,))
QUICK = Config(
    scenes=("paper", LINEAR_SCENE),
    fixed_methods=("exact", "etd2", "etd4", "lawson5", "rk4", "symplectic_euler"),
    adaptive_methods=("RK45",),
    step_exponents=(-2, 0, 2),
    rtols={"RK45": (1e-4, 1e-7)},
    duration=0.5,
    repeats=1,
    slip_scenes=(SLIP_SCENE,),
    slip_methods=("etd2", "rk4"),
    slip_regularised=("rk4",),
    slip_v_eps=(1e-3,),
    slip_duration=0.7,  # the load switches at 0.5 s; slip follows
)


def _one_run(scene, model_name, method, dt, options, reference, repeats):
    mdl = make_model(model_name, scene.params)
    sim = Simulator(mdl, scene.drive, scene.load, method, dt, options, check_stability=False)
    x0 = scene.initial_state.vector(model_name, scene.params.ratio)
    cpu, (times, states) = cpu_time(lambda: sim.run(scene.duration, x0), repeats=repeats)
    return cpu, run_errors(reference, times, states)


def measure(config: Config = FULL, quiet: bool = False) -> list[dict]:
    """Run the sweep; one row per (scene, method, step or rtol) with the columns of :data:`COLUMNS`."""
    rows: list[dict] = []
    for name in config.scenes:
        scene = get_scene(name)
        if config.duration is not None:
            scene = scene.with_overrides(duration=min(config.duration, scene.duration))
        model_name = resolved_model(scene)
        reference = reference_for(scene, model_name)
        mdl = make_model(model_name, scene.params)
        auto = _auto_choice(scene, model_name)
        log(f"[workprecision] {name}: model {model_name}, reference {reference.kind} ({reference.cpu_seconds:.2f} s)", quiet)
        scene_rows = []
        base = dict(scene=name, model=model_name, reference=reference.kind)
        for method in config.fixed_methods:
            for j in config.step_exponents:
                dt = scene.dt * 2.0**j
                report = check_step(mdl.A, mdl.B, method, dt)
                row = dict(base, method=method, kind="fixed", dt=dt, rtol="", h_omega_n=report.h_omega_n,
                           default=int(method == scene.method and j == 0), auto=_is(auto, method, dt))  # fmt: skip
                if not report.stable:
                    row["status"] = "unstable (guard)"
                else:
                    try:
                        cpu, err = _one_run(scene, model_name, method, dt, None, reference, config.repeats)
                        row.update(err, status="ok", cpu_s=cpu)
                    except SimulationDivergedError:
                        row["status"] = "diverged"
                    except BeltDriveError as exc:
                        row["status"] = f"failed: {exc}"
                scene_rows.append(row)
        for method in config.adaptive_methods:
            for rtol in config.rtols.get(method, ()):
                row = dict(base, method=method, kind="adaptive", dt=scene.dt, rtol=rtol, h_omega_n="", default=0)
                try:
                    options = dict(rtol=rtol, atol=1e-3 * rtol)
                    cpu, err = _one_run(scene, model_name, method, scene.dt, options, reference, config.repeats)
                    row.update(err, status="ok", cpu_s=cpu)
                except BeltDriveError as exc:
                    row["status"] = f"failed: {exc}"
                scene_rows.append(row)
        rows += _finish(scene_rows, scene.duration, quiet)
    for name in config.slip_scenes:
        rows += _finish(*_slip_rows(name, config, quiet), quiet)
    return rows


def _finish(scene_rows: list[dict], duration: float, quiet: bool) -> list[dict]:
    """x real time and the Pareto front of one scene's rows; log them."""
    ok = [r for r in scene_rows if r["status"] == "ok"]
    for r in ok:
        r["cpu_per_sim_s"] = r["cpu_s"] / duration
        r["x_realtime"] = duration / r["cpu_s"] if r["cpu_s"] > 0 else math.inf
    front = pareto_mask([r["cpu_per_sim_s"] for r in ok], [r["error"] for r in ok])
    for r, on in zip(ok, front):
        r["pareto"] = int(on)
    for r in scene_rows:
        label = r.get("label", r["method"])
        if r["status"] == "ok":
            log(f"  {label:30s} dt={r['dt']:.3g} rtol={r['rtol'] or '-':<6} err={r['error']:.2e} "
                f"cpu/sim-s={r['cpu_per_sim_s']:.2e} ({r['x_realtime']:.0f}x real time)", quiet)  # fmt: skip
        else:
            log(f"  {label:30s} dt={r['dt']:.3g} rtol={r['rtol'] or '-':<6} {r['status']}", quiet)
    return scene_rows


def _slip_rows(name: str, config: Config, quiet: bool) -> tuple[list[dict], float]:
    """Rows of a slipping scene: hybrid, hybrid without event location, regularised (module docstring)."""
    scene = get_scene(name)
    if config.slip_duration is not None:
        scene = scene.with_overrides(duration=min(config.slip_duration, scene.duration))
    case = slip_runs.case_from_scene(scene)
    steps = [scene.dt * 2.0**j for j in config.step_exponents]
    reference = slip_runs.reference(case, min(steps))
    kind = f"DOP853 + events rtol {slip_runs.REFERENCE_TOL:g}"
    log(f"[workprecision] {name}: slipping model, reference {kind} ({reference.events} events)", quiet)
    flex = make_model("flexible", scene.params)
    auto = _auto_choice(scene, "slipping")
    variants = [("hybrid", m, 0.0) for m in config.slip_methods]
    variants += [("no_location", m, 0.0) for m in config.slip_no_location]
    variants += [("regularised", m, v) for m in config.slip_regularised for v in config.slip_v_eps]
    rows = []
    for family, method, v_eps in variants:
        for j, dt in zip(config.step_exponents, steps):
            report = check_step(flex.A, flex.B, method, dt)
            row = dict(scene=name, model="slipping" if family != "regularised" else "regularised", method=method,
                       kind="fixed", dt=dt, rtol="", h_omega_n=report.h_omega_n, reference=kind, family=family,
                       v_eps=v_eps, label=slip_runs.variant_label(family, method, v_eps),
                       default=int(family == "hybrid" and method == scene.method and j == 0),
                       auto=_is(auto, method, dt) if family == "hybrid" else 0)  # fmt: skip
            if family == "hybrid" and not report.stable:
                row["status"] = "unstable (guard)"
            else:
                r = slip_runs.run(case, family, method, dt, v_eps, config.repeats)
                row["status"] = r.status
                if r.status == "ok":
                    row.update(slip_runs.errors(reference, r), cpu_s=r.cpu_s, events=r.events)
            rows.append(row)
    return rows, scene.duration


_STYLE = {
    "exact": ("tab:blue", "o"),
    "etd2": ("tab:red", "o"),
    "etd4": ("tab:purple", "D"),
    "lawson5": ("m", "*"),
    "euler": ("tab:gray", "v"),
    "symplectic_euler": ("tab:olive", "^"),
    "rk4": ("tab:green", "s"),
    "trapezoidal": ("tab:purple", "D"),
    "RK45": ("tab:orange", "x"),
    "DOP853": ("tab:brown", "+"),
    "Radau": ("tab:pink", "1"),
    "BDF": ("tab:cyan", "2"),
    "LSODA": ("k", "3"),
}


def plot(rows: list[dict], path: Path) -> Path:
    """Log-log chart, one panel per scene (see module docstring)."""
    plt = pyplot()
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    ncol = 2 if len(scenes) > 1 else 1
    nrow = math.ceil(len(scenes) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(6.2 * ncol, 4.6 * nrow), squeeze=False)
    for ax, name in zip(axes.flat, scenes):
        srows = [r for r in rows if r["scene"] == name]
        ok = [r for r in srows if r["status"] == "ok"]
        for label in dict.fromkeys(row_label(r) for r in srows):
            pts = [r for r in ok if row_label(r) == label]  # in sweep order: dt or rtol
            if not pts:
                continue
            color, marker = _STYLE.get(pts[0]["method"], ("k", "."))
            family, ls = pts[0].get("family", "hybrid"), "-"
            if family == "no_location":
                ls = ":"
            elif family == "regularised":
                ls, marker = "--", _V_EPS_MARKERS.get(float(pts[0]["v_eps"]), ".")
            x = [r["cpu_per_sim_s"] for r in pts]
            y = [max(r["error"], PLOT_FLOOR) for r in pts]
            ax.plot(x, y, marker=marker, color=color, ls=ls, lw=0.8, ms=5, label=label, mfc="none" if family != "hybrid" else None)
        front = sorted((r for r in ok if r.get("pareto") == 1), key=lambda r: r["cpu_per_sim_s"])
        if front:
            ax.step([r["cpu_per_sim_s"] for r in front], [max(r["error"], PLOT_FLOOR) for r in front],
                    where="post", color="k", lw=2.2, alpha=0.25, label="Pareto front")  # fmt: skip
        for r in ok:
            if r.get("default") == 1:
                ax.plot(r["cpu_per_sim_s"], max(r["error"], PLOT_FLOOR), "o", ms=14, mfc="none", mec="k", mew=1.5,
                        label="default: the scene's method and dt")  # fmt: skip
            if r.get("auto") in (1, "1"):
                ax.plot(r["cpu_per_sim_s"], max(r["error"], PLOT_FLOOR), "s", ms=18, mfc="none", mec="tab:orange",
                        mew=1.5, label="method: auto (the guard's choice)")  # fmt: skip
        for limit, label in ((1 / 1000, "1000x real time"), (1 / 200, "200x")):
            ax.axvline(limit, color="0.6", ls=":", lw=0.8)
            ax.text(limit, 1.0, label, rotation=90, va="top", ha="right", fontsize=6.5, color="0.4",
                    transform=ax.get_xaxis_transform())  # fmt: skip
        skipped = {}
        for r in srows:
            if r["status"] != "ok":
                mark = "" if r["status"] == "unstable (guard)" else "*"
                skipped.setdefault((row_label(r), r["kind"]), []).append(
                    f"{r['dt']:.2g}{mark}" if r["kind"] == "fixed" else f"{r['rtol']:g}{mark}")  # fmt: skip
        if skipped:
            text = "not plotted (refused by the guard; *: diverged or failed):\n" + "\n".join(
                f"{m}: dt " + ", ".join(v) if kind == "fixed" else f"{m}: rtol " + ", ".join(v) for (m, kind), v in skipped.items()
            )
            ax.text(0.99, 0.01, text, transform=ax.transAxes, fontsize=6, ha="right", va="bottom", color="0.3")
        model = "slipping" if any(r.get("family") for r in srows) else srows[0]["model"]
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{name} ({model} model; reference {srows[0]['reference']})", fontsize=9)
        ax.set_xlabel("CPU seconds per simulated second")
        ax.set_ylabel("error: max rel. error of omega_M, belt torque")
        ax.grid(True, which="major", alpha=0.3)
    for ax in list(axes.flat)[len(scenes) :]:
        ax.set_visible(False)
    handles = {}
    for ax in axes.flat:
        for h, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, h)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=7, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06 if nrow > 1 else 0.1, 1, 1))
    save_figure(fig, path)
    plt.close(fig)
    return Path(path)


_V_EPS_MARKERS = {1e-2: ">", 1e-3: "<", 1e-4: "p"}


def row_label(row: dict) -> str:
    """Legend label of a row: the method, or the slipping scene's variant (:func:`.slip_runs.variant_label`)."""
    family = row.get("family")
    return slip_runs.variant_label(family, row["method"], float(row["v_eps"])) if family else row["method"]


def summary(rows: list[dict]) -> dict:
    """Headline numbers: x real time of each fixed-step method at each scene's own step."""
    out = {}
    for r in rows:
        if r["status"] == "ok" and r["kind"] == "fixed" and r.get("family") in (None, "", "hybrid"):
            scene = get_scene(r["scene"])
            if math.isclose(r["dt"], scene.dt):
                out[(r["scene"], r["method"])] = r["x_realtime"]
    return out


def run(out_dir: Path, quick: bool = False, quiet: bool = False) -> dict:
    """Measure, write ``workprecision.csv`` and ``workprecision.png`` into ``out_dir``."""
    out_dir = Path(out_dir)
    rows = measure(QUICK if quick else FULL, quiet=quiet)
    csv_path = write_csv(out_dir / "workprecision.csv", rows, COLUMNS)
    png_path = plot(rows, out_dir / "workprecision.png")
    return {"rows": rows, "csv": csv_path, "png": png_path}
