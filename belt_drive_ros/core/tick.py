"""The node's common tick in one compiled call: whole grid steps, then every output at their end.

A 1 kHz tick of the linear models is one step of the kernel
(:func:`~belt_drive_ros.core.kernel.linear_steps`) and the sixteen outputs
of :data:`~belt_drive_ros.core.model.OUTPUT_UNITS` at the new state. Done in
Python that is ~25 calls of numpy on tiny arrays and as many interpreted
functions, whose cost on the caches a 1 ms sleep leaves is most of the tick.
:func:`linear_tick` does both in one ``@njit(cache=True, nogil=True)`` call
writing into buffers :class:`TickKernel` allocates once per stepper.

Bit for bit the operations of the reference path (the stepper's
:meth:`~belt_drive_ros.core.stepper.Stepper.advance`, then
:meth:`~belt_drive_ros.core.model._LinearModel.outputs` of one sample):

* grid times ``origin + dt * k`` (the float product and sum of ``Stepper._grid``);
* the torques at the tick time from the profiles' data
  (:func:`~belt_drive_ros.core.kernel.profile_torque`), at the wheel
  coordinates ``W x`` summed over the nonzero entries of ``W`` from the left
  (as :class:`~belt_drive_ros.core.stepper.Plant`'s scalar ``inputs``);
* ``y_j = (x_0 C_j0 + ... + x_{n-1} C_j,n-1) + (u_0 D_j0 + u_1 D_j1)``
  (``model._affine_sample``), then ``drive_torque, load_torque = u``;
* span forces and flags: ``half = 0.5 |T_b| / r_3``, ``F_tight = F_0 + half``,
  ``F_slack = F_0 - half``, slack ``F_slack <= 0``, slip ``slack or F_tight >
  F_slack capstan_ratio`` (:func:`~belt_drive_ros.core.model.span_forces`),
  the flags as 0.0/1.0.

Only the tick the general path would take as plain whole steps comes here
(no breakpoint near, no held-torque jump, a kernel loop without extra
inputs); every other tick goes through the stepper as before.
"""

from __future__ import annotations

import math

import numpy as np

from numba import njit

from .kernel import HEADER, SECTIONS, linear_steps, profile_torque
from .model import LINEAR_OUTPUTS, OUTPUT_UNITS

#: :attr:`TickKernel.y` holds OUTPUT_UNITS in order: the linear outputs first, then these four
_AFTER = ("span_force_tight", "span_force_slack", "slack", "slip")
assert tuple(OUTPUT_UNITS) == LINEAR_OUTPUTS + _AFTER
_N_SECTIONS = len(SECTIONS)


@njit(cache=True, nogil=True)
def _coordinate(rows, q, n, x):
    """Wheel coordinate ``q`` of ``x``: the nonzero entries of row q of W, summed from the left (Plant.inputs)."""
    count, j1 = 0, 0
    for j in range(n):
        if rows[q * n + j] != 0.0:
            count += 1
            j1 = j
    if count == 1:
        c = rows[q * n + j1]
        return x[j1] if c == 1.0 else c * x[j1]
    total = 0.0
    for j in range(n):
        c = rows[q * n + j]
        if c != 0.0:
            total = total + c * x[j]
    return total


@njit(cache=True, nogil=True)
def linear_tick(k0, steps, x, out, reals, ints, dp, lp, rows, y):
    """``steps`` whole grid steps from grid index ``k0`` (state ``x``) into ``out``, then the outputs into ``y``.

    ``reals, ints, dp, lp``: the stepper's kernel loop
    (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`); ``rows`` packs
    ``[W (4 n), C (12 n), D (12 x 2), F_0, r_3, capstan_ratio, origin, dt, speed limit]``
    (:class:`TickKernel`). ``x`` may be a row of ``out`` (the kernel reads it
    before it writes). Returns ``(done, status, t)`` of the kernel; ``y`` is
    written only when every step is done (status OK).
    """
    n = x.size
    d0 = 16 * n
    origin, dt, limit = rows[d0 + 27], rows[d0 + 28], rows[d0 + 29]
    times = np.empty(steps + 1)
    for j in range(steps + 1):
        times[j] = origin + dt * float(k0 + j)
    done, status, t = linear_steps(times, x, out, -math.inf, math.inf, limit, reals, ints, dp, lp)
    if status != 0:
        return done, status, t
    xe = out[steps - 1]
    # the profiles' data inside the loop's arrays (the layout linear_steps unpacks)
    s = ints[1]
    at = ints[HEADER : HEADER + _N_SECTIONS + 1]
    k = HEADER + _N_SECTIONS + 1
    nd = dp.shape[0]
    dk, lk = ints[k + s : k + s + nd], ints[k + s + nd :]
    t1 = times[steps]
    angle_M = _coordinate(rows, 0, n, xe) if ints[7] else 0.0
    angle_3 = _coordinate(rows, 2, n, xe) if ints[8] else 0.0
    u0 = profile_torque(dk, dp, reals[at[7] : at[8]], reals[at[8] : at[9]], t1, angle_M, _coordinate(rows, 1, n, xe))
    u1 = profile_torque(lk, lp, reals[at[9] : at[10]], reals[at[10] : at[11]], t1, angle_3, _coordinate(rows, 3, n, xe))
    c0 = 4 * n
    for j in range(12):  # the LINEAR_OUTPUTS
        a = xe[0] * rows[c0 + j * n]
        for q in range(1, n):
            a = a + xe[q] * rows[c0 + j * n + q]
        y[j] = a + (u0 * rows[d0 + 2 * j] + u1 * rows[d0 + 2 * j + 1])
    y[8], y[9] = u0, u1  # drive_torque, load_torque: the inputs themselves
    F_0, r_3, capstan = rows[d0 + 24], rows[d0 + 25], rows[d0 + 26]
    half = 0.5 * abs(y[10]) / r_3  # belt_torque
    tight = F_0 + half
    slack_force = F_0 - half
    slack = slack_force <= 0.0
    y[12], y[13] = tight, slack_force
    y[14] = 1.0 if slack else 0.0
    y[15] = 1.0 if slack or tight > slack_force * capstan else 0.0
    return done, status, t


class TickKernel:
    """One stepper's tick as one compiled call: :meth:`step` advances its buffers, :attr:`y` holds the outputs.

    ``TickKernel.of(stepper)`` is None where the tick cannot be compiled
    (an adaptive method, a Python-only profile, extra inputs: the general
    path serves those ticks).
    """

    def __init__(self, stepper, limit: float):
        plant, loop = stepper.plant, stepper.loop
        model = plant.model
        n = model.A.shape[0]
        C, D = model.output_matrices()
        p = model.params
        self.rows = np.concatenate([np.ravel(plant.wheel_map), np.ravel(C), np.ravel(D),
                                    [p.F_0, p.r_3, p.capstan_ratio, stepper.origin, stepper.dt, limit]]).astype(np.float64)
        #: the outputs of the last :meth:`step` [SI units, OUTPUT_UNITS order; slack/slip as 0.0/1.0]
        self.y = np.zeros(len(OUTPUT_UNITS))
        self.n, self.dt = n, stepper.dt
        step_ns = round(self.dt * 1e9)
        #: the grid step in whole nanoseconds when dt is one (a node time on ``origin_ns + k step_ns`` is the
        #: grid time ``origin + k dt``, which scene times snap to), else 0
        self.step_ns = step_ns if step_ns > 0 and step_ns / 1e9 == self.dt and stepper.origin == 0.0 else 0
        self._out = np.empty((1, n))
        self._args = (loop.reals, loop.ints, loop._dp, loop._lp, self.rows, self.y)

    @classmethod
    def of(cls, stepper, limit: float):
        """The tick kernel of ``stepper`` (divergence beyond ``limit`` [rad/s]), or None where it cannot run."""
        loop = getattr(stepper, "loop", None)
        if loop is None or stepper.plant.extra or stepper.guard is not None or not hasattr(stepper.plant.model, "C"):
            return None
        return cls(stepper, limit)

    def step(self, x: np.ndarray, k0: int, k1: int):
        """Whole grid steps k0 -> k1 from state ``x``: ``(states (k1 - k0, n), status)``; :attr:`y` at k1 when OK.

        The states are written into a buffer kept for the next call (the
        last row is the next call's ``x``): a caller keeps them by copying.
        """
        out = self._out
        if out.shape[0] != k1 - k0:
            out = self._out = np.empty((k1 - k0, self.n))
        return out, linear_tick(k0, k1 - k0, x, out, *self._args)[1]
