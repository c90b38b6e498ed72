"""Record runs to MCAP: live from a ROS 2 node, or offline from a :class:`SimResult`.

Both paths write the same rosbag2-compatible layout through
:class:`msg_tools.Ros2McapWriter` (profile ``ros2``, ``ros2msg`` schemas,
``cdr`` messages, ``offered_qos_profiles`` on every channel, a ``rosbag2``
metadata record, zstd chunks, a summary section), the same topics and the
same message layout as :class:`belt_drive_ros.ros.node.BeltDriveNode`:

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

:func:`belt_drive_ros.io.torque_bag.scene_from_bag` turns these back into a :class:`Scene`, so a recording
can be re-simulated offline.

Time stamps
-----------
*Live* (:class:`NodeRecorder`, ``belt-drive record``): ``log_time`` is the
receive time on the recording node's clock [ns]: ROS time, i.e. simulated
time when the node has ``use_sim_time`` (then ``0`` until the first
``/clock``). ``publish_time`` equals ``log_time``: the Jazzy wheels'
EventsExecutor cannot deliver the message info that carries the send time.
*Offline* (:func:`write_result_mcap`): both are the start time (default the
wall time of the run, as rosbag2 stamps a recording; ``start_time_ns`` sets
it) plus the simulated time of the sample; ``joint_states`` stamps carry the
same time.

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

This module never imports rclpy: the live recorders that use it are in
:mod:`belt_drive_ros.ros.recorder`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import struct
import time
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from msg_tools import Ros2McapWriter
from msg_tools.errors import MsgToolsError, OverwriteError, WriteError
from msg_tools.units import UNITS_METADATA

from ..core.errors import BeltDriveError
from ..core.scene import SLIP_MODELS

__all__ = [
    "BagError",
    "BagExistsError",
    "BagReadError",
    "BagWriteError",
    "JOINT_NAMES",
    "JointStateEncoder",
    "TF_MESSAGE",
    "TF_TOPIC",
    "TOPIC_TYPES",
    "TfEncoder",
    "TOPIC_UNITS",
    "bag_error",
    "encode_float64",
    "encode_joint_states",
    "encode_robot_description",
    "scene_mapping",
    "write_result_mcap",
]

FLOAT64 = "std_msgs/msg/Float64"
JOINT_STATE = "sensor_msgs/msg/JointState"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
CLOCK = "rosgraph_msgs/msg/Clock"
STRING = "std_msgs/msg/String"
#: the drive's URDF (std_msgs/String), latched: one message at the start of a recording
ROBOT_DESCRIPTION = "robot_description"
#: its offered QoS in recordings (as robot_state_publisher offers it: reliable, transient local, keep last 1)
ROBOT_DESCRIPTION_QOS = "transient_local"

#: the wheels' transforms (tf2_msgs/TFMessage, one TransformStamped per wheel joint): what 3D panels move the URDF with
TF_TOPIC = "/tf"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: its offered QoS (as tf2_ros's TransformBroadcaster: reliable, volatile, keep last 100)
TF_QOS = "reliable"

#: the channel of the drive torque a node applied (after rejection, limit and timeout), one
#: message per tick at the tick time: what a re-simulation replays (zero-order hold)
APPLIED_TOPIC = "drive_torque_applied"

#: Joint names of ``joint_states`` (as :data:`belt_drive_ros.ros.node.JOINT_NAMES`).
JOINT_NAMES: Tuple[str, ...] = ("wheel_M", "wheel_1", "wheel_2", "wheel_3")
#: Float64 outputs in the node's publishing order, with the SimResult signal of each.
FLOAT_OUTPUTS: Tuple[Tuple[str, str], ...] = (
    ("shaft_speed", "omega_M"),
    ("load_torque", "load_torque"),
    ("belt_torque", "belt_torque"),
    ("relative_deflection", "relative_deflection"),
)
#: Float64 outputs of a slipping-model run (written after FLOAT_OUTPUTS when the run has them).
SLIP_FLOAT_OUTPUTS: Tuple[Tuple[str, str], ...] = (
    ("span_force_tight", "span_force_tight"),
    ("span_force_slack", "span_force_slack"),
    ("friction_use", "friction_use"),
    ("slip", "slip"),
    ("slip_speed", "slip_speed"),
    ("elastic_deflection", "elastic_deflection"),
    ("slip_angle", "slip_angle"),
)
#: Topics of the belt-drive node (names relative to its namespace) and their types.
TOPIC_TYPES: Dict[str, str] = {
    "drive_torque": FLOAT64,
    "joint_states": JOINT_STATE,
    "shaft_speed": FLOAT64,
    "load_torque": FLOAT64,
    "belt_torque": FLOAT64,
    "relative_deflection": FLOAT64,
    **{name: FLOAT64 for name, _ in SLIP_FLOAT_OUTPUTS},  # slipping model only
    ROBOT_DESCRIPTION: STRING,
    TF_TOPIC: TF_MESSAGE,
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
    "span_force_tight": "N",
    "span_force_slack": "N",
    "friction_use": "1",
    "slip": "1",
    "slip_speed": "m/s",
    "elastic_deflection": "rad",
    "slip_angle": "rad",
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
    bag (:class:`belt_drive_ros.io.torque_bag.RecordedTorque`) is written as its
    reference mapping, not as its samples; ``drive`` overrides it.
    """
    reference = drive
    if reference is None and hasattr(scene.drive, "reference"):
        reference = scene.drive.reference()
    if reference is not None:
        from ..core.sources import Constant

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


def _sha256(path) -> str:
    """sha256 of a file, or of a bag folder's MCAP files in split order, concatenated."""
    from msg_tools import bag_files

    digest = hashlib.sha256()
    for file in bag_files(path):
        with open(file, "rb") as f:
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


class JointStateEncoder:
    """CDR of the node's ``sensor_msgs/JointState`` for one tick, without rclpy.

    The bytes of :func:`encode_joint_states` (zero padding, as ``mcap_ros2``
    encodes), from a template built once: per tick only the stamp and the
    twelve doubles are packed in (~2.5 us). The node publishes these bytes
    as its ``joint_states`` (rclpy's ``Publisher.publish`` takes a serialized
    message) and records the same bytes: converting a ``JointState`` object
    to its C struct and serializing it cost the node's tick ~30 us. Fast CDR
    leaves its padding bytes uninitialised where this writes zeros; every
    CDR reader skips them (a test deserializes these bytes with rclpy).
    """

    def __init__(self, joints: int = 4):
        marks = np.arange(1, 3 * joints + 1, dtype=float) * 1e300 / 7.0  # distinct, cannot occur elsewhere
        groups = marks.reshape(3, joints)
        template = encode_joint_states(np.zeros(1, dtype=np.int64), *(g[None, :] for g in groups))[0]
        self._array = struct.Struct(f"<{joints}d")
        self._offsets = []
        for group in groups:  # position, velocity, effort: each a contiguous CDR sequence
            packed = self._array.pack(*group)
            offset = template.find(packed)
            if offset < 0 or template.find(packed, offset + 1) >= 0:
                raise RuntimeError("JointState template: an array is not found exactly once")
            self._offsets.append(offset)
        self._template = template
        self._joints = joints
        self._stamp = struct.Struct("<iI")

    def encode(self, stamp_ns: int, values) -> bytes:
        """``values`` = position, velocity, effort of the joints, concatenated."""
        buf = bytearray(self._template)
        self._stamp.pack_into(buf, 4, *divmod(stamp_ns, 1_000_000_000))
        j = self._joints
        for k, offset in enumerate(self._offsets):
            self._array.pack_into(buf, offset, *values[k * j : (k + 1) * j])
        return bytes(buf)



class TfEncoder:
    """CDR of ``tf2_msgs/TFMessage`` for the drive's wheels at their joint angles, without rclpy.

    One ``geometry_msgs/TransformStamped`` per wheel joint, as
    ``robot_state_publisher`` publishes a continuous joint: parent
    ``base_link``, child ``<joint>_link`` (the links of
    :func:`~belt_drive_ros.io.urdf.urdf_from_params`), translation the joint
    origin ``(x, y, 0)`` [m], rotation the joint angle ``q`` [rad] about the
    joint axis ``(0, 0, s)`` (``s = +/-1``): the quaternion
    ``(x, y, z, w) = (0, 0, s sin(q/2), cos(q/2))``. Every transform is
    stamped with the tick's time.

    The bytes come from a template encoded once (:func:`msg_tools.encode`):
    per message only the stamps and the ``z, w`` of each rotation are packed
    in. ``params`` fix the joint origins (a new encoder when the radii change).
    """

    def __init__(self, params, joints: Sequence[str] = JOINT_NAMES):
        import msg_tools

        from .urdf import drive_layout

        wheels = drive_layout(params).wheels
        self.joints = tuple(joints)
        self.signs = np.array([wheels[j][2] for j in self.joints], dtype=float)
        n = len(self.joints)
        sec_marks = [0x5A5A0000 + k for k in range(n)]
        nsec_marks = [0x3C3C0000 + k for k in range(n)]
        rot_marks = np.arange(1, 2 * n + 1, dtype=float).reshape(n, 2) * 1e300 / 7.0  # (z, w) per wheel
        transforms = [{
            "header": {"stamp": {"sec": sec_marks[k], "nanosec": nsec_marks[k]}, "frame_id": "base_link"},
            "child_frame_id": f"{joint}_link",
            "transform": {"translation": {"x": float(wheels[joint][0]), "y": float(wheels[joint][1]), "z": 0.0},
                          "rotation": {"x": 0.0, "y": 0.0, "z": float(rot_marks[k, 0]), "w": float(rot_marks[k, 1])}},
        } for k, joint in enumerate(self.joints)]
        template = msg_tools.encode(TF_MESSAGE, {"transforms": transforms})

        def find(packed: bytes) -> int:
            offset = template.find(packed)
            if offset < 0 or template.find(packed, offset + 1) >= 0:
                raise RuntimeError("TFMessage template: a field is not found exactly once")
            return offset

        self._stamps = [find(struct.pack("<iI", sec_marks[k], nsec_marks[k])) for k in range(n)]
        self._rotations = [find(struct.pack("<2d", *rot_marks[k])) for k in range(n)]
        self._template = template
        self._stamp, self._rotation = struct.Struct("<iI"), struct.Struct("<2d")
        self._sign_list = [float(v) for v in self.signs]

    def quaternions(self, angles) -> np.ndarray:
        """``(z, w)`` of each wheel's rotation for joint angles ``angles`` [rad] (last axis: the wheels)."""
        half = 0.5 * np.asarray(angles, dtype=float)
        return np.stack([self.signs * np.sin(half), np.cos(half)], axis=-1)

    def encode(self, stamp_ns: int, angles) -> bytes:
        """The message at ``stamp_ns`` [ns] for the wheels' joint angles ``angles`` [rad] (a node's tick:
        plain floats, no numpy)."""
        buf = bytearray(self._template)
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        pack_stamp, pack_rotation, sin, cos = self._stamp.pack_into, self._rotation.pack_into, math.sin, math.cos
        for stamp, rotation, sign, angle in zip(self._stamps, self._rotations, self._sign_list, angles):
            half = 0.5 * angle
            pack_stamp(buf, stamp, sec, nsec)
            pack_rotation(buf, rotation, sign * sin(half), cos(half))
        return bytes(buf)

    def encode_many(self, stamp_ns: np.ndarray, angles: np.ndarray) -> List[bytes]:
        """One message per row: ``stamp_ns`` (n,) [ns], ``angles`` (n, wheels) [rad]."""
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        n = stamp_ns.size
        if not n:
            return []
        out = np.tile(np.frombuffer(self._template, dtype=np.uint8), (n, 1))
        sec, nsec = np.divmod(stamp_ns, 1_000_000_000)
        sec_bytes = sec.astype("<i4").view(np.uint8).reshape(n, 4)
        nsec_bytes = nsec.astype("<u4").view(np.uint8).reshape(n, 4)
        q = np.ascontiguousarray(self.quaternions(angles), dtype="<f8")  # (n, wheels, 2)
        for k, (stamp, rotation) in enumerate(zip(self._stamps, self._rotations)):
            out[:, stamp : stamp + 4] = sec_bytes
            out[:, stamp + 4 : stamp + 8] = nsec_bytes
            out[:, rotation : rotation + 16] = q[:, k, :].view(np.uint8).reshape(n, 16)
        return [row.tobytes() for row in out]


def encode_robot_description(params) -> Tuple[str, bytes]:
    """The drive's URDF for ``params`` (:func:`~belt_drive_ros.io.urdf.urdf_from_params`) and its
    ``std_msgs/String`` CDR (as ``mcap_ros2`` and rclpy encode it)."""
    import msg_tools

    from .urdf import urdf_from_params

    urdf = urdf_from_params(params)
    return urdf, msg_tools.encode(STRING, {"data": urdf})


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


def parse_start_time(text: str) -> Optional[int]:
    """``--start-time``: ``now`` (None: the wall time when writing), seconds since the epoch,
    or an ISO 8601 date (UTC unless it names a zone); returns ns since the epoch."""
    import datetime

    text = str(text).strip()
    if text.lower() == "now":
        return None
    try:
        seconds = float(text)
    except ValueError:
        try:
            when = datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(f"--start-time {text!r}: expected 'now', seconds since the epoch or an ISO 8601 date") from None
        if when.tzinfo is None:
            when = when.replace(tzinfo=datetime.timezone.utc)
        seconds = when.timestamp()
    if not (math.isfinite(seconds) and 0 <= seconds < 2**63 / 1e9):
        raise ValueError(f"--start-time {text!r}: must be between 1970 and 2262")
    return int(round(seconds * 1e9))


def write_result_mcap(result, path, force: bool = False, *, namespace: str = "/",
                      output_rate: Optional[float] = None, topics: Optional[Iterable[str]] = None,
                      compression: str = "zstd",
                      extra_metadata: Optional[Mapping[str, Mapping[str, str]]] = None,
                      start_time_ns: Optional[int] = None, bag_folder: bool = False,
                      max_bag_size: Optional[int] = None,
                      max_bag_duration: Optional[float] = None, drive_topic: str = "drive_torque",
                      passthrough: Sequence[tuple] = ()) -> Dict[str, int]:
    """Write an offline run as a ROS 2 MCAP with the node's topics and layout.

    Parameters
    ----------
    result : SimResult
        From :func:`belt_drive_ros.core.simulate.simulate`.
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
        Subset of ``robot_description``, ``drive_torque``, ``joint_states``,
        ``shaft_speed``, ``load_torque``, ``belt_torque``,
        ``relative_deflection`` (and the slipping model's outputs) (default all).
        ``robot_description`` is one ``std_msgs/String`` message at the start:
        the drive's URDF from the scene's radii (:mod:`belt_drive_ros.io.urdf`),
        offered transient local like ``robot_state_publisher``'s, for
        Foxglove's 3D panel.
    compression : {"zstd", "lz4", "none"}
    extra_metadata : mapping of record name to str dict, optional
        Further metadata records.
    start_time_ns : int, optional
        Time stamp [ns since the epoch] of scene time 0. Default: the wall
        time of the call, as rosbag2 stamps a recording (viewers then show
        the day of the run, not 1970). Give a fixed value (0 included) for
        files that must be byte-identical run after run (golden files).
    bag_folder : bool
        Write rosbag2's folder layout (``path/NAME_0.mcap`` +
        ``path/metadata.yaml``, :class:`msg_tools.bagdir.Ros2BagWriter`)
        instead of one file; implied by the split limits.
    max_bag_size : int, optional
        Split into a new file once one holds this many bytes.
    max_bag_duration : float, optional
        Split into a new file once one spans this much time [s].
    drive_topic : str
        Topic of the run's drive torque (a re-simulated node recording:
        ``drive_torque_applied``, beside the recording's raw ``drive_torque``).
    passthrough : sequence of tuple
        Recorded topics copied as they are, ``(topic, type, offered QoS YAML,
        type hash, [(log time [ns], CDR bytes)])``, written in time order
        between the samples (:func:`~belt_drive_ros.io.torque_bag.resimulation`).

    Returns
    -------
    dict
        Messages written per topic.

    Notes
    -----
    ``log_time``, ``publish_time`` and the ``joint_states`` stamps are
    ``start_time_ns`` + simulated time. Messages are encoded as ``mcap_ros2``
    encodes them (zero padding), so the same run with the same
    ``start_time_ns`` gives a byte-identical file (golden files).
    At each time the order is the node's: ``drive_torque``, ``joint_states``,
    then the Float64 outputs; ``robot_description`` comes first of all.

    Raises
    ------
    BagExistsError
        If ``path`` exists and ``force`` is False.
    BagWriteError
        If the file cannot be written.
    """
    writer = ResultMcapWriter(path, result, force=force, namespace=namespace, output_rate=output_rate,
                              topics=topics, compression=compression, extra_metadata=extra_metadata,
                              start_time_ns=start_time_ns, bag_folder=bag_folder, max_bag_size=max_bag_size,
                              max_bag_duration=max_bag_duration, drive_topic=drive_topic, passthrough=passthrough,
                              samples=len(range(0, len(result.time), _output_stride(result, output_rate))))
    try:
        writer.write(result)
    except BaseException:
        writer.abort()
        raise
    return writer.close()


class ResultMcapWriter:
    """The one writer of offline runs to MCAP: :func:`write_result_mcap` for a whole run, window by window for a streamed one.

    ``ResultMcapWriter(path, first_window, ...)`` opens the output (options as
    :func:`write_result_mcap`), :meth:`write` appends a window of the run
    (a :class:`~belt_drive_ros.core.simulate.SimResult` continuing the
    previous one, see :mod:`belt_drive_ros.core.stream`), :meth:`close`
    finishes the file and returns the messages per topic. Output samples are
    every ``stride``-th sample of the whole run, counted across windows, so a
    streamed run writes what the whole run would. With ``samples`` given (a
    whole run), the scene record goes first, as always; otherwise (a stream,
    whose length is known only at the end) it is written at :meth:`close`
    with the count. ``chunk_size`` [bytes] (default the writer's 128 KiB,
    closed every 0.25 s of log time) sets size-only chunks: the MCAP writer
    keeps one chunk index entry per chunk until it finishes, so a day-long
    stream uses a few MiB chunks to keep that small.
    """

    def __init__(self, path, result, force: bool = False, *, namespace: str = "/",
                 output_rate: Optional[float] = None, topics: Optional[Iterable[str]] = None,
                 compression: str = "zstd", extra_metadata: Optional[Mapping[str, Mapping[str, str]]] = None,
                 start_time_ns: Optional[int] = None, bag_folder: bool = False,
                 max_bag_size: Optional[int] = None, max_bag_duration: Optional[float] = None,
                 samples: Optional[int] = None, chunk_size: Optional[int] = None,
                 drive_topic: str = "drive_torque", passthrough: Sequence[tuple] = ()):
        self.float_outputs = FLOAT_OUTPUTS + tuple(o for o in SLIP_FLOAT_OUTPUTS if getattr(result, "model", "") in SLIP_MODELS)
        offline_topics = (ROBOT_DESCRIPTION, "drive_torque", "joint_states", TF_TOPIC.strip("/")) + tuple(
            name for name, _ in self.float_outputs)
        self.wanted = offline_topics if topics is None else tuple(t.strip("/") for t in topics)
        unknown = sorted(set(self.wanted) - set(offline_topics))
        if unknown:
            raise ValueError(f"topics: unknown {', '.join(unknown)}; offline runs have {', '.join(offline_topics)}")
        self.stride = _output_stride(result, output_rate)
        if start_time_ns is None:
            start_time_ns = time.time_ns()
        self.start_time_ns = int(start_time_ns)
        if self.start_time_ns < 0:
            raise ValueError(f"start_time_ns must be >= 0 ns since the epoch, got {start_time_ns}")
        if len(result.time) and result.time[0] < 0:
            raise ValueError(f"result starts at negative time {result.time[0]} s; MCAP times must be >= 0")
        self.namespace = namespace
        self.seen = 0  # samples of the run so far (all windows)
        self.samples = 0  # of them written
        scene = result.scene
        mapping = scene_mapping(scene, model=result.model, method=result.method, dt=result.dt)
        drive_source = "torque_bag" if isinstance(mapping.get("drive"), dict) and mapping["drive"].get("type") == RECORDED_DRIVE else "scene"
        self._record = lambda count: _scene_record(
            mapping, source="offline", drive_source=drive_source,
            extra={
                "model_choice": result.choice.reason if result.choice is not None else f"{result.model}: set explicitly",
                "method_choice": (result.method_choice.reason if getattr(result, "method_choice", None) is not None
                                  else f"{result.method}: set explicitly"),  # fmt: skip
                "output_rate": float(output_rate or scene.output_rate) if self.stride > 1 else 1.0 / result.dt,
                "samples": int(count),
            },
        )
        parameters = {name: _fmt(float(value)) for name, value in scene.params.to_dict().items()}
        parameters.update(model=result.model, method=result.method, dt=_fmt(float(result.dt)))
        self._deferred = samples is None
        # a long stream: fewer, larger chunks (the writer keeps one index entry per chunk until the end)
        chunking = {} if chunk_size is None else {"chunk_size": int(chunk_size), "flush_interval_s": None}
        try:
            if bag_folder or max_bag_size or max_bag_duration:
                from msg_tools.bagdir import Ros2BagWriter

                self.writer: Any = Ros2BagWriter(path, force=force, compression=compression,
                                                 max_bag_size=max_bag_size, max_bag_duration=max_bag_duration,
                                                 **chunking)
            else:
                self.writer = Ros2McapWriter(path, force=force, compression=compression, **chunking)
            w = self.writer
            if not self._deferred:
                w.add_metadata(SCENE_METADATA, self._record(samples))
            self.payload_topics = []
            if "drive_torque" in self.wanted:
                self.payload_topics.append((_absolute(drive_topic, namespace), FLOAT64, "drive_torque"))
            if "joint_states" in self.wanted:
                self.payload_topics.append((_absolute("joint_states", namespace), JOINT_STATE, None))
            if TF_TOPIC.strip("/") in self.wanted:  # /tf is absolute, as tf2 broadcasts it
                self.payload_topics.append((TF_TOPIC, TF_MESSAGE, TF_TOPIC))
                self._tf = TfEncoder(scene.params)
            for topic, signal in self.float_outputs:
                if topic in self.wanted:
                    self.payload_topics.append((_absolute(topic, namespace), FLOAT64, signal))
            w.add_metadata(PARAMETERS_METADATA, parameters)
            written = {topic for topic, _, _ in self.payload_topics}
            w.add_metadata(UNITS_METADATA, {
                key: unit for key, unit in units_metadata(namespace).items()
                if key in written or key.rsplit("/", 1)[0] in written
            })
            for extra_name, values in (extra_metadata or {}).items():
                w.add_metadata(extra_name, dict(values))
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None
        self._params = scene.params
        self._topics_added = False
        # recorded messages copied as they are, in time order between the samples: (time, topic, type, CDR)
        self._passthrough = sorted(((t, topic, type_name, data) for topic, type_name, _, _, messages in passthrough
                                    for t, data in messages), key=lambda m: m[0])
        self._passthrough_qos = [(topic, type_name, qos, type_hash) for topic, type_name, qos, type_hash, _ in passthrough]
        self._next_passthrough = 0

    def _add_topics(self, t0_ns: Optional[int]) -> None:
        """Channels in the file's order: robot_description with its one message (at the first sample), then the signals."""
        w = self.writer
        if ROBOT_DESCRIPTION in self.wanted and t0_ns is not None:
            description = _absolute(ROBOT_DESCRIPTION, self.namespace)
            w.add_topic(description, STRING, ROBOT_DESCRIPTION_QOS)
            if hasattr(w, "latch"):  # a split run starts every file with it
                w.latch(description)
            w.write_raw(description, STRING, encode_robot_description(self._params)[1], t0_ns)
        for topic, type_name, _ in self.payload_topics:
            w.add_topic(topic, type_name, TF_QOS if topic == TF_TOPIC else "reliable")
        for topic, type_name, qos, type_hash in self._passthrough_qos:
            from msg_tools import parse_offered_qos_yaml

            try:
                profiles = parse_offered_qos_yaml(qos) if qos else "reliable"
            except ValueError:
                profiles = "reliable"
            w.add_topic(topic, type_name, profiles or "reliable", type_hash=type_hash)
        self._topics_added = True

    def _write_passthrough(self, until_ns: Optional[int]) -> None:
        """The passed-through messages up to ``until_ns`` (all with None)."""
        messages, k = self._passthrough, self._next_passthrough
        while k < len(messages) and (until_ns is None or messages[k][0] <= until_ns):
            t, topic, type_name, data = messages[k]
            self.writer.write_raw(topic, type_name, data, t)
            k += 1
        self._next_passthrough = k

    def write(self, result) -> None:
        """Append the window ``result`` (the samples after the previous window's last)."""
        n = len(result.time)
        first = (-self.seen) % self.stride
        index = np.arange(first, n, self.stride)
        self.seen += n
        if not index.size:
            return
        self.samples += int(index.size)
        t_ns = np.round(np.asarray(result.time, dtype=float)[index] * 1e9).astype(np.int64) + self.start_time_ns
        o = {name: np.asarray(values)[index] for name, values in result.outputs.items()}
        payloads: List[List[bytes]] = []
        for topic, type_name, signal in self.payload_topics:
            if signal is None:
                zeros = np.zeros(index.size)
                position = np.column_stack([o["phi_M"], o["phi_1"], o["phi_2"], o["phi_3"]])
                velocity = np.column_stack([o["omega_M"], o["omega_1"], o["omega_2"], o["omega_3"]])
                effort = np.column_stack([o["drive_torque"], zeros, zeros, -o["load_torque"]])
                payloads.append(encode_joint_states(t_ns, position, velocity, effort))
            elif signal == TF_TOPIC:
                phi = np.column_stack([o["phi_M"], o["phi_1"], o["phi_2"], o["phi_3"]])
                payloads.append(self._tf.encode_many(t_ns, phi))
            else:
                payloads.append(encode_float64(np.asarray(o[signal], dtype=float)))
        try:
            if not self._topics_added:
                self._add_topics(int(t_ns[0]))
            write = self.writer.write_raw
            topics = self.payload_topics
            passthrough = self._passthrough
            for k, t in enumerate(t_ns.tolist()):
                if self._next_passthrough < len(passthrough) and passthrough[self._next_passthrough][0] <= t:
                    self._write_passthrough(t)
                for (topic, type_name, _), data in zip(topics, payloads):
                    write(topic, type_name, data[k], t)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None

    def close(self) -> Dict[str, int]:
        """Finish the file (the scene record now, for a stream); returns messages per topic."""
        try:
            if not self._topics_added:
                self._add_topics(None)
            self._write_passthrough(None)
            if self._deferred:
                self.writer.add_metadata(SCENE_METADATA, self._record(self.samples))
            counts = self.writer.topic_counts()
            self.writer.__exit__(None, None, None)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None
        return counts

    def abort(self) -> None:
        """Close after a failure (the file is not completed; :mod:`belt_drive_ros.io.atomic` removes it)."""
        try:
            self.writer.__exit__(RuntimeError, RuntimeError("aborted"), None)
        except Exception:  # noqa: BLE001 - the original error is the one to report
            pass
