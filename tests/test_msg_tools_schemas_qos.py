"""Schema texts and rosbag2 QoS YAML of msg_tools (no ROS needed)."""

import pytest
import yaml

from msg_tools import schemas
from msg_tools.errors import UnknownMessageTypeError
from msg_tools.qos import (
    INFINITE,
    PRESETS,
    QosProfile,
    offered_qos_yaml,
    parse_offered_qos_yaml,
    preset,
)

# Field lines of the Jazzy definitions (comments stripped), written out here
# independently of msg_tools.schemas.
FIELD_LINES = {
    "std_msgs/msg/Float64": ["float64 data"],
    "std_msgs/msg/String": ["string data"],
    "builtin_interfaces/msg/Time": ["int32 sec", "uint32 nanosec"],
    "std_msgs/msg/Header": ["builtin_interfaces/Time stamp", "string frame_id"],
    "sensor_msgs/msg/JointState": [
        "std_msgs/Header header",
        "string[] name",
        "float64[] position",
        "float64[] velocity",
        "float64[] effort",
    ],
    "rosgraph_msgs/msg/Clock": ["builtin_interfaces/Time clock"],
    "diagnostic_msgs/msg/KeyValue": ["string key", "string value"],
    "diagnostic_msgs/msg/DiagnosticStatus": [
        "byte OK=0",
        "byte WARN=1",
        "byte ERROR=2",
        "byte STALE=3",
        "byte level",
        "string name",
        "string message",
        "string hardware_id",
        "KeyValue[] values",
    ],
    "diagnostic_msgs/msg/DiagnosticArray": [
        "std_msgs/Header header",
        "DiagnosticStatus[] status",
    ],
}


def _fields(text):
    out = []
    for line in text.splitlines():
        code = line.split("#", 1)[0].strip()
        if code:
            out.append(code)
    return out


@pytest.mark.parametrize("type_name", sorted(FIELD_LINES))
def test_field_lines_match_jazzy(type_name):
    assert _fields(schemas.MESSAGE_DEFINITIONS[type_name]) == FIELD_LINES[type_name]


def test_joint_state_schema_concatenation_rule():
    parts = schemas.split_schema(schemas.schema_text("sensor_msgs/msg/JointState"))
    # dependencies named as the field names them (rosbag2 Jazzy; Foxglove needs exactly this)
    assert [name for name, _ in parts] == [
        "",
        "std_msgs/Header",
        "builtin_interfaces/Time",
    ]
    assert _fields(parts[0][1]) == FIELD_LINES["sensor_msgs/msg/JointState"]
    assert _fields(parts[2][1]) == FIELD_LINES["builtin_interfaces/msg/Time"]
    text = schemas.schema_text("sensor_msgs/msg/JointState")
    assert "\n" + "=" * 80 + "\nMSG: std_msgs/Header\n" in text
    assert "MSG: std_msgs/msg/" not in text
    assert "=" * 81 not in text


def test_diagnostic_array_dependencies_depth_first_each_once():
    names = [n for n, _ in schemas.split_schema(schemas.schema_text("diagnostic_msgs/DiagnosticArray"))]
    # sorted dependencies, depth first, as rosbag2's LocalMessageDefinitionSource
    # (a field type without package, "KeyValue", gets the enclosing package)
    assert names == [
        "",
        "diagnostic_msgs/DiagnosticStatus",
        "diagnostic_msgs/KeyValue",
        "std_msgs/Header",
        "builtin_interfaces/Time",
    ]


def test_schema_without_dependencies_is_the_msg_text():
    assert schemas.schema_text("std_msgs/msg/Float64") == schemas.MESSAGE_DEFINITIONS[
        "std_msgs/msg/Float64"
    ]


def test_schema_parses_with_mcap_ros2():
    from msg_tools._cdr import decoder_for

    for type_name in schemas.known_types():
        assert callable(decoder_for(type_name, schemas.schema_text(type_name)))


def test_unknown_type_error_names_type_and_known_ones():
    with pytest.raises(UnknownMessageTypeError) as info:
        schemas.schema_text("foo_msgs/msg/Bar")
    text = str(info.value)
    assert "foo_msgs/msg/Bar" in text
    assert "std_msgs/msg/Float64" in text and "sensor_msgs/msg/JointState" in text
    assert "\n" not in text
    assert isinstance(info.value, KeyError)


def test_type_hash_known_and_unknown():
    assert schemas.type_hash("std_msgs/Float64").startswith("RIHS01_")
    assert len(schemas.type_hash("std_msgs/msg/Float64")) == len("RIHS01_") + 64
    assert schemas.type_hash("foo_msgs/msg/Bar") == ""


def test_without_ros_the_built_in_definitions_serve(monkeypatch, tmp_path):
    """No ROS install on the search path: msg_tools' own types still get their schemas and hashes."""
    monkeypatch.setenv("AMENT_PREFIX_PATH", "")
    monkeypatch.setattr(schemas.sys, "prefix", str(tmp_path))
    assert schemas.share_directories() == [str(tmp_path / "share")]
    for type_name in schemas.known_types():
        assert schemas.installed_definition(type_name) is None
        text = schemas.schema_text(type_name)
        assert text.startswith(schemas.MESSAGE_DEFINITIONS[type_name])
        assert schemas.type_hash(type_name).startswith("RIHS01_")
    assert schemas.type_hash("geometry_msgs/msg/Twist") == ""


def test_registered_definitions_win_and_hash_changes_with_the_text():
    extra = {"foo_msgs/msg/Bar": "float64 x\nfloat64[<=3] y\nstring<=8 s\n"}
    text = schemas.schema_text("foo_msgs/msg/Bar", extra)
    assert text == extra["foo_msgs/msg/Bar"]
    h1 = schemas.type_hash("foo_msgs/msg/Bar", extra)
    h2 = schemas.type_hash("foo_msgs/msg/Bar", {"foo_msgs/msg/Bar": "float64 x\n"})
    assert h1.startswith("RIHS01_") and h2.startswith("RIHS01_") and h1 != h2
    # comments and default values do not change the hash (REP 2011)
    h3 = schemas.type_hash("foo_msgs/msg/Bar", {"foo_msgs/msg/Bar": "# note\nfloat64 x 1.5 # default\n"})
    assert h3 == h2


def test_invalid_type_name_rejected():
    with pytest.raises(ValueError, match="pkg/msg/Type"):
        schemas.normalize_type_name("Float64")


# ----------------------------------------------------------------------- QoS
EXPECTED_RELIABLE_10 = """\
- history: keep_last
  depth: 10
  reliability: reliable
  durability: volatile
  deadline:
    sec: 9223372036
    nsec: 854775807
  lifespan:
    sec: 9223372036
    nsec: 854775807
  liveliness: automatic
  liveliness_lease_duration:
    sec: 9223372036
    nsec: 854775807
  avoid_ros_namespace_conventions: false"""


def test_reliable_yaml_is_exact_jazzy_layout():
    assert offered_qos_yaml("reliable") == EXPECTED_RELIABLE_10
    assert offered_qos_yaml(None) == EXPECTED_RELIABLE_10


@pytest.mark.parametrize(
    "name, history, depth, reliability, durability",
    [
        ("reliable", "keep_last", 10, "reliable", "volatile"),
        ("clock", "keep_last", 1, "best_effort", "volatile"),
        ("diagnostics", "keep_last", 10, "reliable", "volatile"),
        ("transient_local", "keep_last", 1, "reliable", "transient_local"),
        ("sensor_data", "keep_last", 5, "best_effort", "volatile"),
    ],
)
def test_presets_parse_back(name, history, depth, reliability, durability):
    data = yaml.safe_load(offered_qos_yaml(name))
    assert isinstance(data, list) and len(data) == 1
    item = data[0]
    assert list(item) == [
        "history", "depth", "reliability", "durability", "deadline", "lifespan",
        "liveliness", "liveliness_lease_duration", "avoid_ros_namespace_conventions",
    ]
    assert (item["history"], item["depth"], item["reliability"], item["durability"]) == (
        history, depth, reliability, durability,
    )
    assert item["deadline"] == {"sec": INFINITE[0], "nsec": INFINITE[1]}
    assert parse_offered_qos_yaml(offered_qos_yaml(name)) == [PRESETS[name]]


def test_keep_last_depth_and_list_of_publishers():
    text = offered_qos_yaml([preset("reliable", depth=3), "transient_local"])
    data = yaml.safe_load(text)
    assert [d["depth"] for d in data] == [3, 1]
    assert [d["durability"] for d in data] == ["volatile", "transient_local"]
    assert offered_qos_yaml([]) == "[]"


def test_parse_integer_enums_of_humble_bags():
    humble = (
        "- history: 1\n  depth: 7\n  reliability: 2\n  durability: 1\n"
        "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
        "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
        "  avoid_ros_namespace_conventions: false"
    )
    (profile,) = parse_offered_qos_yaml(humble)
    assert profile == QosProfile(
        depth=7, reliability="best_effort", durability="transient_local",
        deadline=(0, 0), lifespan=(0, 0), liveliness_lease_duration=(0, 0),
    )


def test_from_rclpy_duck_typed():
    class Policy:
        def __init__(self, name):
            self.name = name

    class Duration:
        def __init__(self, ns):
            self.nanoseconds = ns

    class Fake:
        history = Policy("KEEP_LAST")
        depth = 4
        reliability = Policy("BEST_EFFORT")
        durability = Policy("TRANSIENT_LOCAL")
        deadline = Duration(0)
        lifespan = Duration(1_500_000_000)
        liveliness = Policy("AUTOMATIC")
        liveliness_lease_duration = Duration(0)
        avoid_ros_namespace_conventions = False

    profile = QosProfile.from_rclpy(Fake())
    assert profile.depth == 4 and profile.reliability == "best_effort"
    assert profile.durability == "transient_local"
    assert profile.deadline == INFINITE and profile.lifespan == (1, 500_000_000)


def test_bad_qos_values_name_the_policy():
    with pytest.raises(ValueError, match="reliability"):
        QosProfile(reliability="sometimes")
    with pytest.raises(ValueError, match="presets"):
        preset("latched")
