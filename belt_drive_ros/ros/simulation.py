"""The node's simulation: plant, state and scene time, advanced tick by tick (no rclpy).

:class:`NodeSimulation` is what :class:`~belt_drive_ros.ros.node.BeltDriveNode`
calls from every tick: :meth:`~NodeSimulation.advance_to` advances the
state from the last tick time to the new one through the core's one
engine (:class:`~belt_drive_ros.core.stepper.Stepper`, on the grid
``k dt`` of scene time, with partial steps and splits at torque
breakpoints), samples the drive input for the next interval, and
:meth:`~NodeSimulation.outputs` evaluates every output signal at that time
with the model's own ``outputs(x, u)``. The slipping model advances through
the same engine as the offline run (:class:`~belt_drive_ros.core.slip_run.SlippingSimulator`:
phases in the stepper's compiled loop, mode switches located as events
inside a tick), so in ``/clock`` lockstep its outputs equal ``belt-drive
sim`` bit for bit as well. Times are integers [ns] on the
node's time base; scene time ``t = (now - origin) / 1e9`` [s] starts at 0
when the run starts (the first tick, the first ``/clock`` seen, a restart).

Divergence rule
---------------
If the integrator raises, or the state becomes non-finite or faster than
:data:`~belt_drive_ros.core.stepper.SPEED_LIMIT`, the simulation records
the reason (:attr:`~NodeSimulation.last_divergence`), counts it
(``divergences``) and restarts from the scene's initial state at that tick
(scene time 0 again): the node keeps publishing, never a stale or
non-finite value, and ``/diagnostics`` reports ERROR for the window in which
it happened.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.errors import SimulationDivergedError
from ..core.model import OUTPUT_UNITS, FlexibleBeltModel
from ..core.slip import SLIP_OUTPUT_UNITS
from ..core.slip_run import SlippingSimulator
from ..core.sources import Schedule, TorqueProfile
from ..core.kernel_loop import OK
from ..core.step_plan import snap_tolerance
from ..core.stepper import SPEED_LIMIT, Plant, Stepper
from ..io.cdr_encoders import JointStateEncoder
from .gaps import next_tick_ns
from .inputs import DriveInput
from .parameter_schema import NodeSettings

__all__ = ["NodeSimulation", "TICK_OUTPUTS"]

#: the signals of one tick, as :meth:`NodeSimulation.outputs` returns them (the model's outputs;
#: the slipping model adds :data:`~belt_drive_ros.core.slip.SLIP_OUTPUT_UNITS`)
TICK_OUTPUTS = tuple(OUTPUT_UNITS)
SLIP_TICK_OUTPUTS = tuple(SLIP_OUTPUT_UNITS)


#: the node's ``joint_states`` (its layout: the compiled tick writes the message, see :meth:`NodeSimulation.joint_message`)
_JOINT_STATES = JointStateEncoder(4)


#: the compiled tick's clamps (lo, hi [s]) and held-torque change (drive [N m]) of a tick without a torque jump
_NO_CLAMP = (-math.inf, math.inf, math.nan)

#: a compiled tick's flags, which :meth:`NodeSimulation.advance_to` returns plus 1: its outputs' slack and slip set,
#: the slipping model's outputs (``core.tick``'s SLACK, SLIPS, SLIPPING: that module imports numba; tested equal)
SLACK, SLIPS, SLIPPING = 1, 2, 4
#: the tick kernels' return when done: minus (flags + EVENT per mode switch) (``core.tick.EVENT``)
_EVENT = 8


def _left_is_below(profile) -> bool:
    """Whether ``profile.left_of(t)`` is always the float just below ``t``: TorqueProfile's own, or a schedule's
    of such parts (the least of equal floats)."""
    if type(profile).left_of is TorqueProfile.left_of:
        return True
    return type(profile) is Schedule and _left_is_below(profile.active) and _left_is_below(profile.inactive)


class NodeSimulation:
    """Plant, state and scene time of a node (see the module docstring).

    Parameters
    ----------
    settings : NodeSettings
    drive : DriveInput
        The node's drive-torque input (sampled at each tick).
    counters : dict
        Shared counters; ``restarts``, ``divergences`` are added.
    logger
        Anything with ``info``, ``warn`` and ``error`` methods taking a line.
    """

    def __init__(self, settings: NodeSettings, drive: DriveInput, counters: dict, logger):
        self.drive = drive
        self.counters = counters
        for key in ("restarts", "divergences", "clock_jumps"):
            counters.setdefault(key, 0)
        self.log = logger
        self.settings = settings
        #: called ``(node time [ns], why)`` at every start of the run (the node records it: a restart is in the recording)
        self.on_start = None
        self._hybrid = None  # the hybrid state (see hybrid), unless the tick kernel holds it (_live)
        self._live = False
        #: slipping model: mode switches of the run so far (kind, scene time [s], direction) and the count
        self.slip_events: list = []
        counters.setdefault("slip_events", 0)
        #: (node time, stepper, origin, scene time, the previous node time, its scene time): scene_time's answers
        self._scene_time: tuple = (None, None, None, 0.0, None, 0.0)
        self.stepper = self._make_stepper(settings)
        self.x = settings.scene.initial_state.vector(settings.model.name, settings.params.ratio)
        self._init_hybrid()
        #: integrated-to time [ns, node time base]; None before the run starts
        self.t_ns: int | None = None
        #: why the run restarts at the next tick (a new scene: that tick is its scene time 0, publishing its initial
        #: state, as ``~/reset``'s), or None
        self.pending_restart: str | None = None
        #: node time [ns] of scene time 0
        self.origin_ns = 0
        #: (reason, node time [ns]) of the last divergence, or None
        self.last_divergence: tuple[str, int] | None = None
        #: scene time [s] at which the held drive torque last changed (a breakpoint of the drive), or None
        self._held_jump: float | None = None
        #: the held drive torque's value [N m] (drive.applied.value, kept as a float for the tick's comparison)
        self._held = drive.applied.value

    # ------------------------------------------------------------- settings
    def _make_stepper(self, s: NodeSettings) -> Stepper | SlippingSimulator:
        """The core's stepper for the settings' model, torques and integrator (grid origin: scene time 0).

        The slipping model: its engine (a stepper per phase, the same one the offline run uses).
        """
        drive = s.scene.drive if s.drive_source == "scene" else self.drive.applied
        if self._live:  # the old tick kernel's state, kept as an object (the new stepper has a kernel of its own)
            self.hybrid = self._tick_kernel.state()
        self._tick_kernel = None  # the common tick compiled whole (core.tick), where the model allows it
        self._fresh_ns: int | None = None  # node time whose outputs the tick kernel holds (None: none)
        self._plain_ns: int | None = None  # node time of the next plain tick (see advance_to), or None
        self._free_k = (0, -1)  # grid cells k with no plant breakpoint near steps k0 <= k < k1 (lo <= k0, k1 <= hi)
        self._topic = s.drive_source == "topic"  # (the plain tick samples the drive: DriveInput.until)
        self._below = _left_is_below(drive) and _left_is_below(s.scene.load)  # (Plant.left_of: see _jump_tick)
        if s.model.name == "slipping":
            engine = SlippingSimulator(s.params, drive, s.scene.load, s.method, s.dt, s.method_options, check_stability=False)
            self._plant_breakpoints = tuple(engine.breakpoints)
            self._free_k = (0, -1)
            from ..core.tick import SlipTickKernel, slip_tick

            self._tick_kernel = SlipTickKernel(engine, SPEED_LIMIT, _JOINT_STATES.layout)
            self._entry = slip_tick  # (the plain tick's call: the compiled kernel's dispatcher, nogil)
            return engine
        plant = Plant(s.model, drive, s.scene.load)
        stepper = Stepper(plant, s.method, s.dt, s.method_options, origin=0.0, integrator=s.integrator)
        self._plant_breakpoints = tuple(stepper.breakpoints)
        self._free_k = (0, -1)
        from ..core.tick import TickKernel, linear_tick

        self._tick_kernel = TickKernel.of(stepper, SPEED_LIMIT, _JOINT_STATES.layout)
        self._entry = linear_tick  # (the plain tick's call: the compiled kernel's dispatcher, nogil)
        return stepper

    @property
    def plant(self) -> Plant:
        return self.stepper.plant

    @property
    def hybrid(self):
        """Slipping model: the hybrid state (mode, direction, phase coordinates) beside ``x`` (its y); else None.

        After a compiled tick the slipping tick kernel holds it in its buffers (no object per tick): it is built
        when asked for."""
        if self._live:
            self._hybrid, self._live, self._plain_ns = self._tick_kernel.state(), False, None
        return self._hybrid

    @hybrid.setter
    def hybrid(self, state) -> None:
        self._hybrid, self._live, self._plain_ns = state, False, None

    def _init_hybrid(self) -> None:
        """The hybrid state of ``x`` (slipping model; sliding at once if it starts beyond the limit)."""
        self.hybrid = self.stepper.initial(self.x) if isinstance(self.stepper, SlippingSimulator) else None

    def apply(self, new: NodeSettings, changed: set, load_torque: float = 0.0) -> None:
        """Switch to validated settings ``new`` (``changed``: the parameter names) without a restart.

        A new scene restarts from its initial state; a rigid <-> flexible
        switch maps the state (``load_torque`` [N m] sets the flexible
        state's static belt deflection).
        """
        old = self.settings
        self.settings = new
        self._fresh_ns = None
        self.stepper = self._make_stepper(new)
        if new.scene.name != old.scene.name or "scene" in changed:
            if self.t_ns is None:
                self.restart("scene changed")
            else:  # at the next tick (restarted at the last one, already published with the old scene, its first
                self.pending_restart = "scene changed"  # sample was one step into the new one)
        elif new.model.name != old.model.name:
            self.x = np.array(self._map_state(self.x, old.model, new.model, load_torque), dtype=np.float64)
            self._init_hybrid()
        else:
            self.stepper.reset()
            if self.hybrid is not None:  # new parameters: the same motion, the mode decided afresh
                self.hybrid = self.stepper.initial(self.x)

    @staticmethod
    def _map_state(x: np.ndarray, old_model, new_model, load_torque: float) -> np.ndarray:
        """State of ``old_model`` expressed for ``new_model`` (rigid, flexible, slipping), via the flexible state.

        ``load_torque`` [N m] sets the static belt deflection when leaving
        the rigid model. Leaving the slipping model keeps the elastic stretch
        (the linear models have no slip coordinate: the accumulated slip is
        dropped); entering it starts with no slip.
        """
        if old_model.name == "rigid":
            x = FlexibleBeltModel(new_model.params).state_from_rigid(x, load_torque=load_torque)
        elif old_model.name == "slipping":
            x = np.array(x[:4], dtype=float)  # [phi_M, theta_e, omega_M, omega_3]: the flexible state with delta = theta_e
        if new_model.name == "flexible":
            return x
        return new_model.state_from_flexible(x)

    # ----------------------------------------------------------------- time
    @property
    def started(self) -> bool:
        return self.t_ns is not None

    def scene_time(self, now_ns: int) -> float:
        """Scene time [s] of node time ``now_ns``: the stepper's grid time ``k dt`` when it is one.

        (``k * 1e6 / 1e9`` and ``k * 0.001`` may differ in the last bit; the
        torques at a tick are evaluated at the very float the offline run
        uses.) A tick asks for its own time and the last tick's: the last two
        answers are kept (for the same origin and stepper).
        """
        stepper, origin = self.stepper, self.origin_ns
        cached = self._scene_time
        if cached[1] is stepper and cached[2] == origin:
            if cached[0] == now_ns:
                return cached[3]
            if cached[4] == now_ns:
                return cached[5]
        t = (now_ns - origin) / 1e9
        grid = stepper.grid_time(round(t / stepper.dt))
        t = grid if abs(grid - t) <= snap_tolerance(t, stepper.dt) else t
        self._scene_time = (now_ns, stepper, origin, t, cached[0], cached[3]) if cached[1] is stepper and cached[2] == origin \
            else (now_ns, stepper, origin, t, None, 0.0)
        return t

    def grid_time(self, now_ns: int) -> int:
        """The tick of the run's grid (origin + k * tick) a timer call at ``now_ns`` integrates to.

        The next tick after the last one, also when the call comes a little
        early (up to half a period) or late (up to a whole period); the
        latest tick at or before ``now_ns`` when it comes later (the ticks in
        between are integrated, not published); the last tick (nothing to
        do) when it comes more than half a period early.
        """
        if self.t_ns is None or now_ns < self.origin_ns:
            return now_ns
        tick = self.settings.tick_ns
        due = next_tick_ns(self.t_ns, self.origin_ns, tick)
        if now_ns >= due + tick:
            return now_ns - (now_ns - self.origin_ns) % tick
        return due if due - now_ns <= tick // 2 else self.t_ns

    def start(self, now_ns: int, why: str = "start") -> None:
        """Start (or restart) the run at node time ``now_ns``: scene time 0, the initial state. :attr:`on_start`
        is told ``(now_ns, why)`` (``why`` is ``start`` for the first start only)."""
        s = self.settings
        self.origin_ns = now_ns
        self.t_ns = now_ns
        self.x = s.scene.initial_state.vector(s.model.name, s.params.ratio)
        self._fresh_ns = self._plain_ns = None
        self.stepper.reset()
        self._init_hybrid()
        self.slip_events = []
        self.counters["restarts"] += 1
        self._hold(self._sample(now_ns), 0.0, first=True)  # held since before 0: no jump at 0
        if self.on_start is not None:
            self.on_start(now_ns, "start" if self.counters["restarts"] == 1 else why)

    def stop(self) -> None:
        """Forget the time base: the next tick starts the run again (clock source changed)."""
        if self.t_ns is not None:
            self.t_ns = self._plain_ns = None
            self.counters["clock_jumps"] += 1

    def restart(self, why: str, now_ns: int | None = None) -> bool:
        """Restart from the initial state at ``now_ns`` (default: the last tick); True if running.

        Before the run has started this only resets the state. The drive messages received until now are
        taken (:meth:`DriveInput.take`): the restart holds the latest (a divergence's restart inside a tick,
        :meth:`diverged`, holds what the tick took at its start).
        """
        self.drive.take()
        if self.t_ns is None:
            s = self.settings
            self.x = s.scene.initial_state.vector(s.model.name, s.params.ratio)
            self._init_hybrid()
            return False
        self.start(self.t_ns if now_ns is None else now_ns, why)
        self.log.info(f"restarted from the initial state ({why})")
        return True

    def _sample(self, now_ns: int) -> float | None:
        """The drive torque sampled at ``now_ns`` (None when the scene drives): logs a timeout warning."""
        if self.settings.drive_source != "topic":
            return None
        value, warning = self.drive.sample(now_ns, self.origin_ns, self.settings)
        if warning:
            self.log.warn(warning)
        return value

    def _hold(self, value: float | None, t: float, first: bool = False) -> None:
        """Hold the sampled ``value`` from scene time ``t`` on; a change (not the first sample) is a breakpoint."""
        if value is None:
            self._held_jump = None
            return
        held = self.drive.applied
        self._held_jump = None if first or value == held.value else t
        held.value = self._held = value
        if self._tick_kernel is not None:  # (its copy of the held torque's data)
            self._tick_kernel.drive_changed()

    def _drive_breakpoints(self, t0: float, t1: float, value: float | None) -> None:
        """The stepper's breakpoints for the advance t0 -> t1: the plant's, plus where the held torque jumps.

        The held drive is a zero-order hold of the samples, a table that
        jumps at the ticks where the sampled value changes: at ``t0`` if it
        changed there, at ``t1`` if the new sample differs. The offline
        re-simulation of the same samples has exactly these breakpoints, so
        both take the same steps the same way (bit-identical states).
        """
        extra = []
        if self._held_jump is not None and self._held_jump == t0:
            extra.append(t0)
        if value is not None and value != self.drive.applied.value:
            extra.append(t1)
        base = self._plant_breakpoints
        self.stepper.breakpoints = sorted((*base, *extra)) if extra else base

    def advance_to(self, now_ns: int) -> bool:
        """Integrate to ``now_ns``, then sample the input there; True if there are new outputs at ``now_ns``.

        The first call starts the run at ``now_ns``. A clock that went
        backwards restarts the run there (counted in ``clock_jumps``).

        The drive messages received until the call are handed over first (:meth:`DriveInput.take`): the tick's
        sample is the latest of them; one received while the tick computes is the next tick's.

        Returns False when there is nothing new; True after the general path; after a compiled tick (the tick kernel
        holds the outputs: :meth:`fresh`) 1 + their flags (:data:`SLACK`, :data:`SLIPS`, :data:`SLIPPING`): the
        node counts them without reading the outputs.

        A *plain* tick (at ``now_ns == _plain_ns``) is :meth:`plain_tick`'s, which the node's tick calls itself.
        """
        if now_ns == self._plain_ns:
            done = self.plain_tick(now_ns)
            return 1 + (-done & 7) if done <= 0 else done  # (7: SLACK | SLIPS | SLIPPING)
        if self.drive._new:  # messages received since the last tick: handed over now, before the compute
            self.drive.take()
        return self._advance(now_ns)

    def plain_tick(self, now_ns: int) -> int:
        """:meth:`advance_to` of a *plain* tick: ``now_ns`` is ``_plain_ns`` (the node's usual tick at 1 kHz calls
        this itself, with one check fewer on each side: :meth:`BeltDriveNode._tick`).

        A plain tick is the tick after one the tick kernel took, as many grid steps on, no plant breakpoint near:
        the kernel's buffers hold all it needs (:func:`~belt_drive_ros.core.tick.linear_tick` or
        :func:`~belt_drive_ros.core.tick.slip_tick` on them alone: as many grid steps on), so it is the
        drive's sample and one compiled call. A plain tick at which the held torque jumps (a new sample at its
        end) is that call with the clamps the general path gives it (:meth:`_jump_tick`); the tick after it is
        plain, its clamp at the jump (its start) written into the kernel's buffer when the jump was taken.

        Returns the kernel's answer when it took the tick: ``<= 0``, minus its outputs' flags (:data:`SLACK`,
        :data:`SLIPS`, :data:`SLIPPING`; ``-done & 7``) and :data:`_EVENT` per mode switch (located here);
        else (the general path took it: the same steps, or the same failure) :meth:`advance_to`'s answer, ``>= 1``.
        """
        drive = self.drive
        if drive._new:  # messages received since the last tick: handed over now, before the compute (DriveInput.take)
            drive.take()
        value = None
        if self._topic:  # the sample: the last one's while it cannot change (DriveInput.until), else anew
            if now_ns <= drive.until:
                value = drive.value
            else:
                value, warning = drive.sample(now_ns, self.origin_ns, self.settings)
                if warning:
                    self.log.warn(warning)
        if value is None or value == self._held:
            fast = self._tick_kernel
            done = self._entry(fast._address)  # (linear_tick or slip_tick on its buffer, no frame around)
            if done <= 0:  # (else the general path below takes the same steps and raises as it does; the
                # slipping belt's engine locates the events of a tick its kernel could not take)
                if done <= -_EVENT:  # mode switches located in the kernel (slip_tick's answer)
                    self._switched(-done // _EVENT)
                self.t_ns = self._fresh_ns = now_ns
                self._plain_ns = now_ns + self._plain_step if now_ns <= self._plain_end else None
                return done
            return self._advance(now_ns, (value,))
        return self._jump_tick(now_ns, value)

    def _jump_tick(self, now_ns: int, value: float) -> int:
        """A plain tick (:meth:`plain_tick`, whose answer this is) at whose end the held drive torque jumps to
        ``value`` (the sample at ``now_ns``): the tick kernel's one call with the clamps :meth:`_advance` gives the
        same tick (``hi = left_of(t1)``, the new value; ``lo``: -inf, or t0 when the tick before was a jump, written
        then), so the same floats; the general path where the kernel fails or a linear model's tick has several
        steps (the stepper's special step clamps only the step at the jump)."""
        fast = self._tick_kernel
        if self._plain_step == fast.step_ns or self._live:  # (the slipping tick clamps its first and last step alone)
            t1 = fast.origin + (now_ns - self.origin_ns) // fast.step_ns * fast.dt  # (_advance's t1)
            cells = fast.clamps  # (Plant.left_of: the float below t1 when both profiles' is, one call, not three)
            cells[1] = math.nextafter(t1, -math.inf) if self._below else \
                (self.stepper.stepper if self._live else self.stepper).plant.left_of(t1)
            cells[2] = value
            done = self._entry(fast._address)  # (the kernel sets its clamps back when it reads them)
            if done <= 0:
                fast._drive[0] = value  # (the held torque's own data; the kernel wrote its copy)
                if done <= -_EVENT:
                    self._switched(-done // _EVENT)
                self.t_ns = self._fresh_ns = now_ns
                self._held_jump, self._held = t1, value
                self._plain_ns = now_ns + self._plain_step if now_ns <= self._plain_end else None
                if self._plain_ns is not None:
                    cells[0] = t1  # the next tick's: the held torque jumps at its start
                return done
        return self._advance(now_ns, (value,))

    def _advance(self, now_ns: int, sampled: tuple | None = None) -> bool:
        """:meth:`advance_to` but for a plain tick; ``sampled``: ``(value,)`` when the drive was sampled at ``now_ns``."""
        self._plain_ns = None
        if self.t_ns is None:  # a new time base: what was received before counts from its start (DriveInput.rebase)
            self.drive.rebase(now_ns)
            self.start(now_ns, "a new time base (clock source changed)")
            return True
        if now_ns < self.t_ns:
            self.counters["clock_jumps"] += 1
            self.log.warn(f"clock jumped back {(self.t_ns - now_ns) / 1e9:.6g} s: restarting from the initial state")
            self.start(now_ns, "clock jumped back")
            return True
        if now_ns == self.t_ns:
            return False
        fast, origin = self._tick_kernel, self.origin_ns
        step = 0 if fast is None else fast.step_ns
        d0, d1 = self.t_ns - origin, now_ns - origin
        if step and d0 % step == 0 and d1 % step == 0:
            # both ends on the grid (the usual tick): the grid times origin + k dt of Stepper.grid_time, the floats
            # scene_time gives them (it is not asked here: on the caches a 1 ms sleep leaves every line costs)
            k0, k1 = d0 // step, d1 // step
            t0, t1 = fast.origin + k0 * fast.dt, fast.origin + k1 * fast.dt
            s = self.settings
            value = None  # the sample at now_ns: known before the interval is integrated (_sample)
            if sampled is not None:
                value = sampled[0]
            elif s.drive_source == "topic":
                value, warning = self.drive.sample(now_ns, origin, s)
                if warning:
                    self.log.warn(warning)
            jump0 = self._held_jump == t0
            jump1 = value is not None and value != self._held
            lo, hi = self._free_k
            slipping = self._live or self._hybrid is not None
            if (not (jump0 or jump1) or k1 - k0 == 1 or slipping) and (
                    lo <= k0 and k1 <= hi or self._free(t0, t1, k0, k1)):
                # whole grid steps away from the plant's breakpoints: one compiled call, steps and outputs
                # (core.tick; the same floats as the stepper's). A held-torque jump at t0 or t1 is a
                # breakpoint there: the stepper's special step clamps the torque times as these do.
                if jump0 or jump1:
                    lo = t0 if jump0 else -math.inf
                    hi = (self.stepper.stepper if slipping else self.stepper).plant.left_of(t1) if jump1 else math.inf
                    drive = value if jump1 else math.nan  # held from t1 on: the outputs at t1 have it
                else:
                    lo, hi, drive = _NO_CLAMP
                if not slipping:
                    if fast.step(self.x, k0, k1, lo, hi, drive, now_ns) == OK:  # else the general path below
                        # takes the same steps and raises as it does
                        self.x = fast.state  # the tick kernel's buffer, written again by the next tick
                        self._ticked(now_ns, k1, k1 - k0, step, t1 if jump1 else None, value)
                        return 1 + fast.flags
                else:  # the slipping belt, its events located in the kernel (a failure: the engine's path); the
                    # hybrid state stays in the kernel's buffers, x a view of them (written again by the next tick)
                    events = fast.advance(None if self._live else self._hybrid, k0, k1, lo, hi, drive, now_ns)
                    if events is not None:
                        self._live, self.x = True, fast.end_y
                        if events:
                            self._located(events)
                        self._ticked(now_ns, k1, k1 - k0, step, t1 if jump1 else None, value)
                        return 1 + fast.flags
        else:
            t0, t1 = self.scene_time(self.t_ns), self.scene_time(now_ns)
            value = sampled[0] if sampled is not None else self._sample(now_ns)  # needs no state: known before
        self._fresh_ns = None
        self._drive_breakpoints(t0, t1, value)
        try:
            if self.hybrid is None:
                x = self.stepper.advance(self.x, t0, t1)
            else:  # events inside the tick are located by the engine; the state is y of the new hybrid state
                events = []
                hybrid = self.stepper.advance(self.hybrid, t0, t1, events=events)
                x = self.stepper.state_y(hybrid)
        except SimulationDivergedError as exc:
            self.diverged(f"{exc}; drive torque {self.drive.applied.value:g} N m", now_ns)
            return True
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
            self.diverged(f"integrator failed at t={self.scene_time(self.t_ns):.6g} s: {exc}", now_ns)
            return True
        self.x = np.array(x, dtype=np.float64)  # C-contiguous and writable: the tick kernel's one signature
        if self.hybrid is not None:
            self.hybrid = hybrid
            if events:
                self._located(events)
        self.t_ns = now_ns
        self._hold(value, t1)
        return True

    def _ticked(self, now_ns: int, k1: int, steps: int, step_ns: int, jump: float | None, value) -> None:
        """After the tick kernel took ``steps`` grid steps (``step_ns`` [ns] each) to grid index ``k1`` at ``now_ns``
        (``jump``: the scene time there when the held torque jumped to ``value`` there, else None): the time, the
        held torque, and whether the next ticks can be plain (as many steps, each ending at or before grid index
        ``hi`` of :meth:`_free`'s range: the plain ticks run to ``_plain_end``; after a jump the next one's clamp
        at it is written into the kernel's buffer, :meth:`_jump_tick`)."""
        self.t_ns = self._fresh_ns = now_ns
        self._held_jump = jump  # (what _hold makes of the sample)
        if jump is not None:
            self._held = value  # (the tick kernel wrote it into the held torque)
        hi = self._free_k[1]
        if k1 + steps <= hi and (jump is None or steps == 1 or self._live):  # (see _jump_tick)
            self._plain_ns, self._plain_step = now_ns + steps * step_ns, steps * step_ns
            self._plain_end = now_ns + (hi - k1 - steps) * step_ns  # the last tick whose next one ends at hi
            if jump is not None:  # the next tick's clamp at the jump, its start (read by the kernel's next call)
                self._tick_kernel.clamps[0] = jump
    def _located(self, events) -> None:
        """Note a tick's stick/slip events (:class:`~belt_drive_ros.core.slip.Event`): the latest 64 kept."""
        self._note([(e.kind, e.time, e.sigma) for e in events])

    def _switched(self, n: int) -> None:
        """:meth:`_located` of the ``n`` mode switches the tick kernel located, read from its event rows (time, 1.0
        at an onset, sigma, then the state: the columns :func:`~belt_drive_ros.core.slip_run._events` reads) without
        an :class:`~belt_drive_ros.core.slip.Event` built for each (the same kind, time and sigma; one switch, on
        cold caches: ~18 against ~46 us)."""
        rows = self._tick_kernel._events[:n].tolist()
        self._note([("onset" if onset else "restick", t, sigma) for t, onset, sigma, *_ in rows])

    def _note(self, notes: list) -> None:
        """Keep the latest 64 of the run's ``(kind, time, sigma)`` mode switches (diagnostics) and count them."""
        self.slip_events.extend(notes)
        del self.slip_events[:-64]
        self.counters["slip_events"] += len(notes)

    def _free(self, t0: float, t1: float, k0: int, k1: int) -> bool:
        """Whether no plant breakpoint lies near the whole grid steps k0 .. k1 (the stepper's test, remembered
        as a range of grid indices with a step's margin at both ends)."""
        lo, hi = self._free_k
        if lo <= k0 and k1 <= hi:
            return True
        self.stepper.breakpoints = self._plant_breakpoints
        st = self.stepper.stepper if isinstance(self.stepper, SlippingSimulator) else self.stepper  # (the engine's grid stepper)
        if k1 <= k0 or st._near_breakpoint(t0, t1, k0, k1):
            return False
        # no breakpoint in the open interval (left, right) (the stepper's note of it; none at all: everywhere)
        _, left, right = st._free if st.breakpoints else (None, -math.inf, math.inf)
        lo = -(2**62) if left == -math.inf else math.floor(left / st.dt) + 2
        hi = 2**62 if right == math.inf else math.ceil(right / st.dt) - 2
        self._free_k = (lo, hi) if lo <= k0 and k1 <= hi else (0, -1)
        return True

    def diverged(self, reason: str, now_ns: int) -> None:
        """Apply the divergence rule (module docstring) at node time ``now_ns``."""
        self.counters["divergences"] += 1
        self.last_divergence = (reason, now_ns)
        self.log.error(f"{reason}; restarting from the initial state (divergence {self.counters['divergences']})")
        self.start(now_ns, "diverged")

    # -------------------------------------------------------------- outputs
    def outputs(self, now_ns: int) -> dict:
        """Every signal of :data:`TICK_OUTPUTS` at ``now_ns`` (the state integrated to it) [SI units].

        Evaluated by the model's own ``outputs(x, u)``, the function the
        offline simulator applies to its whole run, so the node's values
        equal the offline ones bit for bit. Finite by construction: the
        state was checked by :meth:`advance_to`; torques that are not finite
        count as a divergence (the run restarts; the initial state's outputs
        are returned).
        """
        if self._fresh_ns == now_ns:  # the tick kernel's outputs of this very state and time
            return dict(zip(TICK_OUTPUTS + SLIP_TICK_OUTPUTS, self.values(now_ns)))  # (the linear ones: 16)
        model = self.settings.model
        inputs = self.plant.inputs if self.hybrid is None else self.stepper.inputs
        u = inputs(self.scene_time(now_ns), self.x)
        if not (math.isfinite(u[0]) and math.isfinite(u[1])):
            self.diverged(
                f"non-finite torque at t={self.scene_time(now_ns):.6g} s (drive {u[0]!r}, load {u[1]!r} N m)", now_ns
            )
            u = np.nan_to_num(inputs(0.0, self.x), nan=0.0, posinf=0.0, neginf=0.0)
        if self.hybrid is not None:  # the offline run's function too, on one sample
            return model.outputs(self.x, u, self.hybrid.mode, self.hybrid.sigma)
        out = model.outputs(self.x, u)  # a finite state and finite torques: nothing for numpy to warn about
        return out  # numpy float64 scalars (a float subclass) and numpy bools

    def fresh(self, now_ns: int):
        """The tick kernel when it holds the outputs (``y``) and the ``joint_states`` message (``message``)
        at ``now_ns`` (the compiled tick computed them), else None."""
        return self._tick_kernel if self._fresh_ns == now_ns else None

    def joint_message(self, now_ns: int) -> bytes | None:
        """The CDR bytes of ``joint_states`` at ``now_ns`` when the compiled tick wrote them (its outputs
        are fresh), else None (the caller encodes :meth:`values`; the same bytes)."""
        if self._fresh_ns == now_ns:
            return self._tick_kernel.message.tobytes()
        return None

    def values(self, now_ns: int) -> list:
        """:meth:`outputs` as a list of floats in the order of :data:`TICK_OUTPUTS` (then, for the slipping
        model, :data:`SLIP_TICK_OUTPUTS`); the flags slack and slip as 1.0/0.0 (the publishing tick's form)."""
        if self._fresh_ns == now_ns:
            return self._tick_kernel.values.tolist()
        out = self.outputs(now_ns)  # the general path's (model.outputs)
        names = TICK_OUTPUTS + SLIP_TICK_OUTPUTS if self.hybrid is not None else TICK_OUTPUTS
        return [float(out[name]) for name in names]
