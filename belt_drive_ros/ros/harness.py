"""Launch-free test harness: a belt-drive node in-process, driven by exact /clock steps.

:class:`BeltDriveHarness` starts a :class:`~belt_drive_ros.ros.node.BeltDriveNode`
on its own rclpy ``Context`` and ROS domain (loopback discovery only), plus a
probe node that publishes ``drive_torque`` and ``/clock`` and records every
output topic. With ``use_sim_time=True`` (the default) the harness owns time:
:meth:`~BeltDriveHarness.advance` publishes ``/clock`` in exact integer-
nanosecond increments and, after each, spins until the node has processed
that time, ticked, and its outputs have arrived. Nothing waits on wall-clock
sleeps, so a run is deterministic: the same torque and clock sequence gives
bit-identical outputs.

Example::

    from belt_drive_ros.ros.harness import BeltDriveHarness

    with BeltDriveHarness(scene="paper", model="flexible", method="etd4") as h:
        h.publish_torque(8.0)            # N m on wheel M, sampled at the next tick and held
        h.advance(0.5)                   # 500 ticks of 1 ms of simulated time
        h.publish_torque(0.0)
        h.advance(0.25)
        out = h.outputs()                # dict of numpy arrays
        print(out["time"][-1], out["shaft_speed"][-1], out["relative_deflection"].max())
        print(h.diagnostics()["simulation"]["values"]["model_reason"])
        assert not h.set_parameters(k=-1.0).successful   # rejected with a reason

``outputs()`` keys: ``time`` (s since the harness started the clock),
``stamp`` (s, ROS time), ``phi_M, phi_1, phi_2, phi_3`` [rad],
``omega_M, omega_1, omega_2, omega_3`` [rad/s], ``drive_torque`` (joint_states
effort of wheel_M) [N m], ``shaft_speed`` [rad/s], ``load_torque``,
``belt_torque`` [N m], ``relative_deflection`` [rad], one row per tick.

A torque source can run in the loop as well: ``source=Engine(...)`` (any
:class:`~belt_drive_ros.core.sources.TorqueProfile`, or ``"scene"`` for the
scene's drive) adds a :class:`~belt_drive_ros.ros.source_node.TorqueSourceNode`
that the harness steps itself after each node tick (it publishes a torque
from the latest ``shaft_speed``; the node samples it at its next tick), so
closed-loop runs are deterministic too.

Lockstep needs the wait-set executor (``executor="single"``, the default):
it sees the tick timer become due right after a ``/clock`` update. With
``use_sim_time=False`` the node runs on the system clock and ``advance``
simply spins for that much wall time.

Each harness open at a time has a ROS domain of its own (unless given
``domain_id``), so two in one script never hear each other. Importing this
module keeps this process's DDS discovery on the machine
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, set only when neither it nor
``ROS_LOCALHOST_ONLY`` is set): your own nodes in the same process are then
local too; set the variable before the import to choose another range.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from . import environment as ros_env

ros_env.configure_environment(loopback=True)

import rclpy  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock as ClockMsg  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from .diagnostics import status_prefix  # noqa: E402
from .executors import make_executor  # noqa: E402
from .node import NODE_NAME, OUTPUT_TOPICS, SLIP_OUTPUT_TOPICS, BeltDriveNode  # noqa: E402
from ..core.errors import real  # noqa: E402
from ..core.sources import TorqueProfile  # noqa: E402
from .parameter_schema import NOT_A_PARAMETER, NodeConfigError, unknown_parameter_rule  # noqa: E402
from rcl_interfaces.msg import SetParametersResult  # noqa: E402

#: the probe keeps everything it receives between drains
_PROBE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
_PUB_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
_LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
#: the highest ROS domain id (Fast DDS's ports of a higher one overflow: the participant fails to start)
DOMAIN_ID_MAX = 232
#: the latest /clock a harness starts at [s] (builtin_interfaces/Time's int32 seconds)
_CLOCK_MAX_S = 2**31 - 1
#: slots of the harnesses open now that chose no domain (slot 0: process_domain_id(); slot n: its offset
#: _SLOT_OFFSET + n), so two open at once have two domains
_OPEN_DEFAULTS: set[int] = set()
_SLOT_OFFSET = 1000


class HarnessTimeout(TimeoutError):
    """The node did not reach the expected state within the harness's timeout."""


class DomainShared(RuntimeError):
    """Another publisher on the harness's ROS domain mixed its messages into the node's outputs."""


class BeltDriveHarness:
    """A belt-drive node, a probe node and (optionally) a torque source on a private context.

    Parameters
    ----------
    scene : str, optional
        Scene name or YAML path for the node; default its ``scene``
        parameter (a ``--params-file`` in ``ros_args`` may set it), else
        ``paper``.
    use_sim_time : bool
        True: the harness publishes ``/clock`` (lockstep). False: system time.
    start_time : float
        First ``/clock`` value [s] (>= 0): the node's scene time 0.
    domain_id : int, optional
        ROS domain (0 .. 232); default one of this process's own
        (:func:`belt_drive_ros.ros.environment.process_domain_id`), another for
        each harness open at the same time.
    executor : str
        ``single`` (default, needed for lockstep), ``events`` or ``auto``.
    source : TorqueProfile or "scene", optional
        A torque source in the loop (see the module docstring).
    source_rate_hz : float, optional
        Source publish rate with ``use_sim_time=False`` (default: node rate).
    namespace, node_name : str
    timeout : float
        Wall seconds any single wait may take before :class:`HarnessTimeout`.
    ros_args : list of str, optional
        Node command-line arguments, e.g. ``["--ros-args", "--params-file", "p.yaml"]``
        (``**params`` override them).
    **params
        ROS parameters of the node (``model="flexible"``, ``k=2e4``, ...).
    """

    def __init__(
        self,
        scene: str | None = None,
        *,
        use_sim_time: bool = True,
        start_time: float = 1.0,
        domain_id: int | None = None,
        executor: str = "single",
        source: TorqueProfile | str | None = None,
        source_rate_hz: float | None = None,
        namespace: str = "",
        node_name: str = NODE_NAME,
        timeout: float = 10.0,
        ros_args: list[str] | None = None,
        **params: Any,
    ):
        number = real(start_time)
        if use_sim_time and (number is None or not 0 <= number <= _CLOCK_MAX_S):
            raise ValueError(f"start_time: simulated time must start at a number of seconds in [0, {_CLOCK_MAX_S}] "
                             f"(a /clock's int32 seconds), got {start_time!r}")
        given = real(domain_id) if domain_id is not None else 0
        if given is None or given != int(given) or not 0 <= given <= DOMAIN_ID_MAX:
            raise ValueError(f"domain_id: must be an integer in [0, {DOMAIN_ID_MAX}] (the ROS 2 domains a DDS port "
                             f"fits), got {domain_id!r}")
        if use_sim_time and executor != "single":
            raise ValueError(
                f"executor={executor!r}: /clock lockstep needs the wait-set executor ('single'); the events "
                "executor runs a tick timer made due by /clock asynchronously"
            )
        self.scene_name = scene
        self.use_sim_time = use_sim_time
        self.start_ns = int(round(start_time * 1e9))
        self._chosen_domain = domain_id is not None
        #: the harness's ROS domain (its default is chosen at :meth:`start`: one of its own per open harness)
        self.domain_id = int(domain_id) if domain_id is not None else None
        self._default_slot: int | None = None
        self.executor_kind = executor
        self.source_spec = source
        self.source_rate_hz = source_rate_hz
        self.namespace = namespace
        self.node_name = node_name
        self.timeout = float(timeout)
        self.params = params
        self.ros_args = list(ros_args or [])
        self.context: Context | None = None
        self.node: BeltDriveNode | None = None
        self.probe: Node | None = None
        self.source = None
        self.executor = None
        self._forget()

    def _forget(self) -> None:
        """No rows, clock or diagnostics received yet (a new start begins a new run)."""
        self._clock_ns = 0
        self._rows: list[tuple] = []
        self._floats: dict[str, list[float]] = {name: [] for name in OUTPUT_TOPICS + SLIP_OUTPUT_TOPICS}
        self._diagnostics: list[DiagnosticArray] = []
        self._t0_wall: int | None = None
        self._published_at_close: int | None = None  # the node's count of published ticks when it was closed

    def _started(self, what: str) -> BeltDriveNode:
        """The node, or a RuntimeError saying the harness is not running."""
        if self.node is None or self.executor is None:
            raise RuntimeError(f"harness.{what}: the harness is not running (call start() first, or use it in a "
                               "'with' block; after close() start() begins a new run)")
        return self.node

    # -------------------------------------------------------------- lifecycle
    def __enter__(self) -> "BeltDriveHarness":
        self.start()
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def start(self) -> None:
        """Create the context, nodes and executor; wait for discovery and (sim time) the first tick.

        Also runs BLAS single-threaded in this process
        (:func:`~belt_drive_ros.ros.environment.limit_blas_threads`).
        """
        if self.node is not None:
            raise RuntimeError("harness.start: the harness is already running (close() it first)")
        ros_env.configure_environment(loopback=True)
        ros_env.limit_blas_threads()
        if not self._chosen_domain:  # a domain of its own while open: two harnesses at once never hear each other
            self._default_slot = min(set(range(len(_OPEN_DEFAULTS) + 1)) - _OPEN_DEFAULTS)
            _OPEN_DEFAULTS.add(self._default_slot)
            self.domain_id = ros_env.process_domain_id(0 if self._default_slot == 0 else _SLOT_OFFSET + self._default_slot)
        self._forget()
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain_id)
        try:
            self._start_nodes()
        except BaseException:
            self.close()
            raise

    def _start_nodes(self) -> None:
        ctx, ns = self.context, self.namespace
        overrides = _parameters(self.params)
        overrides.append(Parameter("use_sim_time", value=bool(self.use_sim_time)))
        rule = unknown_parameter_rule(self.ros_args, BeltDriveNode.PARAMETER_NAMES, self.node_name,
                                      self.namespace or "/")  # (rclpy drops it)
        if rule is not None:
            raise NodeConfigError(rule, NOT_A_PARAMETER)
        self.node = BeltDriveNode(
            self.node_name,
            scene=self.scene_name,
            context=ctx,
            namespace=ns,
            parameter_overrides=overrides,
            cli_args=self.ros_args or None,
        )
        unknown = [name for name in self.params if not self.node.has_parameter(name)]  # (rclpy drops them silently)
        if unknown:
            raise NodeConfigError(unknown[0], NOT_A_PARAMETER)
        self.probe = Node("belt_drive_harness", context=ctx, namespace=ns)
        p = self.probe
        self._pub_torque = p.create_publisher(Float64, "drive_torque", _PUB_QOS)
        self._pub_clock = p.create_publisher(ClockMsg, "/clock", _PUB_QOS)
        self._subs = [p.create_subscription(JointState, "joint_states", self._on_joint, _PROBE_QOS)]
        for name in OUTPUT_TOPICS + SLIP_OUTPUT_TOPICS:
            self._subs.append(
                p.create_subscription(Float64, name, lambda m, name=name: self._floats[name].append(m.data), _PROBE_QOS)
            )
        self._subs.append(p.create_subscription(DiagnosticArray, "/diagnostics", self._diagnostics.append, 10))
        self._reset_client = p.create_client(Trigger, f"{self.node.get_fully_qualified_name()}/reset")
        self.executor = make_executor(ctx, self.executor_kind)
        if self.source_spec is not None:
            self._start_source()
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self._wait_discovery()
        if self.use_sim_time:
            self._step_clock(self.start_ns)
        else:
            self._t0_wall = time.time_ns()

    def _start_source(self) -> None:
        from .source_node import TorqueSourceNode

        s = self.node.settings
        profile = s.scene.drive if self.source_spec == "scene" else self.source_spec
        if not isinstance(profile, TorqueProfile):
            raise TypeError(f"source: expected a TorqueProfile or 'scene', got {self.source_spec!r}")
        rate = self.source_rate_hz or s.step_rate_hz
        self.source = TorqueSourceNode(
            profile,
            context=self.context,
            namespace=self.namespace,
            rate_hz=rate,
            initial_speed=s.scene.initial_state.omega_M,
            initial_angle=s.scene.initial_state.phi_M,
            autostart=not self.use_sim_time,  # in lockstep the harness steps it
        )
        self.executor.add_node(self.source)

    def _wait_discovery(self) -> None:
        checks = [
            lambda: self._pub_torque.get_subscription_count() >= 1,
            lambda: all(sub.get_publisher_count() >= 1 for sub in self._subs),
            lambda: self._reset_client.service_is_ready(),
        ]
        if self.use_sim_time:  # the node's clock (rclpy's time source) and its /clock tick subscription
            checks.append(lambda: self._pub_clock.get_subscription_count() >= 2)
        if self.source is not None:
            checks.append(lambda: self.source._pub.get_subscription_count() >= 1)
            if self.source._sub is not None:
                checks.append(lambda: self.source._sub.get_publisher_count() >= 1)
        self._spin_until(lambda: all(c() for c in checks), "discovery between the harness and the node")
        self._spin_until(
            lambda: all(self.node.refresh_subscriber_counts().values()), "the node to see the probe's subscriptions"
        )

    def close(self) -> None:
        """Destroy the nodes and shut the context down (idempotent)."""
        if self.executor is not None:
            try:
                self.executor.shutdown()
            except Exception:  # noqa: BLE001
                pass
            self.executor = None
        if self.node is not None:
            self._published_at_close = self.node.counters["published"]
        for attr in ("source", "probe", "node"):
            obj = getattr(self, attr)
            if obj is not None:
                obj.destroy_node()
                setattr(self, attr, None)
        if self.context is not None:
            rclpy.try_shutdown(context=self.context)
            self.context = None
        if self._default_slot is not None:
            _OPEN_DEFAULTS.discard(self._default_slot)
            self._default_slot = None

    # ---------------------------------------------------------------- spinning
    def _spin_until(self, predicate, what: str, republish=None, timeout: float | None = None) -> None:
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        retry = time.monotonic() + 0.05
        while not predicate():
            now = time.monotonic()
            if now > deadline:
                raise HarnessTimeout(f"harness: timed out waiting for {what}")
            if republish is not None and now > retry:
                republish()  # /clock is best effort on the node's side: a lost sample is resent
                retry = now + 0.05
            self.executor.spin_once(timeout_sec=0.005)

    def _received_all(self) -> bool:
        n, n_slip = self.node.counters["published"], self.node.counters["published_slip"]
        return len(self._rows) >= n and all(
            len(v) >= (n_slip if name in SLIP_OUTPUT_TOPICS else n) for name, v in self._floats.items()
        )

    def _publish_clock(self, ns: int) -> None:
        msg = ClockMsg()
        msg.clock.sec, msg.clock.nanosec = divmod(ns, 1_000_000_000)
        self._pub_clock.publish(msg)

    def _step_clock(self, target_ns: int) -> None:
        """Publish /clock = target and wait until the node (and source) fully processed it."""
        node = self.node
        self._publish_clock(target_ns)
        self._spin_until(
            lambda: node.get_clock().now().nanoseconds == target_ns,
            f"the node's clock to reach {target_ns / 1e9:.9f} s",
            republish=lambda: self._publish_clock(target_ns),
        )
        self._spin_until(
            lambda: node.integrated_ns is not None and not node.tick_pending() and self._received_all(),
            "the node's tick and outputs",
        )
        self._clock_ns = target_ns
        if self.source is not None and node.integrated_ns == target_ns:
            src = self.source
            if src._sub is not None:  # closed loop: the source sees this tick's shaft_speed first
                self._spin_until(
                    lambda: src.counters["speed_received"] >= node.counters["published"], "the source's shaft_speed"
                )
            received = node.counters["received"]
            src.publish_at(target_ns)
            self._spin_until(lambda: node.counters["received"] > received, "the node to receive the source's torque")

    # -------------------------------------------------------------- the API
    @property
    def now(self) -> float:
        """Harness time [s]: the last /clock published (sim time) or the system clock."""
        if self.use_sim_time:
            return self._clock_ns / 1e9
        return time.time_ns() / 1e9

    def publish_torque(self, value: float, wait: bool = True) -> None:
        """Publish ``drive_torque`` [N m]; with ``wait`` spin until the node has taken it in.

        The node samples it at its next tick and holds it from there (the
        outputs of that tick show it as ``drive_torque``): publish, then
        :meth:`advance`, applies the torque from the next tick on.
        """
        node = self._started("publish_torque")
        received = node.counters["received"]
        self._pub_torque.publish(Float64(data=float(value)))
        if wait:
            self._spin_until(lambda: node.counters["received"] > received, "the node to receive drive_torque")

    def advance(self, seconds: float, step: float | None = None) -> None:
        """Advance time by ``seconds``.

        Sim time: ``/clock`` goes up to the points ``start_time + k step``
        [s] (default step: the node's tick period, so the node's tick grid),
        exactly, in integer nanoseconds, each one processed before the next;
        a target between two of them is reached by a last shorter increment,
        and the next ``advance`` goes on from there to the grid again (so
        ``advance(0.0333)`` three times ticks at the same points as
        ``advance(0.0999)`` once). Real time: spin for ``seconds`` of wall
        time.
        """
        node = self._started("advance")
        if not 0 <= seconds <= 1.0e7:  # (nan, inf, and more than 1e7 s: a sim's longest run)
            raise ValueError(f"advance: seconds must be >= 0 and at most 1e7, got {seconds!r}")
        if not self.use_sim_time:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                self.executor.spin_once(timeout_sec=min(0.01, max(end - time.monotonic(), 0.0)))
            return
        step_ns = node.settings.tick_ns if step is None else int(round(step * 1e9))
        if step_ns <= 0:
            raise ValueError("advance: step must be > 0")
        target = self._clock_ns + int(round(seconds * 1e9))
        while self._clock_ns < target:
            k = (self._clock_ns - self.start_ns) // step_ns + 1  # the next grid point after the clock
            self._step_clock(min(self.start_ns + k * step_ns, target))

    def spin(self, seconds: float) -> None:
        """Spin the executor for ``seconds`` of wall time (time itself does not move in sim time)."""
        self._started("spin")
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def outputs(self) -> dict[str, np.ndarray]:
        """Everything the node published so far, one row per tick (see the module docstring).

        Raises :class:`DomainShared` when more ``joint_states`` arrived than
        the node published: another process publishes on this ROS domain (its
        rows would be mixed with the node's, and a slipping model's topics
        would look incomplete). After :meth:`close` the run's rows stay readable.
        """
        published = self.node.counters["published"] if self.node is not None else self._published_at_close
        if published is None:
            self._started("outputs")
        if len(self._rows) > published:
            raise DomainShared(
                f"harness: {len(self._rows)} joint_states received but the node published {published}: "
                f"another publisher shares ROS domain {self.domain_id}"
            )
        n = min([len(self._rows)] + [len(self._floats[name]) for name in OUTPUT_TOPICS])
        rows = np.array(self._rows[:n], dtype=float).reshape(n, 10)
        zero = self.start_ns if self.use_sim_time else (self._t0_wall or 0)
        out = {
            "stamp": rows[:, 0] / 1e9,
            "time": (rows[:, 0] - zero) / 1e9,
        }
        names = ("phi_M", "phi_1", "phi_2", "phi_3", "omega_M", "omega_1", "omega_2", "omega_3")
        for i, name in enumerate(names):
            out[name] = rows[:, 1 + i]
        out["drive_torque"] = rows[:, 9]
        for name, values in self._floats.items():
            if name in OUTPUT_TOPICS or len(values) >= n > 0:  # the slipping model's topics while it runs
                out[name] = np.array(values[:n], dtype=float)
        return out

    def _on_joint(self, msg: JointState) -> None:
        ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self._rows.append((ns, *msg.position, *msg.velocity, *msg.effort[:1]))

    def diagnostics(self) -> dict[str, dict[str, Any]]:
        """Have the node publish ``/diagnostics`` now; return its statuses by short name.

        ``{"simulation": {"level": "OK", "message": ..., "values": {...}}, "input": ..., "belt": ...}``

        Waits for the node's own array (its statuses are named ``<node>: ...``);
        arrays of other nodes on ``/diagnostics`` are passed over.
        """
        prefix = status_prefix(self._started("diagnostics")) + ": "

        def own(m: DiagnosticArray) -> bool:
            return bool(m.status) and all(st.name.startswith(prefix) for st in m.status)

        count = len(self._diagnostics)
        self.node.publish_diagnostics()
        self._spin_until(lambda: any(own(m) for m in self._diagnostics[count:]), "/diagnostics")
        msg = [m for m in self._diagnostics[count:] if own(m)][-1]
        return {
            st.name.removeprefix(prefix): {
                "level": _LEVELS.get(st.level[0] if isinstance(st.level, bytes) else int(st.level), "?"),
                "message": st.message,
                "values": {kv.key: kv.value for kv in st.values},
            }
            for st in msg.status
        }

    def set_parameters(self, **params: Any):
        """Set node parameters atomically; returns the ``SetParametersResult`` (``.successful``, ``.reason``).
        ``use_sim_time`` is the harness's own (its ``/clock`` lockstep or the system clock): refused here."""
        node = self._started("set_parameters")
        if "use_sim_time" in params:
            return SetParametersResult(successful=False, reason=(
                "use_sim_time: the harness's time base, set when it is made (BeltDriveHarness(use_sim_time=...)); "
                "set_parameters_over_the_service() changes it as another process would"))
        unknown = [name for name in params if not node.has_parameter(name)]
        if unknown:  # an answer with its reason, as for every other refusal (rclpy raised ParameterNotDeclaredException)
            return SetParametersResult(successful=False, reason=f"{unknown[0]}: not a parameter of the node")
        try:
            parameters = _parameters(params)
        except NodeConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return self.node.set_parameters_atomically(parameters)

    def set_parameters_over_the_service(self, **params: Any) -> list:
        """Set node parameters as another process would: a ``SetParameters`` request from the probe
        node through DDS (the node's standard ``~/set_parameters`` service). Returns the
        ``SetParametersResult`` of each, in order (:class:`HarnessTimeout` if the call is never answered)."""
        from rcl_interfaces.srv import SetParameters

        self._started("set_parameters_over_the_service")
        client = self.probe.create_client(SetParameters, f"{self.node.get_fully_qualified_name()}/set_parameters")
        try:
            self._spin_until(client.service_is_ready, "the set_parameters service")
            request = SetParameters.Request(parameters=[p.to_parameter_msg() for p in _parameters(params)])
            future = client.call_async(request)
            self._spin_until(future.done, f"SetParameters({', '.join(params)}) to return", timeout=20.0)
            return list(future.result().results)
        finally:
            self.probe.destroy_client(client)

    def reset(self) -> str:
        """Call the node's ``~/reset`` service; returns its message."""
        self._started("reset")
        future = self._reset_client.call_async(Trigger.Request())
        published = self.node.counters["published"]
        self._spin_until(future.done, "~/reset")
        self._spin_until(lambda: self._received_all() or self.node.counters["published"] == published, "reset outputs")
        return future.result().message


def _parameters(params: dict) -> list:
    """``rclpy`` Parameters of ``name=value`` pairs, numpy scalars as Python numbers (rclpy refuses
    ``np.float32``/``np.int64`` with a TypeError); an integer beyond int64 is a :class:`NodeConfigError` naming the
    parameter (rclpy's conversion failed with a SystemError)."""
    out = []
    for name, value in params.items():
        number = real(value)
        if number is not None:
            value = number
        if isinstance(value, int) and not isinstance(value, bool) and not -(2**63) <= value < 2**63:
            raise NodeConfigError(name, "an integer beyond 2^63")
        out.append(Parameter(name, value=value))
    return out
