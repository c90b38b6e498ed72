"""A drive-torque publisher built on the core's torque sources.

:class:`TorqueSourceNode` publishes ``drive_torque`` (``std_msgs/Float64``,
N m) at ``rate_hz`` on the node's clock (so ``use_sim_time`` works as for
the belt node), evaluating any :class:`~belt_drive_ros.core.sources.TorqueProfile`
``torque(t, angle, speed)``:

* ``t`` [s] counts from the source's first tick;
* ``speed`` [rad/s] is the latest ``shaft_speed`` from the belt node (the
  profile's ``initial_speed`` until the first message);
* ``angle`` [rad of wheel M] is integrated from that speed over each tick
  interval (trapezoidal rule between the speed at the previous tick and the
  latest one; an engine applies its own ``crank_ratio`` for the crank angle).

A speed-dependent profile (``Engine`` with a governor, ``MotorCurve``)
therefore closes the loop through the belt node; an open-loop profile
(``Table`` from a CSV, ``Step``, ``Sine`` ...) does not subscribe at all.
Non-finite torques are never published (counted instead). As it stops
(SIGINT, SIGTERM) the source publishes 0 N m once: the drive is off, and a
node holding its last input (``timeout_behavior: hold``) coasts instead of
holding the last torque (a firing pulse) for ever.

Ticks. On the system clock a timer ticks at ``rate_hz``. On simulated time
(``use_sim_time:=true``) the ``/clock`` messages tick the source directly:
it publishes at the first ``/clock`` it sees, then at each ``/clock`` that
reaches the next point of its grid (that first time + k / ``rate_hz``),
once per message however far ``/clock`` jumps, stamped with that message's
time; a ``/clock`` back in time starts over. So a driver that steps
``/clock`` by one period gets exactly one ``drive_torque`` per step. An
rclpy timer on simulated time does not guarantee that under the events
executor: on a loaded machine it fired twice at one ``/clock`` time and then
stayed silent for the next (seen in the README's closed-loop example).
The profile is evaluated once at construction, so its compiled kernel is
loaded before the node runs (under load the first tick took 3-12 s when
it was loaded there).
"""

from __future__ import annotations

import math
from typing import Any

from . import environment as ros_env

ros_env.configure_environment()

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, ParameterType, SetParametersResult  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rosgraph_msgs.msg import Clock as ClockMsg  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from ..core.errors import BeltDriveError  # noqa: E402
from .environment import interruptible_start  # noqa: E402
from .executors import ros_session, spin_nodes  # noqa: E402
from .gaps import next_tick_ns  # noqa: E402
from .qos import CLOCK_TICK_QOS, INPUT_QOS, OUTPUT_QOS  # noqa: E402
from ..core.sources import TorqueProfile  # noqa: E402

SOURCE_NODE_NAME = "torque_source"
RATE_RANGE = (0.1, 20000.0)


class TorqueSourceNode(Node):
    """Publishes ``drive_torque`` from a torque profile (see the module docstring).

    Parameters
    ----------
    profile : TorqueProfile
        The drive torque as a function of (t, angle, speed).
    node_name : str
    rate_hz : float
        Publish rate [Hz] (ROS parameter ``rate_hz``, changeable at runtime).
    initial_speed, initial_angle : float
        Wheel-M speed [rad/s] and angle [rad] assumed before the first
        ``shaft_speed`` message (e.g. the scene's initial state).
    autostart : bool
        False: no timer and no ``/clock`` ticks; the owner calls
        :meth:`publish_at` (the lockstep harness does, to order source and
        belt node deterministically).
    **kwargs
        Passed to :class:`rclpy.node.Node`.
    """

    def __init__(
        self,
        profile: TorqueProfile,
        node_name: str = SOURCE_NODE_NAME,
        *,
        rate_hz: float = 1000.0,
        initial_speed: float = 0.0,
        initial_angle: float = 0.0,
        autostart: bool = True,
        **kwargs: Any,
    ):
        super().__init__(node_name, **kwargs)
        self.profile = profile
        descriptor = ParameterDescriptor(
            name="rate_hz",
            type=ParameterType.PARAMETER_DOUBLE,
            description="drive_torque publish rate [Hz] on the node's clock",
            floating_point_range=[FloatingPointRange(from_value=RATE_RANGE[0], to_value=RATE_RANGE[1], step=0.0)],
            dynamic_typing=True,
        )
        rate = self.declare_parameter("rate_hz", float(rate_hz), descriptor).value
        self._rate = self._check_rate(rate)
        self.speed = float(initial_speed)
        self._tick_speed = self.speed
        self.angle = float(initial_angle)
        self._origin_ns: int | None = None
        self._last_ns: int | None = None
        self.counters = {"published": 0, "speed_received": 0, "speed_rejected": 0, "nonfinite_torque": 0}
        self.last_torque = math.nan
        self._msg = Float64()
        self._pub = self.create_publisher(Float64, "drive_torque", OUTPUT_QOS)
        self._sub = None
        if profile.state_dependent:
            self._sub = self.create_subscription(Float64, "shaft_speed", self._on_speed, INPUT_QOS)
        self._autostart = autostart
        profile.torque(0.0, self.angle, self.speed)  # the compiled kernel loaded now, not in the first tick
        self._next_ns: int | None = None  # on /clock: the grid's next tick [ns] (None: the next /clock ticks)
        self._timer = self.create_timer(1.0 / self._rate, self._on_tick) if autostart else None
        self._clock_sub = self.create_subscription(ClockMsg, "/clock", self._on_clock, CLOCK_TICK_QOS) if autostart else None
        self.add_on_set_parameters_callback(self._on_validate)
        self.add_post_set_parameters_callback(self._on_post_set)

    @staticmethod
    def _check_rate(value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"rate_hz: must be a finite number, got {value!r}")
        if not RATE_RANGE[0] <= value <= RATE_RANGE[1]:
            raise ValueError(f"rate_hz: must be in [{RATE_RANGE[0]:g}, {RATE_RANGE[1]:g}] Hz, got {value!r}")
        return float(value)

    def _on_validate(self, parameters) -> SetParametersResult:
        for p in parameters:
            if p.name == "rate_hz":
                try:
                    self._check_rate(p.value)
                except ValueError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _on_post_set(self, parameters) -> None:
        for p in parameters:
            if p.name == "rate_hz":
                self._rate = float(p.value)
                if self._next_ns is not None and self._last_ns is not None:  # /clock: the new grid from the last tick
                    self._next_ns = self._last_ns + self._period_ns()
                if self._timer is not None:
                    self.destroy_timer(self._timer)
                    self._timer = self.create_timer(1.0 / self._rate, self._on_tick)

    @property
    def rate_hz(self) -> float:
        return self._rate

    def _on_speed(self, msg: Float64) -> None:
        if math.isfinite(msg.data):
            self.speed = msg.data
            self.counters["speed_received"] += 1
        else:
            self.counters["speed_rejected"] += 1

    def _period_ns(self) -> int:
        return max(1, round(1e9 / self._rate))

    def _on_tick(self) -> None:
        clock = self.get_clock()
        if clock.ros_time_is_active:  # /clock ticks (see the module docstring)
            return
        self.publish_at(clock.now().nanoseconds)

    def _on_clock(self, msg: ClockMsg) -> None:
        """A ``/clock`` message on simulated time: publish at its time if it reaches the grid's next tick."""
        if not self.get_clock().ros_time_is_active:
            return
        now = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        last, nxt = self._last_ns, self._next_ns
        if nxt is not None and last is not None and last <= now < nxt:
            return  # the same tick (a repeated /clock, or one between two ticks)
        self.publish_at(now)
        period = self._period_ns()
        if nxt is None or now < last:  # the first /clock, or back in time: a new grid from here
            self._next_ns = now + period
        else:  # the grid point after now
            self._next_ns = next_tick_ns(now, nxt, period)

    def publish_at(self, now_ns: int) -> float:
        """Advance the angle to ``now_ns`` [ns], evaluate the profile and publish; returns the torque [N m]."""
        if self._origin_ns is None:
            self._origin_ns = self._last_ns = now_ns
        if now_ns < self._last_ns:  # clock jumped back: start over
            self._origin_ns = self._last_ns = now_ns
        # trapezoidal rule between the speed used at the last tick and the latest one
        self.angle += 0.5 * (self._tick_speed + self.speed) * (now_ns - self._last_ns) / 1e9
        self._tick_speed = self.speed
        self._last_ns = now_ns
        t = (now_ns - self._origin_ns) / 1e9
        torque = float(self.profile.torque(t, self.angle, self.speed))
        if not math.isfinite(torque):
            self.counters["nonfinite_torque"] += 1
            return torque
        self._msg.data = torque
        self._pub.publish(self._msg)
        self.counters["published"] += 1
        self.last_torque = torque
        return torque

    def stop_torque(self) -> None:
        """Publish 0 N m once, as the source stops (the engine or motor is off): a node holding its last input
        (``timeout_behavior: hold``) would otherwise hold a firing pulse's torque, and the drive ran away (78 to
        885 rad/s in 4 s of the README's pairing, the source stopped first)."""
        if self.counters["published"]:
            from rclpy.duration import Duration

            self._msg.data = 0.0
            self._pub.publish(self._msg)
            self.last_torque = 0.0
            self._pub.wait_for_all_acked(Duration(seconds=0.5))  # (delivered before the node is destroyed)


def run(
    profile: TorqueProfile,
    ros_args: list[str] | None = None,
    rate_hz: float = 1000.0,
    initial_speed: float = 0.0,
    executor: str = "auto",
    node_name: str = SOURCE_NODE_NAME,
) -> int:
    """Run one :class:`TorqueSourceNode` until SIGINT/SIGTERM; return the exit code (0)."""
    interruptible_start()  # SIGINT ends the start-up too (see the paper node's run)
    with ros_session(["belt-drive-source", *(ros_args or [])]) as context:
        try:
            node = TorqueSourceNode(profile, node_name, rate_hz=rate_hz, initial_speed=initial_speed, context=context)
        except ValueError as exc:
            raise SourceConfigError(str(exc)) from None
        node.get_logger().info(
            f"publishing drive_torque at {node.rate_hz:g} Hz from the {profile.kind} profile"
            + (" (closed loop on shaft_speed)" if profile.state_dependent else "")
        )
        spin_nodes([node], context, executor=executor, stopped=lambda _signum: node.stop_torque())
    return 0


class SourceConfigError(BeltDriveError, ValueError):
    """Invalid source node configuration (rate, profile)."""
