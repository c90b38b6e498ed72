"""Regularised friction as a model of its own: ``model: regularised`` with ``v_eps`` [m/s].

The event-driven hybrid (:mod:`.slip`, :mod:`.slip_run`, model ``slipping``)
switches between stick and slip at located events. What users of tools
without events know is one smooth law instead,
``Q = Q_max tanh(v_s / v_eps)``, in series with the belt span
(:class:`~belt_drive_ros.core.slip_reference.RegularisedFriction`, the one
place the contact is written; the charts, ``benchmarks/slip_runs.py``, run it
through the same class). Its run is a numpy step loop over the registry's
fixed-step methods with ``A_reg`` as the linear part and the contact force
and slip speed as inputs (the compiled loops of :mod:`.stepper` take linear
plants with torques of the wheels' coordinates, not an implicit contact law).

Outputs are the slipping model's columns, with the belt counted as sliding
where ``|v_s| > v_eps`` (there ``|Q| > tanh(1) Q_max = 0.76 Q_max``;
:data:`SLIDING_THRESHOLD`); ``friction_use`` is ``Q / Q_max`` as for the hybrid.

Stability (:func:`check_regularised`)
-------------------------------------
Linearized about a state, the contact has the friction slope
``d = dQ/dv_s = Q_max (1 - tanh^2(v_s / v_eps)) / v_eps``, from ``Q_max / v_eps``
at ``v_s = 0`` down to 0 once it saturates. With the span spring and damper
``2 k r_3 theta_e + 2 c (v_rel - v_s) = Q`` in series::

    v_s = (2 k r_3 theta_e + 2 c v_rel) / (2 c + d),   Q = d v_s
    theta_e' = (v_rel - v_s) / r_3  ->  relaxation rate 2 k / (2 c + d)

so a small ``v_eps`` (large ``d``) makes the contact *slower*, not stiffer;
the fastest rate is the saturated contact's ``k / c`` (the hybrid's slip
mode). The guard takes the method's own one-step map (the same stage scheme
that steps the run, ``A_reg`` with ``u = K y``) at slopes from ``Q_max / v_eps``
down to 0 (``c > 0``; for ``c = 0`` the rate ``2 k / d`` has no bound as the
contact saturates, so it stops at the slope at ``|v_s| = 10 v_eps``) and
refuses a step at which any of them grows faster than the linearized flow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import IntegratorError, SimulationDivergedError, UnstableStepError
from .integrators import REGISTRY, make_integrator, method_class
from .params import BeltDriveParams
from .slip import SLIP, SlippingBeltModel
from .slip_reference import RegularisedFriction
from .stepper import SPEED_LIMIT, Plant

#: model name of regularised friction (scene ``model``, ``belt-drive sim --model``)
MODEL_NAME = "regularised"
#: default regularisation speed [m/s]
V_EPS_DEFAULT = 1e-3
#: plausible range of v_eps [m/s]: below 1 um/s the contact is a stiff switch no fixed step resolves;
#: above 1 m/s the "stick" creeps at speeds comparable to the belt's own
V_EPS_RANGE = (1e-6, 1.0)
#: the belt counts as sliding where |v_s| > SLIDING_THRESHOLD * v_eps (|Q| > tanh(1) Q_max)
SLIDING_THRESHOLD = 1.0
#: friction slopes the guard checks, as fractions of Q_max / v_eps (and 0 when c > 0)
SLOPE_FRACTIONS = tuple(10.0**-j for j in range(0, 13))


def check_v_eps(v_eps) -> float:
    """``v_eps`` as a float in :data:`V_EPS_RANGE`, else a one-line :class:`ValueError` (SceneError upstream)."""
    lo, hi = V_EPS_RANGE
    if isinstance(v_eps, bool) or not isinstance(v_eps, (int, float)) or not math.isfinite(v_eps) or v_eps <= 0:
        raise ValueError(f"v_eps: must be a finite speed > 0 m/s, got {v_eps!r}")
    if not lo <= v_eps <= hi:
        raise ValueError(f"v_eps: {v_eps:g} m/s is outside the plausible range [{lo:g}, {hi:g}] m/s")
    return float(v_eps)


# ------------------------------------------------------------ linearization
def contact_gain(model: SlippingBeltModel, slope: float) -> np.ndarray:
    """K (4, 5): inputs ``[M_drive, M_load, Q, v_s]`` of the regularised ODE linearized with friction slope ``slope`` [N s/m].

    ``v_s = (2 k r_3 theta_e + 2 c v_rel) / (2 c + d)``, ``Q = d v_s``
    (torques held: their rows are 0). Needs ``2 c + d > 0``.
    """
    p = model.params
    F = 2.0 * p.c * model.rel_row.copy()
    F[1] += 2.0 * p.k * p.r_3
    dv = F / (2.0 * p.c + slope)
    K = np.zeros((4, 5))
    K[2], K[3] = slope * dv, dv
    return K


def slopes(params: BeltDriveParams, v_eps: float) -> list[float]:
    """Friction slopes [N s/m] the guard checks (module docstring)."""
    d0 = params.friction_limit(0.0) / v_eps
    out = [d0 * f for f in SLOPE_FRACTIONS]
    if params.c > 0.0:
        out.append(0.0)
    else:
        d_min = d0 * (1.0 - math.tanh(10.0) ** 2)
        out = [d for d in out if d >= d_min] + [d_min]
    return out


def _growth(method: str, model: SlippingBeltModel, K: np.ndarray, h: float) -> tuple[float, float]:
    """(spectral radius of the method's one-step map on ``y' = A_reg y + B_reg K y``, the exact flow's ``e^(h max Re lambda)``)."""
    integ = make_integrator(method, model.A_reg, model.B_reg, h)
    M = np.column_stack([integ.step(0.0, e, lambda t, y: K @ y) for e in np.eye(5)])
    mu = np.linalg.eigvals(M)
    mu = np.where(np.abs(mu - 1.0) <= 1e-6, 1.0, mu)  # the angle and slip integrators' eigenvalue 1
    lam = float(np.max(np.real(np.linalg.eigvals(model.A_reg + model.B_reg @ K))))
    return float(np.max(np.abs(mu))), math.exp(h * lam)


def one_step_stable(method: str, model: SlippingBeltModel, K: np.ndarray, h: float) -> bool:
    """True when ``method``'s one-step map at ``h`` [s] on the ODE linearized with gain ``K`` grows no faster than its flow."""
    radius, flow = _growth(method, model, K, h)
    return radius <= max(1.0, flow) + 1e-9


@dataclass(frozen=True)
class RegularisedStability:
    """The guard's verdict (:func:`check_regularised`): worst slope, its rate and the largest stable step [s]."""

    stable: bool
    method: str
    dt: float
    v_eps: float
    slope: float
    relaxation_rate: float
    growth: float
    max_stable_dt: float

    def describe(self) -> str:
        state = "stable" if self.stable else "UNSTABLE"
        return (
            f"{self.method} at dt={self.dt:.4g} s on regularised friction (v_eps={self.v_eps:g} m/s): {state} "
            f"(worst friction slope d={self.slope:.4g} N s/m, span relaxation 2k/(2c+d)={self.relaxation_rate:.4g} 1/s, "
            f"growth/step {self.growth:.6g}; largest stable step {self.max_stable_dt:.4g} s)"
        )


def _largest_step(method, model, Ks, upper=1.0, iterations=40) -> float:
    """Largest step [s] stable at every gain in ``Ks`` (geometric bisection; inf when ``upper`` is)."""
    if all(one_step_stable(method, model, K, upper) for K in Ks):
        return math.inf
    lo, hi = 1e-9, upper
    if not all(one_step_stable(method, model, K, lo) for K in Ks):
        return 0.0
    for _ in range(iterations):
        mid = math.sqrt(lo * hi)
        if all(one_step_stable(method, model, K, mid) for K in Ks):
            lo = mid
        else:
            hi = mid
    return lo


def check_regularised(params: BeltDriveParams, method: str, dt: float, v_eps: float) -> RegularisedStability:
    """Stability of fixed-step ``method`` at ``dt`` [s] on the regularised model, at every slope of :func:`slopes`."""
    model = SlippingBeltModel(params)
    ds = slopes(params, v_eps)
    Ks = [contact_gain(model, d) for d in ds]
    worst, worst_ratio = 0, -math.inf
    for j, K in enumerate(Ks):
        radius, flow = _growth(method, model, K, dt)
        ratio = radius - max(1.0, flow)
        if ratio > worst_ratio:
            worst, worst_ratio, worst_radius = j, ratio, radius
    d = ds[worst]
    rate = 2.0 * params.k / (2.0 * params.c + d)
    stable = worst_ratio <= 1e-9
    return RegularisedStability(stable, method, float(dt), float(v_eps), d, rate, worst_radius, _largest_step(method, model, Ks))


def require_stable_regularised(params, method, dt, v_eps, safety: float = 0.9) -> RegularisedStability:
    """:func:`check_regularised`, raising :class:`UnstableStepError` with the reason and a step that works."""
    report = check_regularised(params, method, dt, v_eps)
    if report.stable:
        return report
    if 0.0 < report.max_stable_dt < math.inf:
        fix = f"use dt <= {safety * report.max_stable_dt:.3g} s"
    else:
        fix = "no step is stable for this method on this contact"
    raise UnstableStepError(f"{report.describe()}; {fix}, or the event-driven model 'slipping'")


# ---------------------------------------------------------------- the run
class RegularisedSimulator:
    """Runs the regularised model with one fixed-step method (a numpy step loop, module docstring).

    Parameters
    ----------
    params : BeltDriveParams; drive, load : torque profiles; method, dt [s]; v_eps [m/s].
    check_stability : refuse (``UnstableStepError``) a step the guard predicts unstable.
    """

    def __init__(self, params, drive, load, method="etd2", dt=1e-3, v_eps=V_EPS_DEFAULT, check_stability=True):
        cls = method_class(method)
        if not getattr(cls, "fixed_step", False):
            fixed = ", ".join(n for n, c in REGISTRY.items() if c.fixed_step)
            raise IntegratorError(f"{cls.name}: the regularised model is stepped by a fixed-step method ({fixed})")
        self.model = SlippingBeltModel(params)
        self.plant = Plant(self.model, drive, load)
        self.method, self.dt, self.v_eps = cls.name, float(dt), check_v_eps(v_eps)
        self.contact = RegularisedFriction(self.model, self.v_eps)
        self.stability = require_stable_regularised(params, method, dt, self.v_eps) if check_stability else None

    def run(self, duration: float, y0) -> tuple[np.ndarray, np.ndarray]:
        """(time (N+1,), states (N+1, 5)) on the grid ``k dt`` (the last step shortened to end at ``duration``)."""
        n = max(1, math.ceil(duration / self.dt - 1e-9))
        time = np.minimum(np.arange(n + 1) * self.dt, duration)
        time[-1] = duration
        with np.errstate(all="ignore"):
            states = self.contact.run(time, y0, self.plant.scalar_drive, self.plant.scalar_load, self.method,
                                      breakpoints=self.plant.breakpoints)  # fmt: skip
        bad = np.flatnonzero(~np.all(np.isfinite(states), axis=1) | (np.max(np.abs(states[:, 2:4]), axis=1) > SPEED_LIMIT))
        if bad.size:
            raise SimulationDivergedError(
                f"regularised run diverged at t={time[bad[0]]:.6g} s ({self.method}, dt={self.dt:g} s, v_eps={self.v_eps:g} m/s)"
            )
        return time, states

    def input_array(self, time, states) -> np.ndarray:
        """u = [drive, load] per sample (the load at phi_3 with the slip part)."""
        t = np.asarray(time, dtype=float)
        d = np.broadcast_to(self.plant.drive.torque(t, states[:, 0], states[:, 2]), t.shape)
        l = np.broadcast_to(self.plant.load.torque(t, self.model.phi_3(states), states[:, 3]), t.shape)
        return np.stack([d, l], axis=-1).astype(float)

    def outputs(self, states, u) -> tuple[dict, np.ndarray, np.ndarray]:
        """(outputs, Q, v_s): the slipping model's output columns of the contact's ``Q`` and ``v_s``.

        The slipping model's formulas with the force written as a slip-mode
        force ``sigma Q_max`` (``sigma = Q / Q_max``); ``slip`` is
        ``|v_s| > v_eps`` and ``slip_speed`` the contact's ``v_s``.
        """
        Q, v = self.contact.outputs_force(states)
        qmax = np.asarray(self.model.limit(states[:, 2]), dtype=float)
        sigma = np.divide(Q, qmax, out=np.zeros_like(Q), where=qmax > 0)
        out = self.model.outputs(states, u, np.full(len(Q), SLIP), sigma)
        out["slip"] = np.abs(v) > SLIDING_THRESHOLD * self.v_eps
        out["slip_speed"] = v
        return out, Q, v


__all__ = [
    "MODEL_NAME", "SLIDING_THRESHOLD", "V_EPS_DEFAULT", "V_EPS_RANGE", "RegularisedSimulator", "RegularisedStability",
    "check_regularised", "check_v_eps", "contact_gain", "one_step_stable", "require_stable_regularised", "slopes",
]  # fmt: skip
