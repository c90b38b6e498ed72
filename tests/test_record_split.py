"""``belt-drive record --max-bag-duration``: a real split of a running node's topics.

The recorder and the node are child processes (the CLI) on a domain private
to this test, Fast DDS over UDP only. The final line's message count, the
folder's ``metadata.yaml``, the mcap library and rosbags agree, and every
file starts with the node's ``robot_description`` (the last file used to be
counted twice; the URDF was only in the first file).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys

import pytest

from belt_drive_ros.ros import environment as ros_env

from test_node_recording import check_split_folder
from test_node_shutdown import Child

pytestmark = pytest.mark.ros

CLI = [sys.executable, "-m", "belt_drive_ros.cli"]


def test_split_recording_counts_equal_its_metadata_and_every_file_has_the_urdf(tmp_path):
    domain = ros_env.process_domain_id(offset=71)
    node = Child([], tmp_path / "node.mcap", domain)
    try:
        node.wait_for("spinning with the")
        folder = tmp_path / "rf"
        record = subprocess.run(
            CLI + ["record", "--out", str(folder), "--max-bag-duration", "1", "--duration", "6",
                   "--topics", "/robot_description", "/shaft_speed", "/joint_states"],
            env=ros_env.child_environment(domain), capture_output=True, text=True, timeout=120,
        )
    finally:
        rc, _ = node.stop(signal.SIGINT, within=30.0)
        node.kill()
    assert record.returncode == 0, record.stderr[-3000:]
    assert rc == 0
    printed = re.search(r"wrote .*: (\d+) messages on 3 topics", record.stdout)
    assert printed, record.stdout
    check_split_folder(folder, "/robot_description", printed_total=int(printed.group(1)),
                       first_at_start=False)
