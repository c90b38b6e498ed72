"""A belt network stepped to a target time with held inputs (no rclpy, no physics of its own).

The node (:mod:`.network_node`) and the re-simulation of its recordings
(``belt-drive sim REC.mcap``) advance a network through this one adapter,
so both take the same steps with the same inputs: their states agree bit
for bit. It only calls the core: the network model's matrices
(:class:`~belt_drive_ros.core.network.model.NetworkModel`), the scene's
fixed-step method (``Integrator.step``, the call the core's whole-run
:func:`~belt_drive_ros.core.network.model.simulate` makes at each step
``k``, at time ``k dt``) and the core's ``outputs``. Scene-driven
(nothing held) it therefore reproduces ``simulate`` exactly.

Inputs: pulley i's torque is ``u_i = sign_i Q_i`` (``sign`` +1 for the
driver, -1 for an accessory: the profile's value is the torque it takes
from the belt). ``Q_i`` is the scene's profile ``Q_i(t, theta_i, omega_i)``
until :meth:`NetworkStepper.hold` gives pulley i a value [N m]; from then on
that value, held constant (zero-order hold), until the next ``hold``.

When the compiled network kernel lands, it replaces the loop in
:meth:`NetworkStepper.advance` behind the same call.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.errors import SceneError, SimulationDivergedError
from ..core.integrators import method_class
from ..core.network.model import NetworkModel, check_step, outputs
from ..core.network.scene import ROLE_SIGN

__all__ = ["NetworkStepper"]


class NetworkStepper:
    """Advance a network scene's state ``x = [q, q']`` on the grid ``k dt`` with held pulley torques.

    Parameters
    ----------
    scene : NetworkScene
    method : str, optional
        Fixed-step method (default the scene's).
    dt : float, optional
        Step [s] (default the scene's).
    """

    def __init__(self, scene, method: str | None = None, dt: float | None = None):
        self.scene = scene
        self.model = NetworkModel.build(scene)
        self.method = method or scene.method
        self.dt = float(scene.dt if dt is None else dt)
        cls = method_class(self.method)
        A, B = self.model.state_space()
        check_step(cls, self.method, A, self.dt)
        self._cls, self._A, self._B = cls, A, B
        self.n = len(scene.pulleys)
        self.m = self.model.M.shape[0]
        #: per pulley the sign of its torque on the belt (driver +1, accessory -1, else 0), with or without a profile
        self.signs = [ROLE_SIGN.get(p.role, 0.0) for p in scene.pulleys]
        self._profiles = [(i, p.sign, p.torque.scalar_torque()) for i, p in enumerate(scene.pulleys) if p.sign]
        #: per pulley the held torque [N m] (profile sign convention) or None: the scene's profile
        self.held: list[float | None] = [None] * self.n
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """A fresh integrator (the run starts again at k = 0); held values are kept."""
        self.integ = self._cls(self._A, self._B, self.dt)

    def initial(self) -> np.ndarray:
        """The scene's initial state: the belt turning at ``initial_speed`` unstretched."""
        x = np.zeros(2 * self.m)
        x[self.m : self.m + self.n] = self.model.speeds_at(self.scene.initial_speed)
        return x

    def hold(self, pulley: int, value: float | None) -> None:
        """Hold pulley ``pulley``'s torque at ``value`` [N m] from now on (None: back to the profile)."""
        if value is not None and self.signs[pulley] == 0.0:
            raise SceneError(f"{self.scene.pulleys[pulley].name}: an idler takes no torque")
        self.held[pulley] = None if value is None else float(value)

    # ----------------------------------------------------------------- inputs
    def inputs(self, t: float, x) -> np.ndarray:
        """The n pulley torques ``u`` [N m] at time ``t`` [s] and state ``x`` (held values or profiles)."""
        held, m = self.held, self.m
        xs = x.tolist()
        u = [0.0] * self.n
        for i, s, f in self._profiles:
            if held[i] is None:
                u[i] = s * f(t, xs[i], xs[m + i])
        for i, value in enumerate(held):
            if value is not None:
                u[i] = self.signs[i] * value
        return np.array(u)

    # ---------------------------------------------------------------- stepping
    def step_index(self, t: float) -> int:
        """The grid index ``k`` of time ``t`` [s] (``t`` must lie on the grid to a part in 1e9 of a step)."""
        k = round(t / self.dt)
        if abs(k * self.dt - t) > 1e-9 * self.dt + 1e-15:
            raise SceneError(f"t = {t!r} s is not on the step grid of {self.dt:g} s")
        return int(k)

    def advance(self, x, k0: int, k1: int) -> np.ndarray:
        """The state after the steps ``k0 .. k1-1`` (times ``k dt``) from ``x`` at ``k0 dt``.

        Raises :class:`SimulationDivergedError` when the state becomes non-finite.
        """
        step, dt, inputs = self.integ.step, self.dt, self.inputs
        for k in range(k0, k1):
            x = step(k * dt, x, inputs)
            if not math.isfinite(x.sum()):
                raise SimulationDivergedError(f"{self.scene.name}: the state became non-finite at t = {k * dt:.6g} s "
                                              f"({self.method} at dt = {dt:g} s)")
        return x

    def sample(self, k: int, x):
        """The run's outputs (:class:`~belt_drive_ros.core.network.model.NetworkRun`, one sample) at step ``k``
        and the pulley torques ``u`` [N m] applied there."""
        t = k * self.dt
        return outputs(self.model, np.array([t]), np.asarray(x, dtype=float)[None, :]), self.inputs(t, x)
