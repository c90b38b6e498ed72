"""The compiled step of the slipping belt across its stick/slip events (numba, ``@njit(cache=True, nogil=True)``).

A grid step of the hybrid model in which a switching function turns
positive is redone here: the event is located by root finding on the
step's continuous extension (the mode's exact flow with the torques linear
in time between their values at the step's ends; held for ``exact``), the
flow is taken to it, the mode switched, and the rest of the step is taken
in the new mode -- as often as events occur in one step (at most 64).
Partial steps of any length are taken on the modal flow, in closed form:

In both modes the state ``y = [phi_M, theta_e, omega_M, omega_3, s]``
splits into ``z = [theta_e, omega_M, omega_3]`` (``z' = A_z z + B_z u``) and
the two integrated coordinates. With ``A_z = V diag(lambda) V^-1`` and an
input ``u_0 + d_1 s + d_2 s^2``, the modal coordinates ``zeta = V^-1 z``
follow::

    zeta_i(tau) = e^(l tau) w_i + tau phi_1 b0_i + tau^2 phi_2 b1_i + 2 tau^3 phi_3 b2_i
    int_0^tau zeta_i = tau phi_1 w_i + tau^2 phi_2 b0_i + tau^3 phi_3 b1_i + 2 tau^4 phi_4 b2_i

(``l = lambda_i``, ``phi_k`` of ``l tau``, ``w = V^-1 z(0)``, ``b_k = V^-1 B_z d_k``,
``phi_k(x) = sum_j x^j / (j + k)!``); the integrated coordinates add
``Re(C V int zeta) + B_{0,4} (tau u_0 + tau^2 d_1 / 2 + tau^3 d_2 / 3)``.
That is the ``exact`` step (held input), the ``etd2`` step (input ramping to
its value at the predicted end) and the ``etd4`` step (Cox-Matthews ETDRK4:
half-step held-input stages, then the quadratic input through them) of any
length; the other fixed-step methods take their partial steps as ``etd4``
(fourth order, exact in the linear part).

Every function is valid Python: ``NUMBA_DISABLE_JIT=1`` runs them with the same floats.

The hybrid run over a step plan that calls this event step (each phase in the linear loop, the step in which its
guard fires redone here) is :mod:`~belt_drive_ros.core.kernel_hybrid`.

Data (built once per model by :func:`pack`):

* ``Z`` (2, 3, 12) complex: per mode (0 stick, 1 slip) and carried eigenvalue
  ``[lambda, V column (3), V^-1 row (3), P = V^-1 B_z row (3), C column (2)]``;
* ``R`` (2, 11) float: ``[weight (3), B rows 0 and 4 (2 x 3), max frequency, modes carried]``;
* ``c`` (:data:`CONSTS`) float: the model's constants; ``mats`` (5, 7): ``[A_stick | B_stick]``;
* ``guards`` (3, 15): stick, slip sigma = +1, slip sigma = -1 as ``[bound, absolute, quad, row (5), speed (5), has_speed, 0]``.
"""

from __future__ import annotations

import cmath
import math

import numpy as np
from numba import njit

from .kernel import borrowed
from .kernel_profiles import NO_ANCHOR, profile_scalars, profile_torque, scalar_at_call

_JIT = dict(cache=True, nogil=True)
#: the event step's small helpers (inputs, modal state, guard, switching, projection) are inlined into their callers:
#: called out of line, each call counted the references of every array it was passed (a dozen per event step)
_INLINE = dict(cache=True, nogil=True, inline="always")
# Inlined, a helper's array arguments are new variables, each counted up and down on every call (an atomic pair
# each; numba prunes the pairs only within one basic block, and most helpers branch or loop): the modal state's eight
# arrays cost ~110 ns a call against ~8 for its arithmetic. So :func:`_event_step` (and :func:`locate_event`,
# :func:`~.kernel_hybrid.hybrid_steps`) rebinds each array it is given to :func:`~.kernel.borrowed`, a view at the
# same address that owns nothing (numba.carray: no meminfo), and everything below it (:func:`_flow`, :func:`_locate`,
# :func:`_stick_keeps` and the inlined helpers) receives those views and their slices: each count is then a call of
# numba's (not inlined) that finds no meminfo and returns, no atomic operation (about three quarters of what compiling
# these functions without NRT saved). The arrays' owners (the callers' arguments) keep them alive for the call

#: Taylor coefficients 1/(j+3)! and 1/(j+4)! (phi_3, phi_4 below |x| = 0.5, to below 1e-17 relative)
_PHI3 = tuple(1.0 / math.factorial(j + 3) for j in range(15))
_PHI4 = tuple(1.0 / math.factorial(j + 4) for j in range(15))
#: names of the entries of ``c``
CONSTS = ("ratio", "r_3", "F_0", "belt_mass", "r", "capstan", "q1", "q2", "q3", "rel2", "rel3", "k", "c",
          "two_k_r3", "dlim", "project", "method")  # fmt: skip
#: method codes of the modal flow (``c[16]``)
EXACT, ETD2, ETD4 = 0, 1, 2
STICK, SLIP = 0, 1
#: at most this many mode switches in one step (chattering otherwise)
MAX_SWITCHES = 64
#: work array sizes (floats, and as many complex): :func:`_flow`'s, :func:`_locate`'s, and :func:`_event_step`'s (its
#: own input and end state, a flow's, a location's, :func:`_stick_keeps`' 13); allocated once per run, not per call
FLOW_WORK, LOCATE_WORK = 36, 24
EVENT_WORK = 8 + FLOW_WORK + LOCATE_WORK + 13
#: a profile left to the dispatcher, typed as :func:`~.kernel_profiles.profile_scalars` answers one that does not fit:
#: ``sd``, ``sl`` for a call of the kernels from Python that has no profile read into scalars (each torque through
#: :func:`~.kernel_profiles.profile_torque`, the same floats)
DISPATCHED = (False, 0, (0.0,) * 9, (0.0,) * 3, (0.0,) * 8, 0, (0.0,) * 9, (0.0,) * 3, (0.0,) * 8, (0.0,) * 4)


@njit(**_INLINE)
def _phi_series(x):
    """(e^x, phi_1(x), ..., phi_4(x)) by their Taylor series (``|x| < 0.5``), of a float or a complex ``x``."""
    p4 = 0.0 * x
    p3 = 0.0 * x
    for j in range(14, -1, -1):
        p4 = p4 * x + _PHI4[j]
        p3 = p3 * x + _PHI3[j]
    p2 = 0.5 + x * p3
    p1 = 1.0 + x * p2
    return 1.0 + x * p1, p1, p2, p3, p4


@njit(**_INLINE)
def _phi_closed(e, r):
    """(e^x, phi_1(x), ..., phi_4(x)) in closed form from ``e = e^x`` and ``r = 1/x`` (floats or complex):
    ``phi_{k+1} = (phi_k - 1/k!) / x``."""
    p1 = (e - 1.0) * r
    p2 = (p1 - 1.0) * r
    p3 = (p2 - 0.5) * r
    return e, p1, p2, p3, (p3 - 1.0 / 6.0) * r


@njit(**_INLINE)
def _phis4(x):
    """(e^x, phi_1(x), ..., phi_4(x)) of a complex x: Taylor series below |x| = 0.5, closed forms above.

    A real ``x`` (a real eigenvalue times a step: every slip-mode eigenvalue, one of the stick mode's) is computed
    in real arithmetic: the same floats as the complex path (each imaginary part there is an exact zero, so each
    real part is the same product or sum; ``exp(v + 0j)`` is ``exp(v) cos 0``), at ~19 ns against ~44 (no ``hypot``
    for ``|x|``, one product per term instead of a complex one)."""
    if x.imag == 0.0:
        v = x.real
        # 1/x as below: v / (v v + 0 0), the complex path's reciprocal of a real x
        e, p1, p2, p3, p4 = _phi_series(v) if abs(v) < 0.5 else _phi_closed(math.exp(v), v / (v * v + 0.0))
        return complex(e, 0.0), complex(p1, 0.0), complex(p2, 0.0), complex(p3, 0.0), complex(p4, 0.0)
    if abs(x) < 0.5:
        return _phi_series(x)
    # 1/x by real arithmetic: numba's complex division and numpy's differ in the last bit
    # (NUMBA_DISABLE_JIT=1 must give the compiled floats), and one reciprocal is 4 divisions fewer
    d = x.real * x.real + x.imag * x.imag
    return _phi_closed(cmath.exp(x), complex(x.real / d, -x.imag / d))


@njit(**_INLINE)
def _limit(c, omega):
    """Q_max at drive speed ``omega``: ``max((F_0 - m' v^2) k_c, 0)``, ``v = r omega`` [N]."""
    v = c[4] * omega
    return max((c[2] - c[3] * v * v) * c[5], 0.0)


@njit(**_JIT)
def _scalar_torques(sd, sl, tc, drive_angle, drive_speed, load_angle, load_speed):
    """(drive, load) torques [N m] at ``tc`` [s] of the profiles read into scalars ``sd``, ``sl``
    (:func:`~.kernel_profiles.scalar_at_call`, no anchor: their harmonics' sines called). Called, not inlined: one
    compiled copy for the event step's eight input sites (inlined at each, compiling the event step took over 15
    minutes), and ``scalar_at`` compiled once for it and the general loop (inlined here, 44 s of compilation)."""
    drive, _ = scalar_at_call(sd, tc, drive_angle, drive_speed, NO_ANCHOR)
    load, _ = scalar_at_call(sl, tc, load_angle, load_speed, NO_ANCHOR)
    return drive, load


@njit(**_INLINE)
def _inputs(mode, sigma, t, y, hi, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, u):
    """u = [drive, load(, sigma Q_max)] at ``t`` (clipped at ``hi``) and state ``y`` into ``u``: where both profiles
    fit in scalars (``sd``, ``sl``: :func:`~.kernel_profiles.profile_scalars`, read once per run) from those
    (:func:`_scalar_torques`: the dispatcher's operations, the same floats; ~80 ns against ~95), else each through
    the dispatcher (:func:`~.kernel_profiles.profile_torque`)."""
    tc = t if t < hi else hi
    drive_angle = y[0] if uses[0] else 0.0
    phi3 = c[0] * y[0] - y[1] - y[4] / c[1]
    load_angle = phi3 if uses[1] else 0.0
    if sd[0] and sl[0]:
        u[0], u[1] = _scalar_torques(sd, sl, tc, drive_angle, y[2], load_angle, y[3])
    else:
        u[0] = profile_torque(dk, dp, dx, dy, tc, drive_angle, y[2])
        u[1] = profile_torque(lk, lp, lx, ly, tc, load_angle, y[3])
    u[2] = sigma * _limit(c, y[2]) if mode == SLIP else 0.0


@njit(**_INLINE)
def _modal(Z, M, y, w):
    """Modal coordinates ``w = V^-1 z`` of state ``y`` in mode ``M``."""
    for k in range(3):
        w[k] = Z[M, k, 4] * y[1] + Z[M, k, 5] * y[2] + Z[M, k, 6] * y[3]


@njit(**_INLINE)
def _pdot(p0, p1, p2, u, m):
    """``P_k . u`` over the mode's ``m`` inputs, ``P_k = (p0, p1, p2)`` (complex, or their real parts)."""
    total = p0 * u[0] + p1 * u[1]
    if m == 3:
        total = total + p2 * u[2]
    return total


@njit(**_INLINE)
def _phis(Z, R, M, tau, ph):
    """``ph[k] = (e^x, phi_1(x), ..., phi_4(x))``, ``x = lambda_k tau``, for mode ``M``'s carried eigenvalues."""
    for k in range(int(R[M, 10])):
        ph[k, 0], ph[k, 1], ph[k, 2], ph[k, 3], ph[k, 4] = _phis4(Z[M, k, 0] * tau)


@njit(**_INLINE)
def _carried(v1, v2, v3, c0, c4, p0, p1_, p2_, e, p1, p2, p3, p4, w, weight, m, u0, d1, d2, order, tau, t2, t3):
    """One carried eigenvalue's share of :func:`_state`'s sums ``(z_0, z_1, z_2, phi_M, s)``: ``Re(V_j zeta)``,
    ``Re(C_j int zeta)`` of its modal coordinate (``V`` column ``v1 .. v3``, ``C`` column ``c0, c4``, ``P`` row
    ``p0, p1_, p2_``, the phis ``e .. p4`` at ``tau``, ``w``: its coordinate at 0, ``weight``: 2 for a pair).

    Complex, or (a real eigenvalue) the real parts alone: the same floats. Its ``V`` and ``C`` columns and its phis
    are real (LAPACK's eigenvector of a real eigenvalue, :func:`_phis4`'s real path), so in every complex product
    an imaginary part meets an exact zero and each real part is the real product or sum (``a r - b 0 = a r``); the
    imaginary parts ``V^-1`` and ``P`` carry from rounding never reach a real part. Each product in the same order.
    ~2x fewer operations: the slip mode's eigenvalues are all real, one of the stick mode's."""
    b0 = _pdot(p0, p1_, p2_, u0, m)
    zeta = e * w + tau * p1 * b0
    integral = tau * p1 * w + t2 * p2 * b0
    if order > 0:
        b1 = _pdot(p0, p1_, p2_, d1, m)
        zeta = zeta + t2 * p2 * b1
        integral = integral + t3 * p3 * b1
        if order > 1:
            b2 = _pdot(p0, p1_, p2_, d2, m)
            zeta = zeta + 2.0 * t3 * p3 * b2
            integral = integral + 2.0 * t2 * t2 * p4 * b2
    zeta = weight * zeta
    integral = weight * integral
    return (v1 * zeta).real, (v2 * zeta).real, (v3 * zeta).real, (c0 * integral).real, (c4 * integral).real


@njit(**_INLINE)
def _state(Z, R, M, m, y0, y4, w, u0, d1, d2, order, tau, ph, out):
    """The state at ``tau`` [s] from (phi_M = ``y0``, modal ``w``, s = ``y4``) with input ``u0 + d1 s + d2 s^2`` into ``out``
    (``ph``: :func:`_phis` at ``tau``). ``order`` 0: ``d1 = d2 = 0`` (held), 1: ``d2 = 0``, 2: both: the zero terms
    are left out of the sums, each the last of its sum (the same floats: x + 0 = x; ``d1``, ``d2`` then not read)."""
    t2 = tau * tau
    t3 = t2 * tau
    z0 = z1 = z2 = i0 = i4 = 0.0
    for k in range(int(R[M, 10])):
        if Z[M, k, 0].imag == 0.0:  # a real eigenvalue: real arithmetic, the same floats (:func:`_carried`)
            a0, a1, a2, a3, a4 = _carried(Z[M, k, 1].real, Z[M, k, 2].real, Z[M, k, 3].real, Z[M, k, 10].real,
                                          Z[M, k, 11].real, Z[M, k, 7].real, Z[M, k, 8].real, Z[M, k, 9].real,
                                          ph[k, 0].real, ph[k, 1].real, ph[k, 2].real, ph[k, 3].real, ph[k, 4].real,
                                          w[k].real, R[M, k], m, u0, d1, d2, order, tau, t2, t3)  # fmt: skip
        else:
            a0, a1, a2, a3, a4 = _carried(Z[M, k, 1], Z[M, k, 2], Z[M, k, 3], Z[M, k, 10], Z[M, k, 11], Z[M, k, 7],
                                          Z[M, k, 8], Z[M, k, 9], ph[k, 0], ph[k, 1], ph[k, 2], ph[k, 3], ph[k, 4],
                                          w[k], R[M, k], m, u0, d1, d2, order, tau, t2, t3)  # fmt: skip
        z0 += a0
        z1 += a1
        z2 += a2
        i0 += a3
        i4 += a4
    for q in range(m):
        ramp = tau * u0[q]
        if order > 0:
            ramp = ramp + 0.5 * t2 * d1[q]
            if order > 1:
                ramp = ramp + t3 * d2[q] / 3.0
        i0 += R[M, 3 + q] * ramp
        i4 += R[M, 6 + q] * ramp
    out[0], out[1], out[2], out[3], out[4] = y0 + i0, z0, z1, z2, y4 + i4


@njit(**_INLINE)
def _copy(src, dst):
    """``dst[:] = src`` element by element (a slice assignment checks the two for overlap and may copy through a
    temporary)."""
    for r in range(src.size):
        dst[r] = src[r]


@njit(**_INLINE)
def _project(c, mode, sigma, y):
    """c = 0 slip with a belt mass: the stretch follows sigma Q_max(omega_M) (the total deflection kept)."""
    if mode == SLIP and c[15] != 0.0:
        te = sigma * _limit(c, y[2]) / c[13]
        y[4] += c[1] * (y[1] - te)
        y[1] = te


@njit(**_JIT)
def _flow(mode, sigma, t, y, h, hi, u0, Z, R, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, out, wf, wc):
    """The method's step of length ``h`` [s] in ``mode`` from (t, y) with ``u0 = u(t, y)`` into ``out``; ``wf``
    (:data:`FLOW_WORK` floats), ``wc`` (:data:`FLOW_WORK` complex): the caller's work arrays (allocated once per run)."""
    M = mode
    m = 3 if mode == SLIP else 2
    method = c[16]
    # ua, ub, uc, um, d1, d2 (3), a, b, cc (5); w, wa (3), the phis at h and at h / 2 (3 x 5)
    ua, ub, uc, um, d1, d2 = wf[0:3], wf[3:6], wf[6:9], wf[9:12], wf[12:15], wf[15:18]
    a, b, cc = wf[18:23], wf[23:28], wf[28:33]
    w, wa, ph, ph_half = wc[0:3], wc[3:6], wc[6:21].reshape((3, 5)), wc[21:36].reshape((3, 5))
    _modal(Z, M, y, w)
    _phis(Z, R, M, h, ph)
    if method != ETD4:
        _state(Z, R, M, m, y[0], y[4], w, u0, d1, d2, 0, h, ph, out)
        if method == ETD2:
            _inputs(mode, sigma, t + h, out, hi, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, ua)
            for q in range(m):
                d1[q] = (ua[q] - u0[q]) / h
            _state(Z, R, M, m, y[0], y[4], w, u0, d1, d2, 1, h, ph, out)
        _project(c, mode, sigma, out)
        return
    # ETDRK4: a from y with U_0, b from y with U_a, c from a with 2 U_b - U_0, then the quadratic input
    half = 0.5 * h
    _phis(Z, R, M, half, ph_half)
    _state(Z, R, M, m, y[0], y[4], w, u0, d1, d2, 0, half, ph_half, a)
    _inputs(mode, sigma, t + half, a, hi, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, ua)
    _state(Z, R, M, m, y[0], y[4], w, ua, d1, d2, 0, half, ph_half, b)
    _inputs(mode, sigma, t + half, b, hi, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, ub)
    _modal(Z, M, a, wa)
    for q in range(m):
        um[q] = 2.0 * ub[q] - u0[q]
    _state(Z, R, M, m, a[0], a[4], wa, um, d1, d2, 0, half, ph_half, cc)
    _inputs(mode, sigma, t + h, cc, hi, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, uc)
    for q in range(m):
        d1[q] = (-3.0 * u0[q] + 2.0 * (ua[q] + ub[q]) - uc[q]) / h
        d2[q] = (2.0 * (u0[q] - ua[q] - ub[q] + uc[q])) / (h * h)
    _state(Z, R, M, m, y[0], y[4], w, u0, d1, d2, 2, h, ph, out)
    _project(c, mode, sigma, out)


@njit(**_INLINE)
def switching(c, mode, sigma, y):
    """> 0 once the mode must end: ``|Q| - Q_max`` sticking, ``-sigma s'`` slipping [N or m/s]."""
    if mode == STICK:
        return abs(c[6] * y[1] + c[7] * y[2] + c[8] * y[3]) - _limit(c, y[2])
    Q = sigma * _limit(c, y[2])
    rel = y[2] * c[9] + y[3] * c[10]
    if c[12] != 0.0:
        rel = rel - (Q - 2.0 * c[11] * c[1] * y[1]) / (2.0 * c[12])
    return -sigma * rel


@njit(**_INLINE)
def _amplitude(g0, g1, g2, lam, e, tp1, t2p2):
    """(value, d/dtau) at tau of one carried eigenvalue's term ``Re(g0 e^(l tau) + tau phi_1 g1 + tau^2 phi_2 g2)``
    of a guard (``tp1 = tau phi_1``, ``t2p2 = tau^2 phi_2``; complex, or a real eigenvalue's real parts)."""
    return (g0 * e + tp1 * g1 + t2p2 * g2).real, (g0 * lam * e + g1 * e + g2 * tp1).real


@njit(**_INLINE)
def _guard(tau, G, lam, nm, quad, absolute, bound):
    """(G, dG/dtau) of a guard on the modal flow: amplitudes ``G[k] = (row a0, a1, a2, speed s0, s1, s2)``."""
    t2 = tau * tau
    v = wv = dv = dwv = 0.0
    for k in range(nm):
        e, p1, p2, _, _ = _phis4(lam[k] * tau)
        tp1, t2p2 = tau * p1, t2 * p2
        # a real eigenvalue in real arithmetic: the same floats (its phis are real, see :func:`_carried`)
        real = lam[k].imag == 0.0
        for j in range(2 if quad != 0.0 else 1):  # the row, then the speed
            o = 3 * j
            if real:
                a, da = _amplitude(G[k, o].real, G[k, o + 1].real, G[k, o + 2].real, lam[k].real, e.real, tp1.real,
                                   t2p2.real)  # fmt: skip
            else:
                a, da = _amplitude(G[k, o], G[k, o + 1], G[k, o + 2], lam[k], e, tp1, t2p2)
            if j == 0:
                v, dv = v + a, dv + da
            else:
                wv, dwv = wv + a, dwv + da
    if absolute and v < 0.0:
        v, dv = -v, -dv
    return v - (bound - quad * wv * wv), dv + 2.0 * quad * wv * dwv


@njit(**_JIT)
def _locate(mode, sigma, t, y, h, hi, u0, y1, Z, R, c, guards, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, wf, wc):
    """First tau in (0, h] where the switching function turns positive on the step's continuous extension.

    The extension is the exact flow with the input linear from ``u(t, y)``
    to ``u(t + h, y1)`` (held for ``exact``). A sign scan (2 points, and 8 per
    half period of the fastest oscillation) finds the first crossing, a
    safeguarded Newton iteration (bisection when a step leaves the bracket)
    the root to ~1e-15 s. Returns nan: no crossing; 0.0: at the start. ``wf`` (:data:`LOCATE_WORK` floats), ``wc``
    (:data:`LOCATE_WORK` complex): the caller's work arrays.
    """
    M = mode
    m = 3 if mode == SLIP else 2
    nm = int(R[M, 10])
    du, u1 = wf[0:3], wf[3:6]  # du, u1; amplitudes (3 x 6), lambda, w
    amp, lam, w = wc[0:18].reshape((3, 6)), wc[18:21], wc[21:24]
    du[0], du[1], du[2] = 0.0, 0.0, 0.0  # (held for exact)
    if c[16] != EXACT:
        _inputs(mode, sigma, t + h, y1, hi, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, u1)
        for q in range(m):
            du[q] = (u1[q] - u0[q]) / h
    g = guards[0] if mode == STICK else guards[1] if sigma > 0.0 else guards[2]
    quad = g[2] if g[13] != 0.0 else 0.0
    _modal(Z, M, y, w)
    for k in range(nm):
        lam[k] = Z[M, k, 0]
        b0, db = _pdot(Z[M, k, 7], Z[M, k, 8], Z[M, k, 9], u0, m), _pdot(Z[M, k, 7], Z[M, k, 8], Z[M, k, 9], du, m)
        for j in range(2):
            o = 3 + 5 * j  # row, then speed
            r = R[M, k] * (g[o + 1] * Z[M, k, 1] + g[o + 2] * Z[M, k, 2] + g[o + 3] * Z[M, k, 3])
            amp[k, 3 * j], amp[k, 3 * j + 1], amp[k, 3 * j + 2] = r * w[k], r * b0, r * db
    absolute, bound = g[1] != 0.0, g[0]
    lo, g_lo = 0.0, switching(c, mode, sigma, y)
    if g_lo >= 0.0:  # starts on the surface (just switched): find where it is inside
        lo = math.nan
        for k in range(1, 40):
            tau = h * 0.5**k
            gv, _ = _guard(tau, amp, lam, nm, quad, absolute, bound)
            if gv < 0.0:
                lo, g_lo = tau, gv
                break
        if lo != lo:
            return 0.0
    n_scan = max(2, math.ceil(8.0 * R[M, 9] * h / math.pi))
    hi_tau, g_hi = math.nan, 0.0
    for j in range(1, n_scan + 1):
        tau = lo + (h - lo) * j / n_scan if j < n_scan else h
        gv, _ = _guard(tau, amp, lam, nm, quad, absolute, bound)
        if gv > 0.0:
            hi_tau, g_hi = tau, gv
            break
        lo, g_lo = tau, gv
    if hi_tau != hi_tau:
        return math.nan
    # safeguarded Newton from the secant point
    a, b = lo, hi_tau
    tau = a - g_lo * (b - a) / (g_hi - g_lo)
    eps4 = 4.0 * 2.220446049250313e-16
    for _ in range(200):
        if not a < tau < b:
            tau = 0.5 * (a + b)
        gv, dg = _guard(tau, amp, lam, nm, quad, absolute, bound)
        if gv == 0.0:
            return tau
        if gv > 0.0:
            b = tau
        else:
            a = tau
        new = tau - gv / dg if dg != 0.0 else 0.5 * (a + b)
        if abs(new - tau) <= 1e-15 + eps4 * abs(tau) or b - a <= 1e-15 + eps4 * abs(b):
            return new if a <= new <= b else tau
        tau = new
    return tau


@njit(**_JIT)
def locate_event(mode, sigma, t, y, h, hi, y1, Z, R, c, guards, uses, dk, dp, dx, dy, lk, lp, lx, ly):
    """:func:`_locate` with the input at the step's start computed here: the event location of a step whose
    partial steps are taken elsewhere (a method without a compiled event step: its own flow, in Python)."""
    wf = np.zeros(3 + LOCATE_WORK)
    wc = np.zeros(LOCATE_WORK, dtype=np.complex128)
    y, y1, Z, R, c, guards = borrowed(y), borrowed(y1), borrowed(Z), borrowed(R), borrowed(c), borrowed(guards)
    uses, dk, dp, dx, dy = borrowed(uses), borrowed(dk), borrowed(dp), borrowed(dx), borrowed(dy)
    lk, lp, lx, ly = borrowed(lk), borrowed(lp), borrowed(lx), borrowed(ly)
    u0 = wf[:3]
    sd, sl = profile_scalars(dk, dp, dx, dy), profile_scalars(lk, lp, lx, ly)
    _inputs(mode, sigma, t, y, hi, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, u0)
    return _locate(mode, sigma, t, y, h, hi, u0, y1, Z, R, c, guards, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly,
                   wf[3:], wc)  # fmt: skip


@njit(**_JIT)
def _stick_keeps(t, y, c, mats, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, wf):
    """True if the stick mode's |Q| does not at once grow past Q_max from (t, y).

    The sign of sigma dQ/dt - dQ_max/dt in stick mode; where that vanishes to
    rounding, the sign of sigma d2Q/dt2 = sigma q . A y' (inputs held). ``wf``: 13 work floats of the caller.
    """
    Q = c[6] * y[1] + c[7] * y[2] + c[8] * y[3]
    if abs(Q) < _limit(c, y[2]) * (1.0 - 1e-9):
        return True
    sig = math.copysign(1.0, Q)
    u, dyv, scale_v = wf[0:3], wf[3:8], wf[8:13]
    stick = np.int64(STICK)  # int64, as every call
    _inputs(stick, 0.0, t, y, math.inf, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, u)
    for r in range(5):
        total, mag = 0.0, 0.0
        for j in range(5):
            total += mats[r, j] * y[j]
            mag += abs(mats[r, j]) * abs(y[j])
        for j in range(2):
            total += mats[r, 5 + j] * u[j]
            mag += abs(mats[r, 5 + j]) * abs(u[j])
        dyv[r], scale_v[r] = total, mag
    dlim = c[14] * y[2] * dyv[2]
    rate = sig * (c[6] * dyv[1] + c[7] * dyv[2] + c[8] * dyv[3]) - dlim
    scale = abs(c[6]) * scale_v[1] + abs(c[7]) * scale_v[2] + abs(c[8]) * scale_v[3] + abs(dlim)
    if abs(rate) > 1e-8 * scale:
        return rate < 0.0
    second = 0.0
    for r in (1, 2, 3):
        total = 0.0
        for j in range(5):
            total += mats[r, j] * dyv[j]
        second += c[5 + r] * total
    return sig * second <= 0.0


@njit(**_JIT)
def event_step(t0, t1, cuts, y, mode, sigma, dt, hi_end, y1, given, Z, R, c, mats, guards, uses,
               dk, dp, dx, dy, lk, lp, lx, ly, events, n0):  # fmt: skip
    """:func:`_event_step` with its work arrays allocated here (a call from Python: :class:`~.slip.EventStep`)."""
    wf = np.zeros(EVENT_WORK)
    wc = np.zeros(FLOW_WORK + LOCATE_WORK, dtype=np.complex128)
    sd, sl = profile_scalars(dk, dp, dx, dy), profile_scalars(lk, lp, lx, ly)
    return _event_step(t0, t1, cuts, y, mode, sigma, dt, hi_end, y1, given, Z, R, c, mats, guards, uses, sd, sl,
                       dk, dp, dx, dy, lk, lp, lx, ly, events, n0, wf, wc)  # fmt: skip


@njit(**_JIT)
def _event_step(t0, t1, cuts, y, mode, sigma, dt, hi_end, y1, given, Z, R, c, mats, guards, uses, sd, sl,
                dk, dp, dx, dy, lk, lp, lx, ly, events, n0, wf, wc):  # fmt: skip
    """Integrate from ``t0`` to ``t1`` [s] in the hybrid model: sub-steps end at each cut, then at each located event.

    ``y`` (5,) is overwritten with the end state. A sub-step whose end has a
    positive switching function holds an event: located (:func:`_locate`),
    the flow taken to it, the mode switched and the sub-step's rest taken
    in the new mode. ``dt``: the grid step for a whole step (nan: none);
    ``hi_end``: torque times clipped there in the last sub-step; ``y1``
    (``given`` 1): the method's state at ``t1`` in ``mode`` already known.
    ``events`` (E, 8) receives ``[time, onset (1) / restick (0), sigma, state (5)]`` from row ``n0``.
    ``wf`` (:data:`EVENT_WORK` floats), ``wc`` (``FLOW_WORK + LOCATE_WORK`` complex): work arrays.

    Returns (mode, sigma, number of events recorded, status): status 0 done,
    1 more than :data:`MAX_SWITCHES` switches (chattering).

    Every array is used as a :func:`~.kernel.borrowed` view (no atomic reference counts below: see the module's top).
    """
    cuts, y, y1, Z, R, c, mats = borrowed(cuts), borrowed(y), borrowed(y1), borrowed(Z), borrowed(R), borrowed(c), borrowed(mats)
    guards, uses, dk, dp, dx, dy = borrowed(guards), borrowed(uses), borrowed(dk), borrowed(dp), borrowed(dx), borrowed(dy)
    lk, lp, lx, ly = borrowed(lk), borrowed(lp), borrowed(lx), borrowed(ly)
    events, wf, wc = borrowed(events), borrowed(wf), borrowed(wc)
    n_rec = 0
    n_switch = 0
    u0, ye = wf[0:3], wf[3:8]
    e1 = 8 + FLOW_WORK
    e2 = e1 + LOCATE_WORK
    flow_f, flow_c, loc_f, loc_c, keep_f = wf[8:e1], wc[:FLOW_WORK], wf[e1:e2], wc[FLOW_WORK:], wf[e2:]
    nc = cuts.size
    for j in range(nc + 1):
        a = t0 if j == 0 else cuts[j - 1]
        b = t1 if j == nc else cuts[j]
        hi = math.nextafter(b, -math.inf) if j < nc else hi_end
        while a < b:
            h = dt if (dt == dt and a == t0 and b == t1) else b - a  # a whole grid step: the grid's dt
            _inputs(mode, sigma, a, y, hi, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, u0)
            if given == 0 or nc > 0:
                _flow(mode, sigma, a, y, h, hi, u0, Z, R, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, y1,
                      flow_f, flow_c)  # fmt: skip
            given = 0
            if switching(c, mode, sigma, y1) <= 0.0:
                _copy(y1, y)
                a = b
                break
            tau = _locate(mode, sigma, a, y, h, hi, u0, y1, Z, R, c, guards, uses, sd, sl, dk, dp, dx, dy, lk, lp,
                          lx, ly, loc_f, loc_c)  # fmt: skip
            if tau != tau:
                _copy(y1, y)
                a = b
                break
            if tau > 0.0:
                _flow(mode, sigma, a, y, tau, hi, u0, Z, R, c, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, ye,
                      flow_f, flow_c)  # fmt: skip
                _copy(ye, y)
            a = a + tau if tau < h else b
            old = mode
            if mode == STICK:
                sigma = 1.0 if c[6] * y[1] + c[7] * y[2] + c[8] * y[3] >= 0.0 else -1.0
                mode = SLIP
                if c[12] == 0.0:  # the stretch sits at the limit exactly
                    te = sigma * _limit(c, y[2]) / c[13]
                    y[4] += c[1] * (y[1] - te)
                    y[1] = te
            elif _stick_keeps(a, y, c, mats, uses, sd, sl, dk, dp, dx, dy, lk, lp, lx, ly, keep_f):
                mode, sigma = STICK, 0.0
            if mode != old and n0 + n_rec < events.shape[0]:
                row = n0 + n_rec
                events[row, 0], events[row, 1], events[row, 2] = a, 1.0 if mode == SLIP else 0.0, sigma
                _copy(y, events[row, 3:])
                n_rec += 1
            n_switch += 1
            if n_switch > MAX_SWITCHES:
                return mode, sigma, n_rec, 1
    return mode, sigma, n_rec, 0


# ------------------------------------------------------------- Python side
def pack(model, method: str, drive_data, load_data, uses_angle):
    """The arrays :func:`event_step` reads for ``model`` (a SlippingBeltModel) and ``method``, or None.

    None where a mode's ``A_z`` is (nearly) defective (no modal split).
    """
    p = model.params
    Z = np.zeros((2, 3, 12), dtype=np.complex128)
    R = np.zeros((2, 11))
    for M, (A, B) in enumerate(((model.A_stick, model.B_stick), (model.A_slip, model.B_slip))):
        if np.any(A[:, 0]) or np.any(A[:, 4]):
            return None
        lam, V = np.linalg.eig(A[1:4, 1:4])
        if not np.all(np.isfinite(lam)) or np.linalg.cond(V) > 1e8:
            return None
        Vinv = np.linalg.inv(V)
        P = Vinv @ B[1:4]
        C = A[[0, 4], 1:4] @ V
        k, pairs = 0, 0
        for i in range(3):  # a complex pair carried once (twice its real part)
            if lam[i].imag < 0.0:
                pairs -= 1
                continue
            pairs += lam[i].imag > 0.0
            Z[M, k, 0] = lam[i]
            Z[M, k, 1:4], Z[M, k, 4:7] = V[:, i], Vinv[i]
            Z[M, k, 7 : 7 + B.shape[1]], Z[M, k, 10:12] = P[i], C[:, i]
            if lam[i].imag == 0.0:  # (real already, LAPACK's: the kernel's real arithmetic reads their real parts)
                Z[M, k, 1:4], Z[M, k, 10:12] = V[:, i].real, C[:, i].real
            R[M, k] = 1.0 if lam[i].imag == 0.0 else 2.0
            k += 1
        if pairs != 0:
            return None
        R[M, 3 : 3 + B.shape[1]], R[M, 6 : 6 + B.shape[1]] = B[0], B[4]
        R[M, 9], R[M, 10] = float(np.max(np.abs(lam.imag))), k
    code = {"exact": EXACT, "etd2": ETD2}.get(method, ETD4)
    q = model.q_row
    c = np.array([p.ratio, p.r_3, p.F_0, p.belt_mass, p.r_2 * p.gear_ratio, p.capstan_factor, q[1], q[2], q[3],
                  model.rel_row[2], model.rel_row[3], p.k, p.c, 2.0 * p.k * p.r_3,
                  -2.0 * p.belt_mass * (p.r_2 * p.gear_ratio) ** 2 * p.capstan_factor,
                  float(p.c == 0.0 and p.belt_mass > 0.0), code], dtype=np.float64)  # fmt: skip
    mats = np.ascontiguousarray(np.hstack([model.A_stick, model.B_stick]))
    guards = np.zeros((3, 15))
    for row, (mode, sigma) in enumerate(((0, 0.0), (1, 1.0), (1, -1.0))):
        g = model.guard(mode, sigma)
        guards[row, :3] = g.bound, float(bool(g.absolute)), g.quad
        guards[row, 3:8] = g.row
        if g.speed is not None:
            guards[row, 8:13], guards[row, 13] = g.speed, 1.0
    uses = np.array([bool(u) for u in uses_angle], dtype=np.int64)
    return (Z, R, c, mats, guards, uses, drive_data.kinds, drive_data.params, drive_data.tx, drive_data.ty,
            load_data.kinds, load_data.params, load_data.tx, load_data.ty)  # fmt: skip

