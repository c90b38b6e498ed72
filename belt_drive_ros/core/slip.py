"""The slipping belt: stick and slip at the capstan limit (a hybrid system, linear in each mode).

The flexible model (:mod:`.model`) transmits any force. A real belt transmits
at most what friction on the pulley with the smaller wrap allows
(capstan / Euler-Eytelwein law, ``docs/slip.md``)::

    Q_max = 2 (F_0 - F_c) tanh(mu_eff beta / 2)      [N]
    mu_eff = mu / sin(alpha / 2),  F_c = m' (r_2 g omega_M)^2

State (one ordering for both modes; SI units)::

    y = [phi_M, theta_e, omega_M, omega_3, s]        [rad, rad, rad/s, rad/s, m]

``theta_e = delta / r_3`` is the elastic deflection (span stretch delta
beyond preload, as an angle at wheel 3), ``s`` the accumulated slip of the
belt on the pulleys [m at the belt]. Wheel 3 is at
``phi_3 = i phi_M - theta_e - s / r_3``; the published relative deflection
``i phi_M - phi_3 = theta_e + s / r_3`` splits into the elastic part and the
slip part. The net force the belt transmits (tight minus slack span) is
``Q = 2 k delta + 2 c delta'``, and::

    I_f omega_M' + b_f omega_M = M_drive - g r_2 Q
    I_3 omega_3' + b_3 omega_3 = r_3 Q - M_load

Modes (each ``y' = A y + B u`` with held inputs):

* **stick**: ``s' = 0``, ``theta_e' = i omega_M - omega_3``,
  ``Q = q . y`` (:attr:`SlippingBeltModel.q_row`); exactly the flexible model.
  Leaves stick when ``|Q|`` reaches ``Q_max`` (event), sliding with
  ``sigma = sign(Q)``.
* **slip**: ``Q = sigma Q_max`` is an input; for ``c > 0`` the span element
  relaxes, ``theta_e' = (Q - 2 k r_3 theta_e) / (2 c r_3)`` and
  ``s' = v_rel - r_3 theta_e'`` with the surface speed difference
  ``v_rel = r_2 g omega_M - r_3 omega_3``; for ``c = 0`` the stretch is held,
  ``theta_e = sigma Q_max / (2 k r_3)``, and ``s' = v_rel``. Re-sticks when
  the slip speed ``s'`` reaches zero (event), if the stick-mode force does not
  at once grow past the limit again.

The switching functions are located as events on the method's own flow over
a partial step (the exact flow for ``exact``), by root finding on the
sub-step length; a grid step is split at each event as at a torque
breakpoint. A regularised alternative, ``Q = Q_max tanh(s' / v_eps)``
(:class:`~belt_drive_ros.core.slip_reference.RegularisedFriction`), is one
smooth but stiff ODE.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .errors import BeltDriveError
from .integrators import make_integrator
from .params import BeltDriveParams
from .stage_scheme import Guard

STICK, SLIP = 0, 1

#: extra output signals of the slipping model, SI units (beside model.OUTPUT_UNITS)
SLIP_OUTPUT_UNITS: dict[str, str] = {
    "elastic_deflection": "rad",
    "slip_angle": "rad",
    "slip_distance": "m",
    "slip_speed": "m/s",
    "friction_use": "1",
    "friction_limit": "N",
}


class SlipError(BeltDriveError, ValueError):
    """Invalid slip-model option, or a hybrid run that cannot make progress."""


class SlippingBeltModel:
    """Flexible belt with Coulomb slip at the capstan limit.

    Parameters
    ----------
    params : BeltDriveParams (``mu``, ``wrap_angle``, ``groove_angle``, ``belt_mass``, ``F_0`` set the limit).

    Attributes
    ----------
    A_stick, B_stick : (5, 5), (5, 2) stick mode, inputs ``[M_drive, M_load]`` [N m].
    A_slip, B_slip : (5, 5), (5, 3) slip mode, inputs ``[M_drive, M_load, Q]`` [N m, N m, N].
    q_row : (5,) stick-mode force ``Q = q_row @ y`` [N].
    rel_row : (5,) surface speed difference ``v_rel = rel_row @ y`` [m/s].
    """

    name = "slipping"
    n_states = 5

    def __init__(self, params: BeltDriveParams):
        p = self.params = params
        g, i, r2, r3 = p.gear_ratio, p.ratio, p.r_2, p.r_3
        If, I3, bf, b3 = p.inertia_drive_side, p.I_3, p.bearing_damping_drive_side, p.b_3
        self.q_row = np.array([0.0, 2.0 * p.k * r3, 2.0 * p.c * r2 * g, -2.0 * p.c * r3, 0.0])
        self.rel_row = np.array([0.0, 0.0, r2 * g, -r3, 0.0])
        self._q = self.q_row.tolist()
        self._scalar_limit = p.scalar_friction_limit()  # friction_limit's own float path, built once
        # stick: Q = q_row @ y
        A = np.zeros((5, 5))
        A[0, 2] = 1.0
        A[1, 2], A[1, 3] = i, -1.0
        A[2] = -g * r2 * self.q_row / If
        A[2, 2] -= bf / If
        A[3] = r3 * self.q_row / I3
        A[3, 3] -= b3 / I3
        B = np.zeros((5, 2))
        B[2, 0], B[3, 1] = 1.0 / If, -1.0 / I3
        self.A_stick, self.B_stick = A, B
        # slip: Q an input
        A = np.zeros((5, 5))
        A[0, 2] = 1.0
        A[2, 2], A[3, 3] = -bf / If, -b3 / I3
        B = np.zeros((5, 3))
        B[2, 0], B[3, 1] = 1.0 / If, -1.0 / I3
        B[2, 2], B[3, 2] = -g * r2 / If, r3 / I3
        A[4] = self.rel_row
        if p.c > 0.0:  # theta_e' = (Q - 2 k r3 theta_e) / (2 c r3);  s' = v_rel - r3 theta_e'
            A[1, 1] = -p.k / p.c
            B[1, 2] = 1.0 / (2.0 * p.c * r3)
            A[4, 1] = p.k * r3 / p.c
            B[4, 2] = -1.0 / (2.0 * p.c)
        self.A_slip, self.B_slip = A, B
        # the regularised ODE: Q and the slip speed v_s are inputs; theta_e' = (v_rel - v_s) / r3, s' = v_s
        A = self.A_slip.copy()
        A[1] = self.rel_row / r3
        A[4] = 0.0
        B = np.zeros((5, 4))
        B[:, :3] = self.B_slip
        B[1, 2] = B[4, 2] = 0.0
        B[1, 3], B[4, 3] = -1.0 / r3, 1.0
        self.A_reg, self.B_reg = A, B

    @property
    def A(self):
        """Stick-mode matrix (what stability checks and generic callers see)."""
        return self.A_stick

    @property
    def B(self):
        return self.B_stick

    def wheel_coordinates(self, y):
        """(phi_M, omega_M, phi_3, omega_3) of state(s) ``y``."""
        return y[..., 0], y[..., 2], self.phi_3(y), y[..., 3]

    # ----------------------------------------------------------- kinematics
    def phi_3(self, y):
        """phi_3 = i phi_M - theta_e - s / r_3 [rad]."""
        return self.params.ratio * y[..., 0] - y[..., 1] - y[..., 4] / self.params.r_3

    def limit(self, omega_M):
        """Q_max at drive speed ``omega_M`` [N] (:meth:`BeltDriveParams.friction_limit`)."""
        if isinstance(omega_M, (int, float)):  # one sample: the closure friction_limit would build per call
            return self._scalar_limit(omega_M)
        return self.params.friction_limit(omega_M)

    def guard(self, mode: int, sigma: float = 0.0) -> Guard:
        """The switching function of ``mode`` as a :class:`~belt_drive_ros.core.stage_scheme.Guard` on ``y``.

        Stick: ``|q . y| - Q_max(omega_M)`` with ``Q_max = 2 F_0 f - 2 m' (r_2 g omega_M)^2 f``,
        ``f = tanh(mu_eff beta / 2)``. Slip (direction sigma): ``-sigma s'`` with
        ``s' = v_rel - (sigma Q_max - 2 k r_3 theta_e) / (2 c)``, i.e.
        ``-sigma (rel + (k r_3 / c) e_theta) . y + Q_max / (2 c)`` (c = 0: ``-sigma v_rel``).
        Positive once the mode must end (what :meth:`HybridStepper.switching`
        evaluates, without the clip of ``Q_max`` at 0 where the belt lifts off).
        """
        p = self.params
        f2 = p.capstan_factor
        quad = p.belt_mass * (p.r_2 * p.gear_ratio) ** 2 * f2
        speed = (0.0, 0.0, 1.0, 0.0, 0.0)
        if mode == STICK:
            return Guard(tuple(float(v) for v in self.q_row), p.F_0 * f2, True, speed, quad)
        row = -sigma * self.rel_row
        if p.c == 0.0:
            return Guard(tuple(float(v) for v in row))
        row[1] -= sigma * p.k * p.r_3 / p.c
        return Guard(tuple(float(v) for v in row), -p.F_0 * f2 / (2.0 * p.c), False, speed, -quad / (2.0 * p.c))

    def slip_speed(self, y, Q):
        """s' in slip mode for transmitted force ``Q`` [m/s] (c = 0: the surface speed difference)."""
        p = self.params
        rel = y[..., 2] * self.rel_row[2] + y[..., 3] * self.rel_row[3]
        if p.c == 0.0:
            return rel
        return rel - (Q - 2.0 * p.k * p.r_3 * y[..., 1]) / (2.0 * p.c)

    def state_from_flexible(self, x: np.ndarray) -> np.ndarray:
        """Slipping state of a flexible state ``[phi_M, delta, omega_M, omega_3]`` (no slip yet: theta_e = delta)."""
        x = np.asarray(x, dtype=float)
        return np.array([x[0], x[1], x[2], x[3], 0.0])

    # -------------------------------------------------------------- outputs
    def force(self, y, mode, sigma, qmax=None):
        """Transmitted force Q per sample [N]: ``q_row @ y`` sticking, ``sigma Q_max`` slipping
        (``qmax``: :meth:`limit` of ``y``'s drive speed, when the caller has it)."""
        if not isinstance(y, _Sample):
            y, mode = np.asarray(y, dtype=float), np.asarray(mode)
        q = self._q  # elementwise (q_0 = q_4 = 0): one sample and a whole run round alike, unlike a matrix product
        stick = q[1] * y[..., 1] + q[2] * y[..., 2] + q[3] * y[..., 3]
        return _where(mode == SLIP, sigma * (self.limit(y[..., 2]) if qmax is None else qmax), stick)

    def outputs(self, y, u, mode, sigma) -> dict:
        """Output signals of samples ``y`` (N, 5), ``u`` (N, 2), ``mode``, ``sigma`` (N,).

        The keys of ``model.OUTPUT_UNITS`` (``slip`` is the slip *mode*,
        ``slack`` a slack span) plus :data:`SLIP_OUTPUT_UNITS`.
        """
        p = self.params
        y, u = np.asarray(y, dtype=float), np.asarray(u, dtype=float)
        if y.ndim == 1:  # one sample (the node's tick): the same formulas on plain floats
            y, u, mode, sigma = _Sample(y.tolist()), _Sample(u.tolist()), int(mode), float(sigma)
        else:
            mode = np.asarray(mode)
        phi_M, theta_e, omega_M, omega_3, s = y[..., 0], y[..., 1], y[..., 2], y[..., 3], y[..., 4]  # read once
        qmax = self.limit(omega_M)
        Q = self.force(y, mode, sigma, qmax)
        speed = _where(mode == SLIP, self.slip_speed(y, Q), 0.0)
        a1, g, r_3 = p.r_M / p.R_1, p.gear_ratio, p.r_3
        slack_force = p.F_0 - 0.5 * Q
        tight = p.F_0 + 0.5 * Q
        slip_angle = s / r_3
        return {
            "phi_M": phi_M,
            "omega_M": omega_M,
            "phi_1": a1 * phi_M,
            "omega_1": a1 * omega_M,
            "phi_2": g * phi_M,
            "omega_2": g * omega_M,
            "phi_3": self.phi_3(y),
            "omega_3": omega_3,
            "drive_torque": u[..., 0],
            "load_torque": u[..., 1],
            "belt_torque": r_3 * Q,
            "relative_deflection": theta_e + slip_angle,
            "span_force_tight": tight,
            "span_force_slack": slack_force,
            "slack": _minimum(slack_force, tight) <= 0.0,
            "slip": mode == SLIP,
            "elastic_deflection": theta_e,
            "slip_angle": slip_angle,
            "slip_distance": s,
            "slip_speed": speed,
            "friction_use": _ratio(Q, qmax),
            "friction_limit": qmax,
        }

    # ------------------------------------------------------------- energies
    def kinetic_energy(self, y):
        """T = 1/2 I_f omega_M^2 + 1/2 I_3 omega_3^2 [J]."""
        p = self.params
        return 0.5 * (p.inertia_drive_side * y[..., 2] ** 2 + p.I_3 * y[..., 3] ** 2)

    def potential_energy(self, y):
        """V = 2 (1/2) k delta^2 = k (r_3 theta_e)^2 [J] (both spans)."""
        p = self.params
        return p.k * (p.r_3 * y[..., 1]) ** 2

    def input_power(self, y, u):
        """P_in = M_drive omega_M - M_load omega_3 [W]."""
        return u[..., 0] * y[..., 2] - u[..., 1] * y[..., 3]

    def damping_power(self, y, mode, sigma):
        """Bearing and span damping losses b_f omega_M^2 + b_3 omega_3^2 + 2 c delta'^2 [W]."""
        p = self.params
        Q = self.force(y, mode, sigma)
        rel = y @ self.rel_row
        ddelta = np.where(np.asarray(mode) == SLIP, rel - self.slip_speed(y, Q), rel)
        return p.bearing_damping_drive_side * y[..., 2] ** 2 + p.b_3 * y[..., 3] ** 2 + 2.0 * p.c * ddelta**2

    def friction_power(self, y, mode, sigma):
        """Friction loss Q s' = Q_max |s'| while slipping [W]."""
        Q = self.force(y, mode, sigma)
        return np.where(np.asarray(mode) == SLIP, Q * self.slip_speed(y, Q), 0.0)


class _Sample:
    """One state (or input) as plain floats, indexed like an array of samples (``y[..., k]``).

    :meth:`SlippingBeltModel.outputs` of one sample (the node's tick) runs
    its formulas on it: the same IEEE operations as on arrays, so the same
    values, without a numpy scalar per operation.
    """

    __slots__ = ("values",)

    def __init__(self, values: list):
        self.values = values

    def __getitem__(self, key):
        return self.values[key[1]]


def _where(condition, a, b):
    """``np.where`` for arrays, the conditional for one sample."""
    if isinstance(condition, np.ndarray):
        return np.where(condition, a, b)
    return a if condition else b


def _minimum(a, b):
    """``np.minimum`` for arrays, ``min`` for one sample."""
    return np.minimum(a, b) if isinstance(a, np.ndarray) else min(a, b)


def _ratio(Q, qmax):
    """Q / Q_max, inf where the limit is 0 (the belt lifted off)."""
    if isinstance(Q, np.ndarray):
        qmax = np.asarray(qmax, dtype=float)
        return np.divide(Q, qmax, out=np.full(Q.shape, np.inf), where=qmax > 0)
    return Q / qmax if qmax > 0 else math.inf


# ================================================================ hybrid run
@dataclass
class Event:
    """One mode switch: time [s], kind ('onset' or 'restick'), direction sigma, state there."""

    time: float
    kind: str
    sigma: float
    state: np.ndarray


@dataclass
class HybridResult:
    """States on the grid, the mode and slip direction at each grid time, and the events."""

    time: np.ndarray
    states: np.ndarray
    mode: np.ndarray
    sigma: np.ndarray
    events: list = field(default_factory=list)


class HybridStepper:
    """Steps the stick/slip model with one fixed-step method, switching modes at located events.

    Parameters
    ----------
    model : SlippingBeltModel.
    drive, load : scalar torque functions ``f(t, angle, speed)`` [N m] (the
        profiles' ``scalar_torque()``); the load sees ``phi_3``, ``omega_3``.
    method : fixed-step method name (``exact``, ``etd2``, ``etd4``, ``lawson5``, ``rk4``, ...).
    locate : True: events located by root finding on the method's flow over a
        partial step; False: the mode is switched at the end of the step in
        which the switching function changed sign (sampling on the grid; for
        comparison only).
    """

    def __init__(self, model: SlippingBeltModel, drive: Callable, load: Callable, method: str = "exact", locate: bool = True,
                 data=None):  # fmt: skip
        self.model, self.drive, self.load, self.method, self.locate = model, drive, load, method, locate
        self._steps: dict = {}
        self._guards: dict = {}
        p = model.params
        self._i, self._r3 = p.ratio, p.r_3
        self._two_k_r3 = 2.0 * p.k * p.r_3
        self.n_located = 0
        #: exact, etd2 and etd4 steps of any length by the compiled modal flow (no matrix exponential per length)
        self._modal_steps = method in ("exact", "etd2", "etd4")
        self._project_slip = p.c == 0.0 and p.belt_mass > 0.0
        self._limit = p.scalar_friction_limit()
        self._rel2, self._rel3 = float(model.rel_row[2]), float(model.rel_row[3])
        self._q1, self._q2, self._q3 = model._q[1:4]
        # dQ_max/dt = dlim * omega_M * omega_M' (the centrifugal part), and |q|, |A|, |B| of stick for the rounding scale
        self._dlim = -2.0 * p.belt_mass * (p.r_2 * p.gear_ratio) ** 2 * p.capstan_factor
        self._abs_stick = (np.abs(model.q_row), np.abs(model.A_stick), np.abs(model.B_stick))
        #: the compiled event step's arrays (:func:`~belt_drive_ros.core.kernel_slip.pack`) when the torques are
        #: data (``data`` = (drive data, load data, uses_angle)) and the method steps on the modal flow
        #: (the method's partial steps then in Python, the events located by the compiled location on the same
        #: continuous extension: ``_located``)
        self._kernel = self._located = None
        if data is not None and None not in data[:2] and locate:
            from . import kernel_slip

            arrays = kernel_slip.pack(model, method, *data)
            if self._modal_steps:
                self._kernel = arrays
                self._event_step = kernel_slip.event_step
                self._event_buffer = np.zeros((kernel_slip.MAX_SWITCHES + 1, 8))
            elif arrays is not None:
                locate_event, Z, R, c, _, guards, uses = kernel_slip.locate_event, *arrays[:6]
                rest = arrays[6:]
                self._located = lambda mode, sigma, t, y, h, hi, y1: locate_event(
                    int(mode), float(sigma), float(t), np.ascontiguousarray(y, dtype=float), float(h), float(hi),
                    np.ascontiguousarray(y1, dtype=float), Z, R, c, guards, uses, *rest)  # C arrays: one signature  # fmt: skip

    # ---------------------------------------------------------- the flows
    def _integrator(self, mode: int, h: float):
        key = (mode, h)
        integ = self._steps.get(key)
        if integ is None:
            if len(self._steps) > 512:
                self._steps.clear()
            m = self.model
            A, B = (m.A_stick, m.B_stick) if mode == STICK else (m.A_slip, m.B_slip)
            integ = self._steps[key] = make_integrator(self.method, A, B, h)
        return integ

    def inputs(self, mode: int, sigma: float, hi: float = math.inf) -> Callable:
        """u(t, y) of ``mode``; times are clipped at ``hi`` (torque read from the left of a cut)."""
        drive, load, i, r3, limit = self.drive, self.load, self._i, self._r3, self.model.limit

        if mode == STICK:

            def u(t, y):
                t = t if t < hi else hi
                return np.array([drive(t, y[0], y[2]), load(t, i * y[0] - y[1] - y[4] / r3, y[3])])

        else:

            def u(t, y):
                t = t if t < hi else hi
                return np.array(
                    [drive(t, y[0], y[2]), load(t, i * y[0] - y[1] - y[4] / r3, y[3]), sigma * limit(y[2])]
                )

        return u

    def flow(self, mode, sigma, t, y, h, hi=math.inf):
        """The method's step of length ``h`` in ``mode`` from (t, y), by an integrator of step ``h`` (cached per length)."""
        y1 = self._integrator(mode, h).step(t, y, self.inputs(mode, sigma, hi))
        return self._project(mode, sigma, y1)

    def _project(self, mode, sigma, y):
        """c = 0 slip: the stretch follows sigma Q_max(omega_M) (keeps the total deflection)."""
        p = self.model.params
        if mode == SLIP and p.c == 0.0 and p.belt_mass > 0.0:
            te = sigma * self.model.limit(y[2]) / self._two_k_r3
            y = y.copy()
            y[4] += self._r3 * (y[1] - te)
            y[1] = te
        return y

    # ------------------------------------------------- switching functions
    def switching(self, mode, sigma, y) -> float:
        """> 0 once the mode must end: ``|Q| - Q_max`` sticking, ``-sigma s'`` slipping [N or m/s]."""
        m = self.model
        if mode == STICK:
            return abs(float(m.q_row @ y)) - self._limit(float(y[2]))
        return -sigma * float(m.slip_speed(y, sigma * self._limit(float(y[2]))))

    def _stick_keeps(self, t, y) -> bool:
        """True if the stick mode's |Q| does not at once grow past Q_max from (t, y).

        Decided by the sign of sigma dQ/dt - dQ_max/dt in stick mode; where that
        vanishes to rounding (c = 0: dQ/dt = 2 k v_rel = 2 k s' = 0 at the
        switch) by the second derivative sigma d2Q/dt2 = sigma q . A y'
        (inputs held over the instant).
        """
        m = self.model
        Q = float(m.q_row @ y)
        if abs(Q) < self._limit(float(y[2])) * (1.0 - 1e-9):
            return True
        sig = math.copysign(1.0, Q)
        u = self.inputs(STICK, 0.0)(t, y)
        dy = m.A_stick @ y + m.B_stick @ u
        dlim = self._dlim * y[2] * dy[2]
        rate = sig * float(m.q_row @ dy) - dlim
        q_abs, A_abs, B_abs = self._abs_stick
        scale = float(q_abs @ (A_abs @ np.abs(y) + B_abs @ np.abs(u))) + abs(dlim)
        if abs(rate) > 1e-8 * scale:
            return rate < 0.0
        return sig * float(m.q_row @ (m.A_stick @ dy)) <= 0.0

    def switch(self, mode, sigma, t, y):
        """New (mode, sigma, y) after an event at (t, y)."""
        m = self.model
        if mode == STICK:
            sigma = 1.0 if float(m.q_row @ y) >= 0.0 else -1.0
            if m.params.c == 0.0:  # the stretch sits at the limit exactly
                te = sigma * self._limit(float(y[2])) / self._two_k_r3
                y = y.copy()
                y[4] += self._r3 * (y[1] - te)
                y[1] = te
            return SLIP, sigma, y
        if self._stick_keeps(t, y):
            return STICK, 0.0, y
        return SLIP, sigma, y

    # ------------------------------------------------------------ stepping
    def _locate(self, mode, sigma, t, y, h, hi, y1=None):
        """First tau in (0, h] where the switching function turns positive along the step.

        With the torques as data, located on the step's continuous extension
        (the mode's exact flow with the torques linear in time between the
        step's ends) by the compiled location
        (:func:`~belt_drive_ros.core.kernel_slip.locate_event`, as the
        compiled event step does): a method unstable for the slip mode's
        fast creep at this step (rk4 at 1 ms) would give a meaningless flow
        over partial steps. Torques given as Python functions: located on
        the method's flow over a partial step, a sign scan on 8 points
        finding the first crossing (the flow may cross and return within a
        step), then Brent's method to ~1e-15 s.
        """
        if self._located is not None and y1 is not None:  # torques as data: on the step's modal extension, compiled
            tau = self._located(mode, sigma, t, y, h, hi, y1)
            if tau != tau:
                return None
            self.n_located += tau > 0.0
            return tau

        def G(tau):
            return self.switching(mode, sigma, y if tau == 0.0 else self.flow(mode, sigma, t, y, tau, hi))

        lo, g_lo = self._inside(G, self.switching(mode, sigma, y), h)
        if lo is None:
            return 0.0
        bracket = self._scan(G, lo, g_lo, h, 8)
        if bracket is None:
            return None
        self.n_located += 1
        import scipy.optimize  # here, at the first event located: a run without one never loads it

        return scipy.optimize.brentq(G, bracket[0], bracket[2], xtol=1e-15, rtol=_EPS4, maxiter=200)

    @staticmethod
    def _inside(G, g_lo, h):
        """(lo, G(lo)): 0 when the step starts inside (G < 0), else the first h 2^-k inside, or (None, None)."""
        if g_lo < 0.0:
            return 0.0, g_lo
        for k in range(1, 40):  # starts on the surface (just switched): find where it is inside
            tau = h * 0.5**k
            g = G(tau)
            if g < 0.0:
                return tau, g
        return None, None

    @staticmethod
    def _scan(G, lo, g_lo, h, n_scan):
        """(lo, G(lo), hi, G(hi)) around the first sign change on n_scan points from lo to h, or None."""
        for j in range(1, n_scan + 1):
            tau = lo + (h - lo) * j / n_scan if j < n_scan else h
            g = G(tau)
            if g > 0.0:
                return lo, g_lo, tau, g
            lo, g_lo = tau, g
        return None

    def advance(self, t0, t1, y, mode, sigma, cuts=(), events=None, dt=None, hi_end=math.inf, y1=None):
        """Integrate from t0 to t1: sub-steps end at each cut, then at each located event.

        A sub-step whose end state has a positive switching function holds an
        event; it is located (:meth:`_locate`), the flow is taken to it, the
        mode switched (:meth:`switch`) and the rest of the sub-step integrated
        in the new mode. ``y1``: the method's state at ``t1`` in ``mode``
        when already known (a step without cuts that a compiled loop took).
        """
        if self._kernel is not None:
            return self._advance_kernel(t0, t1, y, mode, sigma, cuts, events, dt, hi_end, y1)
        edges = [t0, *cuts, t1]
        n_events = 0
        given = None if cuts else y1
        for j in range(len(edges) - 1):
            a, b = edges[j], edges[j + 1]
            hi = math.nextafter(b, -math.inf) if j < len(edges) - 2 else hi_end
            while a < b:
                h = dt if (dt is not None and a == t0 and b == t1) else b - a  # a whole grid step: the grid's dt
                if given is None:
                    y1 = self.flow(mode, sigma, a, y, h, hi)
                given = None
                if self.switching(mode, sigma, y1) <= 0.0:
                    y, a = y1, b
                    break
                if self.locate:
                    tau = self._locate(mode, sigma, a, y, h, hi, y1)
                    if tau is None:
                        y, a = y1, b
                        break
                    if tau > 0.0:
                        y = self.flow(mode, sigma, a, y, tau, hi)
                    a = a + tau if tau < h else b
                else:  # switch at the end of the step (grid sampling, for comparison)
                    y, a = y1, b
                mode, sigma, y = self._switched(mode, sigma, a, y, events)
                n_events += 1
                if n_events > 64:
                    raise SlipError(f"slip: more than 64 mode switches in one step at t={a:.9g} s (chattering); reduce dt")
        return y, mode, sigma

    def _advance_kernel(self, t0, t1, y, mode, sigma, cuts, events, dt, hi_end, y1):
        """:meth:`advance` by the compiled event step (:func:`~belt_drive_ros.core.kernel_slip.event_step`)."""
        yk = np.array(y, dtype=float)
        given = 0 if (cuts or y1 is None) else 1
        y1k = np.array(y1, dtype=float) if given else np.empty(5)
        ev = self._event_buffer
        mode, sigma, n, status = self._event_step(
            float(t0), float(t1), np.asarray(cuts, dtype=float), yk, int(mode), float(sigma),
            math.nan if dt is None else float(dt), float(hi_end), y1k, given, *self._kernel, ev, 0,
        )  # fmt: skip
        if events is not None:
            for row in ev[:n]:
                events.append(Event(float(row[0]), "onset" if row[1] else "restick", float(row[2]), row[3:].copy()))
        if status:
            raise SlipError(f"slip: more than 64 mode switches in one step at t={t0:.9g} s (chattering); reduce dt")
        return yk, int(mode), float(sigma)

    def _switched(self, mode, sigma, a, y, events):
        """:meth:`switch` at an event at (a, y), recorded in ``events`` when the mode changes."""
        old = mode
        mode, sigma, y = self.switch(mode, sigma, a, y)
        if events is not None and mode != old:
            events.append(Event(a, "onset" if mode == SLIP else "restick", sigma, y.copy()))
        return mode, sigma, y

    def run(self, time, y0, mode0=STICK, sigma0=0.0, breakpoints=()) -> HybridResult:
        """Integrate over the grid ``time``; steps are split at ``breakpoints`` and at events."""
        time = np.asarray(time, dtype=float)
        n = time.size - 1
        states = np.empty((n + 1, 5))
        modes = np.empty(n + 1, dtype=int)
        sigmas = np.empty(n + 1)
        y = np.asarray(y0, dtype=float).copy()
        mode, sigma = mode0, sigma0
        if mode == STICK and self.switching(mode, sigma, y) > 0.0:  # starts beyond the limit
            mode, sigma, y = self.switch(mode, sigma, time[0], y)
        states[0], modes[0], sigmas[0] = y, mode, sigma
        events: list = []
        bps = sorted(float(b) for b in breakpoints)
        dt = float(time[1] - time[0]) if n else 0.0
        uniform = n > 0 and bool(np.allclose(np.diff(time), dt, rtol=1e-9, atol=0.0))
        tol = 1e-9 * dt
        for k in range(n):
            a, b = time[k], time[k + 1]
            cuts = [c for c in bps if a + tol < c < b - tol]
            # a step ending on a breakpoint samples the torque's left limit there (as the stepper does)
            hi_end = math.nextafter(b, -math.inf) if any(abs(c - b) <= tol for c in bps) else math.inf
            y, mode, sigma = self.advance(a, b, y, mode, sigma, cuts, events, dt if uniform else None, hi_end)
            states[k + 1], modes[k + 1], sigmas[k + 1] = y, mode, sigma
        return HybridResult(time, states, modes, sigmas, events)


#: relative tolerance of the event location (4 machine epsilons)
_EPS4 = 4.0 * float(np.finfo(float).eps)
