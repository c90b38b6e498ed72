"""Recording, decoding and offline-replay throughput (prints figures; not a test).

``python -m belt_drive_ros.benchmarks.recording [--minutes 60] [--skip-live] [--profile]``

1. *Write*: :class:`msg_tools.Ros2McapWriter.write_raw` of Float64 and
   JointState CDR, no DDS (the recorder's cost per message).
2. *Record live*: a publisher and a :class:`~belt_drive_ros.io.recording.TopicRecorder`
   (raw subscription -> MCAP) on one rclpy context and executor, loopback
   DDS: messages recorded per second of wall time, publisher flat out.
3. *Decode*: :func:`msg_tools.read_topic` (vectorized) of Float64 and
   JointState topics.
4. *Offline replay*: a 1-hour 1 kHz ``drive_torque`` bag (3.6 M messages,
   generated in a temporary folder, not timed) read and run through the
   model with :func:`~belt_drive_ros.io.torque_bag.scene_with_torque_bag` and
   :func:`~belt_drive_ros.core.simulate.simulate` on the ``engine_idle``
   reference scene (flexible belt, compressor load depending on the angle),
   at dt = 1 ms (one step per sample) and at the scene's 0.5 ms. Target: < 60 s.
   With ``--profile`` (or when the target is missed) the top functions of
   a cProfile run of the replay are printed.

Figures are wall-clock seconds on this machine (``time.perf_counter``),
single runs: the machine may be shared, so read them as order of magnitude.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path
from typing import List, Optional

import numpy as np

TARGET_S = 60.0


def _line(label: str, value: str) -> None:
    print(f"  {label:<44s} {value}", flush=True)


def bench_write(n: int = 200_000) -> dict:
    """Messages/s of ``write_raw`` into an MCAP file (Float64, JointState)."""
    from msg_tools import Ros2McapWriter

    from ..io.recording import encode_float64, encode_joint_states

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        f64 = encode_float64(np.sin(np.arange(n) * 1e-3))
        t = (np.arange(n) * 1_000_000).tolist()
        start = time.perf_counter()
        with Ros2McapWriter(Path(tmp) / "f.mcap") as w:
            for k in range(n):
                w.write_raw("/shaft_speed", "std_msgs/msg/Float64", f64[k], t[k])
        out["float64"] = n / (time.perf_counter() - start)
        m = n // 4
        js = encode_joint_states(np.arange(m) * 1_000_000, *(np.random.default_rng(0).normal(size=(3, m, 4))))
        start = time.perf_counter()
        with Ros2McapWriter(Path(tmp) / "j.mcap") as w:
            for k in range(m):
                w.write_raw("/joint_states", "sensor_msgs/msg/JointState", js[k], t[k])
        out["joint_states"] = m / (time.perf_counter() - start)
        out["files"] = {"float64": (Path(tmp) / "f.mcap").stat().st_size / n,
                        "joint_states": (Path(tmp) / "j.mcap").stat().st_size / m}
    return out


def bench_decode(n: int = 1_000_000) -> dict:
    """Messages/s of :func:`msg_tools.read_topic` for Float64 and JointState."""
    from msg_tools import Ros2McapWriter, read_topic

    from ..io.recording import encode_float64, encode_joint_states

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "d.mcap"
        m = n // 4
        f64 = encode_float64(np.arange(n, dtype=float))
        js = encode_joint_states(np.arange(m) * 1_000_000, *(np.random.default_rng(0).normal(size=(3, m, 4))))
        with Ros2McapWriter(path) as w:
            for k in range(n):
                w.write_raw("/shaft_speed", "std_msgs/msg/Float64", f64[k], k * 1_000_000)
                if k < m:
                    w.write_raw("/joint_states", "sensor_msgs/msg/JointState", js[k], k * 1_000_000)
        start = time.perf_counter()
        data = read_topic(path, "/shaft_speed")
        out["float64"] = len(data) / (time.perf_counter() - start)
        start = time.perf_counter()
        data = read_topic(path, "/joint_states")
        out["joint_states"] = len(data) / (time.perf_counter() - start)
        out["joint_states_decoder"] = data.decoder
    return out


def bench_record_live(n: int = 20_000, batch: int = 200) -> dict:
    """Messages/s recorded by a raw-subscription recorder from a publisher in the same process."""
    from ..ros import environment as ros_env

    ros_env.configure_environment(loopback=True)
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from msg_tools import Ros2McapWriter

    from ..ros.recorder import TopicRecorder

    context = Context()
    rclpy.init(context=context, domain_id=ros_env.process_domain_id(offset=37))
    out = {}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            node = rclpy.create_node("bench_recorder", context=context)
            recorder = TopicRecorder(node, Ros2McapWriter(Path(tmp) / "live.mcap"))
            recorder.add("/bench", "std_msgs/msg/Float64")
            pub = node.create_publisher(Float64, "/bench", QoSProfile(depth=batch, reliability=ReliabilityPolicy.RELIABLE))
            try:
                from rclpy.experimental import EventsExecutor

                executor = EventsExecutor(context=context)
            except ImportError:
                from rclpy.executors import SingleThreadedExecutor

                executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            deadline = time.monotonic() + 10
            while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.01)
            msg = Float64()
            start = time.perf_counter()
            sent = 0
            while sent < n:
                for _ in range(batch):
                    msg.data = float(sent)
                    pub.publish(msg)
                    sent += 1
                target = sent
                spin_deadline = time.monotonic() + 5
                while recorder.message_count < target and time.monotonic() < spin_deadline:
                    executor.spin_once(timeout_sec=0.01)
            elapsed = time.perf_counter() - start
            out["recorded"] = recorder.message_count
            out["sent"] = sent
            out["rate"] = recorder.message_count / elapsed
            recorder.close()
            executor.shutdown()
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return out


def make_torque_bag(path, minutes: float, rate_hz: float = 1000.0, chunk_size: int = 1 << 20) -> int:
    """An engine-like drive torque [N m] at ``rate_hz`` for ``minutes``: firing ripple on a slow speed sweep
    (chunks of ``chunk_size`` bytes)."""
    from msg_tools.block_writer import BlockMcapWriter

    from ..io.recording import float64_rows

    n = int(round(minutes * 60.0 * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    speed = 77.5 + 40.0 * np.sin(2 * np.pi * t / 600.0) ** 2  # rad/s, 10-minute cycles
    crank = np.cumsum(speed) / rate_hz
    torque = 15.0 + 300.0 * np.sin(3.0 * crank) + 90.0 * np.sin(6.0 * crank)
    times = np.round(t * 1e9).astype(np.int64)
    chunk = 100_000
    with BlockMcapWriter(path, chunk_size=chunk_size) as w:
        for a in range(0, n, chunk):
            w.write_block([("/drive_torque", "std_msgs/msg/Float64")], times[a : a + chunk], [float64_rows(torque[a : a + chunk])])
    return n


def replay_through_model(bag, dt: Optional[float]) -> dict:
    """Read the bag, build the scene, simulate; times of each part [s]."""
    from ..io.bags import reference_scene
    from ..io.torque_bag import scene_with_torque_bag
    from ..core.simulate import simulate

    base = reference_scene("engine_idle").with_overrides(model="flexible")
    t0 = time.perf_counter()
    scene = scene_with_torque_bag(base, bag)
    t1 = time.perf_counter()
    result = simulate(scene, dt=dt)
    t2 = time.perf_counter()
    return {
        "read": t1 - t0,
        "simulate": t2 - t1,
        "integrate": result.wall_time,
        "total": t2 - t0,
        "steps": result.time.size - 1,
        "simulated_s": float(result.time[-1]),
        "final_speed": float(result.outputs["omega_M"][-1]),
    }


def profile_replay(bag, dt: Optional[float], top: int = 15) -> None:
    import cProfile
    import pstats

    profiler = cProfile.Profile()
    profiler.enable()
    replay_through_model(bag, dt)
    profiler.disable()
    stats = pstats.Stats(profiler)
    stats.sort_stats("tottime").print_stats(top)


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m belt_drive_ros.benchmarks.recording", description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="length of the torque bag to replay (default 60)")
    parser.add_argument("--skip-live", action="store_true", help="skip the live (rclpy) recording benchmark")
    parser.add_argument("--profile", action="store_true", help="print a cProfile of the replay")
    args = parser.parse_args(argv)

    print("MCAP write (Ros2McapWriter.write_raw, zstd, message index, no DDS)")
    w = bench_write()
    _line("Float64", f"{w['float64']:,.0f} msg/s ({w['files']['float64']:.1f} B/msg on disk)")
    _line("JointState (4 joints)", f"{w['joint_states']:,.0f} msg/s ({w['files']['joint_states']:.1f} B/msg on disk)")

    if not args.skip_live:
        print("Live recording (publisher -> loopback DDS -> raw subscription -> MCAP, one process)")
        live = bench_record_live()
        _line("Float64 recorded", f"{live['rate']:,.0f} msg/s ({live['recorded']} of {live['sent']} messages)")

    print("Decode (msg_tools.read_topic, vectorized)")
    d = bench_decode()
    _line("Float64", f"{d['float64']:,.0f} msg/s")
    _line(f"JointState ({d['joint_states_decoder']})", f"{d['joint_states']:,.0f} msg/s")

    print(f"Offline replay of a {args.minutes:g}-minute 1 kHz torque bag through the model (target < {TARGET_S:g} s "
          f"for 60 min)")
    missed = False
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "torque_1h.mcap"
        start = time.perf_counter()
        n = make_torque_bag(bag, args.minutes)
        _line("bag generated (not timed)", f"{n:,} messages, {os.path.getsize(bag) / 2**20:.1f} MiB in "
              f"{time.perf_counter() - start:.1f} s")
        for dt, label in ((1e-3, "dt = 1 ms (one step per sample)"), (None, "dt = 0.5 ms (the scene's)")):
            r = replay_through_model(bag, dt)
            scale = 60.0 / args.minutes
            over = r["total"] * scale > TARGET_S
            missed = missed or (dt == 1e-3 and over)
            _line(label, f"{r['total']:.1f} s total: read {r['read']:.1f} s, simulate {r['simulate']:.1f} s "
                  f"(integration {r['integrate']:.1f} s, {r['steps']:,} steps, "
                  f"{r['steps'] / max(r['integrate'], 1e-9) / 1e6:.2f} M steps/s, "
                  f"{r['simulated_s'] / max(r['total'], 1e-9):,.0f}x real time)"
                  + (f" -> {r['total'] * scale:.0f} s per hour" if args.minutes != 60 else "")
                  + ("  MISSES TARGET" if over else ""))
        if args.profile or missed:
            print("Profile of the replay at dt = 1 ms (top functions by own time):")
            profile_replay(bag, 1e-3)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
