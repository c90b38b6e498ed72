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
from msg_tools.reader import _joint_layout  # noqa: E402
from msg_tools.writer import encode  # noqa: E402
from mcap_ros2._dynamic import generate_dynamic  # noqa: E402

pytestmark = pytest.mark.ros

RNG = np.random.default_rng(7)


def _decode(type_name, data):
    return generate_dynamic(type_name, schemas.schema_text(type_name))[type_name](data)


def _non_padding_mask(data: bytes) -> np.ndarray:
    """Bytes of a JointState that carry values (not alignment padding)."""
    layout = _joint_layout(data)
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


@pytest.mark.parametrize("type_name", schemas.known_types())
def test_definitions_and_hashes_are_the_installed_jazzy_ones(type_name):
    package, _, name = type_name.split("/")
    try:
        share = get_package_share_directory(package)
    except (OSError, LookupError):  # pip-installed ROS wheels: no AMENT_PREFIX_PATH
        share = os.path.join(sys.prefix, "share", package)
    with open(os.path.join(share, "msg", name + ".msg"), encoding="utf-8") as f:
        assert schemas.MESSAGE_DEFINITIONS[type_name] == f.read()
    with open(os.path.join(share, "msg", name + ".json"), encoding="utf-8") as f:
        hashes = {h["type_name"]: h["hash_string"] for h in json.load(f)["type_hashes"]}
    assert schemas.TYPE_HASHES[type_name] == hashes[type_name]
