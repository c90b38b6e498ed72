"""The belt-drive ROS 2 node: the model core stepped on the node's clock.

:class:`BeltDriveNode` is a plain ``rclpy.node.Node`` (composable into any
executor, any number per process). Topic names are relative, so namespaces
and remaps apply. This module is the wiring; the parts live beside it:

==============================  ===============================================
module                          what
==============================  ===============================================
:mod:`.parameter_schema`        parameters, defaults, validation (no rclpy)
:mod:`.parameters`              descriptors and the set-parameters callbacks
:mod:`.simulation`              plant, state, scene time, outputs (no rclpy)
:mod:`.inputs`                  drive_torque: reject, bound, limit, timeout, hold
:mod:`.timing`                  the three tick sources, tick statistics
:mod:`.diagnostics`             ``/diagnostics``
:mod:`.recorder`                MCAP recording (``record_path``)
:mod:`.executors`               executor, signals, shutdown for every command
==============================  ===============================================

Interface (SI units, REP 103)
-----------------------------
=====================  ======  ==============================================
topic                  dir     type / meaning
=====================  ======  ==============================================
``drive_torque``       sub     ``std_msgs/Float64``: torque on drive wheel M [N m]
``shaft_speed``        pub     ``std_msgs/Float64``: omega_M [rad/s]
``load_torque``        pub     ``std_msgs/Float64``: load torque at wheel 3 [N m]
``belt_torque``        pub     ``std_msgs/Float64``: torque of the belt on wheel 3 [N m]
``relative_deflection`` pub    ``std_msgs/Float64``: ``i phi_M - phi_3`` [rad]
``span_force_tight``   pub     ``std_msgs/Float64``: tight span force [N] (slipping model only)
``span_force_slack``   pub     ``std_msgs/Float64``: slack span force [N] (slipping model only)
``friction_use``       pub     ``std_msgs/Float64``: ``Q / Q_max`` [-] (slipping model only)
``slip``               pub     ``std_msgs/Float64``: 1 while the belt slides, else 0 (slipping model only)
``slip_speed``         pub     ``std_msgs/Float64``: ``s'`` [m/s at the belt] (slipping model only)
``elastic_deflection`` pub     ``std_msgs/Float64``: elastic part of the deflection [rad] (slipping model only)
``slip_angle``         pub     ``std_msgs/Float64``: wheel-3 angle lost to slip ``s / r_3`` [rad] (slipping model only)
``joint_states``       pub     ``sensor_msgs/JointState``, stamped with the tick's time
``robot_description``  pub     ``std_msgs/String``: the drive's URDF from the scene's radii (latched)
``/diagnostics``       pub     ``diagnostic_msgs/DiagnosticArray`` (~1 Hz wall clock)
``/clock``             pub     ``rosgraph_msgs/Clock``, only with ``publish_clock``
``~/reset``            srv     ``std_srvs/Trigger``: restart from the scene's initial state
=====================  ======  ==============================================

``joint_states`` carries the joints ``wheel_M, wheel_1, wheel_2, wheel_3``:
position [rad] and velocity [rad/s] of each wheel, and as *effort* the
external torque on the wheel along its positive rotation [N m]: the drive
torque on ``wheel_M`` (the one applied from this tick on), 0 on the idler
gears ``wheel_1`` and ``wheel_2`` (they carry only internal mesh forces),
and minus the load torque on ``wheel_3``. The belt's own torque on wheel 3
is on ``belt_torque``.

Time (:mod:`.timing`)
---------------------
Each tick integrates the state from the previous tick time to the new one
(whole integrator steps of ``dt = 1 / (step_rate_hz * substeps)``, whole
nanoseconds, and a final partial step if the interval is not a multiple),
samples the drive input there and publishes every output stamped with that
time. On the system clock a thread of the node's own ticks
(``tick_thread``, default true; :class:`~.timing.TickThread`): it computes
each tick ahead (``tick_lead`` at least), publishes it at its due time, and publishes
every missed tick after a late wake; every callback that changes the
simulation (parameters, diagnostics) holds the tick source's lock, which a
tick holds through its compute. The inputs (``drive_torque``, ``~/reset``)
do not: their callbacks hand over under a lock of their own that the tick
takes only at its start, so they are served while a tick computes. Scene time 0 is when the run starts: the first tick on the system
clock, the first ``/clock`` the node sees with ``use_sim_time``, the first
tick of its own clock with ``publish_clock``; and every restart
(``~/reset``, a new ``scene``, a divergence, the clock jumping backwards or
switching between system and simulated time). In ``/clock`` lockstep the
outputs equal ``belt-drive sim`` of the same scene and torque sequence.

Inputs (:mod:`.inputs`)
-----------------------
The drive torque is sampled at each tick and held until the next (a
message received between ticks k-1 and k acts from tick k on; on the
system clock the tick thread computes tick k ahead of its due time, by
``tick_lead`` or more (:class:`~.timing.TickThread`), so a message in that
last stretch acts from tick k+1). The rule is the tick's *start*: a message
received before a tick takes its inputs acts from that tick, one received
while it computes (its callback is not held up) from the next.
``drive_source:=scene`` instead drives wheel M with the scene's drive
profile (messages then are counted and ignored). Before the first message
the torque is 0 N m. NaN/Inf messages and messages beyond ``torque_bound``
(default: derived from the scene) are rejected and counted; with
``torque_limit`` > 0 the torque is clamped to +/- the limit and counted.
After ``input_timeout`` seconds (node clock; 0 disables) without a message
the torque is held or zeroed (``timeout_behavior``) and a WARN diagnostic is
raised. The subscription keeps only the latest message (``KEEP_LAST``,
depth 1) and its callback does constant work, so a burst cannot build a
backlog.

A tick sends each output only to topics that have subscribers (tracked with
the publishers' "matched" events; DDS would deliver to nobody otherwise).

Failures
--------
The node never publishes a non-finite value and never stops silently. A
stretch of its tick grid it could not publish (the process stopped or
starved beyond the tick thread's 50 ms catch-up, the system clock stepped
forward, a clock switch) is a *gap* (:mod:`.gaps`): logged, counted on
``/diagnostics`` (``tick_gaps``, ``ticks_missed``, ``last_gap``; WARN in
its window) and recorded as a ``tick_gap`` metadata record. If
the integrator raises or the state becomes non-finite or exceeds
:data:`~belt_drive_ros.core.simulate.SPEED_LIMIT`, it restarts from the
scene's initial state at that tick (counted as ``divergences``) and reports
ERROR with the reason on ``/diagnostics`` (:mod:`.simulation`).

Parameters (:mod:`.parameter_schema`, :mod:`.parameters`)
---------------------------------------------------------
Every field of :class:`~belt_drive_ros.core.params.BeltDriveParams` (defaults
from the scene) plus the node parameters in ``NODE_PARAMETERS``, all with
descriptors and ranges, loadable with ``--ros-args --params-file``. Changes
at runtime are validated as a whole and rejected with a reason, keeping the
old values; accepted changes apply at once without a restart (the state is
kept, mapped across a rigid <-> flexible switch); a new ``scene`` resets
the model parameters, ``model``, ``method`` and ``substeps`` to the new
scene's values (unless set in the same request) and restarts from its
initial state.
"""

from __future__ import annotations

from array import array

from . import environment as ros_env

ros_env.configure_environment()  # discovery: the user's environment wins (see ros/environment.py), before any context starts

from rclpy.clock import Clock, ClockType  # noqa: E402
from rclpy.event_handler import PublisherEventCallbacks  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64, String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from ..core.errors import BeltDriveError  # noqa: E402
from ..io.bag_layout import RESTART_METADATA, restart_record  # noqa: E402
from ..io.recording import (  # noqa: E402
    ROBOT_DESCRIPTION,
    SLIP_FLOAT_OUTPUTS,
    STRING,
    TF_TOPIC,
    JointStateEncoder,
    TfEncoder,
    encode_float64,
    encode_robot_description,
)
from .diagnostics import NodeDiagnostics  # noqa: E402
from .executors import executor_name, make_executor, ros_session, spin_nodes, stop_on_signals  # noqa: E402,F401 - make_executor re-exported
from .gaps import TICK_GAP_METADATA  # noqa: E402
from .inputs import DriveInput, float64_value  # noqa: E402
from .parameter_schema import (  # noqa: E402,F401 - NodeConfigError, unknown_parameter_rule re-exported
    NOT_A_PARAMETER,
    OWN_PARAMETERS,
    NodeConfigError,
    NodeSettings,
    record_path_exists,
    unknown_parameter_rule,
)
from .parameters import NodeParameters  # noqa: E402
from .qos import DESCRIPTION_QOS, INPUT_QOS, OUTPUT_QOS, RESET_QOS, TF_QOS  # noqa: E402
from .simulation import SLACK, SLIP_TICK_OUTPUTS, SLIPPING, SLIPS, TICK_OUTPUTS, NodeSimulation  # noqa: E402
from .timing import TickSource, TickStats, stamp  # noqa: E402

NODE_NAME = "belt_drive"
JOINT_NAMES = ("wheel_M", "wheel_1", "wheel_2", "wheel_3")
#: Float64 output topics, in publishing order (joint_states is published first).
OUTPUT_TOPICS = ("shaft_speed", "load_torque", "belt_torque", "relative_deflection")
#: where the tick's values (NodeSimulation.values) hold each slipping-model Float64 output
_N_TICK = len(TICK_OUTPUTS)
_SLIP_FLOAT_INDEX = tuple((TICK_OUTPUTS + SLIP_TICK_OUTPUTS).index(signal) for _, signal in SLIP_FLOAT_OUTPUTS)
#: Float64 topics of the slipping model (published after OUTPUT_TOPICS while the model is slipping)
SLIP_OUTPUT_TOPICS = tuple(name for name, _ in SLIP_FLOAT_OUTPUTS)


def tf_message_type():
    """``tf2_msgs.msg.TFMessage`` where tf2_msgs is installed (a system ROS 2), else None.

    The pip wheels this package installs have no tf2_msgs: the node then
    records ``/tf`` (its own encoder writes the bytes) but publishes none;
    ``robot_state_publisher`` on ``joint_states`` fills in.
    """
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


class BeltDriveNode(Node):
    """The belt drive as a ROS 2 node (see the module docstring for its interface).

    Parameters
    ----------
    node_name : str
        Default ``belt_drive``.
    scene : str, optional
        Scene name or path; overrides the ``scene`` parameter (and a params file).
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``namespace``,
        ``parameter_overrides``, ``cli_args``, ...).

    Raises
    ------
    NodeConfigError
        When the parameters given at start are invalid (the message names
        the parameter); the node is destroyed again before raising.

    Example
    -------
    >>> node = BeltDriveNode(context=ctx, parameter_overrides=[Parameter("use_sim_time", value=True)])
    >>> executor = make_executor(ctx); executor.add_node(node); executor.spin()
    """

    #: the parameters it declares (rclpy adds ``use_sim_time`` and ``start_type_description_service``)
    PARAMETER_NAMES: tuple[str, ...] = OWN_PARAMETERS

    def __init__(self, node_name: str = NODE_NAME, *, scene: str | None = None, **kwargs):
        if scene is not None:
            overrides = [p for p in kwargs.pop("parameter_overrides", None) or [] if p.name != "scene"]
            kwargs["parameter_overrides"] = overrides + [Parameter("scene", value=str(scene))]
        super().__init__(node_name, **kwargs)
        self.recorder = None  # NodeRecorder when record_path is set
        self.counters = dict.fromkeys(("published", "published_slip", "slack_ticks", "slip_ticks"), 0)
        self._last: tuple | None = None  # the latest tick's (values, stamp) (see last)
        self._duplicate_name_warned = False
        self._resets_pending = 0  # ~/reset calls since the last tick (the tick restarts once for all)
        self.counters["reset_calls"] = 0
        try:
            self.node_parameters = NodeParameters(self, self._apply_settings)
            settings = self.node_parameters.declare()
        except BaseException:
            self.destroy_node()
            raise
        self.drive = DriveInput(self.counters)
        self.sim = NodeSimulation(settings, self.drive, self.counters, self.get_logger())
        self.sim.on_start = self._record_start
        self.stats = TickStats(self.counters)

        # -- outputs: send only to topics somebody subscribes to ("matched" events keep the counts)
        self._readers = dict.fromkeys(("joint_states",) + OUTPUT_TOPICS + SLIP_OUTPUT_TOPICS, 0)
        self._count_listeners()

        def matched(name):
            def on_matched(info):
                self._readers[name] = info.current_count
                self._count_listeners()

            return PublisherEventCallbacks(matched=on_matched)

        self._pub_joint = self.create_publisher(JointState, "joint_states", OUTPUT_QOS, event_callbacks=matched("joint_states"))
        self._send_joint = self._pub_joint.publish  # (bound once: the usual tick's one send)
        self._pub_float = [
            self.create_publisher(Float64, name, OUTPUT_QOS, event_callbacks=matched(name))
            for name in OUTPUT_TOPICS + SLIP_OUTPUT_TOPICS
        ]
        self._joint_cdr = JointStateEncoder(len(JOINT_NAMES))  # joint_states as CDR bytes (see _publish)
        # -- /tf of the wheels (the same CDR bytes, recorded and, with tf2_msgs installed, published)
        self._tf_cdr = TfEncoder(settings.params)
        tf_type = tf_message_type()
        self._pub_tf = None
        if tf_type is not None:
            self._readers["tf"] = 0
            self._pub_tf = self.create_publisher(tf_type, TF_TOPIC, TF_QOS, event_callbacks=matched("tf"))
        else:
            self.get_logger().info("tf2_msgs is not installed: /tf is recorded, not published "
                                   "(robot_state_publisher on joint_states publishes it)")
        self.refresh_subscriber_counts()
        # -- the drive's URDF, latched (published again when the radii or the wrap angle change)
        self._pub_description = self.create_publisher(String, ROBOT_DESCRIPTION, DESCRIPTION_QOS)
        self._description = ("", b"")  # (URDF, its CDR) last published
        self._publish_description()
        # -- input, service, diagnostics, ticks
        self._sub_torque = self.create_subscription(Float64, "drive_torque", self._on_drive_torque, INPUT_QOS, raw=True)
        self._srv_reset = self.create_service(Trigger, "~/reset", self._on_reset, qos_profile=RESET_QOS)
        self.diagnostics = NodeDiagnostics(self)
        self._diagnostics_due = False  # set by the diagnostics timer while ticking on the system clock
        self._diag_timer = self.create_timer(1.0, self._on_diagnostics_timer, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.timing = TickSource(self, self._tick, self.sim, self.stats, after_tick=self._after_tick)
        self.timing.gaps.on_gap = self._record_gap  # every gap in the ticks: a metadata record (see .gaps)
        self.timing.configure()
        s = settings
        self.get_logger().info(
            f"scene '{s.scene.name}', model {s.model.name} ({s.model_reason}); {s.stability.describe()}; "
            + (f"{s.accuracy.describe()}; " if s.accuracy is not None else "")
            + f"{s.steps}; drive torque bound {s.torque_bound:g} N m"
            + (", publishing /clock" if s.publish_clock else "")
            + (", use_sim_time" if self.timing.use_sim_time() else "")
        )
        self._warn_inaccurate(s)
        if s.record_path:
            try:
                self._start_recording(s)
            except BaseException:
                self.destroy_node()
                raise

    # ------------------------------------------------------------ settings
    @property
    def settings(self) -> NodeSettings:
        """The validated settings in force (read-only view)."""
        return self.sim.settings

    def _apply_settings(self, new: NodeSettings, changed: set) -> None:
        with self.timing.lock:  # not between two steps of the tick thread
            self._apply_settings_locked(new, changed)

    def _apply_settings_locked(self, new: NodeSettings, changed: set) -> None:
        old = self.sim.settings
        self.sim.apply(new, changed, load_torque=self.last.get("load_torque", 0.0))
        if changed & {"step_rate_hz", "publish_clock", "real_time_factor", "tick_thread"}:
            self.timing.configure(was_publishing_clock=old.publish_clock)
        if new.params != old.params:
            self._publish_description()
        self.get_logger().info(
            f"parameters {', '.join(sorted(changed))} applied: model {new.model.name} ({new.model_reason}); "
            f"{new.stability.describe()}" + (f"; {new.accuracy.describe()}" if new.accuracy is not None else "")
        )
        self._warn_inaccurate(new)

    def _warn_inaccurate(self, s: NodeSettings) -> None:
        """A warning when the accuracy guard rates the step stable but not accurate (the node runs it)."""
        if s.accuracy is not None and not s.accuracy.accurate:
            self.get_logger().warn(f"step inaccurate: {s.accuracy.describe()}")

    def _start_recording(self, s: NodeSettings) -> None:
        """Open the recording of ``record_path``; a path that exists (without ``record_overwrite``)
        or cannot be written refuses the start (:class:`NodeConfigError`): asked to record, the
        node never runs without recording."""
        from ..io.recording import BagError, BagExistsError
        from .recorder import NodeRecorder

        try:
            self.recorder = NodeRecorder(self, s.record_path, force=s.record_overwrite,
                                         max_bag_duration=s.max_bag_duration, max_bag_size=s.max_bag_size)
        except BagExistsError:
            raise record_path_exists(s.record_path) from None
        except BagError as exc:  # cannot be created (no such folder, permission, ...)
            raise NodeConfigError("record_path", str(exc)) from None
        except ValueError as exc:
            raise NodeConfigError("record_path", str(exc)) from None
        self._count_listeners()  # (a recording: never the usual tick)
        self.get_logger().info(f"recording to {s.record_path}")
        self._record_description()  # first in the file

    # ---------------------------------------------------------------- input
    def _on_drive_torque(self, data: bytes) -> None:
        """Constant time: validate, bound, clamp, hold (sampled at the next tick). ``data``: the message's
        serialized bytes (a raw subscription: no message object per message, see :func:`.inputs.float64_value`)."""
        value = float64_value(data)
        # not the tick's lock: a tick computing now does not hold this callback up (DriveInput.receive's own lock
        # is held for the hand-over alone; the tick takes the message at its start, see DriveInput.take)
        now = self.timing.now_ns()
        self.drive.receive(value, now, self.sim.settings)
        recorder = self.recorder
        if recorder is not None:  # (the recorder's own lock)
            recorder.record_input(value, now)

    def _publish_description(self) -> None:
        """Publish (and record) the URDF of the drive in force, if it changed."""
        description = encode_robot_description(self.sim.settings.params)
        if description[0] != self._description[0]:
            self._description = description
            self._tf_cdr = TfEncoder(self.sim.settings.params)  # the joint origins move with the radii
            self._pub_description.publish(String(data=description[0]))
            self._record_description()

    def _record_start(self, now_ns: int, why: str) -> None:
        """A start of the run from the initial state as a ``restart`` metadata record of the recording (a re-simulation
        repeats one run from one start: it names a restart it cannot repeat)."""
        if self.recorder is not None:
            self.recorder.add_metadata(RESTART_METADATA, restart_record(now_ns, why))

    def _record_gap(self, gap) -> None:
        """A gap in the ticks (:mod:`.gaps`) as a ``tick_gap`` metadata record of the recording."""
        if self.recorder is not None:
            self.recorder.add_metadata(TICK_GAP_METADATA, gap.metadata())

    def _record_description(self) -> None:
        if self.recorder is not None and self._description[0]:
            self.recorder.write(self.recorder.resolve(ROBOT_DESCRIPTION), STRING, self._description[1],
                                self.timing.now_ns())

    # ---------------------------------------------------------------- ticks
    def _tick(self, now_ns: int, defer: bool = False) -> list | None:
        """Integrate to ``now_ns`` and publish the outputs there (after a pending ``~/reset``).

        ``defer`` (the tick thread, which publishes at the tick's due time):
        return the ``(publish, data)`` calls instead of making them, and leave
        a due diagnostics publish to :meth:`_after_tick`.

        The usual tick (a plain one, :meth:`NodeSimulation.plain_tick`, which the tick kernel took, and nobody
        but ``joint_states``' readers, no recording): ``joint_states`` alone (or nothing), the bytes the compiled
        tick wrote; its values stay where it wrote them (a view: :attr:`last` reads them there, the next tick
        writes them again and sets ``_last`` anew; a failed compiled tick writes nothing); its flags counted
        without reading its outputs (:meth:`_count`'s counts). Every other tick: :meth:`_publish`.
        """
        sim = self.sim
        if now_ns == sim._plain_ns and (send := self._usual) is not False and not self._resets_pending \
                and sim.pending_restart is None:
            done = sim.plain_tick(now_ns)
            if done <= 0:  # the tick kernel took it: minus its outputs' flags (and EVENT per mode switch)
                fresh, c = sim._tick_kernel, self.counters
                self._last = (fresh.values, now_ns, sim.origin_ns)  # floats: TICK_OUTPUTS (+ SLIP_TICK_OUTPUTS)
                c["published"] += 1
                if done == -SLIPPING:  # (the slipping model's usual tick)
                    c["published_slip"] += 1
                elif done:
                    flags = -done & 7
                    if flags & SLIPPING:
                        c["published_slip"] += 1
                    if flags & SLACK:
                        self.stats.window.slack += 1
                        c["slack_ticks"] += 1
                    if flags & SLIPS:
                        self.stats.window.slip += 1
                        c["slip_ticks"] += 1
                if defer:
                    return [] if send is None else [(send, fresh.message.tobytes())]  # (tobytes: the same bytes
                    # as bytes(), ~3 us sooner on cold caches)
                if send is not None:
                    send(fresh.message.tobytes())
                self._after_tick()
                return None
            got = done  # (the general path took it)
        else:
            got = False
            if self._resets_pending or sim.pending_restart is not None:  # the restart is this tick's: scene time 0
                with self.drive.lock:  # here, the initial state published (the inputs' hand-over lock: _on_reset
                    calls, self._resets_pending = self._resets_pending, 0  # counts under it)
                why = [sim.pending_restart] if sim.pending_restart is not None else []
                sim.pending_restart = None
                got = sim.restart("; ".join(why + ([f"~/reset, {calls} call(s) since the last tick"] if calls else [])),
                                  now_ns)
            got = got or sim.advance_to(now_ns)
        sends = self._publish(now_ns, defer) if got else None
        if not defer:
            self._after_tick()
        return sends

    def _after_tick(self) -> None:
        """Work that waits until the outputs are out: nearly a period before the next tick
        (a due recording flush, a due diagnostics publish)."""
        recorder = self.recorder
        if recorder is not None and recorder.flush_due:
            recorder.flush_if_due()
        if self._diagnostics_due:
            self._diagnostics_due = False
            self._diagnostics_now()

    def _publish(self, now_ns: int, defer: bool = False) -> list | None:
        """Publish (and record) the outputs at ``now_ns``: ``joint_states`` first, then the Float64 topics.

        ``defer``: record them, and return the ``(publish, data)`` calls in order instead of making them.

        Each message goes out as its CDR bytes (rclpy's ``publish`` takes a
        serialized message): packed into a template (~3 us for all), where
        converting message objects cost the tick ~35 us. A topic nobody
        subscribes to is not published; the recorder writes the same bytes.
        """
        sim = self.sim
        fresh = sim.fresh(now_ns)  # the compiled tick's outputs and message, or None (the usual tick: _tick)
        v = sim.values(now_ns) if fresh is None else fresh.values.tolist()
        recorder = self.recorder
        sends, record = self._sends(now_ns, v, recorder, self._listening)
        if not defer:
            for publish, data in sends:
                publish(data)
        self._count(v)
        if record is not None:
            recorder.record_tick(*record[0], **record[1])
        self._last = (v, now_ns, sim.origin_ns)
        self.counters["published"] += 1
        return sends if defer else None

    def _count(self, v: list) -> None:
        """Count a tick's slack and slip flags and, for the slipping model's outputs ``v``, the tick."""
        if len(v) > _N_TICK:
            self.counters["published_slip"] += 1
        if v[14]:  # slack
            self.stats.window.slack += 1
            self.counters["slack_ticks"] += 1
        if v[15]:  # slip
            self.stats.window.slip += 1
            self.counters["slip_ticks"] += 1

    def _sends(self, now_ns: int, v: list, recorder, listening) -> tuple[list, tuple | None]:
        """:meth:`_publish`'s ``(publish, data)`` calls of the tick's values ``v`` in order, every topic, and
        the recorder's ``record_tick`` arguments (None without a recorder)."""
        sim = self.sim
        sends = []
        joint_cdr = tf_cdr = payloads = joints = None
        if listening[0] or recorder is not None:
            joint_cdr = sim.joint_message(now_ns)  # written by the compiled tick, or encoded here (the same bytes)
        if joint_cdr is None or recorder is not None or listening[1]:
            # phi_M, phi_1, phi_2, phi_3, omega_M, omega_1, omega_2, omega_3; efforts: drive torque on wheel_M, -load on wheel_3
            joints = (v[0], v[2], v[4], v[6], v[1], v[3], v[5], v[7], v[8], 0.0, 0.0, -v[9])
        if listening[0] or recorder is not None:
            if joint_cdr is None:
                joint_cdr = self._joint_cdr.encode(now_ns, joints)
            if listening[0]:
                sends.append((self._pub_joint.publish, joint_cdr))
        if listening[1] or recorder is not None:
            tf_cdr = self._tf_cdr.encode(now_ns, joints[:4])
            if listening[1]:
                sends.append((self._pub_tf.publish, tf_cdr))
        slipping = len(v) > _N_TICK  # the slipping model's outputs
        floats = None
        if recorder is not None or listening[2] or (slipping and listening[3]):
            floats = (v[1], v[9], v[10], v[11])  # shaft speed, load torque, belt torque, relative deflection
            if slipping:
                floats += tuple(v[j] for j in _SLIP_FLOAT_INDEX)
            payloads = encode_float64((*floats, v[8]))  # the last: drive_torque_applied (joint wheel_M's effort)
            readers = self._readers
            for name, pub, data in zip(OUTPUT_TOPICS + SLIP_OUTPUT_TOPICS, self._pub_float, payloads[:-1]):
                if readers[name]:
                    sends.append((pub.publish, data))
        if recorder is None:
            return sends, None
        return sends, ((now_ns, joints, floats, joints[8]), dict(joint_cdr=joint_cdr, float_cdr=payloads, tf_cdr=tf_cdr))

    @property
    def last(self) -> dict:
        """The latest published tick's signals by name (TICK_OUTPUTS, the slipping model's too; slack and slip
        as bools), its scene ``time`` [s] and ``stamp_ns``; empty before the first."""
        with self.timing.lock:  # (the usual tick keeps its values where the compiled tick wrote them)
            if self._last is None:
                return {}
            v, stamp, origin = self._last
            y = dict(zip(TICK_OUTPUTS + SLIP_TICK_OUTPUTS, v))
        y["slack"], y["slip"] = bool(y["slack"]), bool(y["slip"])
        y["time"] = self.sim.scene_time(stamp) if origin == self.sim.origin_ns else (stamp - origin) / 1e9
        y["stamp_ns"] = stamp
        return y

    def _count_listeners(self) -> None:
        """Whom a tick sends to (from the reader counts): joint_states, /tf, a Float64 output of
        every model, a Float64 output of the slipping model."""
        readers = self._readers
        self._listening = (readers["joint_states"] > 0, readers.get("tf", 0) > 0,
                           any(readers[name] for name in OUTPUT_TOPICS), any(readers[name] for name in SLIP_OUTPUT_TOPICS))
        self._joint_only = not any(self._listening[1:])  # nobody but joint_states' readers: the usual tick
        #: the usual tick's send (see _tick): joint_states' publish, None (nobody reads it), False (not the usual
        #: tick: other readers or a recording)
        self._usual = False if not self._joint_only or self.recorder is not None else \
            getattr(self, "_send_joint", None) if self._listening[0] else None

    def refresh_subscriber_counts(self) -> dict[str, int]:
        """Query the readers of each output topic now (the "matched" events keep them current
        afterwards); a driver that has just subscribed calls this before the next tick."""
        self._readers["joint_states"] = self._pub_joint.get_subscription_count()
        if self._pub_tf is not None:
            self._readers["tf"] = self._pub_tf.get_subscription_count()
        for name, pub in zip(OUTPUT_TOPICS + SLIP_OUTPUT_TOPICS, self._pub_float):
            self._readers[name] = pub.get_subscription_count()
        self._count_listeners()
        return {name: n for name, n in self._readers.items() if name != "tf"}  # /tf: nobody need listen

    def tick_pending(self) -> bool:
        """True while the tick timer is due but its callback has not run yet (for lockstep drivers)."""
        return self.timing.tick_pending()

    # --------------------------------------------------------------- status
    @property
    def integrated_ns(self) -> int | None:
        """Time [ns, node time base] the state is integrated to (None before the run starts)."""
        return self.sim.t_ns

    @property
    def origin_ns(self) -> int:
        """Node time [ns] of scene time 0."""
        return self.sim.origin_ns

    @property
    def drive_torque(self) -> float:
        """The drive torque [N m] the plant holds now (sampled at the last tick)."""
        return self.drive.applied.value

    @property
    def state(self):
        """Copy of the model state (ordering: :mod:`belt_drive_ros.core.model`)."""
        return self.sim.x.copy()

    def diagnostic_status(self):
        """The node's health now (see :mod:`.diagnostics`; starts a new window)."""
        with self.timing.lock:
            return self.diagnostics.status()

    def publish_diagnostics(self) -> None:
        """Publish ``/diagnostics`` now (the 1 Hz wall timer calls this too)."""
        with self.timing.lock:
            self.diagnostics.publish()

    def _on_diagnostics_timer(self) -> None:
        failure = self.timing.failure
        if failure is not None:  # the tick thread ended with an exception: the process must not go on without ticks
            raise RuntimeError(f"the tick thread stopped: {type(failure).__name__}: {failure}") from failure
        if self.sim.started and self.timing.time_base() == "system":
            # building them takes 0.2-0.7 ms: the next tick does it right after its outputs are
            # out, instead of now, at any phase of the period, where it would delay that tick
            self._diagnostics_due = True
            self.timing.defer_after_tick()  # (an executor timer's tick calls _after_tick every time)
            return
        self._diagnostics_now()

    def _diagnostics_now(self) -> None:
        with self.timing.lock:
            self._warn_duplicate_name()
            self.diagnostics.publish()

    def _warn_duplicate_name(self) -> None:
        """Warn (once) when another node in the domain has this node's name and namespace."""
        if self._duplicate_name_warned:
            return
        me = (self.get_name(), self.get_namespace())
        if sum(1 for entry in self.get_node_names_and_namespaces() if tuple(entry) == me) > 1:
            self._duplicate_name_warned = True
            self.counters["duplicate_name"] = 1
            self.get_logger().warn(
                f"another node named {self.get_fully_qualified_name()} is in this ROS domain: its topics, "
                "parameters and ~/reset mix with this one's; give each a unique name or namespace"
            )

    # ------------------------------------------------------------- service
    def _on_reset(self, request, response):
        """Constant time: the restart is done by the next tick (every call until then is one restart).

        A burst of calls therefore costs each one only its answer: the ticks
        go on, and no call publishes an output set of its own. The answer
        comes before the restart is published; the next tick publishes the
        initial state. (Two nodes of the same name in a domain
        both serve this one service name: a call reaches either or both, as
        DDS delivers requests to every matching server.) The next tick is the restart: scene time 0 at its
        time, its outputs the initial state (as a /clock that jumped back restarts where it landed).
        """
        with self.drive.lock:  # the inputs' hand-over lock, not the tick's: a tick computing now does not hold it
            self._resets_pending += 1
            self.counters["reset_calls"] += 1
        response.success = True
        response.message = (f"scene '{self.sim.settings.scene.name}' restarts from its initial state at the "
                            "next tick")
        return response

    def reset(self) -> None:
        """Restart from the scene's initial state at the next tick (as ``~/reset``: scene time 0 there, the initial
        state its outputs)."""
        with self.drive.lock:
            self._resets_pending += 1

    def destroy_node(self):
        timing = getattr(self, "timing", None)
        if timing is not None:
            timing.destroy()
        if getattr(self, "recorder", None) is not None:
            try:
                self.recorder.close()
            finally:
                self.recorder = None
        return super().destroy_node()


def run(
    ros_args: list[str] | None = None,
    scene: str | None = None,
    executor: str = "auto",
    node_name: str = NODE_NAME,
    overrides: dict | None = None,
    node_class=None,
) -> int:
    """Run one :class:`BeltDriveNode` (or ``node_class``: a belt network's node) until SIGINT/SIGTERM; return the exit code (0).

    ``ros_args`` are ROS command-line arguments (``--ros-args -p k:=1e5
    --params-file f.yaml -r __ns:=/truck``); ``overrides`` are parameter
    values that win over them (the command's own options). Invalid
    parameters raise :class:`NodeConfigError` after rclpy is shut down again.
    """
    node_class = node_class or BeltDriveNode
    unknown = unknown_parameter_rule(ros_args or [], node_class.PARAMETER_NAMES, node_name)
    if unknown is not None:
        raise NodeConfigError(unknown, NOT_A_PARAMETER)
    # SIGINT/SIGTERM from here on stop the node cleanly, also in its start-up (it opens its recording there): the first
    # is kept and the spin never begins, so the node is destroyed and its recording closed whole (exit 0); a second
    # one in the start-up ends it at once. (Python's KeyboardInterrupt could land in a finalizer of gc.collect(),
    # which swallows it, or inside the recorder's opening; SIGTERM killed the process with the file unfinished.)
    with stop_on_signals(starting=True) as stop, ros_session(["belt-drive-node", *(ros_args or [])]) as context:
        params = [Parameter(name, value=value) for name, value in (overrides or {}).items()]
        node = node_class(node_name, scene=scene, context=context, parameter_overrides=params)
        from . import memprobe

        memprobe.install(node)  # only with BELT_DRIVE_MEMPROBE set (a debugging switch)
        log = node.get_logger()
        if stop.done():
            log.info(f"signal {stop.result()} during the start-up: not spinning")
        spin_nodes(
            [node], context, executor=executor, stop=stop,
            started=lambda ex: stop.done() or log.info(f"spinning with the {executor_name(ex)} executor"),
            stopped=lambda signum: log.info(f"shutting down (signal {signum})" if signum else "shutting down"),
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m belt_drive_ros.ros.node [SCENE] [--ros-args ...]``."""
    import sys

    args = list(sys.argv[1:] if argv is None else argv)
    scene = None
    if args and not args[0].startswith("-"):
        scene = args.pop(0)
    try:
        return run(args, scene=scene)
    except BeltDriveError as exc:
        print(f"belt-drive node: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
