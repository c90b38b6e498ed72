"""What a recording holds (see :mod:`belt_drive_ros.io.recording`): topic names, message types and SI units,
metadata record names, the bag errors, and the ``scene`` metadata record.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from typing import Any, Dict, Mapping, Optional, Tuple

from msg_tools.errors import OverwriteError, WriteError

from ..core.errors import BeltDriveError

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
#: the ``format`` of the ``scene`` record this version writes and reads
SCENE_FORMAT = "belt_drive_ros scene 1"
#: Metadata record names.
SCENE_METADATA = "scene"
PARAMETERS_METADATA = "parameters"
#: a node's run (re)started from the initial state: ``time_ns`` (node time), ``cause`` (``start`` for the first)
RESTART_METADATA = "restart"


def restart_record(now_ns: int, why: str) -> Dict[str, str]:
    """The :data:`RESTART_METADATA` record of a (re)start at node time ``now_ns`` [ns] for ``why`` (both nodes')."""
    return {"time_ns": str(now_ns), "cause": why}


def restarts_of(records) -> list:
    """``(node time [ns] or None where the record's is no number, cause)`` of each restart after the first start among
    the ``(name, values)`` metadata records ``records`` (a re-simulation refuses a run that restarted)."""
    return [(int(v["time_ns"]) if str(v.get("time_ns", "")).isdigit() else None, v.get("cause", ""))
            for name, v in records if name == RESTART_METADATA and v.get("cause", "start") != "start"]
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
        "format": SCENE_FORMAT,
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
