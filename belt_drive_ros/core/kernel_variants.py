"""The compiled loop over a variant axis: the single run's step, for a whole chunk of variants
(``docs/campaigns.md``: the pipeline without threads, variants as vector lanes, the figures).

Each variant's numbers are one row of ``reals`` (the row a single run of that variant packs,
:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`), and each gets its single run's floats bit for bit
(tests/test_ensemble.py): an explicit method on a plant of <= 4 states through :func:`_lanes`, anything else
(more states, an implicit stage, the slipping belt's extra input or guard, a profile with harmonics) through the
single run's loop (:func:`~belt_drive_ros.core.kernel._steps`) once per variant. Serial on purpose (one Dask worker per core).
"""

from __future__ import annotations

import warnings

import numpy as np
from numba import njit
from numba.core.errors import NumbaPerformanceWarning

from .kernel import HEADER, SECTIONS, _friction_force, _steps
from .kernel_profiles import formula, is_formula, motor_line, polynomial, profile_torque
from .profile_data import COMPRESSOR, DIVERGED, ENGINE, MOTOR_LINE, OK, POLYNOMIAL

#: variants stepped together by :func:`_lanes` (lawson5's matrices: ~470 kB for 128 lanes, in the L2 cache)
LANES = 128


#: numba's ``parallel`` option with every transformation off: the parallel pipeline's passes, no threads
_PIPELINE = dict(comprehension=False, reduction=False, inplace_binop=False, setitem=False, numpy=False, stencil=False,
                 fusion=False, prange=False)  # fmt: skip
# numba says so when it compiles (no parallel transformation was possible): that is the point here
warnings.filterwarnings("ignore", message=r"(?s).*'parallel=True' was specified", category=NumbaPerformanceWarning)


@njit(cache=True, nogil=True, parallel=_PIPELINE)
def variant_steps(times, states, j, lo, hi, limit, reals, tables, ints, dp, lp, status):
    """Steps ``times[k] -> times[k+1]`` of every variant from ``states[j, :, v]`` into ``states[j+1 : j+len(times), :, v]``.

    Parameters
    ----------
    times : (K+1,) step ends [s] (shared); states : (J, n, V) the variants' knots, J >= j + K + 1, the variant axis
        last (contiguous: the lanes' state rows are written as vector stores, and the ensemble's windows are this
        array as it is, no transposed copy).
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
    # a profile with harmonics: each variant in the single loop, whose later stages turn their step's first sine and
    # cosine (kernel_profiles._sincos_near) where the lanes call the dispatcher: the single run's floats either way
    harmonic = False
    for q in range(dk.size):
        harmonic = harmonic or dk[q] == ENGINE or dk[q] == COMPRESSOR
    for q in range(lk.size):
        harmonic = harmonic or lk[q] == ENGINE or lk[q] == COMPRESSOR
    V = states.shape[2]
    if n <= 4 and ints[6] == 0 and E == 0 and count > 0 and not harmonic:  # explicit, rigid or flexible, no extra input
        guarded = False
        for v in range(V):
            guarded = guarded or reals[v, at[6]] != 0.0
        if not guarded:
            for a in range(0, V, LANES):
                _lanes(times, states, j, lo, hi, limit, reals, at, n, s, rows, cols, kinds, ints[5], ints[7] != 0, ints[8] != 0,
                       dk, dp, dx, dy, lk, lp, lx, ly, status, a, min(a + LANES, V))  # fmt: skip
            return
    x = np.empty(n)  # a variant's state and knots in the single loop's layout, copied in and out
    out = np.empty((count, n))
    for v in range(V):
        if status[v] != OK:
            states[j + 1 : j + 1 + count, :, v] = np.nan
            continue
        for e in range(n):
            x[e] = states[j, e, v]
        r = reals[v]
        done, st, _ = _steps(
            times, x, out, lo, hi, limit, r[at[0] : at[1]].reshape((1, 4, n)), kinds, r[at[1] : at[2]],
            r[at[2] : at[3]].reshape((s, rows, cols)), r[at[3] : at[4]].reshape((1, n, cols)), ints[5], r[at[4]],
            ints[6], ints[7] != 0, ints[8] != 0, dk, dp, dx, dy, lk, lp, lx, ly, r[at[5] : at[6]].reshape((E, 5)), r[at[6] : at[7]],
        )  # fmt: skip
        if st != OK:
            status[v] = st
            out[done:] = np.nan
        for k in range(count):
            for e in range(n):
                states[j + 1 + k, e, v] = out[k, e]


@njit(cache=True, nogil=True, error_model="numpy")
def window_peaks(times, states, weights, columns, limits, out):
    """Per variant, over the knots ``states`` (K+1, n, V) at ``times`` (K+1,) [s] of a window: the peaks a campaign
    reduces its linear runs to, in one pass, the same floats as numpy's reductions of the outputs
    (``campaign.ensemble_run.GroupRun.peaks``).

    ``weights`` (3, n, V): the rows of C of the belt torque T_b [N m], the relative deflection delta [rad] and the
    speed omega_M [rad/s] per variant; ``columns`` (3, n) int64: 1 for the columns summed (those with a weight not
    0.0 in some variant), each output the sum of its weighted columns from the left, begun from the first
    (:func:`~belt_drive_ros.core.ensemble.weighted_columns`; no column: 0.0); ``limits`` (V, 6): per variant
    ``[1.0, F_0, m', r_2 g, k_c, r_3]``, the row of the capstan limit ``Q_max = max((F_0 - m' v^2) k_c, 0)``,
    ``v = r_2 g omega_M`` [N] (:func:`~belt_drive_ros.core.kernel._friction_force`), then r_3 [m].

    ``out`` (4, V): max |T_b|, max |delta| (NaN if one is NaN, as ``np.max``), and the friction use ``|Q| / Q_max``,
    ``Q = T_b / r_3`` (inf where Q_max <= 0: :func:`~belt_drive_ros.core.fidelity.friction_use`) at its first peak
    (a NaN first, as ``np.argmax``) with that knot's time [s].
    """
    # (numpy's error model: a division by a Q_max <= 0 gives inf or NaN, as numpy's does, and is then replaced)
    count, n, V = states.shape
    y = np.empty((3, V))  # a knot's outputs, the variants as lanes (vector loops over the contiguous variant axis)
    peak_b, peak_d, best, at = out[0], out[1], out[2], out[3]
    nan_b, nan_d = np.zeros(V, dtype=np.bool_), np.zeros(V, dtype=np.bool_)
    peak_b[:] = -1.0
    peak_d[:] = -1.0
    for k in range(count):
        for o in range(3):
            started = False
            for c in range(n):
                if columns[o, c]:
                    if started:
                        for v in range(V):
                            y[o, v] = y[o, v] + weights[o, c, v] * states[k, c, v]
                    else:
                        for v in range(V):
                            y[o, v] = weights[o, c, v] * states[k, c, v]
                    started = True
            if not started:
                y[o, :] = 0.0
        t = times[k]
        for v in range(V):
            b, d = abs(y[0, v]), abs(y[1, v])
            nan_b[v] |= b != b
            peak_b[v] = b if b > peak_b[v] else peak_b[v]
            nan_d[v] |= d != d
            peak_d[v] = d if d > peak_d[v] else peak_d[v]
            q_max = _friction_force(limits[v], y[2, v])  # (1.0 times Q_max: Q_max itself)
            use = b / limits[v, 5] / q_max
            use = use if q_max > 0.0 else np.inf
            was = best[v]
            first = (k == 0) | ((was == was) & ((use != use) | (use > was)))
            best[v] = use if first else was
            at[v] = t if first else at[v]
    for v in range(V):
        peak_b[v] = np.nan if nan_b[v] else peak_b[v]
        peak_d[v] = np.nan if nan_d[v] else peak_d[v]


def warm_peaks() -> None:
    """Compile (or load from the disk cache) :func:`window_peaks` with the one signature campaigns call it with."""
    window_peaks(np.zeros(1), np.zeros((1, 2, 1)), np.zeros((3, 2, 1)), np.ones((3, 2), dtype=np.int64), np.ones((1, 6)),
                 np.empty((4, 1)))  # fmt: skip


@njit(cache=True, nogil=True)
def knot_torques(kinds, params, tx, ty, times, angle, speed, out):
    """``out[k, v] = profile_torque(kinds, params, tx, ty, times[k], angle[k, v], speed[k, v])``: a profile's
    torques [N m] at the knots (K,) of V variants ((K, V) arrays), the variants of a knot as lanes
    (:func:`_lane_torques`: the same floats as the dispatcher's, the motor line and polynomial vectorised)."""
    for k in range(times.size):
        _lane_torques(kinds, params, tx, ty, times[k], angle, speed, out, k, k, k, out.shape[1])


@njit(cache=True, nogil=True, inline="always")
def _lane_torques(kinds, params, tx, ty, t, angle, speed, out, a, v, o, L):
    """``out[o, q] = profile_torque(kinds, params, tx, ty, t, angle[a, q], speed[v, q])`` for q < L (one kind for
    every lane): the motor line and polynomial from the row's numbers read once (vector loops, the same IEEE
    operations per lane), a formula of time once for all lanes, the rest by the dispatcher lane by lane."""
    kind = kinds[0]
    if kind == MOTOR_LINE:  # the row's numbers read once: the loop compiles to vector operations
        p0, p1, p2 = params[0, 0], params[0, 1], params[0, 2]
        for q in range(L):
            out[o, q] = motor_line(p0, p1, p2, t, speed[v, q])
    elif kind == POLYNOMIAL:
        p0, p1, p2 = params[0, 0], params[0, 1], params[0, 2]
        for q in range(L):
            out[o, q] = polynomial(p0, p1, p2, speed[v, q])
    elif is_formula(kind):  # a function of time alone (the speed is not read)
        value = formula(kind, params[0, 0], params[0, 1], params[0, 2], params[0, 3], params[0, 4], t, 0.0)
        for q in range(L):
            out[o, q] = value
    else:
        for q in range(L):
            out[o, q] = profile_torque(kinds, params, tx, ty, t, angle[a, q], speed[v, q])


@njit(cache=True, nogil=True)
def _lanes(times, states, j, lo, hi, limit, reals, at, n, s, rows, cols, kinds, final_base, ua, ub,
           dk, dp, dx, dy, lk, lp, lx, ly, status, a, b):  # fmt: skip
    """Variants ``a .. b-1`` (at most :data:`LANES`) of an explicit method on an n-state plant (n <= 4: rigid or
    flexible), stepped together, the variants as lanes; no extra input (E = 0), no guard.

    The operations of :func:`~belt_drive_ros.core.kernel._explicit` in the same order (per stage the wheel
    coordinates summed from the left from 0.0, the two torques; then the final map), each over all lanes before
    the next. One work array ``w`` (rows, :data:`LANES`): the variants' numbers ``reals[:, at[0]:at[4]]``
    (W, offsets, S, F), then x, U (right after x: the maps read ``[x, U_0 ..]``), B (a kind-2 stage state), the
    next state Y and the wheel coordinates C; the step is a fixed ``plan`` of dot products over rows named by
    integers (no views: ``docs/campaigns.md``). Padding lanes of a partial chunk repeat variant ``b-1``, never
    written back.
    """
    L = b - a
    R0 = at[4] - at[0]
    oX = R0
    oU = oX + n
    oB = oU + 2 * s
    oY = oB + n
    oC = oY + n
    w = np.empty((oC + 4, LANES))
    w[oX:] = 0.0
    for q in range(LANES):
        v = a + min(q, L - 1)
        for e in range(R0):
            w[e, q] = reals[v, at[0] + e]
        for e in range(n):
            w[oX + e, q] = states[j, e, v]
    # the plan: (out, first matrix row, first source row, columns) for a dot product, (-1, stage) for its torques,
    # (-2, ..) for the final map's start B copied onto x (then followed by U as the final map reads it)
    plan = np.zeros((s * (n + 5) + n + 1, 4), dtype=np.int64)
    p = 0
    wheel = [r for r in range(4) if (r != 0 or ua) and (r != 2 or ub)]
    for i in range(s):
        if kinds[i] == 2:  # the whole stage state, then W on it
            for r in range(n):
                plan[p, 0], plan[p, 1], plan[p, 2], plan[p, 3] = oB + r, at[2] - at[0] + (i * rows + r) * cols, oX, n + 2 * i
                p += 1
        for r in wheel:
            if kinds[i] == 1:
                plan[p, 0], plan[p, 1], plan[p, 2], plan[p, 3] = oC + r, at[2] - at[0] + (i * rows + r) * cols, oX, n + 2 * i
            else:
                plan[p, 0], plan[p, 1], plan[p, 2], plan[p, 3] = oC + r, r * n, oX if kinds[i] == 0 else oB, n
            p += 1
        plan[p, 0], plan[p, 1] = -1, i
        p += 1
    if final_base >= 0:
        plan[p, 0] = -2
        p += 1
    for r in range(n):
        plan[p, 0], plan[p, 1], plan[p, 2], plan[p, 3] = oY + r, at[3] - at[0] + r * cols, oX, n + 2 * s
        p += 1
    # the dot products over the columns whose coefficient is not 0.0 in some lane, in runs of adjacent columns
    # (out, first matrix row, first source row, columns, 1: add to the sum so far, 0: start it from 0.0); other
    # entries as in plan. A 0.0 coefficient times a finite number adds +-0.0, which changes no sum begun from 0.0:
    # the same floats wherever a step's numbers are finite (a step that overflows is a diverged lane either way)
    runs = np.zeros((p * (cols + 1), 5), dtype=np.int64)
    z = 0
    for e in range(p):
        out, m, src, count = plan[e, 0], plan[e, 1], plan[e, 2], plan[e, 3]
        if out < 0:
            runs[z, 0], runs[z, 1] = out, m
            z += 1
            continue
        started = False
        c = 0
        while c <= count:
            d = c
            while d < count and _nonzero(w, m + d):
                d += 1
            if d > c or (d == count and not started):  # columns c .. d-1 (none at all: the sum is 0.0)
                runs[z, 0], runs[z, 1], runs[z, 2], runs[z, 3], runs[z, 4] = out, m + c, src + c, d - c, started
                z += 1
                started = True
            c = d + 1
    # a lane's knots are written times 1.0 while it runs (the same floats) and times NaN once it has diverged; its
    # check counts 1 for a bad state of a running lane (integer arithmetic over the lanes: vector operations)
    scale = np.ones(LANES)
    live = np.ones(LANES, dtype=np.int64)
    for q in range(L):
        if status[a + q] != OK:
            scale[q], live[q] = np.nan, 0
    half = n // 2
    for k in range(times.size - 1):
        t = times[k]
        for e in range(z):
            out, m, src, count = runs[e, 0], runs[e, 1], runs[e, 2], runs[e, 3]
            if out >= 0:  # sum_c w[m + c] w[src + c], from the left from 0.0, four columns a pass
                if runs[e, 4] == 0:
                    for q in range(LANES):
                        w[out, q] = 0.0
                c = 0
                while c + 4 <= count:
                    for q in range(LANES):
                        w[out, q] = (w[out, q] + w[m + c, q] * w[src + c, q] + w[m + c + 1, q] * w[src + c + 1, q]
                                     + w[m + c + 2, q] * w[src + c + 2, q] + w[m + c + 3, q] * w[src + c + 3, q])  # fmt: skip
                    c += 4
                while c + 2 <= count:
                    for q in range(LANES):
                        w[out, q] = w[out, q] + w[m + c, q] * w[src + c, q] + w[m + c + 1, q] * w[src + c + 1, q]
                    c += 2
                if c < count:
                    for q in range(LANES):
                        w[out, q] = w[out, q] + w[m + c, q] * w[src + c, q]
            elif out == -2:
                for r in range(n):
                    for q in range(LANES):
                        w[oX + r, q] = w[oB + r, q]
            else:  # stage m's torques at its time, clamped
                offset = reals[a, at[1] + m]
                time = t if offset == 0.0 else t + offset
                tc = lo if time < lo else hi if time > hi else time
                # the drive from C rows 0, 1 (angle, speed), the load from rows 2, 3; four arrays into an inlined
                # helper, counted per call: twice a stage for 128 lanes
                _lane_torques(dk, dp, dx, dy, tc, w, w, w, oC, oC + 1, oU + 2 * m, LANES)
                _lane_torques(lk, lp, lx, ly, tc, w, w, w, oC + 2, oC + 3, oU + 2 * m + 1, LANES)
        o = j + 1 + k
        flags = 0
        for r in range(n):
            if r < half:  # angles finite
                for q in range(L):
                    y = w[oY + r, q]
                    states[o, r, a + q] = y * scale[q]
                    flags += (0 if y - y == 0.0 else 1) * live[q]
            else:  # speeds within the limit (the single loops' check)
                for q in range(L):
                    y = w[oY + r, q]
                    states[o, r, a + q] = y * scale[q]
                    flags += (0 if abs(y) <= limit else 1) * live[q]
            for q in range(LANES):
                w[oX + r, q] = w[oY + r, q]
        if flags:  # a running lane went bad at this knot: its status, NaN knots after it
            for q in range(L):
                if live[q] == 0:
                    continue
                healthy = True
                for r in range(n):
                    y = states[o, r, a + q]
                    if r < half:
                        if y - y != 0.0:
                            healthy = False
                    elif not abs(y) <= limit:
                        healthy = False
                if not healthy:
                    status[a + q] = DIVERGED
                    scale[q], live[q] = np.nan, 0


@njit(cache=True, nogil=True, inline="always")
def _nonzero(w, row):
    """Whether row ``row`` of the lanes' work array holds a number other than 0.0 in some lane."""
    for q in range(w.shape[1]):
        if w[row, q] != 0.0:
            return True
    return False
