"""``belt-drive node``: run the belt-drive ROS 2 node."""

from __future__ import annotations

import argparse
import re

EPILOG = """\
examples:
  belt-drive node                                   # scene 'paper', real time, 1 kHz
  belt-drive node truck_compressor --ros-args -p use_sim_time:=true
  belt-drive node paper --ros-args -p publish_clock:=true -p real_time_factor:=10.0
  belt-drive node my_scene.yaml --ros-args --params-file params.yaml -r __ns:=/truck1
  belt-drive node paper --record run.mcap --force    # record; replace run.mcap if it exists
  belt-drive node paper --record run --max-bag-duration 600   # bag folder run/run_0.mcap, run_1.mcap, ...
  belt-drive node --list-parameters
  belt-drive node truck_compressor --priority 50     # real-time scheduling on a busy machine
  belt-drive node fead_i4 --record fead.mcap         # a belt network: drive_torque + <pulley>/load_torque in,
                                                     # <pulley>/speed, spans/<span>/tension, ... out (docs/serpentine.md)

topics (relative, SI units): sub drive_torque (std_msgs/Float64, N m on wheel M);
pub shaft_speed [rad/s], load_torque [N m], belt_torque [N m], relative_deflection
[rad] (std_msgs/Float64), joint_states (sensor_msgs/JointState), robot_description
(std_msgs/String, the drive's URDF, latched), /diagnostics;
/clock with publish_clock. Service ~/reset (std_srvs/Trigger).
Stops cleanly (exit code 0) on SIGINT or SIGTERM. Invalid parameters at start,
or a recording that cannot start (record_path exists without --force, cannot be
created): exit code 2 with the reason; the node never runs without the
recording it was asked for. A --params-file must be a regular UTF-8 file under
1 MiB of plain YAML (no aliases); /dev/zero or a FIFO is refused, not read.
"""


def node_name(text: str) -> str:
    """argparse type of ``--name``: a ROS node name (letters, digits and '_', not starting with a digit), as rcl
    checks it, without loading ROS (rclpy refused it only when the node was made, as an internal error)."""
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,254}", text):
        raise argparse.ArgumentTypeError(f"a ROS node name is letters, digits and '_', not starting with a digit, "
                                         f"got {text[:60]!r}")
    return text


def register(sub) -> None:
    p = sub.add_parser(
        "node",
        help="run the belt-drive ROS 2 node (real time, /clock lockstep or time master)",
        description="Run the belt-drive node: drive_torque in, shaft speed, torques, deflection, joint_states out.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scene", nargs="?", help="shipped scene name or scene YAML (default: parameter 'scene', 'paper')")
    p.add_argument("--name", type=node_name, default="belt_drive", help="node name (default: belt_drive)")
    p.add_argument(
        "--executor", choices=("auto", "events", "single"), default="auto",
        help="rclpy executor: events (rclpy.experimental), single-threaded, or auto (events if available)",
    )
    p.add_argument("--record", metavar="PATH", help="record input and outputs to this MCAP file (parameter record_path)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing recording (parameter record_overwrite); without it the node refuses to start")
    p.add_argument("--max-bag-duration", type=float, metavar="S",
                   help="split the recording every S seconds of log time into a bag folder (parameter max_bag_duration)")
    p.add_argument("--max-bag-size", type=int, metavar="BYTES",
                   help="split the recording once a file holds BYTES (parameter max_bag_size)")
    p.add_argument("--list-parameters", action="store_true", help="print every parameter with unit, range and default, then exit")
    p.add_argument(
        "--priority", type=int, metavar="N",
        help="run with real-time scheduling (SCHED_FIFO) at priority N (1-99), so ticks come on time on a busy "
             "machine; needs CAP_SYS_NICE or 'ulimit -r N' (refused: a warning, normal scheduling)",
    )
    p.add_argument(
        "--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=None,
        help="ROS arguments, as for any ROS 2 node: -p NAME:=VALUE, --params-file FILE, -r FROM:=TO",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from ..ros.environment import interruptible_start  # (no rclpy)

    # SIGINT ends the start-up, where the process inherited it ignored too: from here, before the imports of rclpy
    # and the node (~2.6 s of a start-up at load 12), not only from the node's run()
    interruptible_start()
    if args.list_parameters and args.scene is not None:
        from ..io.scenes import is_network

        if is_network(args.scene):  # the network node's parameters (taken at start)
            from ..ros.network_node import PARAMETERS

            for name, default, text in PARAMETERS:
                print(f"{name:18s} default {default!r:12s} {text}")
            return 0
    if args.list_parameters:
        from ..ros.parameter_schema import describe_parameters  # the schema imports no rclpy

        print(describe_parameters("paper" if args.scene is None else args.scene))  # ('' is an unknown scene)
        return 0
    if args.priority is not None:
        import sys

        from ..ros.environment import realtime_priority

        if not 1 <= args.priority <= 99:
            print(f"belt-drive: error: --priority must be 1-99, got {args.priority}", file=sys.stderr)
            return 2
        refused = realtime_priority(args.priority)  # before rclpy starts its threads: they inherit it
        if refused:
            print(f"belt-drive: warning: {refused}; running with normal scheduling", file=sys.stderr)
    from ..io.scenes import is_network

    named = args.scene or next((a.split(":=", 1)[1] for a in args.ros_args or [] if a.startswith("scene:=")), None)
    if named and is_network(named):  # a belt network scene: its own node (ros/network_node.py)
        from ..ros.network_node import run as run_node
    else:
        from ..ros.node import run as run_node

    import shutil
    import tempfile

    from ..core.errors import ParameterError

    ros_args = ["--ros-args", *args.ros_args] if args.ros_args else []
    copies = tempfile.mkdtemp(prefix="belt_drive_params_")
    try:
        checked = check_params_files(ros_args, copies)
        try:
            return _run(args, checked, run_node)
        except ParameterError as exc:  # a params file named by the user's path, not by its private copy's
            for copy, given in zip(checked, ros_args):
                if copy != given and copy in exc.field:
                    raise type(exc)(exc.field.replace(copy, given), exc.detail) from None
            raise
    finally:
        shutil.rmtree(copies, ignore_errors=True)


def _run(args, ros_args, run_node) -> int:
    overrides = {}
    if args.record is not None:
        overrides["record_path"] = args.record
    if args.force:
        overrides["record_overwrite"] = True
    if args.max_bag_duration is not None:
        overrides["max_bag_duration"] = float(args.max_bag_duration)
    if args.max_bag_size is not None:
        overrides["max_bag_size"] = int(args.max_bag_size)
    try:
        return run_node(ros_args, scene=args.scene, executor=args.executor, node_name=args.name, overrides=overrides)
    except Exception as exc:
        if type(exc).__name__ != "RCLError":  # rclpy's, for ROS arguments rcl refuses
            raise
        from ..core.errors import ParameterError

        text = str(exc).splitlines()[0].split(", at /")[0]
        raise ParameterError("--ros-args", f"refused by rcl: {text}") from None


def check_params_files(ros_args, copies: str | None = None) -> list:
    """Refuse a ``--params-file`` that rcl would block on or read without bound, before rclpy reads it.

    Each file must be a regular UTF-8 file under 1 MiB with plain YAML (no
    aliases, nesting at most 32 levels, no duplicate keys):
    :mod:`belt_drive_ros.io.inputs`. ``/dev/zero`` or a FIFO would
    otherwise stall the node's start for good.

    With ``copies`` (a private folder), each file's checked text is written
    there and the returned arguments name the copy: rcl reads exactly what
    was checked, so a file swapped or changed between the check and rcl's
    read (e.g. for a FIFO) cannot bypass the check.

    Returns
    -------
    list
        ``ros_args``, with ``--params-file`` values replaced by the copies.

    Raises
    ------
    InputError
        naming the file and what is wrong with it.
    """
    import os

    from ..io.inputs import parse_yaml, read_text

    out = list(ros_args)
    for k, (flag, value) in enumerate(zip(ros_args, ros_args[1:])):
        if flag == "--params-file":
            text = read_text(value, what="params file")
            parse_yaml(text, label=f"params file {value}")
            if copies is not None:
                copy = os.path.join(copies, f"{k}_{os.path.basename(value) or 'params'}")
                with open(copy, "x", encoding="utf-8") as f:
                    f.write(text)
                out[k + 1] = copy
    return out
