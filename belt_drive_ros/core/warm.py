"""Compile (or load from numba's disk cache) every kernel once, with the one signature runs use.

``make install`` calls :func:`warm` so that a first run compiles nothing:
every kernel's argument types are fixed (float64/int64 C arrays and floats),
so one short call per kernel covers every scene. Kept apart from the kernels'
own modules so that no kernel module imports the simulators above it.

The kernels fall in two groups of about equal compile time: the single
belt's linear loop, slipping hybrid and node tick, and the belt network's
loops, node tick and the variant loop. With ``jobs=2`` the second group
compiles in a second process while this one compiles the first: on two
cores the build takes about the longer group's time instead of the sum. The
second group compiles the networks first; by the time it reaches the
variant loop the first group has usually cached the linear loop it calls,
and it loads it instead of compiling it again (a function both compile is
written whole by each, with the same one signature, so that is safe).
"""

from __future__ import annotations

import subprocess
import sys


def warm(jobs: int = 1) -> None:
    """Warm every kernel: the first group here, the second (networks, variants) here too (``jobs=1``) or
    in a second process at the same time (``jobs=2``); a failed second process raises ``RuntimeError``."""
    from . import jit_cache

    jit_cache.refresh()  # once, before either process loads a kernel
    child = None
    if jobs > 1:
        code = "from belt_drive_ros.core.warm import warm_second; warm_second()"
        child = subprocess.Popen([sys.executable, "-c", code])
    warm_single()
    if child is None:
        warm_second()
    elif child.wait() != 0:
        raise RuntimeError(f"warming the network and variant kernels failed (exit {child.returncode})")


def warm_single() -> None:
    """The profile dispatcher, the linear loop, the slipping hybrid loop and the node's compiled tick
    (linear and slipping)."""
    from . import kernel_loop, slip_run, tick

    kernel_loop.warm()
    slip_run.warm_hybrid()
    tick.warm()


def warm_network() -> None:
    """Both belt-network loops (flexible/rigid and slipping) and the network node's compiled tick."""
    from .network import simulate as network_simulate
    from .network import slip as network_slip
    from .network import tick as network_tick

    network_simulate.warm()
    network_slip.warm()
    network_tick.warm()


def warm_second() -> None:
    """The network group, then the variant loop (see the module docstring)."""
    from . import kernel_loop

    warm_network()
    kernel_loop.warm_variants()
