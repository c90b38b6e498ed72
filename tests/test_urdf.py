"""The drive's URDF: read back by an independent parser (yourdfpy), checked against the geometry.

* joints are the node's JointState names, continuous, parented to base_link;
* gear pairs mesh at their pitch circles (centre distance = sum of pitch radii);
* the belt's centre distance gives the scene's wrap angle (open belt:
  beta = pi - 2 asin(|r_2 - r_3| / D)), and its span visuals are tangent to
  both pulleys;
* joint axes follow the sense of rotation: forward kinematics of yourdfpy at
  the positions a rigid drive would have (phi_1 = (r_M/R_1) phi_M, ...) keeps
  the pitch points of each mesh moving together.
"""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
import yourdfpy

from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.scene import shipped_scenes
from belt_drive_ros.io.urdf import JOINT_NAMES, drive_layout, render_urdf, urdf_from_params


def _load(params) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(urdf_from_params(params)), load_meshes=False, build_scene_graph=True)


def _centre(robot, joint):
    return np.asarray(robot.joint_map[joint].origin)[:2, 3]


@pytest.mark.parametrize("scene", shipped_scenes())
def test_independent_parser_reads_the_joints(scene):
    robot = _load(load_scene(scene).params)
    assert sorted(robot.actuated_joint_names) == sorted(JOINT_NAMES)
    for name in JOINT_NAMES:
        joint = robot.joint_map[name]
        assert joint.type == "continuous"
        assert joint.parent == "base_link"


@pytest.mark.parametrize("scene", shipped_scenes())
def test_meshes_and_belt_match_the_parameters(scene):
    p = load_scene(scene).params
    robot = _load(p)
    d = lambda a, b: float(np.linalg.norm(_centre(robot, a) - _centre(robot, b)))  # noqa: E731
    assert d("wheel_M", "wheel_1") == pytest.approx(p.r_M + p.R_1, rel=1e-5)
    assert d("wheel_1", "wheel_2") == pytest.approx(p.r_1 + p.R_2, rel=1e-5)
    D = d("wheel_2", "wheel_3")
    assert D == pytest.approx(drive_layout(p).belt_centre_distance, rel=1e-5)
    fallback = D == pytest.approx(4 * max(p.r_2, p.r_3), rel=1e-12)
    if not fallback:  # the drawn belt wraps the scene's angle
        wrap = math.pi - 2 * math.asin(abs(p.r_2 - p.r_3) / D)
        assert wrap == pytest.approx(p.wrap_angle, rel=1e-9)
    assert p.r_2 + p.r_3 < D <= 10 * (p.r_2 + p.r_3)
    # each span's end points lie on the pulleys' pitch circles and the span is perpendicular to the radius there
    c2, c3 = _centre(robot, "wheel_2"), _centre(robot, "wheel_3")
    for a, b in drive_layout(p).belt_spans:
        a, b = np.asarray(a), np.asarray(b)
        assert np.linalg.norm(a - c2) == pytest.approx(p.r_2, rel=1e-9)
        assert np.linalg.norm(b - c3) == pytest.approx(p.r_3, rel=1e-9)
        span = (b - a) / np.linalg.norm(b - a)
        assert abs(span @ (a - c2)) < 1e-9 and abs(span @ (b - c3)) < 1e-9


def test_wrap_angle_is_the_scenes_when_pulleys_differ():
    p = load_scene("truck_compressor").params
    assert p.r_2 != p.r_3
    D = drive_layout(p).belt_centre_distance
    assert math.pi - 2 * math.asin(abs(p.r_2 - p.r_3) / D) == pytest.approx(p.wrap_angle, rel=1e-12)


def _pitch_point_velocity(robot, joint, radius, towards, q):
    """Velocity (finite difference, per unit phi_M) of the point of ``joint``'s wheel at ``radius`` facing ``towards``."""
    centre = _centre(robot, joint)
    direction = (towards - centre) / np.linalg.norm(towards - centre)
    local = np.r_[radius * direction, 0.0, 1.0]  # point in the wheel frame at q = 0
    pts = []
    for scale in (0.0, 1e-6):
        robot.update_cfg({k: v * scale for k, v in q.items()})
        T = robot.get_transform(f"{joint}_link", "base_link")
        pts.append((T @ local)[:2])
    return (pts[1] - pts[0]) / 1e-6


def test_joint_axes_turn_meshing_wheels_together():
    p = load_scene("truck_compressor").params
    robot = _load(p)
    g1 = p.r_M / p.R_1
    q = {"wheel_M": 1.0, "wheel_1": g1, "wheel_2": p.gear_ratio, "wheel_3": p.ratio}
    cM, c1, c2 = (_centre(robot, j) for j in ("wheel_M", "wheel_1", "wheel_2"))
    vM = _pitch_point_velocity(robot, "wheel_M", p.r_M, c1, q)
    v1 = _pitch_point_velocity(robot, "wheel_1", p.R_1, cM, q)
    np.testing.assert_allclose(vM, v1, atol=1e-5 * np.linalg.norm(vM))  # the mesh M-1 rolls without slip
    v1b = _pitch_point_velocity(robot, "wheel_1", p.r_1, c2, q)
    v2 = _pitch_point_velocity(robot, "wheel_2", p.R_2, c1, q)
    np.testing.assert_allclose(v1b, v2, atol=1e-5 * np.linalg.norm(v1b))  # the mesh 1-2 too
    # the open belt: wheels 2 and 3 turn the same way, belt speed r_2 omega_2 = r_3 omega_3
    assert robot.joint_map["wheel_2"].axis.tolist() == robot.joint_map["wheel_3"].axis.tolist()
    assert p.r_2 * q["wheel_2"] == pytest.approx(p.r_3 * q["wheel_3"], rel=1e-12)


def test_render_writes_a_picture(tmp_path):
    out = tmp_path / "drive.png"
    render_urdf(urdf_from_params(load_scene("paper").params), out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_writes_and_refuses_to_overwrite(tmp_path, capsys):
    from belt_drive_ros.cli import main

    out = tmp_path / "d.urdf"
    assert main(["urdf", "paper", "--out", str(out)]) == 0
    assert yourdfpy.URDF.load(str(out), load_meshes=False).robot.name == "belt_drive_paper"
    assert main(["urdf", "paper", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["urdf", "paper", "--out", str(out), "--force"]) == 0


def test_foxglove_layout_refers_to_topics_and_joints_we_publish():
    import json
    from pathlib import Path

    layout = json.loads((Path(__file__).resolve().parents[1] / "docs/foxglove/belt_drive_layout.json").read_text())
    panels = layout["configById"]
    urdf_layer = panels["3D!drive"]["layers"]["belt-drive-urdf"]
    assert urdf_layer["topic"] == "/robot_description" and urdf_layer["jointStatesTopic"] == "/joint_states"

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)  # every panel placed, none dangling
    plotted = {p["value"].split(".")[0] for k, v in panels.items() if k.startswith("Plot!") for p in v["paths"]}
    assert {"/shaft_speed", "/belt_torque", "/relative_deflection", "/joint_states"} <= plotted
