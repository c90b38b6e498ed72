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
from .integrators import FixedStepIntegrator, make_integrator, method_class
from .model import LINEAR_OUTPUTS, RigidBeltModel

#: default relative tolerance of the guard (speed and belt torque, relative to peak)
ACCURACY_TOLERANCE = 1e-4
#: step-response samples compared (beyond them the horizon is sampled in strides, see step_response_error)
MAX_STEPS = 1200
#: times along the scene at which the torques' slopes are probed
N_PROBES = 5
#: steps per advance of the probes' rigid run (bounds the stepper's plan, so memory does not grow with the duration)
PROBE_CHUNK = 1000
#: growth beyond max(1, exact growth) by this much (relative) is instability, not rounding
GROWTH_TOLERANCE = 1e-9
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

    @property
    def ok(self) -> bool:
        return self.stable and self.accurate

    def describe(self) -> str:
        """One line for logs and errors."""
        state = "UNSTABLE" if not self.stable else ("accurate" if self.accurate else "INACCURATE")
        line = (
            f"{self.method} at dt={self.dt:.4g} s on the closed loop: {state} (estimated error {self.error:.2g} "
            f"of the peak, tolerance {self.tolerance:.2g}; growth/step {self.growth:.6g} vs exact "
            f"{self.exact_growth:.6g}; h*omega={self.h_omega:.4g}; torque slopes {self.slopes[0]:.3g}, "
            f"{self.slopes[1]:.3g} N m s/rad)"
        )
        if self.suggestion is not None:
            line += f"; dt = {self.suggestion:.3g} s is stable and accurate"
        elif not self.ok:
            line += f"; no step down to {self.dt / 2.0**MAX_HALVINGS:.2g} s of this method is"
        if self.alternative is not None:
            line += f"; so is {self.alternative[0]} at dt = {self.alternative[1]:.3g} s"
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


def _probes(plant, duration: float, x0) -> list[tuple]:
    """(K, slopes) at :data:`N_PROBES` times along a cheap rigid run (drive speed from it), distinct ones only."""
    from .stepper import Plant, Stepper

    p = plant.model.params
    rigid = RigidBeltModel(p)
    wm = plant.wheel_map
    phi0, w0 = float(wm[0] @ x0), float(wm[1] @ x0)
    dt = min(duration / 500.0, 5e-3) if duration > 0 else 1e-3
    try:  # advance from probe to probe (memory independent of the duration: runs may stream)
        stepper = Stepper(Plant(rigid, plant.drive, plant.load), "exact", dt)
        t_probe = np.linspace(0.0, duration, N_PROBES) if duration > 0 else np.array([0.0])
        x, speeds = np.array([phi0, w0]), []
        for t0, t1 in zip(np.concatenate([[0.0], t_probe[:-1]]), t_probe):
            # in pieces of PROBE_CHUNK steps: the stepper plans each advance whole
            for a, b in zip(np.arange(t0, t1, PROBE_CHUNK * dt), np.append(np.arange(t0, t1, PROBE_CHUNK * dt)[1:], t1)):
                x = stepper.advance(x, float(a), float(b))
            speeds.append(float(x[1]))
        w_probe = np.array(speeds)
    except Exception:  # a rigid estimate that diverges: probe at the start only
        t_probe, w_probe = np.array([0.0]), np.array([w0])
    gains, seen = [], set()
    for K, slopes in speed_slopes(plant, t_probe, w_probe):
        key = tuple(float(f"{s:.3g}") for s in slopes)  # slopes equal to 3 digits: the same verdict
        if key not in seen:
            seen.add(key)
            gains.append((K, slopes))
    return gains


def closed_loop_maps(integrator, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, G): the method's step on x' = A x + B (K x + u_0) is ``x+ = M x + G u_0`` (from its stage scheme)."""
    n = integrator.A.shape[0]
    scheme, h = integrator.scheme, integrator.dt

    def run(x, u0):
        return _scheme.step(scheme, h, 0.0, x, lambda t, y: K @ y + u0, integrator.name)

    zero_u = np.zeros(2)
    M = np.column_stack([run(e, zero_u) for e in np.eye(n)])
    G = np.column_stack([run(np.zeros(n), e) for e in np.eye(2)])
    return M, G


def exact_maps(A_cl: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(E, F): the exact step of x' = A_cl x + B u_0 with constant u_0 (augmented matrix exponential)."""
    n = A_cl.shape[0]
    aug = np.zeros((n + 2, n + 2))
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
    augmented maps (exact, only samples between strides are skipped).
    """
    n = M.shape[0]
    Ma = np.block([[M, G], [np.zeros((2, n)), np.eye(2)]])
    Ea = np.block([[E, F], [np.zeros((2, n)), np.eye(2)]])
    X = np.vstack([np.zeros((n, 2)), np.eye(2)])
    Z = X.copy()
    err = np.zeros((rows.shape[0], 2))
    peak = np.zeros((rows.shape[0], 2))
    head = min(n_steps, MAX_STEPS // 2)
    stride = max(1, math.ceil((n_steps - head) / (MAX_STEPS // 2)))
    schedule = [(Ma, Ea, head)]
    if n_steps > head:
        schedule.append((np.linalg.matrix_power(Ma, stride), np.linalg.matrix_power(Ea, stride), (n_steps - head) // stride))
    with np.errstate(all="ignore"):
        for P, Q, count in schedule:
            for _ in range(count):
                X, Z = P @ X, Q @ Z
                y, ystar = rows @ X[:n], rows @ Z[:n]
                err = np.maximum(err, np.abs(y - ystar))
                peak = np.maximum(peak, np.abs(ystar))
            if not np.all(np.isfinite(X)):
                return math.inf
    # a unit input that does not move an output at all (peak 0) carries no error either
    return float(np.max(np.where(peak > 0, err / np.where(peak > 0, peak, 1.0), 0.0)))


def check_accuracy(
    plant, method: str, dt: float, duration: float, x0, tolerance: float = ACCURACY_TOLERANCE,
    method_options=None, suggest: bool = True,
) -> AccuracyReport | None:  # fmt: skip
    """Stability and accuracy of ``method`` at ``dt`` [s] on the plant's linearized closed loop.

    Returns None for adaptive methods (they control their own error).
    ``suggest``: when the step fails, search halvings of it for one that is
    both (each candidate checked with ``suggest=False``, so the search never
    searches again).
    """
    cls = method_class(method)
    if not issubclass(cls, FixedStepIntegrator):
        return None
    model = plant.model
    A, B = model.A, model.B
    C = model.C
    rows = C[[LINEAR_OUTPUTS.index("omega_M"), LINEAR_OUTPUTS.index("belt_torque")]]
    if not np.any(rows[1]):  # rigid: the belt torque is C x + D u; its x part alone carries the dynamics
        rows = rows[:1]
    n_steps = max(1, math.ceil(duration / dt - 1e-9))
    gains = _probes(plant, duration, np.asarray(x0, dtype=float))
    integrator = make_integrator(method, A, B, dt, **dict(method_options or {}))
    worst = None
    for K, slopes in gains:
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
        lam = np.linalg.eigvals(A_cl)
        report = AccuracyReport(
            cls.name, dt, stable, error <= tolerance, error, tolerance, growth, exact_growth,
            dt * float(np.max(np.abs(lam))), slopes,
        )  # fmt: skip
        if worst is None or (not report.stable and worst.stable) or (report.stable == worst.stable and report.error > worst.error):
            worst = report
    if suggest and not worst.ok:
        found = _largest_ok(plant, method, dt, duration, x0, tolerance, method_options, range(1, MAX_HALVINGS + 1))
        alternative = None
        if found is None or found < dt / 2.0**ALTERNATIVE_HALVINGS:  # this method needs a tiny step: name another too
            for other in ALTERNATIVES:
                if other != cls.name:
                    h = _largest_ok(plant, other, dt, duration, x0, tolerance, None, range(0, MAX_HALVINGS + 1))
                    if h is not None and (found is None or h > found):
                        alternative = (other, h)
                        break
        worst = AccuracyReport(**{**worst.__dict__, "suggestion": found, "alternative": alternative})
    return worst


def _largest_ok(plant, method, dt, duration, x0, tolerance, method_options, exponents) -> float | None:
    """Largest step dt / 2^j (j in ``exponents``, increasing) at which ``method`` is stable and accurate, or None.

    Each candidate is checked with ``suggest=False``: the search never searches again.
    """
    for j in exponents:
        h = dt / 2.0**j
        if check_accuracy(plant, method, h, duration, x0, tolerance, method_options, suggest=False).ok:
            return h
    return None


def require_accurate(plant, method, dt, duration, x0, tolerance=ACCURACY_TOLERANCE, method_options=None):
    """:func:`check_accuracy`; raises :class:`UnstableStepError` (naming a stable, accurate step) when unstable.

    An inaccurate but stable step is returned (``report.accurate`` False): the caller warns.
    """
    report = check_accuracy(plant, method, dt, duration, x0, tolerance, method_options)
    if report is not None and not report.stable:
        raise UnstableStepError(report.describe())
    return report
