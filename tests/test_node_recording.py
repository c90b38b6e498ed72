"""The node records itself when given ``record_path`` (issue 4 wired into issue 3's node).

Checked with the independent ``mcap`` reader (not project code) and against
the outputs the harness received; a runtime change of ``record_path`` is
rejected with a reason, and an existing file is never overwritten.
"""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader

from msg_tools import read_topic

pytestmark = pytest.mark.ros


def test_node_records_its_run_when_given_record_path(tmp_path, ros_domain_id):
    from belt_drive_ros.ros.harness import BeltDriveHarness

    bag = tmp_path / "run.mcap"
    with BeltDriveHarness(scene="paper", model="flexible", method="exact", domain_id=ros_domain_id,
                          record_path=str(bag)) as h:  # fmt: skip
        h.publish_torque(6.0)
        h.advance(0.2)
        rejected = h.set_parameters(record_path=str(tmp_path / "elsewhere.mcap"))
        assert not rejected.successful and "record_path" in rejected.reason
        h.advance(0.1)
        out = h.outputs()
        recording = h.diagnostics()["simulation"]["values"]["recording"]
        assert "recording" in recording and str(bag) in recording
    # finalized on close: an independent reader sees a complete ros2 bag with a summary
    with open(bag, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 0
        topics = {c.topic for c in summary.channels.values()}
        assert {"/shaft_speed", "/relative_deflection", "/joint_states", "/drive_torque"} <= topics
        assert all("offered_qos_profiles" in c.metadata for c in summary.channels.values())
        names = {m.name for m in reader.iter_metadata()}
        assert "rosbag2" in names
    # what was recorded is what the harness received (decoded values, not bytes: CDR padding)
    speed = read_topic(bag, "/shaft_speed").data
    n = min(speed.size, out["shaft_speed"].size)
    assert n > 250
    np.testing.assert_array_equal(speed[-n:], out["shaft_speed"][-n:])
    assert np.all(np.isfinite(speed))


def test_existing_record_path_is_not_overwritten(tmp_path, ros_domain_id):
    from belt_drive_ros.ros.harness import BeltDriveHarness

    bag = tmp_path / "keep.mcap"
    bag.write_bytes(b"precious")
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(bag)) as h:
        h.advance(0.01)
        assert h.diagnostics()["simulation"]["values"]["recording"] == "off"
    assert bag.read_bytes() == b"precious"
