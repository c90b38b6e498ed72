"""The URDF of a belt network: its layout drawn so Foxglove (or RViz) shows it turning (text only, no ROS).

Links and joints (metres, the drive in the x-y plane, every axis along z):

* ``base_link`` carries the belt: one thin box per span, between the span's
  two tangent points (fixed: the spans follow the installed layout);
* one continuous joint per pulley, named as the pulley (the names of
  ``joint_states``), at its centre, axis ``(0, 0, s)`` with ``s`` the sense
  that turns a positive angle the way the belt runs (inner-face pulleys and
  backside idlers turn opposite ways); its link is a disc of the pulley's
  radius with a spoke, so the rotation shows;
* with a tensioner, a revolute joint ``tensioner_arm`` at the pivot, its
  link a bar from the pivot along the installed arm (joint position 0 = the
  installed arm; ``joint_states`` gives the arm's deviation from it), and
  the tensioner pulley's joint on that link, at the arm's end.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

from .urdf import _COLOURS, _THICKNESS, _material, _visual

__all__ = ["network_urdf"]


def _inertial(link, inertia: float) -> None:
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "mass", value="1")
    j = f"{max(inertia, 1e-9):.12g}"
    ET.SubElement(inertial, "inertia", ixx=j, iyy=j, izz=j, ixy="0", ixz="0", iyz="0")


def network_urdf(layout) -> str:
    """URDF text of a :class:`~belt_drive_ros.io.network_bag.NetworkLayout` (see the module docstring)."""
    scene = layout.scene
    geo = scene.geometry
    robot = ET.Element("robot", name=f"belt_network_{scene.name}".replace("-", "_"))
    for colour in _COLOURS:
        _material(robot, colour)
    base = ET.SubElement(robot, "link", name="base_link")
    belt_z = _THICKNESS
    for j in range(len(scene.pulleys)):
        (xa, ya), (xb, yb) = geo.leave[j], geo.arrive[j]
        length = math.hypot(xb - xa, yb - ya)
        _visual(base, ((xa + xb) / 2, (ya + yb) / 2, belt_z), ("box", {"size": f"{length:.12g} 0.003 {_THICKNESS * 0.8:.12g}"}),
                "belt", rpy=(0.0, 0.0, math.atan2(yb - ya, xb - xa)))
    if layout.arm:
        t, pivot, length, angle = layout.arm
        link = ET.SubElement(robot, "link", name="tensioner_arm_link")
        _visual(link, (length / 2 * math.cos(angle), length / 2 * math.sin(angle), -_THICKNESS),
                ("box", {"size": f"{length:.12g} 0.012 0.004"}), "steel", rpy=(0.0, 0.0, angle))
        _visual(link, (0.0, 0.0, -_THICKNESS), ("cylinder", {"radius": "0.008", "length": "0.006"}), "steel")
        _inertial(link, scene.tensioner.inertia)
        joint = ET.SubElement(robot, "joint", name="tensioner_arm", type="revolute")
        ET.SubElement(joint, "parent", link="base_link")
        ET.SubElement(joint, "child", link="tensioner_arm_link")
        ET.SubElement(joint, "origin", xyz=f"{pivot[0]:.12g} {pivot[1]:.12g} 0", rpy="0 0 0")
        ET.SubElement(joint, "axis", xyz="0 0 1")
        ET.SubElement(joint, "limit", lower=f"{-math.pi:.12g}", upper=f"{math.pi:.12g}", effort="1000", velocity="1000")
    for (name, parent, x, y, sense), p in zip(layout.frames(), scene.pulleys):
        link = ET.SubElement(robot, "link", name=f"{name}_link")
        _visual(link, (0.0, 0.0, 0.0), ("cylinder", {"radius": f"{p.radius:.12g}", "length": f"{_THICKNESS:.12g}"}),
                "pulley" if p.side > 0 else "gear")
        _visual(link, (p.radius / 2, 0.0, _THICKNESS / 2 + 0.001), ("box", {"size": f"{p.radius:.12g} {p.radius / 8:.12g} 0.002"}),
                "spoke")
        _inertial(link, p.inertia)
        joint = ET.SubElement(robot, "joint", name=name, type="continuous")
        ET.SubElement(joint, "parent", link=parent)
        ET.SubElement(joint, "child", link=f"{name}_link")
        ET.SubElement(joint, "origin", xyz=f"{x:.12g} {y:.12g} 0", rpy="0 0 0")
        ET.SubElement(joint, "axis", xyz=f"0 0 {int(sense):d}")
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"
