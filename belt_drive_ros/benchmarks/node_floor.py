"""The floor under ``belt-drive bench node``: rclpy and DDS on this machine, without the belt drive.

A process shaped like ``belt-drive node`` with the physics taken out: the
same session (:func:`~belt_drive_ros.ros.executors.ros_session`: loopback
discovery, single-threaded BLAS, no timer slack), the same executor, the same
tick source, the same raw ``drive_torque`` subscription, and the node's ``joint_states`` CDR
(:class:`~belt_drive_ros.io.recording.JointStateEncoder`, wheel_M effort =
the latest ``drive_torque``, as the node echoes it) published with the
node's QoS and stamped on the node's grid (system clock, origin at the
first tick). The tick source is the node's default: a thread of its own
that wakes ``--lead`` before each tick's due time, packs the message, sleeps
to the due time and publishes (:class:`~belt_drive_ros.ros.timing.TickThread`);
``--timer`` ticks from an executor timer instead (the node's
``tick_thread:=false``). Where it is simpler than the node's tick thread:
a fixed lead (no adaptation: its ticks cost microseconds), no limit on
catching up after a stall, and an exception ends its thread with Python's
own traceback. Everything the benchmark measures on it (achieved
rate, one-way latency, CPU) is what a Python node on rclpy gets on this
machine: the node's figures beside these show what the model and its tick
add.

Not a user command: ``belt-drive bench node --floor`` starts it as its second
child. ``python -m belt_drive_ros.benchmarks.node_floor --rate 1000``.
"""

from __future__ import annotations

import argparse
import threading
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m belt_drive_ros.benchmarks.node_floor", description=__doc__.split("\n\n")[0])
    p.add_argument("--rate", type=float, default=1000.0, help="tick rate [Hz] (default 1000)")
    p.add_argument("--executor", choices=("auto", "events", "single"), default="auto", help="executor (default auto)")
    p.add_argument("--lead", type=float, default=0.0003, help="the tick thread's lead [s] (the node's tick_lead; default 0.0003)")
    p.add_argument("--timer", action="store_true", help="tick from an executor timer (the node's tick_thread:=false)")
    p.add_argument("--joints", help="joint_states' joint names, comma-separated (a belt network's; default the paper "
                   "drive's four)")
    args = p.parse_args(argv)
    if not (args.rate > 0):
        p.error("--rate must be > 0")
    if not (0 <= args.lead < 1.0 / args.rate):
        p.error("--lead must be >= 0 and shorter than a period")

    from ..io.recording import JointStateEncoder
    from ..ros import environment as ros_env
    from ..ros.executors import ros_session, spin_nodes
    from ..ros.inputs import float64_value
    from ..ros.qos import INPUT_QOS, OUTPUT_QOS

    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    period_ns = round(1e9 / args.rate)
    lead_ns = min(round(args.lead * 1e9), period_ns * 3 // 4)  # the node's cap
    stop = threading.Event()
    with ros_session() as context:
        node = Node("belt_drive_floor", context=context)
        names = args.joints.split(",") if args.joints else None
        encoder = JointStateEncoder(names=names)
        joints = len(names) if names else 4
        pub = node.create_publisher(JointState, "joint_states", OUTPUT_QOS)
        torque = [0.0]
        lock = threading.RLock()  # the node's callbacks and ticks hold one

        def on_torque(data):  # raw, as the node takes it
            value = float64_value(data)
            with lock:
                torque[0] = value

        node.create_subscription(Float64, "drive_torque", on_torque, INPUT_QOS, raw=True)
        zeros = (0.0,) * (2 * joints)  # positions, velocities; then the efforts: the torque first (the node's driver)
        rest = (0.0,) * (joints - 1)

        def run_thread(origin):
            """The node's TickThread without the model: wake lead early, pack, sleep to the due time, publish."""
            ros_env.reduce_timer_slack()
            ros_env.name_thread(ros_env.TICK_THREAD)  # (the node's tick thread's name: bench node reads its CPU time)
            now_ns, sleep = time.time_ns, time.sleep
            due = origin
            while not stop.is_set():
                wait = (due - lead_ns - now_ns()) * 1e-9
                if wait > 0:
                    sleep(wait)
                with lock:
                    data = encoder.encode(due, (*zeros, torque[0], *rest))
                wait = (due - now_ns()) * 1e-9
                if wait > 0:
                    sleep(wait)
                pub.publish(data)
                due += period_ns

        threads = []
        origin = [None]

        def tick():
            now = time.time_ns()
            if origin[0] is None:  # the time this first call was scheduled for, as the node starts its grid
                remaining = timer.time_until_next_call()
                origin[0] = now + remaining - period_ns if remaining is not None and 0 <= remaining <= period_ns else now
                origin[0] -= origin[0] % 1000
                if not args.timer:  # the thread ticks from now on
                    timer.cancel()
                    threads.append(threading.Thread(target=run_thread, args=(origin[0],), daemon=True))
                    threads[0].start()
                    return
            with lock:
                now -= (now - origin[0]) % period_ns  # the latest grid point, as the node stamps
                pub.publish(encoder.encode(now, (*zeros, torque[0], *rest)))

        timer = node.create_timer(period_ns / 1e9, tick)

        def stopped(_signum):
            stop.set()
            for thread in threads:
                thread.join(timeout=5.0)

        spin_nodes([node], context, executor=args.executor, stopped=stopped)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
