"""The belt-drive node for a belt network scene (``belt-drive node fead_i4``): wiring only, no physics.

Topics (relative names, SI units, the layout of :mod:`belt_drive_ros.io.network_bag`):

* subscribed: ``drive_torque`` (torque on the driver pulley, the crank [N m])
  and, per accessory ``P``, ``P/load_torque`` (the torque P takes from the
  belt [N m], e.g. an alternator whose current comes from a SIL stack). All
  ``std_msgs/Float64``, QoS as the paper node's input (best effort, keep last
  1). A value is sampled at each tick and held until the next (zero-order
  hold: a message received before tick k starts, after tick k-1 started, acts
  from tick k on; its callback is not held up by a tick computing).
  Until its first message an accessory follows its profile in the scene;
  the crank's torque is 0 N m until the first ``drive_torque``
  (``drive_source:=scene``: the crank follows its profile and the topic is
  ignored). Non-finite values are rejected and counted.
* published every tick: per pulley ``P/angle, speed, belt_torque, hub_load,
  friction_use, slip, slip_speed``, per span ``spans/S/tension, slack``,
  ``tensioner_arm/angle``, ``joint_states`` (every pulley and the arm),
  ``/tf`` (where tf2_msgs is installed) and ``robot_description`` (the
  layout's URDF, latched); ``/diagnostics`` at 1 Hz (status ``NODE:
  simulation``: tier, method, tick counters, period error and the tick
  thread's compute time per tick ``tick_compute_us_p50/p99``; WARN while a
  span would go slack or a pulley reaches its capstan limit). A topic is
  sent only while it has a reader ("matched" events keep the counts); while
  no Float64 output has a reader and nothing records, a tick computes the
  joint states alone (the same values) and skips the per-pulley and
  per-span outputs.

Time: the paper node's tick sources (:class:`~.timing.TickSource`: system
clock with the tick thread, ``/clock`` lockstep with ``use_sim_time``, or
``publish_clock``). Each tick integrates the network from the previous tick
with the scene's method and step through
:class:`~.network_stepper.NetworkStepper`, the adapter the offline
re-simulation uses too: on ``/clock`` the outputs equal
``belt-drive sim REC.mcap`` of the recording bit for bit.

Recording (``record_path``): the published bytes of every output, the
inputs as received and as applied at each tick
(``drive_torque_applied``, ``P/load_torque_applied``), and the scene
(``network_scene`` metadata), in one MCAP.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

from ..core.sources import TORQUE_MAX
from . import environment as ros_env

ros_env.configure_environment()

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rclpy.clock import Clock, ClockType  # noqa: E402
from rclpy.event_handler import PublisherEventCallbacks  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rcl_interfaces.msg import ParameterDescriptor  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64, String  # noqa: E402

from ..core.errors import BeltDriveError, SimulationDivergedError  # noqa: E402
from ..io.network_bag import APPLIED, NetworkBagWriter, NetworkLayout, network_record, scene_text  # noqa: E402
from .network_stepper import NetworkStepper  # noqa: E402
from .parameter_schema import NodeConfigError, check_record_path, record_path_exists, refuse_undeclared  # noqa: E402
from .diagnostics import status_prefix  # noqa: E402
from .parameters import declare_read_only  # noqa: E402
from .qos import DESCRIPTION_QOS, INPUT_QOS, OUTPUT_QOS, TF_QOS  # noqa: E402
from .simulation import NodeSimulation  # noqa: E402
from .timing import TickSource, TickStats  # noqa: E402

__all__ = ["NetworkNode", "NetworkSettings", "run"]

#: parameters of the network node: (name, default, description); read at start, declared read-only (rclpy refuses a
#: change, naming the parameter)
PARAMETERS = (
    ("scene", "fead_i4", "network scene: shipped name or YAML file with kind: network"),
    ("step_rate_hz", 1000.0, "tick rate on the node's clock [Hz]; the scene's dt must divide the tick"),
    ("drive_source", "topic", "topic: the crank's torque from drive_torque; scene: from the scene's profile"),
    ("model", "auto", "belt tier: rigid, flexible, slipping, or auto (the scene's choice, from its own profiles: "
                      "a topic that drives otherwise may need the tier set)"),
    ("publish_clock", False, "publish /clock from the node's own simulated time (time master)"),
    ("real_time_factor", 1.0, "with publish_clock: simulated seconds per wall second; 0 = as fast as possible"),
    ("tick_thread", True, "on the system clock: tick from a thread of the node's own"),
    ("tick_lead", 0.0003, "with tick_thread: compute each tick this long before its due time [s]"),
    ("record_path", "", "record inputs and outputs to this MCAP file ('' = no recording)"),
    ("record_overwrite", False, "replace an existing record_path"),
    ("max_bag_duration", 0.0, "split the recording into a rosbag2 bag folder (NAME/NAME_0.mcap, ..., metadata.yaml), "
                              "a new file every this many seconds of log time; 0 = no split by time"),
    ("max_bag_size", 0, "split the recording into a bag folder once a file holds this many bytes; 0 = no limit"),
)


@dataclass(frozen=True)
class NetworkSettings:
    """What the tick sources and the simulation read (names as the paper node's settings)."""

    scene: object
    text: str
    method: str
    dt: float
    tick_ns: int
    substeps: int
    step_rate_hz: float
    drive_source: str
    publish_clock: bool
    real_time_factor: float
    tick_thread: bool
    tick_lead_ns: int
    record_path: str
    record_overwrite: bool
    max_bag_duration: float = 0.0
    max_bag_size: int = 0
    #: the belt tier asked for (``auto``: the scene's choice)
    model: str = "auto"

    @classmethod
    def from_values(cls, v: dict) -> "NetworkSettings":
        from ..io.scenes import is_network, load_network

        label = str(v["scene"])
        if not is_network(label):
            raise NodeConfigError("scene", f"{label} is not a network scene (kind: network)")
        try:
            scene = load_network(label)
        except BeltDriveError as exc:
            raise NodeConfigError("scene", str(exc)) from None
        rate = float(v["step_rate_hz"])
        if not (math.isfinite(rate) and 1.0 <= rate <= 20000.0):
            raise NodeConfigError("step_rate_hz", f"{rate!r} Hz is outside [1, 20000] Hz")
        tick_ns = int(round(1e9 / rate))
        dt_ns = int(round(scene.dt * 1e9))
        if dt_ns <= 0 or tick_ns % dt_ns or abs(dt_ns - scene.dt * 1e9) > 1e-6:
            raise NodeConfigError("step_rate_hz", f"a tick of {tick_ns} ns is not a whole number of the scene's "
                                  f"steps of {scene.dt:g} s")
        if v["drive_source"] not in ("topic", "scene"):
            raise NodeConfigError("drive_source", f"topic or scene, got {v['drive_source']!r}")
        from ..core.network.simulate import TIERS

        model = v.get("model", "auto")
        if model not in TIERS:
            raise NodeConfigError("model", f"one of {', '.join(TIERS)}, got {model!r}")
        rtf = float(v["real_time_factor"])
        if not (math.isfinite(rtf) and 0.0 <= rtf <= 1e4):
            raise NodeConfigError("real_time_factor", f"{rtf!r} is outside [0, 10000]")
        lead = float(v["tick_lead"])
        if not (math.isfinite(lead) and 0.0 <= lead <= 0.1):
            raise NodeConfigError("tick_lead", f"{lead!r} s is outside [0, 0.1] s")
        split, size = float(v["max_bag_duration"]), int(v["max_bag_size"])
        if not (math.isfinite(split) and 0.0 <= split <= 1.0e7):
            raise NodeConfigError("max_bag_duration", f"{split!r} s is outside [0, 1e7] s")
        if size < 0:
            raise NodeConfigError("max_bag_size", f"{size} bytes is below 0")
        check_record_path(str(v["record_path"]), bool(split or size), v.get("scene"))
        return cls(scene, scene_text(label), scene.method, scene.dt, tick_ns, tick_ns // dt_ns, rate,
                   v["drive_source"], bool(v["publish_clock"]), rtf, bool(v["tick_thread"]),
                   int(round(lead * 1e9)), str(v["record_path"]), bool(v["record_overwrite"]), split, size, model)


class NetworkSimulation:
    """The network's state on the node's tick grid (the time base :class:`~.timing.TickSource` reads)."""

    def __init__(self, settings: NetworkSettings, layout: NetworkLayout, counters: dict, logger):
        self.settings = settings
        self.layout = layout
        self.counters = counters
        for key in ("restarts", "divergences", "clock_jumps", "received", "rejected_nonfinite", "rejected_bound",
                    "ignored"):
            counters.setdefault(key, 0)
        self.log = logger
        self.stepper = NetworkStepper(settings.scene, settings.method, settings.dt,
                                      tier=None if settings.model == "auto" else settings.model)
        self.stepper.use_joints(float(layout.arm[3]) if layout.arm else 0.0, layout.joint_encoder().layout)
        #: latest valid value per input pulley index (None: none received yet)
        self.latest: dict = {i: None for _, i in layout.inputs}
        self.x = self.stepper.initial()
        self.k = 0  # steps since scene time 0
        self.t_ns: int | None = None
        self.origin_ns = 0
        self.last_divergence = None
        #: told ``(now_ns, why)`` at every start (the node records it: a re-simulation refuses a restarted run)
        self.on_start = None
        #: ``~/reset`` calls since the last tick (the next tick restarts once for all)
        self.resets_pending = 0
        self.applied: list = []  # (input topic, value) applied at the last tick (recorded)
        #: the crank's index when its torque comes from drive_torque (0 N m until the first message), else -1
        self._driver = settings.scene.driver if settings.drive_source == "topic" else -1
        self._dt_ns = settings.dt * 1e9  # the step [ns] (settings are fixed while the node runs)
        #: the inputs held (:meth:`_pending`) unless a message came since: a tick holds them again only then
        self._held: list | None = None
        #: the inputs' hand-over: :meth:`receive` (the executor's callbacks) puts a message into ``_inbox`` under
        #: it, a tick moves them into :attr:`latest` at its start (:meth:`take`); never held through a compute
        self.lock = threading.Lock()
        self._inbox: dict = {}

    # the time base of the paper node's simulation (the same attributes: t_ns, origin_ns, settings.tick_ns)
    started = NodeSimulation.started
    stop = NodeSimulation.stop
    grid_time = NodeSimulation.grid_time

    def receive(self, pulley: int, value: float) -> bool:
        self.counters["received"] += 1
        if not math.isfinite(value):
            self.counters["rejected_nonfinite"] += 1
            return False
        if abs(value) > TORQUE_MAX:  # beyond a profile's plausible range (held, it diverged at every tick)
            self.counters["rejected_bound"] += 1
            return False
        if pulley == self.settings.scene.driver and self.settings.drive_source == "scene":
            self.counters["ignored"] += 1
            return False
        with self.lock:
            self._inbox[pulley] = float(value)
        return True

    def request_reset(self) -> None:
        """``~/reset``: the next tick restarts the run (under the hand-over lock; a burst is one restart)."""
        with self.lock:
            self.resets_pending += 1

    def take(self) -> None:
        """The tick's hand-over (at its start, before its compute): the messages received since the last take
        become :attr:`latest`, which the tick holds from its time on; one received while it computes is the next
        tick's (its callback is not held up by the compute)."""
        if self._inbox:
            with self.lock:
                inbox, self._inbox = self._inbox, {}
            self.latest.update(inbox)
            self._held = None

    def _pending(self) -> list:
        """``(topic, pulley, value)`` of the inputs to hold from this tick on (the driver at 0 N m before its
        first message)."""
        driver, latest, pending = self._driver, self.latest, []
        for topic, i in self.layout.inputs:
            value = latest[i]
            if i == driver and value is None:
                value = 0.0
            if value is not None:
                pending.append((topic, i, value))
        return pending

    def _sample(self, pending=None) -> None:
        """Hold the latest inputs (:meth:`_pending`) from this tick on."""
        stepper = self.stepper
        self.applied = []
        pending = self._pending() if pending is None else pending
        for topic, i, value in pending:
            stepper.hold(i, value)
            self.applied.append((topic + APPLIED, value))
        self._held = pending

    def start(self, now_ns: int, why: str = "start") -> None:
        """Start (or restart, ``why``) the run at ``now_ns``: scene time 0, the initial state; :attr:`on_start`
        is told ``(now_ns, why)`` (``why`` is ``start`` for the first start only)."""
        self.origin_ns = self.t_ns = now_ns
        self.k = 0
        self.x = self.stepper.initial()
        self.stepper.reset()
        self.counters["restarts"] += 1
        self._sample()
        if self.on_start is not None:
            self.on_start(now_ns, "start" if self.counters["restarts"] == 1 else why)

    def advance_to(self, now_ns: int) -> bool:
        """Integrate to the tick ``now_ns`` with the inputs held since the last tick, then sample the inputs
        (those received before this call: :meth:`take`)."""
        self.take()
        if self.resets_pending and self.t_ns is not None and now_ns >= self.t_ns:
            # ~/reset: this tick is the restart, scene time 0 here, its outputs the initial state (the paper node's)
            with self.lock:
                calls, self.resets_pending = self.resets_pending, 0
            self.log.info(f"restarted from the initial state (~/reset, {calls} call(s) since the last tick)")
            self.start(now_ns, f"~/reset, {calls} call(s) since the last tick")
            return True
        if self.t_ns is not None and now_ns == self.t_ns:
            return False
        if self.t_ns is not None and now_ns < self.t_ns:  # restart there, as the paper node does
            self.counters["clock_jumps"] += 1
            self.log.warn(f"clock jumped back {(self.t_ns - now_ns) / 1e9:.6g} s: restarting from the initial state")
        if self.t_ns is None or now_ns < self.t_ns:
            self.start(now_ns, "clock jumped back")
            return True
        # whole steps only: the last grid point at or before now (a /clock between grid points rounded to the nearest
        # one published the state of 8 ms stamped 7.6 ms, then again at 8 ms); the tick's time is that point's
        k1 = math.floor((now_ns - self.origin_ns) / self._dt_ns + 1e-9)
        if k1 <= self.k:  # no new grid point since the last tick: nothing new to publish
            return False
        stepper, pending = self.stepper, self._held
        if pending is None:  # a message came since the last tick: the inputs to hold from this tick on
            pending = self._pending()
            for _, i, value in pending:  # the torques the tick's joint values show (held only after the steps)
                stepper.stage(i, value)
        t1 = self.origin_ns + round(k1 * self._dt_ns)  # (now_ns itself on the grid)
        try:  # joint_states stamped at the grid point whose state it carries, as /tf and the recording's log time
            self.x = stepper.tick(self.x, self.k, k1, t1)
        except (SimulationDivergedError, ArithmeticError, ValueError) as exc:
            self.counters["divergences"] += 1
            self.last_divergence = (str(exc), now_ns)
            self.log.error(f"{exc}; restarting from the initial state")
            self.start(now_ns, "diverged")
            return True
        self.k = k1
        self.t_ns = t1
        if pending is not self._held:  # (else held already: holding the same values again changes nothing)
            self._sample(pending)
        return True

    def outputs(self):
        """``(joints, floats, run)`` at the current tick (the core's one-sample outputs)."""
        run, u = self.stepper.sample(self.k, self.x)
        joints, floats = self.layout.values(run, u)
        return joints, floats, run

    def joints(self) -> list:
        """The JointState values at the current tick alone (those of :meth:`outputs`, bit for bit, without the
        per-pulley and per-span outputs: the tick when no Float64 topic has a reader and nothing records)."""
        stepper = self.stepper
        if stepper.fresh == self.k:  # the compiled tick wrote them
            return stepper.y.tolist()
        return self.layout.joint_values(*stepper.pulley_state(self.k, self.x))

    def message(self) -> bytes | None:
        """The ``joint_states`` CDR of the current tick when the compiled tick wrote it (the bytes of the layout's
        :class:`~belt_drive_ros.io.cdr_encoders.JointStateEncoder` of :meth:`joints`), else None."""
        stepper = self.stepper
        if stepper.fresh == self.k and stepper.message is not None:
            return stepper.message.tobytes()  # (the same bytes as bytes(): ~3 us sooner on cold caches)
        return None


class NetworkNode(Node):
    """A belt network as a ROS 2 node (see the module docstring)."""

    #: the parameters it declares
    PARAMETER_NAMES: tuple[str, ...] = tuple(name for name, _, _ in PARAMETERS)

    def __init__(self, node_name: str = "belt_drive", *, scene: str | None = None, **kwargs):
        if scene is not None:
            overrides = [p for p in kwargs.pop("parameter_overrides", None) or [] if p.name != "scene"]
            kwargs["parameter_overrides"] = overrides + [Parameter("scene", value=str(scene))]
        super().__init__(node_name, **kwargs)
        self.recorder = None
        self._record_lock = threading.Lock()  # around the recorder's writes (the input callbacks and the tick)
        self.timing = None
        try:
            values = {}
            for name, default, text in PARAMETERS:
                # read-only (taken at start); a float parameter takes an integer at start (`-p step_rate_hz:=500`,
                # as the paper node): a double
                floating = isinstance(default, float)
                values[name] = declare_read_only(self, name, default, ParameterDescriptor(
                    description=text, dynamic_typing=floating), double=floating)
            settings = NetworkSettings.from_values(values)
        except BaseException:
            self.destroy_node()
            raise
        self.add_pre_set_parameters_callback(self._on_pre_set)
        self.counters: dict = {"published": 0}
        self.layout = NetworkLayout(settings.scene)
        self.sim = NetworkSimulation(settings, self.layout, self.counters, self.get_logger())
        self.sim.on_start = self._record_start
        self.stats = TickStats(self.counters)
        self.last_run = None
        # -- outputs, only to topics with readers ("matched" events keep the counts)
        self._readers = {}

        self._float_readers = 0  # readers of all Float64 outputs together (a tick computes them only for some)
        floats = {topic for topic, _ in self.layout.floats}

        def matched(name):
            self._readers[name] = 0

            def on_matched(info):
                self._readers[name] = info.current_count
                if name in floats:
                    self._float_readers = sum(self._readers.get(topic, 0) for topic in floats)

            return PublisherEventCallbacks(matched=on_matched)

        self._pub_joint = self.create_publisher(JointState, "joint_states", OUTPUT_QOS, event_callbacks=matched("joint_states"))
        self._pub_float = [self.create_publisher(Float64, topic, OUTPUT_QOS, event_callbacks=matched(topic))
                           for topic, _ in self.layout.floats]
        self._pub_tf = None
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            TFMessage = None
        if TFMessage is not None:
            self._pub_tf = self.create_publisher(TFMessage, "/tf", TF_QOS, event_callbacks=matched("/tf"))
        self._pub_description = self.create_publisher(String, "robot_description", DESCRIPTION_QOS)
        self._urdf = self.layout.urdf()
        self._pub_description.publish(String(data=self._urdf))
        self._joint_cdr = self.layout.joint_encoder()
        self._tf_cdr = self.layout.tf_encoder()
        from ..io.cdr_encoders import encode_float64

        self._encode_floats = encode_float64
        # -- inputs
        self._subs = [self.create_subscription(Float64, topic, self._input_callback(topic, i), INPUT_QOS)
                      for topic, i in self.layout.inputs]
        # -- ~/reset (std_srvs/Trigger), as the paper node's: answered at once, the next tick restarts the run
        from std_srvs.srv import Trigger

        from .qos import RESET_QOS  # (the paper node's)

        self._srv_reset = self.create_service(Trigger, "~/reset", self._on_reset, qos_profile=RESET_QOS)
        # -- diagnostics, ticks
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._divergences_seen = 0  # the divergence count at the last /diagnostics (ERROR: more since)
        self._diag_timer = self.create_timer(1.0, self._diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))
        if settings.record_path:
            try:
                self._start_recording(settings)
            except BaseException:
                self.destroy_node()
                raise
        self.timing = TickSource(self, self._tick, self.sim, self.stats, after_tick=lambda: None)
        self.timing.configure()
        names = ", ".join(p.name for p in settings.scene.pulleys)
        self.get_logger().info(f"belt network '{settings.scene.name}' ({names}); {settings.method} at dt = "
                               f"{settings.dt:g} s, {settings.step_rate_hz:g} Hz x {settings.substeps} step(s); "
                               f"crank torque from {settings.drive_source}")

    @property
    def settings(self) -> NetworkSettings:
        return self.sim.settings

    def _on_reset(self, request, response):
        """``~/reset``: the next tick is scene time 0 and publishes the initial state (a burst of calls, one restart)."""
        self.sim.request_reset()
        self.counters["reset_calls"] = self.counters.get("reset_calls", 0) + 1
        response.success = True
        response.message = f"belt network '{self.settings.scene.name}' restarts from its initial state at the next tick"
        return response

    def _on_pre_set(self, params):
        """A name the node does not have is refused by name (:func:`~.parameter_schema.refuse_undeclared`)."""
        refuse_undeclared(self, params, "not a parameter of the node")
        return params

    def _record_start(self, now_ns: int, why: str) -> None:
        """A start of the run as a ``restart`` metadata record of the recording, as the paper node writes it."""
        if self.recorder is not None:
            from ..io.bag_layout import RESTART_METADATA, restart_record

            with self._record_lock:
                self.recorder.add_metadata(RESTART_METADATA, restart_record(now_ns, why))

    def _start_recording(self, s: NetworkSettings) -> None:
        from ..io.recording import BagError, BagExistsError

        record = network_record(s.scene, s.text, method=self.sim.stepper.method, dt=s.dt, tick_ns=s.tick_ns,
                                source="node", tier=self.sim.stepper.tier,  # (the slipping tier steps exact)
                                drive_source=s.drive_source, namespace=self.get_namespace())
        try:
            self.recorder = NetworkBagWriter(s.record_path, self.layout, record, force=s.record_overwrite,
                                             namespace=self.get_namespace(), max_bag_duration=s.max_bag_duration,
                                             max_bag_size=s.max_bag_size, output_qos=OUTPUT_QOS)
        except BagExistsError:
            raise record_path_exists(s.record_path) from None
        except BagError as exc:
            raise NodeConfigError("record_path", str(exc)) from None
        self.get_logger().info(f"recording to {s.record_path}")

    def _input_callback(self, topic: str, pulley: int):
        def on_message(msg):
            # not the tick's lock: the hand-over's (NetworkSimulation.receive) and the recorder's, neither held
            # through a tick's compute
            self.sim.receive(pulley, msg.data)
            recorder = self.recorder
            if recorder is not None:
                now = self.timing.now_ns()
                with self._record_lock:
                    recorder.write_input(topic, msg.data, now)

        return on_message

    # ---------------------------------------------------------------- ticks
    def _tick(self, now_ns: int, defer: bool = False):
        if not self.sim.advance_to(now_ns):
            return None
        t = self.sim.t_ns
        readers, recorder = self._readers, self.recorder
        floats = None
        if recorder is not None or self._float_readers:
            joints, floats, run = self.sim.outputs()
            self.last_run = run
        else:  # nothing reads the per-pulley/span outputs: the joints alone (diagnostics compute the rest at 1 Hz)
            self.last_run = None
            tf_read = self._pub_tf is not None and readers.get("/tf")
            if not (readers["joint_states"] or tf_read):
                self.counters["published"] += 1
                return [] if defer else None
            data = None if tf_read else self.sim.message()
            if data is not None:  # the compiled tick wrote the message: nothing else to do
                self.counters["published"] += 1
                if defer:
                    return [(self._pub_joint.publish, data)]
                self._pub_joint.publish(data)
                return None
            joints = self.sim.joints()
        sends = []
        joint_cdr = tf_cdr = None
        if readers["joint_states"] or recorder is not None:
            joint_cdr = self.sim.message() or self._joint_cdr.encode(t, joints)
            if readers["joint_states"]:
                sends.append((self._pub_joint.publish, joint_cdr))
        tf_read = self._pub_tf is not None and readers.get("/tf")
        if tf_read or recorder is not None:
            tf_cdr = self._tf_cdr.encode(t, joints[: len(self.layout.joints)])
            if tf_read:
                sends.append((self._pub_tf.publish, tf_cdr))
        if floats is not None and self._float_readers:  # the CDR of the outputs read (the recording keeps values)
            for (topic, _), pub, value in zip(self.layout.floats, self._pub_float, floats):
                if readers[topic]:
                    sends.append((pub.publish, self._encode_floats((value,))[0]))
        if recorder is not None:
            with self._record_lock:
                for topic, value in self.sim.applied:
                    recorder.write_input(topic, value, t)
                recorder.write_tick(t, joint_cdr, tf_cdr, floats)
        self.counters["published"] += 1
        if defer:
            return sends
        for publish, data in sends:
            publish(data)
        return None

    def _diagnostics(self) -> None:
        s = self.settings
        with self.timing.lock:
            run = self.last_run
            if run is None and self.sim.started:  # the ticks skipped the outputs (no reader): this tick's
                run = self.sim.outputs()[2]
        status = DiagnosticStatus(name=f"{status_prefix(self)}: simulation", hardware_id=s.scene.name)
        level, message = DiagnosticStatus.OK, "running"
        values = {"scene": s.scene.name, "tier": self.sim.stepper.tier, "method": self.sim.stepper.method}
        values.update({k: str(v) for k, v in self.counters.items() if isinstance(v, int)})
        p50, p99, pmax = self.stats.period_error_ms(self.timing.nominal_period())
        compute = self.timing.compute_us()  # the tick thread's compute time per tick [us] (None without it)
        values.update(period_error_ms_p50=f"{p50:.4f}", period_error_ms_p99=f"{p99:.4f}",
                      period_error_ms_max=f"{pmax:.4f}",
                      tick_compute_us_p50="-" if compute is None else f"{compute[0]:.1f}",
                      tick_compute_us_p99="-" if compute is None else f"{compute[1]:.1f}")
        if run is None:
            message = "waiting for the first tick"
        else:
            use = run.friction_use[0]
            worst = int(use.argmax())
            values["friction_use_max"] = f"{use[worst]:.4g} ({s.scene.pulleys[worst].name})"
            slack = [name for name, flag in zip(s.scene.span_names(), run.slack[0]) if flag]
            if slack:
                level, message = DiagnosticStatus.WARN, f"span(s) would go slack: {', '.join(slack)}"
            elif use[worst] >= 1.0:
                level, message = DiagnosticStatus.WARN, f"{s.scene.pulleys[worst].name} at its capstan limit"
        if self.sim.last_divergence is not None:
            values["last_divergence"] = self.sim.last_divergence[0]
        diverged = self.counters["divergences"] - self._divergences_seen  # in the window since the last publish
        self._divergences_seen = self.counters["divergences"]
        if diverged:  # (as the paper node's: ERROR with the reason; a WARN of slack spans is the lesser news)
            reason = self.sim.last_divergence[0] if self.sim.last_divergence else "diverged"
            level, message = DiagnosticStatus.ERROR, f"{diverged} divergence(s), restarted from the initial state: {reason}"
        status.level, status.message = level, message
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._pub_diag.publish(msg)

    def destroy_node(self):
        if self.timing is not None:
            self.timing.destroy()
        if self.recorder is not None:
            try:
                with self._record_lock:
                    self.recorder.close()
            finally:
                self.recorder = None
        return super().destroy_node()


def run(ros_args: list[str] | None = None, scene: str | None = None, executor: str = "auto",
        node_name: str = "belt_drive", overrides: dict | None = None) -> int:
    """Run one :class:`NetworkNode` until SIGINT/SIGTERM (the paper node's :func:`~.node.run`); exit code 0."""
    from .node import run as run_node

    return run_node(ros_args, scene=scene, executor=executor, node_name=node_name, overrides=overrides,
                    node_class=NetworkNode)
