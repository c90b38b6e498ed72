"""ROS 2 message definitions: ``ros2msg`` schema texts and RIHS01 type hashes.

Where the texts come from
-------------------------
The ``.msg`` file of a type is looked up where ROS installs it,
``<prefix>/share/<pkg>/msg/<Type>.msg``, for every prefix on
``AMENT_PREFIX_PATH`` and this Python's own prefix (the ``ros-*`` wheels
install there); files are only read, nothing from ROS is imported. Without a
ROS installation the texts of msg_tools' own types (:data:`MESSAGE_DEFINITIONS`,
the Jazzy files byte for byte; a test compares them with the installed ones)
are used, so msg_tools works without ROS. Further types can be registered
(``extra_definitions``, :meth:`msg_tools.Ros2McapWriter.register_type`).

Complete definitions (schema texts)
-----------------------------------
Exactly as rosbag2 Jazzy writes them (``docs/message_definition_encoding.md``
and ``rosbag2_cpp/src/rosbag2_cpp/message_definitions/local_message_definition_source.cpp``
in ros2/rosbag2): the root ``.msg`` text first; then, depth-first, for the
dependencies of each type (field types found by rosbag2's regular
expression, a type without package taken from the enclosing package, in
sorted order, each type once) a newline, a line of 80 ``=``, a line
``MSG: <type as the field names it>`` -- ``MSG: std_msgs/Header`` for the
field ``std_msgs/Header header`` -- and that type's text. Foxglove's parser
(``@foxglove/rosmsg``) matches these names exactly.

Type hashes
-----------
``RIHS01_<sha256>`` of the type description as REP 2011 and
``rosidl_generator_type_description`` define it: the type and every type it
references (sorted by name), each as its name and fields (name, type id,
capacity, string capacity, nested type name; no default values), serialized
as JSON with ``", "`` and ``": "`` separators. :func:`type_hash` computes it
from the ``.msg`` texts; a test checks it against the hashes the installed
ROS packages ship for every message of several packages.

This module is pure Python: it never imports rclpy.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import sys
from functools import lru_cache
from typing import Dict, List, Mapping, Optional, Tuple

from .errors import UnknownMessageTypeError

__all__ = [
    "MESSAGE_DEFINITIONS",
    "definition",
    "installed_definition",
    "known_types",
    "normalize_type_name",
    "schema_text",
    "type_description",
    "type_hash",
]

#: Width of the separator line between definitions (rosbag2 uses exactly 80).
SEPARATOR = "=" * 80

#: ``.msg`` text of msg_tools' own types, exactly as in ROS 2 Jazzy: the fallback
#: when no ROS installation provides them.
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
    ),    "geometry_msgs/msg/TransformStamped": (
        '# This expresses a transform from coordinate frame header.frame_id\n'
        '# to the coordinate frame child_frame_id at the time of header.stamp\n'
        '#\n'
        '# This message is mostly used by the\n'
        '# <a href="https://docs.ros.org/en/rolling/p/tf2/">tf2</a> package.\n'
        '# See its documentation for more information.\n'
        '#\n'
        '# The child_frame_id is necessary in addition to the frame_id\n'
        '# in the Header to communicate the full reference for the transform\n'
        '# in a self contained message.\n'
        '\n'
        '# The frame id in the header is used as the reference frame of this transform.\n'
        'std_msgs/Header header\n'
        '\n'
        '# The frame id of the child frame to which this transform points.\n'
        'string child_frame_id\n'
        '\n'
        '# Translation and rotation in 3-dimensions of child_frame_id from header.frame_id.\n'
        'Transform transform\n'
    ),
    "geometry_msgs/msg/Transform": (
        '# This represents the transform between two coordinate frames in free space.\n'
        '\n'
        'Vector3 translation\n'
        'Quaternion rotation\n'
    ),
    "geometry_msgs/msg/Vector3": (
        '# This represents a vector in free space.\n'
        '\n'
        '# This is semantically different than a point.\n'
        '# A vector is always anchored at the origin.\n'
        '# When a transform is applied to a vector, only the rotational component is applied.\n'
        '\n'
        'float64 x\n'
        'float64 y\n'
        'float64 z\n'
    ),
    "geometry_msgs/msg/Quaternion": (
        '# This represents an orientation in free space in quaternion form.\n'
        '\n'
        'float64 x 0\n'
        'float64 y 0\n'
        'float64 z 0\n'
        'float64 w 1\n'
    ),
    "tf2_msgs/msg/TFMessage": (
        'geometry_msgs/TransformStamped[] transforms\n'
    ),
}

_PRIMITIVE_TYPES = frozenset(
    [
        "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
        "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring",
    ]
)

# rosbag2's MSG_FIELD_TYPE_REGEX, applied to the whole text ("^" = start of text):
# "foo_msgs/Bar" in "foo_msgs/Bar[] bar".
_ROSBAG2_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")

_TYPE_NAME = re.compile(r"^([a-zA-Z][a-zA-Z0-9_]*)/(?:(msg)/)?([a-zA-Z][a-zA-Z0-9_]*)$")

#: deepest nesting of message types followed (rosbag2 stops at 50 too)
MAX_DEPTH = 50


def known_types() -> List[str]:
    """Return the sorted names of the types msg_tools has a built-in definition of."""
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


def share_directories() -> List[str]:
    """``share`` folders searched for ``.msg`` files, in order.

    Every prefix on ``AMENT_PREFIX_PATH`` (a sourced ROS install or
    workspace), then this Python's prefix (where the ``ros-*`` wheels put
    their files).
    """
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    out: List[str] = []
    for prefix in prefixes:
        share = os.path.join(prefix, "share")
        if share not in out:
            out.append(share)
    return out


@lru_cache(maxsize=512)
def _read_installed(share_dirs: Tuple[str, ...], full_name: str) -> Optional[str]:
    package, _, short = full_name.split("/")
    for share in share_dirs:
        path = os.path.join(share, package, "msg", short + ".msg")
        try:
            with open(path, "rb") as f:
                return f.read().decode("utf-8")
        except (OSError, UnicodeDecodeError):
            continue
    return None


def installed_definition(type_name: str) -> Optional[str]:
    """The installed ``.msg`` text of ``type_name``, or None if no ROS install has it."""
    return _read_installed(tuple(share_directories()), normalize_type_name(type_name))


def definition(type_name: str, extra_definitions: Optional[Mapping[str, str]] = None) -> str:
    """The ``.msg`` text of ``type_name``: registered, else installed, else built in.

    Raises
    ------
    UnknownMessageTypeError
        If none of the three has it; the message lists the built-in types.
    """
    full = normalize_type_name(type_name)
    if extra_definitions:
        for key, text in extra_definitions.items():
            if normalize_type_name(key) == full:
                return text
    text = installed_definition(full)
    if text is None:
        text = MESSAGE_DEFINITIONS.get(full)
    if text is None:
        raise UnknownMessageTypeError(full, set(MESSAGE_DEFINITIONS) | set(extra_definitions or {}))
    return text


def dependencies_as_written(type_name: str, text: str) -> List[str]:
    """Field types of ``text`` that are messages, named as rosbag2 names them, sorted.

    ``"std_msgs/Header"`` for ``std_msgs/Header header``; a type without a
    package (``KeyValue[] values`` in ``diagnostic_msgs``) gets the package of
    ``type_name``: ``"diagnostic_msgs/KeyValue"``.
    """
    package = normalize_type_name(type_name).split("/")[0]
    found = set()
    for match in _ROSBAG2_FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVE_TYPES:  # also skips constants ("byte OK=0")
            continue
        found.add(field_type if "/" in field_type else f"{package}/{field_type}")
    return sorted(found)


def dependencies(type_name: str, text: str) -> List[str]:
    """Sorted full names (``pkg/msg/Type``) of the message types ``text`` uses."""
    return sorted({normalize_type_name(d) for d in dependencies_as_written(type_name, text)})


def schema_text(type_name: str, extra_definitions: Optional[Mapping[str, str]] = None) -> str:
    """Return the complete ``ros2msg`` schema text of ``type_name``, as rosbag2 Jazzy writes it.

    Parameters
    ----------
    type_name : str
        Message type, ``"sensor_msgs/msg/JointState"`` (or ``"sensor_msgs/JointState"``).
    extra_definitions : dict of str to str, optional
        ``.msg`` texts of further types (full names), used before installed
        and built-in ones.

    Returns
    -------
    str
        The root definition, then for every dependency ``"\n"``, 80 ``=``,
        ``"\nMSG: pkg/Type\n"`` (the name as the field writes it) and its text.

    Raises
    ------
    UnknownMessageTypeError
        If the type or one of its dependencies has no definition; the message
        names the type and lists the known ones.
    """
    extra = {normalize_type_name(k): v for k, v in (extra_definitions or {}).items()}
    root = normalize_type_name(type_name)
    seen = set()

    def append(name: str, depth: int) -> str:
        if depth > MAX_DEPTH:
            raise RecursionError(f"message definition of {root} nests deeper than {MAX_DEPTH} levels")
        text = definition(name, extra)
        out = text
        for dep in dependencies_as_written(name, text):
            if dep not in seen:
                seen.add(dep)
                out += "\n" + SEPARATOR + "\nMSG: " + dep + "\n" + append(dep, depth + 1)
        return out

    return append(root, 0)


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


# --------------------------------------------------------------------------
# type descriptions and RIHS01 hashes (REP 2011)
# --------------------------------------------------------------------------
#: FieldType ids of type_description_interfaces (rosidl_generator_type_description)
_BASE_TYPE_ID = {
    "nested": 1, "int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7,
    "int64": 8, "uint64": 9, "float32": 10, "float64": 11, "char": 3,  # .msg char is IDL uint8
    "bool": 15, "byte": 16, "string": 17, "wstring": 18,
    "bounded_string": 21, "bounded_wstring": 22,
}
_ARRAY, _BOUNDED_SEQUENCE, _UNBOUNDED_SEQUENCE = 48, 96, 144

_FIELD = re.compile(
    r"^(?P<type>[a-zA-Z][a-zA-Z0-9_/]*)(?:<=(?P<strcap>\d+))?(?:\[(?P<arr>(?:<=)?\d*)\])?"
    r"\s+(?P<name>[a-zA-Z][a-zA-Z0-9_]*)(?P<rest>.*)$"
)


def _strip_comment(line: str) -> str:
    """The code part of a ``.msg`` line (``#`` inside a quoted default is kept)."""
    quote = None
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#":
            return line[:i].strip()
    return line.strip()


def _fields(type_name: str, text: str) -> List[dict]:
    """Fields of a ``.msg`` text as type-description dicts (constants skipped)."""
    package = type_name.split("/")[0]
    fields: List[dict] = []
    for raw in text.splitlines():
        code = _strip_comment(raw)
        if not code:
            continue
        match = _FIELD.match(code)
        if match is None:
            raise ValueError(f"{type_name}: cannot parse the line {raw.strip()!r}")
        if match.group("rest").lstrip().startswith("="):
            continue  # constant: NAME=VALUE
        base, strcap, arr = match.group("type"), match.group("strcap"), match.group("arr")
        nested = ""
        string_capacity = 0
        if base in _PRIMITIVE_TYPES:
            key = base
            if strcap is not None:
                key = "bounded_" + base
                string_capacity = int(strcap)
        else:
            key = "nested"
            nested = normalize_type_name(base if "/" in base else f"{package}/{base}")
        type_id = _BASE_TYPE_ID[key]
        capacity = 0
        if arr is not None:
            if arr == "":
                type_id += _UNBOUNDED_SEQUENCE
            elif arr.startswith("<="):
                type_id += _BOUNDED_SEQUENCE
                capacity = int(arr[2:])
            else:
                type_id += _ARRAY
                capacity = int(arr)
        fields.append({
            "name": match.group("name"),
            "type": {"type_id": type_id, "capacity": capacity,
                     "string_capacity": string_capacity, "nested_type_name": nested},
        })
    if not fields:  # rosidl adds a placeholder member to empty structures
        fields.append({"name": "structure_needs_at_least_one_member",
                       "type": {"type_id": 3, "capacity": 0, "string_capacity": 0,
                                "nested_type_name": ""}})
    return fields


def type_description(type_name: str, extra_definitions: Optional[Mapping[str, str]] = None) -> dict:
    """The hashable type description of ``type_name`` (REP 2011, without default values).

    ``{"type_description": {"type_name", "fields"}, "referenced_type_descriptions": [...]}``
    with the referenced types sorted by name, as ``rosidl_generator_type_description``
    builds it.
    """
    root = normalize_type_name(type_name)
    described: Dict[str, dict] = {}
    todo = [root]
    while todo:
        name = todo.pop()
        if name in described:
            continue
        if len(described) > 10 * MAX_DEPTH:
            raise RecursionError(f"type description of {root} references too many types")
        fields = _fields(name, definition(name, extra_definitions))
        described[name] = {"type_name": name, "fields": fields}
        todo.extend(f["type"]["nested_type_name"] for f in fields if f["type"]["nested_type_name"])
    return {
        "type_description": described[root],
        "referenced_type_descriptions": [described[n] for n in sorted(described) if n != root],
    }


def hash_type_description(description: Mapping) -> str:
    """``RIHS01_`` + sha256 of the JSON of a hashable type description."""
    text = json.dumps(description, ensure_ascii=True, allow_nan=False, indent=None,
                      separators=(", ", ": "), sort_keys=False)
    return "RIHS01_" + hashlib.sha256(text.encode("utf-8")).hexdigest()


def type_hash(type_name: str, extra_definitions: Optional[Mapping[str, str]] = None) -> str:
    """Return the ``RIHS01_...`` hash of ``type_name``, or ``""`` if its definition is unknown."""
    try:
        key = tuple(sorted((extra_definitions or {}).items()))
        return _type_hash_cached(normalize_type_name(type_name), key, tuple(share_directories()))
    except (ValueError, UnknownMessageTypeError, RecursionError):
        return ""


@lru_cache(maxsize=512)
def _type_hash_cached(full_name: str, extra: Tuple[Tuple[str, str], ...], _shares: Tuple[str, ...]) -> str:
    return hash_type_description(type_description(full_name, dict(extra)))
