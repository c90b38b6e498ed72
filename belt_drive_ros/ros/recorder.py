"""Live MCAP recording from ROS 2: :class:`TopicRecorder` (any topics) and :class:`NodeRecorder`.

The file layout, metadata and time stamps are those of
:mod:`belt_drive_ros.io.recording` (read its docstring); this module adds
what needs rclpy: subscriptions that write serialized messages as received,
the offered QoS from discovery, and a flush timer on the node.
"""

from __future__ import annotations

import os
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional

from msg_tools import Ros2McapWriter
from msg_tools.errors import MsgToolsError

from msg_tools.units import UNITS_METADATA

from ..io.recording import (
    APPLIED_TOPIC,
    FLOAT64,
    FLOAT_OUTPUTS,
    SLIP_FLOAT_OUTPUTS,
    JOINT_STATE,
    PARAMETERS_METADATA,
    RECORDED_DRIVE,
    SCENE_METADATA,
    TF_MESSAGE,
    TF_TOPIC,
    TOPIC_TYPES,
    _fmt,
    _scene_record,
    bag_error,
    encode_float64,
    JointStateEncoder,  # re-exported: it lived here
    scene_mapping,
    units_metadata,
)

__all__ = ["APPLIED_TOPIC", "DIRECT_TOPICS", "JointStateEncoder", "NodeRecorder", "TopicRecorder", "message_definitions",
           "open_writer", "release_free_heap"]

def _message_class(type_name: str):
    """The rclpy message class of ``pkg/msg/Type``."""
    import importlib

    package, _, name = type_name.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"message type {type_name} is not installed ({exc})") from None


def message_definitions(type_name: str) -> Dict[str, str]:
    """``.msg`` texts of ``type_name`` and its dependencies that msg_tools does not know.

    Read from the installed ROS share directory (``share/<pkg>/msg/<Type>.msg``
    under the ament prefix or this Python's prefix). Raises ``ValueError``
    when one cannot be found.
    """
    import sys

    from msg_tools import schemas

    out: Dict[str, str] = {}
    todo = [schemas.normalize_type_name(type_name)]
    while todo:
        name = todo.pop()
        if name in out or name in schemas.MESSAGE_DEFINITIONS:
            continue
        package, _, short = name.split("/")
        candidates = []
        try:
            from ament_index_python.packages import get_package_share_directory

            candidates.append(get_package_share_directory(package))
        except Exception:  # noqa: BLE001 - no ament index (pip wheels)
            pass
        candidates.append(os.path.join(sys.prefix, "share", package))
        for share in candidates:
            file = os.path.join(share, "msg", short + ".msg")
            if os.path.isfile(file):
                with open(file, encoding="utf-8") as f:
                    out[name] = f.read()
                break
        else:
            raise ValueError(f"no .msg definition of {name} found (looked in {', '.join(candidates)})")
        todo.extend(schemas.dependencies(name, out[name]))
    return out


def release_free_heap() -> bool:
    """Give malloc's free heap pages back to the system: glibc ``malloc_trim(0)`` (through ctypes).

    A split recording finishes a file every ``max_bag_duration``: its chunk
    indexes and buffers are freed, but glibc keeps the freed pages in its
    arenas, fragmented by what stayed allocated between them, so the RSS
    creeps up while Python's own memory is flat. Called when a split file has
    been finished. Returns True if glibc reported memory released; False on
    any other C library (musl, macOS) or if the call is unavailable: never
    raises.
    """
    global _MALLOC_TRIM
    if _MALLOC_TRIM is None:
        _MALLOC_TRIM = False
        try:
            import ctypes
            import platform

            if platform.libc_ver()[0] == "glibc":
                libc = ctypes.CDLL("libc.so.6", use_errno=True)
                trim = libc.malloc_trim
                trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
                _MALLOC_TRIM = trim
        except (OSError, AttributeError, ValueError):
            _MALLOC_TRIM = False
    if not _MALLOC_TRIM:
        return False
    try:
        return bool(_MALLOC_TRIM(0))
    except Exception:  # noqa: BLE001 - an optimisation, never fatal
        return False


_MALLOC_TRIM: Any = None  # resolved on first use: the ctypes function, or False

#: latched topics (by their last name segment): a split recording starts every file with the latest message of each
LATCHED_TOPICS = ("robot_description", "tf_static")
#: messages held on simulated time until the first /clock (TopicRecorder.write) keep at most this many bytes
MAX_HELD_BYTES = 8 * 2**20


def open_writer(path, *, force: bool = False, max_bag_duration: float = 0.0, max_bag_size: int = 0,
                what: str = "--out", **options: Any):
    """The writer of a recording: one MCAP file, or a rosbag2 bag folder split by time or size.

    Parameters
    ----------
    path : path
        The ``.mcap`` file; with a split, the bag folder ``NAME`` (files
        ``NAME/NAME_0.mcap``, ``NAME_1.mcap``, ... and ``metadata.yaml``).
    force : bool
        Replace an existing file (or the bag files of an existing folder).
    max_bag_duration : float
        New file once the current one spans this much log time [s]; 0: no limit.
    max_bag_size : int
        New file once the current one holds this many bytes; 0: no limit.
    what : str
        What named ``path`` (``--out``; '' for a node's ``record_path``), for the bag folder lock's refusal.
    **options
        Passed to :class:`msg_tools.Ros2McapWriter` (chunk_size, compression, flush_interval_s).

    Notes
    -----
    The MCAP writer keeps one chunk index per chunk until the file is
    finished (the summary needs them): ~0.9 KiB per chunk for the node's 7
    topics (measured by tests/test_recording_memory.py), with a chunk every
    0.25 s ~3.6 KiB per second of recording, ~12 MiB an hour. A split finishes each
    file and drops its indexes, which bounds a recording's memory by the
    split size.

    A bag folder is written under its lock (:func:`belt_drive_ros.io.bag_folder.bag_folder_lock`, as ``belt-drive
    sim --bag-folder`` takes it), held until the writer finishes: a second recorder or run into the same folder is
    refused (:class:`~belt_drive_ros.io.bag_folder.BagFolderBusy`, naming the holder's pid) before it looks at it.
    """
    from msg_tools.bagdir import Ros2BagWriter

    if max_bag_duration or max_bag_size:
        from ..io.bag_folder import bag_folder_lock

        return Ros2BagWriter(path, force=force, max_bag_duration=max_bag_duration or None,
                             max_bag_size=max_bag_size or None, hold=bag_folder_lock(path, what), **options)
    return Ros2McapWriter(path, force=force, **options)


class TopicRecorder:
    """Raw subscriptions on an rclpy node whose CDR bytes go to a :class:`Ros2McapWriter`.

    Parameters
    ----------
    node : rclpy.node.Node
        Node that owns the subscriptions and whose clock stamps ``log_time``.
    writer : Ros2McapWriter
        Open writer; :meth:`close` finishes it.
    flush_period : float or None
        Wall-clock (steady) period [s] of the flush timer; None: no timer.
    depth : int
        ``keep_last`` depth of each subscription (messages queued while the
        executor is busy).

    Notes
    -----
    Each message costs one Python callback (~10-20 us) and one
    :meth:`~msg_tools.Ros2McapWriter.write_raw`. The subscriptions match the
    publishers' reliability (best effort if any publisher is) and
    durability (transient local if all publishers are), as ``ros2 bag record``
    does; what the publishers offered goes into ``offered_qos_profiles``.
    """

    def __init__(self, node, writer: Ros2McapWriter, *, flush_period: Optional[float] = 0.25, depth: int = 1000,
                 lock=None):
        import threading

        from rclpy.clock import Clock, ClockType

        #: held around every use of the writer (a node's tick thread writes beside the executor's callbacks)
        self.lock = lock if lock is not None else threading.RLock()
        #: when it returns True the flush timer only marks a flush due (``flush_due``) and the owner
        #: calls :meth:`flush_if_due` at a better moment (a node's tick thread: right after a tick is out;
        #: ``flush_due`` is set before it is called)
        self.defer_flush: Optional[Callable[[], bool]] = None
        self.flush_due = False
        self.node = node
        self.writer = writer
        self.path = writer.path or "<stream>"
        self.depth = int(depth)
        self.error: Optional[BaseException] = None
        self.closed = False
        self._clock = node.get_clock()
        #: log time [ns] of a message a subscription receives: the node's clock (a node recorder: its time base)
        self.now_ns: Callable[[], int] = lambda: self._clock.now().nanoseconds
        self._subs: Dict[str, Any] = {}
        self._types: Dict[str, str] = {}
        self._declared: set = set()
        self._unflushed = 0
        self._files_done = 0  # split files finished so far (a bag folder)
        self._time_known = False  # False until the first message with a time of the run (see write)
        self._first_ns = 0  # that time [ns]
        self._held: List[tuple] = []  # (topic, type, data) written on sim time before the first /clock
        self._held_bytes = 0
        self.held_dropped = 0
        self.heap_trims = 0
        self._timer = None
        #: subscribe transient local where every publisher offers it, so the history a
        #: latched topic kept from before the recording starts is recorded too (as ros2 bag
        #: record does); NodeRecorder turns it off: a run's recording starts with the run
        self.record_history = True
        if flush_period:
            self._timer = node.create_timer(float(flush_period), self._on_flush_timer,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))

    # -------------------------------------------------------------- status
    @property
    def failed(self) -> bool:
        """True after a write error (recording stopped)."""
        return self.error is not None

    @property
    def topics(self) -> Dict[str, str]:
        """Recorded topics (resolved names) and their types."""
        return dict(self._types)

    @property
    def message_count(self) -> int:
        return self.writer.message_count

    @property
    def status(self) -> str:
        """One line for ``/diagnostics``: where, how much, or why it stopped."""
        if self.error is not None:
            return f"FAILED, recording stopped: {self.error}"
        if self.closed:
            return f"closed {self.path} ({self.writer.message_count} messages)"
        return f"recording {self.path} ({self.writer.message_count} messages)"

    # ------------------------------------------------------------- topics
    def publisher_counts(self) -> Dict[str, int]:
        """Publishers matched by each subscription (0: nothing recorded from it yet)."""
        return {topic: sub.get_publisher_count() for topic, sub in self._subs.items()}

    def resolve(self, topic: str) -> str:
        return self.node.resolve_topic_name(topic)

    def offered_qos(self, topic: str) -> List[Any]:
        """QoS profiles the current publishers of ``topic`` offer (rclpy profiles)."""
        try:
            infos = self.node.get_publishers_info_by_topic(topic)
        except Exception:  # noqa: BLE001 - graph query failed: fall back to the default
            return []
        return [info.qos_profile for info in infos]

    def subscription_qos(self, topic: str):
        """QoS that matches every current publisher of ``topic`` (see class notes)."""
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        offered = self.offered_qos(topic)
        reliability = ReliabilityPolicy.RELIABLE
        durability = DurabilityPolicy.VOLATILE
        if topic == "/clock" or any(q.reliability == ReliabilityPolicy.BEST_EFFORT for q in offered):
            reliability = ReliabilityPolicy.BEST_EFFORT
        if (self.record_history and offered
                and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)):
            durability = DurabilityPolicy.TRANSIENT_LOCAL
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self.depth,
                          reliability=reliability, durability=durability)

    def add(self, topic: str, type_name: str) -> str:
        """Subscribe to ``topic`` (relative names resolve against the node) of ``type_name``.

        Returns the resolved topic name. Types msg_tools has no definition of
        are looked up in the installed ROS share directory (``ValueError`` if
        absent).
        """
        from msg_tools import schemas

        resolved = self.resolve(topic)
        full_type = schemas.normalize_type_name(type_name)
        if resolved in self._subs:
            return resolved
        if full_type not in schemas.MESSAGE_DEFINITIONS:
            for name, text in message_definitions(full_type).items():
                self.writer.register_type(name, text)
        msg_class = _message_class(full_type)
        self._types[resolved] = full_type
        self._subs[resolved] = self.node.create_subscription(
            msg_class, resolved, self._callback(resolved, full_type), self.subscription_qos(resolved), raw=True
        )
        return resolved

    def _callback(self, topic: str, type_name: str) -> Callable[[bytes], None]:
        write = self.write

        def on_message(data: bytes) -> None:
            write(topic, type_name, data, self.now_ns())

        return on_message

    def _declare(self, topic: str, type_name: str) -> None:
        from msg_tools.qos import QosProfile

        try:
            infos = self.node.get_publishers_info_by_topic(topic)
        except Exception:  # noqa: BLE001 - graph query failed: defaults below
            infos = []
        offered = [QosProfile.from_rclpy(info.qos_profile) for info in infos]
        # the type hash as discovery reports it; computed from the definition if none is valid
        hashes = [str(info.topic_type_hash) for info in infos
                  if str(getattr(info, "topic_type_hash", "")).startswith("RIHS")]
        self.writer.add_topic(topic, type_name, offered or "reliable", type_hash=hashes[0] if hashes else None)
        if topic.rsplit("/", 1)[-1] in LATCHED_TOPICS and hasattr(self.writer, "latch"):
            self.writer.latch(topic)  # a split recording repeats it at the start of every file
        self._declared.add(topic)

    def write(self, topic: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        """Write one serialized message directly (no subscription), with the same error handling.

        On simulated time before the first ``/clock`` (``log_time_ns`` 0 while
        ROS time is active) the message is held and written, in order, with
        the first time of the run: that of the first message written at a later
        time, or the time :meth:`run_started` gives (a node's first tick, whose
        time is the run's even when ``/clock`` started at 0). A latched ``robot_description`` and the
        first ``/diagnostics`` therefore do not sit at the epoch, decades before
        the rest. Held messages are bounded (:data:`MAX_HELD_BYTES`: the oldest
        are dropped beyond, counted in ``held_dropped``); :meth:`close` writes
        what is still held at time 0 (no ``/clock`` ever came).
        """
        if self.error is not None or self.closed:
            return
        with self.lock:
            if log_time_ns == 0 and self._clock.ros_time_is_active:  # the node's clock has no /clock yet
                if not self._time_known:
                    self._hold(topic, type_name, data)
                    return
                log_time_ns = self._first_ns
            elif not self._time_known:
                self.run_started(log_time_ns)
            self._write(topic, type_name, data, log_time_ns)

    def run_started(self, log_time_ns: int) -> None:
        """The run's time base is known from ``log_time_ns`` on (0 included): write what was held there."""
        with self.lock:
            if not self._time_known and self.error is None and not self.closed:
                self._time_known, self._first_ns = True, int(log_time_ns)
                self._write_held(log_time_ns)

    def _write(self, topic: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        try:
            if topic not in self._declared:
                self._declare(topic, type_name)
            self.writer.write_raw(topic, type_name, data, log_time_ns)
            self._unflushed += 1
        except (MsgToolsError, OSError) as exc:
            self._fail(exc)

    def _hold(self, topic: str, type_name: str, data: bytes) -> None:
        self._held.append((topic, type_name, data))
        self._held_bytes += len(data)
        while self._held_bytes > MAX_HELD_BYTES and len(self._held) > 1:
            self._held_bytes -= len(self._held.pop(0)[2])
            self.held_dropped += 1

    def _write_held(self, log_time_ns: int) -> None:
        held, self._held, self._held_bytes = self._held, [], 0
        for topic, type_name, data in held:
            self._write(topic, type_name, data, log_time_ns)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        if self.error is not None or self.closed:
            return
        with self.lock:
            try:
                self.writer.add_metadata(name, dict(data))
            except (MsgToolsError, OSError) as exc:
                self._fail(exc)

    # --------------------------------------------------------- flush/close
    def _on_flush_timer(self) -> None:
        if self.defer_flush is not None:
            self.flush_due = True  # (marked before the owner is told: it may flush at once)
            if self.defer_flush():
                return
            self.flush_due = False
        with self.lock:
            self._flush()

    def flush_if_due(self) -> None:
        """Flush now if the flush timer marked a flush due (see ``defer_flush``)."""
        if self.flush_due:
            self.flush_due = False
            with self.lock:
                self._flush()

    def _flush(self) -> None:
        if self._unflushed and self.error is None and not self.closed:
            try:
                self.writer.flush()
                self._unflushed = 0
            except (MsgToolsError, OSError) as exc:
                self._fail(exc)
        files = getattr(self.writer, "files", None)  # a split recording (Ros2BagWriter)
        if files is not None and len(files) - 1 > self._files_done:
            self._files_done = len(files) - 1
            release_free_heap()  # a file was finished: its freed memory back to the system
            self.heap_trims += 1

    def _fail(self, exc: BaseException) -> None:
        if self.error is None:
            self.error = bag_error(exc)
            self.node.get_logger().error(
                f"recording stopped: {self.error}; the file keeps what was written up to its last "
                "complete chunk; the node keeps running"
            )

    def close(self) -> None:
        """Stop recording and finalize the file (summary, rosbag2 metadata). Idempotent."""
        with self.lock:
            self._close()

    def _close(self) -> None:
        if self.closed:
            return
        if self._held and self.error is None:  # no /clock ever came: time 0 is all there is
            self.run_started(0)
        self.closed = True
        for sub in self._subs.values():
            try:
                self.node.destroy_subscription(sub)
            except Exception:  # noqa: BLE001 - node may be shutting down already
                pass
        self._subs.clear()
        if self._timer is not None:
            try:
                self.node.destroy_timer(self._timer)
            except Exception:  # noqa: BLE001
                pass
            self._timer = None
        try:
            self.writer.finish()
        except (MsgToolsError, OSError) as exc:
            self._fail(exc)


def _node_parameters(node) -> Dict[str, str]:
    """All parameters of ``node`` as text."""
    out = {}
    for name, parameter in sorted(node.get_parameters_by_prefix("").items()):
        value = parameter.value
        out[name] = _fmt(list(value) if isinstance(value, (list, tuple)) else value)
    return out


#: topics the node writes itself from its tick or input callback (no subscription, no DDS loop-back)
DIRECT_TOPICS = ("drive_torque", APPLIED_TOPIC, "joint_states", TF_TOPIC) + tuple(
    name for name, _ in FLOAT_OUTPUTS + SLIP_FLOAT_OUTPUTS)
_DIRECT_TYPES = {"joint_states": JOINT_STATE, TF_TOPIC.lstrip("/"): TF_MESSAGE}


class NodeRecorder(TopicRecorder):
    """Record a belt-drive node's input and outputs into an MCAP file.

    The node writes its own topics (:data:`DIRECT_TOPICS`) straight to the
    writer: :meth:`record_input` from its ``drive_torque`` callback (log time
    = receipt on the node's clock, the value as received) and
    :meth:`record_tick` from every tick (log time = the tick time exactly):
    ``joint_states``, the four Float64 outputs and ``drive_torque_applied``,
    the torque the plant holds from that tick on (after NaN rejection, the
    bound, the limit and the input timeout). The scene metadata refers to
    ``drive_torque_applied``, so
    :func:`~belt_drive_ros.io.torque_bag.scene_from_bag` re-simulates the run
    from what the node really applied. Other topics (``/diagnostics``,
    ``/clock``) are subscribed.

    Parameters
    ----------
    node : rclpy.node.Node
        The node (usually :class:`~belt_drive_ros.ros.node.BeltDriveNode`). Its
        topics are resolved against its namespace; ``log_time`` comes from
        its clock (simulated time with ``use_sim_time``).
    path : path or binary stream
        Output file; refused if it exists unless ``force``.
    topics : iterable of str, optional
        Default: :data:`DIRECT_TOPICS`, ``/diagnostics``, and ``/clock``
        when the node uses or publishes sim time. Names outside
        :data:`TOPIC_TYPES` are given as ``name:pkg/msg/Type``.
    force : bool
        Replace an existing file.
    chunk_size, compression, flush_interval_s
        See :class:`msg_tools.Ros2McapWriter`; the wall-clock flush timer
        uses ``flush_interval_s`` too.
    max_bag_duration, max_bag_size
        Split into a rosbag2 bag folder at ``path`` (see :func:`open_writer`);
        every file repeats the metadata so far (scene, parameters, units).

    Raises
    ------
    BagExistsError, BagWriteError
        If the file exists (without ``force``) or cannot be created.

    Notes
    -----
    A run re-simulates exactly while it is one run: a restart (``~/reset``,
    a divergence, a clock jump) or a parameter change starts a different
    one; the ``parameters`` metadata records each change with its time.
    """

    def __init__(self, node, path, topics: Optional[Iterable[str]] = None, force: bool = False, *,
                 chunk_size: int = 128 * 1024, compression: str = "zstd", flush_interval_s: float = 0.25,
                 max_bag_duration: float = 0.0, max_bag_size: int = 0):
        try:
            writer = open_writer(path, force=force, chunk_size=chunk_size, compression=compression,
                                 flush_interval_s=flush_interval_s, max_bag_duration=max_bag_duration,
                                 max_bag_size=max_bag_size, what="")  # (the node says record_path)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None
        timing = getattr(node, "timing", None)
        # a lock of its own (not the tick's): a drive_torque callback records its message while a tick computes
        super().__init__(node, writer, flush_period=flush_interval_s)
        if timing is not None:
            # one time base in the file: with publish_clock the outputs' is the node's simulated time, so /clock and
            # /diagnostics are logged on it too (the node's clock is the system's: 56 years apart)
            self.now_ns = timing.now_ns
            self.defer_flush = timing.defer_after_tick  # compressing a chunk takes ~1 ms: not while a tick waits
        self.record_history = False  # the node's outputs keep 10 messages for late joiners: not this run's
        uses_clock = self._uses_sim_time() or self._publishes_clock()
        if topics is None:
            wanted = list(DIRECT_TOPICS) + [t for t in TOPIC_TYPES if t.startswith("/") and t not in DIRECT_TOPICS
                                            and (t != "/clock" or uses_clock)]
        else:
            wanted = list(topics)
        self._direct: Dict[str, str] = {}
        namespace = node.get_namespace()
        try:
            units = units_metadata(namespace)
            units[self.resolve(APPLIED_TOPIC)] = units[self.resolve("drive_torque")]
            self.add_metadata(UNITS_METADATA, units)
            self._write_scene()
            self.add_metadata(PARAMETERS_METADATA, _node_parameters(node))
            for spec in wanted:
                name, _, type_name = spec.partition(":")
                base = name.lstrip("/")
                if base in DIRECT_TOPICS or "/" + base in DIRECT_TOPICS:
                    self._direct[base] = self.resolve(name)
                    self._types[self._direct[base]] = _DIRECT_TYPES.get(base, FLOAT64)
                    continue
                type_name = type_name or TOPIC_TYPES.get(name) or TOPIC_TYPES.get(base, "")
                if not type_name:
                    raise ValueError(f"topic {name!r}: unknown type; give it as '{name}:pkg/msg/Type'")
                self.add(name, type_name)
        except BaseException:
            self.close()
            raise
        self._param_callback = self._on_parameters_set
        node.add_post_set_parameters_callback(self._param_callback)
        self._joint_states = JointStateEncoder()
        self._floats = [(self._direct.get(name), FLOAT64) for name, _ in FLOAT_OUTPUTS + SLIP_FLOAT_OUTPUTS]
        node.get_logger().info(
            f"recording {len(self._types)} topics to {self.path} (log time = "
            f"{'simulated' if self._uses_sim_time() else 'node clock'} time)"
        )

    def _uses_sim_time(self) -> bool:
        try:
            return bool(self.node.get_parameter("use_sim_time").value)
        except Exception:  # noqa: BLE001
            return False

    def _publishes_clock(self) -> bool:
        settings = getattr(self.node, "settings", None)
        return bool(getattr(settings, "publish_clock", False))

    def _write_scene(self) -> None:
        settings = getattr(self.node, "settings", None)
        scene = getattr(settings, "scene", None)
        if scene is None:
            return
        drive_source = getattr(settings, "drive_source", "topic")
        drive = None
        if drive_source == "topic":
            drive = {"type": RECORDED_DRIVE, "bag": "", "topic": self.resolve(APPLIED_TOPIC),
                     "interpolation": "previous"}
        mapping = scene_mapping(scene, model=getattr(settings.model, "name", None),
                                method=getattr(settings, "method", None),
                                dt=getattr(settings, "dt", None), drive=drive)
        self.add_metadata(SCENE_METADATA, _scene_record(
            mapping, source="node", drive_source=drive_source,
            extra={"node": self.node.get_fully_qualified_name(),
                   "model_choice": getattr(settings, "model_reason", ""),
                   "tick_ns": getattr(settings, "tick_ns", "")},
        ))

    def _on_parameters_set(self, parameters) -> None:
        changed = {p.name: _fmt(p.value) for p in parameters}
        changed["time_ns"] = str(self.now_ns())
        self.add_metadata(PARAMETERS_METADATA, changed)
        if getattr(getattr(self.node, "settings", None), "scene", None) is not None and (
            set(changed) & {"scene", "model", "method", "step_rate_hz", "substeps"}
        ):
            self._write_scene()

    def record_input(self, value: float, now_ns: int) -> None:
        """One ``drive_torque`` message as received [N m], at node time ``now_ns``."""
        topic = self._direct.get("drive_torque")
        if topic is not None:
            self.write(topic, FLOAT64, encode_float64((value,))[0], now_ns)

    def record_tick(self, now_ns: int, joints, floats, applied: float, joint_cdr: bytes | None = None,
                    float_cdr=None, tf_cdr: bytes | None = None) -> None:
        """One tick: ``joints`` (position, velocity, effort of the 4 wheels), the Float64 outputs
        in the order of :data:`FLOAT_OUTPUTS` (then :data:`SLIP_FLOAT_OUTPUTS` with the slipping
        model), and the applied drive torque [N m]. ``joint_cdr`` and ``float_cdr`` (the CDR of
        the joint states and of ``(*floats, applied)``) when the caller has encoded them already;
        ``tf_cdr``: the wheels' ``/tf`` (:class:`~belt_drive_ros.io.recording.TfEncoder`), recorded when given."""
        if self.error is not None or self.closed:
            return
        direct = self._direct
        if not self._time_known:  # the run's first tick: what was held is written at its time
            self.run_started(now_ns)
        topic = direct.get("joint_states")
        if topic is not None:
            self.write(topic, JOINT_STATE, joint_cdr or self._joint_states.encode(now_ns, joints), now_ns)
        topic = direct.get("tf")
        if topic is not None and tf_cdr is not None:
            self.write(topic, TF_MESSAGE, tf_cdr, now_ns)
        payloads = float_cdr if float_cdr is not None else encode_float64((*floats, applied))
        for (topic, type_name), data in zip(self._floats, payloads[:-1]):
            if topic is not None:
                self.write(topic, type_name, data, now_ns)
        topic = direct.get(APPLIED_TOPIC)
        if topic is not None:
            self.write(topic, FLOAT64, payloads[-1], now_ns)

    def close(self) -> None:
        callback = getattr(self, "_param_callback", None)
        if callback is not None:
            try:
                self.node.remove_post_set_parameters_callback(callback)
            except Exception:  # noqa: BLE001
                pass
            self._param_callback = None
        super().close()
