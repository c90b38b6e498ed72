"""The compiled kernel's torque profiles: a profile's torque read from its data (:mod:`~belt_drive_ros.core.profile_data`).

Every function is ``@njit(cache=True, nogil=True)`` over plain arrays and floats (as :mod:`~belt_drive_ros.core.kernel`,
whose loops call them): compiled once per installed version, cached on disk, run without the GIL.

* :func:`torque` -- the dispatcher over a profile's rows (a kind code per row, :mod:`~belt_drive_ros.core.profile_data`):
  the formula kinds (:func:`formula`, scalars only), tables (:func:`_interp`, :func:`_held`), engines and compressors
  (harmonics), motor curves, schedules; inlined into its entries;
* :func:`profile_torque`, :func:`profile_torque_at`, :func:`profile_torque_array` -- its compiled entries (one
  profile, a profile of a stack, arrays of samples);
* :func:`profile_scalars`, :func:`scalar_torque`, :func:`scalar_at` -- a profile that fits in a few numbers read once
  per call and evaluated from scalars (the time loops' fast path: no array reaches an inlined step);
  :func:`scalar_at_call`, the same compiled once and called (the loops off the hot path).

Compilation time: numba's inliner copies a callee's IR block by block, each block's copy taking every variable of
the callee's scope with it, so an inlined copy costs about (blocks x variables) of the callee, nested inlining
included. Inlined copies of the dispatcher and of :func:`scalar_at` made ``make install`` compile for 5.5 minutes
on two cores; hot loops inline only :func:`formula` and :func:`scalar_torque`, everything read once per call or off
the hot path is called (1.5 minutes).

Only a run imports this module (``--help``, ``scenes``, ``msg-tools`` never do).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .profile_data import (
    COMPRESSOR, CONSTANT, ENGINE, MOTOR_CURVE, MOTOR_LINE, POLYNOMIAL, RAMP, SCHEDULE, SINE, STEP, TABLE_HELD,
    TABLE_HELD_NS, TABLE_LINEAR,
)
from . import jit_cache

jit_cache.refresh()  # before any kernel loads: drop cache entries built from other kernel sources

_JIT = dict(cache=True, nogil=True)
#: small helpers are inlined into their callers (no call; numba prunes the reference counts of the arrays one receives
#: unless it passes them on to a call); each inlined copy is compiled again: the dispatcher and the loops are called
_INLINE = dict(cache=True, nogil=True, inline="always")
#: harmonic amplitudes an engine or compressor row may have to run from scalars (:func:`profile_scalars`)
SCALAR_HARMONICS = 3
#: points a motor curve or a linear table may have to run from scalars (:func:`profile_scalars`)
SCALAR_POINTS = 4


@njit(**_JIT)
def _bisect_right(xs, offset, n, x):
    """Index ``i`` in ``[0, n]`` with ``xs[offset + j] <= x`` for all j < i (as :func:`bisect.bisect_right`): the
    search starts where ``x`` would lie among evenly spaced points (a recording's samples nearly are), widens by
    doubling until it brackets ``x``, then halves (the same index as a plain bisection's)."""
    lo, hi = 0, n
    if n > 8 and xs[offset] <= x < xs[offset + n - 1]:
        g = int((x - xs[offset]) / (xs[offset + n - 1] - xs[offset]) * (n - 1))
        g = 0 if g < 0 else n - 2 if g > n - 2 else g
        width = 1
        if xs[offset + g] <= x:  # the answer is above g: xs[j] <= x for every j <= g
            lo, hi = g + 1, g + 1 + width
            while hi < n and xs[offset + hi] <= x:
                lo = hi + 1
                width *= 2
                hi = lo + width
            hi = n if hi > n else hi
        else:  # the answer is at most g: xs[j] > x for every j >= g
            lo, hi = g - width, g
            while lo >= 0 and xs[offset + lo] > x:
                hi = lo
                width *= 2
                lo = hi - width
            lo = 0 if lo < 0 else lo + 1
    while lo < hi:
        mid = (lo + hi) // 2
        if x < xs[offset + mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo


@njit(**_JIT)
def _interp(x, xs, ys, offset, n):
    """``np.interp(x, xp, fp)`` for one float: linear between the points, held beyond the ends."""
    if x <= xs[offset]:
        return ys[offset]
    if x >= xs[offset + n - 1]:
        return ys[offset + n - 1]
    if x != x:
        return x
    j = offset + _bisect_right(xs, offset, n, x) - 1
    return (ys[j + 1] - ys[j]) / (xs[j + 1] - xs[j]) * (x - xs[j]) + ys[j]


@njit(**_JIT)
def _held(x, xs, ys, offset, n):
    """Zero-order hold: the value of the last switching time <= x (the first before the table)."""
    j = _bisect_right(xs, offset, n, x) - 1
    if j < 0:
        j = 0
    elif j >= n:
        j = n - 1
    return ys[offset + j]


@njit(**_INLINE)
def _fade(value, t, duration):
    """``value * clip(t / duration, 0, 1)`` (duration > 0; written without a call, as the branches)."""
    return value * (0.0 if t < 0.0 else 1.0 if t > duration else t / duration)


@njit(**_INLINE)
def is_formula(kind):
    """Whether a row of ``kind`` is a formula of its first five numbers alone (no table, no angle): :func:`formula`."""
    return kind == CONSTANT or kind == STEP or kind == RAMP or kind == SINE or kind == MOTOR_LINE or kind == POLYNOMIAL


@njit(**_INLINE)
def formula(kind, p0, p1, p2, p3, p4, t, speed):
    """Torque [N m] of a row of a formula kind (:func:`is_formula`) from its numbers ``p0 .. p4`` at ``t`` [s],
    ``speed`` [rad/s] (scalars only: no array whose references numba would count, see :data:`_INLINE`)."""
    if kind == CONSTANT:
        return p0
    if kind == STEP:
        return p1 if t >= p2 else p0
    if kind == RAMP:  # v0 + clip((t - t0) / span, 0, 1) * rise
        return p0 + (0.0 if t < p2 else 1.0 if t > p3 else (t - p2) / p4) * p1
    if kind == SINE:  # mean + amplitude sin(omega t + phase)
        return p0 + p1 * math.sin(p2 * t + p3)
    if kind == MOTOR_LINE:
        return motor_line(p0, p1, p2, t, speed)
    if kind == POLYNOMIAL:
        return polynomial(p0, p1, p2, speed)
    return math.nan


@njit(**_INLINE)
def _affine_in_speed(c0, c1, speed):
    """``(c0 + c1 speed, any term)`` without the zero terms (nothing added for a zero coefficient)."""
    value, have = 0.0, False
    if c0 != 0.0:
        value, have = c0, True
    if c1 != 0.0:
        term = c1 * speed
        value, have = (value + term if have else term), True
    return value, have


@njit(**_INLINE)
def motor_line(stall, no_load, fade, t, speed):
    """Motor line row ``(stall, no_load, fade)``: stall (1 - speed / no_load) [N m], faded in over ``fade`` [s]
    (scalars: the variant lanes' loop over speeds compiles to vector operations)."""
    value = stall * (1.0 - speed / no_load)
    return _fade(value, t, fade) if fade > 0.0 else value


@njit(**_INLINE)
def polynomial(c0, c1, c2, speed):
    """Polynomial row ``(c0, c1, c2)``: c0 + c1 speed + c2 speed |speed| [N m], zero terms dropped (scalars: see
    :func:`motor_line`)."""
    value, have = _affine_in_speed(c0, c1, speed)
    if c2 != 0.0:
        term = c2 * speed * abs(speed)
        value = value + term if have else term
    return value


@njit(**_INLINE)
def torque(kinds, params, tx, ty, row, t, angle, speed):
    """Torque [N m] of the profile whose first row is ``row`` at ``t`` [s], ``angle`` [rad], ``speed`` [rad/s]
    (row layouts: :mod:`~belt_drive_ros.core.profile_data`); a schedule row resolves to its active row inside a
    period [start, end), else its inactive one."""
    while kinds[row] == SCHEDULE:
        offset, n = int(params[row, 0]), int(params[row, 1])
        inside = False
        for j in range(n):
            if tx[offset + j] <= t < ty[offset + j]:
                inside = True
                break
        row = int(params[row, 2]) if inside else int(params[row, 3])
    kind = kinds[row]
    if is_formula(kind):
        return formula(kind, params[row, 0], params[row, 1], params[row, 2], params[row, 3], params[row, 4], t, speed)
    if kind == TABLE_LINEAR:
        return _interp(t, tx, ty, int(params[row, 0]), int(params[row, 1]))
    if kind == TABLE_HELD:
        return _held(t, tx, ty, int(params[row, 0]), int(params[row, 1]))
    if kind == TABLE_HELD_NS:  # switching at whole nanoseconds (t rounded half to even)
        return _held(np.rint(t * 1e9), tx, ty, int(params[row, 0]), int(params[row, 1]))
    if kind == ENGINE:
        base = _engine_base(params[row, 0], params[row, 1], params[row, 2], params[row, 3], params[row, 4], speed)
        o, n = int(params[row, 9]), int(params[row, 10])
        value, _ = _harmonics(base, np.bool_(True), ty[o : o + n], params[row, 5] * (params[row, 6] * angle) + params[row, 7])
        return _fade(value, t, params[row, 8]) if params[row, 8] > 0.0 else value
    if kind == MOTOR_CURVE:
        value = _interp(speed, tx, ty, int(params[row, 0]), int(params[row, 1]))
        return _fade(value, t, params[row, 2]) if params[row, 2] > 0.0 else value
    if kind == COMPRESSOR:  # mean + c1 speed + sum_k A_k sin(k (z angle + phase)), zero terms dropped
        value, have = _affine_in_speed(params[row, 0], params[row, 1], speed)
        o, n = int(params[row, 5]), int(params[row, 6])
        value, have = _harmonics(value, have, ty[o : o + n], params[row, 2] * angle + params[row, 3])
        return _fade(value, t, params[row, 4]) if params[row, 4] > 0.0 else value
    return math.nan


@njit(**_INLINE)
def _top(amplitudes):
    """The order of the last nonzero amplitude (0: none)."""
    top = 0
    for k in range(len(amplitudes)):
        if amplitudes[k] != 0.0:
            top = k + 1
    return top


@njit(**_INLINE)
def _series(total, have, amplitudes, top, s, c):
    """``total + sum_{k <= top} A_k sin(k arg)`` over the nonzero A_k from ``s = sin(arg)``, ``c = cos(arg)``, summed
    from the left: ``sin((k+1) arg) = s_k c + c_k s``, ``cos((k+1) arg) = c_k c - s_k s`` (angle addition)."""
    sk, ck = s, c
    for k in range(top):
        a = amplitudes[k]
        if a != 0.0:
            term = a * sk
            total = total + term if have else term
            have = True
        sk, ck = sk * c + ck * s, ck * c - sk * s
    return total, have


@njit(**_INLINE)
def _harmonics(total, have, amplitudes, arg):
    """``total + sum_k A_k sin(k arg)`` over the nonzero A_k (a table's slice, or a tuple of scalars), summed from
    the left; ``have``: total holds a term. One harmonic: ``sin(arg)``; more: :func:`_series` from ``sin(arg)``,
    ``cos(arg)`` (a few ulp from ``sin(k arg)`` for the first harmonics, without the rounding of ``k arg``)."""
    top = _top(amplitudes)
    if top == 1:
        term = amplitudes[0] * math.sin(arg)
        return (total + term if have else term), True
    if top == 0:
        return total, have
    return _series(total, have, amplitudes, top, math.sin(arg), math.cos(arg))


#: the farthest [rad] a harmonic argument is turned from its step's anchor (:func:`_sincos_near`); beyond, sin and cos
#: are called
TURN = 0.5
#: Taylor coefficients of ``sin d / d`` and ``cos d`` in ``z = d^2`` (to d^15 and d^16: at |d| = 0.5 the first term
#: left out is 2e-20, below the rounding of the sums)
_SIN = tuple((-1.0) ** j / math.factorial(2 * j + 1) for j in range(8))
_COS = tuple((-1.0) ** j / math.factorial(2 * j) for j in range(9))
#: no anchor: the next :func:`_sincos_near` calls sin and cos and anchors there (a time loop's step starts with it)
NO_ANCHOR = (math.nan, 0.0, 0.0)


@njit(**_INLINE)
def _sincos_near(arg, anchor):
    """``(sin arg, cos arg, anchor)``. Within :data:`TURN` of the anchor ``(a0, sin a0, cos a0)`` the anchor's pair
    turned by ``d = arg - a0`` (``sin d``, ``cos d`` by their Taylor series, Estrin's scheme; ``s0 cos d + c0 sin d``,
    ``c0 cos d - s0 sin d``: within ~2 ulp of 1 of the library's values, ~2x faster on the critical path); else both
    called and ``arg`` is the new anchor. ``d`` is exact when ``a0 / 2 <= arg <= 2 a0`` (Sterbenz), so only the
    turn rounds: a step's later stages turned from its first stage's angle."""
    a0, s0, c0 = anchor
    d = arg - a0
    if abs(d) <= TURN:
        z = d * d
        z2 = z * z
        z4 = z2 * z2
        sd = d * (((_SIN[0] + _SIN[1] * z) + z2 * (_SIN[2] + _SIN[3] * z))
                  + z4 * ((_SIN[4] + _SIN[5] * z) + z2 * (_SIN[6] + _SIN[7] * z)))  # fmt: skip
        cd = (((_COS[0] + _COS[1] * z) + z2 * (_COS[2] + _COS[3] * z))
              + z4 * ((_COS[4] + _COS[5] * z) + z2 * (_COS[6] + _COS[7] * z) + z4 * _COS[8]))  # fmt: skip
        return s0 * cd + c0 * sd, c0 * cd - s0 * sd, anchor
    s, c = math.sin(arg), math.cos(arg)
    return s, c, (arg, s, c)


@njit(**_INLINE)
def _harmonics_near(total, have, amplitudes, arg, anchor):
    """:func:`_harmonics` from ``sin(arg)``, ``cos(arg)`` by :func:`_sincos_near`, and the anchor: with
    :data:`NO_ANCHOR` (a step's first stage, a result's samples) the library's values, so :func:`_harmonics`' floats
    (one harmonic: ``A_1 sin(arg)``, its cosine then only computed for the anchor)."""
    top = _top(amplitudes)
    if top == 0:
        return total, have, anchor
    s, c, anchor = _sincos_near(arg, anchor)
    total, have = _series(total, have, amplitudes, top, s, c)
    return total, have, anchor


@njit(**_INLINE)
def _engine_base(mode, mean, gain, setpoint, top, speed):
    """An engine row's torque before its harmonics: ``mean`` (mode 0), the droop governor
    ``clip(mean + gain (setpoint - speed), 0, top)`` (mode 1) or ``top`` (mode 2)."""
    if mode == 0.0:
        return mean
    if mode == 1.0:
        b = mean + gain * (setpoint - speed)
        return 0.0 if b < 0.0 else top if b > top else b
    return top


@njit(**_INLINE)
def _row_scalars(kinds, params, tx, ty, row):
    """(whether row ``row`` evaluates from scalars alone, its kind, its first nine numbers, its harmonic
    amplitudes, its points ``(x_0 .. x_3, y_0 .. y_3)``): a formula row, an engine or compressor of at most
    :data:`SCALAR_HARMONICS` harmonics, or a motor curve or linear table of at most :data:`SCALAR_POINTS` points."""
    kind = kinds[row]
    p = (params[row, 0], params[row, 1], params[row, 2], params[row, 3], params[row, 4], params[row, 5],
         params[row, 6], params[row, 7], params[row, 8])  # fmt: skip
    col = 9 if kind == ENGINE else 5
    offset, count = int(params[row, col]), int(params[row, col + 1])
    harmonic = (kind == ENGINE or kind == COMPRESSOR) and count <= SCALAR_HARMONICS
    amplitudes = (ty[offset] if harmonic and count > 0 else 0.0, ty[offset + 1] if harmonic and count > 1 else 0.0,
                  ty[offset + 2] if harmonic and count > 2 else 0.0)  # fmt: skip
    table = kind == MOTOR_CURVE or kind == TABLE_LINEAR
    o, n = (int(params[row, 0]), int(params[row, 1])) if table else (0, 0)
    few = table and 0 < n <= SCALAR_POINTS
    points = (tx[o] if few else 0.0, tx[o + 1] if few and n > 1 else 0.0, tx[o + 2] if few and n > 2 else 0.0,
              tx[o + 3] if few and n > 3 else 0.0, ty[o] if few else 0.0, ty[o + 1] if few and n > 1 else 0.0,
              ty[o + 2] if few and n > 2 else 0.0, ty[o + 3] if few and n > 3 else 0.0)  # fmt: skip
    return is_formula(kind) or harmonic or few, kind, p, amplitudes, points


@njit(**_JIT)
def profile_scalars(kinds, params, tx, ty):
    """A profile as scalars for a loop that reads them once per call (:func:`scalar_torque`): (whether it fits,
    the active part's kind, numbers, amplitudes and points, the inactive part's, the periods ``(s0, e0, s1, e1)``).
    Fits: a row of :func:`_row_scalars`, or a schedule of at most two periods of two such rows (a profile that is
    not a schedule is its own active part, always inside ``(-inf, inf)``). Called, not inlined: each caller reads it
    once, before its loop (inlined, its three row reads of conditional tuples cost ~10 s of compilation a site)."""
    fits, ka, pa, aa, qa = _row_scalars(kinds, params, tx, ty, 0)
    ki, pi, ai, qi = ka, pa, aa, qa
    periods = (-math.inf, math.inf, 0.0, 0.0)
    if kinds[0] == SCHEDULE:
        offset, n, active, inactive = int(params[0, 0]), int(params[0, 1]), int(params[0, 2]), int(params[0, 3])
        fits, ka, pa, aa, qa = _row_scalars(kinds, params, tx, ty, active)
        fits_i, ki, pi, ai, qi = _row_scalars(kinds, params, tx, ty, inactive)
        fits = fits and fits_i and n <= 2
        periods = (tx[offset] if n > 0 else 0.0, ty[offset] if n > 0 else 0.0,
                   tx[offset + 1] if n > 1 else 0.0, ty[offset + 1] if n > 1 else 0.0)  # fmt: skip
    return fits, ka, pa, aa, qa, ki, pi, ai, qi, periods


@njit(**_INLINE)
def _points_interp(x, q, n):
    """:func:`_interp` of ``x`` on the ``n`` <= :data:`SCALAR_POINTS` points ``q = (x_0 .. x_3, y_0 .. y_3)``: the
    same tests and the same segment (the last point at or below x), so the same floats."""
    x0, x1, x2, x3, y0, y1, y2, y3 = q
    if x <= x0:
        return y0
    if x >= (x0 if n == 1 else x1 if n == 2 else x2 if n == 3 else x3):
        return y0 if n == 1 else y1 if n == 2 else y2 if n == 3 else y3
    if x != x:
        return x
    if n > 2 and x >= x1:
        if n > 3 and x >= x2:
            return (y3 - y2) / (x3 - x2) * (x - x2) + y2
        return (y2 - y1) / (x2 - x1) * (x - x1) + y1
    return (y1 - y0) / (x1 - x0) * (x - x0) + y0


@njit(**_INLINE)
def scalar_torque(kind, p, amplitudes, points, t, angle, speed, anchor):
    """(torque [N m], anchor) of a row read by :func:`_row_scalars`: the same operations as :func:`torque`, the
    harmonics' sine and cosine from ``anchor`` (:func:`_harmonics_near`; :data:`NO_ANCHOR`: the same floats)."""
    if kind == ENGINE:
        base = _engine_base(p[0], p[1], p[2], p[3], p[4], speed)
        value, _, anchor = _harmonics_near(base, True, amplitudes, p[5] * (p[6] * angle) + p[7], anchor)
        return (_fade(value, t, p[8]) if p[8] > 0.0 else value), anchor
    if kind == COMPRESSOR:
        value, have = _affine_in_speed(p[0], p[1], speed)
        value, have, anchor = _harmonics_near(value, have, amplitudes, p[2] * angle + p[3], anchor)
        return (_fade(value, t, p[4]) if p[4] > 0.0 else value), anchor
    if kind == MOTOR_CURVE:
        value = _points_interp(speed, points, int(p[1]))
        return (_fade(value, t, p[2]) if p[2] > 0.0 else value), anchor
    if kind == TABLE_LINEAR:
        return _points_interp(t, points, int(p[1])), anchor
    return formula(kind, p[0], p[1], p[2], p[3], p[4], t, speed), anchor


@njit(**_JIT)
def profile_torque(kinds, params, tx, ty, t, angle, speed):
    """Torque [N m] of the profile whose data are ``kinds, params, tx, ty`` (row 0; :func:`torque`). This and
    :func:`profile_torque_at` are called, never inlined: each inlined copy compiled the whole dispatcher again."""
    return torque(kinds, params, tx, ty, 0, t, angle, speed)


@njit(**_JIT)
def profile_torque_at(kinds, params, tx, ty, row, t, angle, speed):
    """Torque [N m] of the profile whose first row is ``row`` (profiles stacked end to end:
    :func:`~belt_drive_ros.core.profile_data.stack`; :func:`torque`)."""
    return torque(kinds, params, tx, ty, row, t, angle, speed)


@njit(**_JIT)
def profile_torque_array(kinds, params, tx, ty, t, angle, speed, out):
    """:func:`profile_torque` at each sample of the equal-length 1-D arrays ``t``, ``angle``, ``speed`` into ``out``:
    a profile that fits in scalars (:func:`profile_scalars`) read once per call, any other through this function's
    one inlined copy of :func:`torque` (a call per sample cost 15-39 ns)."""
    fits, ka, pa, aa, qa, ki, pi, ai, qi, per = profile_scalars(kinds, params, tx, ty)
    for i in range(t.size):
        ti = t[i]
        if fits:
            k, p, a, q = (ka, pa, aa, qa) if per[0] <= ti < per[1] or per[2] <= ti < per[3] else (ki, pi, ai, qi)
            out[i], _ = scalar_torque(k, p, a, q, ti, angle[i], speed[i], NO_ANCHOR)
        else:
            out[i] = torque(kinds, params, tx, ty, 0, ti, angle[i], speed[i])


@njit(**_INLINE)
def scalar_at(sc, tc, angle, speed, anchor):
    """(torque [N m], anchor) of a profile read into scalars (``sc``: :func:`profile_scalars`, which fits) at ``tc``:
    its active part inside a period, else its inactive one (:func:`scalar_torque`, harmonics from ``anchor``)."""
    _, ka, pa, aa, qa, ki, pi, ai, qi, per = sc
    if per[0] <= tc < per[1] or per[2] <= tc < per[3]:
        return scalar_torque(ka, pa, aa, qa, tc, angle, speed, anchor)
    return scalar_torque(ki, pi, ai, qi, tc, angle, speed, anchor)


@njit(**_JIT)
def scalar_at_call(sc, tc, angle, speed, anchor):
    """:func:`scalar_at`, compiled once and called, for the loops off the hot path (the general loop's two-wheel
    inputs, the slip event step's). Why not inlined there: numba's inliner copies a callee's whole IR once per block,
    each copy with every variable of the callee's scope, so an inlined :func:`scalar_at` (two :func:`scalar_torque`
    with their harmonics, tables and fades) cost ~20 s of compilation per site; ``wheel_steps`` had four (169 s to
    compile, 34 s calling this). The same operations, so the same floats."""
    return scalar_at(sc, tc, angle, speed, anchor)
