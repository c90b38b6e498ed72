"""Offline simulation: :func:`simulate` runs a scene (guards, model and method choice) and computes every output
and the energy terms; :class:`Simulator` runs one model on the :class:`~belt_drive_ros.core.stepper.Stepper`, the
one engine that advances time for every caller (its compiled loop: :func:`~belt_drive_ros.core.kernel.linear_steps`).
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from .accuracy import (
    AccuracyReport, between_samples, probe_scene, require_accurate, require_accurate_slipping, slip_run_error,
    with_between_samples, with_slip_run_error,
)  # fmt: skip
from .accuracy_probes import rigid_plant
from .errors import SceneError, SimulationDivergedError, UnstableStepError
from .fidelity import ModelChoice, RigidSurvey, choose_model, limit_exceedance
from .integrators import method_class
from .method_choice import MethodChoice, good_step_error, resolve as resolve_method
from .model import make_model
from .scene import SLIP_MODELS, Scene
from .slip_run import SlippingSimulator
from .stability import StabilityReport, require_stable
from .stepper import SPEED_LIMIT, Plant, Stepper, shared_plant, shared_stepper

__all__ = ["CSV_COLUMNS", "SPEED_LIMIT", "Plant", "SimResult", "Simulator", "simulate"]
#: ``method: auto`` runs the scene again at the step its run's own estimate names only up to this many steps (a run
#: in memory holds each: ~256 B a step with its outputs, so ~1 GB); past it the result says so and names the step
RERUN_MAX_STEPS = 4_000_000
#: CSV columns required by the CLI, SI units.
CSV_COLUMNS = (
    "time",
    "phi_M",
    "omega_M",
    "phi_3",
    "omega_3",
    "drive_torque",
    "load_torque",
    "belt_torque",
    "relative_deflection",
)
#: extra CSV columns of a slipping-model run (SI units; ``slip`` is 1 while the belt slides)
SLIP_CSV_COLUMNS = (
    "span_force_tight",
    "span_force_slack",
    "friction_use",
    "slip",
    "slip_speed",
    "elastic_deflection",
    "slip_angle",
)

@dataclass
class SimResult:
    """States, inputs and outputs of one run on the grid ``time`` [s].

    ``outputs`` holds every signal of :data:`belt_drive_ros.core.model.OUTPUT_UNITS` as an (N,) array (SI units,
    named there), a slipping run's also those of :data:`belt_drive_ros.core.slip.SLIP_OUTPUT_UNITS`; ``states`` is
    (N, n) in the model's state ordering; ``inputs`` (N, 2) the drive and load torques [N m]; ``energy`` the energy
    terms [J] by name.
    """

    scene: Scene
    model: str
    method: str
    dt: float
    time: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    outputs: dict
    choice: ModelChoice | None = None
    stability: StabilityReport | None = None
    #: the accuracy guard's verdict on the closed loop (core/accuracy.py); None when not checked
    accuracy: AccuracyReport | None = None
    wall_time: float = 0.0
    energy: dict = field(default_factory=dict)
    #: slipping model: mode switches as (kind 'onset'/'restick', time [s], direction sigma)
    events: list = field(default_factory=list)
    #: how method and step were chosen when the scene named none (``method: auto``); None: stated
    method_choice: MethodChoice | None = None

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        return self.outputs[name]

    def table(self, columns=CSV_COLUMNS) -> np.ndarray:
        """(N, len(columns)) array of the named signals."""
        return np.column_stack([np.asarray(self[c], dtype=float) for c in columns])

    def to_csv(self, path) -> None:
        """CSV with a header line of column names; SI units (rad, rad/s, N m, s, m, m/s). Columns:
        :data:`CSV_COLUMNS`, and for the slipping model also :data:`SLIP_CSV_COLUMNS`."""
        columns = CSV_COLUMNS + (SLIP_CSV_COLUMNS if self.model in SLIP_MODELS else ())
        np.savetxt(path, self.table(columns), delimiter=",", header=",".join(columns), comments="", fmt="%.12g")


class Simulator:
    """Runs one model with one integrator from an initial state (through the :class:`~belt_drive_ros.core.stepper.Stepper`).

    Parameters
    ----------
    model : RigidBeltModel or FlexibleBeltModel; drive, load : torque profiles.
    method : integrator name; dt : step [s]; method_options : passed to it.
    check_stability : refuse (``UnstableStepError``) a step the guard predicts unstable.
    """

    def __init__(self, model, drive, load, method="etd2", dt=1e-3, method_options=None, check_stability=True):
        self.model = model
        self.plant = shared_plant(model, drive, load)
        self.method, self.dt = method, float(dt)
        self.method_options = dict(method_options or {})
        self.stepper = Stepper(self.plant, method, self.dt, self.method_options)
        self.integrator = self.stepper.integrator
        self.stability = require_stable(model.A, model.B, method, dt) if check_stability else None

    def run(self, duration: float, x0: np.ndarray, t0: float = 0.0,
            progress: Callable[[float], None] | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """Integrate over ``duration`` [s] on the grid ``t0 + k dt``; return (time (N+1,), states (N+1, n)).

        Steps at torque breakpoints are split or clamped (:mod:`belt_drive_ros.core.stepper`; ``stepper.split_steps``
        lists the split steps after)."""
        self.stepper.origin = float(t0)
        return self.stepper.run(x0, float(t0), float(t0) + float(duration), progress)


def simulate(
    scene: Scene,
    model: str | None = None,
    method: str | None = None,
    dt: float | None = None,
    duration: float | None = None,
    progress: Callable[[float], None] | None = None,
    check_stability: bool = True,
) -> SimResult:
    """Run ``scene`` (overrides for model, method, dt [s], duration [s]) and compute all outputs.

    With ``model='auto'`` the choice and its reason are in ``result.choice``
    (:func:`~belt_drive_ros.core.fidelity.choose_model`: rigid or flexible by the frequency rule, slipping when that
    run passes the capstan limit; a scene that stays within it returns that very run). Flexible with a fixed-step
    method (not a second-order-form one): the slipping engine's first phase, the flexible model's compiled loop with
    the capstan check after each step (:mod:`~belt_drive_ros.core.slip_run`): within the limit the flexible run bit
    for bit, else it slips on from the located onset (the reason names the onset time).
    """
    if not isinstance(scene, Scene):
        raise SceneError(f"scene: expected a Scene (load_scene or Scene.from_mapping), got {type(scene).__name__}")
    if progress is not None and not callable(progress):
        raise SceneError(f"progress: expected a callable taking the fraction done, got {type(progress).__name__}")
    if not (model is None and method is None and dt is None and duration is None):  # (a scene is immutable)
        scene = scene.with_overrides(model=model, method=method, dt=dt, duration=duration)
    # one rigid run for the model choice, the method choice and the guard's probes (at the scene's step)
    survey = RigidSurvey.of_scene(scene)
    linear = choose_model(scene, check_slip=False, survey=survey) if scene.model == "auto" else None
    scene, method_choice = resolve_method(scene, linear.model if linear is not None else None, survey)
    if scene.dt != survey.dt:  # auto chose substeps: the probes follow the step
        survey = RigidSurvey.of_scene(scene)
    checked = getattr(method_choice, "report", None)  # the choice's check is the run's (same plant, step, probes)
    if checked is not None and (not checked.ok or method_choice.substeps != 1 or scene.method_options):
        checked = None
    try:
        result = _rated_choice(_simulate(scene, linear, progress, check_stability, survey, checked))
    except UnstableStepError as exc:  # the stability guard's refusal names a step the accuracy guard accepts too
        raise good_step_error(scene, linear.model if linear is not None else scene.model, exc) from None
    if method_choice is None:
        return result
    report = result.accuracy
    if (report is not None and not report.accurate and report.suggestion is not None and report.suggestion < scene.dt
            and scene.duration / report.suggestion > RERUN_MAX_STEPS):  # fmt: skip
        # (a run in memory holds every step: 64x the steps of a long run is gigabytes; the caller runs that step)
        result.method_choice = replace(method_choice, reason=(
            f"{method_choice.reason}; {method_choice.method} at dt={scene.dt:.3g} s rated {report.error:.2g} on the "
            f"run itself, and the step that meets it, {report.suggestion:.3g} s, would hold "
            f"{scene.duration / report.suggestion:.3g} steps in memory: not run again here (run that dt: "
            "belt-drive sim streams a long run)"))
        return result
    if report is not None and not report.accurate and report.suggestion is not None and report.suggestion < scene.dt:
        # the slipping run's own estimate (events, error across slip phases) is only known after it: once more
        # at the step it names, the chosen method kept
        first = f"{method_choice.method} at dt={scene.dt:.3g} s rated {report.error:.2g} on the run itself"
        result = _rated_choice(_simulate(scene.with_overrides(dt=report.suggestion), linear, progress, check_stability,
                                         None))  # fmt: skip
        n = max(1, round(method_choice.dt * method_choice.substeps / report.suggestion))
        method_choice = replace(method_choice, dt=report.suggestion, substeps=n,
                                error=result.accuracy.error if result.accuracy else math.nan,
                                met=bool(result.accuracy and result.accuracy.accurate),
                                reason=f"{method_choice.reason}; {first} ({report.mode} mode), so run again at "
                                       f"dt={report.suggestion:.3g} s")  # fmt: skip
    result.method_choice = method_choice
    return result


def _rated_choice(result: SimResult) -> SimResult:
    """``result`` whose model choice, made on a run the accuracy guard rates inaccurate, says so: which model the
    run needs was read off that run (rk4 at 3 ms, 0.42 off: 'flexible, no slip' where an accurate run passes the
    capstan limit at 0.21 s)."""
    if result.choice is not None and result.accuracy is not None and not result.accuracy.accurate:
        result.choice = replace(result.choice, reason=f"{result.choice.reason}; read off a run rated INACCURATE "
                                                      f"({result.accuracy.error:.2g}): at an accurate step it may differ")
    return result


def _simulate(scene: Scene, linear, progress, check_stability: bool, survey=None, checked=None) -> SimResult:
    """:func:`simulate` of a scene with its method stated (``linear``: auto's frequency-rule choice, or None;
    ``survey``: its :class:`~belt_drive_ros.core.fidelity.RigidSurvey`; ``checked``: ``method: auto``'s guard report)."""
    survey = survey or RigidSurvey.of_scene(scene)
    if scene.model != "auto":
        if scene.model == "slipping":
            return simulate_slipping(scene, None, progress, check_stability, survey=survey)
        return _simulate_linear(scene, scene.model, progress, check_stability, survey, checked)
    cls = method_class(scene.method)  # the slipping engine refuses adaptive and second-order-form methods
    if linear.model == "flexible" and cls.fixed_step and not getattr(cls, "second_order_form", False):
        return _simulate_auto_flexible(scene, linear, progress, check_stability, survey, checked)
    runs: dict = {}

    def linear_run(kind):  # the choice's check run is the result when the scene stays linear
        runs[kind] = _simulate_linear(scene, kind, progress, check_stability, survey, checked)
        return runs[kind].time, runs[kind].outputs

    choice = choose_model(scene, linear_run=linear_run, linear=linear)
    if choice.model == "slipping":
        flexible = runs.get("flexible")  # its guard verdict is the stick mode's
        return simulate_slipping(scene, choice, progress, check_stability, flexible.accuracy if flexible else None,
                                 survey)  # fmt: skip
    result = runs[choice.model]
    result.choice = choice
    return result


def _simulate_auto_flexible(scene: Scene, linear: ModelChoice, progress, check_stability: bool, survey,
                            checked=None) -> SimResult:  # fmt: skip
    """``auto`` with the flexible tier on the slipping engine (the flexible phase alone first when the survey puts the
    scene well within the limit): a flexible result if it never slipped. ``probes``: the stick check's, both modes'."""
    sim, x0, probes = _slipping_engine(scene, check_stability, survey)
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    # the flexible phase runs inside the guard once it found the step stable: its first knots are a forcing window's
    head = None if _may_slip(scene, survey) else _once(lambda: _flexible_phase(sim, y0, scene.duration, progress))
    accuracy = (
        checked or require_accurate(sim.plant, scene.method, scene.dt, scene.duration, x0, scene.tolerance,
                                    method_options=scene.method_options, probes=probes, head=head,
                                    stepper=_WindowRuns(sim) if head is not None else None)
        if check_stability else None
    )  # fmt: skip
    flex = head() if head is not None else None
    wall, start = head.wall if head is not None else 0.0, _time.perf_counter()
    if flex is None:
        try:
            time, states, modes, sigmas = sim.run(scene.duration, y0, progress=progress)
        except SimulationDivergedError:
            if check_stability and sim.events:  # diverged after slipping: the slip mode's guard names the step that works
                _slipping_accuracy(scene, sim, accuracy, probes)
            raise
        if not sim.events and not np.any(modes):  # it never slipped (the guess was wrong): the flexible states
            flex = _flexible_phase(sim, y0, scene.duration)
        wall += _time.perf_counter() - start
    if flex is not None:  # the flexible model throughout: its run, bit for bit
        time, states = flex
        result = _linear_result(scene, sim.flexible, sim.plant, time, states, sim.stability, accuracy, wall)
        ratio, t_peak = limit_exceedance(scene.params, time, result.outputs)
        omega_n = sim.stability.omega_n if sim.stability is not None else math.inf
        # an excursion past the limit the step-end check did not see: not silent. Between two samples a swing of
        # amplitude A at omega_n rises at most A (1 - cos(h omega_n / 2)) above them (A <= the peak force): a run
        # whose sampled peak stays below the limit by twice that cannot reach it (paper: 0.41 of it, h omega_n 0.33)
        reach = 1.0 + 2.0 * (1.0 - math.cos(min(scene.dt * omega_n, math.pi) / 2.0)) if math.isfinite(omega_n) else math.inf
        if result.accuracy is not None and ratio * reach >= 1.0:
            y = np.column_stack([result.states, np.zeros(len(result.time))])
            result.accuracy = with_between_samples(result.accuracy, *between_samples(
                sim.model, result.time, y, np.zeros(len(result.time), dtype=np.int8), result.inputs), omega_n)
        result.choice = replace(linear, limit_ratio=ratio, limit_time=t_peak)
        return result
    # a run that slips from its first sample (an initial deflection past the limit) has no onset event, and its
    # first event is a restick: the onset is t = 0 then, else the first onset event
    onset = float(time[0]) if modes[0] else next((e.time for e in sim.events if e.kind == "onset"), float(time[0]))
    reason = (
        f"slipping: transmitted force reaches the capstan limit "
        f"(Q_max = {scene.params.friction_limit(0.0):.0f} N at rest) at t = {onset:.3g} s "
        f"in the {linear.model} run ({linear.reason})"
    )
    choice = replace(linear, model="slipping", reason=reason, limit_ratio=1.0, limit_time=onset)
    # the guard on both modes once the run has slipped (its stick part is the check made before the run)
    accuracy = _slipping_accuracy(scene, sim, accuracy, probes) if check_stability else None
    return _slipping_result(scene, sim, time, states, modes, sigmas, wall, choice, accuracy)


class _WindowRuns:
    """The accuracy guard's runs at the scene's step on the slipping engine ``sim``'s flexible stepper (its integrator,
    plant, method and step; for a new scene no second stepper and compiled loop of them are built): each window's
    knots as that stepper gives them, or, where its capstan check stopped the run, as the plant's unguarded stepper
    gives them (:func:`~belt_drive_ros.core.stepper.shared_stepper`). A run the check does not stop is the same steps
    of the same compiled loop, the check only reading the states (the flexible phase's own first knots are already
    read as the first window's): the same floats as the unguarded stepper's. Used where the survey puts the scene
    well within the limit (its windows' runs are not stopped, else each would be run twice)."""

    def __init__(self, sim):
        self._sim = sim
        self.integrator = sim.stepper.integrator

    def run(self, x0, t0: float, t1: float):
        """(times, states) of the window from ``x0`` at ``t0`` to ``t1`` [s], unguarded (see the class)."""
        sim = self._sim
        out = sim.stepper.run(x0, t0, t1)
        if sim.stepper.stopped is None:
            return out
        return shared_stepper(sim.plant, sim.method, sim.dt, sim.method_options).run(x0, t0, t1)


def _once(run):
    """``run`` made at the first call only, its result returned at every call (``.wall``: that call's wall time [s])."""
    def once():
        if not hasattr(once, "result"):
            start = _time.perf_counter()
            once.result, once.wall = run(), _time.perf_counter() - start
        return once.result

    return once


def _may_slip(scene: Scene, survey) -> bool:
    """Whether the flexible run may reach the capstan limit, by the rigid survey: twice its peak belt torque (a
    step's undamped overshoot) against Q_max at its top speed. It only picks what runs first, the same result."""
    try:
        w, _, peak = survey.speeds
    except Exception:  # noqa: BLE001 - a survey that diverged: the slipping engine decides
        return True
    return not 2.0 * peak / scene.params.r_3 < scene.params.friction_limit(float(w))


def _flexible_phase(sim, y0, duration: float, progress=None):
    """(time, flexible states) of the slipping engine ``sim``'s first phase (its guarded flexible stepper: the steps
    its ``run`` takes) from ``y0`` over ``duration`` [s]; None when the run starts beyond the capstan limit or reaches it."""
    state = sim.initial(y0)
    if state.kind != "flexible":
        return None
    sim.origin = 0.0
    time, states = sim.stepper.run(state.x, 0.0, duration, progress)
    return (time, states) if sim.stepper.stopped is None else None


def _simulate_linear(scene: Scene, kind: str, progress, check_stability: bool, survey=None,
                     checked=None) -> SimResult:  # fmt: skip
    """``scene`` on the rigid or flexible model ``kind``: states, outputs and energy terms."""
    if kind == "rigid" and survey is not None and survey.drive is scene.drive and survey.load is scene.load:
        mdl, plant = survey.rigid, survey.plant
    else:
        mdl = make_model(kind, scene.params)
        plant = (rigid_plant if kind == "rigid" else shared_plant)(mdl, scene.drive, scene.load)
    # a fixed-step method steps on the plant's shared stepper (the guards' windows too; it holds no verdict and a
    # run's outcome does not depend on the runs before it); an adaptive one (solver history) on its own
    stepper = (shared_stepper(plant, scene.method, scene.dt, scene.method_options) if method_class(scene.method).fixed_step
               else Stepper(plant, scene.method, scene.dt, scene.method_options))  # fmt: skip
    stability = require_stable(mdl.A, mdl.B, scene.method, scene.dt) if check_stability else None
    x0 = scene.initial_state.vector(kind, scene.params.ratio)
    run = _once(lambda: stepper.run(x0, 0.0, scene.duration, progress))  # (inside the guard: its first window)
    # closed loop (torque slopes): refuses an unstable step, reports an inaccurate one (the CLI warns)
    accuracy = (
        checked or require_accurate(
            plant, scene.method, scene.dt, scene.duration, x0, scene.tolerance, method_options=scene.method_options,
            stepper=stepper, probes=probe_scene(plant, scene.duration, x0, scene.dt, survey=survey), head=run,
        )
        if check_stability else None
    )  # fmt: skip
    time, states = run()
    return _linear_result(scene, mdl, plant, time, states, stability, accuracy, run.wall)


def _linear_result(scene, mdl, plant, time, states, stability, accuracy, wall, totals=None, choice=None) -> SimResult:
    """The result of a rigid or flexible run: outputs and energy terms of its states on the grid ``time``
    (``totals``: a streamed window's running energy, :func:`_energy`)."""
    cx = mdl.state_part(states)  # C x once: the torques' wheel coordinates and the outputs read it
    u = plant.input_array(time, states, cx)
    work, keep = _energy(totals, time, {"input_work": mdl.input_power(states, u), "dissipated": mdl.dissipation_power(states)})
    time, states, u, cx = time[keep], states[keep], u[keep], cx[keep]
    energy = {"kinetic": mdl.kinetic_energy(states), "potential": mdl.potential_energy(states), **work}
    return SimResult(scene=scene, model=mdl.name, method=method_class(scene.method).name, dt=scene.dt, time=time,
                     states=states, inputs=u, outputs=mdl.outputs(states, u, cx), choice=choice, stability=stability,
                     accuracy=accuracy, wall_time=wall, energy=energy)  # fmt: skip


def _energy(totals: dict | None, time: np.ndarray, powers: dict) -> tuple[dict, slice]:
    """The energy terms [J] of ``powers`` [W] (running trapezoidal integrals over ``time`` [s]) and the samples a
    result keeps. A whole run (``totals`` None): every sample, the integrals from 0. A streamed window: they go on
    from ``totals`` (the windows before: ``{}`` at the first, updated here), and past the first window its first
    sample, the previous window's last (the quadrature's seam), is dropped."""
    if totals is None:
        dt_grid = time[1:] - time[:-1]  # (np.diff's operation)
        return {name: _integral(p, dt_grid) for name, p in powers.items()}, slice(None)
    n = len(time) - (1 if totals else 0)
    keep = slice(1, None) if totals else slice(None)
    out = {}
    for name, p in powers.items():
        integral = totals.get(name, 0.0) + _integral(p, np.diff(time))
        totals[name] = float(integral[-1])
        out[name] = integral[-n:]
    return out, keep


def _integral(p: np.ndarray, dt_grid: np.ndarray) -> np.ndarray:
    """Running trapezoidal integral of a power ``p`` [W] over the output grid's steps ``dt_grid`` [s]: energy [J]."""
    out = np.empty(p.shape[0])
    out[0] = 0.0
    np.cumsum(0.5 * (p[1:] + p[:-1]) * dt_grid, out=out[1:])
    return out


def simulate_slipping(scene, choice=None, progress=None, check_stability=True, stick=None, survey=None) -> SimResult:
    """Run ``scene`` on the slipping model (:mod:`belt_drive_ros.core.slip_run`).

    ``result.outputs`` has every signal of the other models plus :data:`~belt_drive_ros.core.slip.SLIP_OUTPUT_UNITS`;
    ``result.events`` lists the mode switches (kind, time [s], direction); ``result.energy`` adds ``friction``, the
    integral of Q s'. ``stick``: the guard's flexible report when made; ``survey``: the scene's rigid survey."""
    sim, _, probes = _slipping_engine(scene, check_stability, survey)
    accuracy = _slipping_accuracy(scene, sim, stick, probes) if check_stability else None
    start = _time.perf_counter()
    time, states, modes, sigmas = sim.run(scene.duration, scene.initial_state.vector("slipping", scene.params.ratio),
                                          progress=progress)  # fmt: skip
    wall = _time.perf_counter() - start
    return _slipping_result(scene, sim, time, states, modes, sigmas, wall, choice, accuracy)


def _slipping_engine(scene, check_stability: bool, survey):
    """(the slipping engine of ``scene``, its flexible initial state, the guard's probes of its flexible plant or None)."""
    sim = SlippingSimulator(scene.params, scene.drive, scene.load, scene.method, scene.dt, scene.method_options, check_stability,
                            lazy=True)  # fmt: skip
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    return sim, x0, probe_scene(sim.plant, scene.duration, x0, scene.dt, survey=survey) if check_stability else None


def _slipping_accuracy(scene, sim, stick=None, probes=None):
    """The accuracy guard on both modes of the slipping model, each linearized (``accuracy.require_accurate_slipping``);
    ``stick``, ``probes``: the flexible check's verdict and probes when made."""
    return require_accurate_slipping(
        scene.params, scene.drive, scene.load, scene.method, scene.dt, scene.duration,
        scene.initial_state.vector("flexible", scene.params.ratio), scene.tolerance, method_options=scene.method_options,
        stepper=sim.stepper, stick=stick, probes=probes,
    )  # fmt: skip


def _slipping_result(scene, sim, time, states, modes, sigmas, wall, choice, accuracy=None, events=None,
                     totals=None, between=None) -> SimResult:  # fmt: skip
    """The result of a slipping-model run of ``sim``: outputs, energy terms (with friction) and events (``events``:
    a streamed window's, else the run's; ``totals``: a streamed window's running energy, :func:`_energy`;
    ``between``: a streamed run's largest excursion between samples so far, ``[excess, time]``, updated here from the
    window's samples with its seam sample, so each window's verdict is the run's so far and the last the run's)."""
    m = sim.model
    u = sim.input_array(time, states)
    found = between_samples(m, time, states, modes, u) if accuracy is not None else None  # (the seam sample kept)
    if found is not None and between is not None:
        if found[0] > between[0]:
            between[:] = found
        found = tuple(between)
    parts = m.force_parts(states, modes, sigmas)  # (Q_max, Q, s'): made once for the energy terms and outputs
    work, keep = _energy(totals, time, {"input_work": m.input_power(states, u),
                                        "dissipated": m.damping_power(states, modes, sigmas, parts),
                                        "friction": m.friction_power(states, modes, sigmas, parts)})  # fmt: skip
    time, states, u, modes, sigmas = time[keep], states[keep], u[keep], modes[keep], sigmas[keep]
    outputs = m.outputs(states, u, modes, sigmas, tuple(v[keep] for v in parts))
    events = sim.events if events is None else events
    if accuracy is not None and totals is None:  # the slipping run itself, rerun over its slipping stretch (what the
        # modes alone miss; a streamed run's guard has the modes only)
        accuracy = with_slip_run_error(accuracy, slip_run_error(
            scene.params, scene.drive, scene.load, scene.method, scene.dt, time, states, modes, sigmas,
            [e.time for e in events], scene.method_options, sim._hybrid, (outputs["omega_M"], outputs["belt_torque"]),
        ))  # fmt: skip
    if found is not None:
        accuracy = with_between_samples(accuracy, *found, sim.stability.omega_n if sim.stability is not None else math.nan)
    energy = {"kinetic": m.kinetic_energy(states), "potential": m.potential_energy(states), **work}
    return SimResult(
        scene=scene, model="slipping", method=sim.integrator.name, dt=scene.dt, time=time, states=states,
        inputs=u, outputs=outputs, choice=choice, stability=sim.stability,
        wall_time=wall, energy=energy, events=[(e.kind, e.time, e.sigma) for e in events], accuracy=accuracy,
    )
