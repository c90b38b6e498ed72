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

The switching functions are located as events by root finding on the
step's continuous extension, compiled (:class:`EventStep`,
:mod:`~belt_drive_ros.core.kernel_slip`); a grid step is split at each event
as at a torque breakpoint. A regularised alternative,
``Q = Q_max tanh(s' / v_eps)`` (``RegularisedFriction`` in
``benchmarks/slip_reference.py``, the charts' comparison), is one
smooth but stiff ODE.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import BeltDriveError
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
        Positive once the mode must end (what :func:`~belt_drive_ros.core.kernel_slip.switching`
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

    def force_parts(self, y, mode, sigma) -> tuple:
        """``(Q_max, Q, s')`` of samples ``y`` (N, 5): :meth:`limit` of their drive speed, :meth:`force` and
        :meth:`slip_speed` at that force (its slip-mode formula at every sample), made once for
        :meth:`outputs`, :meth:`damping_power` and :meth:`friction_power` of the same samples (``parts``)."""
        qmax = self.limit(y[..., 2])
        Q = self.force(y, mode, sigma, qmax)
        return qmax, Q, self.slip_speed(y, Q)

    def outputs(self, y, u, mode, sigma, parts=None) -> dict:
        """Output signals of samples ``y`` (N, 5), ``u`` (N, 2), ``mode``, ``sigma`` (N,).

        The keys of ``model.OUTPUT_UNITS`` (``slip`` is the slip *mode*,
        ``slack`` a slack span) plus :data:`SLIP_OUTPUT_UNITS`. ``parts``: :meth:`force_parts` of these samples
        when made (the same floats).
        """
        p = self.params
        y, u = np.asarray(y, dtype=float), np.asarray(u, dtype=float)
        if y.ndim == 1:  # one sample (the node's tick): the same formulas on plain floats
            y, u, mode, sigma = _Sample(y.tolist()), _Sample(u.tolist()), int(mode), float(sigma)
        else:
            mode = np.asarray(mode)
        phi_M, theta_e, omega_M, omega_3, s = y[..., 0], y[..., 1], y[..., 2], y[..., 3], y[..., 4]  # read once
        qmax, Q, sdot = self.force_parts(y, mode, sigma) if parts is None else parts
        speed = _where(mode == SLIP, sdot, 0.0)
        a1, g, r_3 = p.r_M / p.R_1, p.gear_ratio, p.r_3
        half = 0.5 * abs(Q)  # the tight span is the one the belt torque stretches, either way (model.span_forces)
        slack_force = p.F_0 - half
        tight = p.F_0 + half
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

    def damping_power(self, y, mode, sigma, parts):
        """Bearing and span damping losses b_f omega_M^2 + b_3 omega_3^2 + 2 c delta'^2 [W] (``parts``:
        :meth:`force_parts` of the same samples)."""
        p = self.params
        _, Q, sdot = parts
        rel = y @ self.rel_row
        ddelta = np.where(np.asarray(mode) == SLIP, rel - sdot, rel)
        return p.bearing_damping_drive_side * y[..., 2] ** 2 + p.b_3 * y[..., 3] ** 2 + 2.0 * p.c * ddelta**2

    def friction_power(self, y, mode, sigma, parts):
        """Friction loss Q s' = Q_max |s'| while slipping [W] (``parts``: :meth:`force_parts` of the same samples)."""
        _, Q, sdot = parts
        return np.where(np.asarray(mode) == SLIP, Q * sdot, 0.0)


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


# ================================================================ events
@dataclass
class Event:
    """One mode switch: time [s], kind ('onset' or 'restick'), direction sigma, state there."""

    time: float
    kind: str
    sigma: float
    state: np.ndarray


class EventStep:
    """The compiled step of the hybrid model across its events (:func:`~belt_drive_ros.core.kernel_slip.event_step`).

    Bound to a model, a fixed-step method and the torques as data
    (``data`` = (drive data, load data, uses_angle): the plant's). The
    events are located on the step's continuous extension and the partial
    steps taken on the modal flow: ``exact`` and ``etd2`` by their own step
    of any length, every other method by ``etd4`` (fourth order, exact in
    the linear part); a whole step the method already took (``y1``) is kept
    when it holds no event.
    """

    def __init__(self, model: SlippingBeltModel, method: str, data, kernel=False):
        from . import kernel_slip

        self.model = model
        p = model.params
        self._two_k_r3, self._r3 = 2.0 * p.k * p.r_3, p.r_3
        #: the arrays :func:`~belt_drive_ros.core.kernel_slip.event_step` reads (None: no compiled event step);
        #: ``kernel``: those of this model, method and data already packed (read-only: shared)
        if kernel is False:
            kernel = None if None in data[:2] else kernel_slip.pack(model, method, *data)
        self._kernel = kernel
        self._event_step = kernel_slip.event_step
        self._event_buffer = np.zeros((kernel_slip.MAX_SWITCHES + 1, 8))

    def onset(self, y) -> tuple[int, float, np.ndarray]:
        """(SLIP, sigma, y) of a sticking state ``y`` at the limit: sliding with the force's sign
        (c = 0: the stretch set on the limit exactly, the total deflection kept)."""
        sigma = 1.0 if float(self.model.q_row @ y) >= 0.0 else -1.0
        if self.model.params.c == 0.0:
            te = sigma * self.model.limit(float(y[2])) / self._two_k_r3
            y = y.copy()
            y[4] += self._r3 * (y[1] - te)
            y[1] = te
        return SLIP, sigma, y

    def advance(self, t0, t1, y, mode, sigma, cuts=(), events=None, dt=None, hi_end=math.inf, y1=None):
        """(y, mode, sigma) at ``t1`` [s] from ``y`` at ``t0``: sub-steps end at each cut, then at each located event.

        ``dt``: the grid step when this is a whole grid step; ``hi_end``: torque
        times clipped there in the last sub-step; ``y1``: the method's state at
        ``t1`` in ``mode`` when already known (a step without cuts). ``events``
        receives the mode switches (:class:`Event`).
        """
        if self._kernel is None:
            raise SlipError("slip: the slipping model needs torque profiles with a data form and modes with a modal "
                            "split (diagonalisable stick and slip matrices)")  # fmt: skip
        yk = np.array(y, dtype=float)
        given = 0 if (len(cuts) or y1 is None) else 1
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
