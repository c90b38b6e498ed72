"""Memory probe of a running node (for long runs): set ``BELT_DRIVE_MEMPROBE=DIR``.

A debugging switch, off unless the variable is set (``belt-drive bench soak
--memprobe DIR`` sets it for its child node). Every
``BELT_DRIVE_MEMPROBE_PERIOD`` seconds (default 60) a steady-clock timer on
the node, i.e. between two ticks (no half-built tick in the figures),
appends one row to ``DIR/memprobe.csv``:

* ``elapsed_s`` since the probe started;
* ``rss_kib``: the process's resident set (``VmRSS``);
* ``py_blocks``: memory blocks Python's allocator holds (``sys.getallocatedblocks``);
* ``malloc_used``, ``malloc_free``, ``malloc_mmap``: glibc's ``mallinfo2``
  in-use bytes of the heap arenas, their free bytes (fragmentation or
  not yet returned to the kernel) and the bytes in mmap'd blocks;
* ``traced``: bytes ``tracemalloc`` traces (0 without snapshots).

With ``BELT_DRIVE_MEMPROBE_FRAMES=N`` (N > 0) tracemalloc runs with N
frames and each row also dumps ``DIR/snap_K.bin``; :func:`growth` diffs two
of them and names the lines whose allocations grew. RSS growth with flat
``py_blocks`` and ``malloc_used`` is outside Python and the heap (DDS
buffers, mmap); growth of ``malloc_free`` alone is fragmentation.
"""

from __future__ import annotations

import csv
import ctypes
import os
import sys
import time
from pathlib import Path

__all__ = ["COLUMNS", "ENV", "growth", "install", "mallinfo", "read_rows", "sample"]

#: the switch (a folder) and its options
ENV = "BELT_DRIVE_MEMPROBE"
ENV_PERIOD = "BELT_DRIVE_MEMPROBE_PERIOD"
ENV_FRAMES = "BELT_DRIVE_MEMPROBE_FRAMES"
COLUMNS = ("elapsed_s", "rss_kib", "py_blocks", "malloc_used", "malloc_free", "malloc_mmap", "traced")


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]


def mallinfo() -> dict[str, int]:
    """glibc's heap figures [bytes]: ``used`` (in-use in arenas), ``free`` (free in arenas), ``mmap``; {} elsewhere."""
    try:
        libc = ctypes.CDLL(None)
        fn = libc.mallinfo2
    except (OSError, AttributeError):
        return {}
    fn.restype = _MallInfo2
    info = fn()
    return {"used": int(info.uordblks), "free": int(info.fordblks), "mmap": int(info.hblkhd)}


def _rss_kib() -> int:
    try:
        with open(f"/proc/{os.getpid()}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return -1


def sample(start: float) -> dict[str, float]:
    """One row of :data:`COLUMNS` for this process now."""
    import tracemalloc

    heap = mallinfo()
    return {
        "elapsed_s": round(time.monotonic() - start, 3), "rss_kib": _rss_kib(),
        "py_blocks": sys.getallocatedblocks(), "malloc_used": heap.get("used", -1),
        "malloc_free": heap.get("free", -1), "malloc_mmap": heap.get("mmap", -1),
        "traced": tracemalloc.get_traced_memory()[0] if tracemalloc.is_tracing() else 0,
    }


def install(node, folder: str | os.PathLike | None = None) -> bool:
    """Start the probe on ``node`` if ``BELT_DRIVE_MEMPROBE`` (or ``folder``) names a folder; True if started."""
    folder = folder or os.environ.get(ENV)
    if not folder:
        return False
    import tracemalloc

    from rclpy.clock import Clock, ClockType

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    period = float(os.environ.get(ENV_PERIOD, "60"))
    frames = int(os.environ.get(ENV_FRAMES, "0"))
    if frames > 0 and not tracemalloc.is_tracing():
        tracemalloc.start(frames)
    start = time.monotonic()
    table = out / "memprobe.csv"
    with open(table, "w", newline="") as f:
        csv.writer(f).writerow(COLUMNS)
    count = [0]

    def on_timer() -> None:
        row = sample(start)
        with open(table, "a", newline="") as f:
            csv.writer(f).writerow([row[c] for c in COLUMNS])
        if tracemalloc.is_tracing():
            tracemalloc.take_snapshot().dump(str(out / f"snap_{count[0]:03d}.bin"))
        count[0] += 1

    node._memprobe_timer = node.create_timer(period, on_timer, clock=Clock(clock_type=ClockType.STEADY_TIME))
    node.get_logger().warn(f"memory probe on: {table} every {period:g} s (tracemalloc frames {frames})")
    return True


def read_rows(folder: str | os.PathLike) -> list[dict[str, float]]:
    """The rows of ``folder/memprobe.csv`` as numbers."""
    with open(Path(folder) / "memprobe.csv", newline="") as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def growth(first: str | os.PathLike, last: str | os.PathLike, top: int = 10) -> list[tuple[int, int, str]]:
    """(bytes grown, blocks grown, where) of the ``top`` source lines whose traced memory grew most
    from snapshot ``first`` to ``last`` (tracemalloc's own frames left out)."""
    import tracemalloc

    skip = [tracemalloc.Filter(False, tracemalloc.__file__), tracemalloc.Filter(False, "<frozen importlib._bootstrap>")]
    a = tracemalloc.Snapshot.load(str(first)).filter_traces(skip)
    b = tracemalloc.Snapshot.load(str(last)).filter_traces(skip)
    out = []
    for stat in sorted(b.compare_to(a, "traceback"), key=lambda s: -s.size_diff)[:top]:
        frames = stat.traceback.format(limit=-3)
        where = " <- ".join(line.strip() for line in reversed(frames) if line.strip().startswith("File"))
        out.append((stat.size_diff, stat.count_diff, where))
    return out
