"""``belt-drive replay``: publish a recorded drive torque on ROS 2."""

from __future__ import annotations

import argparse
from pathlib import Path

EPILOG = """\
examples:
  belt-drive replay bags/engine_idle_torque.mcap
  belt-drive replay run.mcap --rate 0.5 --loop --start-offset 1.0
  belt-drive replay run.mcap --clock            # node with use_sim_time:=true follows
  belt-drive replay run.mcap --clock --sync /joint_states --rate 100   # lockstep, fast, deterministic
  belt-drive replay run.mcap --ros-args -r __ns:=/truck      # into the node of namespace /truck
  belt-drive replay node_run.mcap --topic /drive_torque_applied --clock --sync /joint_states

Publishes the recorded std_msgs/Float64 messages of --topic (default
/drive_torque) on --to (default drive_torque, the node's input: in the
replay's namespace) with their recorded spacing divided by --rate. With --clock it
publishes /clock = the message's recorded time right after each message, so
a belt-drive node with use_sim_time ticks to that time and samples the new
torque there: the same zero-order hold as 'belt-drive sim SCENE --torque-bag BAG'.
Without --sync the node must keep up (a loaded machine can make it take two
/clock samples at once); --sync waits for the node's output at each time, so
the run is deterministic; if the node stops answering (it ended), the replay
ends with an error (exit 1). Looping shifts each pass by the span plus one
sample period (the clock keeps increasing). Offline and deterministic instead: belt-drive sim --torque-bag.
"""


def register(sub) -> None:
    p = sub.add_parser(
        "replay",
        help="publish the drive_torque recorded in an MCAP file (optionally with /clock)",
        description="Publish a recorded drive torque with its original timing (scaled by --rate).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("bag", type=Path, help="MCAP file with std_msgs/Float64 drive torque messages")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor, 0.001 to 1000 (default 1)")
    p.add_argument("--loop", action="store_true", help="repeat until interrupted")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S",
                   help="start this many seconds into the recording")
    p.add_argument("--clock", action="store_true", help="publish /clock = the message's time after each message")
    p.add_argument("--topic", default="/drive_torque", help="topic to read from the bag (default /drive_torque)")
    p.add_argument("--to", default="drive_torque", metavar="TOPIC",
                   help="topic to publish on (default drive_torque: the node's input, in the namespace of "
                        "--ros-args -r __ns:=..., whatever the bag's topic is named, e.g. /drive_torque_applied)")
    p.add_argument("--wait-subscribers", type=int, default=0, metavar="N",
                   help="wait (up to 10 s) for N matched subscribers (on the torque topic and /clock) before starting")
    p.add_argument("--sync", metavar="TOPIC",
                   help="with --clock: after each message and its /clock wait until TOPIC (sensor_msgs/JointState, e.g. "
                        "/joint_states) is stamped at its time: lockstep, deterministic")
    p.add_argument("--delay", type=float, default=0.0, metavar="S",
                   help="wait S seconds (wall clock) before the first message")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument("--ros-args", nargs=argparse.REMAINDER, default=[], dest="ros_args",
                   help="ROS arguments for the replay node (everything after it)")
    p.set_defaults(func=run)


def run(args) -> int:
    import signal
    import sys

    from ..io.recording import BagReadError
    from ..ros.replay import run_replay

    from ..core.errors import ParameterError

    # (exit 2 like every bad input, before rclpy starts)
    if not 1e-3 <= args.rate <= 1e3:  # (1e-300 slowed one second of bag to 1e292 years: a hang, not a replay)
        raise ParameterError("--rate", f"must be 0.001 to 1000, got {args.rate!r}")
    if args.sync and not args.clock:
        raise ParameterError("--sync", "needs --clock")
    if not 0 <= args.delay < float("inf"):
        raise ParameterError("--delay", f"must be finite and >= 0 s, got {args.delay!r}")
    if not 0 <= args.start_offset < float("inf"):
        raise ParameterError("--start-offset", f"must be finite and >= 0 s, got {args.start_offset!r}")
    if args.wait_subscribers < 0:
        raise ParameterError("--wait-subscribers", f"must be >= 0, got {args.wait_subscribers!r}")
    from ..ros.executors import stop_on_signals

    def log(text: str) -> None:
        if not args.quiet or text.startswith("warning"):
            print(("belt-drive: " if text.startswith("warning") else "") + text, file=sys.stderr, flush=True)

    from ..ros.replay import SyncNeverAnswered

    with stop_on_signals() as stop:
        try:
            count = run_replay(
                args.bag, rate=args.rate, loop=args.loop, start_offset=args.start_offset, clock=args.clock,
                topic=args.topic, out_topic=args.to, wait_subscribers=args.wait_subscribers, delay=args.delay,
                sync_topic=args.sync,
                ros_args=args.ros_args, should_stop=stop.done, log=log,
            )
        except ValueError as exc:  # schedule: offset past the end, ...
            if isinstance(exc, BagReadError):
                raise
            raise BagReadError(f"{args.bag}: {exc}") from None
        except SyncNeverAnswered as exc:  # the run failed (its input was fine): exit 1
            print(f"belt-drive: error: {exc}", file=sys.stderr)
            return 1
    if not args.quiet:
        print(f"published {count} messages", file=sys.stderr)
    if stop.signum:  # interrupted (SIGINT, SIGTERM): the shell's status of a process ended by it, as other commands
        print(f"belt-drive: interrupted ({signal.Signals(stop.signum).name}) after {count} message(s)", file=sys.stderr)
        return 128 + stop.signum
    return 0
