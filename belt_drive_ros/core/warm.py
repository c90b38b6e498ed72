"""Compile (or load from numba's disk cache) every kernel once, with the one signature runs use.

``make install`` calls :func:`warm` so that a first run compiles nothing:
every kernel's argument types are fixed (float64/int64 C arrays and floats),
so one short call per kernel covers every scene. Kept apart from the kernels'
own modules so that no kernel module imports the simulators above it.
"""

from __future__ import annotations


def warm() -> None:
    """Warm the profile dispatcher, the linear and variant loops, the slipping hybrid loop, the node's
    compiled tick (linear and slipping) and both belt-network loops (flexible/rigid and slipping)."""
    from . import jit_cache, kernel_loop, slip_run, tick
    from .network import simulate as network_simulate
    from .network import slip as network_slip

    jit_cache.refresh()
    kernel_loop.warm()
    slip_run.warm_hybrid()
    tick.warm()
    network_simulate.warm()
    network_slip.warm()
