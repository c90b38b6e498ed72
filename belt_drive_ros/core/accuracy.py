"""Accuracy guard beside the stability guard: is a fixed step stable *and* accurate on the closed loop?

The stability guard (:mod:`belt_drive_ros.core.stability`) reads the
method's growth on the free belt, ``x' = A x``. Torques that depend on speed
(a governor, a motor curve, a fan or compressor load ``c_1 omega``) add
their slopes to the loop: linearized about a state, ``u = u_0 + K x`` with
``K = du/dx`` [N m s/rad on the speed columns], the plant is

    x' = A_cl x + B u_0,        A_cl = A + B K.

A load of ``10 omega_3`` on a light wheel 3 is a damping rate of
``10 / I_3`` [1/s] that ``exact`` (which holds the torque over the step)
amplifies instead of damping once ``h 10 / I_3`` passes 2. And methods exact
for the free belt mode need not be exact for the forced response: Lawson
methods integrate ``e^{hA}`` exactly but not the convolution with a held
torque, so their settled deflection under constant torques drifts from the
static value as ``h omega_n`` grows (1.65 of it at 8).

This guard checks both, from the method's own stage scheme (no per-method
formula): the one-step map of the method on the linearized closed loop,
``x+ = M x + G u_0``, is read off :func:`~belt_drive_ros.core.stage_scheme.step`
with the torque ``K x + u_0`` (``n + 2`` calls), and compared with the
exact map of that linear system (the matrix exponential of the augmented
system, ``x+ = E x + F u_0``):

* **stable**: spectral radius of M at most ``max(1, spectral radius of E)``
  (up to rounding);
* **accurate to** ``tolerance``: the step response (a unit drive torque, a
  unit load torque, each switched on at t = 0 from rest; this excites the
  belt mode fully) of drive speed and belt torque, run over the scene's
  duration with M, G against E, F, stays within ``tolerance`` of each
  signal's peak.

That is the error of the method on the belt mode and the torques' slopes.
It is not the error from how fast the torques vary in time (firing
pulsations, recorded profiles): that one falls with the method's order and
is measured per scene (``docs/performance.md``, tests/test_scene_defaults.py).

The slopes are taken by central differences of the torques at speeds and
times along a cheap rigid run of the scene (:data:`N_PROBES` probes); the
worst probe counts. Only speed slopes are used: angle slopes of periodic
torques average out and would read as a spurious stiffness.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from . import stage_scheme as _scheme
from .errors import IntegratorError, UnstableStepError
from .forced_response import ORBIT_SAMPLES, harmonic_error, orbit_error, profile_harmonics
from .integrators import FixedStepIntegrator, make_integrator, method_class
from .model import LINEAR_OUTPUTS, RigidBeltModel

#: default relative tolerance of the guard (speed and belt torque, relative to peak)
ACCURACY_TOLERANCE = 1e-4
#: step-response samples compared (beyond them the horizon is sampled in strides, see step_response_error)
MAX_STEPS = ORBIT_SAMPLES
#: times along the scene at which the torques' slopes are probed
N_PROBES = 5
#: steps of the method in each forcing window (run at dt and dt / 2, Richardson)
WINDOW_STEPS = 48
#: a smaller step (the search for one that works) keeps the window's length up to this many of its steps
MAX_WINDOW_STEPS = 8 * WINDOW_STEPS
#: a step named as working has an estimated error at most this fraction of the tolerance (the estimate's spread)
SUGGEST_MARGIN = 0.25
#: probe windows closer than this in drive speed (relative to the run's top speed) to another: one of them
SPEED_SPREAD = 0.1
#: torque breakpoints inside the run that get a forcing window of their own (the first ones)
MAX_BREAKPOINT_WINDOWS = 4
#: steps per advance of the probes' rigid run (bounds the stepper's plan, so memory does not grow with the duration)
PROBE_CHUNK = 1000
#: growth beyond max(1, exact growth) by this much (relative) is instability, not rounding
GROWTH_TOLERANCE = 1e-9
#: least weight of the step response (perturbations the scene does not state: torques from the node, re-excitation)
MIN_INPUT_WEIGHT = 0.05
#: halvings tried when naming a step that is both stable and accurate
MAX_HALVINGS = 16
#: when the method itself needs more halvings than this, another method is named as well
ALTERNATIVE_HALVINGS = 3
#: methods tried as the alternative, in this order (exact for the belt mode, high order)
ALTERNATIVES = ("etd4", "lawson5", "etd2")


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
    suggestion : a step [s] that is both stable and accurate for this method (None: not searched or none found).
    alternative : (method, step [s]) of another method that is both at a larger step, or None.
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

    @property
    def ok(self) -> bool:
        return self.stable and self.accurate

    def describe(self) -> str:
        """One line for logs and errors."""
        state = "UNSTABLE" if not self.stable else ("accurate" if self.accurate else "INACCURATE")
        where = f" ({self.mode} mode)" if self.mode else ""
        line = (
            f"{self.method} at dt={self.dt:.4g} s on the closed loop{where}: {state} (estimated error {self.error:.2g} "
            f"of the peak, tolerance {self.tolerance:.2g}; growth/step {self.growth:.6g} vs exact "
            f"{self.exact_growth:.6g}; belt mode and slopes {self.linear_error:.2g}, forcing {self.forcing_error:.2g}; "
            + (f"harmonics over the run {self.harmonic_error:.2g}; " if not math.isnan(self.harmonic_error) else "")
            + (f"slipping run {self.slip_run_error:.2g}; " if not math.isnan(self.slip_run_error) else "")
            + f"h*omega={self.h_omega:.4g}; torque slopes {self.slopes[0]:.3g}, "
            f"{self.slopes[1]:.3g} N m s/rad)"
        )
        if self.suggestion is not None:
            line += f"; dt = {self.suggestion:.3g} s is stable and accurate"
        elif not self.ok:
            line += f"; no step down to {self.dt / 2.0**MAX_HALVINGS:.2g} s of this method is"
        if self.alternative is not None:
            other = f"{self.alternative[0]} at dt = {self.alternative[1]:.3g} s"
            line += f"; so is {other}" if self.suggestion is not None else f"; {other} is stable and accurate"
        return line


def speed_slopes(plant, times, speeds_M) -> list[np.ndarray]:
    """(K, (d drive/d omega_M, d load/d omega_3)) per probe: feedback gains K (2, n) from the torques' speed slopes.

    ``plant`` is a :class:`~belt_drive_ros.core.stepper.Plant`; the drive's
    slope acts on omega_M, the load's on omega_3 (rows of the model's
    wheel map), evaluated at (t, phi_M, omega_M) and (t, i phi_M, i omega_M).
    """
    W = plant.wheel_map
    i = plant.model.params.ratio
    gains = []
    for t, w in zip(times, speeds_M):
        slopes = []
        for torque, speed in ((plant.scalar_drive, w), (plant.scalar_load, i * w)):
            d = 1e-6 * max(1.0, abs(speed))
            slopes.append((torque(t, 0.0, speed + d) - torque(t, 0.0, speed - d)) / (2.0 * d))
        gains.append((np.vstack([slopes[0] * W[1], slopes[1] * W[3]]), tuple(slopes)))
    return gains


@dataclass(frozen=True)
class Probes:
    """What the guard reads off a cheap rigid run of the scene (:func:`probe_scene`).

    gains : distinct ``(K, slopes)`` of the torques' speed slopes at the probes (see :func:`speed_slopes`).
    x0 : the scene's initial state (the first forcing window starts there at t = 0).
    windows : further forcing windows as ``(t [s], phi_M [rad], omega_M [rad/s], anchor)``: the rigid run's
        motion at t; ``anchor`` a torque breakpoint [s] the window straddles (None: the window starts at t).
    duration : the scene's duration [s].
    window : length [s] of a forcing window (:data:`WINDOW_STEPS` steps of the step probed with; a smaller
        step keeps it, up to :data:`MAX_WINDOW_STEPS` of its steps).
    input_weight : what the unit step response's error is scaled by for this scene (:func:`input_weight`).
    harmonics : ``(input, frequency [Hz], amplitude [N m])`` the torques excite
        (:func:`~belt_drive_ros.core.forced_response.profile_harmonics`).
    peaks : estimated peaks of drive speed [rad/s] and quasi-static belt torque [N m] at the probes.
    """

    gains: tuple
    x0: np.ndarray
    windows: tuple
    duration: float
    window: float
    input_weight: float = 1.0
    harmonics: tuple = ()
    peaks: tuple = (0.0, 0.0)

    def span(self, dt: float) -> float:
        """Window length [s] for step ``dt``: :attr:`window`, at most :data:`MAX_WINDOW_STEPS` steps."""
        return min(self.window, MAX_WINDOW_STEPS * dt)

    def window_starts(self, plant, dt: float):
        """``(t0, x)`` of every window for step ``dt``: t0 on the grid k dt, x the plant model's state.

        A breakpoint's window starts a quarter window before it; the rigid
        motion is carried there at constant speed; the deflection is the quasi-static one.
        """
        yield 0.0, self.x0
        for t, phi, omega, anchor in self.windows:
            t0 = t if anchor is None else max(0.0, dt * math.floor((anchor - 0.25 * self.span(dt)) / dt))
            if t0 > 0.0:
                yield t0, _model_state(plant, t0, phi + omega * (t0 - t), omega)


def _model_state(plant, t: float, phi: float, omega: float) -> np.ndarray:
    """The plant model's state with the rigid motion (phi_M, omega_M) at time t and the quasi-static deflection."""
    model = plant.model
    if model.A.shape[0] == 2:
        return np.array([phi, omega])
    i = model.params.ratio
    drive = plant.scalar_drive(t, phi, omega)
    load = plant.scalar_load(t, i * phi, i * omega)
    return model.state_from_rigid(np.array([phi, omega]), load_torque=load, drive_torque=drive)


def probe_scene(plant, duration: float, x0, dt: float, stated_inputs: bool = True) -> Probes:
    """Speed slopes at :data:`N_PROBES` times and the forcing windows' starts, from one cheap rigid run.

    Windows start at t = 0 (from ``x0``), at the probe times before the end,
    and about each of the first :data:`MAX_BREAKPOINT_WINDOWS` torque
    breakpoints inside the run (see :meth:`Probes.window_starts`).
    ``stated_inputs``: the plant's torques are all the inputs (the step
    response is weighted by their steps, :func:`input_weight`); False
    (torques from outside, e.g. a node's topic): unit steps, weight 1.
    """
    from .stepper import Plant, Stepper

    x0 = np.asarray(x0, dtype=float)
    wm = plant.wheel_map
    phi0, w0 = float(wm[0] @ x0), float(wm[1] @ x0)
    t_probe = np.linspace(0.0, duration, N_PROBES) if duration > 0 else np.array([0.0])
    inner = [b for b in plant.breakpoints if 0.0 < b < duration][:MAX_BREAKPOINT_WINDOWS]
    early = {b: max(0.0, dt * math.floor((b - 0.25 * WINDOW_STEPS * dt) / dt)) for b in inner}
    plain = [float(t) for t in t_probe[1:] if t < duration - 2.0 * dt]
    stops = sorted(set(plain) | set(early.values()) | {float(t) for t in t_probe})
    rdt = min(duration / 500.0, 5e-3) if duration > 0 else 1e-3
    states = {0.0: (phi0, w0)}
    try:  # advance from stop to stop (memory independent of the duration: runs may stream)
        stepper = Stepper(Plant(RigidBeltModel(plant.model.params), plant.drive, plant.load), "exact", rdt)
        x, t = np.array([phi0, w0]), 0.0
        for t1 in stops:
            # in pieces of PROBE_CHUNK steps: the stepper plans each advance whole
            edges = np.append(np.arange(t, t1, PROBE_CHUNK * rdt), t1)
            for a, b in zip(edges[:-1], edges[1:]):
                x = stepper.advance(x, float(a), float(b))
            states[t1], t = (float(x[0]), float(x[1])), t1
        probe_times = t_probe
    except Exception:  # a rigid estimate that diverges: probe at the start only
        probe_times, plain, early = np.array([0.0]), [], {}
    gains, seen = [], set()
    speeds = [states[float(t)][1] for t in probe_times]
    for K, slopes in speed_slopes(plant, probe_times, speeds):
        key = tuple(float(f"{s:.3g}") for s in slopes)  # slopes equal to 3 digits: the same verdict
        if key not in seen:
            seen.add(key)
            gains.append((K, slopes))
    # a probe window at a speed within SPEED_SPREAD of one already windowed sees the same harmonics: skipped
    kept, scale = [0.0], max(abs(w) for _, w in states.values()) or 1.0
    for t in plain:
        if all(abs(states[t][1] - states[k][1]) > SPEED_SPREAD * scale for k in kept):
            kept.append(t)
    windows = [(t, *states[t], None) for t in kept[1:]] + [(t, *states[t], b) for b, t in early.items()]
    at = [(float(t), *states[float(t)]) for t in probe_times]
    weight = 1.0 if not stated_inputs else input_weight(plant, x0, dt, at, [(b, *states[t]) for b, t in early.items()])
    harmonics = tuple(profile_harmonics(plant, at))
    return Probes(tuple(gains), x0, tuple(windows), float(duration), WINDOW_STEPS * dt, weight, harmonics,
                  _peaks(plant, at))  # fmt: skip


def _peaks(plant, at) -> tuple[float, float]:
    """(max |omega_M| [rad/s], max |quasi-static belt torque| [N m]) over the probes ``(t, phi_M, omega_M)``."""
    p = plant.model.params
    rigid, i = RigidBeltModel(p), p.ratio
    w, tb = 0.0, 0.0
    with np.errstate(all="ignore"):
        for t, phi, omega in at:
            u = np.array([plant.scalar_drive(t, phi, omega), plant.scalar_load(t, i * phi, i * omega)])
            w, tb = max(w, abs(omega)), max(tb, abs(float(rigid.belt_torque(np.array([phi, omega]), u))))
    return (w if math.isfinite(w) else 0.0, tb if math.isfinite(tb) else 0.0)


def input_weight(plant, x0, dt: float, probes, jumps) -> float:
    """Scale [-] of the unit step response's error for this scene: ``min(1, 2 dB / T_peak)``, at least
    :data:`MIN_INPUT_WEIGHT`.

    The step response (:func:`step_response_error`) switches a unit torque
    on at once; its error relative to its own peak (``2`` steps of belt
    torque: the undamped overshoot) becomes, in the scene, that times
    ``2 dB / T_peak``, with ``dB`` [N m] the largest step of belt torque
    the scene's inputs make:

    * at the start, the quasi-static belt torque the torques at t = 0 need
      (rigid model) less what the initial state carries
      (:func:`~belt_drive_ros.core.fidelity.start_mismatch`'s sizes);
    * at each torque breakpoint ``jumps`` ``(b, phi_M, omega_M)``, the jump
      of the rigid belt torque across it;
    * a ramp of the quasi-static belt torque at rate ``R`` [N m/s] (a soft
      start, a motor curve) moves the belt mode by ``R / omega_n``: an
      equivalent step (forward difference over ``dt`` at each probe
      ``(t, phi_M, omega_M)``, the start included).

    ``T_peak``: the largest |quasi-static belt torque| at the probes. Rigid
    model (no belt mode): 1. The floor keeps perturbations the scene does
    not state (a node's torques) rated.
    """
    model = plant.model
    p = model.params
    rigid = RigidBeltModel(p)
    i = p.ratio

    def quasi_static(t, phi, omega):
        u = np.array([plant.scalar_drive(t, phi, omega), plant.scalar_load(t, i * phi, i * omega)])
        return float(rigid.belt_torque(np.array([phi, omega]), u))

    wm = plant.wheel_map
    x0 = np.asarray(x0, dtype=float)
    phi0, w0 = float(wm[0] @ x0), float(wm[1] @ x0)
    rigid_model = model.A.shape[0] == 2
    j = LINEAR_OUTPUTS.index("belt_torque")
    carried = 0.0 if rigid_model else float(model.C[j] @ x0)  # rigid: the torques at t = 0 switch on from none
    steps = [abs(quasi_static(0.0, phi0, w0) - carried)]
    levels = [abs(quasi_static(0.0, phi0, w0))]
    omega_n = 1.0 / dt if rigid_model else p.belt_natural_frequency  # rigid: a ramp held over a step is a step R dt
    with np.errstate(all="ignore"):
        for t, phi, omega in probes:
            here = quasi_static(t, phi, omega)
            levels.append(abs(here))
            steps.append(abs(quasi_static(t + dt, phi, omega) - here) / dt / omega_n)
        for b, phi, omega in jumps:
            eps = 1e-6 * dt
            before, after = quasi_static(b - eps, phi, omega), quasi_static(b + eps, phi, omega)
            levels += [abs(before), abs(after)]
            steps.append(abs(after - before))
    peak, step = max(levels), max(steps)
    if not (math.isfinite(peak) and math.isfinite(step)) or peak <= 0.0:
        return 1.0
    return float(min(1.0, max(MIN_INPUT_WEIGHT, 2.0 * step / peak)))


def closed_loop_maps(integrator, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, G): the method's step on x' = A x + B (K x + u_0) is ``x+ = M x + G u_0`` (from its stage scheme)."""
    n = integrator.A.shape[0]
    scheme, h = integrator.scheme, integrator.dt

    def run(x, u0):
        return _scheme.step(scheme, h, 0.0, x, lambda t, y: K @ y + u0, integrator.name)

    m = K.shape[0]
    if not scheme.implicit:  # affine in (x, u_0): every unit column in one call, as a matrix
        MG = run(np.eye(n, n + m), np.eye(m, n + m, n))
        return MG[:, :n], MG[:, n:]
    zero_u = np.zeros(m)
    M = np.column_stack([run(e, zero_u) for e in np.eye(n)])
    G = np.column_stack([run(np.zeros(n), e) for e in np.eye(m)])
    return M, G


def exact_maps(A_cl: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(E, F): the exact step of x' = A_cl x + B u_0 with constant u_0 (augmented matrix exponential)."""
    n, m = B.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n], aug[:n, n:] = A_cl, B
    expo = scipy.linalg.expm(aug * h)
    return expo[:n, :n], expo[:n, n:]


def _spectral_radius(M: np.ndarray) -> float:
    mu = np.linalg.eigvals(M)
    mu = np.where(np.abs(mu - 1.0) <= 1e-6, 1.0, mu)  # rigid-body Jordan block at 1: 1 +/- sqrt(eps)
    return float(np.max(np.abs(mu)))


def step_response_error(M, G, E, F, rows: np.ndarray, n_steps: int) -> float:
    """Max over unit inputs and output rows of max_k |y_k - y*_k| / max_k |y*_k|, k = 1 .. ``n_steps``.

    From rest with a unit drive and a unit load torque (two columns at
    once), ``X_{k+1} = M X_k + G`` against ``Z_{k+1} = E Z_k + F``. The
    first :data:`MAX_STEPS` / 2 steps are taken one by one; the rest, when
    there are more, in strides of ``s`` steps with the s-th powers of the
    augmented maps (exact, only samples between strides are skipped). Both
    recurrences are evaluated at once by doubling (:func:`~belt_drive_ros.core.forced_response.orbit_error`).
    """
    n, m = G.shape
    Ma = np.block([[M, G], [np.zeros((m, n)), np.eye(m)]])
    Ea = np.block([[E, F], [np.zeros((m, n)), np.eye(m)]])
    err, peak = orbit_error(Ma, Ea, n, rows, n_steps)
    if not np.all(np.isfinite(err)):
        return math.inf
    # a unit input that does not move an output at all (peak 0) carries no error either
    return float(np.max(np.where(peak > 0, err / np.where(peak > 0, peak, 1.0), 0.0)))


def _output_rows(model) -> tuple[np.ndarray, np.ndarray]:
    """(C rows, D rows) of drive speed and belt torque (the guard's two signals)."""
    j = [LINEAR_OUTPUTS.index("omega_M"), LINEAR_OUTPUTS.index("belt_torque")]
    return model.C[j], model.D[j]


#: the linear (belt mode and slopes) verdicts already computed: key -> (stable, error, growth, exact growth, h omega)
_LINEAR_CACHE: dict = {}
_LINEAR_CACHE_SIZE = 512


def linear_verdict(integrator, A, B, rows, K, n_steps: int) -> tuple:
    """(stable, error, growth, exact growth, h omega) of the method's closed-loop map ``A + B K`` (cached).

    The key is every number the verdict depends on (matrices, method and its
    options through the integrator's one-step map, step, gains, horizon), so a
    hit is the same computation.
    """
    dt = integrator.dt
    key = (integrator.name, dt, A.tobytes(), B.tobytes(), rows.tobytes(), K.tobytes(), n_steps,
           repr(sorted(getattr(integrator, "options", {}).items())))  # fmt: skip
    hit = _LINEAR_CACHE.get(key)
    if hit is not None:
        return hit
    A_cl = A + B @ K
    E, F = exact_maps(A_cl, B, dt)
    try:
        M, G = closed_loop_maps(integrator, K)
    except IntegratorError:
        M, G = np.full_like(E, np.inf), np.full_like(F, np.inf)
    growth = _spectral_radius(M) if np.all(np.isfinite(M)) else math.inf
    exact_growth = _spectral_radius(E)
    stable = growth <= max(1.0, exact_growth) * (1.0 + GROWTH_TOLERANCE) + 1e-15
    error = step_response_error(M, G, E, F, rows, n_steps) if stable else math.inf
    verdict = (stable, error, growth, exact_growth, dt * float(np.max(np.abs(np.linalg.eigvals(A_cl)))))
    if len(_LINEAR_CACHE) >= _LINEAR_CACHE_SIZE:
        _LINEAR_CACHE.pop(next(iter(_LINEAR_CACHE)))
    _LINEAR_CACHE[key] = verdict
    return verdict


def forcing_error(plant, method: str, dt: float, probes: Probes, method_options=None, stepper=None) -> float:
    """A posteriori error [-] of the method at ``dt`` on the scene's real torques (time, angle, speed), by Richardson.

    Each window of :data:`WINDOW_STEPS` steps (``probes.windows``) is run at
    ``dt`` and at ``dt / 2`` from the same state; for a method of order p
    the error of the ``dt`` run is ``|y_dt - y_dt/2| 2^p / (2^p - 1)``.
    Signals: drive speed and belt torque, each relative to its peak over all
    windows' ``dt / 2`` runs; the worst signal and window counts. This sees
    what the linearization does not: firing and compressor harmonics in
    crank angle, schedules, profiles (their bandwidth at the operating speed
    against the step). A run that diverges: inf.
    """
    windows = window_errors(plant, method, dt, probes, method_options, stepper)
    if windows is None:
        return math.inf
    err = np.max([e for _, e, _ in windows], axis=0)
    peak = np.max([p for _, _, p in windows], axis=0)
    return float(np.max(np.where(peak > 0, err / np.where(peak > 0, peak, 1.0), 0.0)))


#: integrators of the windows' half steps, by (method, step, options, A, B): built once (their stage schemes cost expm)
_INTEGRATORS: dict = {}


def _integrator(model, method: str, dt: float, method_options=None):
    """``make_integrator`` for ``model``'s A, B, cached (up to 64)."""
    options = dict(method_options or {})
    key = (method, dt, repr(sorted(options.items())), model.A.tobytes(), model.B.tobytes(), model.A.shape)
    hit = _INTEGRATORS.get(key)
    if hit is None:
        if len(_INTEGRATORS) >= 64:
            _INTEGRATORS.pop(next(iter(_INTEGRATORS)))
        hit = _INTEGRATORS[key] = make_integrator(method, model.A, model.B, dt, **options)
    return hit


def window_errors(plant, method: str, dt: float, probes: Probes, method_options=None, stepper=None) -> list | None:
    """``[(t0, Richardson error (2,), peak (2,))]`` per forcing window (see :func:`forcing_error`); None: diverged."""
    from .errors import SimulationDivergedError
    from .stepper import Stepper

    order = method_class(method).order or 1
    factor = 2.0**order / (2.0**order - 1.0)
    C, D = _output_rows(plant.model)
    coarse = stepper or Stepper(plant, method, dt, method_options)
    fine = Stepper(plant, method, dt / 2.0, method_options, integrator=_integrator(plant.model, method, dt / 2.0, method_options))
    out = []
    for t0, x in probes.window_starts(plant, dt):
        t1 = min(t0 + probes.span(dt), probes.duration)
        if t1 <= t0 + 0.5 * dt:
            continue
        try:
            tc, xc = coarse.run(x, t0, t1, vectorize=False)
            tf, xf = fine.run(x, t0, t1, vectorize=False)
        except (SimulationDivergedError, IntegratorError):  # diverged, or an implicit stage did not converge
            return None
        idx = np.clip(np.searchsorted(tf, tc - 1e-9 * dt), 0, tf.size - 1)
        same = np.abs(tf[idx] - tc) <= 1e-9 * dt + 8.0 * np.spacing(np.abs(tc) + dt)
        tc, xc, tf, xf = tc[same], xc[same], tf[idx[same]], xf[idx[same]]
        yc = xc @ C.T + plant.input_array(tc, xc) @ D.T
        yf = xf @ C.T + plant.input_array(tf, xf) @ D.T
        if not (np.all(np.isfinite(yc)) and np.all(np.isfinite(yf))):
            return None
        err = factor * np.max(np.abs(yc - yf), axis=0)
        if any(plant.uses_angle) and tf.size > 1:
            err = np.maximum(err, _phase_drift(plant, xc, xf, tf, yf, factor, _drift_time(plant, probes)))
        out.append((t0, err, np.max(np.abs(yf), axis=0)))
    return out


def _drift_time(plant, probes) -> float:
    """How long [s] a speed error lasts, at most the run: ``1 / |Re lambda|`` of the slowest decaying closed-loop mode.

    The angle integrates the speed error for as long as it lasts: a governor
    or a speed-dependent load (``A + B K``, the probes' slopes) damps it in
    ``~1 / (K / I)``; without one it lasts the whole run.
    """
    A, B = plant.model.A, plant.model.B
    longest = 0.0
    for K, _ in probes.gains:
        lams = np.linalg.eigvals(A + B @ K)
        scale = float(np.max(np.abs(lams))) or 1.0
        decaying = [abs(lam.real) for lam in lams if abs(lam) > 1e-7 * scale and lam.real < 0.0]
        moving = [lam for lam in lams if abs(lam) > 1e-7 * scale]
        if len(decaying) < len(moving) or not decaying:
            return probes.duration  # a mode that does not decay: the error stays for the whole run
        longest = max(longest, 1.0 / min(decaying))
    return min(probes.duration, longest) if longest > 0.0 else probes.duration


def _phase_drift(plant, xc, xf, tf, yf, factor: float, duration: float) -> np.ndarray:
    """Error (2,) of the outputs from the angle error a window leaves, grown over the run (torques by crank angle).

    The angle has no restoring force: an error ``d phi`` can stay, and while
    the speed error that makes it persists (a speed transient, a systematic
    error per firing period) it grows about linearly over the run (measured:
    5.6e-5 rad after 48 steps, 6.8e-4 after 800 on an engine and compressor
    scene). Torques by angle then run early or late by ``d t = d phi / |omega|``,
    which moves each output by ``|dy/dt| d t``. Here ``d phi(t)`` is the
    Richardson error of the window's angles (drive and wheel 3, each over
    its top speed in the window: a wheel rocking about rest barely turns);
    its growth over the window, ``g = log2(max over the window / max over
    its first half)`` in [0, 1] (1: linear, 0: not growing), sets
    the growth over the time a speed error lasts (``duration``,
    :func:`_drift_time`), ``(duration / window)^g``; ``|dy/dt|`` is the
    fine run's largest rate. ``xc``, ``xf``: the window's states at dt and
    dt / 2 on the common times ``tf``.
    """
    W = plant.wheel_map
    span = float(tf[-1] - tf[0])
    rate = np.max(np.abs(np.diff(yf, axis=0)) / np.diff(tf)[:, None], axis=0)
    worst = np.zeros_like(rate)
    half = max(1, tf.size // 2)
    for row_phi, row_w in ((W[0], W[1]), (W[2], W[3])):
        w = float(np.max(np.abs(xf @ row_w)))  # the window's top speed: a wheel rocking about rest barely turns
        if not w > 1e-9:
            continue
        shift = factor * np.abs((xc - xf) @ row_phi) / w
        first, whole = float(np.max(shift[: half + 1])), float(np.max(shift))
        g = 1.0 if first <= 0.0 else min(1.0, max(0.0, math.log2(max(whole / first, 1.0))))
        worst = np.maximum(worst, rate * whole * max(1.0, duration / span) ** g)
    return worst


def check_accuracy(
    plant, method: str, dt: float, duration: float, x0, tolerance: float = ACCURACY_TOLERANCE,
    method_options=None, suggest: bool = True, probes: Probes | None = None, stepper=None, stated_inputs: bool = True,
) -> AccuracyReport | None:  # fmt: skip
    """Stability and accuracy of ``method`` at ``dt`` [s] on the plant's closed loop.

    The estimated error is the larger of the linearized closed loop's step
    response error (:func:`linear_verdict`: the belt mode and the torques'
    speed slopes over the whole duration) and the a-posteriori error on the
    real torques in short windows (:func:`forcing_error`: their variation in
    time and angle). Returns None for adaptive methods (they control their
    own error). ``suggest``: when the step fails, search halvings of it for
    one that is both (each candidate checked with ``suggest=False``, so the
    search never searches again). ``probes``: a :func:`probe_scene` of this
    plant already made; ``stepper``: a Stepper of this plant, method and dt
    to reuse for the windows' ``dt`` runs.
    """
    cls = method_class(method)
    if not issubclass(cls, FixedStepIntegrator):
        return None
    model = plant.model
    A, B = model.A, model.B
    rows = _output_rows(model)[0]
    if not np.any(rows[1]):  # rigid: the belt torque is C x + D u; its x part alone carries the dynamics
        rows = rows[:1]
    n_steps = max(1, math.ceil(duration / dt - 1e-9))
    if probes is None:
        probes = probe_scene(plant, duration, x0, dt, stated_inputs)
    integrator = stepper.integrator if stepper is not None else make_integrator(method, A, B, dt, **dict(method_options or {}))
    worst, harmonic = None, 0.0
    for K, slopes in probes.gains:
        stable, error, growth, exact_growth, h_omega = linear_verdict(integrator, A, B, rows, K, n_steps)
        error *= probes.input_weight  # the scene's own steps onto the belt, not a unit step (input_weight)
        report = AccuracyReport(cls.name, dt, stable, error <= tolerance, error, tolerance, growth, exact_growth, h_omega, slopes, linear_error=error)
        if worst is None or (not report.stable and worst.stable) or (report.stable == worst.stable and report.error > worst.error):
            worst = report
        if stable:  # periodic torques over the whole run on this closed loop (forced_response)
            harmonic = max(harmonic, harmonic_error(integrator, A, B, rows, K, n_steps, probes.harmonics,
                                                    probes.peaks[: rows.shape[0]]))  # fmt: skip
    if worst.stable:
        forcing = forcing_error(plant, method, dt, probes, method_options, stepper)
        error = max(worst.error, forcing, harmonic)
        worst = AccuracyReport(**{**worst.__dict__, "error": error, "accurate": error <= tolerance, "forcing_error": forcing,
                                  "harmonic_error": harmonic})  # fmt: skip
    if suggest and not worst.ok:
        found = _largest_ok(plant, method, dt, duration, x0, tolerance, method_options, range(1, MAX_HALVINGS + 1), probes)
        alternative = None
        if found is None or found < dt / 2.0**ALTERNATIVE_HALVINGS:  # this method needs a tiny step: name another too
            for other in ALTERNATIVES:
                if other != cls.name:
                    h = _largest_ok(plant, other, dt, duration, x0, tolerance, None, range(0, MAX_HALVINGS + 1), probes)
                    if h is not None and (found is None or h > found):
                        alternative = (other, h)
                        break
        worst = AccuracyReport(**{**worst.__dict__, "suggestion": found, "alternative": alternative})
    return worst


def _largest_ok(plant, method, dt, duration, x0, tolerance, method_options, exponents, probes) -> float | None:
    """Largest step dt / 2^j (j in ``exponents``, increasing) at which ``method`` is stable and accurate, or None.

    Each candidate is checked with ``suggest=False``: the search never searches again. The windows of the
    forcing check start where ``probes`` says (their length follows the candidate step). A candidate the
    stability guard (free belt) refuses is skipped: a step named is accepted by both guards.
    """
    from .stability import check_step

    for j in exponents:
        h = dt / 2.0**j
        if not check_step(plant.model.A, plant.model.B, method, h).stable:  # the stability guard's view too
            continue
        report = check_accuracy(plant, method, h, duration, x0, tolerance, method_options, suggest=False, probes=probes)
        if report.stable and report.error <= SUGGEST_MARGIN * tolerance:
            return h
    return None


def require_accurate(plant, method, dt, duration, x0, tolerance=ACCURACY_TOLERANCE, method_options=None, stepper=None,
                     stated_inputs=True, probes=None):  # fmt: skip
    """:func:`check_accuracy`; raises :class:`UnstableStepError` (naming a stable, accurate step) when unstable.

    An inaccurate but stable step is returned (``report.accurate`` False): the caller warns.
    ``probes``: a :func:`probe_scene` of this plant, duration, state and step already made.
    """
    report = check_accuracy(plant, method, dt, duration, x0, tolerance, method_options, stepper=stepper,
                            stated_inputs=stated_inputs, probes=probes)  # fmt: skip
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
    * **slip** (each direction sigma = +/-1): ``A_slip`` with the friction
      force an input ``Q = sigma Q_max(omega_M)`` (belt mass makes ``Q_max``
      grow with speed: its slope is a feedback on omega_M beside the torques'
      slopes), ``A_cl = A_slip + B_slip K``; the method's map against the
      exact one (:func:`linear_verdict`; unit steps of drive, load and Q;
      signals drive and wheel-3 speed). The slip mode carries the elastic
      creep ``theta_e' = -(k / c) theta_e + ...``: a fast real mode that
      explicit methods must resolve.

    ``stepper``: the flexible-model stepper of the run (its integrator is reused); ``stick``: the
    flexible model's report for this method, step and tolerance already made (``auto``'s check run);
    ``probes``: the :func:`probe_scene` of the flexible plant at this step already made (that check's).
    """
    from .model import FlexibleBeltModel
    from .slip import SlippingBeltModel
    from .stepper import Plant

    cls = method_class(method)
    if not issubclass(cls, FixedStepIntegrator):
        return None
    plant = Plant(FlexibleBeltModel(params), drive, load)
    if probes is None:
        probes = probe_scene(plant, duration, x0_flexible, dt, stated_inputs)
    if stick is None:
        stick = check_accuracy(plant, method, dt, duration, x0_flexible, tolerance, method_options, suggest=False,
                               probes=probes, stepper=stepper)  # fmt: skip
    stick = AccuracyReport(**{**stick.__dict__, "mode": "stick", "suggestion": None, "alternative": None})
    model = SlippingBeltModel(params)
    A, B = model.A_slip, model.B_slip
    integrator = make_integrator(method, A, B, dt, **dict(method_options or {}))
    rows = np.zeros((2, 5))
    rows[0, 2] = rows[1, 3] = 1.0  # omega_M, omega_3
    n_steps = max(1, math.ceil(duration / dt - 1e-9))
    worst = stick
    for K2, slopes in probes.gains:
        for sigma in (1.0, -1.0):
            K = np.zeros((3, 5))
            K[0, 2], K[1, 3] = slopes
            w = max(abs(float(plant.wheel_map[1] @ probes.x0)), *(abs(w_) for _, _, w_, _ in probes.windows), 1.0)
            d = 1e-6 * w
            K[2, 2] = sigma * (model.limit(w + d) - model.limit(w - d)) / (2.0 * d)
            stable, error, growth, exact_growth, h_omega = linear_verdict(integrator, A, B, rows, K, n_steps)
            report = AccuracyReport(cls.name, dt, stable, error <= tolerance, error, tolerance, growth, exact_growth,
                                    h_omega, slopes, linear_error=error, mode="slip")  # fmt: skip
            if (not report.stable and worst.stable) or (report.stable == worst.stable and report.error > worst.error):
                worst = report
    if suggest and not worst.ok:  # a step of this method that passes in both modes, else another method's
        for j in range(1, ALTERNATIVE_HALVINGS + 1):
            h = dt / 2.0**j
            other = check_slipping(params, drive, load, method, h, duration, x0_flexible, tolerance * SUGGEST_MARGIN,
                                   method_options, suggest=False, stated_inputs=stated_inputs)  # fmt: skip
            if other.ok:
                return AccuracyReport(**{**worst.__dict__, "suggestion": h})
        for name in ALTERNATIVES:
            if name != cls.name:
                other = check_slipping(params, drive, load, name, dt, duration, x0_flexible, tolerance * SUGGEST_MARGIN,
                                       suggest=False, stated_inputs=stated_inputs)  # fmt: skip
                if other.ok:
                    return AccuracyReport(**{**worst.__dict__, "alternative": (name, dt)})
    return worst


def require_accurate_slipping(params, drive, load, method, dt, duration, x0_flexible, tolerance=ACCURACY_TOLERANCE,
                              method_options=None, stepper=None, stick=None, stated_inputs=True, probes=None):  # fmt: skip
    """:func:`check_slipping`; raises :class:`UnstableStepError` when either mode is unstable."""
    report = check_slipping(params, drive, load, method, dt, duration, x0_flexible, tolerance, method_options, stepper,
                            stick=stick, stated_inputs=stated_inputs, probes=probes)  # fmt: skip
    if report is not None and not report.stable:
        raise UnstableStepError(report.describe())
    return report



def slip_run_error(params, drive, load, method: str, dt: float, time, states, modes, sigmas, event_times,
                   method_options=None) -> float:  # fmt: skip
    """A posteriori error [-] of a slipping run at ``dt`` over its slipping stretch, by Richardson on the run itself.

    The linearized checks of :func:`check_slipping` see each mode alone;
    what happens where the modes meet (located events, the force jumping to
    ``sigma Q_max``, the forcing carried across) and how the error of each
    slip phase accumulates over many (``truck_compressor``: 112 events, the
    belt-torque error grows from 6e-5 to 2.4e-4 of the peak across them at
    etd4, 1 ms) they do not, and neither do short windows about single
    events (they read 5e-5 there). So the stretch from a window
    (:data:`WINDOW_STEPS` steps) before the first event to one after the
    last is run again from the run's own state, at ``2 dt`` (half the
    stretch's cost); for a method of order p the ``dt`` run's error is
    ``|y_dt - y_2dt| / (2^p - 1)``. When the ``2 dt`` run diverges it is
    run at ``dt / 2`` instead (error ``|y_dt - y_dt/2| 2^p / (2^p - 1)``).
    Signals: drive speed and belt torque at the common grid times, relative
    to their peaks over the run (``time``, ``states``, ``modes``,
    ``sigmas``: the run's samples). No events: 0; both reruns diverge: inf.
    """
    from .errors import SimulationDivergedError
    from .slip import SlippingBeltModel
    from .slip_run import SlippingSimulator, _joined

    event_times = sorted(float(t) for t in event_times)
    order = method_class(method).order
    if not event_times or order is None:
        return 0.0
    time = np.asarray(time, dtype=float)
    model, r3 = SlippingBeltModel(params), params.r_3

    def outputs(ys, m, s):
        return np.column_stack([ys[:, 2], r3 * model.force(ys, m, s)])

    run_out = outputs(np.asarray(states), np.asarray(modes), np.asarray(sigmas))
    peak = np.max(np.abs(run_out), axis=0)
    span = WINDOW_STEPS * dt
    k0 = 2 * max(0, math.floor((event_times[0] - span) / (2.0 * dt)))  # on both grids
    t0 = k0 * dt
    t1 = min(event_times[-1] + span, float(time[-1]))
    i = int(np.searchsorted(time, t0 + 1e-9 * dt, side="right")) - 1  # the run's last sample at t0
    if i < 0 or abs(time[i] - t0) > 1e-9 * dt or t1 <= t0 + dt:
        return 0.0
    for h, factor in ((2.0 * dt, 1.0 / (2.0**order - 1.0)), (dt / 2.0, 2.0**order / (2.0**order - 1.0))):
        # lazy: each phase's stepper is built when the rerun first enters that phase
        sim = SlippingSimulator(params, drive, load, method, h, method_options, check_stability=False, lazy=True)
        state = sim._native(np.asarray(states[i], dtype=float), int(modes[i]), float(sigmas[i]))
        pieces = [(np.array([t0]), sim.state_y(state)[None, :], state.mode, state.sigma)]
        try:
            with np.errstate(all="ignore"):
                sim.advance(state, t0, t1, pieces, [])
        except (SimulationDivergedError, IntegratorError):
            continue
        tr, yr, mr, sr = _joined(pieces)
        out = outputs(yr, mr, sr)
        if not np.all(np.isfinite(out)):
            continue
        lo, hi = (time, tr) if h > dt else (tr, time)  # match the coarser run's grid times in the finer one
        idx = np.clip(np.searchsorted(hi, lo - 1e-9 * dt), 0, hi.size - 1)
        same = (np.abs(hi[idx] - lo) <= 1e-9 * dt + 8.0 * np.spacing(np.abs(lo) + dt)) & (lo >= t0) & (lo <= t1)
        a = (run_out if h > dt else out)[same]
        b = (out if h > dt else run_out)[idx[same]]
        err = factor * np.max(np.abs(a - b), axis=0)
        return float(np.max(np.where(peak > 0, err / np.where(peak > 0, peak, 1.0), 0.0)))
    return math.inf


def with_slip_run_error(report: AccuracyReport, run_error: float) -> AccuracyReport:
    """``report`` (of :func:`check_slipping`) with the slipping run's own a-posteriori error (:func:`slip_run_error`).

    The estimate counts when larger; when it fails the tolerance, the step
    named is the largest ``dt / 2^j`` at which it would fall (order p) to
    :data:`SUGGEST_MARGIN` of the tolerance.
    """
    error = max(report.error, run_error)
    fields = {**report.__dict__, "error": error, "accurate": error <= report.tolerance, "slip_run_error": run_error}
    if run_error > report.error:  # the verdict is the hybrid run's, not one mode's
        fields["mode"] = "hybrid"
    if run_error > report.tolerance and math.isfinite(run_error):
        p = method_class(report.method).order or 1
        j = max(1, math.ceil(math.log2(run_error / (SUGGEST_MARGIN * report.tolerance)) / p))
        h = report.dt / 2.0**j
        if report.suggestion is None or report.suggestion > h:
            fields["suggestion"] = h
    return AccuracyReport(**fields)
