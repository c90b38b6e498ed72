"""ROS 2 message definitions (``ros2msg`` schema texts) for the types we record.

The texts are the ``.msg`` files exactly as shipped in ROS 2 Jazzy
(``share/<pkg>/msg/<Type>.msg`` of ``builtin_interfaces`` 2.0, ``std_msgs`` /
``sensor_msgs`` / ``diagnostic_msgs`` 5.3, ``rosgraph_msgs`` 2.0), comments
included, so the schema stored in a bag is byte-for-byte what ``ros2 bag
record`` would store apart from the dependency header line.

Complete definitions follow the ``ros2msg`` rule of rosbag2
(``docs/message_definition_encoding.md`` and
``rosbag2_cpp/src/rosbag2_cpp/message_definitions/local_message_definition_source.cpp``
in ros2/rosbag2): the root ``.msg`` text first; then, depth-first with the
dependencies of each type in sorted order and each type once, a line of 80
``=``, a line ``MSG: pkg/msg/Type`` and that type's text.

This module is pure Python: it never imports rclpy.
"""

from __future__ import annotations

import re
from typing import Dict, List, Tuple

from .errors import UnknownMessageTypeError

__all__ = [
    "MESSAGE_DEFINITIONS",
    "TYPE_HASHES",
    "known_types",
    "normalize_type_name",
    "schema_text",
    "type_hash",
]

#: Width of the separator line between definitions (rosbag2 uses exactly 80).
SEPARATOR = "=" * 80

#: ``.msg`` text of each known type, exactly as in ROS 2 Jazzy.
MESSAGE_DEFINITIONS: Dict[str, str] = {
    "builtin_interfaces/msg/Time": (
        "# This message communicates ROS Time defined here:\n"
        "# https://design.ros2.org/articles/clock_and_time.html\n"
        "\n"
        "# The seconds component, valid over all int32 values.\n"
        "int32 sec\n"
        "\n"
        "# The nanoseconds component, valid in the range [0, 1e9), to be added to the seconds component. \n"
        "# e.g.\n"
        "# The time -1.7 seconds is represented as {sec: -2, nanosec: 3e8}\n"
        "# The time 1.7 seconds is represented as {sec: 1, nanosec: 7e8}\n"
        "uint32 nanosec\n"
    ),
    "std_msgs/msg/Header": (
        "# Standard metadata for higher-level stamped data types.\n"
        "# This is generally used to communicate timestamped data\n"
        "# in a particular coordinate frame.\n"
        "\n"
        "# Two-integer timestamp that is expressed as seconds and nanoseconds.\n"
        "builtin_interfaces/Time stamp\n"
        "\n"
        "# Transform frame with which this data is associated.\n"
        "string frame_id\n"
    ),
    "std_msgs/msg/Float64": (
        "# This was originally provided as an example message.\n"
        "# It is deprecated as of Foxy\n"
        "# It is recommended to create your own semantically meaningful message.\n"
        "# However if you would like to continue using this please use the equivalent in example_msgs.\n"
        "\n"
        "float64 data\n"
    ),
    "std_msgs/msg/String": (
        "# This was originally provided as an example message.\n"
        "# It is deprecated as of Foxy\n"
        "# It is recommended to create your own semantically meaningful message.\n"
        "# However if you would like to continue using this please use the equivalent in example_msgs.\n"
        "\n"
        "string data\n"
    ),
    "sensor_msgs/msg/JointState": (
        "# This is a message that holds data to describe the state of a set of torque controlled joints.\n"
        "#\n"
        "# The state of each joint (revolute or prismatic) is defined by:\n"
        "#  * the position of the joint (rad or m),\n"
        "#  * the velocity of the joint (rad/s or m/s) and\n"
        "#  * the effort that is applied in the joint (Nm or N).\n"
        "#\n"
        "# Each joint is uniquely identified by its name\n"
        "# The header specifies the time at which the joint states were recorded. All the joint states\n"
        "# in one message have to be recorded at the same time.\n"
        "#\n"
        "# This message consists of a multiple arrays, one for each part of the joint state.\n"
        "# The goal is to make each of the fields optional. When e.g. your joints have no\n"
        "# effort associated with them, you can leave the effort array empty.\n"
        "#\n"
        "# All arrays in this message should have the same size, or be empty.\n"
        "# This is the only way to uniquely associate the joint name with the correct\n"
        "# states.\n"
        "\n"
        "std_msgs/Header header\n"
        "\n"
        "string[] name\n"
        "float64[] position\n"
        "float64[] velocity\n"
        "float64[] effort\n"
    ),
    "rosgraph_msgs/msg/Clock": (
        "# This message communicates the current time.\n"
        "#\n"
        "# For more information, see https://design.ros2.org/articles/clock_and_time.html.\n"
        "builtin_interfaces/Time clock\n"
    ),
    "diagnostic_msgs/msg/KeyValue": (
        "# What to label this value when viewing.\n"
        "string key\n"
        "# A value to track over time.\n"
        "string value\n"
    ),
    "diagnostic_msgs/msg/DiagnosticStatus": (
        "# This message holds the status of an individual component of the robot.\n"
        "\n"
        "# Possible levels of operations.\n"
        "byte OK=0\n"
        "byte WARN=1\n"
        "byte ERROR=2\n"
        "byte STALE=3\n"
        "\n"
        "# Level of operation enumerated above.\n"
        "byte level\n"
        "# A description of the test/component reporting.\n"
        "string name\n"
        "# A description of the status.\n"
        "string message\n"
        "# A hardware unique string.\n"
        "string hardware_id\n"
        "# An array of values associated with the status.\n"
        "KeyValue[] values\n"
        "\n"
    ),
    "diagnostic_msgs/msg/DiagnosticArray": (
        "# This message is used to send diagnostic information about the state of the robot.\n"
        "std_msgs/Header header # for timestamp\n"
        "DiagnosticStatus[] status # an array of components being reported on\n"
    ),
}

#: REP-2011 type description hashes (``RIHS01_...``) of the Jazzy types, copied
#: from the ``type_hashes`` entry of each ``share/<pkg>/msg/<Type>.json``. rosbag2
#: stores this per channel (metadata key ``topic_type_hash``) and in the bag
#: metadata (``type_description_hash``); playback does not need it.
TYPE_HASHES: Dict[str, str] = {
    "builtin_interfaces/msg/Time": "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
    "std_msgs/msg/Header": "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "std_msgs/msg/Float64": "RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a",
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "rosgraph_msgs/msg/Clock": "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    "diagnostic_msgs/msg/KeyValue": "RIHS01_d68081eaa540288c5440753baecef0c4e16e81a5f78ad68902ded5100413bb42",
    "diagnostic_msgs/msg/DiagnosticStatus": "RIHS01_b0e3e692ea2d54a8af2f4ef1930e81556a2db55216b771f8a7d2724ed47bf0e4",
    "diagnostic_msgs/msg/DiagnosticArray": "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
}

_PRIMITIVE_TYPES = frozenset(
    [
        "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
        "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring",
    ]
)

# Field type at the start of a line, as rosbag2's MSG_FIELD_TYPE_REGEX:
# "foo_msgs/Bar" in "foo_msgs/Bar[] bar"; bounded strings ("string<=5") too.
_FIELD_TYPE = re.compile(r"^\s*([a-zA-Z0-9_/]+)(?:<=\d+)?(?:\[[^\]]*\])?\s+", re.MULTILINE)

_TYPE_NAME = re.compile(r"^([a-zA-Z][a-zA-Z0-9_]*)/(?:(msg)/)?([a-zA-Z][a-zA-Z0-9_]*)$")


def known_types() -> List[str]:
    """Return the sorted names of the message types with a built-in definition."""
    return sorted(MESSAGE_DEFINITIONS)


def normalize_type_name(type_name: str) -> str:
    """Return the full ``pkg/msg/Type`` form of ``type_name``.

    Parameters
    ----------
    type_name : str
        ``"pkg/msg/Type"`` or the short form ``"pkg/Type"``.

    Raises
    ------
    ValueError
        If ``type_name`` is not of either form.
    """
    match = _TYPE_NAME.match(type_name.strip()) if isinstance(type_name, str) else None
    if match is None:
        raise ValueError(
            f"invalid ROS 2 message type name {type_name!r}; expected 'pkg/msg/Type'"
        )
    return f"{match.group(1)}/msg/{match.group(3)}"


def dependencies(type_name: str, text: str) -> List[str]:
    """Return the sorted full names of the non-primitive field types in ``text``.

    Parameters
    ----------
    type_name : str
        Full name of the type whose definition ``text`` is; a field type
        without a package (``KeyValue``) is taken from this package.
    text : str
        ``.msg`` text of that type.
    """
    package = type_name.split("/")[0]
    found = set()
    for line in text.splitlines():
        code = line.split("#", 1)[0]
        match = _FIELD_TYPE.match(code)
        if match is None:
            continue
        field_type = match.group(1)
        if field_type in _PRIMITIVE_TYPES:  # also skips constants ("byte OK=0")
            continue
        if "/" not in field_type:
            field_type = f"{package}/{field_type}"
        found.add(normalize_type_name(field_type))
    return sorted(found)


def _definition(type_name: str, extra: Dict[str, str]) -> str:
    if type_name in extra:
        return extra[type_name]
    if type_name in MESSAGE_DEFINITIONS:
        return MESSAGE_DEFINITIONS[type_name]
    raise UnknownMessageTypeError(type_name, set(MESSAGE_DEFINITIONS) | set(extra))


def schema_text(type_name: str, extra_definitions: Dict[str, str] | None = None) -> str:
    """Return the complete ``ros2msg`` schema text of ``type_name``.

    Parameters
    ----------
    type_name : str
        Message type, ``"sensor_msgs/msg/JointState"`` (or ``"sensor_msgs/JointState"``).
    extra_definitions : dict of str to str, optional
        ``.msg`` texts of further types (full names), used before the built-in ones.

    Returns
    -------
    str
        The root definition followed by every dependency, each preceded by an
        80-character ``=`` line and ``MSG: pkg/msg/Type``.

    Raises
    ------
    UnknownMessageTypeError
        If the type or one of its dependencies has no definition; the message
        names the type and lists the known ones.
    """
    extra = {normalize_type_name(k): v for k, v in (extra_definitions or {}).items()}
    root = normalize_type_name(type_name)
    seen = {root}

    def append(name: str, depth: int) -> str:
        if depth > 50:
            raise RecursionError(f"message definition of {root} nests deeper than 50 levels")
        text = _definition(name, extra)
        out = text
        for dep in dependencies(name, text):
            if dep not in seen:
                seen.add(dep)
                out += "\n" + SEPARATOR + "\nMSG: " + dep + "\n" + append(dep, depth + 1)
        return out

    return append(root, 0)


def type_hash(type_name: str) -> str:
    """Return the ``RIHS01_...`` hash of a known type, or ``""`` if unknown."""
    try:
        return TYPE_HASHES.get(normalize_type_name(type_name), "")
    except ValueError:
        return ""


def split_schema(text: str) -> List[Tuple[str, str]]:
    """Split a complete ``ros2msg`` text into ``(type_name, text)`` pairs.

    The first pair has an empty type name (the root). Used by tests to check
    the concatenation rule.
    """
    parts = re.split(r"^={80}\n", text, flags=re.MULTILINE)
    out: List[Tuple[str, str]] = [("", parts[0])]
    for part in parts[1:]:
        first, _, body = part.partition("\n")
        out.append((first[len("MSG: "):] if first.startswith("MSG: ") else first, body))
    return out
