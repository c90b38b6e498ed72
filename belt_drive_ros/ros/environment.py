"""Process environment for ROS 2: the discovery rule and a private domain per test process.

Imports nothing from ROS: call :func:`configure_environment` *before* rclpy
is imported or a context is initialised (rcl reads the variables then).

The discovery rule (also in the README's node section):

* The user's explicit environment always wins: ``ROS_AUTOMATIC_DISCOVERY_RANGE``,
  ``ROS_STATIC_PEERS``, ``ROS_LOCALHOST_ONLY`` and ``ROS_DOMAIN_ID`` are never
  changed once set, and the package never sets ``ROS_LOCALHOST_ONLY``
  (deprecated since Jazzy; rcl warns when it sees it, and with it set it
  ignores the range).
* The product commands (``belt-drive node``, ``source``, ``record``,
  ``replay``, and :mod:`belt_drive_ros.ros.node` on import) set nothing:
  with nothing set they discover like any ROS 2 Jazzy program (range
  ``SUBNET``, domain 0), so a SIL stack on other hosts or containers reaches
  them.
* Throw-away graphs that must not leak onto the network (``belt-drive demo``,
  the test harness, the benchmarks, the test suite and the Makefile) keep to
  this machine: they set ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` when
  neither discovery variable is set (:func:`configure_environment` with
  ``loopback=True``), and each test process or demo gets its own ROS domain
  (:func:`process_domain_id`), so concurrent runs on one machine do not see
  each other's topics.

Private domains are allocated, not derived: an id is taken by holding an
exclusive ``flock`` on ``/tmp/belt_drive_ros-domains/<id>.lock`` for
the life of the process (the kernel drops the lock when the process ends,
however it ends), so two processes of this package on one machine never get
the same id while both run. A ROS program that does not take these locks
(e.g. one started by hand with ``ROS_DOMAIN_ID`` set) is not seen.
"""

from __future__ import annotations

import fcntl
import os
import re
import signal
import tempfile
import threading
from pathlib import Path
from typing import MutableMapping

#: the variables by which a user chooses how far DDS discovery reaches
DISCOVERY_VARIABLES = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY")

#: set by :func:`configure_environment` ``(loopback=True)`` when the user chose no range
LOOPBACK_ENVIRONMENT = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}

#: domain ids handed out by :func:`process_domain_id`: 1 ... 100. 0 is the
#: default domain every ROS install uses. Fast DDS maps domain d to UDP ports
#: 7400 + 250 d (+ 10, + 11 + 2 participant): up to d = 101 they stay below
#: Linux's ephemeral port range (32768-60999); the ROS 2 docs give 0-101 as
#: the safe range on Linux.
DOMAIN_ID_RANGE = (1, 100)


def configure_environment(env: MutableMapping[str, str] | None = None, *,
                          loopback: bool = False) -> MutableMapping[str, str]:
    """Apply the discovery rule to ``env`` (default ``os.environ``) and return it.

    Parameters
    ----------
    env : mutable mapping, optional
        Environment to prepare: ``os.environ`` before rclpy starts in this
        process, or a copy for a child process.
    loopback : bool
        False (product commands): nothing is changed, ROS 2's defaults apply
        where the user set nothing. True (demo, harness, benchmarks, tests):
        ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` when neither
        ``ROS_AUTOMATIC_DISCOVERY_RANGE`` nor ``ROS_LOCALHOST_ONLY`` is set.
        ``ROS_LOCALHOST_ONLY`` is never set, and a value the user set is
        never changed.
    """
    env = os.environ if env is None else env
    if loopback and not any(env.get(key) for key in DISCOVERY_VARIABLES):
        env.update(LOOPBACK_ENVIRONMENT)
    return env


#: the ids this process holds: (pid, offset) -> (domain id, locked file descriptor)
_HELD: dict[tuple[int, int], tuple[int, int]] = {}


def domain_lock_dir() -> Path:
    """The directory of the per-id lock files (``/tmp/belt_drive_ros-domains``), created if absent.

    ``/tmp`` rather than ``$TMPDIR``: every process on the machine must find
    the same files, whatever its environment (``tempfile.gettempdir()`` only
    where there is no /tmp). Shared by every user (mode 1777, like /tmp
    itself), since DDS domains are too.
    """
    base = Path("/tmp") if Path("/tmp").is_dir() else Path(tempfile.gettempdir())
    path = base / "belt_drive_ros-domains"
    if not path.is_dir():
        path.mkdir(exist_ok=True)
        try:
            path.chmod(0o1777)
        except OSError:
            pass
    return path


def _try_lock(path: Path) -> int | None:
    """An open descriptor holding an exclusive flock on ``path``, or None if another holder has it."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except PermissionError:  # another user's lock file: flock works on a read-only descriptor too
        fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    except BaseException:
        os.close(fd)
        raise
    try:
        os.fchmod(fd, 0o666)  # let other users lock the file too
    except OSError:
        pass
    return fd


def process_domain_id(offset: int = 0) -> int:
    """A ROS domain id held by this process for its life; each ``offset`` gives a further id.

    The first call for an ``offset`` tries the ids of :data:`DOMAIN_ID_RANGE`
    in turn, starting at ``1 + (pid + offset) % 100``, and keeps the first
    whose lock file (in :func:`domain_lock_dir`) it can lock exclusively;
    later calls return the same id. The lock lasts until the process ends, so
    no other process of this package on the machine gets that id meanwhile
    (child processes started on it, e.g. through :func:`child_environment`,
    share it). A forked child allocates its own ids. Deliberately ignores
    ``ROS_DOMAIN_ID``: in-process harnesses and demos must not share a domain
    with whatever else runs on the machine.

    Raises
    ------
    RuntimeError
        If every id of the range is held by another process.
    """
    pid = os.getpid()
    held = _HELD.get((pid, int(offset)))
    if held is not None:
        return held[0]
    lo, hi = DOMAIN_ID_RANGE
    count = hi - lo + 1
    start = (pid + int(offset)) % count
    folder = domain_lock_dir()
    for k in range(count):
        domain = lo + (start + k) % count
        fd = _try_lock(folder / f"{domain}.lock")
        if fd is not None:
            _HELD[(pid, int(offset))] = (domain, fd)
            return domain
    raise RuntimeError(f"no free ROS domain id: all of {lo}-{hi} are held by other processes (locks in {folder})")


def child_environment(domain_id: int, udp_only: bool = True, loopback: bool = True,
                      **extra: str) -> dict[str, str]:
    """Environment for a child ROS process on ``domain_id`` (tests, demo, benchmarks).

    ``udp_only`` selects Fast DDS's UDPv4 transport: a child that is killed
    (rather than shut down) then leaves no shared-memory segments behind in
    /dev/shm. ``loopback``: as in :func:`configure_environment`.
    """
    env = dict(os.environ)
    configure_environment(env, loopback=loopback)
    env["ROS_DOMAIN_ID"] = str(int(domain_id))
    if udp_only:
        env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    env.setdefault("PYTHONUNBUFFERED", "1")
    env.update(extra)
    return env


#: OpenBLAS entry points that set the thread count, by build flavour
_BLAS_SET_THREADS = (
    "openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "scipy_openblas_set_num_threads64_",
)


def interruptible_start() -> bool:
    """Let SIGINT end a program's start-up (building its nodes: imports, the guards, numba loading its kernels):
    where the process inherited SIGINT *ignored*, Python's own handler (``KeyboardInterrupt``) is put back.

    A background job of a non-interactive shell (``belt-drive node &`` in a script) starts with SIGINT ignored,
    and Python then leaves it ignored; :func:`spin_until_signal` handles it anyway once the spin starts, so a
    SIGINT in the seconds before (5-15 s of start-up at load 10) was lost and the node went on running. With the
    handler back, it stops the start-up as it does in a process started normally (the command's exit code 130).
    Returns True when the handler was put back. Only in the main thread (elsewhere nothing is changed). Here, with
    no rclpy: a command calls it before its imports of rclpy and the node (seconds of start-up themselves)."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) != signal.SIG_IGN:
        return False
    signal.signal(signal.SIGINT, signal.default_int_handler)
    return True


def limit_blas_threads(n: int = 1) -> int:
    """Run BLAS single-threaded (``n`` threads) in this process; returns how many libraries were set.

    A real-time loop multiplies tiny matrices (4x4; the 8x8 Van Loan block of
    a partial exact step): OpenBLAS's worker threads only add wake-up
    latency there (measured here: median 20 us, but spikes of 12-20 ms per
    ``expm`` and >100 % CPU next to the DDS threads on 2 cores; one thread:
    max 0.26 ms). Sets the ``*_NUM_THREADS`` variables for libraries not yet
    loaded and calls ``openblas_set_num_threads`` on those already loaded
    (numpy and scipy each bundle one), as threadpoolctl would.
    """
    import ctypes

    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(n))
    try:
        with open("/proc/self/maps") as f:
            paths = {ln.split()[-1] for ln in f if "blas" in ln.lower() and ".so" in ln.rsplit("/", 1)[-1]}
    except OSError:
        return 0
    done = 0
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for symbol in _BLAS_SET_THREADS:
            func = getattr(lib, symbol, None)
            if func is not None:
                func.argtypes = [ctypes.c_int]
                func.restype = None
                func(int(n))
                done += 1
                break
    return done


#: ``prctl`` option that sets the calling thread's timer slack (linux/prctl.h)
_PR_SET_NAME = 15
_PR_SET_TIMERSLACK = 29


#: the node's tick thread's name, the operating system's too (:func:`name_thread`; ``belt-drive bench node`` reads
#: its CPU time by it, and the floor's thread has it)
TICK_THREAD = "belt_drive_tick"


def name_thread(name: str) -> bool:
    """Give the calling thread ``name`` (its first 15 bytes) as the operating system's name of it (Linux
    ``prctl(PR_SET_NAME)``; ``/proc/PID/task/TID/comm``), so its CPU time can be found by name. Returns False where
    ``prctl`` is unavailable."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_NAME, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def reduce_timer_slack(slack_ns: int = 1) -> bool:
    """Set this thread's timer slack to ``slack_ns`` (Linux); threads it creates later inherit it.

    Linux lets a sleep of an ordinary (``SCHED_OTHER``) thread end up to its
    timer slack late (default 50 us) so that wake-ups can be merged. A 1 kHz
    tick wakes twice per period (the executor's timer thread, then the spinning
    thread), so the default slack alone delays each tick by up to ~0.1 ms:
    measured in ``belt-drive node`` at 1 kHz, the median delay from the tick's
    grid time to its callback went from 132 us to 75 us with a slack of 1 ns.
    Call it before rclpy starts its threads (context, executor). Returns
    False where ``prctl`` is unavailable (the default slack then stays).
    """
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(int(slack_ns)), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def realtime_priority(priority: int) -> str:
    """Schedule this process ``SCHED_FIFO`` at ``priority`` (1-99); returns "" or why it was refused.

    A real-time thread runs as soon as it is ready, ahead of every ordinary
    process: on a machine shared with other work, ticks then come on time
    (``belt-drive bench node``, 30 s at 1 kHz on 2 cores at load average
    6-8: 836-867 Hz with thousands of skipped ticks without it, 995-999 Hz
    with it; docs/performance.md). Threads
    created afterwards inherit the policy, so call it before rclpy starts
    (DDS and executor threads included). Needs ``CAP_SYS_NICE`` or an
    ``rtprio`` limit (``ulimit -r``) of at least ``priority``. Linux keeps
    5 % of each second for ordinary processes (``sched_rt_runtime_us``), so
    a run that cannot keep up does not lock the machine.
    """
    if not 1 <= int(priority) <= 99:
        return f"priority must be 1-99, got {priority}"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
    except (OSError, AttributeError) as exc:
        return f"SCHED_FIFO {priority} refused ({exc}); needs CAP_SYS_NICE or 'ulimit -r {priority}'"
    return ""


# ------------------------------------------------------- Fast DDS shared memory
#: a participant's own Fast DDS segment in /dev/shm and its lock file (the shared
#: ``fastrtps_port*`` segments and their semaphores are reused by every participant)
_OWN_SEGMENT = re.compile(r"fastrtps_[0-9a-f]{16}(_el)?")
SHM_DIR = "/dev/shm"


def shared_memory_of(pid) -> set[str]:
    """Names of the /dev/shm files process ``pid`` has mapped or open (raises OSError if unreadable)."""
    found = set()
    with open(f"/proc/{pid}/maps") as f:
        found |= {line.rsplit("/dev/shm/", 1)[1].strip() for line in f if "/dev/shm/" in line}
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("/dev/shm/"):
            found.add(target[len("/dev/shm/"):])
    return found


def shared_memory_in_use() -> set[str]:
    """Names of the /dev/shm files some live process (that this one may inspect) has mapped or open."""
    found: set[str] = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            found |= shared_memory_of(pid)
        except OSError:  # gone, or not ours to read
            continue
    return found


def fast_dds_segments() -> set[str]:
    """Names of the participants' own Fast DDS segments now in /dev/shm (``fastrtps_<16 hex>``, ``_el``)."""
    try:
        return {n for n in os.listdir(SHM_DIR) if _OWN_SEGMENT.fullmatch(n)}
    except OSError:
        return set()


def remove_orphan_segments(names) -> set[str]:
    """Delete those of ``names`` that are a participant's own Fast DDS segment and no live process uses.

    A participant killed (SIGKILL, or a crash) leaves its segment behind;
    one that shuts down removes it itself. Returns the names removed.
    """
    own = {n for n in names if _OWN_SEGMENT.fullmatch(n)}
    orphans = own - shared_memory_in_use() if own else set()
    for name in orphans:
        try:
            os.unlink(os.path.join(SHM_DIR, name))
        except FileNotFoundError:
            pass
    return orphans
