"""Accuracy guard beside the stability guard: is a fixed step stable *and* accurate on the closed loop?

The stability guard (:mod:`belt_drive_ros.core.stability`) reads the method's growth on the free belt, ``x' = A x``.
Torques that depend on speed (a governor, a motor curve, a fan or compressor load ``c_1 omega``) add their slopes to
the loop: linearized about a state, ``u = u_0 + K x`` with ``K = du/dx`` [N m s/rad on the speed columns], the plant
is

    x' = A_cl x + B u_0,        A_cl = A + B K.

A load of ``10 omega_3`` on a light wheel 3 is a damping rate of ``10 / I_3`` [1/s] that ``exact`` (which holds the
torque over the step) amplifies instead of damping once ``h 10 / I_3`` passes 2. And methods exact for the free belt
mode need not be exact for the forced response: Lawson methods integrate ``e^{hA}`` exactly but not the convolution
with a held torque, so their settled deflection under constant torques drifts from the static value as ``h omega_n``
grows (1.67 of it at 8).

This guard checks both, from the method's own stage scheme (no per-method formula): the one-step map of the method
on the linearized closed loop, ``x+ = M x + G u_0``, is read off :func:`~belt_drive_ros.core.stage_scheme.step` with
the torque ``K x + u_0`` (``n + 2`` calls), and compared with the exact map of that linear system (the matrix
exponential of the augmented system, ``x+ = E x + F u_0``):

* **stable**: spectral radius of M at most ``max(1, spectral radius of E)``
  (up to rounding);
* **accurate to** ``tolerance``: the step response (a unit drive torque, a
  unit load torque, each switched on at t = 0 from rest; this excites the
  belt mode fully) of drive speed and belt torque, run over the scene's
  duration with M, G against E, F, stays within ``tolerance`` of each
  signal's peak.

How fast the torques vary in time and angle is rated apart: the forcing windows
(:mod:`~belt_drive_ros.core.accuracy_windows`) and the harmonic term (:mod:`~belt_drive_ros.core.forced_response`).

The slopes are taken by central differences of the torques at speeds and
times along a cheap rigid run of the scene (:data:`~belt_drive_ros.core.accuracy_probes.N_PROBES` probes); the
worst probe counts. Only speed slopes are used: angle slopes of periodic
torques average out and would read as a spurious stiffness.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# the guard's terms live beside this module (probe_scene importable from here)
from .accuracy_probes import (
    ACCURACY_TOLERANCE, ALTERNATIVE_HALVINGS, ALTERNATIVES, MAX_HALVINGS, SUGGEST_MARGIN, WINDOW_STEPS, Probes,
    _output_rows, linear_verdicts, probe_scene,
)  # fmt: skip
from .accuracy_windows import forcing_error
from .errors import IntegratorError, SimulationDivergedError, UnstableStepError
from .forced_response import harmonic_error
from .integrators import FixedStepIntegrator, make_integrator, method_class
from .model import make_model
from .scene import MAX_STEPS, RANGES
from .slip import STICK, SlippingBeltModel
from .slip_run import _joined, _shared_phases, rerun_simulator
from .stability import check_step
from .stepper import shared_plant

#: the smallest step [s] a scene accepts (``scene.RANGES``): a step the guard names is one a scene can state
MIN_STEP = RANGES["dt"][0]


def scene_takes(h: float, duration: float) -> bool:
    """Whether a scene takes the step ``h`` [s] for a run of ``duration`` [s]: ``h >=`` :data:`MIN_STEP` and at most
    ``scene.MAX_STEPS`` steps (``duration / h``). The guards' searches (halvings, ``method: auto``'s substeps) try
    and name no other step."""
    return h >= MIN_STEP and duration / h <= MAX_STEPS


@dataclass(frozen=True)
class AccuracyReport:
    """Outcome of :func:`check_accuracy`.

    Attributes
    ----------
    method, dt : method and step [s] checked.
    stable : growth of the method's closed-loop map within that of the exact map.
    accurate : estimated error <= tolerance.
    error : estimated relative error of drive speed and belt torque [-] (inf: unstable or not converging).
    tolerance : the tolerance checked [-].
    growth, exact_growth : spectral radius per step of the method's and the exact closed-loop map [-].
    h_omega : dt times the fastest closed-loop eigenvalue's modulus [-].
    slopes : (d drive / d omega_M, d load / d omega_3) of the worst probe [N m s/rad].
    suggestion : a step [s] that is both stable and accurate for this method (None: not searched or none found);
        when ``suggestion_checked`` is False it is extrapolated from the slipping run's own error (not yet run).
    alternative : (method, step [s]) of another method that is both at a larger step, or None.
    searched : the smallest step [s] of this method the search for ``suggestion`` tried (None: ``dt / 2^16``).
    """

    method: str
    dt: float
    stable: bool
    accurate: bool
    error: float
    tolerance: float
    growth: float
    exact_growth: float
    h_omega: float
    slopes: tuple
    suggestion: float | None = None
    alternative: tuple | None = None
    linear_error: float = math.nan
    forcing_error: float = math.nan
    mode: str = ""
    slip_run_error: float = math.nan
    harmonic_error: float = math.nan
    suggestion_checked: bool = True
    searched: float | None = None
    #: the belt force's largest excursion past the capstan limit between two samples, relative to its peak
    #: (:func:`between_samples`), and its time [s]; nan: none
    between: float = math.nan
    between_time: float = math.nan

    @property
    def ok(self) -> bool:
        return self.stable and self.accurate

    @property
    def searched_to(self) -> float:
        """The smallest step [s] of this method found not to work: :attr:`searched`, else ``dt / 2^16`` (the
        search's depth), never below :data:`MIN_STEP` (a scene takes no shorter step)."""
        return self.searched if self.searched is not None else max(self.dt / 2.0**MAX_HALVINGS, MIN_STEP)

    def describe(self) -> str:
        """One line for logs and errors."""
        state = "UNSTABLE" if not self.stable else ("accurate" if self.accurate else "INACCURATE")
        if not self.stable and self.growth == math.inf and not getattr(method_class(self.method), "explicit", True):
            # an implicit method's maps are inf only where its stage's iteration failed (_maps_of): not instability
            state = ("NOT CONVERGED (the implicit stage's fixed-point iteration for the state-dependent torque does not "
                     "converge at this step: raise max_iter, loosen tol or reduce dt; ")
        else:
            state += " ("
        where = f" ({self.mode} mode)" if self.mode else ""
        line = (
            f"{self.method} at dt={self.dt:.4g} s on the closed loop{where}: {state}estimated error {self.error:.2g} "
            f"of the peak, tolerance {self.tolerance:.2g}; growth/step {self.growth:.6g} vs exact "
            f"{self.exact_growth:.6g}; belt mode and slopes {self.linear_error:.2g}, forcing {self.forcing_error:.2g}; "
            + (f"harmonics over the run {self.harmonic_error:.2g}; " if not math.isnan(self.harmonic_error) else "")
            + (f"slipping run {self.slip_run_error:.2g}; " if not math.isnan(self.slip_run_error) else "")
            + f"h*omega={self.h_omega:.4g}; torque slopes {self.slopes[0]:.3g}, "
            f"{self.slopes[1]:.3g} N m s/rad)"
        )
        unchecked = self.suggestion is not None and not self.suggestion_checked
        if not math.isnan(self.between):
            line += (f"; the belt force passes the capstan limit between two samples by {self.between:.2g} of its "
                     f"peak near t = {self.between_time:.4g} s, unseen by the check at the step ends (a step that "
                     "resolves the belt mode, h omega_n <= 1, sees it"
                     + (f": dt = {self.suggestion:.3g} s, not yet run; `method: auto` runs it)" if unchecked else ")"))
        if unchecked:
            if math.isnan(self.between):
                line += (f"; dt = {self.suggestion:.3g} s would meet it by the slipping run's own error at first "
                         "order (extrapolated, not yet run: run it to check; `method: auto` does so by itself)")
        elif self.suggestion is not None:
            line += f"; dt = {self.suggestion:.3g} s is stable and accurate"
        elif not self.ok:
            line += f"; no step of {self.method} down to {self.searched_to:.2g} s is stable and accurate"
        if self.alternative is not None:
            other = f"{self.alternative[0]} at dt = {self.alternative[1]:.3g} s"
            line += f"; so is {other}" if self.suggestion is not None else f"; {other} is stable and accurate"
        return line


def check_accuracy(
    plant, method: str, dt: float, duration: float, x0, tolerance: float = ACCURACY_TOLERANCE,
    method_options=None, suggest: bool = True, probes: Probes | None = None, stepper=None, stated_inputs: bool = True,
    head=None,
) -> AccuracyReport | None:  # fmt: skip
    """Stability and accuracy of ``method`` at ``dt`` [s] on the plant's closed loop.

    The estimated error is the larger of the linearized closed loop's step response error (:func:`linear_verdicts`:
    the belt mode and the torques' speed slopes over the whole duration) and the a-posteriori error on the real
    torques in short windows (:func:`forcing_error`: their variation in time and angle). Returns None for adaptive
    methods (they control their own error). ``suggest``: when the step fails, search halvings of it for one that is
    both (each candidate checked with ``suggest=False``, so the search never searches again). ``probes``: a
    :func:`probe_scene` of this plant already made; ``stepper``: a Stepper of this plant, method and dt to reuse for
    the windows' ``dt`` runs; ``head``: the run itself, called once the step is found stable
    (:func:`~belt_drive_ros.core.accuracy_windows.window_errors`).
    """
    cls = method_class(method)
    if not issubclass(cls, FixedStepIntegrator):
        return None
    model = plant.model
    A, B = model.A, model.B
    rows = _output_rows(model)[0]
    if not rows[1].any():  # rigid: the belt torque is C x + D u; its x part alone carries the dynamics
        rows = rows[:1]
    n_steps = max(1, math.ceil(duration / dt - 1e-9))
    if probes is None:
        probes = probe_scene(plant, duration, x0, dt, stated_inputs)
    integrator = stepper.integrator if stepper is not None else make_integrator(method, A, B, dt, **dict(method_options or {}))
    worst, harmonic = None, 0.0  # worst: (stable, error, growth, exact growth, h omega, slopes) of a probe's loop
    verdicts = linear_verdicts(integrator, A, B, rows, [K for K, _ in probes.gains], n_steps)
    for (K, slopes), (stable, error, growth, exact_growth, h_omega) in zip(probes.gains, verdicts):
        error *= probes.input_weight  # the scene's own steps onto the belt, not a unit step (input_weight)
        if worst is None or (not stable and worst[0]) or (stable == worst[0] and error > worst[1]):
            worst = (stable, error, growth, exact_growth, h_omega, slopes)
        if stable:  # periodic torques over the whole run on this closed loop (forced_response)
            harmonic = max(harmonic, harmonic_error(integrator, A, B, rows, K, n_steps, probes.harmonics,
                                                    probes.peaks[: rows.shape[0]]))  # fmt: skip
    stable, linear, growth, exact_growth, h_omega, slopes = worst
    forcing = forcing_error(plant, method, dt, probes, method_options, stepper, head) if stable else math.nan
    # a NaN term (an estimate that failed to come out) is no verdict of accurate: the error is then unknown, inf
    error = (math.inf if any(v != v for v in (linear, forcing, harmonic)) else max(linear, forcing, harmonic)) \
        if stable else linear
    worst = AccuracyReport(cls.name, dt, stable, error <= tolerance, error, tolerance, growth, exact_growth, h_omega,
                           slopes, linear_error=linear, forcing_error=forcing,
                           harmonic_error=harmonic if stable else math.nan)  # fmt: skip
    if suggest and not worst.ok:
        found = _largest_ok(plant, method, dt, duration, x0, tolerance, method_options, range(1, MAX_HALVINGS + 1), probes,
                            stated_inputs)
        alternative = None
        if found is None or found < dt / 2.0**ALTERNATIVE_HALVINGS:  # this method needs a tiny step: name another too
            for other in ALTERNATIVES:
                if other != cls.name:
                    h = _largest_ok(plant, other, dt, duration, x0, tolerance, None, range(0, MAX_HALVINGS + 1), probes,
                                    stated_inputs)
                    if h is not None and (found is None or h > found):
                        alternative = (other, h)
                        break
        searched = min(_halvings(dt, range(MAX_HALVINGS + 1), duration), default=dt)
        worst = AccuracyReport(**{**worst.__dict__, "suggestion": found, "alternative": alternative, "searched": searched})
    return worst


def _halvings(dt: float, exponents, duration: float) -> list:
    """The steps ``dt / 2^j`` [s] (``j`` in ``exponents``, increasing) a scene takes for a run of ``duration`` [s]
    (:func:`scene_takes`): the candidates every search of the guard tries."""
    return [dt / 2.0**j for j in exponents if scene_takes(dt / 2.0**j, duration)]


def _largest_ok(plant, method, dt, duration, x0, tolerance, method_options, exponents, probes,
                stated_inputs: bool = True) -> float | None:  # fmt: skip
    """Largest step dt / 2^j (j in ``exponents``, increasing) at which ``method`` is stable and accurate, or None.

    Each candidate is checked with ``suggest=False``: the search never searches again. The windows of the
    forcing check start where ``probes`` says (their length follows the candidate step). A candidate the
    stability guard (free belt) refuses is skipped: a step named is accepted by both guards. The search stops
    where a scene stops taking the step (:func:`scene_takes`: below :data:`MIN_STEP`, or beyond ``scene.MAX_STEPS``
    steps over ``duration``). A candidate that passes is checked once more on the probes a run at that step makes
    (the forcing windows placed for it: before breakpoints on its own grid), so the step named passes the check its
    run makes (etd4 at 0.2 ms, named on the 0.4 ms probes, was then rated 6e-6 against 1e-6 by its own run); one
    that fails it is passed over.
    """
    for h in _halvings(dt, exponents, duration):
        if not check_step(plant.model.A, plant.model.B, method, h).stable:  # the stability guard's view too
            continue
        report = check_accuracy(plant, method, h, duration, x0, tolerance, method_options, suggest=False, probes=probes)
        if not (report.stable and report.error <= SUGGEST_MARGIN * tolerance):
            continue
        own = check_accuracy(plant, method, h, duration, x0, tolerance, method_options, suggest=False,
                             stated_inputs=stated_inputs)  # (its own probes: as its run makes them)
        if own.stable and own.error <= tolerance:
            return h
    return None


def require_accurate(plant, method, dt, duration, x0, tolerance=ACCURACY_TOLERANCE, method_options=None, stepper=None,
                     stated_inputs=True, probes=None, head=None):  # fmt: skip
    """:func:`check_accuracy`; raises :class:`UnstableStepError` (naming a stable, accurate step) when unstable.

    An inaccurate but stable step is returned (``report.accurate`` False): the caller warns.
    ``probes``, ``head``: see :func:`check_accuracy`.
    """
    return _refuse_unstable(check_accuracy(plant, method, dt, duration, x0, tolerance, method_options, stepper=stepper,
                                           stated_inputs=stated_inputs, probes=probes, head=head))  # fmt: skip


def _refuse_unstable(report):
    """``report``, raising :class:`UnstableStepError` with its line when it is unstable."""
    if report is not None and not report.stable:
        raise UnstableStepError(report.describe())
    return report


def check_slipping(
    params, drive, load, method: str, dt: float, duration: float, x0_flexible, tolerance: float = ACCURACY_TOLERANCE,
    method_options=None, stepper=None, suggest: bool = True, stick: AccuracyReport | None = None,
    stated_inputs: bool = True, probes: Probes | None = None,
) -> AccuracyReport | None:  # fmt: skip
    """The guard for a run on the slipping model: each mode linearized, the worse verdict counts.

    * **stick**: the belt holds; the flexible model with the scene's torques
      (:func:`check_accuracy`: closed loop and forcing windows), named
      ``stick`` in the report;
    * **slip** (each direction sigma = +/-1): ``A_slip`` with the friction force an input
      ``Q = sigma Q_max(omega_M)`` (belt mass makes ``Q_max`` grow with speed: its slope is a feedback on omega_M
      beside the torques' slopes), ``A_cl = A_slip + B_slip K``; the method's map against the exact one
      (:func:`linear_verdicts`; unit steps of drive, load and Q; signals drive and wheel-3 speed). The slip mode
      carries the elastic creep ``theta_e' = -(k / c) theta_e + ...``: a fast real mode explicit methods must resolve.

    ``stepper``: the flexible-model stepper of the run (its integrator is reused); ``stick``, ``probes``: the
    flexible model's report and :func:`probe_scene` at this step, when already made.
    """
    cls = method_class(method)
    if not issubclass(cls, FixedStepIntegrator):
        return None
    plant = shared_plant(make_model("flexible", params), drive, load)  # the run's own (read-only)
    if probes is None:
        probes = probe_scene(plant, duration, x0_flexible, dt, stated_inputs)
    if stick is None:
        stick = check_accuracy(plant, method, dt, duration, x0_flexible, tolerance, method_options, suggest=False,
                               probes=probes, stepper=stepper)  # fmt: skip
    stick = AccuracyReport(**{**stick.__dict__, "mode": "stick", "suggestion": None, "alternative": None})
    model = _shared_phases(params, drive, load, plant)["model"]  # the run's slipping model (read-only)
    A, B = model.A_slip, model.B_slip
    integrator = make_integrator(method, A, B, dt, **dict(method_options or {}))
    rows = np.zeros((2, 5))
    rows[0, 2] = rows[1, 3] = 1.0  # omega_M, omega_3
    n_steps = max(1, math.ceil(duration / dt - 1e-9))
    worst = stick
    gains = []  # (slopes, K) of each probe and slip direction, their verdicts made together (linear_verdicts)
    # the slope of Q_max at the top speed: the same for every probe (sigma its sign)
    w = max(abs(float(plant.wheel_map[1] @ probes.x0)), *(abs(w_) for _, _, w_, _ in probes.windows), 1.0)
    d = 1e-6 * w
    rise = model.limit(w + d) - model.limit(w - d)
    for _, slopes in probes.gains:
        for sigma in (1.0, -1.0):
            K = np.zeros((3, 5))
            K[0, 2], K[1, 3] = slopes
            K[2, 2] = sigma * rise / (2.0 * d)
            gains.append((slopes, K))
    verdicts = linear_verdicts(integrator, A, B, rows, [K for _, K in gains], n_steps)
    creep = _creep_error(integrator, model, w)
    for (slopes, _), (stable, error, growth, exact_growth, h_omega) in zip(gains, verdicts):
        error = max(error, creep) if stable else error
        report = AccuracyReport(cls.name, dt, stable, error <= tolerance, error, tolerance, growth, exact_growth,
                                h_omega, slopes, linear_error=error, mode="slip")  # fmt: skip
        if (not report.stable and worst.stable) or (report.stable == worst.stable and report.error > worst.error):
            worst = report
    if suggest and not worst.ok:  # a step of this method that passes in both modes, else another method's
        steps = _halvings(dt, range(ALTERNATIVE_HALVINGS + 1), duration)  # (a scene's steps only)
        searched = min(steps, default=dt)
        for h in steps[1:]:
            other = check_slipping(params, drive, load, method, h, duration, x0_flexible, tolerance * SUGGEST_MARGIN,
                                   method_options, suggest=False, stated_inputs=stated_inputs)  # fmt: skip
            if other.ok:
                return AccuracyReport(**{**worst.__dict__, "suggestion": h})
        for h in steps:  # another method, at this step or a few halvings below
            for name in ALTERNATIVES:
                if name != cls.name:
                    other = check_slipping(params, drive, load, name, h, duration, x0_flexible, tolerance * SUGGEST_MARGIN,
                                           suggest=False, stated_inputs=stated_inputs)  # fmt: skip
                    if other.ok:
                        return AccuracyReport(**{**worst.__dict__, "alternative": (name, h), "searched": searched})
        return AccuracyReport(**{**worst.__dict__, "searched": searched})
    return worst


def _creep_error(integrator, model: SlippingBeltModel, w: float) -> float:
    """The slip speed's error [-] from the method's equilibrium of the elastic creep, relative to the belt speed
    ``r_2 g w`` at the top drive speed ``w`` [rad/s]; 0.0 without belt mass.

    In slip (``c > 0``) the span element creeps, ``theta_e' = -(k / c) theta_e + Q / (2 c r_3)``, a fast real mode
    driven by the friction force ``Q = sigma Q_max(omega_M)``, and the slip speed reads it,
    ``s' = v_rel + (k r_3 / c) theta_e - Q / (2 c)``: an error ``d`` of ``theta_e`` is ``(k r_3 / c) d`` of ``s'``,
    which decides the re-stick. With belt mass ``Q`` is an input evaluated at each stage (without it a constant,
    stepped exactly as the plant's affine term). A method that keeps equilibria (every Runge-Kutta, the ETD methods,
    ``exact``) holds ``theta_e`` at ``Q / (2 k r_3)`` under a held ``Q``; an integrating-factor (Lawson) one does
    not once ``h k / c`` is large: its fixed point ``G / (1 - Phi)`` of the creep's one-step map is off by
    ``S(h lambda) / phi_1(h lambda) - 1`` (lawson5: 0.5 % at ``h k / c = 5``, 190 % at 25, where ``bsg_start`` at
    1 ms slid on for the whole run). That equilibrium error at ``Q_max(w)``, as the slip speed's, is the term."""
    params = model.params
    if params.belt_mass <= 0.0 or params.c <= 0.0:
        return 0.0
    step = integrator.linear_step()
    gain = float(sum(G[1, 2] for G in step.gains))
    a, b = float(model.A_slip[1, 1]), float(model.B_slip[1, 2])
    held = gain / (1.0 - float(step.Phi[1, 1])) if step.Phi[1, 1] != 1.0 else math.inf
    speed = abs(float(model.rel_row[2]) * w)
    if speed <= 0.0:
        return 0.0
    return abs(float(model.A_slip[4, 1]) * (held - (-b / a)) * float(model.limit(w))) / speed


def require_accurate_slipping(params, drive, load, method, dt, duration, x0_flexible, tolerance=ACCURACY_TOLERANCE,
                              method_options=None, stepper=None, stick=None, stated_inputs=True, probes=None):  # fmt: skip
    """:func:`check_slipping`; raises :class:`UnstableStepError` when either mode is unstable."""
    return _refuse_unstable(check_slipping(params, drive, load, method, dt, duration, x0_flexible, tolerance,
                                           method_options, stepper, stick=stick, stated_inputs=stated_inputs, probes=probes))



def slip_run_error(params, drive, load, method: str, dt: float, time, states, modes, sigmas, event_times,
                   method_options=None, hybrid=None, signals=None) -> float:  # fmt: skip
    """A posteriori error [-] of a slipping run at ``dt`` over its slipping stretch, by Richardson on the run itself.

    The linearized checks of :func:`check_slipping` see each mode alone, not
    what happens where the modes meet (located events, the force jumping to
    ``sigma Q_max``) nor how the error of each slip phase accumulates over
    many (``truck_compressor`` at etd4, 1 ms: from 6e-5 to 2.4e-4 of the
    belt-torque peak across 112 events; windows about single events read
    5e-5). So the stretch from a window (:data:`WINDOW_STEPS` steps) before
    the first event to one after the last is run again from the run's own
    state at ``2 dt``; for a method of order p the ``dt`` run's error is
    ``|y_dt - y_2dt| / (2^p - 1)`` (the ``2 dt`` run diverges: at ``dt / 2``,
    ``|y_dt - y_dt/2| 2^p / (2^p - 1)``). Signals: drive speed and belt
    torque at the common grid times, relative to their peaks over the run
    (``time``, ``states``, ``modes``, ``sigmas``: the run's samples;
    ``signals``: its (drive speed, belt torque) when made). No events: 0;
    both reruns diverge: inf. ``hybrid``: the run's
    :class:`~belt_drive_ros.core.slip.EventStep` (no step length: the reruns share it).
    """
    order = method_class(method).order
    if not len(event_times) or order is None:
        return 0.0
    span = WINDOW_STEPS * dt
    k0 = 2 * max(0, math.floor((float(min(event_times)) - span) / (2.0 * dt)))  # on both grids
    t0 = k0 * dt
    t1 = min(float(max(event_times)) + span, float(time[-1]))
    i = int(np.searchsorted(time, t0 + 1e-9 * dt, side="right")) - 1  # the run's last sample at t0
    if i < 0 or abs(time[i] - t0) > 1e-9 * dt or t1 <= t0 + dt:
        return 0.0
    model, r3 = hybrid.model if hybrid is not None else SlippingBeltModel(params), params.r_3
    if signals is None:
        signals = states[:, 2], r3 * model.force(states, modes, sigmas)
    peak = [float(np.max(np.abs(v))) for v in signals]  # over the run
    j = int(np.searchsorted(time, t1 + dt, side="right"))  # the run's samples the reruns can meet (one past t1)
    run_t, run_out = time[i:j], [v[i:j] for v in signals]
    # the reruns stop at their last grid step before t1 unless the run has a sample at t1 (a partial step meets none)
    n = int(run_t.searchsorted(t1))  # |t - t1| is least at the samples either side of t1 (run_t is sorted)
    at_t1 = bool(np.any(np.abs(run_t[max(n - 1, 0) : n + 1] - t1) <= 1e-9 * dt + 8.0 * np.spacing(abs(t1) + dt)))
    for h, factor in ((2.0 * dt, 1.0 / (2.0**order - 1.0)), (dt / 2.0, 2.0**order / (2.0**order - 1.0))):
        sim = rerun_simulator(params, drive, load, method, h, method_options)  # (kept per scene, step and thread)
        sim._hybrid = hybrid
        sim.slip_phases()  # (the stretch slips; the scene's steppers, shared)
        state = sim._native(np.asarray(states[i], dtype=float), int(modes[i]), float(sigmas[i]))
        pieces = [(np.array([t0]), sim.state_y(state)[None, :], state.mode, state.sigma)]
        end = t1 if at_t1 or sim.stepper._snap(t1) is not None else max(t0, sim.grid_time(math.floor(t1 / h)))
        try:
            with np.errstate(all="ignore"):
                sim.advance(state, t0, end, pieces)  # its events are the run's again: not collected
        except (SimulationDivergedError, IntegratorError):
            continue
        tr, yr, mr, sr = _joined(pieces)
        out = [yr[:, 2], r3 * model.force(yr, mr, sr)]
        if not all(np.all(np.isfinite(v)) for v in out):
            continue
        coarse, fine = (run_out, out) if h > dt else (out, run_out)
        lo, hi = (run_t, tr) if h > dt else (tr, run_t)  # match the coarser run's grid times in the finer one
        idx = np.clip(np.searchsorted(hi, lo - 1e-9 * dt), 0, hi.size - 1)
        same = (np.abs(hi[idx] - lo) <= 1e-9 * dt + 8.0 * np.spacing(np.abs(lo) + dt)) & (lo >= t0) & (lo <= t1)
        at = idx[same]
        return max((factor * float(np.max(np.abs(a[same] - b[at]))) / p if p > 0 else 0.0)
                   for a, b, p in zip(coarse, fine, peak))  # fmt: skip
    return math.inf


#: points inside each step at which :func:`between_samples` evaluates its cubic (fractions of the step)
_BETWEEN = np.linspace(0.0, 1.0, 11)[1:-1]


def between_samples(model: SlippingBeltModel, time, states, modes, u) -> tuple[float, float]:
    """``(excess, t)``: the largest excursion of the belt force past the capstan limit between two samples of a
    stick stretch that neither sample shows, relative to the run's peak force, and its time [s]; ``(0.0, nan)``
    without one.

    The capstan check reads ``g = |Q| - Q_max(omega_M)`` at the step ends only, so an excursion that starts and
    ends inside one step is not seen (a step of ``h omega_n = 2.3`` missed a 17 % excursion of a belt ringing after
    a torque step, and the run slipped 0.1 s late, rated accurate). Between two stick samples ``g`` is taken as the
    cubic through its values and slopes at both ends (Hermite; ``g' = sign(Q) q . y' - Q_max'(omega_M) omega_M'``
    with ``y' = A y + B u`` of the stick mode, ``u`` the torques at the samples): exact to ``(h omega_n)^4 / 384`` of
    the swing, so at a step that resolves the belt mode it finds only what the run really missed.
    ``states`` (N, 5), ``modes`` (N,), ``u`` (N, 2) of the run's samples ``time`` [s]."""
    y = np.asarray(states, dtype=float)
    t = np.asarray(time, dtype=float)
    if y.shape[0] < 2:
        return 0.0, math.nan
    stick = np.asarray(modes) == STICK
    both = stick[:-1] & stick[1:]
    if not np.any(both):
        return 0.0, math.nan
    Q = y @ model.q_row
    w = y[:, 2]
    qmax = model.limit(w)
    g = np.abs(Q) - qmax
    ends = both & (g[:-1] < 0.0) & (g[1:] < 0.0)  # (a sample past the limit is the run's own event)
    if not np.any(ends):
        return 0.0, math.nan
    A, B, q = model.A_stick, model.B_stick, model.q_row
    dQ = y @ (A.T @ q) + u @ (B.T @ q)  # q . y', y' = A y + B u
    dg = np.sign(Q) * dQ
    quad = model.guard(STICK).quad  # Q_max = F_0 f - quad omega_M^2 while positive (belt mass)
    if quad:  # Q_max falls with speed: - Q_max'(omega_M) omega_M' = 2 quad omega_M omega_M'
        dg += np.where(qmax > 0.0, 2.0 * quad * w, 0.0) * (y @ A[2] + u @ B[2])
    # a cubic with these end values and slopes stays below max(g_0, g_1) + (4/27) h (|g_0'| + |g_1'|) (the slope
    # basis functions peak at 4/27): only the steps that bound lets past the limit are evaluated
    h_all = t[1:] - t[:-1]
    ends &= np.maximum(g[:-1], g[1:]) + (4.0 / 27.0) * h_all * (np.abs(dg[:-1]) + np.abs(dg[1:])) > 0.0
    if not np.any(ends):
        return 0.0, math.nan
    k = np.flatnonzero(ends)
    h = (t[k + 1] - t[k])[:, None]
    s = _BETWEEN[None, :]
    s2, s3 = s * s, s * s * s
    cubic = ((2 * s3 - 3 * s2 + 1) * g[k, None] + (s3 - 2 * s2 + s) * h * dg[k, None]
             + (-2 * s3 + 3 * s2) * g[k + 1, None] + (s3 - s2) * h * dg[k + 1, None])  # fmt: skip
    peak = np.max(cubic, axis=1)
    j = int(np.argmax(peak))
    if not peak[j] > 0.0:
        return 0.0, math.nan
    scale = float(np.max(np.abs(Q)))
    return (float(peak[j]) / scale if scale > 0.0 else math.inf), float(t[k[j]] + h[j, 0] * _BETWEEN[int(np.argmax(cubic[j]))])


def with_between_samples(report: AccuracyReport, excess: float, when: float, omega_n: float = math.nan) -> AccuracyReport:
    """``report`` with :func:`between_samples`' excursion: it counts as an error of that size (the slip the run
    missed there), and the line says where (``between``, ``between_time``). When it fails the tolerance and the
    belt mode ``omega_n`` [rad/s] is known, the step named is the largest ``dt / 2^j`` with ``h omega_n <= 1`` (not
    yet run: ``suggestion_checked`` False; ``method: auto`` runs it)."""
    if not excess > 0.0:
        return report
    error = max(report.error, excess)
    fields = {**report.__dict__, "error": error, "accurate": error <= report.tolerance, "between": excess,
              "between_time": when}
    if error > report.tolerance and omega_n > 0.0 and report.dt * omega_n > 1.0:
        h = report.dt / 2.0 ** math.ceil(math.log2(report.dt * omega_n))
        if h >= MIN_STEP and (report.suggestion is None or h < report.suggestion):
            fields.update(suggestion=h, suggestion_checked=False)
    return AccuracyReport(**fields)


def with_slip_run_error(report: AccuracyReport, run_error: float) -> AccuracyReport:
    """``report`` (of :func:`check_slipping`) with the slipping run's own a-posteriori error (:func:`slip_run_error`).

    The estimate counts when larger; when it fails the tolerance, the step
    named is the largest ``dt / 2^j`` at which it would fall to
    :data:`SUGGEST_MARGIN` of the tolerance at first order (across stick/slip
    events a run converges at first order in the step: extrapolating at the
    method's order p named steps the run then refused); an extrapolation, not
    a checked step (``suggestion_checked`` False, and the report says so).
    """
    error = max(report.error, run_error)
    fields = {**report.__dict__, "error": error, "accurate": error <= report.tolerance, "slip_run_error": run_error}
    if run_error > report.error:  # the verdict is the hybrid run's, not one mode's
        fields["mode"] = "hybrid"
    if run_error > report.tolerance and math.isfinite(run_error):
        j = max(1, math.ceil(math.log2(run_error / (SUGGEST_MARGIN * report.tolerance))))
        h = report.dt / 2.0**j
        if h >= MIN_STEP and (report.suggestion is None or report.suggestion > h):
            fields["suggestion"], fields["suggestion_checked"] = h, False
    return AccuracyReport(**fields)
