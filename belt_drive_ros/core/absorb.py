"""Steps next to torque breakpoints on the grid, absorbed into runs of whole steps (a recording at the step rate).

A torque sampled at the step rate (``--torque-bag``, a node recording re-simulated) puts a breakpoint on
every knot; planned alone, each such step is one clamped kernel call (~15 us of Python per step).
:func:`absorbed_steps` finds those one call of :func:`end_loop` can take instead with the same stage
torques, so the same states, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np


#: how far [s] before the step's end a stage at the step's end reads the torques in an absorbed step
#: (at most a thousandth of the step): a recording's hold switches at whole nanoseconds
END_SHIFT = 1e-9
_NO_CELLS = np.empty(0, dtype=np.int64)


def left_of_array(profile, b: np.ndarray) -> np.ndarray:
    """``profile.left_of`` of each time of ``b`` [s]: its ``left_of_array`` if it has one, the default's
    float below as an array, a schedule's from its parts', else one call per time."""
    from .sources import Schedule, TorqueProfile

    own = getattr(profile, "left_of_array", None)
    if own is not None:
        return np.asarray(own(b), dtype=np.float64)
    if type(profile).left_of is TorqueProfile.left_of:
        return np.nextafter(b, -np.inf)
    if type(profile) is Schedule:  # Schedule.left_of: the least of the float below and both parts' (min of equal floats)
        below = np.nextafter(b, -np.inf)
        return np.minimum(np.minimum(below, left_of_array(profile.active, b)), left_of_array(profile.inactive, b))
    return np.array([profile.left_of(v) for v in b.tolist()], dtype=np.float64)


def time_free(data, t_min: float) -> bool:
    """Whether a profile's kernel data read no time from ``t_min`` [s] on: constants, polynomials in
    speed, and engine/motor/compressor rows whose fade is over (or absent)."""
    from . import profile_data as D

    fade = {D.CONSTANT: None, D.POLYNOMIAL: None, D.ENGINE: 8, D.MOTOR_LINE: 2, D.MOTOR_CURVE: 2, D.COMPRESSOR: 4}
    for kind, row in zip(data.kinds.tolist(), data.params.tolist()):
        if kind not in fade or (fade[kind] is not None and row[fade[kind]] > 0.0 and not t_min >= row[fade[kind]]):
            return False
    return True


def offset_slice(loop) -> slice:
    """Where a kernel loop's packed ``reals`` hold the stage time offsets ``c_i h`` [s] (kernel.SECTIONS)."""
    from .kernel import HEADER

    return slice(int(loop.ints[HEADER + 1]), int(loop.ints[HEADER + 2]))


def offsets(loop) -> np.ndarray:
    """The stage time offsets ``c_i h`` [s] a kernel loop adds to a step's start."""
    return loop.reals[offset_slice(loop)]


class EndLoop:
    """The stepper's kernel loop with other stage time offsets, written into its packed numbers for the
    call and put back after (the loop's arrays, a recording's table among them, are not copied)."""

    def __init__(self, loop, offsets: np.ndarray):
        self.loop, self.offsets = loop, offsets
        self.reals = loop.reals[: loop.reals.size - loop.tables.size].copy()  # for offsets() (the section is in front)
        self.reals[offset_slice(loop)] = offsets
        self.ints = loop.ints

    def __call__(self, times, x, out, lo=-math.inf, hi=math.inf, limit=1.0e5):
        where = offset_slice(self.loop)
        plain = self.loop.reals[where].copy()
        self.loop.reals[where] = self.offsets
        try:
            return self.loop(times, x, out, lo, hi, limit)
        finally:
            self.loop.reals[where] = plain


def absorbed_steps(stepper, bps: np.ndarray, first: int, last: int) -> tuple[np.ndarray, np.ndarray]:
    """``(absorbed cells (sorted int64), mask of the sorted breakpoints ``bps`` whose both cells are absorbed)``.

    Step ``j`` (cells ``first + 1 .. last - 1``) is absorbed when every breakpoint touching it lies on its
    knots and each torque gives, at every stage time of :func:`end_loop`, the same float as at the stage time
    clamped into ``[lo_j, hi_j]`` (what the step planned alone reads): a time-only torque is evaluated at both,
    any other must read no time there (:func:`time_free`).
    """
    origin, dt = stepper.origin, stepper.dt
    plant = stepper.plant
    if any((p.state_dependent or angle) and not time_free(data, origin + last * dt)
           for p, data, angle in zip((plant.drive, plant.load), plant.data, plant.uses_angle)):
        return _NO_CELLS, None  # a torque reading the state and the time to the end: no step (as _same_torques finds)
    end = end_loop(stepper)
    kf = np.rint((bps - origin) / dt)
    d = np.abs(origin + kf * dt - bps)
    on = (d <= stepper.grid_tolerance * dt) | (d <= 8.0 * np.spacing(np.abs(bps)))
    k = kf.astype(np.int64)
    cand = on & (k >= first + 2) & (k <= last - 1)
    if not cand.any():
        return _NO_CELLS, None
    # marks over the cells first .. last (k sorted: no sorting here)
    size = last - first + 1
    touched = np.zeros(size + 1, dtype=bool)
    kc, bc = k[cand], bps[cand]
    touched[kc - first] = touched[kc - 1 - first] = True
    # cells any other breakpoint touches are planned as before: off the grid (split), near the ends
    blocked = np.zeros(size + 2, dtype=bool)
    cell = np.clip(np.floor((bps[~on] - origin) / dt).astype(np.int64) - first, -1, size)
    blocked[cell] = blocked[cell + 1] = blocked[np.maximum(cell - 1, -1)] = True
    other = np.clip(k[on & ~cand] - first, 0, size)
    blocked[other] = blocked[np.maximum(other - 1, 0)] = True
    first_of = np.ones(kc.size, dtype=bool)
    first_of[1:] = kc[1:] != kc[:-1]
    at = np.flatnonzero(first_of)
    knots = kc[at]
    lo_k = np.maximum.reduceat(bc, at)  # the step starting at a knot samples from its latest breakpoint
    hi_k = np.minimum.reduceat(stepper.plant.left_of_array(bc), at)  # the step ending there, before the first
    lo = np.full(size + 1, -math.inf)
    hi = np.full(size + 1, math.inf)
    lo[knots - first], hi[knots - 1 - first] = lo_k, hi_k
    index = np.flatnonzero(touched[:size] & ~blocked[:size])
    ok = _same_torques(stepper, origin + dt * (index + first).astype(np.float64), lo[index], hi[index], end)
    good = np.zeros(size + 1, dtype=bool)
    good[index[ok]] = True
    return index[ok] + first, cand & good[np.clip(k - first, 0, size)] & good[np.clip(k - 1 - first, 0, size)]

def _same_torques(stepper, g: np.ndarray, lo: np.ndarray, hi: np.ndarray, end) -> np.ndarray:
    """Per step starting at ``g`` [s]: whether the torques at the stage times of ``end`` equal those at the
    stage times of the stepper's loop clamped into ``[lo, hi]`` (see :func:`absorbed_steps`)."""
    from .kernel_profiles import profile_torque_array

    ok = np.ones(g.size, dtype=bool)
    plain, shifted = offsets(stepper.loop), offsets(end)
    zeros, a, b = np.zeros(g.size), np.empty(g.size), np.empty(g.size)
    for profile, data, angle in zip((stepper.plant.drive, stepper.plant.load), stepper.plant.data, stepper.plant.uses_angle):
        if profile.state_dependent or angle:
            if not time_free(data, float(g[0]) if g.size else 0.0):
                return np.zeros(g.size, dtype=bool)
            continue
        for c, e in zip(plain.tolist(), shifted.tolist()):
            t = g if c == 0.0 else g + c
            t = np.where(t < lo, lo, np.where(t > hi, hi, t))  # the kernel's clamp
            u = g if e == 0.0 else g + e
            moved = np.flatnonzero(t != u)  # the same time gives the same torque: only the others are read
            if moved.size:
                n = moved.size
                profile_torque_array(data.kinds, data.params, data.tx, data.ty, t[moved], zeros[:n], zeros[:n], a[:n])
                profile_torque_array(data.kinds, data.params, data.tx, data.ty, u[moved], zeros[:n], zeros[:n], b[:n])
                ok[moved[a[:n] != b[:n]]] = False
    return ok

def end_loop(stepper):
    """The kernel loop of absorbed steps: the stepper's, a stage at the step's end (node 1) reading the
    torques :data:`END_SHIFT` (at most dt/1000) before it (:class:`EndLoop`)."""
    if stepper._end is None:
        nodes = stepper.integrator.scheme.nodes
        if 1.0 not in nodes:
            stepper._end = stepper.loop
        else:
            shift = min(END_SHIFT, 1e-3 * stepper.dt)
            moved = [1.0 - shift / stepper.dt if c == 1.0 else c for c in nodes]
            # KernelLoop's offsets c h of these nodes
            stepper._end = EndLoop(stepper.loop, np.array([float(c * stepper.dt) if c else 0.0 for c in moved]))
    return stepper._end
