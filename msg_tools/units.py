"""SI units of recorded signals, for column names and plot labels.

Topics carry SI values (REP 103) but no unit. A recording may declare units in
a metadata record named ``"units"`` whose keys are topic names
(``"/drive_torque": "N*m"``) or topic/field (``"/joint_states/effort": "N*m"``);
without one, units are guessed from the topic name. rpm appears only as a
secondary label in plots (:data:`RAD_PER_S_TO_RPM`), never in data.
"""

from __future__ import annotations

import math
import re
from typing import Mapping, Optional

__all__ = ["RAD_PER_S_TO_RPM", "UNITS_METADATA", "is_shaft_speed", "label", "unit_for"]

#: Name of the metadata record that declares units.
UNITS_METADATA = "units"

#: 1 rad/s in rpm: 60 / (2 pi).
RAD_PER_S_TO_RPM = 60.0 / (2.0 * math.pi)

# JointState fields of revolute joints (sensor_msgs/JointState documents
# rad, rad/s and N*m; prismatic joints would be m, m/s, N).
_JOINT_UNITS = {"position": "rad", "velocity": "rad/s", "effort": "N*m", "stamp": "s"}

# Keyword in the topic name -> unit, first match wins.
_KEYWORDS = (
    (r"torque|moment", "N*m"),
    (r"speed|velocity|omega|angular_rate", "rad/s"),
    (r"accel", "rad/s^2"),
    (r"angle|position|theta|phase", "rad"),
    (r"tension|force", "N"),
    (r"power", "W"),
    (r"energy|work", "J"),
    (r"stiffness", "N/m"),
    (r"inertia", "kg*m^2"),
)


def unit_for(topic: str, field: str = "data", declared: Optional[Mapping[str, str]] = None) -> str:
    """Return the SI unit of ``field`` of ``topic`` ("" if unknown).

    Parameters
    ----------
    topic : str
        Topic name, e.g. ``"/drive_torque"``.
    field : str
        ``"data"`` for scalar topics, ``"position"`` / ``"velocity"`` /
        ``"effort"`` for JointState, or a dotted field path.
    declared : mapping, optional
        Contents of the bag's ``units`` metadata record.
    """
    declared = declared or {}
    name = topic if topic.startswith("/") else "/" + topic
    for key in (f"{name}/{field}", f"{name.lstrip('/')}/{field}", name, name.lstrip("/")):
        if key in declared:
            return declared[key]
    if field in _JOINT_UNITS:
        return _JOINT_UNITS[field]
    base = name.rsplit("/", 1)[-1].lower()
    for pattern, unit in _KEYWORDS:
        if re.search(pattern, base):
            return unit
    return ""


def label(name: str, unit: str) -> str:
    """Return ``"name [unit]"`` (just ``name`` without a unit)."""
    return f"{name} [{unit}]" if unit else name


def is_shaft_speed(unit: str) -> bool:
    """True for angular speeds, which plots also label in rpm."""
    return unit == "rad/s"
