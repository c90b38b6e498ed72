"""The compiled loop over a variant axis: :func:`~belt_drive_ros.core.kernel._steps` once per variant.

An ensemble (:mod:`~belt_drive_ros.core.ensemble`) steps V variants of one
plant that share the torque profiles, the method and the step but not
their matrices. :func:`variant_steps` runs, for each variant in turn, the
single run's own loop on that variant's numbers (one row of ``reals``,
packed by :class:`~belt_drive_ros.core.kernel_loop.KernelLoop` from the
stacked scheme): the same compiled operations on the same floats, so each
variant equals its single run bit for bit, and one call covers a whole
chunk of variants (no Python per variant or per step).

Serial on purpose (no ``prange``): a campaign runs one single-threaded Dask
worker process per core, each calling this on its own chunk of variants;
threads inside a worker would only compete with the other worker for the
same cores (measured: ``prange`` on 2 threads in one process was no faster
than 1 thread on this 2-core machine, and 2 such processes would run 4
threads on 2 cores). The function is compiled through numba's parallel
pipeline with every parallel transformation switched off (:data:`_PIPELINE`:
no parfor, so no thread is ever started): the same floats, and 2.5x less
CPU per variant-step than the plain pipeline on ``paper``'s lawson5
(170 against 430 ns here; docs/campaigns.md).
"""

from __future__ import annotations

import warnings

import numpy as np
from numba import njit
from numba.core.errors import NumbaPerformanceWarning

from .kernel import HEADER, SECTIONS, _steps
from .profile_data import OK


#: numba's ``parallel`` option with every transformation off: the parallel pipeline's passes, no threads
_PIPELINE = dict(comprehension=False, reduction=False, inplace_binop=False, setitem=False, numpy=False, stencil=False,
                 fusion=False, prange=False)  # fmt: skip
# numba says so when it compiles (no parallel transformation was possible): that is the point here
warnings.filterwarnings("ignore", message=r"(?s).*'parallel=True' was specified", category=NumbaPerformanceWarning)


@njit(cache=True, nogil=True, parallel=_PIPELINE)
def variant_steps(times, states, j, lo, hi, limit, reals, tables, ints, dp, lp, status):
    """Steps ``times[k] -> times[k+1]`` of every variant from ``states[v, j]`` into ``states[v, j+1 : j+len(times)]``.

    Parameters
    ----------
    times : (K+1,) step ends [s] (shared); states : (V, J, n) each variant's knots, J >= j + K + 1.
    lo, hi : torque times clamped into [lo, hi] [s]; limit : divergence speed [rad/s].
    reals : (V, R) per variant the numbers of :func:`~belt_drive_ros.core.kernel.linear_steps`'s
        ``reals`` before the profiles' tables; tables : the tables (shared); ints, dp, lp : as there.
    status : (V,) int64, :data:`OK` on entry for a variant still running; a variant whose state
        diverges gets its status and NaN knots from there on, and is skipped by later calls.
    """
    n, s, E, rows, cols = ints[0], ints[1], ints[2], ints[3], ints[4]
    at = ints[HEADER : HEADER + len(SECTIONS) + 1]
    k0 = HEADER + len(SECTIONS) + 1
    nd = dp.shape[0]
    kinds, dk, lk = ints[k0 : k0 + s], ints[k0 + s : k0 + s + nd], ints[k0 + s + nd :]
    base = at[7]
    dx, dy = tables[at[7] - base : at[8] - base], tables[at[8] - base : at[9] - base]
    lx, ly = tables[at[9] - base : at[10] - base], tables[at[10] - base : at[11] - base]
    count = times.size - 1
    for v in range(states.shape[0]):
        out = states[v, j + 1 : j + 1 + count]
        if status[v] != OK:
            out[:] = np.nan
            continue
        r = reals[v]
        done, st, _ = _steps(
            times, states[v, j], out, lo, hi, limit, r[at[0] : at[1]].reshape((1, 4, n)), kinds, r[at[1] : at[2]],
            r[at[2] : at[3]].reshape((s, rows, cols)), r[at[3] : at[4]].reshape((1, n, cols)), ints[5], r[at[4]],
            ints[6], ints[7] != 0, ints[8] != 0, dk, dp, dx, dy, lk, lp, lx, ly, r[at[5] : at[6]].reshape((E, 5)), r[at[6] : at[7]],
        )  # fmt: skip
        if st != OK:
            status[v] = st
            out[done:] = np.nan
