"""A belt network stepped to a target time with held inputs (no rclpy, no physics of its own).

The node (:mod:`.network_node`) and the re-simulation of its recordings
(``belt-drive sim REC.mcap``) advance a network through this one adapter,
so both take the same steps with the same inputs: their states agree bit
for bit. It only calls the core: the network's compiled loop for the tier
``belt-drive sim`` chooses (:class:`~belt_drive_ros.core.network.simulate.NetworkLoop`,
advanced by :func:`~belt_drive_ros.core.network.simulate.advance`, the call
the whole-run :func:`~belt_drive_ros.core.network.simulate.simulate` makes)
and the core's outputs. Scene-driven (nothing held) it therefore reproduces
``simulate`` exactly. States are the loop's own (flexible: the driver's
angle and the other pulleys' lags; rigid: the driver's angle and speed;
slipping: :func:`~belt_drive_ros.core.network.slip.slip_state`, the pulleys'
and arm's angles, speeds and slips, the stick/slip mode and the works, so a
tick continues the slipping run exactly where the last one stopped:
:func:`~belt_drive_ros.core.network.slip.advance_slipping`, the call the
whole offline slipping run makes).

Inputs: pulley i's torque is ``u_i = sign_i Q_i`` (``sign`` +1 for the
driver, -1 for an accessory: the profile's value is the torque it takes
from the belt). ``Q_i`` is the scene's profile ``Q_i(t, theta_i, omega_i)``
until :meth:`NetworkStepper.hold` gives pulley i a value [N m]; from then on
that value, held constant (zero-order hold), until the next ``hold``.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from ..core.errors import SceneError
from ..core.kernel import wheel_steps
from ..core.network.model import arm_swing, grid_breakpoints
from ..core.network.scene import ROLE_SIGN
from ..core.network.simulate import (LIMIT, NetworkLoop, advance, auto_tier, clamp, model_of, outputs,
                                     rigid_outputs)
from ..core.network.tick import network_tick
from ..core.profile_data import CONSTANT, OK

__all__ = ["NetworkStepper"]


class NetworkStepper:
    """Advance a network scene's state on the grid ``k dt`` with held pulley torques.

    Parameters
    ----------
    scene : NetworkScene
    method : str, optional
        Fixed-step method (default the scene's).
    dt : float, optional
        Step [s] (default the scene's).
    tier : str, optional
        ``flexible``, ``rigid`` or ``slipping`` (default: the tier ``model: auto`` chooses for the scene's run,
        :func:`~belt_drive_ros.core.network.simulate.auto_tier`).
    """

    def __init__(self, scene, method: str | None = None, dt: float | None = None, tier: str | None = None):
        self.scene = scene
        self.model = model_of(scene)
        self.method = method or scene.method
        self.dt = float(scene.dt if dt is None else dt)
        self.tier = tier or auto_tier(scene, self.method, self.dt)[0]
        self.n = len(scene.pulleys)
        self.m = self.model.M.shape[0]
        self._hf = self._hv = None  # the compiled tick's held flags and values (linear tiers: views into its arrays)
        if self.tier == "slipping":
            from ..core.network.slip import SlipArrays

            self.method = "exact"  # the slipping tier's one method
            self.loop = SlipArrays(self.model, self.dt)  # its own: hold() writes into it
            self._names = [p.name for p in scene.pulleys]
        else:
            self.loop = NetworkLoop(self.model, self.tier, self.method, self.dt)  # its own: hold() writes into it
            self._rows = (self.loop.pk.copy(), self.loop.pp.copy())
            self._pack(scene)
            loop = self.loop
            #: the compiled loop's arguments after (times, x, out, lo, hi, limit) (hold() writes into pk, pp in place):
            #: those NetworkLoop's call gives wheel_steps (both profile banks the loop's stack)
            stacked = (loop.pk, loop.pp, loop.px, loop.py)
            self._kernel_args = (*loop.args, loop.start, *stacked, *stacked, *loop._none)
            # advance's breakpoints: a tick with none of its cuts inside is one call of the loop (the fast path)
            self._marks, self._left, inside = grid_breakpoints(self.model, self.dt)
            self._split = sorted(inside)  # steps split at a breakpoint inside them
            self._grid = sorted(k for k in (round(b / self.dt) for b in self._marks) if k * self.dt in self._marks)
        d, m = scene.driver, self.m
        #: per pulley i != driver (i, rho_i): theta_i = rho_i theta_d - l_i (the flexible tier's lags)
        self._lags = [(i, float(r)) for i, r in enumerate(self.model.ratios) if i != d]
        self._rho = [float(r) for r in self.model.ratios]
        self._arm = m > self.n
        #: per pulley the sign of its torque on the belt (driver +1, accessory -1, else 0), with or without a profile
        self.signs = [ROLE_SIGN.get(p.role, 0.0) for p in scene.pulleys]
        #: per pulley with a torque (held or profile): (index, sign, gear, profile uses its angle, scalar profile)
        self._profiles = [(i, p.sign, p.gear, p.torque is not None and p.torque.uses_angle,
                           _scalar_torque(p.torque) if p.torque is not None else None)
                          for i, p in enumerate(scene.pulleys) if p.sign or self.signs[i]]
        #: per pulley the held torque [N m] (profile sign convention) or None: the scene's profile
        self.held: list[float | None] = [None] * self.n
        #: the joint values of the last :meth:`tick` (positions, velocities, efforts) and its step index (-1: none)
        self.y, self.fresh = None, -1
        #: the compiled tick's (reals, ints) after :meth:`use_joints` (else None); its message buffer and bytes
        self._tick, self._msg, self.message = None, np.zeros(8, dtype=np.uint8), None
        self._outs, self._flip = [np.empty((0, 0)), np.empty((0, 0))], 0
        self._state = None  # the state the last compiled tick returned
        #: (t_a, t_b, lo, hi): ticks from t0 >= t_a to t1 <= t_b have no cut and the clamp (lo, hi) (see tick)
        self._window = (math.inf, -math.inf, -math.inf, math.inf)

    def _pack(self, scene) -> None:
        """The loop's arrays and the joint values' data as :class:`~belt_drive_ros.core.tick.PackedArrays`
        (the compiled tick's two buffers); the loop's ``pk, pp`` become their views (held torques written there)."""
        from ..core.network.tick import FLOATS, INTS, LAG, RIGID, SAME, STATIC
        from ..core.tick import PackedArrays

        loop, n, m, d = self.loop, len(scene.pulleys), self.model.M.shape[0], scene.driver
        arm = m > n
        if self.tier == "flexible":
            jkind = [SAME if i == d or i >= n else LAG for i in range(m)]
        else:  # (the rigid tier's arm: at its quasi-static equilibrium)
            jkind = [RIGID] * n + [STATIC] * (m - n)
        armc = self.model.rigid_arm_row() if self.tier == "rigid" and arm else np.zeros(n + 2)
        rho = [float(r) for r in self.model.ratios] + [0.0] * (m - n)
        row = [-1] * n
        for r, i in zip(loop.start, loop.active):
            row[i] = int(r)
        W, kinds, offsets, S, F, final_base, tol, max_iter, uses_angle = loop.args
        extra, guard = loop._none
        self._arrays = PackedArrays(
            (FLOATS, INTS),
            dict(W=W, offsets=offsets, S=S, F=F, pp=loop.pp, px=loop.px, py=loop.py, extra=extra, guard=guard, rho=rho,
                 value=np.zeros(n), tsign=[ROLE_SIGN.get(p.role, 0.0) for p in scene.pulleys],
                 gear=[float(p.gear) for p in scene.pulleys], qp=self._rows[1], y=np.zeros(3 * (n + int(arm))),
                 armc=armc, fscalars=[self.dt, 0.0, LIMIT, tol]),
            dict(kinds=kinds, uses_angle=uses_angle, start=loop.start, pk=loop.pk, jkind=jkind, held=np.zeros(n),
                 uses=[int(p.torque is not None and p.torque.uses_angle) for p in scene.pulleys], row=row,
                 qk=self._rows[0], iscalars=[final_base, max_iter, d, int(arm), -1, -1, -1, -1]))
        views = self._arrays.views
        loop.pk, loop.pp = views["pk"], views["pp"]  # (no piece of the loop exists yet: they share these)
        self._hf, self._hv = views["held"], views["value"]

    def use_joints(self, theta0: float, message: tuple | None = None) -> None:
        """Let :meth:`tick` write the joint values (``theta0``: the arm's installed angle [rad], 0.0 without an
        arm) into :attr:`y`; ``message``: ``(template, offsets)`` of the ``joint_states`` CDR
        (:attr:`~belt_drive_ros.io.cdr_encoders.JointStateEncoder.layout`), which :meth:`tick` then writes too
        (:attr:`message`, stamped). The slipping tier has no compiled tick."""
        if self.tier == "slipping":
            return
        views = self._arrays.views
        views["fscalars"][1] = theta0
        if message is not None:
            from ..core.tick import joints_message

            self._msg, where, at = joints_message(*message)
            self.message = memoryview(self._msg)[where]
            views["iscalars"][4:] = [int(a) for a in at]
        self.y = views["y"]
        self._tick = (self._arrays.reals, self._arrays.ints)
        from ..core.tick import load_compiled

        load_compiled(network_tick, (0, 1, np.zeros(1), np.empty((1, 1)), -math.inf, math.inf, *self._tick, self._msg, 0))

    def stage(self, pulley: int, value: float | None) -> None:
        """The torque :meth:`tick`'s joint values show for pulley ``pulley`` (the value :meth:`hold` is given right
        after the tick; the steps take the values held before)."""
        if self._hf is None:
            return
        self._hf[pulley] = value is not None
        if value is not None:
            self._hv[pulley] = value

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """The run starts again at k = 0 (the loop keeps no history); held values are kept."""

    def initial(self) -> np.ndarray:
        """The scene's initial state: the belt turning at ``initial_speed`` unstretched."""
        if self.tier == "slipping":
            from ..core.network.slip import slip_state

            return slip_state(self.model, self.loop, speed=self.scene.initial_speed)
        return self.loop.initial()

    def hold(self, pulley: int, value: float | None) -> None:
        """Hold pulley ``pulley``'s torque at ``value`` [N m] from now on (None: back to the profile)."""
        if value is not None and self.signs[pulley] == 0.0:
            raise SceneError(f"{self.scene.pulleys[pulley].name}: an idler takes no torque")
        before = self.held[pulley]
        if value is not None and before is not None and _same(before, float(value)):
            return  # held already (the node holds its inputs again every tick)
        self.held[pulley] = None if value is None else float(value)
        self.stage(pulley, value)
        if self.tier == "slipping":
            self.loop.hold(pulley, value, self.signs[pulley])
        elif pulley in self.loop.active:
            if value is None:
                row = self.loop.start[self.loop.active.index(pulley)]
                self.loop.pk[row], self.loop.pp[row] = self._rows[0][row], self._rows[1][row]
            else:
                self.loop.hold(pulley, float(value))

    # ----------------------------------------------------------------- inputs
    def inputs(self, t: float, x, full=None) -> np.ndarray:
        """The n pulley torques ``u`` [N m] at time ``t`` [s] and state ``x`` (held values or profiles);
        ``full``: :meth:`absolute` of ``x`` when the caller has it."""
        full = self.absolute(x) if full is None else full
        n, m = self.n, self.m
        return np.array(self.torques(t, full[0, :n].tolist(), full[0, m : m + n].tolist()))

    def torques(self, t: float, angle: list, speed: list) -> list:
        """The n pulley torques ``u`` [N m] (Python floats) at time ``t`` [s] and the pulleys' own angles and
        speeds (Python floats: the profiles' scalar evaluation is cheaper on them)."""
        u = [0.0] * self.n
        t = float(t)
        held, signs = self.held, self.signs
        for i, sign, gear, uses_angle, torque in self._profiles:
            value = held[i]
            if value is not None:
                u[i] = signs[i] * value / gear
            elif not sign:  # no profile: nothing until held
                continue
            elif gear == 1.0:  # NetworkPulley.load's formula, the profile's scalar evaluation
                u[i] = sign * torque(t, angle[i] if uses_angle else 0.0, speed[i])
            else:
                u[i] = sign * torque(t, (angle[i] if uses_angle else 0.0) / gear, speed[i] / gear) / gear
        return u

    def pulley_state(self, k: int, x) -> tuple[list, list, list]:
        """``(angle, speed, u)`` at step ``k`` as Python floats: the absolute state's angles and speeds (m each,
        the arm's last; :meth:`absolute`'s values, computed by the same operations) and the n pulley torques
        (:meth:`torques`). What a tick needs for ``joint_states`` alone, without numpy on tiny arrays."""
        xs = x.tolist() if isinstance(x, np.ndarray) else list(x)
        m = self.m
        if self.tier == "flexible":  # theta_i = rho_i theta_d - l_i (to_absolute's operations)
            angle = xs[:m]
            theta_d = xs[self.scene.driver]
            for i, rho in self._lags:
                angle[i] = rho * theta_d - xs[i]
            speed = xs[m : 2 * m]
        elif self.tier == "rigid":  # the arm where the quasi-static tensions hold it (rigid_outputs' arm_swing)
            angle = [xs[0] * rho for rho in self._rho] + ([0.0] if self._arm else [])
            speed = [xs[1] * rho for rho in self._rho] + ([0.0] if self._arm else [])
            u = self.torques(k * self.dt, angle, speed)
            if self._arm:
                angle[-1] = float(arm_swing(self.model.rigid_arm_row().tolist(), xs[0], xs[1], u))
            return angle, speed, u
        else:
            angle, speed = xs[:m], xs[m : 2 * m]
        return angle, speed, self.torques(k * self.dt, angle, speed)

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
        x = np.asarray(x, dtype=float)
        if k1 <= k0:
            return x
        if self.tier == "slipping":
            from ..core.network.slip import advance_slipping

            x = x.copy()
            advance_slipping(self.loop, x, k0, k1, None, self.scene.name, self._names)
            return x
        out = np.empty((k1 - k0, x.size))
        if self._cut(k0, k1):  # advance cuts these steps
            advance(self.loop, x, out, k0, k1)
            return out[-1]
        lo, hi = clamp(self._marks, self._left, k0 * self.dt, k1 * self.dt)
        # whole steps between breakpoints: the one kernel call advance makes for them, its arguments kept
        times = np.arange(k0, k1 + 1) * self.dt
        if not x.flags.c_contiguous:
            x = np.ascontiguousarray(x)
        status = wheel_steps(times, x, out, lo, hi, LIMIT, *self._kernel_args)[1]
        if status != OK:  # advance again: it raises the error that names the step
            advance(self.loop, x, out, k0, k1)
        return out[-1]

    def _cut(self, k0: int, k1: int) -> bool:
        """``advance`` cuts a step of ``k0 .. k1-1`` (split at a breakpoint inside, or a grid breakpoint between)."""
        split, grid = self._split, self._grid
        i, j = bisect.bisect_left(split, k0), bisect.bisect_right(grid, k0)
        return (i < len(split) and split[i] < k1) or (j < len(grid) and grid[j] < k1)

    def tick(self, x, k0: int, k1: int, stamp: int = 0) -> np.ndarray:
        """:meth:`advance`'s state, and for a tick of whole steps between breakpoints (after :meth:`use_joints`)
        the joint values at step ``k1`` into :attr:`y` in the same compiled call (:attr:`fresh` = ``k1``; those of
        ``pulley_state`` and the layout's ``joint_values``, with the torques :meth:`stage` gave, bit for bit) and,
        with a message layout, the ``joint_states`` CDR stamped ``stamp`` [ns] into :attr:`message`.

        The compiled tick's state is a row of one of two buffers it writes in turn: valid until the tick after
        the next (a caller keeps it longer by copying)."""
        self.fresh = -1
        if x is not self._state and (self._tick is None or not isinstance(x, np.ndarray) or not x.flags.c_contiguous):
            return self.advance(x, k0, k1)  # (the state the last compiled tick returned is one of its C rows)
        if k1 <= k0:
            return self.advance(x, k0, k1)
        t0, t1 = k0 * self.dt, k1 * self.dt
        t_a, t_b, lo, hi = self._window
        if not (t_a <= t0 and t1 <= t_b):
            if self._cut(k0, k1):
                return self.advance(x, k0, k1)
            lo, hi = clamp(self._marks, self._left, t0, t1)
            marks = self._marks
            i = bisect.bisect_right(marks, t0) - 1
            if i + 1 == bisect.bisect_left(marks, t1):  # no mark between: the ticks up to the next mark are alike
                self._window = (marks[i] if i >= 0 else -math.inf, marks[i + 1] if i + 1 < len(marks) else math.inf,
                                lo, hi)
        self._flip ^= 1
        out = self._outs[self._flip]
        if out.shape[0] != k1 - k0 or x is not self._state:
            out = self._outs[self._flip] = np.empty((k1 - k0, x.size))
        if network_tick(k0, k1 - k0, x, out, lo, hi, *self._tick, self._msg, stamp)[1] != OK:
            advance(self.loop, x, out, k0, k1)  # it raises the error that names the step
            return out[-1]
        self.fresh = k1
        self._state = x = out[-1]
        return x

    def run(self, steps: int) -> np.ndarray:
        """States (steps + 1, n_x) from the scene's start (the whole run, as ``simulate`` steps it)."""
        x = self.initial()
        out = np.empty((steps + 1, x.size))
        out[0] = x
        if self.tier == "slipping":  # the whole run's states, then each step's whole state (as the ticks keep it)
            from ..core.network.slip import advance_slipping

            N, n = self.loop.N, self.n
            rows = (np.empty((steps + 1, N)), np.zeros((steps + 1, n), dtype=np.int64), np.empty((steps + 1, n)),
                    np.zeros((steps + 1, n)), np.zeros((steps + 1, n)), np.zeros((steps + 1, n)))
            rows[0][0], rows[2][0] = x[:N], x[N + 4 * n : N + 5 * n]
            advance_slipping(self.loop, x, 0, steps, rows, self.scene.name, self._names)
            for j, part in ((0, rows[1]), (2, rows[4]), (3, rows[5]), (4, rows[2]), (5, rows[3])):
                out[:, N + j * n : N + (j + 1) * n] = part
            out[:, :N] = rows[0]
            out[1:, N + n : N + 2 * n] = np.nan  # which pulleys are fresh is kept for the last step only
            out[-1] = x
            return out
        advance(self.loop, x, out[1:], 0, steps)
        return out

    def absolute(self, x) -> np.ndarray:
        """The (1, 2m) state ``[theta, theta_a, omega, omega_a]`` in the pulleys' own angles of loop state ``x``
        (the ``states`` of :meth:`sample`'s run, computed as it computes them)."""
        X = np.asarray(x, dtype=float)[None, :]
        if self.tier == "rigid":
            n, m, rho = self.n, self.m, self.model.ratios
            full = np.zeros((1, 2 * m))
            full[:, :n], full[:, m : m + n] = X[:, :1] * rho, X[:, 1:2] * rho
            return full
        if self.tier == "slipping":
            return X[:, : 2 * self.m]
        return self.model.to_absolute(X)

    def sample(self, k: int, x):
        """The run's outputs (:class:`~belt_drive_ros.core.network.model.NetworkRun`, one sample) at step ``k``
        and the pulley torques ``u`` [N m] applied there."""
        t = k * self.dt
        X = np.asarray(x, dtype=float)[None, :]
        full = self.absolute(x)
        u = self.inputs(t, x, full)
        if self.tier == "rigid":
            return rigid_outputs(self.loop, np.array([t]), X, u[None, :]), u
        if self.tier == "slipping":
            from ..core.network.slip import slip_run

            N, n = self.loop.N, self.n
            p = lambda j: X[:, N + j * n : N + (j + 1) * n]  # noqa: E731 - the packed state's parts
            return slip_run(self.model, np.array([t]), X[:, :N], p(0), p(4), p(5), p(2), p(3)), u
        return outputs(self.model, np.array([t]), full, self.model.run_tensions(X)), u


def _scalar_torque(profile):
    """The profile's scalar ``f(t, angle, speed)``; a constant profile's value without a call into the kernel (the
    kernel's constant row returns its value, whatever t, angle and speed)."""
    data = profile.data()
    if data is not None and data.kinds.size == 1 and data.kinds[0] == CONSTANT:
        value = float(data.params[0, 0])
        return lambda t, angle, speed: value
    return profile.scalar_torque()


def _same(a: float, b: float) -> bool:
    """``a`` and ``b`` are the same float, sign of zero included (a held -0.0 N m publishes as -0.0)."""
    return a == b and (a != 0.0 or math.copysign(1.0, a) == math.copysign(1.0, b))
