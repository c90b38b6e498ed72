"""A URDF of the drive, built from a scene's parameters, and a picture rendered from it.

The URDF lets ``robot_state_publisher`` (and Foxglove's 3D panel, which reads
``/robot_description`` and ``/tf``) show the drive turning from the node's
``joint_states``: its four continuous joints carry the names the node
publishes, ``wheel_M, wheel_1, wheel_2, wheel_3``.

Geometry (all in metres, the drive lies in the x-y plane, wheels turn about z):

* wheel M at the origin; the gear pair M -> 1 meshes at the pitch circles, so
  wheel 1 sits at centre distance ``r_M + R_1`` along +x;
* wheel 1 carries two gears stacked along z (``R_1`` meshing with M, ``r_1``
  meshing with wheel 2); wheel 2 sits at centre distance ``r_1 + R_2`` from
  wheel 1, along +y (keeps the drive compact);
* wheel 2 carries its gear ``R_2`` and the belt pulley ``r_2``; wheel 3 (pulley
  ``r_3``) sits at the belt centre distance ``D`` along +x from wheel 2, with
  ``D`` chosen so that the open belt's smaller wrap angle equals the scene's
  ``wrap_angle``: ``beta = pi - 2 asin(|r_2 - r_3| / D)``. Equal pulleys wrap
  exactly pi whatever D; then, and when the wrap angle would need D beyond
  ``10 (r_2 + r_3)`` (a wrap angle within a hair of pi) or is not reachable,
  the picture uses ``D = 4 max(r_2, r_3)`` (the model uses ``wrap_angle``
  itself, never this drawing);
* the belt's two straight spans are thin boxes on the common outer tangents,
  fixed to ``base_link``; a short box on each wheel (a "spoke") makes the
  rotation visible.

Joint axes follow the sense of rotation: an external gear mesh reverses it,
the open belt keeps it, so wheel 1 turns about -z and wheels M, 2, 3 about +z
for positive joint positions (each wheel's coordinate is positive in its own
running direction, as on the topics).

This module is ROS-free (text only; rendering uses matplotlib when asked).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Dict, List, Tuple

__all__ = ["JOINT_NAMES", "DriveLayout", "drive_layout", "render_urdf", "urdf_from_params"]

#: the node's JointState names, one continuous joint each
JOINT_NAMES = ("wheel_M", "wheel_1", "wheel_2", "wheel_3")

_THICKNESS = 0.012  # [m] face width of a gear or pulley (visual only)
_MAX_DISTANCE_FACTOR = 10.0  # a belt longer than 10 (r_2 + r_3) between centres is drawn at the fallback
_COLOURS = {
    "steel": (0.62, 0.64, 0.68, 1.0),
    "gear": (0.35, 0.45, 0.60, 1.0),
    "pulley": (0.75, 0.55, 0.25, 1.0),
    "belt": (0.10, 0.10, 0.10, 1.0),
    "spoke": (0.85, 0.15, 0.10, 1.0),
}


@dataclass(frozen=True)
class DriveLayout:
    """Where the wheels are [m] and what they carry.

    ``wheels`` maps a joint name to ``(x, y, axis_sign, discs)`` where each disc
    is ``(radius [m], z offset [m], material)``.
    """

    wheels: Dict[str, Tuple[float, float, int, Tuple[Tuple[float, float, str], ...]]]
    belt_centre_distance: float
    belt_spans: Tuple[Tuple[Tuple[float, float], Tuple[float, float]], ...]
    belt_z: float


def _belt_centre_distance(r_2: float, r_3: float, wrap_angle: float) -> float:
    """Centre distance D [m] giving the smaller wrap angle ``wrap_angle`` [rad] of an open belt."""
    fallback = 4.0 * max(r_2, r_3)
    gap = abs(r_2 - r_3)
    if gap == 0.0 or not (0.0 < wrap_angle < math.pi):
        return fallback
    distance = gap / math.sin((math.pi - wrap_angle) / 2.0)
    return distance if r_2 + r_3 < distance <= _MAX_DISTANCE_FACTOR * (r_2 + r_3) else fallback


def _outer_tangents(c1, r1, c2, r2):
    """The two outer common tangent segments of circles (c1, r1), (c2, r2)."""
    (x1, y1), (x2, y2) = c1, c2
    dx, dy = x2 - x1, y2 - y1
    d = math.hypot(dx, dy)
    base = math.atan2(dy, dx)
    alpha = math.acos((r1 - r2) / d)  # angle of the tangent points' normals from the centre line
    spans = []
    for sign in (+1, -1):
        a = base + sign * alpha
        nx, ny = math.cos(a), math.sin(a)
        spans.append(((x1 + r1 * nx, y1 + r1 * ny), (x2 + r2 * nx, y2 + r2 * ny)))
    return tuple(spans)


def drive_layout(params) -> DriveLayout:
    """The drive's geometry from a :class:`~belt_drive_ros.core.params.BeltDriveParams`."""
    t = _THICKNESS
    x1 = params.r_M + params.R_1
    y2 = params.r_1 + params.R_2
    distance = _belt_centre_distance(params.r_2, params.r_3, params.wrap_angle)
    wheels = {
        "wheel_M": (0.0, 0.0, +1, ((params.r_M, 0.0, "gear"),)),
        "wheel_1": (x1, 0.0, -1, ((params.R_1, 0.0, "gear"), (params.r_1, t, "gear"))),
        "wheel_2": (x1, y2, +1, ((params.R_2, t, "gear"), (params.r_2, 2 * t, "pulley"))),
        "wheel_3": (x1 + distance, y2, +1, ((params.r_3, 2 * t, "pulley"),)),
    }
    spans = _outer_tangents((x1, y2), params.r_2, (x1 + distance, y2), params.r_3)
    return DriveLayout(wheels, distance, spans, 2 * t)


def _material(parent, name):
    r, g, b, a = _COLOURS[name]
    m = ET.SubElement(parent, "material", name=name)
    ET.SubElement(m, "color", rgba=f"{r:g} {g:g} {b:g} {a:g}")


def _visual(link, xyz, geometry, material, rpy=(0.0, 0.0, 0.0)):
    visual = ET.SubElement(link, "visual")
    ET.SubElement(visual, "origin", xyz=" ".join(f"{v:.12g}" for v in xyz), rpy=" ".join(f"{v:.12g}" for v in rpy))
    geo = ET.SubElement(visual, "geometry")
    kind, attrs = geometry
    ET.SubElement(geo, kind, **attrs)
    ET.SubElement(visual, "material", name=material)


def urdf_from_params(params, name: str = "belt_drive") -> str:
    """URDF text of the drive (see the module docstring for the geometry).

    Parameters
    ----------
    params : BeltDriveParams
        Radii [m] and the wrap angle [rad] are used; inertias become the
        links' ``<inertial>`` (about the turning axis; the others are not
        modelled and set equal, which viewers ignore).
    name : str
        The ``<robot name>``.
    """
    layout = drive_layout(params)
    robot = ET.Element("robot", name=name)
    for colour in _COLOURS:
        _material(robot, colour)
    base = ET.SubElement(robot, "link", name="base_link")
    for k, ((xa, ya), (xb, yb)) in enumerate(layout.belt_spans):
        length = math.hypot(xb - xa, yb - ya)
        _visual(
            base, ((xa + xb) / 2, (ya + yb) / 2, layout.belt_z),
            ("box", {"size": f"{length:.12g} 0.003 {_THICKNESS * 0.8:.12g}"}), "belt",
            rpy=(0.0, 0.0, math.atan2(yb - ya, xb - xa)),
        )
    inertias = {"wheel_M": params.I_M, "wheel_1": params.I_1, "wheel_2": params.I_2, "wheel_3": params.I_3}
    for joint_name, (x, y, sign, discs) in layout.wheels.items():
        link = ET.SubElement(robot, "link", name=f"{joint_name}_link")
        for radius, z, material in discs:
            _visual(link, (0.0, 0.0, z), ("cylinder", {"radius": f"{radius:.12g}", "length": f"{_THICKNESS:.12g}"}),
                    material)
        outer = max(r for r, _, _ in discs)
        top = max(z for _, z, _ in discs) + _THICKNESS / 2
        _visual(link, (outer / 2, 0.0, top + 0.001), ("box", {"size": f"{outer:.12g} {outer / 8:.12g} 0.002"}), "spoke")
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "mass", value="1")
        j = max(inertias[joint_name], 1e-9)
        ET.SubElement(inertial, "inertia", ixx=f"{j:.12g}", iyy=f"{j:.12g}", izz=f"{j:.12g}", ixy="0", ixz="0", iyz="0")
        joint = ET.SubElement(robot, "joint", name=joint_name, type="continuous")
        ET.SubElement(joint, "parent", link="base_link")
        ET.SubElement(joint, "child", link=f"{joint_name}_link")
        ET.SubElement(joint, "origin", xyz=f"{x:.12g} {y:.12g} 0", rpy="0 0 0")
        ET.SubElement(joint, "axis", xyz=f"0 0 {sign:d}")
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _parse(urdf: str):
    """Visual primitives of a URDF in the base frame for joint positions 0.

    Returns a list of ``(kind, x, y, yaw, dims, rgba)`` with ``kind`` in
    {"cylinder", "box"}; handles the URDF this module writes (one level of
    joints under ``base_link``, origins with x, y and yaw).
    """
    root = ET.fromstring(urdf)
    colours = {m.get("name"): tuple(float(v) for v in m.find("color").get("rgba").split())
               for m in root.findall("material") if m.find("color") is not None}
    link_origin = {"base_link": (0.0, 0.0, 0.0)}
    for joint in root.findall("joint"):  # parents before children (a network's tensioner pulley hangs on its arm)
        xyz = [float(v) for v in joint.find("origin").get("xyz").split()]
        rpy = [float(v) for v in joint.find("origin").get("rpy").split()]
        px, py, pyaw = link_origin.get(joint.find("parent").get("link"), (0.0, 0.0, 0.0))
        c, s = math.cos(pyaw), math.sin(pyaw)
        link_origin[joint.find("child").get("link")] = (px + c * xyz[0] - s * xyz[1], py + s * xyz[0] + c * xyz[1],
                                                        pyaw + rpy[2])
    shapes: List[tuple] = []
    for link in root.findall("link"):
        ox, oy, oyaw = link_origin.get(link.get("name"), (0.0, 0.0, 0.0))
        for visual in link.findall("visual"):
            xyz = [float(v) for v in visual.find("origin").get("xyz").split()]
            yaw = float(visual.find("origin").get("rpy").split()[2])
            c, s = math.cos(oyaw), math.sin(oyaw)
            x, y = ox + c * xyz[0] - s * xyz[1], oy + s * xyz[0] + c * xyz[1]
            geo = visual.find("geometry")[0]
            if geo.tag == "cylinder":
                dims = (float(geo.get("radius")),)
            else:
                dims = tuple(float(v) for v in geo.get("size").split())
            shapes.append((geo.tag, x, y, oyaw + yaw, dims, colours.get(visual.find("material").get("name"),
                                                                         (0.5, 0.5, 0.5, 1.0)), xyz[2]))
    return shapes


def render_urdf(urdf: str, path, title: str = "") -> None:
    """Draw the URDF's visuals seen from +z (the plane the drive turns in) to an image file.

    Cylinders are drawn as translucent discs with their outlines on top (dashed
    below the top layer, so a gear under a pulley stays visible), boxes as
    rectangles, in the order of their height. Headless (matplotlib's Agg).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle
    from matplotlib.transforms import Affine2D

    shapes = sorted(_parse(urdf), key=lambda s: s[6])
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for kind, x, y, yaw, dims, rgba, _ in shapes:
        if kind == "cylinder":
            ax.add_patch(Circle((x, y), dims[0], facecolor=rgba[:3] + (0.55,), edgecolor="none"))
        else:
            length, width = dims[0], dims[1]
            patch = Rectangle((-length / 2, -width / 2), length, width, facecolor=rgba, edgecolor="none")
            patch.set_transform(Affine2D().rotate(yaw).translate(x, y) + ax.transData)
            ax.add_patch(patch)
    for kind, x, y, _, dims, _, z in shapes:  # every disc's outline on top: lower gears stay visible
        if kind == "cylinder":
            ax.add_patch(Circle((x, y), dims[0], facecolor="none", edgecolor="black", linewidth=0.7,
                                linestyle="-" if z == max(sh[6] for sh in shapes if sh[0] == "cylinder") else "--"))
    root = ET.fromstring(urdf)
    origins = {j.find("child").get("link"): j for j in root.findall("joint")}
    for joint in root.findall("joint"):
        xyz = [float(v) for v in joint.find("origin").get("xyz").split()]
        parent = origins.get(joint.find("parent").get("link"))
        if parent is not None:  # one level down (a network's tensioner pulley on its arm)
            xyz = [a + float(b) for a, b in zip(xyz, parent.find("origin").get("xyz").split())]
        ax.annotate(joint.get("name"), (xyz[0], xyz[1]), textcoords="offset points", xytext=(0, -14),
                    ha="center", fontsize=8, color="black", weight="bold")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.margins(0.08)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{root.get('name')}: URDF seen from +z (joint positions 0)")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=120, format="png")  # path or binary file (an atomic output)
    finally:
        plt.close(fig)
