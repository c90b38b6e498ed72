"""The network node's common tick in one compiled call (:func:`network_tick`, ``@njit(cache=True, nogil=True)``):
the network loop's whole grid steps (:func:`~belt_drive_ros.core.kernel.wheel_steps`), each pulley's (and the arm's)
angle, speed and torque at the new state, and the tick's ``joint_states`` CDR bytes. Its arrays are packed once
into one buffer (:class:`~belt_drive_ros.core.tick.PackedArrays`: ``reals`` and ``ints``, its int64 view), cut into
views again in the kernel (``wheel_steps`` keeps its one signature); the caller writes held torques into them.
Why a tick is one call, what it replaced and its figures: ``docs/performance.md``, "The network node's tick".

Bit for bit the operations of the reference path
(:meth:`~belt_drive_ros.ros.network_stepper.NetworkStepper.advance`, then
``pulley_state`` and the layout's ``joint_values``):

* grid times ``k dt`` for ``k = k0 .. k0 + steps`` (numpy's int64 times float64);
* angles: flexible ``theta_i = x_i`` (driver, arm) or ``rho_i theta_d - l_i`` (a lag),
  speeds ``x_{m+i}``; rigid ``theta_i = x_0 rho_i``, ``omega_i = x_1 rho_i`` (the arm 0.0);
* torques at ``t = k1 dt``: a held value ``sign_i Q / g_i``, else the profile's
  ``sign Q(t, theta, omega)`` (gear 1) or ``sign Q(t, theta / g, omega / g) / g``
  (the angle 0.0 where the profile reads none);
* the arm's position ``(theta_a + theta_0) - theta_0``, its velocity ``omega_a``, its effort 0.0; on the rigid
  tier ``theta_a`` is its quasi-static swing (:func:`~.model.arm_swing` of the new state and the torques) and
  ``omega_a`` 0.0.

Only ticks of whole steps between the profiles' breakpoints come here; the rest
go through the stepper's ``advance`` as before.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..kernel import wheel_steps
from ..kernel_profiles import profile_torque_at
from ..profile_data import OK
from ..tick import PackedArrays, _f1, _f2, _f3, _i1

#: per state angle how its joint angle and speed are formed (``jkind``; STATIC: the rigid tier's arm, its swing
#: from the state and torques by the ``armc`` row, :meth:`~.model.NetworkModel.rigid_arm_row`)
SAME, LAG, RIGID, ZERO, STATIC = 0, 1, 2, 3, 4
#: the float sections of the packed buffer ``reals``, in order (fscalars: dt, theta0, speed limit, tol)
FLOATS = ("W", "offsets", "S", "F", "pp", "px", "py", "extra", "guard", "rho", "value", "tsign", "gear", "qp", "y",
          "armc", "fscalars")
#: the int sections in ``ints`` (iscalars: final_base, max_iter, driver, arm, then the message's layout: the float64
#: index of its positions, velocities, efforts and the uint32 index of its stamp; -1: no message)
INTS = ("kinds", "uses_angle", "start", "pk", "jkind", "held", "uses", "row", "qk", "iscalars")
_W, _OFFSETS, _S, _F, _PP, _PX, _PY, _EXTRA, _GUARD, _RHO, _VALUE, _TSIGN, _GEAR, _QP, _Y, _ARMC, _FSCALARS = range(17)
_KINDS, _USES_ANGLE, _START, _PK, _JKIND, _HELD, _USES, _ROW, _QK, _ISCALARS = range(17, 27)


@njit(cache=True, nogil=True)
def network_tick(k0, steps, x, out, lo, hi, reals, ints, msg, stamp):
    """``steps`` grid steps from index ``k0`` (state ``x``) into ``out``, then the joint values into the ``y``
    section of ``reals`` and, when ``ints`` gives its layout, the ``joint_states`` message stamped ``stamp`` [ns]
    into ``msg`` (uint8, 8-byte aligned: :func:`~belt_drive_ros.core.tick.joints_message`).

    ``reals``, ``ints``: the packed buffer, its int64 view (:data:`FLOATS`, :data:`INTS`). ``W .. guard, kinds .. pk``:
    the network loop's arguments of :func:`~belt_drive_ros.core.kernel.wheel_steps` (both profile banks the same stack,
    :class:`~.simulate.NetworkLoop`). ``jkind, rho`` (m,): per state angle :data:`SAME`/:data:`LAG`/:data:`RIGID`/
    :data:`ZERO`/:data:`STATIC` and its ratio; ``theta0`` the arm's installed angle, ``arm`` 1 with an arm,
    ``armc`` (n + 2) the rigid tier arm's row (:meth:`~.model.NetworkModel.rigid_arm_row`). Per pulley (n,):
    ``held`` 1 when its torque is held at ``value`` [N m], ``tsign`` its profile's sign (0: no profile), ``gear``,
    ``uses`` 1 when the profile reads its angle, ``row`` its first row in ``qk, qp`` (the scene's profiles,
    stacked as the loop's ``pk, pp`` before any hold) and ``px, py``. ``y`` (3 (n + arm)): positions, velocities,
    efforts. Returns the loop's ``(done, status, t)``; ``y`` and ``msg`` are written only when every step is done
    (status OK).
    """
    fs, js = _f1(reals, ints, _FSCALARS), _i1(ints, _ISCALARS)
    dt, theta0, limit, tol = fs[0], fs[1], fs[2], fs[3]
    final_base, max_iter, driver, arm = js[0], js[1], js[2], js[3]
    pk, pp, px, py = _i1(ints, _PK), _f2(reals, ints, _PP), _f1(reals, ints, _PX), _f1(reals, ints, _PY)
    times = np.empty(steps + 1)
    for i in range(steps + 1):
        times[i] = (k0 + i) * dt
    done, status, t = wheel_steps(times, x, out, lo, hi, limit, _f3(reals, ints, _W), _i1(ints, _KINDS),
                                  _f1(reals, ints, _OFFSETS), _f3(reals, ints, _S), _f3(reals, ints, _F), final_base,
                                  tol, max_iter, _i1(ints, _USES_ANGLE), _i1(ints, _START), pk, pp, px, py, pk, pp,
                                  px, py, _f2(reals, ints, _EXTRA), _f1(reals, ints, _GUARD))  # fmt: skip
    if status != OK:
        return done, status, t
    jkind, rho, y = _i1(ints, _JKIND), _f1(reals, ints, _RHO), _f1(reals, ints, _Y)
    held, value, tsign, gear = _i1(ints, _HELD), _f1(reals, ints, _VALUE), _f1(reals, ints, _TSIGN), _f1(reals, ints, _GEAR)
    uses, row, qk, qp = _i1(ints, _USES), _i1(ints, _ROW), _i1(ints, _QK), _f2(reals, ints, _QP)
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
        if jkind[m - 1] == STATIC:  # the rigid tier's arm: its swing from the state and the torques, from the left
            c = _f1(reals, ints, _ARMC)
            a = 0.0 + c[0] * xs[0]
            a = a + c[1] * xs[1]
            for i in range(n):
                a = a + c[2 + i] * y[2 * j + i]
            y[n] = (a + theta0) - theta0
    if js[7] >= 0:  # the joint_states message: its three arrays of j doubles and its stamp
        f, words = msg.view(np.float64), msg.view(np.uint32)
        for q in range(3):
            base = js[4 + q]
            for i in range(j):
                f[base + i] = y[q * j + i]
        words[js[7]] = stamp // 1000000000
        words[js[7] + 1] = stamp % 1000000000
    return done, status, t


def warm() -> None:
    """Compile (or load from the disk cache) :func:`network_tick` with the one signature the node uses: one step
    of a two-pulley belt's flexible loop, its driver's torque held."""
    from .simulate import LIMIT, NetworkLoop, model_of, warm_scene

    loop = NetworkLoop(model_of(warm_scene()), "flexible", "etd2", 1e-3)
    x = loop.initial()
    W, kinds, offsets, S, F, final_base, tol, max_iter, uses_angle = loop.args
    extra, guard = loop._none
    packed = PackedArrays(
        (FLOATS, INTS),
        dict(W=W, offsets=offsets, S=S, F=F, pp=loop.pp, px=loop.px, py=loop.py, extra=extra, guard=guard,
             rho=np.ones(2), value=np.array([0.1, 0.0]), tsign=np.array([1.0, -1.0]), gear=np.ones(2), qp=loop.pp,
             y=np.zeros(6), armc=np.zeros(4), fscalars=np.array([1e-3, 0.0, LIMIT, tol])),
        dict(kinds=kinds, uses_angle=uses_angle, start=loop.start, pk=loop.pk, jkind=np.array([SAME, LAG]),
             held=np.array([1, 0]), uses=np.zeros(2), row=loop.start, qk=loop.pk,
             iscalars=np.array([final_base, max_iter, 0, 0, -1, -1, -1, -1])))
    network_tick(0, 1, x, np.empty((1, x.size)), -np.inf, np.inf, packed.reals, packed.ints, np.zeros(8, dtype=np.uint8),
                 0)
