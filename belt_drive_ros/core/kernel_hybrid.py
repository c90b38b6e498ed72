"""The slipping belt's compiled hybrid run over a step plan (numba, ``@njit(cache=True, nogil=True)``).

:func:`hybrid_steps` takes the grid steps of a plan in one call: each stick or slip phase in the linear loop
(:func:`~belt_drive_ros.core.kernel.linear_steps`) with the mode's switching function as its guard; the step in
which the guard fires is redone by the compiled event step (:mod:`~belt_drive_ros.core.kernel_slip`: the event
located and the step split on the modal flow), and the run goes on in the new mode's phase.

Here too: the phase kinds (the state each phase carries), the statuses of the run, and the small helpers that map
a phase's state to the slipping state ``y`` and back (:func:`_to_y`, :func:`_flexible`, :func:`_native`; the
node's compiled tick, :mod:`~belt_drive_ros.core.tick`, inlines them as well). Every function is valid Python:
``NUMBA_DISABLE_JIT=1`` runs them with the same floats.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kernel import borrowed, doubles_view, linear_steps
from .kernel_profiles import profile_scalars
from .kernel_slip import EVENT_WORK, FLOW_WORK, LOCATE_WORK, MAX_SWITCHES, SLIP, STICK, _event_step, _limit
from .profile_data import COMPRESSOR, DIVERGED, ENGINE, GUARDED, NOT_CONVERGED

_JIT = dict(cache=True, nogil=True)
#: the phase-state helpers are inlined into their callers (:func:`hybrid_steps`, the node's tick)
_INLINE = dict(cache=True, nogil=True, inline="always")

#: phase kinds of :func:`hybrid_steps` (the state's coordinates): the flexible model (sticking, no slip so far),
#: the stick mode, the massless slip mode ``[y, Q]`` (sigma +1, -1), the slip mode of a belt with mass and span
#: damping (+1, -1), the slip mode stepped event step by event step (a belt with mass, c = 0)
FLEXIBLE, STICKING, SLIP_UP, SLIP_DOWN, MASS_UP, MASS_DOWN, STEPWISE = 0, 1, 2, 3, 4, 5, 6
#: the phase kinds' names (:class:`~belt_drive_ros.core.slip_run.SlipState` ``kind``) and stepper keys
KIND_NAMES = ("flexible", "stick", "slip", "slip", "mass", "mass", "hybrid")
PHASE_KEYS = ("flexible", "stick", ("slip", 1.0), ("slip", -1.0), ("mass", 1.0), ("mass", -1.0))
#: states per phase kind
PHASE_SIZE = (4, 5, 6, 6, 5, 5, 5)
#: statuses of :func:`hybrid_steps` beyond the linear loop's (OK 0, DIVERGED 1, NOT_CONVERGED 3)
SPECIAL, EVENTS_FULL, CHATTER, NO_PHASE = 4, 5, 6, 7


@njit(**_INLINE)
def _to_y(kind, x, Yflex, y):
    """The slipping state ``y`` (5,) of phase state ``x`` (flexible: ``Yflex @ x`` summed from the left)."""
    if kind == FLEXIBLE:
        for r in range(5):
            total = 0.0
            for j in range(4):
                total = total + Yflex[r, j] * x[j]
            y[r] = total
    else:
        for r in range(5):
            y[r] = x[r]


@njit(**_INLINE)
def _shift_angle(lk, lp, out, c, uses, s):
    """The load's numbers sticking after slip ``s`` [m]: ``lp``, or where the load reads its angle (``uses[1]``)
    ``out``, ``lp`` with every angle-reading row read at its angle + ``shift = -s / r_3`` [rad].

    Sticking after slip is the flexible model with the load at
    ``phi_3 = i phi_M - theta_e - s / r_3``: the flexible loop reads
    ``i phi_M - theta_e``, and ``-s / r_3`` goes into the phase of each
    harmonic row (:mod:`~belt_drive_ros.core.profile_data`'s layouts: engine
    ``p5 (p6 angle) + p7``, compressor ``p2 angle + p3``; no other kind reads the angle).
    """
    if uses[1] == 0:
        return lp
    shift = (-1.0 / c[1]) * s  # the stick plant's wheel map term, as it rounds
    for row in range(lk.size):
        for q in range(lp.shape[1]):
            out[row, q] = lp[row, q]
        if lk[row] == ENGINE:
            out[row, 7] = lp[row, 7] + lp[row, 5] * (lp[row, 6] * shift)
        elif lk[row] == COMPRESSOR:
            out[row, 3] = lp[row, 3] + lp[row, 2] * shift
    return out


@njit(**_INLINE)
def _flexible(y, Minv, x):
    """The flexible state ``x[:4] = Minv @ y[:4]`` of slipping state ``y`` (summed from the left)."""
    for r in range(4):
        total = 0.0
        for j in range(4):
            total = total + Minv[r, j] * y[j]
        x[r] = total


@njit(**_INLINE)
def _native(mode, sigma, y, x, Minv, c, have):
    """The phase kind of (mode, sigma, y) and its state written into ``x`` (``have[kind]``: the phase exists)."""
    if mode == STICK:
        if y[4] == 0.0:
            _flexible(y, Minv, x)
            return FLEXIBLE
        x[:5] = y
        return STICKING
    up = sigma > 0.0
    x[:5] = y
    if have[SLIP_UP if up else SLIP_DOWN] != 0:
        x[5] = sigma * _limit(c, 0.0)
        return SLIP_UP if up else SLIP_DOWN
    if have[MASS_UP if up else MASS_DOWN] != 0:
        return MASS_UP if up else MASS_DOWN
    return STEPWISE


@njit(**_JIT)
def hybrid_steps(grid, knots, lo, hi, special, k0, kind, x, dt, limit, out_y, out_mode, out_sigma, out_native,
                 reals, ints, offsets, have, Yflex, Minv, Z, R, c, mats, guards, uses, dk, dp, dx, dy, lk, lp, lx, ly,
                 events, n_events):  # fmt: skip
    """The hybrid run over steps ``k0 .. N-1`` of a plan: each phase in the linear loop, each event step compiled.

    Step ``k`` goes from ``knots[k]`` to ``knots[k+1]`` [s] (the linear loop
    steps on ``grid``, the grid times those knots snap to), torque times
    clamped into ``[lo[k], hi[k]]``; ``special[k]`` 1: a partial step or one
    split at a breakpoint (left to the caller). The phase of kind ``kind`` with
    state ``x`` (6,) runs :func:`~belt_drive_ros.core.kernel.linear_steps` (its
    arrays ``reals[offsets[kind, 0]:offsets[kind, 1]]``, ``ints`` likewise)
    with its switching function as the guard (sticking after slip: the
    flexible loop, the load's angle shifted by ``-s / r_3``, :func:`_shift_angle`); the step in which the guard
    fires is redone by :func:`~.kernel_slip.event_step`, which returns the new mode, and
    the run goes on in that mode's phase. Sample ``k + 1`` is written to
    ``out_y[k]`` (5 states), ``out_mode``, ``out_sigma`` and the phase's own
    state to ``out_native[k]`` (NaN-padded). ``events`` (E, 8) from row
    ``n_events`` receives the events.

    Returns (next step, status, phase kind, sigma, events recorded so far):
    status 0 all done; :data:`DIVERGED` (sample ``next - 1`` is non-finite or
    too fast); :data:`NOT_CONVERGED` (step ``next``); :data:`SPECIAL` (step
    ``next`` is the caller's); :data:`EVENTS_FULL` (drain ``events``, call
    again); :data:`CHATTER` (step ``next``); :data:`NO_PHASE` (build phase
    ``kind``, call again). ``x`` holds the phase state at ``knots[next]``.
    """
    N = grid.size - 1
    k = k0
    # the arguments as views that own nothing (:func:`~.kernel.borrowed`): no atomic reference counts in the event steps
    Z, R, c, mats, guards, uses = borrowed(Z), borrowed(R), borrowed(c), borrowed(mats), borrowed(guards), borrowed(uses)
    dk, dp, dx, dy = borrowed(dk), borrowed(dp), borrowed(dx), borrowed(dy)
    lk, lp, lx, ly, events = borrowed(lk), borrowed(lp), borrowed(lx), borrowed(ly), borrowed(events)
    y = np.empty(5)
    y1 = np.empty(5)
    shifted = lp.copy()  # the load's numbers with its angle shifted by the slip (stick after slip)
    no_cuts = np.zeros(0)
    sd, sl = profile_scalars(dk, dp, dx, dy), profile_scalars(lk, lp, lx, ly)  # the profiles as scalars, once per call
    wf = np.zeros(EVENT_WORK)  # the event steps' work arrays, once per call
    wc = np.zeros(FLOW_WORK + LOCATE_WORK, dtype=np.complex128)
    xs6 = np.empty(6)  # a phase's start state for the linear loop
    buf = np.empty(N * 6 + 6)
    # ends[q]: the end of the stretch of steps from q with the same clamps and no special step (one pass, not a
    # scan to the end of the plan at every phase's start: O(N) per run instead of O(N) per event)
    ends = np.empty(max(N, 1), dtype=np.int64)
    if N > 0:
        ends[N - 1] = N
    for q in range(N - 2, -1, -1):
        ends[q] = ends[q + 1] if (not special[q + 1] and lo[q + 1] == lo[q] and hi[q + 1] == hi[q]) else q + 1
    sigma = 0.0
    if kind == SLIP_UP or kind == MASS_UP:
        sigma = 1.0
    elif kind == SLIP_DOWN or kind == MASS_DOWN:
        sigma = -1.0
    elif kind == STEPWISE:
        sigma = x[5]
    while k < N:
        if special[k]:
            return k, SPECIAL, kind, sigma, n_events
        if have[kind] != 2:
            return k, NO_PHASE, kind, sigma, n_events
        mode = STICK if kind <= STICKING else SLIP
        if events.shape[0] - n_events <= MAX_SWITCHES:
            return k, EVENTS_FULL, kind, sigma, n_events
        n = PHASE_SIZE[kind]
        if kind == STEPWISE:  # a belt with mass and c = 0 slipping: one event step per grid step
            g, given = k, np.int64(0)
            _to_y(kind, x, Yflex, y)
        else:
            j = ends[k]
            # sticking after slip: the flexible loop (4 states) from Minv y, the load's angle shifted by -s / r_3
            loop = FLEXIBLE if kind == STICKING else kind
            m = PHASE_SIZE[loop]
            r0, r1, i0, i1 = offsets[loop, 0], offsets[loop, 1], offsets[loop, 2], offsets[loop, 3]
            states = doubles_view(buf, 0, (j - k, m))  # (not reshape: numba's calls a C helper, ~0.25 us per phase)
            load = lp
            if kind == STICKING:
                xs = xs6[:4]
                _flexible(x, Minv, xs)
                load = _shift_angle(lk, lp, shifted, c, uses, x[4])
            else:
                xs = xs6[:n]
                xs[:] = x[:n]
            done, status, _ = linear_steps(grid[k : j + 1], xs, states, lo[k], hi[k], limit, reals[r0:r1], ints[i0:i1], dp, load)
            kept = done - 1 if status == GUARDED else done
            for q in range(kept):  # element by element: no array views or copies per step
                r = k + q
                out_mode[r], out_sigma[r] = mode, sigma
                if loop == FLEXIBLE:  # Yflex @ states[q], each row summed from the left (:func:`_to_y`)
                    for i in range(5):
                        total = 0.0
                        for jj in range(4):
                            total = total + Yflex[i, jj] * states[q, jj]
                        out_y[r, i] = total
                else:
                    for i in range(5):
                        out_y[r, i] = states[q, i]
                if kind == STICKING:
                    out_y[r, 4] = x[4]
                    for i in range(5):
                        out_native[r, i] = out_y[r, i]
                    out_native[r, 5] = math.nan
                else:
                    for i in range(6):
                        out_native[r, i] = states[q, i] if i < n else math.nan
            if status == DIVERGED or status == NOT_CONVERGED:
                return k + done, status, kind, sigma, n_events
            if status != GUARDED:
                if kind == STICKING:
                    x[:5] = out_y[k + done - 1]
                else:
                    x[:n] = states[done - 1]
                k = j
                continue
            g, given = k + kept, np.int64(1)  # the step in which the guard fired: redone with the event located
            if kind == STICKING:
                y[:] = x[:5] if kept == 0 else out_y[k + kept - 1]
                _to_y(FLEXIBLE, states[kept], Yflex, y1)
                y1[4] = x[4]
            else:
                _to_y(kind, x if kept == 0 else states[kept - 1], Yflex, y)
                _to_y(kind, states[kept], Yflex, y1)
        mode, sigma, got, st = _event_step(knots[g], knots[g + 1], no_cuts, y, mode, sigma, dt, hi[g], y1, given,
                                           Z, R, c, mats, guards, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly,
                                           events, n_events, wf, wc)  # fmt: skip
        n_events += got
        if st:
            return g, CHATTER, kind, sigma, n_events
        kind = _native(mode, sigma, y, x, Minv, c, have)
        if kind == STEPWISE:
            x[5] = sigma
        out_y[g] = y
        out_mode[g], out_sigma[g] = mode, sigma
        out_native[g] = math.nan
        out_native[g, : PHASE_SIZE[kind]] = x[: PHASE_SIZE[kind]]
        k = g + 1
        if not (abs(y[2]) <= limit and abs(y[3]) <= limit and y[0] - y[0] == 0.0 and y[1] - y[1] == 0.0
                and y[4] - y[4] == 0.0):  # fmt: skip
            return k, DIVERGED, kind, sigma, n_events
    return k, 0, kind, sigma, n_events
