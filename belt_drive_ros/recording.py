"""Record runs to MCAP: live from a ROS 2 node, or offline from a :class:`SimResult`.

Both paths write the same rosbag2-compatible layout through
:class:`msg_tools.Ros2McapWriter` (profile ``ros2``, ``ros2msg`` schemas,
``cdr`` messages, ``offered_qos_profiles`` on every channel, a ``rosbag2``
metadata record, zstd chunks, a summary section), the same topics and the
same message layout as :class:`belt_drive_ros.node.BeltDriveNode`:

=========================  ===========================  ======================
topic                      type                         content [unit]
=========================  ===========================  ======================
``/drive_torque``          ``std_msgs/msg/Float64``     torque on wheel M [N m]
``/joint_states``          ``sensor_msgs/msg/JointState`` wheels ``wheel_M, wheel_1,
                                                        wheel_2, wheel_3``:
                                                        position [rad], velocity
                                                        [rad/s], effort = external
                                                        torque [N m] (drive, 0, 0,
                                                        -load)
``/shaft_speed``           ``std_msgs/msg/Float64``     omega_M [rad/s]
``/load_torque``           ``std_msgs/msg/Float64``     load torque at wheel 3 [N m]
``/belt_torque``           ``std_msgs/msg/Float64``     belt torque on wheel 3 [N m]
``/relative_deflection``   ``std_msgs/msg/Float64``     ``i phi_M - phi_3`` [rad]
``/diagnostics``           ``diagnostic_msgs/msg/DiagnosticArray`` (live only)
``/clock``                 ``rosgraph_msgs/msg/Clock``  (live, when the node uses
                                                        or publishes sim time)
=========================  ===========================  ======================

Every file is self-describing: metadata records

* ``scene``: ``yaml`` (the scene as :meth:`Scene.to_yaml` writes it, with the
  model, integrator and step actually used; a drive recorded in a bag is
  stored as a reference ``{type: recorded, bag, topic, samples, sha256}``
  instead of its samples), ``name``, ``model``, ``method``, ``dt``,
  ``drive_source`` and ``source`` (``offline`` or ``node``);
* ``parameters``: the node's ROS parameters (live) or the model parameters
  (offline), values as text; a live recording appends one
  ``parameters`` record per accepted runtime change, with ``time_ns``;
* ``units``: SI unit of every topic (:mod:`msg_tools.units`).

:func:`scene_from_bag` turns these back into a :class:`Scene`, so a recording
can be re-simulated offline.

Time stamps
-----------
*Live* (:class:`NodeRecorder`, ``belt-drive record``): ``log_time`` is the
receive time on the recording node's clock [ns]: ROS time, i.e. simulated
time when the node has ``use_sim_time`` (then ``0`` until the first
``/clock``). ``publish_time`` equals ``log_time``: the Jazzy wheels'
EventsExecutor cannot deliver the message info that carries the send time.
*Offline* (:func:`write_result_mcap`): both are the simulated time of the
sample [ns since scene time 0]; ``joint_states`` stamps carry the same time.

Crash safety
------------
Chunks are closed every ``flush_interval_s`` of log time and, live, by a
wall-clock (steady) timer as well, so after SIGKILL the file reads up to its
last complete chunk (:func:`msg_tools.read_topic` tolerates the missing
summary). SIGINT/SIGTERM finalize (``belt-drive record`` and the node's
shutdown call :meth:`NodeRecorder.close`). An existing file is never
replaced unless ``force``. A write error (disk full, permission) stops the
recording, not the node: it is logged once, :attr:`NodeRecorder.failed`
turns True and :attr:`NodeRecorder.status` says why (for ``/diagnostics``).

This module imports rclpy only inside :class:`TopicRecorder` /
:class:`NodeRecorder`; :func:`write_result_mcap` and :func:`scene_from_bag`
work without ROS.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from msg_tools import Ros2McapWriter
from msg_tools.errors import MsgToolsError, OverwriteError, RecoveredBagWarning, WriteError
from msg_tools.units import UNITS_METADATA

from .errors import BeltDriveError

__all__ = [
    "BagError",
    "BagExistsError",
    "BagReadError",
    "BagWriteError",
    "JOINT_NAMES",
    "NodeRecorder",
    "TOPIC_TYPES",
    "TOPIC_UNITS",
    "TopicRecorder",
    "bag_error",
    "encode_float64",
    "encode_joint_states",
    "scene_from_bag",
    "scene_mapping",
    "write_result_mcap",
]

FLOAT64 = "std_msgs/msg/Float64"
JOINT_STATE = "sensor_msgs/msg/JointState"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
CLOCK = "rosgraph_msgs/msg/Clock"

#: Joint names of ``joint_states`` (as :data:`belt_drive_ros.node.JOINT_NAMES`).
JOINT_NAMES: Tuple[str, ...] = ("wheel_M", "wheel_1", "wheel_2", "wheel_3")
#: Float64 outputs in the node's publishing order, with the SimResult signal of each.
FLOAT_OUTPUTS: Tuple[Tuple[str, str], ...] = (
    ("shaft_speed", "omega_M"),
    ("load_torque", "load_torque"),
    ("belt_torque", "belt_torque"),
    ("relative_deflection", "relative_deflection"),
)
#: Topics of the belt-drive node (names relative to its namespace) and their types.
TOPIC_TYPES: Dict[str, str] = {
    "drive_torque": FLOAT64,
    "joint_states": JOINT_STATE,
    "shaft_speed": FLOAT64,
    "load_torque": FLOAT64,
    "belt_torque": FLOAT64,
    "relative_deflection": FLOAT64,
    "/diagnostics": DIAGNOSTIC_ARRAY,
    "/clock": CLOCK,
}
#: SI unit of each topic (field), written as the ``units`` metadata record.
TOPIC_UNITS: Dict[str, str] = {
    "drive_torque": "N*m",
    "shaft_speed": "rad/s",
    "load_torque": "N*m",
    "belt_torque": "N*m",
    "relative_deflection": "rad",
    "joint_states/position": "rad",
    "joint_states/velocity": "rad/s",
    "joint_states/effort": "N*m",
}
#: Metadata record names.
SCENE_METADATA = "scene"
PARAMETERS_METADATA = "parameters"
#: ``type`` of the drive mapping that refers to a torque recorded in a bag.
RECORDED_DRIVE = "recorded"


# ----------------------------------------------------------------- errors
class BagError(BeltDriveError):
    """A bag cannot be read, written or used; the message is one line naming the file."""


class BagReadError(BagError, ValueError):
    """A bag is missing, not MCAP, cut off before any data, or lacks what is needed."""


class BagWriteError(BagError, OSError):
    """Writing a bag failed (disk full, permission, ...); ``errno`` as the cause's."""

    def __init__(self, message: str, errno: Optional[int] = None):
        BagError.__init__(self, message)
        self.errno = errno
        self.strerror = message

    def __str__(self) -> str:
        return self.strerror


class BagExistsError(BagError, FileExistsError):
    """The output bag exists and ``force`` was not given."""

    def __str__(self) -> str:
        return str(self.args[0])


def bag_error(exc: BaseException) -> BagError:
    """The :class:`BagError` for a :mod:`msg_tools` (or OS) error, same one-line message."""
    if isinstance(exc, BagError):
        return exc
    message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if isinstance(exc, (OverwriteError, FileExistsError)):
        return BagExistsError(message)
    if isinstance(exc, (WriteError, PermissionError)) or (
        isinstance(exc, OSError) and not isinstance(exc, FileNotFoundError)
    ):
        return BagWriteError(message, getattr(exc, "errno", None))
    return BagReadError(message)


def _absolute(topic: str, namespace: str = "/") -> str:
    """``topic`` resolved against ``namespace`` (``~`` is not supported here)."""
    if topic.startswith("/"):
        return topic
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{topic}"


def units_metadata(namespace: str = "/") -> Dict[str, str]:
    """The ``units`` record for the node's topics under ``namespace``."""
    return {_absolute(k, namespace): v for k, v in TOPIC_UNITS.items()}


# ------------------------------------------------------------ scene metadata
def _fmt(value: Any) -> str:
    """Text of a metadata value: floats with ``repr`` (round-trips exactly)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def scene_mapping(scene, *, model: Optional[str] = None, method: Optional[str] = None,
                  dt: Optional[float] = None, drive: Optional[Mapping[str, Any]] = None) -> Dict[str, Any]:
    """Mapping of ``scene`` for the ``scene`` metadata record (YAML-ready).

    ``model``, ``method`` and ``dt`` replace the scene's (the ones a run
    actually used, e.g. the outcome of ``model: auto``). A drive recorded in a
    bag (:class:`belt_drive_ros.replay.RecordedTorque`) is written as its
    reference mapping, not as its samples; ``drive`` overrides it.
    """
    reference = drive
    if reference is None and hasattr(scene.drive, "reference"):
        reference = scene.drive.reference()
    if reference is not None:
        from .sources import Constant

        scene = dataclasses.replace(scene, drive=Constant(0.0))
    data = scene.to_dict()
    if reference is not None:
        data["drive"] = dict(reference)
    if model is not None:
        data["model"] = model
    if method is not None:
        data["method"] = method
    if dt is not None:
        data["dt"] = float(dt)
    return data


def _scene_record(mapping: Mapping[str, Any], *, source: str, drive_source: str,
                  extra: Optional[Mapping[str, Any]] = None) -> Dict[str, str]:
    import yaml

    record = {
        "format": "belt_drive_ros scene 1",
        "source": source,
        "name": str(mapping.get("name", "")),
        "model": str(mapping.get("model", "")),
        "method": str(mapping.get("method", "")),
        "dt": _fmt(float(mapping.get("dt", math.nan))),
        "duration": _fmt(float(mapping.get("duration", math.nan))),
        "drive_source": drive_source,
        "yaml": yaml.safe_dump(dict(mapping), sort_keys=False),
    }
    for key, value in (extra or {}).items():
        record[key] = _fmt(value)
    return record


def _read_metadata(path) -> Tuple[Dict[str, str], str]:
    """``scene`` metadata of a bag and its path text; errors as :class:`BagReadError`."""
    import warnings

    from msg_tools import summary

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecoveredBagWarning)
        try:
            info = summary(path)
        except MsgToolsError as exc:
            raise bag_error(exc) from None
    return info.metadata_dict(SCENE_METADATA), info.path


def scene_from_bag(path, *, torque_bag=None):
    """Rebuild the :class:`~belt_drive_ros.scene.Scene` stored in a recording.

    Parameters
    ----------
    path : path
        An MCAP file written by :func:`write_result_mcap`, a
        :class:`NodeRecorder` or ``belt-drive make-bags``.
    torque_bag : path, optional
        Where the recorded drive torque is, when the scene refers to one
        (``drive: {type: recorded, ...}``). By default the bag named in the
        reference, looked up next to ``path``; a node recording refers to its
        own ``drive_torque`` topic (``bag: ""``).

    Returns
    -------
    Scene
        With the model, integrator and step the run used; a recorded drive is
        the zero-order hold of the referenced bag's ``drive_torque``
        (:func:`belt_drive_ros.replay.scene_with_torque_bag`), over the stored
        duration.

    Raises
    ------
    BagReadError
        If the file has no ``scene`` record, the record is invalid, or the
        referenced torque bag is missing or has changed (sha256).
    """
    import yaml

    from .scene import Scene

    record, name = _read_metadata(path)
    if "yaml" not in record:
        raise BagReadError(f"{name}: no '{SCENE_METADATA}' metadata record; not written by belt_drive_ros")
    try:
        data = yaml.safe_load(record["yaml"])
    except yaml.YAMLError as exc:
        raise BagReadError(f"{name}: scene metadata is not valid YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise BagReadError(f"{name}: scene metadata is not a mapping")
    drive = data.get("drive")
    reference = drive if isinstance(drive, dict) and drive.get("type") == RECORDED_DRIVE else None
    if reference is not None:
        data = dict(data, drive=0.0)
    try:
        scene = Scene.from_mapping(data)
    except (BeltDriveError, ValueError, TypeError) as exc:
        raise BagReadError(f"{name}: stored scene is invalid: {exc}") from None
    if reference is None:
        return scene
    from .replay import scene_with_torque_bag

    source = torque_bag
    if source is None:
        ref = str(reference.get("bag", ""))
        source = path if ref in ("", "self") else os.path.join(os.path.dirname(os.fspath(path)), ref)
        if not os.path.exists(source):
            raise BagReadError(
                f"{name}: the drive torque was recorded in {ref}, which is not next to it "
                "(pass torque_bag=... / --torque-bag)"
            )
        expected = reference.get("sha256")
        if expected and ref not in ("", "self") and _sha256(source) != expected:
            raise BagReadError(
                f"{name}: {source} is not the torque bag this run used (sha256 differs); "
                "regenerate the pair or pass torque_bag=..."
            )
    # a node recording runs as long as it was recorded: its span; an offline run: its duration
    own = torque_bag is None and str(reference.get("bag", "")) in ("", "self")
    return scene_with_torque_bag(
        scene, source, topic=str(reference.get("topic", "/drive_torque")),
        duration=None if own else scene.duration,
    )


def _sha256(path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# ------------------------------------------------------- offline encoding
_F64_HEADER = b"\x00\x01\x00\x00"


def encode_float64(values: np.ndarray) -> List[bytes]:
    """CDR of ``std_msgs/Float64`` for each value, as ``mcap_ros2`` encodes it.

    Header ``00 01 00 00`` (little endian) then the IEEE double; byte-identical
    to :func:`msg_tools.encode` (a test checks), ~50x faster for long runs.
    """
    raw = np.ascontiguousarray(values, dtype="<f8").tobytes()
    return [_F64_HEADER + raw[i : i + 8] for i in range(0, len(raw), 8)]


def encode_joint_states(stamp_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                        effort: np.ndarray, names: Sequence[str] = JOINT_NAMES,
                        frame_id: str = "") -> List[bytes]:
    """CDR of ``sensor_msgs/JointState`` messages, as ``mcap_ros2`` encodes them.

    The layout of a JointState with fixed names and array sizes does not
    change from message to message, so one message is encoded with
    :func:`msg_tools.encode` (zero padding) as a template and the stamps and
    values are written into copies of it. Byte-identical to encoding each
    message with :func:`msg_tools.encode` (a test checks).

    Parameters
    ----------
    stamp_ns : (N,) int
        ``header.stamp`` [ns].
    position, velocity, effort : (N, J) float
        One column per joint of ``names``.
    """
    from msg_tools import encode

    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    n, joints = len(stamp_ns), len(names)
    cols = [np.asarray(a, dtype=float).reshape(n, joints) for a in (position, velocity, effort)]
    # sentinels that cannot collide with the rest of the template
    sentinels = [[1e300 + 1e290 * (joints * k + j + 1) for j in range(joints)] for k in range(3)]
    template = encode(JOINT_STATE, {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": frame_id},
        "name": list(names),
        "position": sentinels[0],
        "velocity": sentinels[1],
        "effort": sentinels[2],
    })
    buf = np.frombuffer(template, dtype=np.uint8)
    offsets = []
    for group in sentinels:
        starts = []
        for value in group:
            pattern = np.frombuffer(np.float64(value).astype("<f8").tobytes(), dtype=np.uint8)
            hits = [i for i in range(len(buf) - 7) if np.array_equal(buf[i : i + 8], pattern)]
            if len(hits) != 1:
                raise RuntimeError("JointState template: sentinel not found exactly once")
            starts.append(hits[0])
        if any(b - a != 8 for a, b in zip(starts, starts[1:])):
            raise RuntimeError("JointState template: array not contiguous")
        offsets.append(starts[0])
    out = np.tile(buf, (n, 1))
    sec, nanosec = np.divmod(stamp_ns, 1_000_000_000)
    out[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
    out[:, 8:12] = nanosec.astype("<u4").view(np.uint8).reshape(n, 4)
    for start, values in zip(offsets, cols):
        out[:, start : start + 8 * joints] = np.ascontiguousarray(values, dtype="<f8").view(np.uint8).reshape(n, 8 * joints)
    return [row.tobytes() for row in out]


def _output_stride(result, output_rate: Optional[float]) -> int:
    """Samples of ``result`` per output message (1 if the rate does not divide the grid)."""
    rate = float(output_rate or result.scene.output_rate)
    if not rate > 0 or not math.isfinite(rate):
        raise ValueError(f"output_rate must be a finite number > 0 Hz, got {output_rate!r}")
    stride = int(round(1.0 / (rate * result.dt)))
    if stride < 1 or abs(stride * result.dt * rate - 1.0) > 1e-9:
        return 1
    return stride


def write_result_mcap(result, path, force: bool = False, *, namespace: str = "/",
                      output_rate: Optional[float] = None, topics: Optional[Iterable[str]] = None,
                      compression: str = "zstd",
                      extra_metadata: Optional[Mapping[str, Mapping[str, str]]] = None) -> Dict[str, int]:
    """Write an offline run as a ROS 2 MCAP with the node's topics and layout.

    Parameters
    ----------
    result : SimResult
        From :func:`belt_drive_ros.simulate.simulate`.
    path : path or binary stream
        Output file (refused if it exists, unless ``force``).
    force : bool
        Replace an existing file.
    namespace : str
        Namespace of the topics (default ``/``: ``/shaft_speed`` ...).
    output_rate : float, optional
        Messages per second [Hz]; default the scene's ``output_rate`` (the
        node's publish rate). Samples are taken every ``round(1/(rate*dt))``
        integrator steps; all steps if that does not divide evenly.
    topics : iterable of str, optional
        Subset of ``drive_torque``, ``joint_states``, ``shaft_speed``,
        ``load_torque``, ``belt_torque``, ``relative_deflection`` (default all).
    compression : {"zstd", "lz4", "none"}
    extra_metadata : mapping of record name to str dict, optional
        Further metadata records.

    Returns
    -------
    dict
        Messages written per topic.

    Notes
    -----
    Times are simulated time [ns from scene time 0] for ``log_time``,
    ``publish_time`` and the ``joint_states`` stamps. Messages are encoded as
    ``mcap_ros2`` encodes them (zero padding), and the file holds no wall-clock
    time, so the same run gives a byte-identical file (golden files).
    At each time the order is the node's: ``drive_torque``, ``joint_states``,
    then the Float64 outputs.

    Raises
    ------
    BagExistsError
        If ``path`` exists and ``force`` is False.
    BagWriteError
        If the file cannot be written.
    """
    offline_topics = ("drive_torque", "joint_states") + tuple(name for name, _ in FLOAT_OUTPUTS)
    wanted = offline_topics if topics is None else tuple(t.strip("/") for t in topics)
    unknown = sorted(set(wanted) - set(offline_topics))
    if unknown:
        raise ValueError(f"topics: unknown {', '.join(unknown)}; offline runs have {', '.join(offline_topics)}")
    stride = _output_stride(result, output_rate)
    index = np.arange(0, len(result.time), stride)
    t_ns = np.round(np.asarray(result.time, dtype=float)[index] * 1e9).astype(np.int64)
    if t_ns.size and t_ns[0] < 0:
        raise ValueError(f"result starts at negative time {result.time[0]} s; MCAP times must be >= 0")
    o = {name: np.asarray(values)[index] for name, values in result.outputs.items()}
    zeros = np.zeros(index.size)
    position = np.column_stack([o["phi_M"], o["phi_1"], o["phi_2"], o["phi_3"]])
    velocity = np.column_stack([o["omega_M"], o["omega_1"], o["omega_2"], o["omega_3"]])
    effort = np.column_stack([o["drive_torque"], zeros, zeros, -o["load_torque"]])
    payloads: List[Tuple[str, str, List[bytes]]] = []
    if "drive_torque" in wanted:
        payloads.append((_absolute("drive_torque", namespace), FLOAT64, encode_float64(o["drive_torque"])))
    if "joint_states" in wanted:
        payloads.append((_absolute("joint_states", namespace), JOINT_STATE,
                         encode_joint_states(t_ns, position, velocity, effort)))
    for topic, signal in FLOAT_OUTPUTS:
        if topic in wanted:
            payloads.append((_absolute(topic, namespace), FLOAT64, encode_float64(o[signal])))

    scene = result.scene
    mapping = scene_mapping(scene, model=result.model, method=result.method, dt=result.dt)
    drive_source = "torque_bag" if isinstance(mapping.get("drive"), dict) and mapping["drive"].get("type") == RECORDED_DRIVE else "scene"
    scene_record = _scene_record(
        mapping, source="offline", drive_source=drive_source,
        extra={
            "model_choice": result.choice.reason if result.choice is not None else f"{result.model}: set explicitly",
            "output_rate": float(output_rate or scene.output_rate) if stride > 1 else 1.0 / result.dt,
            "samples": int(index.size),
        },
    )
    parameters = {name: _fmt(float(value)) for name, value in scene.params.to_dict().items()}
    parameters.update(model=result.model, method=result.method, dt=_fmt(float(result.dt)))
    counts: Dict[str, int] = {}
    try:
        with Ros2McapWriter(path, force=force, compression=compression) as writer:
            writer.add_metadata(SCENE_METADATA, scene_record)
            writer.add_metadata(PARAMETERS_METADATA, parameters)
            written = {topic for topic, _, _ in payloads}
            writer.add_metadata(UNITS_METADATA, {
                key: unit for key, unit in units_metadata(namespace).items()
                if key in written or key.rsplit("/", 1)[0] in written
            })
            for extra_name, values in (extra_metadata or {}).items():
                writer.add_metadata(extra_name, dict(values))
            for topic, type_name, _ in payloads:
                writer.add_topic(topic, type_name, "reliable")
            write = writer.write_raw
            times = t_ns.tolist()
            for k, t in enumerate(times):
                for topic, type_name, data in payloads:
                    write(topic, type_name, data[k], t)
            counts = writer.topic_counts()
    except MsgToolsError as exc:
        raise bag_error(exc) from None
    except OSError as exc:
        raise bag_error(exc) from None
    return counts


# ------------------------------------------------------------ live recording
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

    def __init__(self, node, writer: Ros2McapWriter, *, flush_period: Optional[float] = 0.25, depth: int = 1000):
        from rclpy.clock import Clock, ClockType

        self.node = node
        self.writer = writer
        self.path = writer.path or "<stream>"
        self.depth = int(depth)
        self.error: Optional[BaseException] = None
        self.closed = False
        self._clock = node.get_clock()
        self._subs: Dict[str, Any] = {}
        self._types: Dict[str, str] = {}
        self._declared: set = set()
        self._unflushed = 0
        self._timer = None
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
        if offered and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered):
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
        now = self._clock.now
        write = self.writer.write_raw

        def on_message(data: bytes) -> None:
            if self.error is not None or self.closed:
                return
            try:
                if topic not in self._declared:
                    self._declare(topic, type_name)
                write(topic, type_name, data, now().nanoseconds)
                self._unflushed += 1
            except (MsgToolsError, OSError) as exc:
                self._fail(exc)

        return on_message

    def _declare(self, topic: str, type_name: str) -> None:
        from msg_tools.qos import QosProfile

        offered = [QosProfile.from_rclpy(q) for q in self.offered_qos(topic)]
        self.writer.add_topic(topic, type_name, offered or "reliable")
        self._declared.add(topic)

    def write(self, topic: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        """Write one serialized message directly (no subscription), with the same error handling."""
        if self.error is not None or self.closed:
            return
        try:
            if topic not in self._declared:
                self._declare(topic, type_name)
            self.writer.write_raw(topic, type_name, data, log_time_ns)
            self._unflushed += 1
        except (MsgToolsError, OSError) as exc:
            self._fail(exc)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        if self.error is not None or self.closed:
            return
        try:
            self.writer.add_metadata(name, dict(data))
        except (MsgToolsError, OSError) as exc:
            self._fail(exc)

    # --------------------------------------------------------- flush/close
    def _on_flush_timer(self) -> None:
        if self._unflushed and self.error is None and not self.closed:
            try:
                self.writer.flush()
                self._unflushed = 0
            except (MsgToolsError, OSError) as exc:
                self._fail(exc)

    def _fail(self, exc: BaseException) -> None:
        if self.error is None:
            self.error = bag_error(exc)
            self.node.get_logger().error(
                f"recording stopped: {self.error}; the file keeps what was written up to its last "
                "complete chunk; the node keeps running"
            )

    def close(self) -> None:
        """Stop recording and finalize the file (summary, rosbag2 metadata). Idempotent."""
        if self.closed:
            return
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


class NodeRecorder(TopicRecorder):
    """Record a belt-drive node's input and outputs into an MCAP file.

    Parameters
    ----------
    node : rclpy.node.Node
        The node (usually :class:`~belt_drive_ros.node.BeltDriveNode`). Its
        topics are resolved against its namespace; ``log_time`` comes from
        its clock (simulated time with ``use_sim_time``).
    path : path or binary stream
        Output file; refused if it exists unless ``force``.
    topics : iterable of str, optional
        Default: ``drive_torque``, ``joint_states``, ``shaft_speed``,
        ``load_torque``, ``belt_torque``, ``relative_deflection``,
        ``/diagnostics``, and ``/clock`` when the node uses or publishes sim
        time. Names outside :data:`TOPIC_TYPES` are given as ``name:pkg/msg/Type``.
    force : bool
        Replace an existing file.
    capture : {"subscription", "direct"}
        ``subscription`` (default): every topic through a raw subscription,
        the bytes as received. ``direct``: the node's state outputs are
        serialized at publish time through :meth:`record` (log time = tick
        time exactly, no DDS round trip); the other topics are subscribed.
    chunk_size, compression, flush_interval_s
        See :class:`msg_tools.Ros2McapWriter`; the wall-clock flush timer
        uses ``flush_interval_s`` too.

    Raises
    ------
    BagExistsError, BagWriteError
        If the file exists (without ``force``) or cannot be created.

    Examples
    --------
    In :class:`BeltDriveNode.__init__`, once the publishers exist::

        if s.record_path:
            try:
                self._recorder = NodeRecorder(self, s.record_path)
            except BagError as exc:  # exists (never overwritten) or cannot be created
                self.get_logger().error(f"record_path: {exc}; not recording")

    and ``destroy_node`` calls ``self._recorder.close()``.
    """

    def __init__(self, node, path, topics: Optional[Iterable[str]] = None, force: bool = False, *,
                 capture: str = "subscription", chunk_size: int = 128 * 1024, compression: str = "zstd",
                 flush_interval_s: float = 0.25):
        if capture not in ("subscription", "direct"):
            raise ValueError(f"capture must be 'subscription' or 'direct', got {capture!r}")
        try:
            writer = Ros2McapWriter(path, force=force, chunk_size=chunk_size, compression=compression,
                                    flush_interval_s=flush_interval_s)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None
        super().__init__(node, writer, flush_period=flush_interval_s)
        self.capture = capture
        uses_clock = self._uses_sim_time() or self._publishes_clock()
        if topics is None:
            wanted = [t for t in TOPIC_TYPES if t != "/clock" or uses_clock]
        else:
            wanted = list(topics)
        self._direct: Dict[str, str] = {}
        namespace = node.get_namespace()
        try:
            self.add_metadata(UNITS_METADATA, units_metadata(namespace))
            self._write_scene()
            self.add_metadata(PARAMETERS_METADATA, _node_parameters(node))
            for spec in wanted:
                name, _, type_name = spec.partition(":")
                type_name = type_name or TOPIC_TYPES.get(name) or TOPIC_TYPES.get(name.lstrip("/"), "")
                if not type_name:
                    raise ValueError(f"topic {name!r}: unknown type; give it as '{name}:pkg/msg/Type'")
                base = name.lstrip("/")
                if capture == "direct" and (base == "joint_states" or base in dict(FLOAT_OUTPUTS)):
                    self._direct[base] = self.resolve(name)
                    self._types[self._direct[base]] = type_name
                    continue
                self.add(name, type_name)
        except BaseException:
            self.close()
            raise
        self._param_callback = self._on_parameters_set
        node.add_post_set_parameters_callback(self._param_callback)
        if self._direct:
            from rclpy.serialization import serialize_message

            self._serialize = serialize_message
        node.get_logger().info(
            f"recording {len(self._types)} topics to {self.path} ({capture}; log time = "
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
            drive = {"type": RECORDED_DRIVE, "bag": "", "topic": self.resolve("drive_torque"),
                     "interpolation": "previous"}
        mapping = scene_mapping(scene, model=getattr(settings.model, "name", None),
                                method=getattr(settings, "method", None),
                                dt=getattr(settings, "dt", None), drive=drive)
        self.add_metadata(SCENE_METADATA, _scene_record(
            mapping, source="node", drive_source=drive_source,
            extra={"node": self.node.get_fully_qualified_name(),
                   "model_choice": getattr(settings, "model_reason", "")},
        ))

    def _on_parameters_set(self, parameters) -> None:
        changed = {p.name: _fmt(p.value) for p in parameters}
        changed["time_ns"] = str(self._clock.now().nanoseconds)
        self.add_metadata(PARAMETERS_METADATA, changed)
        if getattr(getattr(self.node, "settings", None), "scene", None) is not None and (
            set(changed) & {"scene", "model", "method", "step_rate_hz", "substeps"}
        ):
            self._write_scene()

    def record(self, now_ns: int, joint_state, floats: Mapping[str, Any]) -> None:
        """Hook the node calls after publishing a tick's outputs.

        With ``capture="direct"`` it writes them with ``log_time = now_ns``;
        with the default ``capture="subscription"`` the subscriptions already
        receive them and this returns at once.
        """
        if not self._direct or self.error is not None or self.closed:
            return
        serialize = self._serialize
        topic = self._direct.get("joint_states")
        if topic is not None:
            self.write(topic, JOINT_STATE, serialize(joint_state), now_ns)
        for name, msg in floats.items():
            topic = self._direct.get(name)
            if topic is not None:
                self.write(topic, FLOAT64, serialize(msg), now_ns)

    def close(self) -> None:
        callback = getattr(self, "_param_callback", None)
        if callback is not None:
            try:
                self.node.remove_post_set_parameters_callback(callback)
            except Exception:  # noqa: BLE001
                pass
            self._param_callback = None
        super().close()
