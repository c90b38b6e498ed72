"""Rigid-belt (1 DOF) and flexible-belt (2 DOF) models of the accessory drive.

Both models are stateless: every function takes the state ``x`` (and the
input ``u``) and returns derived quantities; the simulator or the ROS node
owns the state. Both are linear time-invariant systems::

    x' = A x + B u,      u = [drive_torque, load_torque]   [N m]

with the drive torque acting on wheel M and the load torque on wheel 3
(opposing positive rotation). State ordering, written down once:

* flexible: ``x = [phi_M, phi_3, omega_M, omega_3]``  [rad, rad, rad/s, rad/s]
* rigid:    ``x = [phi_M, omega_M]``                  [rad, rad/s]

Equations of motion (derived step by step in ``docs/model.md``; the paper's eq. 18/20
with its errata corrected, plus belt span damping c and bearing damping b)::

    M q'' + C q' + K q = [M_drive, -M_load],   q = [phi_M, phi_3]
    M = diag(I_f, I_3)
    K = 2k [[r_2^2 g^2, -r_2 r_3 g], [-r_2 r_3 g, r_3^2]]
    C = 2c [[r_2^2 g^2, -r_2 r_3 g], [-r_2 r_3 g, r_3^2]] + diag(b_f, b_3)

    rigid:  I_red phi_M'' + b_red phi_M' = M_drive - i M_load

The relative deflection ``delta = i phi_M - phi_3`` [rad at wheel 3] is the
lag of wheel 3 behind the position a rigid belt would give it; the belt
torque on wheel 3 is ``T_b = 2 k r_3^2 delta + 2 c r_3^2 delta'``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .params import BeltDriveParams

#: Names of the per-sample output signals, in CSV/plot order. SI units.
OUTPUT_UNITS: dict[str, str] = {
    "phi_M": "rad",
    "omega_M": "rad/s",
    "phi_1": "rad",
    "omega_1": "rad/s",
    "phi_2": "rad",
    "omega_2": "rad/s",
    "phi_3": "rad",
    "omega_3": "rad/s",
    "drive_torque": "N m",
    "load_torque": "N m",
    "belt_torque": "N m",
    "relative_deflection": "rad",
    "span_force_tight": "N",
    "span_force_slack": "N",
    "slack": "bool",
    "slip": "bool",
}


@dataclass(frozen=True)
class _LinearModel:
    """Common part of the two models: matrices built once from ``params``."""

    params: BeltDriveParams
    A: np.ndarray
    B: np.ndarray

    name: ClassVar[str] = ""
    n_states: ClassVar[int] = 0

    # -- torque coordinates -------------------------------------------------
    def wheel_coordinates(self, x: np.ndarray) -> tuple:
        """(phi_M, omega_M, phi_3, omega_3) of state(s) ``x`` (last axis = state)."""
        raise NotImplementedError

    def derivatives(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """x' = A x + B u (``t`` unused: the model is time-invariant)."""
        return self.A @ x + self.B @ u

    def outputs(self, x: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
        """All output signals of :data:`OUTPUT_UNITS` for samples ``x`` (N, n), ``u`` (N, 2)."""
        raise NotImplementedError

    # -- helpers shared by both models --------------------------------------
    def _span_forces(self, belt_torque: np.ndarray) -> tuple:
        """Span forces and slack/slip flags from the belt torque at wheel 3.

        The transmitted force Q = T_b / r_3 splits symmetrically about the
        pre-tension: F_tight = F_0 + |Q|/2, F_slack = F_0 - |Q|/2. A span
        cannot push (F_slack < 0: slack), and the capstan (Euler-Eytelwein)
        limit F_tight <= F_slack e^(mu*wrap) bounds what friction transmits
        (beyond it: slip). Either flag means the linear model is outside its
        validity.
        """
        p = self.params
        half = 0.5 * np.abs(belt_torque) / p.r_3
        tight = p.F_0 + half
        slack_force = p.F_0 - half
        slack = slack_force <= 0.0
        slip = slack | (tight > slack_force * p.capstan_ratio)
        return tight, slack_force, slack, slip

    def _wheels(self, phi_M, omega_M, phi_3, omega_3, u, belt_torque, deflection):
        p = self.params
        a1 = p.r_M / p.R_1
        g = p.gear_ratio
        tight, slack_force, slack, slip = self._span_forces(belt_torque)
        return {
            "phi_M": phi_M,
            "omega_M": omega_M,
            "phi_1": a1 * phi_M,
            "omega_1": a1 * omega_M,
            "phi_2": g * phi_M,
            "omega_2": g * omega_M,
            "phi_3": phi_3,
            "omega_3": omega_3,
            "drive_torque": u[..., 0],
            "load_torque": u[..., 1],
            "belt_torque": belt_torque,
            "relative_deflection": deflection,
            "span_force_tight": tight,
            "span_force_slack": slack_force,
            "slack": slack,
            "slip": slip,
        }


class FlexibleBeltModel(_LinearModel):
    """Two-degree-of-freedom model: elastic, damped belt between wheels 2 and 3.

    ``x = [phi_M, phi_3, omega_M, omega_3]``. See the module docstring for the
    equations; :attr:`mass_matrix`, :attr:`stiffness_matrix` and
    :attr:`damping_matrix` are M, K, C there.
    """

    name: ClassVar[str] = "flexible"
    n_states: ClassVar[int] = 4

    def __init__(self, params: BeltDriveParams):
        p = params
        g = p.gear_ratio
        shape = np.array([[p.r_2**2 * g**2, -p.r_2 * p.r_3 * g], [-p.r_2 * p.r_3 * g, p.r_3**2]])
        mass = np.diag([p.inertia_drive_side, p.I_3])
        stiffness = 2.0 * p.k * shape  # K, symmetric PSD (erratum 1 fixed)
        damping = 2.0 * p.c * shape + np.diag([p.bearing_damping_drive_side, p.b_3])
        minv = np.diag(1.0 / np.diag(mass))
        A = np.zeros((4, 4))
        A[0:2, 2:4] = np.eye(2)  # phi' = omega
        A[2:4, 0:2] = -minv @ stiffness  # omega' = -M^-1 K phi - M^-1 C omega + ...
        A[2:4, 2:4] = -minv @ damping
        B = np.zeros((4, 2))
        B[2, 0] = 1.0 / p.inertia_drive_side  # drive torque on M
        B[3, 1] = -1.0 / p.I_3  # load torque opposes wheel 3 (erratum 2 fixed)
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "mass_matrix", mass)
        object.__setattr__(self, "stiffness_matrix", stiffness)
        object.__setattr__(self, "damping_matrix", damping)

    def wheel_coordinates(self, x):
        return x[..., 0], x[..., 2], x[..., 1], x[..., 3]

    def relative_deflection(self, x: np.ndarray) -> np.ndarray:
        """delta = i phi_M - phi_3 [rad]."""
        return self.params.ratio * x[..., 0] - x[..., 1]

    def belt_torque(self, x: np.ndarray) -> np.ndarray:
        """T_b = 2 k r_3^2 delta + 2 c r_3^2 delta' [N m], torque of the belt on wheel 3."""
        p = self.params
        i = p.ratio
        delta = i * x[..., 0] - x[..., 1]
        delta_dot = i * x[..., 2] - x[..., 3]
        return 2.0 * p.r_3**2 * (p.k * delta + p.c * delta_dot)

    def outputs(self, x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        return self._wheels(
            x[..., 0], x[..., 2], x[..., 1], x[..., 3], u, self.belt_torque(x), self.relative_deflection(x)
        )

    # -- energies -------------------------------------------------------------
    def kinetic_energy(self, x: np.ndarray) -> np.ndarray:
        """T = 1/2 q'^T M q' [J] (wheels M, 1, 2 via the gear ratios)."""
        w = x[..., 2:4]
        return 0.5 * np.einsum("...i,ij,...j->...", w, self.mass_matrix, w)

    def potential_energy(self, x: np.ndarray) -> np.ndarray:
        """V = 1/2 q^T K q = 2 (1/2) k (r_2 phi_2 - r_3 phi_3)^2 [J] (paper eq. 15)."""
        q = x[..., 0:2]
        return 0.5 * np.einsum("...i,ij,...j->...", q, self.stiffness_matrix, q)

    def dissipation_power(self, x: np.ndarray) -> np.ndarray:
        """P_d = q'^T C q' = 2 D_D (Rayleigh) [W], power lost in belt and bearings."""
        w = x[..., 2:4]
        return np.einsum("...i,ij,...j->...", w, self.damping_matrix, w)

    def input_power(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """P_in = M_drive omega_M - M_load omega_3 [W]."""
        return u[..., 0] * x[..., 2] - u[..., 1] * x[..., 3]

    def total_energy(self, x: np.ndarray) -> np.ndarray:
        """E = T + V [J]."""
        return self.kinetic_energy(x) + self.potential_energy(x)

    # -- conversions ----------------------------------------------------------
    def state_from_rigid(
        self, x_rigid: np.ndarray, load_torque: float = 0.0, drive_torque: float | None = None
    ) -> np.ndarray:
        """Flexible state with the rigid motion and the quasi-static belt deflection.

        With ``drive_torque`` given, the deflection is the rigid model's own
        quasi-static ``T_b / (2 k r_3^2)`` including the torque that
        accelerates wheel 3 (no belt transient when switching during a
        run-up); otherwise the static ``M_L / (2 k r_3^2)``.
        """
        i = self.params.ratio
        phi, omega = float(x_rigid[0]), float(x_rigid[1])
        if drive_torque is None:
            delta = static_deflection(self.params, load_torque)
        else:
            rigid = RigidBeltModel(self.params)
            tb = float(rigid.belt_torque(np.array([phi, omega]), np.array([drive_torque, load_torque])))
            delta = tb / self.params.belt_torsional_stiffness
        return np.array([phi, i * phi - delta, omega, i * omega])


class RigidBeltModel(_LinearModel):
    """One-degree-of-freedom model (paper eq. 12-14, load reduced through i).

    ``x = [phi_M, omega_M]``; wheel 3 follows ``phi_3 = i phi_M``. The belt
    torque on wheel 3 is what wheel 3's own equation needs,
    ``T_b = I_3 i phi_M'' + b_3 i omega_M + M_load``, and the reported
    relative deflection is its quasi-static value ``T_b / (2 k r_3^2)``.
    """

    name: ClassVar[str] = "rigid"
    n_states: ClassVar[int] = 2

    def __init__(self, params: BeltDriveParams):
        p = params
        A = np.array([[0.0, 1.0], [0.0, -p.bearing_damping_reduced / p.inertia_reduced]])
        B = np.array([[0.0, 0.0], [1.0 / p.inertia_reduced, -p.ratio / p.inertia_reduced]])
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "B", B)

    def wheel_coordinates(self, x):
        i = self.params.ratio
        return x[..., 0], x[..., 1], i * x[..., 0], i * x[..., 1]

    def belt_torque(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """T_b = I_3 i a_M + b_3 i omega_M + M_load [N m] (wheel 3's equation)."""
        p = self.params
        i = p.ratio
        accel = (u[..., 0] - i * u[..., 1] - p.bearing_damping_reduced * x[..., 1]) / p.inertia_reduced
        return p.I_3 * i * accel + p.b_3 * i * x[..., 1] + u[..., 1]

    def outputs(self, x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        i = self.params.ratio
        tb = self.belt_torque(x, u)
        return self._wheels(
            x[..., 0], x[..., 1], i * x[..., 0], i * x[..., 1], u, tb, tb / self.params.belt_torsional_stiffness
        )

    def kinetic_energy(self, x: np.ndarray) -> np.ndarray:
        """T = 1/2 I_red omega_M^2 [J] (paper eq. 11)."""
        return 0.5 * self.params.inertia_reduced * x[..., 1] ** 2

    def potential_energy(self, x: np.ndarray) -> np.ndarray:
        """V = 0: a rigid belt stores no energy [J]."""
        return np.zeros_like(x[..., 0])

    def dissipation_power(self, x: np.ndarray) -> np.ndarray:
        """P_d = b_red omega_M^2 [W]."""
        return self.params.bearing_damping_reduced * x[..., 1] ** 2

    def input_power(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """P_in = (M_drive - i M_load) omega_M [W]."""
        return (u[..., 0] - self.params.ratio * u[..., 1]) * x[..., 1]

    def total_energy(self, x: np.ndarray) -> np.ndarray:
        return self.kinetic_energy(x)

    def state_from_flexible(self, x_flex: np.ndarray) -> np.ndarray:
        """Rigid state [phi_M, omega_M] of a flexible state (drops the belt mode)."""
        return np.array([float(x_flex[0]), float(x_flex[2])])


def static_deflection(params: BeltDriveParams, load_torque: float) -> float:
    """Static relative deflection under a constant load: M_L / (2 k r_3^2) [rad]."""
    return load_torque / params.belt_torsional_stiffness


def make_model(kind: str, params: BeltDriveParams):
    """Model by name: ``"rigid"``, ``"flexible"`` or ``"slipping"`` (:class:`~belt_drive_ros.core.slip.SlippingBeltModel`)."""
    if kind == "rigid":
        return RigidBeltModel(params)
    if kind == "flexible":
        return FlexibleBeltModel(params)
    if kind == "slipping":
        from .slip import SlippingBeltModel

        return SlippingBeltModel(params)
    raise ValueError(f"model: unknown model {kind!r}; choose 'rigid', 'flexible', 'slipping' or 'auto'")


def paper_as_printed_stiffness(params: BeltDriveParams) -> np.ndarray:
    """The stiffness matrix exactly as printed in the paper's eq. 20 (erratum 1).

    Row 1 carries ``g`` where ``g^2`` belongs and lacks ``g`` in the coupling
    term, so the matrix is not symmetric. Exists only so that tests and docs
    can show what the erratum does; never used by a simulation.
    """
    p = params
    g = p.gear_ratio
    return 2.0 * p.k * np.array([[p.r_2**2 * g, -p.r_2 * p.r_3], [-p.r_2 * p.r_3 * g, p.r_3**2]])
