"""The belt network's compiled time loop: the kernel's third model family (numba).

One loop for both linear tiers of a network (flexible: every pulley and the
tensioner arm; rigid: one DOF through the speed ratios). It is the linear
family's loop (:func:`belt_drive_ros.core.kernel.linear_steps`) with P torque
profiles instead of two: a fixed-step method's
:class:`~belt_drive_ros.core.stage_scheme.StageScheme` as its matrices,
the stage torques from the profiles' data through the one dispatcher
(:func:`belt_drive_ros.core.kernel.profile_torque`), the profiles stacked as
data (``pk`` (P, R), ``pp`` (P, R, WIDTH), ``px``/``py`` (P, K): profile p's
own arrays, zero-padded; its row and table indices unchanged).

``@njit(cache=True, nogil=True)`` over float64/int64 C arrays and floats:
compiled once per installed version, never per scene; valid Python
(``NUMBA_DISABLE_JIT=1`` gives the same floats).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..kernel import profile_torque_at
from ..profile_data import DIVERGED, NOT_CONVERGED, OK

_INLINE = dict(cache=True, nogil=True, inline="always")
#: the implicit stage's fixed point has stalled at rounding when its torques repeat with period two and the two
#: values differ by at most this part (a torque summed from large terms, e.g. a governor's ``g (w_set - w)``, moves
#: by more than the tolerance when the state moves by one ulp: the iteration cannot get closer, it alternates)
ROUNDING = 1e-9


@njit(**_INLINE)
def _matvec(mats, g, shape, v, voff, out, ooff):
    """``out[ooff + r] = sum_j M_g[r, j] v[voff + j]``, each row summed from the left (zero products included:
    adding an exact zero changes no sum).

    ``shape[g]`` = (start, rows, stored columns, identity): ``M_g`` is stored by rows at ``mats[start:]``;
    with ``identity`` = 1 its leading square block is the identity and is not stored (a final map that
    starts from a stage's state: row r's sum up to that block is exactly ``v[r]``, so it starts there).
    Four rows are summed together, each in its own accumulator: a single row's sum is a chain of
    dependent additions, four chains overlap.
    """
    at, rows, cols, eye = shape[g, 0], shape[g, 1], shape[g, 2], shape[g, 3]
    skip = rows if eye else 0
    r = 0
    while r + 4 <= rows:
        p0 = at + r * cols
        p1, p2, p3 = p0 + cols, p0 + 2 * cols, p0 + 3 * cols
        if eye:
            a0, a1, a2, a3 = v[voff + r], v[voff + r + 1], v[voff + r + 2], v[voff + r + 3]
        else:
            a0 = a1 = a2 = a3 = 0.0
        for j in range(cols):
            vj = v[voff + skip + j]
            a0 = a0 + mats[p0 + j] * vj
            a1 = a1 + mats[p1 + j] * vj
            a2 = a2 + mats[p2 + j] * vj
            a3 = a3 + mats[p3 + j] * vj
        out[ooff + r], out[ooff + r + 1], out[ooff + r + 2], out[ooff + r + 3] = a0, a1, a2, a3
        r += 4
    while r < rows:
        p0 = at + r * cols
        a0 = v[voff + r] if eye else 0.0
        for j in range(cols):
            a0 = a0 + mats[p0 + j] * v[voff + skip + j]
        out[ooff + r] = a0
        r += 1


@njit(**_INLINE)
def _torques(buf, base, coords, time, lo, hi, uses_angle, start, pk, pp, px, py):
    """Write the P stage torques at ``time`` clamped to [lo, hi] into ``buf[base:]`` (coords: angle, speed per profile)."""
    tc = lo if time < lo else hi if time > hi else time
    for p in range(start.size):
        angle = coords[2 * p] if uses_angle[p] else 0.0
        buf[base + p] = profile_torque_at(pk, pp, px, py, start[p], tc, angle, coords[2 * p + 1])


@njit(cache=True, nogil=True)
def network_steps(times, x, out, lo, hi, limit, mats, shape, kinds, offsets, final_base, tol, max_iter,
                  uses_angle, start, pk, pp, px, py):  # fmt: skip
    """Steps ``times[k] -> times[k+1]`` of one fixed-step method on ``x' = A x + B u(t, x)`` from ``x``; states into ``out[k]``.

    Parameters
    ----------
    times : (N+1,) step ends [s]; x : (n,) state at ``times[0]``; out : (N, n).
    lo, hi : stage times are clamped into [lo, hi] [s] (a run between two torque breakpoints).
    limit : speed [rad/s] past which the state counts as diverged (the second half of x holds speeds).
    mats, shape : the method's matrices, each stored by rows in ``mats`` (:func:`_matvec`); ``shape[g]`` =
        (start, rows, stored columns, identity) of matrix g. Matrix 0 is W (2P, n): profile p's angle and speed are rows 2p and
        2p + 1 of ``W x``; matrix 1 + i is stage i's map, matrix 1 + s the final map F (n, n + P s).
    kinds : (s,) per stage: 0 the stage state is x; 1 its map holds ``W @ stage map``; 2 the stage map itself
        (the stage whose state starts the final map), then W.
    offsets : (s,) ``c_i h`` [s]; final_base : -1 or the stage whose state starts the final map.
    tol, max_iter : the implicit last stage's fixed point (max_iter 0: explicit).
    uses_angle : (P,) int; start : (P,) each profile's first row in the stacked profiles ``pk, pp, px, py``
        (:func:`~belt_drive_ros.core.profile_data.stack`).

    Returns (steps done, status, time [s] of the failing step): status OK, DIVERGED (the last state written is
    non-finite or too fast) or NOT_CONVERGED (the implicit stage of the step after the last one written).
    """
    n = x.size
    s = kinds.size
    m = start.size
    half = n // 2
    cols = n + m * s
    rows = 2 * m
    fin = 1 + s
    work = np.zeros(cols + 2 * n + rows + s * n + m)
    v = work[:cols]
    xs = work[cols : cols + n]
    state = work[cols + n : cols + 2 * n]
    coords = work[cols + 2 * n : cols + 2 * n + rows]
    full = work[cols + 2 * n + rows : cols + 2 * n + rows + s * n]
    back = work[cols + 2 * n + rows + s * n :]  # the implicit stage's torques two sweeps back
    for r in range(n):
        xs[r] = x[r]
    n_explicit = s - 1 if max_iter > 0 else s
    steps = times.size - 1
    for k in range(steps):
        t = times[k]
        for r in range(n):
            v[r] = xs[r]
        for i in range(n_explicit):
            time = t if offsets[i] == 0.0 else t + offsets[i]
            width = n + m * i
            if kinds[i] == 0:
                _matvec(mats, 0, shape, v, 0, coords, 0)
            elif kinds[i] == 1:
                _matvec(mats, 1 + i, shape, v, 0, coords, 0)
            else:
                _matvec(mats, 1 + i, shape, v, 0, full, i * n)
                _matvec(mats, 0, shape, full, i * n, coords, 0)
            _torques(v, width, coords, time, lo, hi, uses_angle, start, pk, pp, px, py)
        if final_base >= 0:
            for r in range(n):
                v[r] = full[final_base * n + r]
        if max_iter == 0:
            _matvec(mats, fin, shape, v, 0, state, 0)
        else:  # implicit last stage (trapezoidal): fixed point on its torques from the previous stage's
            known = n + m * (s - 1)
            for q in range(m):
                v[known + q] = v[known - m + q]
                back[q] = np.nan
            converged = False
            time = t if offsets[s - 1] == 0.0 else t + offsets[s - 1]
            tc = lo if time < lo else hi if time > hi else time
            for _ in range(max_iter):
                _matvec(mats, fin, shape, v, 0, state, 0)
                _matvec(mats, 0, shape, state, 0, coords, 0)
                same = True
                cycle = True  # every torque back at its value two sweeps ago, the two a rounding apart: stalled
                for p in range(m):
                    old = v[known + p]
                    angle = coords[2 * p] if uses_angle[p] else 0.0
                    new = profile_torque_at(pk, pp, px, py, start[p], tc, angle, coords[2 * p + 1])
                    v[known + p] = new
                    if not abs(new - old) <= tol * (1.0 + abs(new)):
                        same = False
                    if not (new == back[p] and abs(new - old) <= ROUNDING * (1.0 + abs(new))):
                        cycle = False
                    back[p] = old
                if same or cycle:
                    converged = True
                    break
            if not converged:
                return k, NOT_CONVERGED, t
            _matvec(mats, fin, shape, v, 0, state, 0)
        healthy = True
        for r in range(n):
            xs[r] = state[r]
            out[k, r] = state[r]
            if r < half:
                if xs[r] - xs[r] != 0.0:
                    healthy = False
            elif not abs(xs[r]) <= limit:
                healthy = False
        if not healthy:
            return k + 1, DIVERGED, t
    return steps, OK, times[steps] if steps >= 0 else 0.0
