"""A long 1 kHz torque bag replayed offline to MCAP, this tree beside another checkout (prints figures; not a test).

``belt-drive bench replay --minutes 60 [--baseline DIR]``: the bag (an
engine-like drive torque, generated once, not timed) goes through what
``belt-drive sim SCENE --torque-bag BAG --out OUT.mcap`` runs: read the bag
(:func:`~belt_drive_ros.io.torque_bag.scene_with_torque_bag`), the windows of
:func:`~belt_drive_ros.core.stream.stream` (simulation) and
:class:`~belt_drive_ros.io.run_writers.McapWindows` (writing: encoding,
blocks, waiting for the compression threads). Each run is a fresh child
process, so its peak resident memory (``VmHWM``; ``ru_maxrss`` would keep the bench's own
peak across the exec) is its own: with
``--baseline DIR`` (a checkout of another commit, e.g. ``git worktree add ../old v1``, its
numba cache warm) the same measurement runs on that code too, the runs
alternating, on the same bag, in one invocation. The child's code uses only
the public calls both trees have. This tree also runs once with every window
written in the caller's thread (``McapWindows(background=False)``): beside
the default, where a thread of its own writes while the next window is
simulated, it shows what that overlap gains. Whether the runs wrote the same
output is said twice: the same bytes (the hour's files), and the same
messages, the chunks' records decompressed (the shorter bag's files: a
compression setting changes the bytes, never the messages).
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

#: issue 20: a 1-hour 1 kHz torque bag replayed offline to MCAP [s of wall time]
REPLAY_TARGET_S = 8.0

_CHILD = r'''
import json, os, resource, sys, time
bag, out, caller = sys.argv[1], sys.argv[2], len(sys.argv) > 3
from belt_drive_ros.core.stream import stream
from belt_drive_ros.io.bags import reference_scene
from belt_drive_ros.io.run_writers import McapWindows
from belt_drive_ros.io import torque_bag
from belt_drive_ros.core import kernel  # noqa: F401 (numba loaded before the clock starts, as sim's import does)

def peak():  # this process's own high-water mark (ru_maxrss keeps the parent's across the exec on Linux)
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime

base = peak()
start, cpu0, main0 = time.perf_counter(), cpu(), time.thread_time()
base_scene = reference_scene("engine_idle").with_overrides(model="flexible", dt=1e-3)
paged = getattr(torque_bag, "paged_torque_bag", None)  # (what sim runs for a streamed run; an older tree has none)
scene = (paged(base_scene, bag) if paged else None) or torque_bag.scene_with_torque_bag(base_scene, bag)
read = time.perf_counter() - start
read_cpu = time.thread_time() - main0
after_read = peak()
simulate = write = simulate_cpu = write_cpu = 0.0
samples = 0
with open(out, "wb") as f:
    sink = McapWindows(f, start_time_ns=0, **({"background": False} if caller else {}))
    windows = stream(scene)
    while True:
        a, ca = time.perf_counter(), time.thread_time()
        window = next(windows, None)
        b, cb = time.perf_counter(), time.thread_time()
        simulate += b - a
        simulate_cpu += cb - ca
        if window is None:
            break
        samples += len(window.time)
        sink.add(window)
        write += time.perf_counter() - b
        write_cpu += time.thread_time() - cb
    a, ca = time.perf_counter(), time.thread_time()
    counts = sink.close()
    write += time.perf_counter() - a
    write_cpu += time.thread_time() - ca
total = time.perf_counter() - start
print(json.dumps({"read": read, "simulate": simulate, "write": write, "total": total, "cpu": cpu() - cpu0,
                  "read_cpu": read_cpu, "simulate_cpu": simulate_cpu, "write_cpu": write_cpu, "samples": samples, "messages": sum(counts.values()), "bytes": os.path.getsize(out),
                  "peak": peak(), "base": base, "after_read": after_read, "drive": type(scene.drive).__name__,
                  "pages_cpu": getattr(scene.drive, "read_cpu", 0.0), "writer_cpu": getattr(sink, "write_cpu", None)}))
'''


def _child(code_root: Path, bag: Path, out: Path, caller: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(code_root), OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", _CHILD, str(bag), str(out)] + (["caller"] if caller else []), env=env,
                          cwd=str(code_root),
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"belt-drive: error: the replay under {code_root} failed: "
                         f"{(done.stderr.strip().splitlines() or ['?'])[-1]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _records_digest(path: Path) -> str:
    """SHA-256 of a file's chunks' records, decompressed: the same messages (channels, sequence numbers,
    times and CDR bytes, so the same decoded values) in the same order, whatever the compression."""
    import zstandard
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for record in StreamReader(f, skip_magic=False, emit_chunks=True).records:
            if isinstance(record, Chunk):
                if record.compression == "zstd":
                    data = zstandard.ZstdDecompressor().decompress(record.data, max_output_size=record.uncompressed_size)
                elif record.compression == "lz4":
                    import lz4.frame

                    data = lz4.frame.decompress(record.data)
                else:
                    data = record.data
                digest.update(data)
    return digest.hexdigest()


def _line(label: str, value: str) -> None:
    print(f"  {label:<30s} {value}", flush=True)


def main(minutes: float = 60.0, baseline: str | None = None, repeat: int = 1) -> int:
    """Print the split (read / simulation / writing), wall, CPU and peak memory of this tree (and the baseline's)."""
    from .recording import make_torque_bag

    own = Path(__file__).resolve().parents[2]
    # this tree twice: windows written by McapWindows' thread (what sim runs), and in the caller's thread
    trees = [("this tree", own, False), ("this tree, writing in the caller's thread", own, True)] + (
        [("baseline", Path(baseline).resolve(), False)] if baseline else [])
    print(f"Offline replay of a {minutes:g}-minute 1 kHz torque bag to MCAP (belt-drive sim SCENE --torque-bag BAG "
          f"--out OUT.mcap; engine_idle, flexible, dt = 1 ms; target <= {REPLAY_TARGET_S:g} s for 60 min)")
    with tempfile.TemporaryDirectory() as tmp:
        bag, short = Path(tmp) / "torque.mcap", Path(tmp) / "short.mcap"
        n = make_torque_bag(bag, minutes)
        make_torque_bag(short, minutes / 6.0)
        _line("bags (not timed)", f"{n:,} messages, {bag.stat().st_size / 2**20:.1f} MiB; and one a sixth as long "
              "(the growth of peak memory per sample is the slope between the two)")
        results: dict = {name: [] for name, _, _ in trees}
        shorts: dict = {name: [] for name, _, _ in trees}
        digests: dict = {}
        messages: dict = {}
        for _ in range(max(1, repeat)):
            for name, root, caller in trees:
                out = Path(tmp) / "out.mcap"
                results[name].append(_child(root, bag, out, caller))
                digests.setdefault(name, hashlib.sha256(out.read_bytes()).hexdigest())
                out.unlink()
                shorts[name].append(_child(root, short, out, caller))
                messages.setdefault(name, _records_digest(out))
                out.unlink()
    scale = 60.0 / minutes
    for name, root, _ in trees:
        print(f"{name} ({root}):")
        for r, q in zip(results[name], shorts[name]):
            _line("wall", f"{r['total']:.2f} s ({r['total'] * scale:.1f} s per hour; target <= {REPLAY_TARGET_S:g}: "
                  f"{'met' if r['total'] * scale <= REPLAY_TARGET_S else 'MISSED'})")
            _line("  read the bag", f"{r['read']:.2f} s (main thread CPU {r['read_cpu']:.2f} s)")
            _line("  simulation", f"{r['simulate']:.2f} s (main thread CPU {r['simulate_cpu']:.2f} s; "
                  f"{r['samples'] / max(r['simulate'], 1e-9) / 1e6:.2f} M samples/s)")
            if r.get("pages_cpu"):  # a bag read in pages: the chunks decoded (opening pass included)
                _line("  decoding the bag's pages", f"main thread CPU {r['pages_cpu']:.2f} s (in the read and the simulation)")
            _line("  writing", f"{r['write']:.2f} s (main thread CPU {r['write_cpu']:.2f} s; "
                  f"{r['messages'] / max(r['write'], 1e-9) / 1e6:.2f} M messages/s)")
            if r.get("writer_cpu") is not None:  # windows written by a thread of their own (overlapping the simulation)
                _line("  encoding and assembling", f"CPU {r['writer_cpu']:.2f} s (all windows, in whichever thread; "
                      "compression apart)")
            _line("process CPU", f"{r['cpu']:.2f} s (other threads included: "
                  f"{r['cpu'] - r['read_cpu'] - r['simulate_cpu'] - r['write_cpu']:.2f} s beside the main thread)")
            _line("output", f"{r['messages']:,} messages, {r['bytes'] / 2**20:.0f} MiB (drive: {r.get('drive', '?')})")
            grow = (r["peak"] - q["peak"]) / max(r["samples"] - q["samples"], 1)
            _line("peak RSS", f"{r['peak'] / 2**20:.0f} MiB (after imports {r['base'] / 2**20:.0f} MiB, after reading "
                  f"{r['after_read'] / 2**20:.0f} MiB); a sixth as long: {q['peak'] / 2**20:.0f} MiB: "
                  f"{grow:+.1f} B per bag sample")
    same = len(set(digests.values())) == 1
    print(f"output MCAP of the {minutes:g}-minute bag: {'the same bytes' if same else 'DIFFERENT bytes'} in every run above")
    same = len(set(messages.values())) == 1
    print(f"output MCAP of the {minutes / 6.0:g}-minute bag, its chunks decompressed: "
          f"{'the same messages (the same decoded values)' if same else 'DIFFERENT messages'} in every run above")
    return 0


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(prog="python -m belt_drive_ros.benchmarks.replay", description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--baseline", help="a checkout of another commit to measure beside this tree")
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args()
    raise SystemExit(main(args.minutes, args.baseline, args.repeat))
