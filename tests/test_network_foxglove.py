"""A belt network's MCAP decodes in Foxglove's own parser stack, and its /tf turns the layout's URDF.

Foxglove (tests/foxglove/decode.mjs: @mcap/core, @foxglove/rosmsg, @foxglove/rosmsg2-serialization)
decodes every message of ``belt-drive sim fead_i4 --out x.mcap`` without error, as many as the
summary counts, the first and last values equal to msg_tools' decode. The /tf transforms are the
URDF's joints (parent link, child link, origin) rotated by the recorded joint angle about the
joint axis: the 3D panel's transform tree moves the pulleys and swings the arm.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
from mcap.reader import make_reader
from msg_tools import read_bag
from test_foxglove import foxglove_decode


def test_network_run_decodes_in_foxglove_and_its_tf_moves_the_urdf(tmp_path):
    from belt_drive_ros.cli import main
    from belt_drive_ros.io.scenes import load_network
    from belt_drive_ros.io.network_bag import NetworkLayout

    path = tmp_path / "fead.mcap"
    assert main(["sim", "fead_i4", "--duration", "0.02", "--out", str(path)]) == 0
    result = foxglove_decode(path)[str(path)]
    assert result["mode"] == "indexed"
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    expected = {}
    for cid, channel in summary.channels.items():
        expected[channel.topic] = summary.statistics.channel_message_counts.get(cid, 0)
    bag = read_bag(path)
    assert set(result["topics"]) == set(expected) and "/alternator/speed" in expected
    for topic, state in result["topics"].items():
        assert state["errors"] == 0 and state["count"] == expected[topic] > 0, topic
        data = bag.topics[topic]
        if data.type_name == "std_msgs/msg/Float64":
            assert state["first"] == [data.data[0]] and state["last"] == [data.data[-1]], topic
    scene = load_network("fead_i4")
    urdf = NetworkLayout(scene).urdf()
    assert result["topics"]["/robot_description"]["first"] == [urdf]
    joints = {j.get("name"): j for j in ET.fromstring(urdf).findall("joint")}
    js, tf = bag.topics["/joint_states"], bag.topics["/tf"]
    assert list(js.names) == [p.name for p in scene.pulleys] + ["tensioner_arm"]
    for k in (0, -1):
        for j, (name, t) in enumerate(zip(js.names, tf.messages[k].transforms)):
            joint = joints[name]
            assert t.child_frame_id == joint.find("child").get("link")
            assert t.header.frame_id == joint.find("parent").get("link")
            origin = [float(v) for v in joint.find("origin").get("xyz").split()]
            np.testing.assert_allclose([t.transform.translation.x, t.transform.translation.y, 0.0], origin,
                                       rtol=1e-11, atol=1e-15)
            axis = np.array([float(v) for v in joint.find("axis").get("xyz").split()])
            q, angle = t.transform.rotation, js.position[k, j]
            np.testing.assert_allclose([q.x, q.y, q.z, q.w], [*(axis * np.sin(angle / 2)), np.cos(angle / 2)],
                                       rtol=0, atol=1e-15)
    assert joints["tensioner"].find("parent").get("link") == "tensioner_arm_link"
    assert np.ptp(js.position[:, -1]) > 0.0  # the arm swings


def test_network_layout_reads_topics_a_network_recording_has(tmp_path):
    import json
    from pathlib import Path

    from msg_tools import summary
    from test_foxglove_layout import layout_topics

    from belt_drive_ros.cli import main

    layout = json.loads((Path(__file__).resolve().parents[1] / "docs" / "foxglove" / "fead_i4_layout.json").read_text())
    wanted = layout_topics(layout)
    assert {"/robot_description", "/joint_states", "/alternator/speed", "/tensioner_arm/angle",
            "/spans/crank_tensioner/tension"} <= wanted
    path = tmp_path / "fead.mcap"
    assert main(["sim", "fead_i4", "--duration", "0.01", "--out", str(path)]) == 0
    assert wanted <= {t.topic for t in summary(path).topics}
