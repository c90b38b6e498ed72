"""Compile (or load from numba's disk cache) every kernel once, with the one signature runs use.

``make install`` calls :func:`warm`, so a first run compiles nothing (the
argument types never change with the scene). Which kernel calls which (a
caller's compilation needs its callees' machine code: from the cache, else
it compiles them again)::

    wheel_steps, _explicit, _explicit_wide <- _steps <- linear_steps <- hybrid loop <- node's slipping tick   (_steps <- clamped_steps)
              |                     <- variant loop    <- node's linear tick
              <- network node tick (and the network's linear tiers, called from Python)
    profile dispatcher (kernel_profiles: profile_torque, profile_torque_at) <- every kernel but the variant lanes

With ``jobs=2`` the longest builds run side by side: this process compiles
``wheel_steps`` (called from Python with the types ``_steps`` gives it), then
the slipping belt's event step (``slip_run.warm_events``: no linear loop in it),
while a second process compiles ``_explicit`` and ``_explicit_wide`` (likewise) and tells it so
on a pipe; this process waits for that line, then goes on with the linear loop,
whose compilation loads them from the cache. The second process goes on with
the network slipping tier, takes the network node tick once this process has
cached the linear loop through a short network run (``wheel_steps``), the
variant loop once it has cached ``linear_steps`` (told on its stdin): on two
cores the longer chain's time, and nothing compiled twice (a second process
that fails before ``_explicit``: this one compiles them, as with ``jobs=1``, and
raises once its own part is done; one that cannot be started at all: this
process warms everything, as with ``jobs=1``, and says so on stderr).
"""

from __future__ import annotations

import os
import subprocess
import sys

#: the milestones this process tells the second one, in order (a line each on its stdin)
WHEEL, LINEAR = "wheel_steps", "linear_steps"
#: the milestone the second process tells this one (a line on the pipe whose descriptor it is given)
EXPLICIT = "_explicit"
#: the second process's program (``{fd}``: the pipe's descriptor it tells :data:`EXPLICIT` on)
SECOND = "from belt_drive_ros.core.warm import warm_second; warm_second(wait=True, tell_fd={fd})"


def warm(jobs: int = 1) -> None:
    """Warm every kernel: all here (``jobs=1``), or split with a second process as the module docstring
    says (``jobs=2``); a failed second process raises ``RuntimeError``."""
    from . import jit_cache

    jit_cache.refresh()  # once, before either process loads a kernel
    if jobs <= 1:
        warm_single()
        warm_second()
        return
    read, write = os.pipe()
    try:
        child = subprocess.Popen([sys.executable, "-c", SECOND.format(fd=write)], stdin=subprocess.PIPE, text=True,
                                 pass_fds=(write,))
    except OSError as exc:  # (no process to be had: fork refused, no memory)
        os.close(read)
        print(f"warm: cannot start a second process ({exc.strerror or exc}); warming every kernel in this one",
              file=sys.stderr)
        warm_single()
        warm_second()
        return
    finally:
        os.close(write)  # the child's copy only: its exit ends this process's wait
    with os.fdopen(read) as told:
        try:
            warm_single(tell=child.stdin, told=told)
        finally:
            try:
                child.stdin.close()  # a milestone never told: the second process stops (it compiles nothing twice)
            except BrokenPipeError:  # (gone already: what _tell could not write is dropped with it)
                pass
    if child.wait() != 0:
        raise RuntimeError(f"warming the network and variant kernels failed (exit {child.returncode})")


def warm_single(tell=None, told=None) -> None:
    """The linear loop (``wheel_steps`` through a short network run, then the profile dispatcher,
    ``_steps`` and ``linear_steps``), the slipping hybrid loop and the node's compiled ticks; each
    milestone of :data:`WHEEL`, :data:`LINEAR` is written to ``tell`` (a text stream) once cached;
    with ``told`` (a text stream), the linear loop waits for a line from it (:data:`EXPLICIT`: cached by
    the second process; any other line or its end: compiled here)."""
    from . import kernel, kernel_loop, slip_run, tick
    from .network import simulate as network_simulate

    if told is not None:  # while the second process compiles _explicit: the general loop, then the event step
        kernel.wheel_steps(*_loop_arguments(wheel=True))
        slip_run.warm_events()
        told.readline()
    network_simulate.warm()  # calls wheel_steps from Python: its one signature, written to the cache
    _tell(tell, WHEEL)
    kernel_loop.warm()
    _tell(tell, LINEAR)
    slip_run.warm_hybrid()
    tick.warm()


def warm_second(wait: bool = False, tell_fd: int | None = None) -> None:
    """``_explicit`` and ``_explicit_wide`` (:func:`warm_explicit`; :data:`EXPLICIT` then written to the descriptor ``tell_fd``),
    the network slipping tier, the network node's tick, the variant loop and its window peaks; with ``wait`` each of the
    last two only after its milestone line has been read from stdin (:func:`warm`)."""
    from . import kernel_loop, kernel_variants
    from .network import slip as network_slip
    from .network import tick as network_tick

    warm_explicit()
    if tell_fd is not None:
        with os.fdopen(tell_fd, "w") as stream:
            _tell(stream, EXPLICIT)
    network_slip.warm()
    _wait(wait, WHEEL)
    network_tick.warm()
    _wait(wait, LINEAR)
    kernel_loop.warm_variants()
    kernel_variants.warm_peaks()


def warm_explicit() -> None:
    """Compile (or load from the disk cache) :func:`~belt_drive_ros.core.kernel._explicit` and ``_explicit_wide``
    alone, so that compiling the linear loop loads them instead of compiling them (each about as long a build as
    ``wheel_steps``). The wide loop is compiled for the same argument types, not run (a 2-state loop's arrays are
    not a 5- or 6-state one's)."""
    from . import kernel

    from .tick import load_compiled

    args = _loop_arguments(wheel=False)
    kernel._explicit(*args)
    load_compiled(kernel._explicit_wide, args)


def _loop_arguments(wheel: bool) -> tuple:
    """The arguments :func:`~belt_drive_ros.core.kernel._steps` passes :func:`~belt_drive_ros.core.kernel.wheel_steps`
    (``wheel``) or :func:`~belt_drive_ros.core.kernel._explicit`, for one step of a 2-state loop of a constant torque:
    its packed arrays cut by ``_unpacked`` run as Python (C-contiguous arrays, int64, float64 and booleans: the types
    compiled code gives them, so the one signature each is compiled)."""
    import math

    import numpy as np

    from . import kernel
    from .kernel_loop import _warm_loop

    _, loop = _warm_loop(False)
    times, x, out, dp, lp = np.array([0.0, 1e-3]), np.zeros(2), np.empty((1, 2)), loop._dp, loop._lp
    W, kinds, offsets, S, F, base, tol, iters, ua, ub, dk, dx, dy, lk, lx, ly, extra, guard = kernel._unpacked.py_func(
        loop.reals, loop.ints, dp)  # fmt: skip
    if wheel:
        uses = np.array([ua, ub], dtype=np.int64)
        return (times, x, out, -math.inf, math.inf, 1.0e5, W, kinds, offsets, S, F, base, tol, iters, uses,
                np.zeros(2, dtype=np.int64), dk, dp, dx, dy, lk, lp, lx, ly, extra, guard)  # fmt: skip
    return (times, x, out, -math.inf, math.inf, dk[:0], times[:0], times[:0], np.int64(0), 1.0e5, W, kinds, offsets, S,
            F, ua, ub, dk, dp, dx, dy, lk, lp, lx, ly, extra, guard, x.size)  # fmt: skip


def _tell(stream, milestone: str) -> None:
    """``milestone`` as a line on ``stream`` (none: nobody to tell); a second process already gone is told nothing
    (its exit status says why, after this process's part)."""
    if stream is not None:
        try:
            stream.write(milestone + "\n")
            stream.flush()
        except BrokenPipeError:
            pass


def _wait(wait: bool, milestone: str) -> None:
    if wait and sys.stdin.readline().strip() != milestone:
        raise SystemExit(f"warm: the first process stopped before {milestone} was cached")
