"""Compile (or load from numba's disk cache) every kernel once, with the one signature runs use.

``make install`` calls :func:`warm` so that a first run compiles nothing:
every kernel's argument types are fixed (float64/int64 C arrays and floats),
so one short call per kernel covers every scene. Kept apart from the kernels'
own modules so that no kernel module imports the simulators above it.

Which kernel calls which (a caller's compilation needs its callees' machine
code: from the disk cache where another process has written it, else it
compiles them itself, a second time)::

    wheel_steps <- _steps <- linear_steps <- hybrid loop <- node's slipping tick
                |        <- variant loop    <- node's linear tick
                <- network node tick (and the network's linear tiers, called from Python)
    network slipping tier: calls none of them

With ``jobs=2`` the work runs in two processes along that graph, and no
kernel is compiled by both: this one compiles ``wheel_steps`` (through a
short network run), then ``_steps`` and ``linear_steps``, then the slipping
hybrid loop and the node ticks; the second process starts with the network
slipping tier (which needs nothing) and takes each kernel that calls the
linear loop only once this process has written the callee to the cache
(told through its stdin): the network node tick after ``wheel_steps``, the
variant loop after ``linear_steps``. On two cores the build takes about the
longer chain's time instead of the sum, without the duplicate compilations
of the loop both chains start with.
"""

from __future__ import annotations

import subprocess
import sys

#: the milestones this process tells the second one, in order (a line each on its stdin)
WHEEL, LINEAR = "wheel_steps", "linear_steps"


def warm(jobs: int = 1) -> None:
    """Warm every kernel: all here (``jobs=1``), or split with a second process as the module docstring
    says (``jobs=2``); a failed second process raises ``RuntimeError``."""
    from . import jit_cache

    jit_cache.refresh()  # once, before either process loads a kernel
    if jobs <= 1:
        warm_single()
        warm_second()
        return
    code = "from belt_drive_ros.core.warm import warm_second; warm_second(wait=True)"
    child = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, text=True)
    try:
        warm_single(tell=child.stdin)
    finally:
        child.stdin.close()  # a milestone never told: the second process stops (it compiles nothing twice)
    if child.wait() != 0:
        raise RuntimeError(f"warming the network and variant kernels failed (exit {child.returncode})")


def warm_single(tell=None) -> None:
    """The linear loop (``wheel_steps`` through a short network run, then the profile dispatcher,
    ``_steps`` and ``linear_steps``), the slipping hybrid loop and the node's compiled ticks; each
    milestone of :data:`WHEEL`, :data:`LINEAR` is written to ``tell`` (a text stream) once cached."""
    from . import kernel_loop, slip_run, tick
    from .network import simulate as network_simulate

    network_simulate.warm()  # calls wheel_steps from Python: its one signature, written to the cache
    _tell(tell, WHEEL)
    kernel_loop.warm()
    _tell(tell, LINEAR)
    slip_run.warm_hybrid()
    tick.warm()


def warm_second(wait: bool = False) -> None:
    """The network slipping tier, the network node's tick and the variant loop; with ``wait`` each of
    the last two only after its milestone line has been read from stdin (:func:`warm`)."""
    from . import kernel_loop
    from .network import slip as network_slip
    from .network import tick as network_tick

    network_slip.warm()
    _wait(wait, WHEEL)
    network_tick.warm()
    _wait(wait, LINEAR)
    kernel_loop.warm_variants()


def _tell(stream, milestone: str) -> None:
    if stream is not None:
        stream.write(milestone + "\n")
        stream.flush()


def _wait(wait: bool, milestone: str) -> None:
    if wait and sys.stdin.readline().strip() != milestone:
        raise SystemExit(f"warm: the first process stopped before {milestone} was cached")
