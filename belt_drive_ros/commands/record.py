"""``belt-drive record``: record ROS 2 topics to a rosbag2-compatible MCAP file."""

from __future__ import annotations

import argparse
from pathlib import Path

EPILOG = """\
examples:
  belt-drive record --out run.mcap                       # every topic (not /rosout, /parameter_events)
  belt-drive record --topics /drive_torque /joint_states --out run.mcap --duration 10
  belt-drive record --out run.mcap --use-sim-time        # log times from /clock
  belt-drive record --out run.mcap --ros-args -r __ns:=/truck
  belt-drive record --out run --max-bag-duration 600     # bag folder run/run_0.mcap, run_1.mcap, ... + metadata.yaml

Messages are written as received (raw CDR), log time = receive time on the
recorder's clock [ns] (simulated time with --use-sim-time), with the QoS the
publishers offer. Topics that appear later are picked up (polled every
0.5 s). SIGINT/SIGTERM (Ctrl-C) finalize the file; after SIGKILL it reads up
to its last complete chunk (chunks close every 0.25 s). An existing file is
never replaced without --force. A bag folder is written by one recorder or
run at a time (its lock file .NAME.lock beside it, as sim --bag-folder takes
it): a second is refused, naming the first's pid (exit 1).
"""

DEFAULT_EXCLUDE = ("/rosout", "/parameter_events")


def register(sub) -> None:
    p = sub.add_parser(
        "record",
        help="record topics to an MCAP file (ros2 bag compatible)",
        description="Record ROS 2 topics (raw CDR) into a rosbag2-compatible MCAP file.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="topics to record (default: all discovered)")
    p.add_argument("--exclude", nargs="+", metavar="TOPIC", default=list(DEFAULT_EXCLUDE),
                   help="topics not to record when recording all (default: /rosout /parameter_events)")
    p.add_argument("--out", "-o", type=Path, required=True,
                   help="output .mcap file (with a split: the bag folder)")
    p.add_argument("--max-bag-duration", type=float, metavar="S", default=0.0,
                   help="split into a rosbag2 bag folder, a new file every S seconds of log time")
    p.add_argument("--max-bag-size", type=int, metavar="BYTES", default=0,
                   help="split into a rosbag2 bag folder, a new file once one holds BYTES")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.add_argument("--duration", type=float, help="stop after this many seconds (wall clock)")
    p.add_argument("--use-sim-time", action="store_true", help="log times on /clock (use_sim_time:=true)")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd", help="chunk compression")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--ros-args", nargs=argparse.REMAINDER, default=[], dest="ros_args",
                   help="ROS arguments for the recorder node (everything after it)")
    p.set_defaults(func=run)


def run(args) -> int:
    """The command (see the module docstring); SIGINT/SIGTERM from the opening of the recording on finish it
    (:func:`~belt_drive_ros.ros.executors.stop_on_signals`: in the start-up too, the spin then never begins)."""
    from ..ros.executors import stop_on_signals

    with stop_on_signals(starting=True) as stop:
        return _record(args, stop)


def _record(args, stop) -> int:
    import contextlib
    import os
    import signal
    import sys

    from msg_tools.errors import MsgToolsError

    from ..io.recording import BagWriteError, bag_error

    from ..core.errors import ParameterError

    if args.duration is not None and not args.duration > 0:  # (exit 2 like every bad input; inf: until interrupted)
        raise ParameterError("--duration", f"must be > 0 s, got {args.duration!r}")

    if not 0 <= args.max_bag_duration < float("inf"):
        raise ParameterError("--max-bag-duration", f"must be finite and >= 0 s, got {args.max_bag_duration!r}")
    if args.max_bag_size < 0:
        raise ParameterError("--max-bag-size", f"must be >= 0 bytes, got {args.max_bag_size!r}")
    split = bool(args.max_bag_duration or args.max_bag_size)
    if split and args.out.suffix.lower() == ".mcap":
        raise ParameterError("--out", f"{args.out}: a split recording is a bag folder (NAME/NAME_0.mcap, ...); "
                             "give a folder name without .mcap")
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_topic_name import validate_topic_name

    for flag, names in (("--topics", args.topics), ("--exclude", args.exclude)):
        for name in names or ():  # (before the writer: a refused name left an empty recording, exit 1)
            try:
                validate_topic_name(name)
            except InvalidTopicNameException as exc:
                raise ParameterError(flag, f"{name[:80]!r} is not a topic name: {str(exc).splitlines()[0][:200].rstrip(': ')}") from None
    if not split:  # a file: a .mcap path in an existing folder (checked before ROS starts)
        from ..io.atomic import check_output

        if args.out.suffix.lower() != ".mcap":
            raise ParameterError("--out", f"{args.out}: a recording is an .mcap file (a bag folder, named without "
                                 ".mcap, with --max-bag-duration or --max-bag-size)")
        check_output(args.out, force=True, what="--out")  # (an existing file: the writer's own refusal, --force)
    from ..ros.recorder import open_writer

    try:
        writer = open_writer(args.out, force=args.force, compression=args.compression,
                             max_bag_duration=args.max_bag_duration, max_bag_size=args.max_bag_size)
    except MsgToolsError as exc:
        raise bag_error(exc) from None

    from ..ros.executors import ros_session, spin_nodes
    from ..ros.recorder import TopicRecorder

    def say(text: str) -> None:
        if not args.quiet:
            print(text, file=sys.stderr, flush=True)

    recorder = None
    signum = 0
    try:
        with ros_session(["belt-drive-record", "--ros-args", *args.ros_args]) as context:
            import rclpy
            from rclpy.parameter import Parameter

            overrides = [Parameter("use_sim_time", value=True)] if args.use_sim_time else []
            node = rclpy.create_node("belt_drive_recorder", context=context, parameter_overrides=overrides)
            recorder = TopicRecorder(node, writer)
            wanted = None if not args.topics else [node.resolve_topic_name(t) for t in args.topics]
            excluded = {node.resolve_topic_name(t) for t in (args.exclude or [])}
            skipped: set = set()

            def discover() -> None:
                for name, types in node.get_topic_names_and_types():
                    if name in recorder.topics or name in skipped:
                        continue
                    if wanted is not None and name not in wanted:
                        continue
                    if wanted is None and name in excluded:
                        continue
                    if not node.get_publishers_info_by_topic(name):
                        continue  # its publishers' QoS not known yet (a latched topic needs it): next poll
                    if len(types) != 1:
                        skipped.add(name)
                        say(f"skipping {name}: {len(types)} types advertised ({', '.join(types)})")
                        continue
                    try:
                        recorder.add(name, types[0])
                    except ValueError as exc:
                        skipped.add(name)
                        say(f"skipping {name}: {exc}")
                        continue
                    say(f"recording {name} ({types[0]})")

            say(f"recording to {args.out}; Ctrl-C to stop")
            # topics that appear later are picked up every `poll` seconds
            signum = spin_nodes([node], context, freeze_gc=False, poll=0.5, every=discover, stop=stop,
                                until=lambda: recorder.failed, duration=args.duration,
                                stopped=lambda _signum: recorder.close())
    finally:
        if recorder is not None:
            recorder.close()
        else:  # ROS never started (--ros-args refused ...): nothing recorded, no empty recording left behind
            try:
                writer.finish()
            except MsgToolsError:
                pass
            if not split:
                with contextlib.suppress(OSError):
                    os.unlink(args.out)
    if recorder.failed:
        raise BagWriteError(str(recorder.error), getattr(recorder.error, "errno", None))
    counts = writer.topic_counts()
    why = f" (signal {signal.Signals(signum).name})" if signum else ""
    print(f"wrote {args.out}: {sum(counts.values())} messages on {len(counts)} topics{why}")
    if args.topics:  # asked for by name: one that never came is said, and a recording of none of them failed
        got = {t.strip("/").rsplit("/", 1)[-1] for t, n in counts.items() if n}
        missing = [t for t in args.topics if t.strip("/").rsplit("/", 1)[-1] not in got]
        if missing:
            print(f"belt-drive: warning: no message on {', '.join(missing)} during the recording", file=sys.stderr)
        if not any(counts.values()):
            return 1
    return 0
