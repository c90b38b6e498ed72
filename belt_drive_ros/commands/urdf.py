"""``belt-drive urdf``: the drive's URDF from a scene, and a picture rendered from it."""

from __future__ import annotations

import os


def register(sub) -> None:
    p = sub.add_parser(
        "urdf", help="write the drive's URDF (wheels M, 1, 2, 3 from the scene's radii) and render it",
        description=(
            "Write the URDF of a scene's drive: four continuous joints named as the node's joint_states "
            "(wheel_M, wheel_1, wheel_2, wheel_3), gears and pulleys with the scene's radii, the belt's "
            "spans as visuals. Feed it to robot_state_publisher (robot_description) or load it in Foxglove's "
            "3D panel (URDF layer, joint states from /joint_states)."
        ),
        epilog="examples:\n  belt-drive urdf truck_compressor > drive.urdf\n"
               "  belt-drive urdf paper --out paper.urdf --png paper_drive.png\n"
               "  belt-drive urdf fead_i4 --png fead.png    # a belt network: pulleys, belt path, tensioner arm",
        formatter_class=__import__("argparse").RawDescriptionHelpFormatter,
    )
    p.add_argument("scene", help="shipped scene name or scene YAML file")
    p.add_argument("--out", help="write the URDF here (default: standard output)")
    p.add_argument("--png", help="also render the URDF seen from +z to this PNG file")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io.atomic import OutputRefused, atomic_output, check_output
    from ..io.inputs import input_replaced
    from ..io.urdf import render_urdf, urdf_from_params

    from ..io.scenes import is_network, load_network

    if is_network(args.scene):  # a belt network: its layout, a joint per pulley and the tensioner arm
        from ..io.network_bag import NetworkLayout

        scene = load_network(args.scene)
        text = NetworkLayout(scene).urdf()
    else:
        from ..io.scenes import load_either_scene

        scene = load_either_scene(args.scene)  # (an unknown name: the belt networks listed too)
        text = urdf_from_params(scene.params, name=f"belt_drive_{scene.name}".replace("-", "_"))
    for option, path in (("--out", args.out), ("--png", args.png)):
        if path is not None and not path:
            raise OutputRefused(f"{option}: an empty path; give a file name (or leave --out out for standard output)")
        if path:
            if input_replaced(path, [args.scene]) is not None:
                raise OutputRefused(f"{option} {path}: would replace the scene file {args.scene}, which this run reads; "
                                    "write elsewhere")
            check_output(path, args.force, option)
    if args.png and not args.png.lower().endswith(".png"):
        raise OutputRefused(f"--png {args.png}: the picture is a PNG; give a .png path")
    if args.out and args.png and os.path.abspath(args.out) == os.path.abspath(args.png):
        raise OutputRefused("--out and --png name the same file")
    if args.out:
        with atomic_output(args.out, args.force, "w", what="--out") as f:
            f.write(text)
    else:
        print(text, end="")
    if args.png:
        with atomic_output(args.png, args.force, "wb", what="--png") as f:
            render_urdf(text, f, title=f"{scene.name}: drive rendered from its URDF")
    return 0
