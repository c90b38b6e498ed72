"""The shipped Foxglove layout reads topics our recordings have, in the root namespace and, after the
documented rewrite (docs/foxglove/README.md), in a node's namespace."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from msg_tools import summary

DOCS = Path(__file__).resolve().parents[1] / "docs" / "foxglove"


def layout_topics(layout: dict) -> set:
    """Every topic a panel reads: URDF and joint-state topics, and the topic of each plotted message path
    (the 3D panel's "publish" tool topics are what it would send, not read)."""
    found = set()

    def walk(value, key=""):
        if isinstance(value, dict):
            for k, v in value.items():
                if k != "publish":
                    walk(v, k)
        elif isinstance(value, list):
            for v in value:
                walk(v, key)
        elif isinstance(value, str) and value.startswith("/"):
            if key in ("topic", "jointStatesTopic"):
                found.add(value)
            elif key == "value":  # a message path: /topic.field...
                found.add(value.split(".", 1)[0])

    walk(layout)
    return found


def offline_recording(path, namespace):
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.recording import write_result_mcap

    run = simulate(load_scene("truck_compressor").with_overrides(duration=0.05), model="slipping")
    write_result_mcap(run, path, namespace=namespace, start_time_ns=0)
    return {t.topic for t in summary(path).topics}


def test_layout_topics_exist_in_a_recording_and_move_with_the_documented_namespace(tmp_path):
    layout = json.loads((DOCS / "belt_drive_layout.json").read_text())
    wanted = layout_topics(layout)
    assert {"/robot_description", "/joint_states", "/shaft_speed", "/span_force_tight"} <= wanted
    assert wanted <= offline_recording(tmp_path / "root.mcap", "/")

    readme = (DOCS / "README.md").read_text()
    command = re.search(r"^sed -E '(.+)' docs/foxglove/belt_drive_layout\.json > truck1_layout\.json$", readme, re.M)
    assert command, "docs/foxglove/README.md: the namespace rewrite command"
    sed = shutil.which("sed")
    if sed is None:
        pytest.fail("sed is needed to run the documented command")
    out = subprocess.run([sed, "-E", command.group(1), str(DOCS / "belt_drive_layout.json")],
                         capture_output=True, text=True, check=True).stdout
    moved = layout_topics(json.loads(out))
    assert moved == {t if t in ("/tf", "/diagnostics") else "/truck1" + t for t in wanted}
    assert moved <= offline_recording(tmp_path / "truck1.mcap", "/truck1")
