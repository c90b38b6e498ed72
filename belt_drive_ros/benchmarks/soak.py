"""``belt-drive bench soak``: the recording node over a long run (prints figures; not a test).

Runs ``belt-drive node`` as a child process on the system clock at
``--rate`` (default 1 kHz), recording to a bag folder split every
``--max-bag-duration`` seconds (0: one file), for ``--seconds`` (default
60) after a ``--warmup``, while this process publishes ``drive_torque`` at
~97 Hz and subscribes to ``joint_states``. It prints:

* **RSS growth** of the node process: VmRSS (``/proc/PID/status``) sampled
  every second; growth per minute = the least-squares slope of RSS over
  time [KiB/min], and the first and last samples;
* **output rate per window**: ``joint_states`` received in each
  ``--window`` (default 10 s) divided by its length [Hz], min / median / max;
* **messages lost**: the ticks the node made inside the measured span (its
  recording holds every tick it makes, written from the tick) whose
  ``joint_states`` never reached this process over DDS; and, apart, the
  ticks the node **skipped** on its 1/rate grid (a timer call later than a
  period integrates to the latest grid tick: such a tick is never made, so
  it is not lost).

Usage::

    belt-drive bench soak --seconds 600
    python -m belt_drive_ros.benchmarks.soak --seconds 60 --max-bag-duration 0
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="belt-drive bench soak", description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=60.0, help="measured seconds (default 60)")
    p.add_argument("--warmup", type=float, default=5.0, help="seconds before the measurement starts (default 5)")
    p.add_argument("--window", type=float, default=10.0, help="rate window [s] (default 10)")
    p.add_argument("--rate", type=float, default=1000.0, help="node tick rate [Hz] (default 1000)")
    p.add_argument("--scene", default="paper", help="scene (default paper)")
    p.add_argument("--executor", choices=("auto", "events", "single"), default="auto", help="the node's executor")
    p.add_argument("--max-bag-duration", type=float, default=60.0,
                   help="split the recording every this many seconds (default 60; 0: one file)")
    p.add_argument("--record", type=Path, help="recording path (default: a temporary folder, removed afterwards)")
    p.add_argument("--out", type=Path, help="also write soak.md here")
    p.add_argument("--memprobe", type=Path, metavar="DIR",
                   help="run the node with its memory probe (belt_drive_ros.ros.memprobe) writing to DIR, and report "
                        "where RSS grows: Python blocks, malloc in-use and free bytes (growth per minute)")
    p.add_argument("--memprobe-frames", type=int, default=0, metavar="N",
                   help="with --memprobe: tracemalloc with N frames, snapshots diffed first to last (slows the node)")
    return p.parse_args(argv)


def _rss_kib(pid: int) -> int:
    """Resident set size [KiB] of process ``pid`` (Linux /proc)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for process {pid}")


def _recorded_stamps(path: Path):
    """(stamps [ns] of the recorded joint_states, number of files) of the recording at ``path``."""
    from msg_tools import bag_files, read_topic

    return read_topic(path, "/joint_states").stamp_ns, len(bag_files(path))


def measure(args) -> dict:
    """Run the recording child node and this process's probe; return the figures."""
    from ..ros import environment as ros_env

    ros_env.configure_environment(loopback=True)
    import numpy as np
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.task import Future
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from ..io.scenes import is_network
    from ..ros.executors import make_executor

    tmp = None
    record = args.record
    if record is None:
        tmp = tempfile.mkdtemp(prefix="belt_drive_soak_")
        record = Path(tmp) / "soak"
    if not args.max_bag_duration and record.suffix.lower() != ".mcap":
        record = record.with_suffix(".mcap")
    domain = ros_env.process_domain_id(offset=29)
    cmd = [
        sys.executable, "-m", "belt_drive_ros.cli", "node", args.scene, "--executor", args.executor,
        "--record", str(record), "--force",
        *(["--max-bag-duration", str(args.max_bag_duration)] if args.max_bag_duration else []),
        "--ros-args", "-p", f"step_rate_hz:={float(args.rate)}", "--log-level", "warn",
        *(() if is_network(args.scene) else ("-p", "input_timeout:=0.0")),  # (a network node has no input timeout)
    ]
    probe_env = {}
    if args.memprobe is not None:
        from ..ros import memprobe

        probe_env = {memprobe.ENV: str(args.memprobe), memprobe.ENV_PERIOD: str(max(min(args.window, 60.0), 1.0)),
                     memprobe.ENV_FRAMES: str(args.memprobe_frames)}
    child = subprocess.Popen(cmd, env=ros_env.child_environment(domain, **probe_env), stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    probe = Node("soak_probe", context=context)
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    received: list[tuple[float, int]] = []  # (receipt monotonic s, stamp ns)
    probe.create_subscription(
        JointState, "joint_states",
        lambda m: received.append((time.monotonic(), m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)),
        qos)
    pub = probe.create_publisher(Float64, "drive_torque", QoSProfile(depth=10))
    count = [0]

    def send_torque():
        count[0] += 1
        pub.publish(Float64(data=2.0 + math.sin(count[0] * 0.01)))

    ex = make_executor(context, "auto")
    ex.add_node(probe)
    never = Future()
    rss: list[tuple[float, int]] = []
    code = None
    try:
        deadline = time.monotonic() + 60.0
        while not received:
            if child.poll() is not None:
                raise RuntimeError(f"the node exited ({child.returncode}):\n{child.stderr.read()[-2000:]}")
            if time.monotonic() > deadline:
                raise RuntimeError("the node did not publish within 60 s")
            ex.spin_until_future_complete(never, timeout_sec=0.1)
        probe.create_timer(1.0 / 97.0, send_torque)
        end_warmup = time.monotonic() + args.warmup
        while time.monotonic() < end_warmup:
            ex.spin_until_future_complete(never, timeout_sec=0.1)
        t0 = time.monotonic()
        first = len(received)
        next_rss = t0
        while (now := time.monotonic()) < t0 + args.seconds:
            if now >= next_rss:
                rss.append((now - t0, _rss_kib(child.pid)))
                next_rss += 1.0
            if child.poll() is not None:
                raise RuntimeError(f"the node exited ({child.returncode}):\n{child.stderr.read()[-2000:]}")
            ex.spin_until_future_complete(never, timeout_sec=min(0.1, max(t0 + args.seconds - now, 0.001)))
        rss.append((time.monotonic() - t0, _rss_kib(child.pid)))
        rows = received[first:]
    finally:
        if child.poll() is None:
            child.send_signal(signal.SIGINT)
        try:
            code = child.wait(timeout=30)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
        ex.shutdown()
        probe.destroy_node()
        rclpy.try_shutdown(context=context)
    try:
        period_ns = round(1e9 / args.rate)
        stamps = np.unique(np.array([s for _, s in rows], dtype=np.int64))
        expected = int(round((stamps[-1] - stamps[0]) / period_ns)) + 1 if stamps.size else 0
        times = np.array([t for t, _ in rows]) - t0
        edges = np.arange(0.0, args.seconds + 1e-9, args.window)
        if edges[-1] < args.seconds - 1e-9:
            edges = np.append(edges, args.seconds)
        per_window = np.histogram(times, bins=edges)[0] / np.diff(edges)
        t_rss, kib = (np.array(v, dtype=float) for v in zip(*rss))
        slope = float(np.polyfit(t_rss / 60.0, kib, 1)[0]) if t_rss.size > 2 else math.nan
        recorded, files = _recorded_stamps(record)
        in_span = recorded[(recorded >= stamps[0]) & (recorded <= stamps[-1])] if stamps.size else recorded[:0]
        steps = np.rint(np.diff(in_span) / period_ns)
        skipped = int(np.sum(np.maximum(steps - 1, 0)))
        lost = int(np.setdiff1d(in_span, stamps).size)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return {
        "seconds": args.seconds, "rate_set_hz": args.rate, "executor": args.executor, "scene": args.scene,
        "max_bag_duration_s": args.max_bag_duration, "exit_code": code,
        "rss_first_kib": int(kib[0]), "rss_last_kib": int(kib[-1]), "rss_growth_kib_per_min": slope,
        "windows": per_window.tolist(), "window_s": args.window,
        "rate_min_hz": float(per_window.min()), "rate_median_hz": float(np.median(per_window)),
        "rate_max_hz": float(per_window.max()),
        "ticks": int(in_span.size), "grid_ticks": expected, "skipped": skipped, "lost_dds": lost,
        "recorded": int(recorded.size), "files": files,
        "load_average": os.getloadavg()[0],
        "memprobe": _memprobe_figures(args.memprobe, args.warmup) if args.memprobe is not None else None,
    }


def _memprobe_figures(folder: Path, warmup: float) -> dict:
    """Growth per minute of each memory probe column after the warm-up, and the top tracemalloc growth."""
    import numpy as np

    from ..ros import memprobe

    rows = [r for r in memprobe.read_rows(folder)]
    late = [r for r in rows if r["elapsed_s"] >= warmup + 10.0] or rows
    out = {"samples": len(late)}
    if len(late) > 2:
        t = np.array([r["elapsed_s"] for r in late]) / 60.0
        for column in memprobe.COLUMNS[1:]:
            scale = 1024.0 if column == "rss_kib" else 1.0
            out[column] = float(np.polyfit(t, np.array([r[column] for r in late]) * scale, 1)[0])
    snaps = sorted(folder.glob("snap_*.bin"))
    out["top"] = memprobe.growth(snaps[1 if len(snaps) > 2 else 0], snaps[-1]) if len(snaps) >= 2 else []
    return out


def report(f: dict) -> str:
    split = f"split every {f['max_bag_duration_s']:g} s" if f["max_bag_duration_s"] else "one file"
    return "\n".join([
        f"belt-drive soak: {f['seconds']:g} s at {f['rate_set_hz']:g} Hz recording ({split}), scene {f['scene']}, "
        f"executor {f['executor']}, load average {f['load_average']:.2f}, {os.cpu_count()} CPUs; node exit {f['exit_code']}",
        f"  RSS growth             {f['rss_growth_kib_per_min']:+.1f} KiB/min (least squares over 1 s samples; "
        f"{f['rss_first_kib'] / 1024:.1f} -> {f['rss_last_kib'] / 1024:.1f} MiB)",
        f"  rate per {f['window_s']:g} s window   min {f['rate_min_hz']:.1f} Hz, median {f['rate_median_hz']:.1f} Hz, "
        f"max {f['rate_max_hz']:.1f} Hz ({len(f['windows'])} windows of joint_states received)",
        f"  messages lost          {f['lost_dds']} of the node's {f['ticks']} ticks in the window never "
        f"arrived (DDS); the recording holds all {f['ticks']} ({f['recorded']} in {f['files']} file(s) "
        f"with warm-up and stop)",
        f"  ticks skipped          {f['skipped']} of {f['grid_ticks']} on the 1/rate grid (late timer calls "
        "integrate to the latest tick; not lost, never made)",
    ] + _memprobe_lines(f.get("memprobe")))


def _memprobe_lines(m) -> list:
    if not m or "rss_kib" not in m:
        return []
    lines = [f"  memory probe (per minute, {m['samples']} samples after warm-up): RSS {m['rss_kib'] / 1024:+.1f} KiB, "
             f"Python blocks {m['py_blocks']:+.0f}, malloc in use {m['malloc_used'] / 1024:+.1f} KiB, "
             f"malloc free {m['malloc_free'] / 1024:+.1f} KiB, mmap {m['malloc_mmap'] / 1024:+.1f} KiB, "
             f"traced {m['traced'] / 1024:+.1f} KiB"]
    lines += [f"    {size:+d} B in {count:+d} blocks: {where}" for size, count, where in m.get("top", [])[:5]]
    return lines


def main(argv=None) -> int:
    args = parse_args(argv)
    if not (args.seconds > 0 and args.window > 0 and args.warmup >= 0 and args.max_bag_duration >= 0):
        raise SystemExit("belt-drive: error: --seconds and --window must be > 0, --warmup and --max-bag-duration >= 0")
    figures = measure(args)
    text = report(figures)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        from ..io.atomic import write_output

        write_output(args.out / "soak.md", "```\n" + text + "\n```\n", force=True)
        print(f"wrote {args.out / 'soak.md'}")
    return 0 if figures["exit_code"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
