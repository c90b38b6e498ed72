"""Compile (or load from numba's disk cache) every kernel once, with the one signature runs use.

``make install`` calls :func:`warm`, so a first run compiles nothing (the
argument types never change with the scene). Which kernel calls which (a
caller's compilation needs its callees' machine code: from the cache, else
it compiles them again)::

    wheel_steps, _explicit <- _steps <- linear_steps <- hybrid loop <- node's slipping tick   (_steps <- clamped_steps)
              |                     <- variant loop    <- node's linear tick
              <- network node tick (and the network's linear tiers, called from Python)
    profile dispatcher (kernel_profiles: profile_torque, profile_torque_at) <- every kernel but the variant lanes

With ``jobs=2`` a second process starts with the network slipping tier and
takes the network node tick once this process has cached ``wheel_steps``, the
variant loop once it has cached ``linear_steps`` (told on its stdin): on two
cores the longer chain's time, and nothing compiled twice.
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
