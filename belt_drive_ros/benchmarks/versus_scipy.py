"""Against what users would pick instead: ``solve_ivp`` RK45, and x real time per scene.

1. **Matched accuracy** on ``paper`` (closed loop, the paper's scene; the
   paper used Matlab's Runge-Kutta) and on its open-loop variant: the
   default method (each scene's own, paper: ``lawson5``) and the package's other fixed-step methods
   swept over the step (quarter octaves), against a plain ``scipy.integrate.solve_ivp(method=
   "RK45")`` call swept over ``rtol`` (quarter decades, ``atol = 1e-3 rtol``) with ``t_eval``
   on the scene's output grid and the right-hand side ``A x + B u(t, x)`` a
   user would write (with the package's fast :class:`~belt_drive_ros.core.simulate.Plant`
   inputs, so the comparison is of the integrators, not of the torque code).
   For each target error, the CPU time of the **cheapest measured run** of
   each method reaching it (no interpolation) and their ratio.
2. **x real time**: every fixed-step method at each scene's own step,
   ``Simulator.run`` only, minimum of 15 repeats; and the whole
   ``simulate()`` call (model choice, outputs, energy terms) of the default.
3. **Whole calls, side by side** (printed first, also with ``--quick``): the
   whole warm ``simulate()`` (model and method choice, both guards, the
   accuracy check, outputs, energy terms) of each shipped scene as x real
   time, and ``simulate(paper)`` against the user's whole ``solve_ivp`` RK45
   call at the largest ``rtol`` (quarter decades) whose error is at most
   :data:`RK45_TARGET`, each the minimum CPU time of the same number of
   repeats in one process. Ours twice: the same ``Scene`` object called
   again (what a repeated call costs: the models, plants, steppers and the
   method's matrices built for that object are reused, and the belt mode's
   verdict is cached by its numbers), and a new ``Scene`` of the same file
   each call (read before the clock starts: a scene read again holds the
   parameter and torque objects of the earlier read, equal to the bit, so
   it reuses what was built from them as the same ``Scene`` does:
   :func:`belt_drive_ros.core.scene._shared`), and a new ``Scene`` whose
   belt damping differs by one part in 1e12 each call (numbers no cache has
   seen but the torques': a sweep's variant, what a first call of an edited
   scene costs). The user's RK45 call has nothing to reuse.

Error and timing definitions: :mod:`belt_drive_ros.benchmarks.common`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.integrate

from ..core.integrators import FIXED_STEP_METHODS
from ..core.model import make_model
from ..core.simulate import Plant, Simulator, simulate
from ..core.stability import check_step
from .common import (
    LINEAR_SCENE,
    PLOT_FLOOR,
    SHIPPED_SCENES,
    cpu_time,
    get_scene,
    is_open_loop,
    log,
    pyplot,
    save_figure,
    reference_for,
    resolved_model,
    run_errors,
    write_csv,
)

SWEEP_COLUMNS = (
    "scene", "model", "method", "dt", "rtol", "user_default", "cpu_s", "cpu_per_sim_s", "x_realtime", "e_speed", "e_belt", "error",
)  # fmt: skip
MATCH_COLUMNS = ("scene", "target_error", "method", "cpu_per_sim_s", "setting", "rk45_cpu_per_sim_s", "rk45_rtol", "speedup")
REALTIME_COLUMNS = ("scene", "model", "method", "dt", "open_loop", "run_cpu_s", "x_realtime", "simulate_cpu_s", "x_realtime_simulate")

TARGETS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)
#: the whole-call comparison's accuracy: RK45 at the largest rtol reaching it
RK45_TARGET = 1e-6
WHOLE_COLUMNS = ("measure", "cpu_s", "x_realtime", "error", "note")
#: scenes of the whole-call table (issue targets: paper and e_motor_start, bsg_start, truck_compressor)
WHOLE_SCENES = ("paper", "e_motor_start", "bsg_start", "truck_compressor")
RK45_USER_DEFAULT = dict(rtol=1e-3, atol=1e-6)  # solve_ivp's defaults


@dataclass(frozen=True)
class Config:
    scenes: tuple = ("paper", LINEAR_SCENE)
    fixed_methods: tuple = ("lawson5", "etd4", "etd2", "rk4", "exact")
    # dt = scene.dt * 2^j, quarter octaves (steps off the soft start's end are split there: Simulator.run);
    # rtol in quarter decades: the same resolution for both sides of the comparison
    step_exponents: tuple = tuple(j / 4 for j in range(-20, 13))  # 2^-5 ... 2^3
    rtols: tuple = tuple(10.0 ** (-e / 4) for e in range(12, 45))  # 1e-3 ... 1e-11
    realtime_scenes: tuple = (*SHIPPED_SCENES, LINEAR_SCENE)
    realtime_methods: tuple = FIXED_STEP_METHODS
    realtime_repeats: int = 15
    duration: float | None = None
    repeats: int | None = None


FULL = Config()
QUICK = Config(
    scenes=("paper",),
    fixed_methods=("lawson5", "etd2"),
    step_exponents=(-2, 0),
    rtols=(1e-4, 1e-7),
    realtime_scenes=("paper",),
    realtime_methods=("etd2",),
    realtime_repeats=1,
    duration=0.5,
    repeats=1,
)


def solve_ivp_run(scene, model_name: str, rtol: float, atol: float):
    """What a user would write: solve_ivp RK45 on x' = A x + B u(t, x), outputs on the scene's grid."""
    mdl = make_model(model_name, scene.params)
    inputs = Plant(mdl, scene.drive, scene.load).inputs
    A, B = mdl.A, mdl.B
    x0 = scene.initial_state.vector(model_name, scene.params.ratio)
    n = int(round(scene.duration / scene.dt))
    t_eval = scene.dt * np.arange(n + 1)

    def rhs(t, x):
        return A @ x + B @ inputs(t, x)

    def call():
        return scipy.integrate.solve_ivp(rhs, (0.0, t_eval[-1]), x0, method="RK45", rtol=rtol, atol=atol, t_eval=t_eval)

    return call


def _sweep(config: Config, quiet: bool) -> list[dict]:
    rows = []
    for name in config.scenes:
        scene = get_scene(name)
        if config.duration is not None:
            scene = scene.with_overrides(duration=min(config.duration, scene.duration))
        model_name = resolved_model(scene)
        ref = reference_for(scene, model_name)
        mdl = make_model(model_name, scene.params)
        x0 = scene.initial_state.vector(model_name, scene.params.ratio)
        base = dict(scene=name, model=model_name)
        for method in config.fixed_methods:
            for j in config.step_exponents:
                if is_open_loop(scene) and j != int(j):
                    continue  # the open-loop reference is exact on binary grids only (common.exact_reference)
                dt = scene.dt * 2.0**j
                if not check_step(mdl.A, mdl.B, method, dt).stable:
                    continue
                sim = Simulator(mdl, scene.drive, scene.load, method, dt)
                cpu, (t, x) = cpu_time(lambda: sim.run(scene.duration, x0), repeats=config.repeats)
                rows.append(dict(base, method=method, dt=dt, rtol="", cpu_s=cpu, **run_errors(ref, t, x)))
        for rtol in sorted(set(config.rtols) | {RK45_USER_DEFAULT["rtol"]}, reverse=True):
            # atol = 1e-3 rtol: at rtol 1e-3 these are solve_ivp's own defaults (rtol 1e-3, atol 1e-6)
            cpu, sol = cpu_time(solve_ivp_run(scene, model_name, rtol, 1e-3 * rtol), repeats=config.repeats)
            rows.append(dict(base, method="solve_ivp RK45", dt=scene.dt, rtol=rtol, cpu_s=cpu,
                             user_default=int(rtol == RK45_USER_DEFAULT["rtol"]), **run_errors(ref, sol.t, sol.y.T)))  # fmt: skip
        for r in rows:
            if r["scene"] == name:
                r["cpu_per_sim_s"] = r["cpu_s"] / scene.duration
                r["x_realtime"] = scene.duration / r["cpu_s"] if r["cpu_s"] > 0 else math.inf
        for r in (r for r in rows if r["scene"] == name):
            setting = f"rtol={r['rtol']:.3g}" if r["rtol"] != "" else f"dt={r['dt']:.3g}"
            log(f"[versus] {name} {r['method']:26s} {setting:14s} err={r['error']:.2e} {r['x_realtime']:.0f}x real time", quiet)
    return rows


def matched(rows: list[dict], targets=TARGETS) -> list[dict]:
    """For each scene, target and method: the cheapest run with error <= target, against RK45's."""
    out = []
    for name in dict.fromkeys(r["scene"] for r in rows):
        srows = [r for r in rows if r["scene"] == name]
        methods = [m for m in dict.fromkeys(r["method"] for r in srows) if m != "solve_ivp RK45"]
        for target in targets:
            rk = [r for r in srows if r["method"] == "solve_ivp RK45" and r["error"] <= target]
            best_rk = min(rk, key=lambda r: r["cpu_per_sim_s"]) if rk else None
            for method in methods:
                ok = [r for r in srows if r["method"] == method and r["error"] <= target]
                if not ok:
                    continue
                best = min(ok, key=lambda r: r["cpu_per_sim_s"])
                out.append(dict(
                    scene=name, target_error=target, method=method, cpu_per_sim_s=best["cpu_per_sim_s"],
                    setting=f"dt={best['dt']:.4g}",
                    rk45_cpu_per_sim_s=best_rk["cpu_per_sim_s"] if best_rk else "",
                    rk45_rtol=best_rk["rtol"] if best_rk else "not reached",
                    speedup=best_rk["cpu_per_sim_s"] / best["cpu_per_sim_s"] if best_rk else "",
                ))  # fmt: skip
    return out


def realtime(config: Config, quiet: bool) -> list[dict]:
    """x real time of each fixed-step method at each scene's own step (see module docstring)."""
    rows = []
    for name in config.realtime_scenes:
        scene = get_scene(name)
        if config.duration is not None:
            scene = scene.with_overrides(duration=min(config.duration, scene.duration))
        model_name = resolved_model(scene)
        mdl = make_model(model_name, scene.params)
        x0 = scene.initial_state.vector(model_name, scene.params.ratio)
        open_loop = not (scene.drive.state_dependent or scene.load.state_dependent)
        for method in config.realtime_methods:
            if not check_step(mdl.A, mdl.B, method, scene.dt).stable:
                rows.append(dict(scene=name, model=model_name, method=method, dt=scene.dt, open_loop=int(open_loop),
                                 run_cpu_s="unstable (guard)"))  # fmt: skip
                continue
            sim = Simulator(mdl, scene.drive, scene.load, method, scene.dt)
            sim.run(scene.duration, x0)  # warm-up: compile the loop, fill the expm cache
            cpu, _ = cpu_time(lambda: sim.run(scene.duration, x0), repeats=config.realtime_repeats)
            row = dict(scene=name, model=model_name, method=method, dt=scene.dt, open_loop=int(open_loop),
                       run_cpu_s=cpu, x_realtime=scene.duration / cpu)  # fmt: skip
            if method == scene.method:
                total, _ = cpu_time(lambda: simulate(scene), repeats=max(1, config.realtime_repeats // 2))
                row.update(simulate_cpu_s=total, x_realtime_simulate=scene.duration / total)
            rows.append(row)
            log(f"[versus] x real time {name:17s} {model_name:8s} {method:16s} dt={scene.dt:.3g}: "
                f"{row['x_realtime']:.0f}x" + (f" (whole simulate(): {row['x_realtime_simulate']:.0f}x)"
                                                 if "x_realtime_simulate" in row else ""), quiet)  # fmt: skip
    return rows


def whole_calls(repeats: int, quiet: bool) -> list[dict]:
    """Whole warm simulate() per shipped scene, and ``paper``'s against the user's RK45 call (module docstring, 3)."""
    rows = []
    for name in WHOLE_SCENES:
        scene = get_scene(name)
        simulate(scene)  # warm: compiled kernels, imports
        cpu, result = cpu_time(lambda: simulate(scene), repeats=repeats)
        rows.append(dict(measure=f"simulate({name})", cpu_s=cpu, x_realtime=scene.duration / cpu, error="",
                         note=f"{result.model}, {result.method} dt={result.dt:.3g} s; the same Scene again"))  # fmt: skip
        new = iter([get_scene(name) for _ in range(repeats)])  # each read before the clock starts
        first, _ = cpu_time(lambda: simulate(next(new)), repeats=repeats)
        rows.append(dict(measure=f"simulate({name}), a new Scene", cpu_s=first, x_realtime=scene.duration / first,
                         error="", note="a new Scene of the same file each call (its parameters and torques shared by value)"))  # fmt: skip
        # a sweep's variant: the belt damping c one part in 1e12 apart each call, numbers no cache has seen
        unseen = iter([get_scene(name) for _ in range(repeats)])
        unseen = iter([s.with_params(s.params.replace(c=s.params.c * (1.0 + (j + 1) * 1e-12))) for j, s in enumerate(unseen)])
        cold, _ = cpu_time(lambda: simulate(next(unseen)), repeats=repeats)
        rows.append(dict(measure=f"simulate({name}), new numbers", cpu_s=cold, x_realtime=scene.duration / cold,
                         error="", note="a new Scene with c x (1 + j 1e-12): a sweep's first call of each variant"))  # fmt: skip
        log(f"[versus] whole warm simulate({name}): {cpu * 1e3:.2f} ms CPU, {scene.duration / cpu:.0f}x real time "
            f"({rows[-3]['note']}); a new Scene each call: {first * 1e3:.2f} ms, {scene.duration / first:.0f}x; "
            f"new numbers each call: {cold * 1e3:.2f} ms, {scene.duration / cold:.0f}x", quiet)  # fmt: skip
    scene = get_scene("paper")
    model_name = resolved_model(scene)
    ref = reference_for(scene, model_name)
    ours = next(r for r in rows if r["measure"] == "simulate(paper)")
    fresh = next(r for r in rows if r["measure"] == "simulate(paper), a new Scene")
    unseen = next(r for r in rows if r["measure"] == "simulate(paper), new numbers")
    result = simulate(scene)
    ours["error"] = run_errors(ref, result.time, result.states)["error"]
    for e in range(16, 45):  # rtol 1e-4 ... 1e-11 in quarter decades, atol = 1e-3 rtol (as the sweep)
        rtol = 10.0 ** (-e / 4)
        call = solve_ivp_run(scene, model_name, rtol, 1e-3 * rtol)
        sol = call()
        error = run_errors(ref, sol.t, sol.y.T)["error"]
        if error <= RK45_TARGET:
            cpu, _ = cpu_time(call, repeats=repeats)  # (as many repeats as ours: the minimum of as many tries)
            rows.append(dict(measure="solve_ivp RK45 (paper)", cpu_s=cpu, x_realtime=scene.duration / cpu, error=error,
                             note=f"rtol {rtol:.3g}, atol {1e-3 * rtol:.3g}: the largest reaching {RK45_TARGET:g}"))  # fmt: skip
            ratio, first, cold = cpu / ours["cpu_s"], cpu / fresh["cpu_s"], cpu / unseen["cpu_s"]
            rows.append(dict(measure="paper: RK45 / simulate, whole calls", cpu_s="", x_realtime=ratio, error="",
                             note=f"simulate error {ours['error']:.2g}, RK45 error {error:.2g}; the same Scene again"))  # fmt: skip
            rows.append(dict(measure="paper: RK45 / simulate, whole calls, a new Scene", cpu_s="", x_realtime=first,
                             error="", note="a new Scene of the same file each call"))  # fmt: skip
            rows.append(dict(measure="paper: RK45 / simulate, whole calls, new numbers", cpu_s="", x_realtime=cold,
                             error="", note="c x (1 + j 1e-12) each call: what a sweep's variant costs"))  # fmt: skip
            log(f"[versus] paper at error <= {RK45_TARGET:g}: solve_ivp RK45 rtol {rtol:.3g} {cpu * 1e3:.1f} ms vs whole "
                f"simulate() {ours['cpu_s'] * 1e3:.2f} ms (error {ours['error']:.2g}): {ratio:.1f}x; a new Scene each "
                f"call {fresh['cpu_s'] * 1e3:.2f} ms: {first:.1f}x; new numbers each call {unseen['cpu_s'] * 1e3:.2f} ms: "
                f"{cold:.1f}x", quiet)  # fmt: skip
            break
    return rows


def plot(rows: list[dict], path: Path) -> Path:
    plt = pyplot()
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(6.2 * len(scenes), 4.6), squeeze=False)
    style = {"lawson5": ("m", "*-"), "etd4": ("tab:purple", "D-"), "etd2": ("tab:red", "o-"), "rk4": ("tab:green", "s-"), "exact": ("tab:blue", "o-"),
             "solve_ivp RK45": ("tab:orange", "x-")}  # fmt: skip
    for ax, name in zip(axes.flat, scenes):
        for method in dict.fromkeys(r["method"] for r in rows if r["scene"] == name):
            pts = sorted((r for r in rows if r["scene"] == name and r["method"] == method), key=lambda r: r["cpu_per_sim_s"])
            color, fmt = style.get(method, ("0.5", ".-"))
            ax.plot([r["cpu_per_sim_s"] for r in pts], [max(r["error"], PLOT_FLOOR) for r in pts], fmt, color=color,
                    ms=4, lw=0.9, label=method)  # fmt: skip
        scene = get_scene(name)
        for r in rows:
            if r["scene"] == name and r.get("user_default") == 1:
                ax.plot(r["cpu_per_sim_s"], max(r["error"], PLOT_FLOOR), "X", color="k", ms=9,
                        label="solve_ivp defaults (rtol 1e-3, atol 1e-6)")  # fmt: skip
            if r["scene"] == name and r["method"] == scene.method and math.isclose(r["dt"], scene.dt):
                ax.plot(r["cpu_per_sim_s"], max(r["error"], PLOT_FLOOR), "o", ms=13, mfc="none", mec="k",
                        label=f"default: {scene.method} dt={scene.dt:.3g} s")  # fmt: skip
        ax.axhline(1e-6, color="0.5", ls=":", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU seconds per simulated second")
        ax.set_ylabel("error: max rel. error of omega_M, belt torque")
        ax.set_title(f"{name}: package methods vs scipy solve_ivp RK45", fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return Path(path)


def run(out_dir: Path, quick: bool = False, quiet: bool = False) -> dict:
    config = QUICK if quick else FULL
    out_dir = Path(out_dir)
    whole = whole_calls(5 if quick else 15, quiet)
    sweep = _sweep(config, quiet)
    match = matched(sweep)
    rt = realtime(config, quiet)
    for m in match:
        if m["method"] == get_scene(m["scene"]).method and m["speedup"] != "":
            log(f"[versus] {m['scene']}: error <= {m['target_error']:g}: {m['method']} {m['setting']} is {m['speedup']:.1f}x "
                f"faster than RK45 rtol {m['rk45_rtol']:.2g}", quiet)  # fmt: skip
    return {
        "sweep": sweep,
        "matched": match,
        "realtime": rt,
        "whole": whole,
        "csv": [
            write_csv(out_dir / "whole_call.csv", whole, WHOLE_COLUMNS),
            write_csv(out_dir / "versus_scipy.csv", sweep, SWEEP_COLUMNS),
            write_csv(out_dir / "versus_matched.csv", match, MATCH_COLUMNS),
            write_csv(out_dir / "realtime.csv", rt, REALTIME_COLUMNS),
        ],
        "png": plot(sweep, out_dir / "versus_scipy.png"),
    }
