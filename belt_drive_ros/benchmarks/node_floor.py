"""The floor under ``belt-drive bench node``: rclpy and DDS on this machine, without the belt drive.

A process shaped like ``belt-drive node`` with the physics taken out: the
same session (:func:`~belt_drive_ros.ros.executors.ros_session`: loopback
discovery, single-threaded BLAS, no timer slack), the same executor, a timer
at ``--rate`` whose callback stamps the tick on the node's grid (system
clock, origin at the first tick), packs the node's ``joint_states`` CDR
(:class:`~belt_drive_ros.io.recording.JointStateEncoder`, wheel_M effort =
the latest ``drive_torque``, as the node echoes it) and publishes it with the
node's QoS. Everything the benchmark measures on it (achieved rate, one-way
latency, CPU) is what any Python node on rclpy gets on this machine: the
node's figures beside these show what the model and its tick add.

Not a user command: ``belt-drive bench node --floor`` starts it as its second
child. ``python -m belt_drive_ros.benchmarks.node_floor --rate 1000``.
"""

from __future__ import annotations

import argparse
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m belt_drive_ros.benchmarks.node_floor", description=__doc__.split("\n\n")[0])
    p.add_argument("--rate", type=float, default=1000.0, help="tick rate [Hz] (default 1000)")
    p.add_argument("--executor", choices=("auto", "events", "single"), default="auto", help="executor (default auto)")
    args = p.parse_args(argv)
    if not (args.rate > 0):
        p.error("--rate must be > 0")

    from ..io.recording import JointStateEncoder
    from ..ros.executors import ros_session, spin_nodes
    from ..ros.qos import INPUT_QOS, OUTPUT_QOS

    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    period_ns = round(1e9 / args.rate)
    with ros_session() as context:
        node = Node("belt_drive_floor", context=context)
        encoder = JointStateEncoder(4)
        pub = node.create_publisher(JointState, "joint_states", OUTPUT_QOS)
        torque = [0.0]
        node.create_subscription(Float64, "drive_torque", lambda msg: torque.__setitem__(0, msg.data), INPUT_QOS)
        origin = [None]
        zeros = (0.0,) * 8

        def tick():
            now = time.time_ns()
            if origin[0] is None:  # the time this first call was scheduled for, as the node starts its grid
                remaining = timer.time_until_next_call()
                origin[0] = now + remaining - period_ns if remaining is not None and 0 <= remaining <= period_ns else now
            now -= (now - origin[0]) % period_ns  # the latest grid point, as the node stamps
            pub.publish(encoder.encode(now, (*zeros, torque[0], 0.0, 0.0, 0.0)))

        timer = node.create_timer(period_ns / 1e9, tick)
        spin_nodes([node], context, executor=args.executor)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
