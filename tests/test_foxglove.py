"""Foxglove decodes every message of the project's recordings (issue: Foxglove could not decode
``/joint_states`` or ``/diagnostics``).

Foxglove's own open-source parser stack, pinned in ``tests/foxglove/package.json`` and its lock
file (``@mcap/core`` reads the file through its summary, ``@foxglove/rosmsg`` parses each
channel's ``ros2msg`` schema, ``@foxglove/rosmsg2-serialization`` decodes the CDR), runs under
the system ``node`` (``make install`` runs ``npm ci`` there). Three kinds of file: an offline run,
a node recording (with ``/diagnostics``), and a ``belt-drive record`` file of topics outside the
node's own (``geometry_msgs/Twist``, ``rcl_interfaces/Log``). For every topic: no decode error,
as many messages as the file's summary counts, and the first and last decoded values equal
msg_tools' own decode. Every channel carries the type hash of its type. Offline runs and node
recordings start with ``/robot_description`` (the drive's URDF, what Foxglove's 3D panel reads):
Foxglove decodes it to the very URDF of the scene's parameters.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from msg_tools import read_bag, schemas

FOXGLOVE_DIR = Path(__file__).parent / "foxglove"


def foxglove_decode(*paths) -> dict:
    node = shutil.which("node")
    assert node, "the system 'node' (v18+) is needed for the Foxglove check; install nodejs"
    assert (FOXGLOVE_DIR / "node_modules" / "@foxglove" / "rosmsg").is_dir(), (
        "Foxglove packages missing: run 'make install' (npm ci --prefix tests/foxglove)")
    proc = subprocess.run([node, str(FOXGLOVE_DIR / "decode.mjs"), *map(str, paths)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)


def check_file(path: Path, result: dict) -> dict:
    """Assert Foxglove decoded every message of ``path`` as msg_tools does; return counts per topic."""
    assert result["mode"] == "indexed", result.get("indexedError")
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    per_channel = summary.statistics.channel_message_counts
    expected = {}
    for cid, channel in summary.channels.items():
        expected[channel.topic] = expected.get(channel.topic, 0) + per_channel.get(cid, 0)
        type_name = summary.schemas[channel.schema_id].name
        assert channel.metadata["topic_type_hash"] == schemas.type_hash(type_name), channel.topic
    assert result["summaryMessageCount"] == summary.statistics.message_count
    bag = read_bag(path)
    counts = {}
    for topic, state in result["topics"].items():
        assert state["errors"] == 0, f"{path.name} {topic}: {state['firstError']}"
        assert state["count"] == expected[topic] > 0, (topic, state["count"], expected[topic])
        counts[topic] = state["count"]
        data = bag.topics[topic]
        if data.type_name == "std_msgs/msg/Float64":
            assert state["first"] == [data.data[0]] and state["last"] == [data.data[-1]], topic
        elif data.type_name == "std_msgs/msg/String":
            assert state["first"] == [data.messages[0].data] and state["last"] == [data.messages[-1].data], topic
        elif data.type_name == "sensor_msgs/msg/JointState":
            for k, row in ((0, state["first"]), (-1, state["last"])):
                sec, nanosec = divmod(int(data.stamp_ns[k]), 1_000_000_000)
                ours = [sec, nanosec, *data.position[k], *data.velocity[k], *data.effort[k]]
                assert row == ours  # stamp and values bit for bit
        elif data.type_name == "tf2_msgs/msg/TFMessage":
            for k, row in ((0, state["first"]), (-1, state["last"])):
                ours = []
                for t in data.messages[k].transforms:
                    tr, rot = t.transform.translation, t.transform.rotation
                    ours += [t.header.stamp.sec, t.header.stamp.nanosec, t.header.frame_id, t.child_frame_id,
                             tr.x, tr.y, tr.z, rot.x, rot.y, rot.z, rot.w]
                assert row == ours and len(row) == 4 * 11, topic  # every wheel, bit for bit
    return counts


def check_tf_moves_the_urdf(path, params):
    """The /tf of ``path`` is the URDF's joints at the recorded angles: parent base_link, child
    ``<joint>_link``, translation the joint origin, rotation the angle of joint_states about the
    joint axis, stamped as joint_states (the 3D panel's transform tree)."""
    import xml.etree.ElementTree as ET

    import numpy as np

    from belt_drive_ros.io.urdf import urdf_from_params

    bag = read_bag(path)
    js, tf = bag.topics["/joint_states"], bag.topics["/tf"]
    assert len(tf.messages) == js.stamp_ns.size > 0
    np.testing.assert_array_equal(tf.log_time_ns, js.log_time_ns)
    joints = {j.get("name"): j for j in ET.fromstring(urdf_from_params(params)).findall("joint")}
    for k in (0, js.stamp_ns.size // 2, -1):
        transforms = tf.messages[k].transforms
        assert [t.child_frame_id for t in transforms] == [joints[n].find("child").get("link") for n in js.names]
        for j, (name, t) in enumerate(zip(js.names, transforms)):
            joint = joints[name]
            assert t.header.frame_id == joint.find("parent").get("link") == "base_link"
            assert t.header.stamp.sec * 1_000_000_000 + t.header.stamp.nanosec == js.stamp_ns[k]
            origin = [float(v) for v in joint.find("origin").get("xyz").split()]
            np.testing.assert_allclose([t.transform.translation.x, t.transform.translation.y,
                                        t.transform.translation.z], origin, rtol=1e-11, atol=0)  # URDF: 12 digits
            axis = np.array([float(v) for v in joint.find("axis").get("xyz").split()])
            q, angle = t.transform.rotation, js.position[k, j]
            np.testing.assert_allclose([q.x, q.y, q.z, q.w], [*(axis * np.sin(angle / 2)), np.cos(angle / 2)],
                                       rtol=0, atol=1e-15)


def test_offline_run_decodes_in_foxglove(tmp_path):
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.recording import write_result_mcap

    from belt_drive_ros.io.urdf import urdf_from_params

    path = tmp_path / "offline.mcap"
    scene = load_scene("paper").with_overrides(duration=0.3)
    write_result_mcap(simulate(scene), path)
    result = foxglove_decode(path)[str(path)]
    counts = check_file(path, result)
    assert set(counts) == {"/robot_description", "/drive_torque", "/joint_states", "/tf", "/shaft_speed",
                           "/load_torque", "/belt_torque", "/relative_deflection"}
    assert counts["/robot_description"] == 1
    check_tf_moves_the_urdf(path, scene.params)
    assert result["topics"]["/robot_description"]["first"] == [urdf_from_params(scene.params)]
    with open(path, "rb") as f:
        first = next(iter(make_reader(f).iter_messages()))[1]
    assert first.topic == "/robot_description"  # before the first sample


@pytest.mark.ros
def test_node_recording_decodes_in_foxglove(tmp_path, ros_domain_id):
    from belt_drive_ros.ros.harness import BeltDriveHarness

    from belt_drive_ros.io.urdf import urdf_from_params

    path = tmp_path / "node.mcap"
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(path)) as h:
        params = h.node.settings.params
        h.publish_torque(6.0)
        h.advance(1.5)  # diagnostics come once a second
    result = foxglove_decode(path)[str(path)]
    counts = check_file(path, result)
    assert {"/robot_description", "/joint_states", "/tf", "/diagnostics", "/drive_torque", "/shaft_speed"} <= set(counts)
    check_tf_moves_the_urdf(path, params)
    assert result["topics"]["/robot_description"]["first"] == [urdf_from_params(params)]
    with open(path, "rb") as f:
        first = next(iter(make_reader(f).iter_messages()))[1]
    assert first.topic == "/robot_description"  # the file starts with it


@pytest.mark.ros
def test_record_command_file_decodes_in_foxglove(tmp_path, ros_domain_id):
    import rclpy
    from geometry_msgs.msg import Twist
    from rclpy.context import Context
    from std_msgs.msg import Float64

    from belt_drive_ros.ros import environment as ros_env

    path = tmp_path / "record.mcap"
    env = ros_env.child_environment(ros_domain_id)
    cmd = [os.path.join(os.path.dirname(sys.executable), "belt-drive"), "record", "--out", str(path),
           "--topics", "/drive_torque", "/cmd_vel", "/rosout", "--quiet"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    try:
        node = rclpy.create_node("foxglove_probe", context=ctx)
        torque = node.create_publisher(Float64, "/drive_torque", 10)
        twist = node.create_publisher(Twist, "/cmd_vel", 10)
        deadline = time.monotonic() + 30
        while torque.get_subscription_count() < 1 or twist.get_subscription_count() < 1:
            assert time.monotonic() < deadline and proc.poll() is None, "recorder did not subscribe"
            time.sleep(0.05)
        time.sleep(0.3)
        for i in range(50):
            torque.publish(Float64(data=float(i)))
            msg = Twist()
            msg.linear.x, msg.angular.z = 0.1 * i, -0.2 * i
            twist.publish(msg)
            node.get_logger().info(f"sample {i}")
            time.sleep(0.01)
        time.sleep(0.5)
        proc.send_signal(2)
        assert proc.wait(timeout=30) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
        rclpy.try_shutdown(context=ctx)
    result = foxglove_decode(path)[str(path)]
    counts = check_file(path, result)
    assert counts["/drive_torque"] == 50 and counts["/cmd_vel"] == 50 and counts["/rosout"] >= 50
    assert result["topics"]["/cmd_vel"]["schema"] == "geometry_msgs/msg/Twist"
