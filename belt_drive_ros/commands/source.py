"""``belt-drive source engine|motor|profile``: publish drive_torque from a torque source."""

from __future__ import annotations

import argparse
from pathlib import Path

from .node import node_name

EPILOG = """\
examples:
  belt-drive source engine --scene truck_compressor        # the scene's diesel, governor closes the loop
  belt-drive source engine --mean-torque 30 --harmonics 40,12 --cylinders 6 --speed-setpoint 80
  belt-drive source motor --scene e_motor_start
  belt-drive source motor --stall-torque 60 --no-load-speed 300 --soft-start-time 1.5
  belt-drive source profile --csv torque.csv --interpolation previous
  belt-drive source profile --scene paper --rate 500 --ros-args -p use_sim_time:=true

Publishes drive_torque (std_msgs/Float64, N m) at --rate on the node clock.
Speed-dependent sources (engine with a governor, motor curve) subscribe to
shaft_speed [rad/s] from the belt node and integrate the drive-wheel angle from
it (the engine's crank angle is crank_ratio times that angle).
A CSV has a time column [s] and a torque column [N m]: the first two columns,
or by name with a header line (--column; a 'belt-drive sim --out' CSV works).
"""


def _floats(text: str) -> tuple:
    """argparse type: comma-separated numbers, at least one, none empty (``,,,`` or ``40,,12`` is refused)."""
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, e.g. 40,12, got {text[:60]!r}") from None


def _curve(text: str) -> tuple:
    try:
        pts = [tuple(float(v) for v in pair.split(":")) for pair in text.split(",") if pair.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SPEED:TORQUE,SPEED:TORQUE,..., got {text!r}") from None
    if any(len(p) != 2 for p in pts):
        raise argparse.ArgumentTypeError(f"expected SPEED:TORQUE pairs, got {text!r}")
    return tuple(pts)


def _common(p) -> None:
    p.add_argument("--rate", type=float, default=1000.0, help="publish rate [Hz] (default 1000)")
    p.add_argument("--initial-speed", type=float, help="wheel-M speed [rad/s] assumed before the first shaft_speed (default: the scene's or 0)")
    p.add_argument("--name", type=node_name, default="torque_source", help="node name (default: torque_source)")
    p.add_argument("--executor", choices=("auto", "events", "single"), default="auto", help="rclpy executor (default auto)")
    p.add_argument("--print", dest="print_only", action="store_true", help="print the profile as YAML and exit (no ROS)")
    p.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=None, help="ROS arguments (-p, -r, --params-file)")
    p.set_defaults(func=run)


def register(sub) -> None:
    p = sub.add_parser(
        "source",
        help="publish drive_torque from an engine, a motor curve or a recorded profile",
        description="A torque publisher node for drive_torque built on the core's sources.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    kinds = p.add_subparsers(dest="source_kind", metavar="KIND")
    kinds.required = True

    e = kinds.add_parser("engine", help="combustion engine: mean torque, governor, firing pulsations by crank angle")
    e.add_argument("--scene", help="start from this scene's engine drive")
    e.add_argument("--mean-torque", type=float, help="mean torque [N m]")
    e.add_argument("--cylinders", type=int, help="number of cylinders")
    e.add_argument("--strokes", type=int, choices=(2, 4), help="2- or 4-stroke")
    e.add_argument("--harmonics", type=_floats, help="firing-order amplitudes [N m], e.g. 40,12")
    e.add_argument("--phase", type=float, help="firing phase [rad]")
    e.add_argument("--crank-ratio", type=float, help="crank angle per wheel-M angle [-]")
    e.add_argument("--speed-setpoint", type=float, help="governor speed setpoint [rad/s of wheel M] (closes the loop)")
    e.add_argument("--governor-gain", type=float, help="droop governor gain [N m s/rad]")
    e.add_argument("--max-torque", type=float, help="governor torque limit [N m]")
    e.add_argument("--ramp-time", type=float, help="fade-in time at start [s]")
    _common(e)

    m = kinds.add_parser("motor", help="electric motor torque-speed curve with soft start")
    m.add_argument("--scene", help="start from this scene's motor drive")
    m.add_argument("--stall-torque", type=float, help="torque at standstill [N m] (linear curve)")
    m.add_argument("--no-load-speed", type=float, help="speed at zero torque [rad/s] (linear curve)")
    m.add_argument("--curve", type=_curve, help="SPEED:TORQUE points [rad/s:N m], e.g. 0:60,150:60,314:28,400:0")
    m.add_argument("--soft-start-time", type=float, help="torque-limit ramp at start [s]")
    _common(m)

    r = kinds.add_parser("profile", help="a recorded profile (CSV) or any scene's drive profile")
    src = r.add_mutually_exclusive_group(required=True)
    src.add_argument("--csv", type=Path, help="CSV with time [s] and torque [N m] columns")
    src.add_argument("--scene", help="use this scene's drive profile, whatever its type")
    r.add_argument("--column", default=None, help="torque column name in a CSV with a header (default: 2nd column, or 'drive_torque')")
    r.add_argument("--interpolation", choices=("previous", "linear"), default="previous", help="between samples: hold (default) or linear")
    _common(r)


_ENGINE_FIELDS = (
    "mean_torque", "cylinders", "strokes", "harmonics", "phase", "crank_ratio",
    "speed_setpoint", "governor_gain", "max_torque", "ramp_time",
)
_MOTOR_FIELDS = ("stall_torque", "no_load_speed", "curve", "soft_start_time")


def _from_scene(scene_name: str, expected_kind: str | None):
    from ..core.errors import SceneError
    from ..io.scenes import load_scene

    scene = load_scene(scene_name)
    if expected_kind is not None and scene.drive.kind != expected_kind:
        raise SceneError(
            f"scene '{scene.name}': its drive is a {scene.drive.kind!r} profile, not {expected_kind!r}; "
            f"use 'belt-drive source profile --scene {scene_name}'"
        )
    return scene


#: largest CSV profile [bytes] (~1.5 M rows of "time, torque")
CSV_LIMIT = 64 << 20


def read_csv_profile(path: Path, column: str | None = None, interpolation: str = "previous"):
    """Table profile from a CSV: time [s] + torque [N m] columns (see the command's help)."""
    import numpy as np

    from ..core.errors import SceneError, short
    from ..core.sources import Table

    from ..io.inputs import read_text

    text = read_text(path, "CSV profile", limit=CSV_LIMIT)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise SceneError(f"{path}: empty CSV")
    first = [c.strip() for c in lines[0].split(",")]

    def number(text: str) -> bool:
        try:
            float(text)
            return True
        except ValueError:
            return False

    # a header names its columns: no field of it a number (a first data row with a typo, "0,1.0.0", is a row whose
    # error is named below, not a header that drops it)
    header = None if any(number(c) for c in first) else first
    if header is not None:
        lines = lines[1:]
    try:
        data = np.array([[float(c) for c in ln.split(",")] for ln in lines], dtype=float)
    except ValueError as exc:
        raise SceneError(f"{path}: not a numeric CSV: {short(str(exc), 120)}") from None
    if data.ndim != 2 or data.shape[1] < 2 or data.shape[0] < 1:
        raise SceneError(f"{path}: need a time column and a torque column")
    t_col, v_col = 0, 1
    if header is not None:
        if "time" in header:
            t_col = header.index("time")
        wanted = column or ("drive_torque" if "drive_torque" in header else None)
        if wanted is not None:
            if wanted not in header:
                raise SceneError(f"{path}: no column {short(wanted)}; columns: {short(', '.join(header), 200)}")
            v_col = header.index(wanted)
        else:  # the first column that is not the time's ("torque,time": the torque, not the time again)
            v_col = 1 if t_col == 0 else 0
        if v_col == t_col:
            raise SceneError(f"{path}: --column {short(wanted)} is the time column; name the torque's")
    elif column is not None:
        raise SceneError(f"{path}: --column needs a header line")
    try:  # (checked as a scene's table: a torque of 1e300 N m was published)
        return Table(times=tuple(data[:, t_col]), values=tuple(data[:, v_col]), interpolation=interpolation).check_plausible("table")
    except SceneError as exc:
        raise SceneError(f"{path}: {exc}") from None


def build_profile(args):
    """(profile, initial_speed) for the parsed arguments; no ROS involved."""
    from ..core.sources import Engine, MotorCurve

    kind = args.source_kind
    initial_speed = 0.0
    if kind == "profile":
        if args.csv is not None:
            profile = read_csv_profile(args.csv, args.column, args.interpolation)
        else:
            scene = _from_scene(args.scene, None)
            profile, initial_speed = scene.drive, scene.initial_state.omega_M
    else:
        cls, names = (Engine, _ENGINE_FIELDS) if kind == "engine" else (MotorCurve, _MOTOR_FIELDS)
        base = {}
        if args.scene:
            scene = _from_scene(args.scene, cls.kind)
            base = {k: v for k, v in scene.drive.to_dict().items() if k != "type"}
            initial_speed = scene.initial_state.omega_M
        for name in names:
            value = getattr(args, name, None)
            if value is not None:
                base[name] = value
        from ..core.sources import make_profile

        profile = make_profile({"type": cls.kind, **base}, f"source {kind}")
    if args.initial_speed is not None:
        from ..core.errors import InputError
        from ..core.sources import SPEED_MAX

        if not abs(args.initial_speed) <= SPEED_MAX:  # (nan too: the source would publish nothing)
            raise InputError(f"--initial-speed: {args.initial_speed!r} rad/s is outside [-{SPEED_MAX:g}, {SPEED_MAX:g}] rad/s")
        initial_speed = args.initial_speed
    return profile, initial_speed


def run(args) -> int:
    profile, initial_speed = build_profile(args)
    if args.print_only:
        import yaml

        print(yaml.safe_dump({"drive": profile.to_dict(), "initial_speed": initial_speed}, sort_keys=False), end="")
        return 0
    from ..ros.source_node import RATE_RANGE
    from ..ros.source_node import run as run_source

    if not RATE_RANGE[0] <= args.rate <= RATE_RANGE[1]:  # (rclpy's own refusal was an internal error)
        from ..core.errors import InputError

        raise InputError(f"--rate: must be in [{RATE_RANGE[0]:g}, {RATE_RANGE[1]:g}] Hz, got {args.rate!r}")

    ros_args = ["--ros-args", *args.ros_args] if args.ros_args else []
    return run_source(profile, ros_args, rate_hz=args.rate, initial_speed=initial_speed, executor=args.executor, node_name=args.name)
