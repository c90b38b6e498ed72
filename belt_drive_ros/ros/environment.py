"""Process environment for ROS 2: loopback-only discovery and a private domain.

Imports nothing from ROS: call :func:`configure_environment` *before* rclpy
is imported or a context is initialised (rcl reads the variables then).

* DDS discovery stays on this machine: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
  (Jazzy) and ``ROS_LOCALHOST_ONLY=1`` (the older switch, still honoured;
  rcl prints a deprecation warning when it sees both). Values the user set
  are kept.
* Every test process or demo gets its own ROS domain, derived from its pid
  (:func:`process_domain_id`), so concurrent runs on one machine do not see
  each other's topics.
"""

from __future__ import annotations

import os
from typing import MutableMapping

#: variables set (when unset) before rclpy starts
LOOPBACK_ENVIRONMENT = {
    "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    "ROS_LOCALHOST_ONLY": "1",
}

#: domain ids handed out by :func:`process_domain_id`: 1 ... 100 (0 is the
#: default domain every ROS install uses; ids above ~101 collide with the
#: ephemeral port range on Linux).
DOMAIN_ID_RANGE = (1, 100)


def configure_environment(env: MutableMapping[str, str] | None = None) -> MutableMapping[str, str]:
    """Set the loopback discovery variables in ``env`` (default ``os.environ``) where unset.

    Returns ``env``. Call before importing rclpy in a process, or pass a copy
    of ``os.environ`` to prepare a child process's environment.
    """
    env = os.environ if env is None else env
    for key, value in LOOPBACK_ENVIRONMENT.items():
        env.setdefault(key, value)
    return env


def process_domain_id(pid: int | None = None, offset: int = 0) -> int:
    """A ROS domain id private to this process: ``1 + (pid + offset) % 100``.

    Deliberately ignores ``ROS_DOMAIN_ID``: in-process harnesses and demos
    must not share a domain with whatever else runs on the machine. ``offset``
    gives further ids for the same process (e.g. one per child process).
    """
    lo, hi = DOMAIN_ID_RANGE
    pid = os.getpid() if pid is None else pid
    return lo + (pid + offset) % (hi - lo + 1)


def child_environment(domain_id: int, udp_only: bool = True, **extra: str) -> dict[str, str]:
    """Environment for a child ROS process on ``domain_id``.

    ``udp_only`` selects Fast DDS's UDPv4 transport: a child that is killed
    (rather than shut down) then leaves no shared-memory segments behind in
    /dev/shm. Loopback discovery is set as in :func:`configure_environment`.
    """
    env = dict(os.environ)
    configure_environment(env)
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
