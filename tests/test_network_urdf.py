"""A belt network's URDF, read back by an independent parser (yourdfpy), checked against the scene's geometry."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
import yourdfpy

from belt_drive_ros.core.network.model import arm
from belt_drive_ros.io.scenes import load_network, shipped_networks
from belt_drive_ros.io.network_bag import NetworkLayout


def _load(scene) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(NetworkLayout(scene).urdf()), load_meshes=False, build_scene_graph=True)


@pytest.mark.parametrize("name", shipped_networks())
def test_urdf_names_every_pulley_joint_and_places_it_at_its_centre(name):
    scene = load_network(name)
    urdf = _load(scene)
    pulleys = [p.name for p in scene.pulleys]
    assert set(urdf.actuated_joint_names) == set(pulleys) | ({"tensioner_arm"} if scene.tensioner else set())
    for p in scene.pulleys:
        origin = urdf.get_transform(f"{p.name}_link", "base_link")[:3, 3]
        assert np.allclose(origin[:2], p.centre, atol=1e-12) and origin[2] == 0.0, p.name


def test_arm_joint_swings_the_tensioner_pulley_about_the_pivot():
    scene = load_network("fead_i4")
    urdf = _load(scene)
    t, pivot, length, angle = arm(scene.pulleys, scene.tensioner)
    name = scene.pulleys[t].name
    urdf.update_cfg({"tensioner_arm": 0.1})
    moved = urdf.get_transform(f"{name}_link", "base_link")[:3, 3]
    assert np.allclose(moved[:2], pivot + length * np.array([math.cos(angle + 0.1), math.sin(angle + 0.1)]), atol=1e-12)


def test_belt_spans_are_tangent_to_their_pulleys_and_axes_follow_the_belt():
    """Each span box's centre line lies at distance r from both pulley centres; a pulley's joint axis is the
    sense in which the belt, leaving along the span, turns it (inner face and backside opposite)."""
    scene = load_network("fead_i4")
    root = __import__("xml.etree.ElementTree", fromlist=["x"]).fromstring(NetworkLayout(scene).urdf())
    base = next(link for link in root.findall("link") if link.get("name") == "base_link")
    boxes = base.findall("visual")
    assert len(boxes) == len(scene.pulleys)
    n = len(scene.pulleys)
    for j, visual in enumerate(boxes):
        x, y, _ = (float(v) for v in visual.find("origin").get("xyz").split())
        yaw = float(visual.find("origin").get("rpy").split()[2])
        e = np.array([math.cos(yaw), math.sin(yaw)])
        for p in (scene.pulleys[j], scene.pulleys[(j + 1) % n]):
            d = np.asarray(p.centre) - np.array([x, y])
            assert abs(abs(d[0] * e[1] - d[1] * e[0]) - p.radius) < 1e-9, (j, p.name)
    axes = {j.get("name"): int(j.find("axis").get("xyz").split()[2]) for j in root.findall("joint")}
    sides = {p.name: p.side for p in scene.pulleys}
    crank = axes["crank"]
    for name, side in sides.items():  # the loop runs one way: inner faces turn with the crank, backsides against
        assert axes[name] == (crank if side > 0 else -crank), name


def test_urdf_command_writes_a_network_urdf_and_its_picture(tmp_path):
    from belt_drive_ros.cli import main

    out, png = tmp_path / "f.urdf", tmp_path / "f.png"
    assert main(["urdf", "fead_i4", "--out", str(out), "--png", str(png)]) == 0
    assert yourdfpy.URDF.load(str(out), load_meshes=False).robot.name == "belt_network_fead_i4"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
