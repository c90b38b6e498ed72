"""msg_tools against real ROS 2 (Jazzy) serialization: rclpy bytes vs mcap_ros2.

Only rclpy.serialization is used (no rclpy.init), so no DDS traffic is made;
the ROS_* variables keep any later discovery on this machine anyway.
rclpy leaves CDR alignment padding and a few trailing bytes uninitialised, so
JointState bytes are compared outside padding and values after decoding.
"""

import io
import json
import os
import struct
import sys

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", "57")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from ament_index_python.packages import get_package_share_directory  # noqa: E402
from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from msg_tools import Ros2McapWriter, read_topic  # noqa: E402
from msg_tools import schemas  # noqa: E402
from msg_tools.decode import joint_layout  # noqa: E402
from msg_tools.writer import encode  # noqa: E402
from msg_tools._cdr import decoder_for  # noqa: E402

pytestmark = pytest.mark.ros

RNG = np.random.default_rng(7)


def _decode(type_name, data):
    return decoder_for(type_name, schemas.schema_text(type_name))(data)


def _non_padding_mask(data: bytes) -> np.ndarray:
    """Bytes of a JointState that carry values (not alignment padding)."""
    layout = joint_layout(data)
    mask = layout.meaningful.copy()
    mask[4:12] = True  # stamp
    for offset, count in layout.arrays.values():
        mask[offset : offset + 8 * count] = True
    return mask


@pytest.mark.parametrize("value", [0.0, -0.0, 1.5, -273.15, 1e-300, np.pi * 1e12, float("inf")])
def test_float64_bytes_identical(value):
    ros = bytes(serialize_message(Float64(data=value)))
    ours = encode("std_msgs/msg/Float64", {"data": value})
    assert ros == ours == b"\x00\x01\x00\x00" + struct.pack("<d", value)
    assert deserialize_message(ours, Float64).data == value or np.isnan(value)


def _ros_joint_state(i, names, with_effort=True):
    msg = JointState()
    msg.header.stamp = Time(sec=1_700_000_000 + i, nanosec=123_456_789)
    msg.header.frame_id = "ab"  # 3 bytes with NUL -> 1 padding byte follows
    msg.name = list(names)
    msg.position = RNG.normal(size=len(names)).tolist()
    msg.velocity = RNG.normal(scale=100, size=len(names)).tolist()
    msg.effort = RNG.normal(size=len(names)).tolist() if with_effort else []
    return msg


def _as_dict(msg):
    return {
        "header": {"stamp": {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec},
                   "frame_id": msg.header.frame_id},
        "name": list(msg.name),
        "position": list(msg.position),
        "velocity": list(msg.velocity),
        "effort": list(msg.effort),
    }


@pytest.mark.parametrize("names, with_effort", [(["crank", "alt", "wp"], True), (["a", "bcd"], False)])
def test_joint_state_rclpy_and_mcap_ros2_agree(names, with_effort):
    msg = _ros_joint_state(0, names, with_effort)
    ros = bytes(serialize_message(msg))
    ours = encode("sensor_msgs/msg/JointState", _as_dict(msg))
    # same bytes wherever there is a value (padding may differ)
    assert len(ros) >= len(ours)
    mask = _non_padding_mask(ours)
    np.testing.assert_array_equal(np.frombuffer(ros[: len(ours)], np.uint8)[mask],
                                  np.frombuffer(ours, np.uint8)[mask])
    # mcap_ros2 decodes rclpy bytes ...
    decoded = _decode("sensor_msgs/msg/JointState", ros)
    assert list(decoded.name) == names
    assert list(decoded.position) == list(msg.position)
    assert list(decoded.effort) == list(msg.effort)
    assert decoded.header.stamp.sec == msg.header.stamp.sec
    # ... and rclpy deserializes mcap_ros2 bytes
    back = deserialize_message(ours, JointState)
    assert list(back.name) == names and back.header.frame_id == "ab"
    assert list(back.velocity) == list(msg.velocity) and list(back.effort) == list(msg.effort)
    assert back.header.stamp.nanosec == 123_456_789


def test_reader_decodes_rclpy_bytes_vectorized():
    names = ["crank", "alternator", "water_pump"]
    msgs = [_ros_joint_state(i, names) for i in range(300)]
    buf = io.BytesIO()
    with Ros2McapWriter(buf) as w:
        for i, m in enumerate(msgs):
            t = i * 1_000_000
            w.write_raw("/joint_states", "sensor_msgs/msg/JointState", serialize_message(m), t)
            w.write_raw("/drive_torque", "std_msgs/msg/Float64",
                        serialize_message(Float64(data=float(i) / 7)), t)
    js = read_topic(buf.getvalue(), "/joint_states")
    assert js.decoder == "vectorized" and js.names == names
    np.testing.assert_array_equal(js.position, [list(m.position) for m in msgs])
    np.testing.assert_array_equal(js.velocity, [list(m.velocity) for m in msgs])
    np.testing.assert_array_equal(js.effort, [list(m.effort) for m in msgs])
    np.testing.assert_array_equal(
        js.stamp_ns, [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs])
    torque = read_topic(buf.getvalue(), "/drive_torque")
    np.testing.assert_array_equal(torque.data, np.arange(300) / 7)


def test_clock_and_diagnostics_round_trip_both_ways():
    clock = Clock(clock=Time(sec=12, nanosec=345))
    assert bytes(serialize_message(clock)) == encode(
        "rosgraph_msgs/msg/Clock", {"clock": {"sec": 12, "nanosec": 345}})
    diag = DiagnosticArray()
    diag.header.stamp = Time(sec=3)
    diag.status = [DiagnosticStatus(level=DiagnosticStatus.WARN, name="belt", message="slip",
                                    hardware_id="sim", values=[KeyValue(key="slip", value="0.02")])]
    decoded = _decode("diagnostic_msgs/msg/DiagnosticArray", bytes(serialize_message(diag)))
    assert decoded.status[0].values[0].value == "0.02" and decoded.status[0].level == 1
    ours = encode("diagnostic_msgs/msg/DiagnosticArray", {
        "header": {"stamp": {"sec": 3}},
        "status": [{"level": 1, "name": "belt", "message": "slip", "hardware_id": "sim",
                    "values": [{"key": "slip", "value": "0.02"}]}],
    })
    back = deserialize_message(ours, DiagnosticArray)
    assert back.status[0].level == DiagnosticStatus.WARN and back.status[0].values[0].key == "slip"


def _share(package):
    try:
        return get_package_share_directory(package)
    except (OSError, LookupError):  # pip-installed ROS wheels: no AMENT_PREFIX_PATH
        return os.path.join(sys.prefix, "share", package)


# tf2_msgs has no wheel on PyPI (nothing to read its .msg files from here): its definition and type hash are
# checked against rosbags' Jazzy type store in tests/test_tf.py.
@pytest.mark.parametrize("type_name", [t for t in schemas.known_types() if not t.startswith("tf2_msgs/")])
def test_built_in_definitions_are_the_installed_jazzy_ones(type_name):
    package, _, name = type_name.split("/")
    with open(os.path.join(_share(package), "msg", name + ".msg"), encoding="utf-8") as f:
        assert schemas.MESSAGE_DEFINITIONS[type_name] == f.read()


HASHED_PACKAGES = ("builtin_interfaces", "std_msgs", "sensor_msgs", "diagnostic_msgs", "geometry_msgs",
                   "rosgraph_msgs", "rcl_interfaces", "lifecycle_msgs", "action_msgs")


@pytest.mark.parametrize("package", HASHED_PACKAGES)
def test_computed_type_hashes_equal_the_ones_rosidl_generated(package):
    """RIHS01 hashes computed from the .msg texts equal the ones rosidl shipped (share/<pkg>/msg/*.json)."""
    import glob

    files = sorted(glob.glob(os.path.join(_share(package), "msg", "*.json")))
    assert files, f"no type description files of {package}"
    for path in files:
        with open(path, encoding="utf-8") as f:
            shipped = json.load(f)["type_hashes"]
        for entry in shipped:  # the type itself and every type it references
            assert schemas.type_hash(entry["type_name"]) == entry["hash_string"], entry["type_name"]


def test_computed_type_hash_equals_the_one_discovery_reports():
    """The hash rclpy's discovery reports for a publisher's type (what a live recording stores) is ours."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Twist
    from rcl_interfaces.msg import Log
    from rclpy.context import Context
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from belt_drive_ros.ros.environment import process_domain_id

    types = {"/t_float": (Float64, "std_msgs/msg/Float64"),
             "/t_joint": (JointState, "sensor_msgs/msg/JointState"),
             "/t_diag": (DiagnosticArray, "diagnostic_msgs/msg/DiagnosticArray"),
             "/t_twist": (Twist, "geometry_msgs/msg/Twist"),
             "/t_log": (Log, "rcl_interfaces/msg/Log")}
    context = Context()
    rclpy.init(context=context, domain_id=process_domain_id(offset=71))
    try:
        node = rclpy.create_node("hash_probe", context=context)
        for topic, (cls, _) in types.items():
            node.create_publisher(cls, topic, 1)
        for topic, (_, name) in types.items():
            infos = node.get_publishers_info_by_topic(topic)
            assert len(infos) == 1
            assert str(infos[0].topic_type_hash) == schemas.type_hash(name), name
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
