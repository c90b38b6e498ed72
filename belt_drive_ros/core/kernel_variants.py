"""The compiled loop over a variant axis: the single run's step, for a whole chunk of variants.

An ensemble (:mod:`~belt_drive_ros.core.ensemble`) steps V variants of one
plant that share the torque profiles, the method and the step but not
their matrices. Each variant's numbers are one row of ``reals``, packed by
:class:`~belt_drive_ros.core.kernel_loop.KernelLoop` from the stacked
scheme (the row a single run of that variant packs), and one call of
:func:`variant_steps` covers a whole chunk of variants (no Python per
variant or per step):

* an explicit method on a rigid or flexible plant (<= 4 states: every
  linear campaign of the shipped scenes): :func:`_lanes` steps :data:`LANES` variants at a time
  as vector lanes, the operations of the single run's 4-state loop
  (``kernel._explicit``) in the same order per variant, each one applied
  to all lanes before the next. One variant's step is a chain (state ->
  stage speeds -> torques -> next stage) that a processor runs one
  operation after the other; 32 independent chains side by side fill its
  vector units instead (``paper``'s lawson5: 102 against 230 ns per
  variant-step for the single run's loop, measured side by side on a
  loaded machine). A lockstep of the same loop with one variant per
  operation (scalar, the single loop's helpers) was measured no faster;
* anything else (more states, an implicit stage, the slipping
  belt's extra input or guard): the single run's own loop
  (:func:`~belt_drive_ros.core.kernel._steps`) once per variant.

Both give each variant its single run's floats bit for bit
(tests/test_ensemble.py).

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

from .kernel import HEADER, SECTIONS, _steps, formula, is_formula, motor_line, polynomial, profile_torque
from .profile_data import DIVERGED, MOTOR_LINE, OK, POLYNOMIAL

#: variants stepped together by :func:`_lanes` (their matrices, ~4 kB each for lawson5, stay in the cache)
LANES = 32


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
    if n <= 4 and ints[6] == 0 and E == 0 and count > 0:  # an explicit method on a rigid or flexible plant, no extra input
        guarded = False
        for v in range(states.shape[0]):
            guarded = guarded or reals[v, at[6]] != 0.0
        if not guarded:
            for a in range(0, states.shape[0], LANES):
                _lanes(times, states, j, lo, hi, limit, reals, at, n, s, cols, kinds, ints[5], ints[7] != 0, ints[8] != 0,
                       dk, dp, dx, dy, lk, lp, lx, ly, status, a, min(a + LANES, states.shape[0]))  # fmt: skip
            return
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


@njit(cache=True, nogil=True)
def knot_torques(kinds, params, tx, ty, times, angle, speed, out):
    """``out[k, v] = profile_torque(kinds, params, tx, ty, times[k], angle[k, v], speed[k, v])``: a profile's
    torques [N m] at the knots (K,) of V variants ((K, V) arrays), the variants of a knot as lanes
    (:func:`_lane_torques`: the same floats as the dispatcher's, the motor line and polynomial vectorised)."""
    for k in range(times.size):
        _lane_torques(kinds, params, tx, ty, times[k], angle[k], speed[k], out[k], out.shape[1])


@njit(cache=True, nogil=True, inline="always")
def _lane_torques(kinds, params, tx, ty, t, angle, speed, out, L):
    """``out[q] = profile_torque(kinds, params, tx, ty, t, angle[q], speed[q])`` for q < L.

    The kind is the same for every lane. The motor line and the polynomial
    through their formulas with the row's numbers read once before the loop
    (:func:`~belt_drive_ros.core.kernel.motor_line`,
    :func:`~belt_drive_ros.core.kernel.polynomial`), so the loop runs over
    the lanes in vector registers (the same IEEE operations per lane;
    through the dispatcher, reading the row per lane, it was not vectorised
    and the torques were half of ``paper``'s lawson5 step); the other
    formulas (constant, step, ramp, sine) read neither speed nor angle: one
    :func:`~belt_drive_ros.core.kernel.formula` for every lane; tables,
    schedules, engines and compressors by the dispatcher, lane by lane.
    """
    kind = kinds[0]
    if kind == MOTOR_LINE:  # the row's numbers read once: the loop compiles to vector operations
        a, b, c = params[0, 0], params[0, 1], params[0, 2]
        for q in range(L):
            out[q] = motor_line(a, b, c, t, speed[q])
    elif kind == POLYNOMIAL:
        a, b, c = params[0, 0], params[0, 1], params[0, 2]
        for q in range(L):
            out[q] = polynomial(a, b, c, speed[q])
    elif is_formula(kind):  # a function of time alone (speed[0] is not read)
        value = formula(kind, params[0, 0], params[0, 1], params[0, 2], params[0, 3], params[0, 4], t, speed[0])
        for q in range(L):
            out[q] = value
    else:
        for q in range(L):
            out[q] = profile_torque(kinds, params, tx, ty, t, angle[q], speed[q])


@njit(cache=True, nogil=True, inline="always")
def _lane_rows(M, i, r, X, n, U, count, out, L):
    """``out[q] = M[i, r, :, q] @ [X[:n, q], U[:count, q]]`` per lane, summed from the left from 0.0
    (the single loops' ``_dot`` / ``_row4`` then the torque columns: the same operations per lane)."""
    if n == 4:
        for q in range(L):
            out[q] = 0.0 + M[i, r, 0, q] * X[0, q] + M[i, r, 1, q] * X[1, q] + M[i, r, 2, q] * X[2, q] + M[i, r, 3, q] * X[3, q]
    else:
        for q in range(L):
            out[q] = 0.0 + M[i, r, 0, q] * X[0, q]
        for c in range(1, n):
            for q in range(L):
                out[q] = out[q] + M[i, r, c, q] * X[c, q]
    for e in range(count):
        for q in range(L):
            out[q] = out[q] + M[i, r, n + e, q] * U[e, q]


@njit(cache=True, nogil=True)
def _lanes(times, states, j, lo, hi, limit, reals, at, n, s, cols, kinds, final_base, ua, ub,
           dk, dp, dx, dy, lk, lp, lx, ly, status, a, b):  # fmt: skip
    """Variants ``a .. b-1`` of an explicit method on an n-state plant (n <= 4: rigid or flexible), stepped
    together, the variants as lanes.

    Each variant's floats are those of the single run's loop (the 4-state
    :func:`~belt_drive_ros.core.kernel._explicit`, which also covers the
    one-stage methods of ``_one_stage4`` with the same operations; the
    general ``_linear_steps`` for the rigid model's 2 states): per
    stage the wheel coordinates (``W`` or the stage map on ``[x, U_0 ..]``,
    summed from the left from 0.0), the two torques of
    :func:`~belt_drive_ros.core.kernel.profile_torque`, then the final map;
    the same numbers in the same order. The loop order differs: each
    operation runs over all the chunk's variants before the next (the
    matrices transposed so the variants are the contiguous axis), so the
    variants' independent chains fill the vector registers. No extra
    input (E = 0), no guard.
    """
    L = b - a
    W = np.empty((1, 4, n, L))
    S = np.empty((s, 4, cols, L))  # the stage maps' rows: max(4, n) = 4
    F = np.empty((1, n, cols, L))
    for q in range(L):  # the chunk's own numbers, variant axis last (row-major, as packed: no index division)
        r = reals[a + q]
        e = at[0]
        for x in range(4):
            for y in range(n):
                W[0, x, y, q] = r[e]
                e += 1
        e = at[2]
        for i in range(s):
            for x in range(4):
                for y in range(cols):
                    S[i, x, y, q] = r[e]
                    e += 1
        e = at[3]
        for x in range(n):
            for y in range(cols):
                F[0, x, y, q] = r[e]
                e += 1
    X = np.empty((n, L))
    B = np.empty((n, L))
    Y = np.empty((n, L))
    C = np.zeros((4, L))
    U = np.zeros((2 * s, L))
    alive = np.zeros(L, dtype=np.bool_)
    half = n // 2
    for q in range(L):
        for e in range(n):
            X[e, q] = states[a + q, j, e]
        alive[q] = status[a + q] == OK
        if not alive[q]:
            states[a + q, j + 1 : j + times.size] = np.nan
    offsets = reals[a, at[1] : at[2]]  # c_i h: the same for every variant (shared method and step)
    count = times.size - 1
    for k in range(count):
        t = times[k]
        for i in range(s):
            time = t if offsets[i] == 0.0 else t + offsets[i]
            tc = lo if time < lo else hi if time > hi else time
            if kinds[i] == 0:
                for r in range(4):
                    if (r == 0 and not ua) or (r == 2 and not ub):
                        continue
                    _lane_rows(W, 0, r, X, n, U, 0, C[r], L)
            elif kinds[i] == 1:
                for r in range(4):
                    if (r == 0 and not ua) or (r == 2 and not ub):
                        continue
                    _lane_rows(S, i, r, X, n, U, 2 * i, C[r], L)
            else:  # the whole stage state (it starts the final map), then its wheel coordinates
                for r in range(n):
                    _lane_rows(S, i, r, X, n, U, 2 * i, B[r], L)
                for r in range(4):
                    if (r == 0 and not ua) or (r == 2 and not ub):
                        continue
                    _lane_rows(W, 0, r, B, n, U, 0, C[r], L)
            if not ua:
                C[0, :L] = 0.0
            if not ub:
                C[2, :L] = 0.0
            _lane_torques(dk, dp, dx, dy, tc, C[0], C[1], U[2 * i], L)
            _lane_torques(lk, lp, lx, ly, tc, C[2], C[3], U[2 * i + 1], L)
        base = B if final_base >= 0 else X
        for r in range(n):  # F @ [x (or the stage that starts it), U_0 .. U_{s-1}], summed from the left
            _lane_rows(F, 0, r, base, n, U, 2 * s, Y[r], L)
        o = j + 1 + k
        for q in range(L):
            healthy = True
            for r in range(n):  # angles finite, speeds within the limit (the single loops' check)
                y = Y[r, q]
                X[r, q] = y
                states[a + q, o, r] = y
                if r < half:
                    if y - y != 0.0:
                        healthy = False
                elif not abs(y) <= limit:
                    healthy = False
            if not alive[q]:
                states[a + q, o] = np.nan
                continue
            if not healthy:
                status[a + q] = DIVERGED
                alive[q] = False
                states[a + q, j + 2 + k : j + times.size] = np.nan
