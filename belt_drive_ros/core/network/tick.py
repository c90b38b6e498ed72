"""The network node's common tick in one compiled call: whole grid steps, then the joint values at their end.

A 1 kHz tick of a belt network (flexible or rigid tier) is one call of the
network loop (:func:`~belt_drive_ros.core.kernel.wheel_steps`)
and the JointState values at the new state: each pulley's (and the arm's)
angle, speed and torque. Done in Python that is a dozen interpreted calls
(grid times, buffers, the profiles' scalar evaluations, list building) whose
cost on the caches a 1 ms sleep leaves is most of the tick.
:func:`network_tick` does both in one ``@njit(cache=True, nogil=True)`` call.

Bit for bit the operations of the reference path
(:meth:`~belt_drive_ros.ros.network_stepper.NetworkStepper.advance`, then
``pulley_state`` and the layout's ``joint_values``):

* grid times ``k dt`` for ``k = k0 .. k0 + steps`` (numpy's int64 times float64);
* angles: flexible ``theta_i = x_i`` (driver, arm) or ``rho_i theta_d - l_i`` (a lag),
  speeds ``x_{m+i}``; rigid ``theta_i = x_0 rho_i``, ``omega_i = x_1 rho_i`` (the arm 0.0);
* torques at ``t = k1 dt``: a held value ``sign_i Q / g_i``, else the profile's
  ``sign Q(t, theta, omega)`` (gear 1) or ``sign Q(t, theta / g, omega / g) / g``
  (the angle 0.0 where the profile reads none);
* the arm's position ``(theta_a + theta_0) - theta_0``, its velocity ``omega_a``, its effort 0.0.

Only ticks of whole steps between the profiles' breakpoints come here; the rest
go through the stepper's ``advance`` as before.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..kernel import profile_torque_at, wheel_steps
from ..profile_data import OK

#: per state angle how its joint angle and speed are formed (``jkind``)
SAME, LAG, RIGID, ZERO = 0, 1, 2, 3


@njit(cache=True, nogil=True)
def network_tick(k0, steps, x, out, lo, hi, limit, W, kinds, offsets, S, F, final_base, tol, max_iter,
                 uses_angle, start, pk, pp, px, py, extra, guard, dt, driver, jkind, rho, theta0, arm,
                 held, value, tsign, gear, uses, row, qk, qp, y):  # fmt: skip
    """``steps`` grid steps from index ``k0`` (state ``x``) into ``out``, then the joint values into ``y``.

    ``W .. py, extra, guard``: the network loop's arguments of :func:`~belt_drive_ros.core.kernel.wheel_steps`
    (both profile banks the same stack, :class:`~.simulate.NetworkLoop`). ``jkind, rho`` (m,): per state angle
    :data:`SAME`/:data:`LAG`/:data:`RIGID`/:data:`ZERO` and its ratio; ``theta0`` the arm's installed angle,
    ``arm`` 1 with an arm. Per pulley (n,): ``held`` 1 when its torque is held at ``value`` [N m], ``tsign``
    its profile's sign (0: no profile), ``gear``, ``uses`` 1 when the profile reads its angle, ``row`` its
    first row in ``qk, qp`` (the scene's profiles, stacked as the loop's ``pk, pp`` before any hold) and
    ``px, py``. ``y`` (3 (n + arm)): positions, velocities, efforts. Returns the loop's
    ``(done, status, t)``; ``y`` is written only when every step is done (status OK).
    """
    times = np.empty(steps + 1)
    for i in range(steps + 1):
        times[i] = (k0 + i) * dt
    done, status, t = wheel_steps(times, x, out, lo, hi, limit, W, kinds, offsets, S, F, final_base, tol, max_iter,
                                  uses_angle, start, pk, pp, px, py, pk, pp, px, py, extra, guard)
    if status != OK:
        return done, status, t
    xs = out[steps - 1]
    m = jkind.size
    n = held.size
    j = n + arm
    for i in range(m):
        c = jkind[i]
        if c == SAME:
            a, w = xs[i], xs[m + i]
        elif c == LAG:
            a, w = rho[i] * xs[driver] - xs[i], xs[m + i]
        elif c == RIGID:
            a, w = xs[0] * rho[i], xs[1] * rho[i]
        else:
            a, w = 0.0, 0.0
        if i < n:
            y[i], y[j + i] = a, w
        else:  # the arm (as the run's arm_angle gives it)
            y[n], y[j + n] = (a + theta0) - theta0, w
    tk = float(k0 + steps) * dt
    for i in range(n):
        u = 0.0
        g = gear[i]
        if held[i]:
            u = tsign[i] * value[i] / g
        elif row[i] >= 0:
            a = y[i] if uses[i] else 0.0
            w = y[j + i]
            if g == 1.0:
                u = tsign[i] * profile_torque_at(qk, qp, px, py, row[i], tk, a, w)
            else:
                u = tsign[i] * profile_torque_at(qk, qp, px, py, row[i], tk, a / g, w / g) / g
        y[2 * j + i] = u
    if arm:
        y[2 * j + n] = 0.0
    return done, status, t


def warm() -> None:
    """Compile (or load from the disk cache) :func:`network_tick` with the one signature the node uses: one step
    of a two-pulley belt's flexible loop, its driver's torque held."""
    from .simulate import LIMIT, NetworkLoop, model_of, warm_scene

    loop = NetworkLoop(model_of(warm_scene()), "flexible", "etd2", 1e-3)
    x = loop.initial()
    ints = lambda values: np.array(values, dtype=np.int64)  # noqa: E731
    network_tick(0, 1, x, np.empty((1, x.size)), -np.inf, np.inf, LIMIT, *loop.args, loop.start, loop.pk, loop.pp,
                 loop.px, loop.py, *loop._none, 1e-3, 0, ints([SAME, LAG]), np.ones(2), 0.0, 0, ints([1, 0]),
                 np.array([0.1, 0.0]), np.array([1.0, -1.0]), np.ones(2), ints([0, 0]), ints(loop.start),
                 loop.pk.copy(), loop.pp.copy(), np.zeros(6))
