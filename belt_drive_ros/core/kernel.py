"""The compiled kernel: the one time loop of the linear family (its torque profiles: :mod:`.kernel_profiles`).

Every function is ``@njit(cache=True, nogil=True)`` over plain arrays and floats: compiled once per installed
version, cached on disk, run without the GIL; ``NUMBA_DISABLE_JIT=1`` runs them as Python with the same floats.

* :func:`wheel_steps` -- the time loop: steps of a fixed-step method (its StageScheme as zero-padded matrices,
  :class:`~belt_drive_ros.core.kernel_loop.KernelLoop`) on ``x' = A x + B u(t, x)`` with P wheels each driven by
  a profile: torque times clamped into ``[lo, hi]``, the implicit stage by fixed point, a slipping belt's
  speed-dependent extra input, the divergence check and an optional guard after every step (the two-wheel drive
  and belt networks);
* :func:`linear_steps` -- the two-wheel drive's entry (its arrays packed), with the fast path of an explicit method,
  the state in scalars (:func:`_state_loop`: :func:`_explicit` for 2 or 4 states, :func:`_explicit_wide` for the
  slipping belt's 5- and 6-state phases);
* :func:`clamped_steps` -- a run of whole steps with their own clamps at breakpoints on the knots (a torque recorded
  at the step rate: one per step) in one compiled call: an explicit method's :func:`_explicit` reads each step's own
  clamps as it goes (one loop for the whole run); another method's loop runs once per group of steps.

Each stage's torques come from :mod:`~belt_drive_ros.core.kernel_profiles` (:func:`formula`, :func:`scalar_torque`,
:func:`torque`, :func:`profile_torque_at`). Only a run imports this module (``--help``, ``scenes``, ``msg-tools``
never do). Every matrix-vector product is summed column by column from the left (zero entries included), as
:func:`~belt_drive_ros.core.stage_scheme.affine` does.
"""

from __future__ import annotations

import math

import numpy as np
from numba import carray, literally, njit, types
from numba.extending import intrinsic, overload

from .kernel_profiles import (
    NO_ANCHOR, formula, is_formula, profile_scalars, profile_torque, profile_torque_at, scalar_at_call, scalar_torque,
)
from .profile_data import DIVERGED, GUARDED, NOT_CONVERGED, OK

_JIT = dict(cache=True, nogil=True)
#: the implicit stage's fixed point has stalled at rounding when its torques repeat with period two and the two
#: values differ by at most this part (a torque summed from large terms, e.g. a governor's ``g (w_set - w)``, moves
#: by more than the tolerance when the state moves by one ulp: the iteration cannot get closer, it alternates)
ROUNDING = 1e-9
#: small helpers are inlined into their callers (no call; numba prunes the reference counts of the arrays one receives
#: unless it passes them on to a call); each inlined copy is compiled again: the dispatcher and the loops are called
_INLINE = dict(cache=True, nogil=True, inline="always")


@njit(**_INLINE)
def _friction_force(e, omega):
    """Extra input ``sigma max((F_0 - m' v^2) k_c, 0)`` at drive speed ``omega``, ``v = r omega`` (``e`` = [sigma, F_0, m', r, k_c])."""
    v = e[3] * omega
    return e[0] * max((e[1] - e[2] * v * v) * e[4], 0.0)


@njit(**_INLINE)
def _rows(M, i, rows, cols, v, voff, out, ooff):
    """``out[ooff + r] = sum_j M[i, r, j] v[voff + j]`` for ``r < rows``, ``j < cols``: each row summed from the
    left from 0.0 (zero products included: adding an exact zero changes no sum). Four rows are summed together,
    each in its own accumulator (four chains of dependent additions overlap; the same floats as row by row)."""
    r = 0
    while r + 4 <= rows:
        a0 = a1 = a2 = a3 = 0.0
        for j in range(cols):
            vj = v[voff + j]
            a0 = a0 + M[i, r, j] * vj
            a1 = a1 + M[i, r + 1, j] * vj
            a2 = a2 + M[i, r + 2, j] * vj
            a3 = a3 + M[i, r + 3, j] * vj
        out[ooff + r], out[ooff + r + 1], out[ooff + r + 2], out[ooff + r + 3] = a0, a1, a2, a3
        r += 4
    while r < rows:
        a0 = 0.0
        for j in range(cols):
            a0 = a0 + M[i, r, j] * v[voff + j]
        out[ooff + r] = a0
        r += 1


@njit(**_INLINE)
def _formula_inputs(buf, base, coords, tc, fk, fp, extra):
    """:func:`_inputs` where wheel p's profile is one formula row ``fk[p]``, ``fp[p]`` (:func:`is_formula`, read once
    per call): no array reaches an out-of-line call, so numba prunes their reference counts (trapezoidal 360 -> 120 ns)."""
    P = fk.size
    for p in range(P):
        buf[base + p] = formula(fk[p], fp[p, 0], fp[p, 1], fp[p, 2], fp[p, 3], fp[p, 4], tc, coords[2 * p + 1])
    for e in range(extra.shape[0]):
        buf[base + P + e] = _friction_force(extra[e], coords[1])


@njit(**_INLINE)
def _inputs(buf, base, coords, tc, uses, start, ak, ap, ax, ay, bk, bp, bx, by, extra):
    """Write a stage's inputs ``[torque_0 .. torque_{P-1}, extras...]`` at the clamped time ``tc`` into ``buf[base:]``:
    wheel p's profile (first row ``start[p]``; profile 0 in the first bank, the others in the second) reads
    ``coords[2p]`` (its angle where ``uses[p]``, else 0.0) and ``coords[2p + 1]``."""
    P = start.size
    buf[base] = profile_torque_at(ak, ap, ax, ay, start[0], tc, coords[0] if uses[0] else 0.0, coords[1])
    for p in range(1, P):
        buf[base + p] = profile_torque_at(bk, bp, bx, by, start[p], tc, coords[2 * p] if uses[p] else 0.0, coords[2 * p + 1])
    for e in range(extra.shape[0]):
        buf[base + P + e] = _friction_force(extra[e], coords[1])


@njit(**_INLINE)
def _pair_inputs(buf, base, coords, tc, uses, sd, sl, ak, ap, ax, ay, bk, bp, bx, by, extra, ad, al):
    """:func:`_inputs` of a two-wheel drive (P = 2, each profile its bank's from row 0) where the drive's or the load's
    profile fits in scalars (``sd``, ``sl``: :func:`profile_scalars`, read once per call): that one evaluated from its
    scalars (no array passed to a call, no reference counted; its harmonics from its anchor ``ad``, ``al``:
    :func:`~belt_drive_ros.core.kernel_profiles.scalar_at_call`, called: inlined at the four sites it took 2 minutes of
    compilation), the other through :func:`profile_torque_at`. Returns
    the anchors."""
    row = np.int64(0)  # (not a literal 0: profile_torque_at keeps its one compiled signature)
    angle = coords[0] if uses[0] else 0.0
    if sd[0]:
        buf[base], ad = scalar_at_call(sd, tc, angle, coords[1], ad)
    else:
        buf[base] = profile_torque_at(ak, ap, ax, ay, row, tc, angle, coords[1])
    angle = coords[2] if uses[1] else 0.0
    if sl[0]:
        buf[base + 1], al = scalar_at_call(sl, tc, angle, coords[3], al)
    else:
        buf[base + 1] = profile_torque_at(bk, bp, bx, by, row, tc, angle, coords[3])
    for e in range(extra.shape[0]):
        buf[base + 2 + e] = _friction_force(extra[e], coords[1])
    return ad, al


@njit(**_INLINE)
def _free_part(F, n, known, v, free):
    """``free[r] = sum_{j < known} F[0, r, j] v[j]``: x+ without the implicit stage, each row summed from the left
    from its first product (``stage_scheme.step``'s ``free``: :func:`~belt_drive_ros.core.stage_scheme.affine`)."""
    for r in range(n):
        a = F[0, r, 0] * v[0]
        for j in range(1, known):
            a = a + F[0, r, j] * v[j]
        free[r] = a


@njit(**_INLINE)
def _implicit_state(F, n, known, m, free, v, state):
    """``state = free + G u`` with ``G = F[0, :, known:known + m]`` and ``u = v[known:known + m]``, ``G u`` summed from
    the left from its first product, then added to ``free`` (``stage_scheme.step``'s ``free + affine(gain, u)``: the
    same floats; a sweep costs n m products, not the whole final map's)."""
    for r in range(n):
        a = F[0, r, known] * v[known]
        for q in range(1, m):
            a = a + F[0, r, known + q] * v[known + q]
        state[r] = free[r] + a


@njit(**_JIT)
def wheel_steps(times, x, out, lo, hi, limit, W, kinds, offsets, S, F, final_base, tol, max_iter,
          uses, start, ak, ap, ax, ay, bk, bp, bx, by, extra, guard):  # fmt: skip
    """The one time loop of the linear family: steps ``times[k] -> times[k+1]`` of one fixed-step method on
    ``x' = A x + B u(t, x)`` from ``x``, with P wheels each driven by a torque profile; states into ``out[k]``.

    The two-wheel drive (:func:`linear_steps`) and a belt network (one wheel per driven pulley) step here;
    a two-wheel plant of 2 or 4 states with an explicit method in :func:`_explicit`, of 5 or 6 (a slipping belt's
    phases) in :func:`_explicit_wide` (the same floats).

    Parameters (all arrays float64/int64, C order)
    ----------
    times : (N+1,) step ends [s]; x : (n,) state at ``times[0]``; out : (N, n).
    lo, hi : torque times are clamped into [lo, hi] (-inf, inf: no clamp) [s].
    limit : speed [rad/s] beyond which the state counts as diverged (its speeds: the second half of x, or x[2:] of a
        slipping belt's phase; stepper.speed_columns).
    W : (1, 2P, n) the wheel map: wheel p's angle and speed are rows 2p, 2p + 1 of ``W x``.
    kinds : (s,) per stage: 0 the stage state is x; 1 only its wheel coordinates
        (``S[i]`` holds ``W @ stages[i]``); 2 the whole stage state (``S[i]`` holds ``stages[i]``, then W).
    offsets : (s,) ``c_i h`` [s]; a stage at ``c_i = 0`` samples at ``t`` itself.
    S : (s, max(2P, n), n + m s) the stage maps, zero-padded; F : (1, n, n + m s) the final map (m = P + E inputs).
    final_base : -1 (``x+ = F @ [x, U...]``) or the stage j whose state starts the final map.
    tol, max_iter : the implicit last stage's fixed point (max_iter 0: explicit method) on all m inputs (the torques
        and the extras), as :func:`~belt_drive_ros.core.stage_scheme.step` iterates it, with its sums
        (``x+ = free + G u``: :func:`_implicit_state`); it also ends when the inputs alternate between two values
        :data:`ROUNDING` apart (stalled at rounding: no closer value exists).
    uses : (P,) whether wheel p's profile reads its angle (else 0.0 is passed); start : (P,) its first row.
    ak, ap, ax, ay : profile 0's bank (kinds, params, tx, ty); bk, bp, bx, by : the other profiles' bank (the
        drive's and load's own data; or a network's stacked profiles, :func:`~belt_drive_ros.core.profile_data.stack`).
    extra : (E, 5) speed-dependent extra inputs at wheel 0's speed (:func:`_friction_force`).
    guard : (5 + 2n,) ``[active, absolute, bound, quad, has_speed, row..., speed...]``:
        stop after the first step whose end state has ``f(row x) > bound - quad (speed x)^2``.
    Every product sums the stage's own columns ``[x, U_0 .. U_{i-1}]`` from the left.

    Returns
    -------
    (steps done, status, time [s] of the failing step): status :data:`OK`, :data:`DIVERGED` (the last state written
    is non-finite or too fast), :data:`GUARDED` (the last state written is the first past the guard) or
    :data:`NOT_CONVERGED` (the implicit stage of the step after the last one written).
    """
    n = x.size
    s = kinds.size
    P = start.size
    m = P + extra.shape[0]
    fast = n // 2 if n <= 4 else 2  # the entries from here on held to the limit (stepper.speed_columns)
    cols = n + m * s
    rows = 2 * P
    # each its own allocation: numba could not prune the reference counts of two views of one array in a helper
    v = np.zeros(cols)  # [x (or the base stage's state), U_0, ..., U_{s-1}]
    xs, state, coords = np.zeros(n), np.zeros(n), np.zeros(rows)  # coords: the wheels' angles and speeds
    prev, back = np.zeros(m), np.zeros(m)  # the implicit stage's inputs before an iteration, and two iterations back
    free = np.zeros(n)  # x+ without the implicit stage's inputs (:func:`_implicit_state`)
    full = np.zeros(s * n)  # stage i's whole state at [i n, (i + 1) n) (a stage that starts the final map)
    fk, fp = np.zeros(P, dtype=np.int64), np.zeros((P, 5))  # wheel p's first row: its kind and first five numbers
    formulas = True  # every wheel's profile one formula row (:func:`_formula_inputs`)
    for p in range(P):
        fk[p] = ak[start[p]] if p == 0 else bk[start[p]]
        formulas = formulas and is_formula(fk[p])
        for j in range(5):
            fp[p, j] = ap[start[p], j] if p == 0 else bp[start[p], j]
    # a two-wheel drive (the drive's and the load's own data, from row 0): a profile that fits in scalars (engines,
    # compressors, schedules of them) is read once per call, as :func:`_explicit` reads it (:func:`_pair_inputs`)
    sd, sl = profile_scalars(ak, ap, ax, ay), profile_scalars(bk, bp, bx, by)
    pair = not formulas and P == 2 and start[0] == 0 and start[1] == 0 and (sd[0] or sl[0])
    for r in range(n):
        xs[r] = x[r]
    n_explicit = s - 1 if max_iter > 0 else s
    count = times.size - 1
    for k in range(count):
        t = times[k]
        ad = al = NO_ANCHOR  # each step's first stage anchors the harmonics of its later explicit stages
        for r in range(n):
            v[r] = xs[r]
        for i in range(n_explicit):
            time = t if offsets[i] == 0.0 else t + offsets[i]
            width = n + m * i
            if kinds[i] == 0:
                _rows(W, 0, rows, n, v, 0, coords, 0)
            elif kinds[i] == 1:
                _rows(S, i, rows, width, v, 0, coords, 0)
            else:
                _rows(S, i, n, width, v, 0, full, i * n)
                _rows(W, 0, rows, n, full, i * n, coords, 0)
            tc = lo if time < lo else hi if time > hi else time
            if formulas:
                _formula_inputs(v, width, coords, tc, fk, fp, extra)
            elif pair:
                ad, al = _pair_inputs(v, width, coords, tc, uses, sd, sl, ak, ap, ax, ay, bk, bp, bx, by, extra, ad, al)
            else:
                _inputs(v, width, coords, tc, uses, start, ak, ap, ax, ay, bk, bp, bx, by, extra)
        if final_base >= 0:
            for r in range(n):
                v[r] = full[final_base * n + r]
        if max_iter == 0:
            _rows(F, 0, n, cols, v, 0, state, 0)
        else:  # x+ = free + G u_last, u_last = u(t + h, x+) by fixed point from the previous stage's inputs
            known = n + m * (s - 1)
            _free_part(F, n, known, v, free)
            for q in range(m):
                v[known + q] = v[known - m + q]
                back[q] = np.nan
            converged = False
            time = t if offsets[s - 1] == 0.0 else t + offsets[s - 1]
            tc = lo if time < lo else hi if time > hi else time
            for _ in range(max_iter):
                _implicit_state(F, n, known, m, free, v, state)
                _rows(W, 0, rows, n, state, 0, coords, 0)
                for q in range(m):
                    prev[q] = v[known + q]
                if formulas:
                    _formula_inputs(v, known, coords, tc, fk, fp, extra)
                elif pair:  # (no anchor: the implicit stage's torques are the library's, as stage_scheme.step's)
                    _pair_inputs(v, known, coords, tc, uses, sd, sl, ak, ap, ax, ay, bk, bp, bx, by, extra, NO_ANCHOR, NO_ANCHOR)
                else:
                    _inputs(v, known, coords, tc, uses, start, ak, ap, ax, ay, bk, bp, bx, by, extra)
                same = True
                cycle = True  # every input back at its value two iterations ago, the two a rounding apart: stalled
                for q in range(m):  # the torques and the extra inputs (the slip force), as stage_scheme.step
                    new = v[known + q]
                    if not abs(new - prev[q]) <= tol * (1.0 + abs(new)):
                        same = False
                    if not (new == back[q] and abs(new - prev[q]) <= ROUNDING * (1.0 + abs(new))):
                        cycle = False
                    back[q] = prev[q]
                if same or cycle:
                    converged = True
                    break
            if not converged:
                return k, NOT_CONVERGED, t
            _implicit_state(F, n, known, m, free, v, state)
        healthy = True
        for r in range(n):
            xs[r] = state[r]
            out[k, r] = state[r]
            if r < fast:
                if xs[r] - xs[r] != 0.0:
                    healthy = False
            elif not abs(xs[r]) <= limit:
                healthy = False
        if not healthy:
            return k + 1, DIVERGED, t
        if guard[0] != 0.0:
            g = 0.0
            for r in range(n):
                g = g + guard[5 + r] * xs[r]
            if guard[1] != 0.0:
                g = abs(g)
            bound = guard[2]
            if guard[4] != 0.0 and guard[3] != 0.0:
                w = 0.0
                for r in range(n):
                    w = w + guard[5 + n + r] * xs[r]
                bound = bound - guard[3] * w * w
            if g > bound:
                return k + 1, GUARDED, t
    return count, OK, times[count] if count >= 0 else 0.0


#: ``ints`` header of :func:`linear_steps`: n, s, E (extra inputs), rows, cols, final_base, max_iter,
#: uses_angle (2), then the start of each section of ``reals`` (and its end), then kinds, dk, lk
HEADER = 9
SECTIONS = ("W", "offsets", "S", "F", "tol", "extra", "guard", "dx", "dy", "lx", "ly")


# numba converts an int argument in a fraction of an array's time, and its reshape calls a C helper of its own (~0.25 us
# each, ~0.7 us for the first, on the caches a 1 ms sleep leaves: a node's tick): the packed arrays' sections are
# viewed at their address (numba's public extension API: an intrinsic for the address as a pointer, numba.carray for
# the array at it, not owned; the buffer's owner keeps it alive through the call)


@intrinsic
def _doubles_at(typingctx, address):
    """``address`` (int64) as a pointer to float64 (LLVM ``inttoptr``)."""
    sig = types.CPointer(types.float64)(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

    return sig, codegen


def doubles_view(words: np.ndarray, offset: int, shape: tuple) -> np.ndarray:
    """``words[offset : offset + prod(shape)]`` (a C-contiguous float64 or int64 array, e.g. a packed buffer or
    its int64 view) as an array of ``shape``, not a copy: the 2-D and 3-D sections of a packed buffer.

    Compiled, the view is made at the address (``numba.carray`` at :func:`_doubles_at`, an int64 array's as the
    float64 view's ``.view(np.int64)``; ``words``' owner keeps it alive) rather than by ``reshape``, which calls a
    C helper of numba's (see above); the same elements either way. Interpreted (``NUMBA_DISABLE_JIT=1``): the
    slice reshaped."""
    size = 1
    for d in shape:
        size *= d
    return words[offset : offset + size].reshape(shape)


@overload(doubles_view, jit_options=dict(nogil=True))
def _doubles_view(words, offset, shape):
    if words.dtype == types.int64:
        def impl(words, offset, shape):
            return carray(_doubles_at(np.int64(words.ctypes.data) + 8 * offset), shape).view(np.int64)
    else:
        def impl(words, offset, shape):
            return carray(_doubles_at(np.int64(words.ctypes.data) + 8 * offset), shape)

    return impl


@intrinsic
def _elements_at(typingctx, address, like):
    """``address`` (int64) as a pointer to the element type of the array ``like`` (LLVM ``inttoptr``)."""
    sig = types.CPointer(like.dtype)(types.int64, like)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

    return sig, codegen


def borrowed(a: np.ndarray) -> np.ndarray:
    """``a`` itself, compiled (a writable C-contiguous array) as a view at its address that owns nothing
    (``numba.carray`` at :func:`_elements_at`: the same type, elements and address; ``a``'s owner must keep it alive
    for as long as the view is used, e.g. an argument of the function making the view, for that call).

    Why: numba counts the references of every array variable (an atomic increment and decrement, ~14 ns a pair) on
    each assignment and each inlined call it is passed to, and prunes those pairs only within one basic block. For an
    array without an owner (a carray's ``meminfo`` is NULL) each of those is a call that finds NULL and returns, no
    atomic operation. Any other array (not C-contiguous, read-only), and interpreted (``NUMBA_DISABLE_JIT=1``): ``a``
    itself."""
    return a


@overload(borrowed, jit_options=dict(nogil=True), inline="always")
def _borrowed(a):
    if isinstance(a, types.Array) and a.layout == "C" and a.mutable:
        def impl(a):
            return carray(_elements_at(np.int64(a.ctypes.data), a), a.shape)
    else:
        def impl(a):
            return a

    return impl


@njit(**_INLINE)
def _unpacked(reals, ints, dp):
    """The packed arrays of :func:`linear_steps` cut into :func:`_steps`' arguments after its first six (views, no
    copy; ``dp`` only for the drive's row count): ``(W, kinds, offsets, S, F, final_base, tol, max_iter, ua, ub, dk,
    dx, dy, lk, lx, ly, extra, guard)`` (the profiles' parameters ``dp``, ``lp`` are passed as themselves); the 3-D
    and 2-D ones by :func:`doubles_view`, not ``reshape``."""
    n, s, E, rows, cols = ints[0], ints[1], ints[2], ints[3], ints[4]
    at = ints[HEADER : HEADER + len(SECTIONS) + 1]
    k0 = HEADER + len(SECTIONS) + 1
    nd = dp.shape[0]
    kinds, dk, lk = ints[k0 : k0 + s], ints[k0 + s : k0 + s + nd], ints[k0 + s + nd :]
    return (
        doubles_view(reals, at[0], (1, 4, n)), kinds, reals[at[1] : at[2]], doubles_view(reals, at[2], (s, rows, cols)),
        doubles_view(reals, at[3], (1, n, cols)), ints[5], reals[at[4]], ints[6], ints[7] != 0, ints[8] != 0, dk,
        reals[at[7] : at[8]], reals[at[8] : at[9]], lk, reals[at[9] : at[10]], reals[at[10] : at[11]],
        doubles_view(reals, at[5], (E, 5)), reals[at[6] : at[7]],
    )  # fmt: skip


@njit(**_JIT)
def linear_steps(times, x, out, lo, hi, limit, reals, ints, dp, lp):
    """Steps ``times[k] -> times[k+1]`` of one fixed-step method from state ``x``; states into ``out[k]``: the plant's
    and method's arrays packed into ``reals`` and ``ints`` (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`;
    layout :data:`HEADER`, :data:`SECTIONS`; a call type-checks ten arguments, not twenty-five), unpacked for
    :func:`_steps` (:func:`_unpacked`). ``dp``, ``lp``: the drive's and load's profile parameters (a held torque
    writes into them)."""
    W, kinds, offsets, S, F, final_base, tol, max_iter, ua, ub, dk, dx, dy, lk, lx, ly, extra, guard = _unpacked(reals, ints, dp)
    return _steps(times, x, out, lo, hi, limit, W, kinds, offsets, S, F, final_base, tol, max_iter, ua, ub, dk, dp, dx, dy,
                  lk, lp, lx, ly, extra, guard)  # fmt: skip


@njit(**_JIT)
def clamped_steps(times, x, out, c0, c1, base, cells, clo, chi, ends, half, limit, reals, ints, dp, lp):
    """Whole grid steps ``c0 <= c < c1`` (step ``c``: ``times[c] -> times[c+1]``, its state into ``out[c]``; ``x``: the
    state at ``times[c0]``) whose torque samples are clamped at breakpoints on the knots: returns ``(c, status, t)``,
    ``c`` the steps done (the failing one included).

    An explicit method on a plant of 2, 4, 5 or 6 states (what :func:`_steps` gives :func:`_explicit` or
    :func:`_explicit_wide`) is one run of that loop over all the steps, each step reading its own clamps from
    ``cells``, ``clo``, ``chi`` (one set-up per call, not per clamped step). Any other method runs in groups of one
    :func:`_steps` run each:

    ``cells`` (sorted, grid indices: step ``c`` is cell ``base + c``) and ``clo``, ``chi`` [s]: each clamped step's
    bounds (``-inf``/``inf`` where none). A group runs from a step to the next end of ``ends`` (sorted grid indices:
    a cell with a finite ``hi``, the cell before one with a finite ``lo``, the last) with its first step's ``lo`` and
    its last step's ``hi``: every sample of the steps between lies inside both already (a bound within ``half`` [s]
    of its knot), so each step reads the torques of its own clamps; a bound farther inside: that step alone, its own
    clamps. The packed arrays are unpacked once per call (:func:`_unpacked`), then each group is one :func:`_steps`
    call. Either way each step's samples are those of its own clamps (a group's bounds lie outside the samples of
    its other steps), so the same floats as one call per step."""
    W, kinds, offsets, S, F, final_base, tol, max_iter, ua, ub, dk, dx, dy, lk, lx, ly, extra, guard = _unpacked(reals, ints, dp)
    N = times.size - 1
    loop = _scalar_loop(max_iter, extra.shape[0], x.size)  # (as _steps chooses)
    if c1 > c0 and loop != 0:
        if loop == 1:
            done, status, t = _explicit(times[c0 : c1 + 1], x, out[c0:c1], -math.inf, math.inf, cells, clo, chi, base + c0,
                                        limit, W, kinds, offsets, S, F, ua, ub, dk, dp, dx, dy, lk, lp, lx, ly, extra, guard,
                                        x.size)  # fmt: skip
        else:
            done, status, t = _explicit_wide(times[c0 : c1 + 1], x, out[c0:c1], -math.inf, math.inf, cells, clo, chi,
                                             base + c0, limit, W, kinds, offsets, S, F, ua, ub, dk, dp, dx, dy, lk, lp, lx,
                                             ly, extra, guard, x.size)  # fmt: skip
        return c0 + done, status, t
    j = np.searchsorted(cells, base + c0)
    e = np.searchsorted(ends, base + c0)
    c = c0
    while c < c1:
        cell = base + c
        while j < cells.size and cells[j] < cell:
            j += 1
        lo = clo[j] if j < cells.size and cells[j] == cell else -math.inf
        while e < ends.size and ends[e] < cell:
            e += 1
        d = ends[e] - base if e < ends.size else N - 1
        d = N - 1 if d > N - 1 else d
        i = j
        while i < cells.size and cells[i] < base + d:
            i += 1
        hi = chi[i] if i < cells.size and cells[i] == base + d else math.inf
        if (lo != -math.inf and lo > times[c] + half) or (hi != math.inf and hi < times[d] + half):
            d = c  # a bound far inside: this step alone, its own clamps
            hi = chi[j] if j < cells.size and cells[j] == cell else math.inf
        d = c1 - 1 if d > c1 - 1 else d
        done, status, t = _steps(times[c : d + 2], x, out[c : d + 1], lo, hi, limit, W, kinds, offsets, S, F, final_base,
                                 tol, max_iter, ua, ub, dk, dp, dx, dy, lk, lp, lx, ly, extra, guard)  # fmt: skip
        if status != OK:
            return c + done, status, t
        x = out[d]
        c = d + 1
    return c1, OK, times[c1] if c1 <= N else 0.0


@njit(**_JIT)
def piece_steps(times, x, out, sets, plo, phi, rows, limit, reals, ints, dp, lp):
    """Steps of various lengths (the pieces of steps split at off-grid breakpoints) in one compiled call: step ``k``
    (``times[k] -> times[k+1]``, its state into ``out[k]``; ``x``: the state at ``times[0]``) with the method's
    numbers of row ``sets[k]`` of ``rows`` (the head of ``reals`` of a loop of that step: its offsets, stage and
    final maps, tolerance and guard, :meth:`~belt_drive_ros.core.kernel_loop.KernelLoop.piece_rows`) and its
    torque times clamped into ``[plo[k], phi[k]]`` [s]; returns ``(steps done, status, t)`` as :func:`clamped_steps`.

    Consecutive steps of one row and one clamp are one :func:`_steps` run (the stepping loop of every method; each
    step's operations do not depend on the run it is in), so the same floats as one call per step."""
    W, kinds, o0, S0, F0, final_base, t0, max_iter, ua, ub, dk, dx, dy, lk, lx, ly, extra, g0 = _unpacked(reals, ints, dp)
    N = times.size - 1
    k = 0
    while k < N:
        g, lo, hi = sets[k], plo[k], phi[k]
        d = k
        while d + 1 < N and sets[d + 1] == g and plo[d + 1] == lo and phi[d + 1] == hi:
            d += 1
        # the row's own sections (those after its head, the tables, come out empty: read from reals above)
        W1, k1, offsets, S, F, b1, tol, m1, a1, a2, dk1, dx1, dy1, lk1, lx1, ly1, e1, guard = _unpacked(rows[g], ints, dp)
        done, status, t = _steps(times[k : d + 2], x, out[k : d + 1], lo, hi, limit, W, kinds, offsets, S, F, final_base,
                                 tol, max_iter, ua, ub, dk, dp, dx, dy, lk, lp, lx, ly, extra, guard)  # fmt: skip
        if status != OK:
            return k + done, status, t
        x = out[d]
        k = d + 1
    return N, OK, times[N] if N >= 0 else 0.0


@njit(**_JIT)  # out of line: the variant loop calls the same compiled body (its inlining doubled the build)
def _steps(times, x, out, lo, hi, limit, W, kinds, offsets, S, F, final_base, tol, max_iter,
           ua, ub, dk, dp, dx, dy, lk, lp, lx, ly, extra, guard):  # fmt: skip
    """The two-wheel loop on these unpacked arrays: :func:`_explicit` for an explicit method on a 2- or 4-state plant,
    :func:`_explicit_wide` on a 5- or 6-state one (a slipping belt's phases), else :func:`wheel_steps` with P = 2
    (the drive's data its first bank, the load's the second); the same floats."""
    loop = _scalar_loop(max_iter, extra.shape[0], x.size)
    if loop == 1:
        return _explicit(times, x, out, lo, hi, dk[:0], times[:0], times[:0], np.int64(0), limit, W, kinds, offsets, S, F,
                         ua, ub, dk, dp, dx, dy, lk, lp, lx, ly, extra, guard, x.size)  # fmt: skip
    if loop == 2:
        return _explicit_wide(times, x, out, lo, hi, dk[:0], times[:0], times[:0], np.int64(0), limit, W, kinds, offsets,
                              S, F, ua, ub, dk, dp, dx, dy, lk, lp, lx, ly, extra, guard, x.size)  # fmt: skip
    uses = np.zeros(2, dtype=np.int64)
    uses[0], uses[1] = ua, ub
    return wheel_steps(times, x, out, lo, hi, limit, W, kinds, offsets, S, F, final_base, tol, max_iter,
                       uses, np.zeros(2, dtype=np.int64), dk, dp, dx, dy, lk, lp, lx, ly, extra, guard)  # fmt: skip


@njit(**_INLINE)
def _scalar_loop(max_iter, E, n):
    """Which loop with the state in scalars steps a run of ``n`` states, ``E`` extra inputs and a method whose implicit
    stage iterates ``max_iter`` times: 1 :func:`_explicit` (explicit, at most one extra input, 2 or 4 states), 2
    :func:`_explicit_wide` (5 or 6), 0 none (:func:`wheel_steps`)."""
    if max_iter != 0 or E > 1:
        return 0
    return 1 if n == 2 or n == 4 else 2 if n == 5 or n == 6 else 0


@njit(**_INLINE)
def _row(M, i, r, x0, x1, x2, x3, x4, x5, n, wide):
    """``sum_j M[i, r, j] x_j`` over the ``n`` state columns (2 or 4; ``wide``: 5 or 6), summed from the left from 0.0
    (as :func:`_rows`). ``wide`` is a constant of each compiled loop (:func:`_explicit`, :func:`_explicit_wide`): its
    branches fold, and each loop tests ``n`` once (more tests of ``n`` kept LLVM from specialising the loop on it:
    paper's ``exact`` step 12 -> 37 ns)."""
    y = 0.0 + M[i, r, 0] * x0 + M[i, r, 1] * x1
    if wide:
        y = y + M[i, r, 2] * x2 + M[i, r, 3] * x3 + M[i, r, 4] * x4
        return y + M[i, r, 5] * x5 if n == 6 else y
    return y + M[i, r, 2] * x2 + M[i, r, 3] * x3 if n == 4 else y


@njit(**_INLINE)
def _stage_rows(M, i, ra, rb, x0, x1, x2, x3, x4, x5, n, wide, U, count):
    """Rows ``ra`` and ``rb`` of ``M[i] @ [x, U[:count]]``: the n state columns, then the earlier stages' torques,
    each row summed from the left (one pass over U for both: half the loop's overhead, the same floats)."""
    ya, yb = _row(M, i, ra, x0, x1, x2, x3, x4, x5, n, wide), _row(M, i, rb, x0, x1, x2, x3, x4, x5, n, wide)
    for j in range(count):
        u = U[j]
        ya = ya + M[i, ra, n + j] * u
        yb = yb + M[i, rb, n + j] * u
    return ya, yb


@njit(**_INLINE)
def _final(F, i, ra, rb, x0, x1, x2, x3, x4, x5, n, wide, u0, u1, e0, E, U, last):
    """Rows ``ra``, ``rb`` of ``F[i] @ [x, U[:last], u0, u1 (, e0)]`` (the latest stage's torques as scalars: they go
    into the sums straight from the registers, not through ``U``), from the left."""
    ya, yb = _stage_rows(F, i, ra, rb, x0, x1, x2, x3, x4, x5, n, wide, U, last)
    ya = ya + F[i, ra, n + last] * u0 + F[i, ra, n + 1 + last] * u1
    yb = yb + F[i, rb, n + last] * u0 + F[i, rb, n + 1 + last] * u1
    return (ya + F[i, ra, n + 2 + last] * e0, yb + F[i, rb, n + 2 + last] * e0) if E else (ya, yb)


@njit(**_INLINE)
def _stage_pair(S, i, ra, rb, x0, x1, x2, x3, x4, x5, n, wide, U, m, u0, u1, e0, E):
    """Rows ``ra``, ``rb`` of stage ``i``'s ``S[i] @ [x, U_0, ..., U_{i-1}]`` (``m`` torques a stage), ``U_{i-1}``
    being the scalars ``u0, u1 (, e0)``: :func:`_final` of the stage (the same sums as :func:`_stage_rows` over
    ``U``; the previous stage's torques are not stored and read back on the path from one torque to the next). At
    stage 0 the scalars are 0.0 and its columns past x are zero padding (:func:`~.kernel_loop.scheme_arrays`): the
    terms add exact zeros to sums that start from +0.0, which changes no float (and no branch here)."""
    return _final(S, i, ra, rb, x0, x1, x2, x3, x4, x5, n, wide, u0, u1, e0, E, U, m * max(i - 1, 0))


@njit(**_INLINE)
def _past_guard(guard, x0, x1, x2, x3, x4, x5, n, wide):
    """Whether state ``x`` (n = 2 or 4 scalars; ``wide``: 5 or 6) is past the guard (the general loop's test, its sums)."""
    g = _row_of(guard, 5, x0, x1, x2, x3, x4, x5, n, wide)
    if guard[1] != 0.0:
        g = abs(g)
    bound = guard[2]
    if guard[4] != 0.0 and guard[3] != 0.0:
        w = _row_of(guard, 5 + n, x0, x1, x2, x3, x4, x5, n, wide)
        bound = bound - guard[3] * w * w
    return g > bound


@njit(**_INLINE)
def _row_of(v, a, x0, x1, x2, x3, x4, x5, n, wide):
    """``sum_j v[a + j] x_j`` over the n state columns, summed from the left from 0.0 (:func:`_row` of a 1-D array)."""
    y = 0.0 + v[a] * x0 + v[a + 1] * x1
    if wide:
        y = y + v[a + 2] * x2 + v[a + 3] * x3 + v[a + 4] * x4
        return y + v[a + 5] * x5 if n == 6 else y
    return y + v[a + 2] * x2 + v[a + 3] * x3 if n == 4 else y


@njit(**_JIT)
def _explicit(times, x, out, lo, hi, cells, clo, chi, base, limit, W, kinds, offsets, S, F, ua, ub, dk, dp, dx, dy, lk, lp,
              lx, ly, extra, guard, n):  # fmt: skip
    """:func:`wheel_steps` for an explicit method on a plant of ``n`` = 2 (rigid) or 4 (flexible) states:
    :func:`_state_loop` (one compiled loop for both sizes: a constant ``n`` compiled it twice)."""
    return _state_loop(times, x, out, lo, hi, cells, clo, chi, base, limit, W, kinds, offsets, S, F, ua, ub, dk, dp, dx, dy,
                       lk, lp, lx, ly, extra, guard, n, False)  # fmt: skip


@njit(**_JIT)
def _explicit_wide(times, x, out, lo, hi, cells, clo, chi, base, limit, W, kinds, offsets, S, F, ua, ub, dk, dp, dx, dy, lk,
                   lp, lx, ly, extra, guard, n):  # fmt: skip
    """:func:`wheel_steps` for an explicit method on a plant of ``n`` = 5 or 6 states (a slipping belt's phases:
    :mod:`.kernel_hybrid`): :func:`_state_loop`, the same source compiled with its wide rows."""
    return _state_loop(times, x, out, lo, hi, cells, clo, chi, base, limit, W, kinds, offsets, S, F, ua, ub, dk, dp, dx, dy,
                       lk, lp, lx, ly, extra, guard, n, True)  # fmt: skip


@njit(**_JIT)
def _state_loop(times, x, out, lo, hi, cells, clo, chi, base, limit, W, kinds, offsets, S, F, ua, ub, dk, dp, dx, dy, lk, lp,
                lx, ly, extra, guard, n, wide):  # fmt: skip
    """:func:`wheel_steps` for an explicit method with the state in scalars (stage kinds as there): ``n`` = 2 (rigid)
    or 4 (flexible) states, or with ``wide`` 5 or 6 (a slipping belt's phases). ``wide`` is a literal: one compiled
    loop per value (:func:`_explicit`, :func:`_explicit_wide`), its branches folded, ``n`` tested once in each (more
    tests of ``n`` in one loop kept LLVM from specialising it: paper's ``exact`` step 12 -> 37 ns).

    Step ``k`` (grid cell ``base + k``) clamps its torque times into ``[lo, hi]``, or where its cell is one of
    ``cells`` (sorted, distinct grid indices) into that one's ``[clo, chi]`` (:func:`clamped_steps`: a run with a
    clamp at every knot is one call; a plain run passes no cells).

    The same operations in the same order, with the state, each stage's wheel coordinates and torques in scalars
    and the earlier stages' torques in a small array ``U`` (rows summed in pairs over it, :func:`_stage_rows`): no
    store and reload on the critical path x -> omega_M -> torque -> x+. An angle no profile reads is not computed.
    A profile of one formula row (:func:`is_formula`) or that fits in scalars (:func:`profile_scalars`: engines,
    compressors, motor curves and linear tables of a few points, schedules) is read once per call, so no array reaches inlined code and numba's reference counts
    drop out of the step (paper's ``exact`` 33 -> 14 ns); any other through the dispatcher, called
    (:func:`profile_torque`: a table's lookup is a call either way; inlined, the dispatcher's two copies took ~20 s of
    each loop copy's compilation, for ~6 ns a torque on a 10-point table).
    """
    literally(wide)
    x0, x1 = x[0], x[1]
    x2 = x[2] if n == 4 or wide else 0.0
    x3 = x[3] if n == 4 or wide else 0.0
    x4 = x[4] if wide else 0.0
    x5 = x[5] if wide and n == 6 else 0.0
    s = kinds.size
    E = extra.shape[0]
    m = 2 + E
    U = np.zeros(m * s)
    last = m * (s - 1)
    guarded = guard[0] != 0.0
    steps = times.size - 1
    dkind, lkind = dk[0], lk[0]
    dform, lform = is_formula(dkind), is_formula(lkind)
    d0, d1, d2, d3, d4 = dp[0, 0], dp[0, 1], dp[0, 2], dp[0, 3], dp[0, 4]
    l0, l1, l2, l3, l4 = lp[0, 0], lp[0, 1], lp[0, 2], lp[0, 3], lp[0, 4]
    # (engines, compressors, small motor curves and tables, schedules of them)
    dfits, dka, dpa, daa, dqa, dki, dpi, dai, dqi, dper = profile_scalars(dk, dp, dx, dy)
    lfits, lka, lpa, laa, lqa, lki, lpi, lai, lqi, lper = profile_scalars(lk, lp, lx, ly)
    nc = cells.size
    j = np.searchsorted(cells, base) if nc else 0  # the first clamped cell at or after step 0's
    for k in range(steps):
        t = times[k]
        lo_k, hi_k = lo, hi
        if j < nc and cells[j] == base + k:  # this step's own clamps
            lo_k, hi_k = clo[j], chi[j]
            j += 1
        u0 = u1 = e0 = 0.0
        da = la = NO_ANCHOR  # each step's first stage anchors the harmonics of its later stages
        b0, b1, b2, b3, b4, b5 = x0, x1, x2, x3, x4, x5  # the state the final map starts from: x, or the stage of kind 2
        for i in range(s):
            time = t if offsets[i] == 0.0 else t + offsets[i]
            tc = lo_k if time < lo_k else hi_k if time > hi_k else time
            if kinds[i] == 2:  # the whole stage state (etd2's a), then its wheel coordinates from it
                b0, b1 = _stage_pair(S, i, 0, 1, x0, x1, x2, x3, x4, x5, n, wide, U, m, u0, u1, e0, E)
                if n == 4 or wide:
                    b2, b3 = _stage_pair(S, i, 2, 3, x0, x1, x2, x3, x4, x5, n, wide, U, m, u0, u1, e0, E)
                if wide:  # (n = 5: row 4 twice, no row 5 read)
                    b4, b5 = _stage_pair(S, i, 4, n - 1, x0, x1, x2, x3, x4, x5, n, wide, U, m, u0, u1, e0, E)
            if kinds[i] == 1:  # the wheel coordinates straight from [x, U]
                c1, c3 = _stage_pair(S, i, 1, 3, x0, x1, x2, x3, x4, x5, n, wide, U, m, u0, u1, e0, E)
                c0 = c2 = 0.0
                if ua or ub:
                    c0, c2 = _stage_pair(S, i, 0, 2, x0, x1, x2, x3, x4, x5, n, wide, U, m, u0, u1, e0, E)
                    c0, c2 = (c0 if ua else 0.0), (c2 if ub else 0.0)
            else:  # W @ the stage state (x itself for kind 0)
                a0, a1, a2, a3, a4, a5 = (x0, x1, x2, x3, x4, x5) if kinds[i] == 0 else (b0, b1, b2, b3, b4, b5)
                c1, c3 = _row(W, 0, 1, a0, a1, a2, a3, a4, a5, n, wide), _row(W, 0, 3, a0, a1, a2, a3, a4, a5, n, wide)
                c0 = _row(W, 0, 0, a0, a1, a2, a3, a4, a5, n, wide) if ua else 0.0
                c2 = _row(W, 0, 2, a0, a1, a2, a3, a4, a5, n, wide) if ub else 0.0
            # written out here, not in a helper: an inlined helper receiving the arrays would count their
            # references on every step again
            if dform:
                u0 = formula(dkind, d0, d1, d2, d3, d4, tc, c1)
            elif dfits:
                kind, p, a, q = (dka, dpa, daa, dqa) if dper[0] <= tc < dper[1] or dper[2] <= tc < dper[3] else (dki, dpi, dai, dqi)
                u0, da = scalar_torque(kind, p, a, q, tc, c0, c1, da)
            else:
                u0 = profile_torque(dk, dp, dx, dy, tc, c0, c1)
            if lform:
                u1 = formula(lkind, l0, l1, l2, l3, l4, tc, c3)
            elif lfits:
                kind, p, a, q = (lka, lpa, laa, lqa) if lper[0] <= tc < lper[1] or lper[2] <= tc < lper[3] else (lki, lpi, lai, lqi)
                u1, la = scalar_torque(kind, p, a, q, tc, c2, c3, la)
            else:
                u1 = profile_torque(lk, lp, lx, ly, tc, c2, c3)
            e0 = _friction_force(extra[0], c1) if E else 0.0
            if i < s - 1:
                U[m * i], U[m * i + 1] = u0, u1
                if E:
                    U[m * i + 2] = e0
        y0, y1 = _final(F, 0, 0, 1, b0, b1, b2, b3, b4, b5, n, wide, u0, u1, e0, E, U, last)
        x0, x1 = y0, y1
        out[k, 0], out[k, 1] = y0, y1
        if wide:  # the general loop's test: x0, x1 finite, the rest (omega_M on) within the limit
            y2, y3 = _final(F, 0, 2, 3, b0, b1, b2, b3, b4, b5, n, wide, u0, u1, e0, E, U, last)
            # (n = 5: row 4 twice, no row 5 read)
            y4, y5 = _final(F, 0, 4, n - 1, b0, b1, b2, b3, b4, b5, n, wide, u0, u1, e0, E, U, last)
            x2, x3, x4 = y2, y3, y4
            out[k, 2], out[k, 3], out[k, 4] = y2, y3, y4
            if n == 6:
                x5 = y5
                out[k, 5] = y5
            # (n = 5: x5 stays 0.0)
            if (x0 - x0 != 0.0 or x1 - x1 != 0.0 or not abs(x2) <= limit or not abs(x3) <= limit or not abs(x4) <= limit
                    or not abs(x5) <= limit):  # fmt: skip
                return k + 1, DIVERGED, t
        elif n == 4:
            y2, y3 = _final(F, 0, 2, 3, b0, b1, b2, b3, b4, b5, n, wide, u0, u1, e0, E, U, last)
            x2, x3 = y2, y3
            out[k, 2], out[k, 3] = y2, y3
            if x0 - x0 != 0.0 or x1 - x1 != 0.0 or not abs(x2) <= limit or not abs(x3) <= limit:
                return k + 1, DIVERGED, t
        elif x0 - x0 != 0.0 or not abs(x1) <= limit:
            return k + 1, DIVERGED, t
        if guarded and _past_guard(guard, x0, x1, x2, x3, x4, x5, n, wide):
            return k + 1, GUARDED, t
    return steps, OK, times[steps] if steps >= 0 else 0.0
