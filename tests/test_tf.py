"""``/tf``: the wheels' transforms as tf2 and Foxglove's 3D panel read them.

``tf2_msgs/msg/TFMessage`` and the geometry_msgs types it uses are written
with their Jazzy ``.msg`` texts and RIHS01 type hashes (checked against
rosbags' own Jazzy type store, an independent implementation); the encoder's
bytes decode with rosbags; the node publishes ``/tf`` where ``tf2_msgs`` is
importable (here it is not: a stand-in module shows the path works) and
records it either way (tests/test_foxglove.py decodes it with Foxglove's
parser and checks it against the URDF).
"""

from __future__ import annotations

import importlib.util
import sys
import types

import numpy as np
import pytest

from msg_tools import encode, schemas

from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.io.recording import TF_MESSAGE, TfEncoder

TF_TYPES = ("tf2_msgs/msg/TFMessage", "geometry_msgs/msg/TransformStamped", "geometry_msgs/msg/Transform",
            "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Quaternion", "std_msgs/msg/Header")


def test_tf_types_have_jazzys_definitions_and_type_hashes():
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    for name in TF_TYPES:
        assert name in schemas.MESSAGE_DEFINITIONS, name  # usable without a ROS installation
        installed = schemas.installed_definition(name)
        if installed is not None:  # the pinned ros-geometry-msgs wheel: byte for byte
            assert schemas.MESSAGE_DEFINITIONS[name] == installed, name
        assert schemas.type_hash(name) == store.hash_rihs01(name), name
    assert schemas.type_hash(TF_MESSAGE) == "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
    text = schemas.schema_text(TF_MESSAGE)
    parts = dict(schemas.split_schema(text))
    assert parts[""] == "geometry_msgs/TransformStamped[] transforms\n\n"
    # dependencies named as the fields write them (rosbag2 Jazzy), every one once
    assert sorted(k for k in parts if k) == ["builtin_interfaces/Time", "geometry_msgs/Quaternion",
                                              "geometry_msgs/Transform", "geometry_msgs/TransformStamped",
                                              "geometry_msgs/Vector3", "std_msgs/Header"]


def test_tf_encoder_gives_the_wheels_rotations_as_rosbags_decodes_them():
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    params = load_scene("truck_compressor").params
    encoder = TfEncoder(params)
    angles = np.array([[0.3, -1.0, 2.0, 7.0], [0.0, 0.0, 0.0, 0.0], [-12.5, 3.1, 100.0, -0.2]])
    stamps = np.array([1_767_225_600_123_456_789, 5, 2_000_000_000])
    many = encoder.encode_many(stamps, angles)
    for stamp, row, data in zip(stamps, angles, many):
        assert data == encoder.encode(int(stamp), row)
        msg = store.deserialize_cdr(data, TF_MESSAGE)
        assert [t.child_frame_id for t in msg.transforms] == ["wheel_M_link", "wheel_1_link", "wheel_2_link",
                                                              "wheel_3_link"]
        for t, angle, sign in zip(msg.transforms, row, (1, -1, 1, 1)):  # the gear mesh reverses wheel 1
            assert t.header.frame_id == "base_link"
            assert t.header.stamp.sec * 1_000_000_000 + t.header.stamp.nanosec == stamp
            q = t.transform.rotation
            assert (q.x, q.y) == (0.0, 0.0)
            assert q.z == sign * np.sin(angle / 2) and q.w == np.cos(angle / 2)
        # byte-identical to the generic encoder given the same message
        assert data == encode(TF_MESSAGE, {"transforms": [
            {"header": {"stamp": {"sec": t.header.stamp.sec, "nanosec": t.header.stamp.nanosec},
                        "frame_id": t.header.frame_id},
             "child_frame_id": t.child_frame_id,
             "transform": {"translation": vars_of(t.transform.translation), "rotation": vars_of(t.transform.rotation)}}
            for t in msg.transforms]})


def vars_of(value):
    return {k: getattr(value, k) for k in ("x", "y", "z", "w") if hasattr(value, k)}


def test_tf_publisher_type_is_tf2_msgs_where_installed(monkeypatch):
    """The node publishes /tf with tf2_msgs' TFMessage where it is importable, and not otherwise."""
    from belt_drive_ros.ros.node import tf_message_type

    if importlib.util.find_spec("tf2_msgs") is None:
        assert tf_message_type() is None
    fake = stand_in_tf2_msgs(monkeypatch)
    assert tf_message_type() is fake


def stand_in_tf2_msgs(monkeypatch):
    """A ``tf2_msgs.msg`` module whose ``TFMessage`` is a registered rclpy type (std_msgs/String):
    a publisher of it sends the node's TFMessage bytes as they are."""
    from std_msgs.msg import String

    package, msg = types.ModuleType("tf2_msgs"), types.ModuleType("tf2_msgs.msg")
    msg.TFMessage = String
    package.msg = msg
    monkeypatch.setitem(sys.modules, "tf2_msgs", package)
    monkeypatch.setitem(sys.modules, "tf2_msgs.msg", msg)
    return String


@pytest.mark.ros
def test_node_publishes_and_records_tf_where_tf2_msgs_is_importable(tmp_path, ros_domain_id, monkeypatch):
    from std_msgs.msg import String

    from msg_tools import read_topic

    from belt_drive_ros.ros.harness import BeltDriveHarness

    stand_in_tf2_msgs(monkeypatch)
    bag = tmp_path / "tf.mcap"
    received = []
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(bag), input_timeout=0.0) as h:
        assert h.node._pub_tf is not None
        h.probe.create_subscription(String, "/tf", received.append, 1000, raw=True)
        h._spin_until(lambda: h.node._pub_tf.get_subscription_count() >= 1, "the /tf subscription")
        h.node.refresh_subscriber_counts()
        h.publish_torque(6.0)
        h.advance(0.05)
        h.spin(0.2)
    recorded = read_topic(bag, "/tf")
    assert len(received) >= 40
    raw = {bytes(m.data if hasattr(m, "data") else m) for m in received}
    with open(bag, "rb") as f:
        from mcap.reader import make_reader

        in_file = [m.data for _, c, m in make_reader(f).iter_messages() if c.topic == "/tf"]
    assert len(in_file) == len(recorded.messages) and raw <= set(in_file)  # the published bytes are the recorded ones
