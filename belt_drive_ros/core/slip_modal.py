"""Exact flow of one mode of the slipping belt by its eigenvalues, on plain floats (event handling).

In both modes of :class:`~belt_drive_ros.core.slip.SlippingBeltModel` the
state ``y = [phi_M, theta_e, omega_M, omega_3, s]`` splits into the
sub-state ``z = [theta_e, omega_M, omega_3]``, which evolves by itself
(``z' = A_z z + B_z u``), and the two integrated coordinates ``phi_M`` and
``s``, whose rates read only ``z`` and ``u`` (columns 0 and 4 of ``A`` are
zero). With ``A_z = V diag(lambda) V^-1`` and an input linear in time from
``u_0`` at ``tau = 0`` to ``u_1`` at ``tau = h``, the modal coordinates
``zeta = V^-1 z`` follow::

    zeta_i(tau) = e^(l tau) w_i + tau phi_1(l tau) b0_i + tau^2 phi_2(l tau) db_i
    int_0^tau zeta_i = tau phi_1(l tau) w_i + tau^2 phi_2(l tau) b0_i + tau^3 phi_3(l tau) db_i

with ``l = lambda_i``, ``w = V^-1 z(0)``, ``b0 = V^-1 B_z u_0``,
``db = V^-1 B_z (u_1 - u_0) / h`` and ``phi_k(x) = sum_j x^j / (j + k)!``
(from ``int_0^tau s^k phi_k(l s) ds = tau^(k+1) phi_(k+1)(l tau)``). The
integrated coordinates add ``Re(a_j V int zeta) + b_j (tau u_0 + tau^2 (u_1 - u_0) / (2 h))``.

This is the exact solution of the mode's linear ODE with that input: the
``exact`` method's step (held input, ``u_1 = u_0``) and the ``etd2`` step
(``u_1`` from the predictor, ``h = tau``) of any length (and, with a
quadratic input, the ``etd4`` step: :meth:`ModalFlow.step_etd4`), and the continuous
extension on which events are located, each for a few dozen complex
multiply-adds instead of a matrix exponential per sub-step length. Where
``A_z`` is (nearly) defective the constructor raises ``LinAlgError`` and
the callers use the integrators instead.
"""

from __future__ import annotations

import cmath
import math
from typing import Callable

import numpy as np


#: Taylor coefficients 1/(j+3)! of phi_3, enough for |x| < 0.5 to below 1e-17 relative
_PHI3 = tuple(1.0 / math.factorial(j + 3) for j in range(15))
#: Taylor coefficients 1/(j+4)! of phi_4
_PHI4 = tuple(1.0 / math.factorial(j + 4) for j in range(15))


def _horner(coefficients, x):
    """``p = 0 x; p = p x + c`` for each ``c`` of ``coefficients`` from the last (the series' value at ``x``)."""
    p = 0.0 * x
    for c in reversed(coefficients):
        p = p * x + c
    return p


def _series3(x):
    return _horner(_PHI3, x)


def _series4(x):
    return _horner(_PHI4, x)


def phis(x: complex) -> tuple[complex, complex, complex, complex]:
    """(e^x, phi_1(x), phi_2(x), phi_3(x)): Taylor series below |x| = 0.5, closed forms above."""
    if abs(x) < 0.5:
        p3 = _series3(x)
        p2 = 0.5 + x * p3
        p1 = 1.0 + x * p2
        return 1.0 + x * p1, p1, p2, p3
    e = cmath.exp(x) if isinstance(x, complex) else math.exp(x)
    p1 = (e - 1.0) / x
    p2 = (p1 - 1.0) / x
    return e, p1, p2, (p2 - 0.5) / x


def phis4(x: complex) -> tuple:
    """(e^x, phi_1(x), ..., phi_4(x)) (the etd4 step's quadratic input needs phi_4 for the integrated coordinates)."""
    if abs(x) < 0.5:
        p4 = _series4(x)
        p3 = 1.0 / 6.0 + x * p4
        p2 = 0.5 + x * p3
        p1 = 1.0 + x * p2
        return 1.0 + x * p1, p1, p2, p3, p4
    e, p1, p2, p3 = phis(x)
    return e, p1, p2, p3, (p3 - 1.0 / 6.0) / x


def _dot(P, u) -> complex:
    """sum_q P[q] u[q] for the 2 or 3 inputs of a mode."""
    if len(u) == 2:
        return P[0] * u[0] + P[1] * u[1]
    return P[0] * u[0] + P[1] * u[1] + P[2] * u[2]


class ModalFlow:
    """Exact flow of ``y' = A y + B u`` (5 states, ``u`` linear in time) by the eigenvalues of ``A[1:4, 1:4]``.

    Parameters
    ----------
    A : (5, 5) mode matrix with zero columns 0 and 4.
    B : (5, m) input matrix.

    A complex pair of eigenvalues is carried once (its partner contributes the
    complex conjugate: twice the real part); real eigenvalues in real
    arithmetic.
    """

    def __init__(self, A, B):
        A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
        if np.any(A[:, 0]) or np.any(A[:, 4]):
            raise np.linalg.LinAlgError("phi_M or s feeds back: no modal split")
        lam, V = np.linalg.eig(A[1:4, 1:4])
        if not np.all(np.isfinite(lam)) or np.linalg.cond(V) > 1e8:
            raise np.linalg.LinAlgError("defective")
        Vinv = np.linalg.inv(V)
        P = Vinv @ B[1:4]  # V^-1 B_z, (3, m)
        C = A[[0, 4], 1:4] @ V  # rates of phi_M and s on zeta
        self.m = B.shape[1]
        self.B04 = [[float(v) for v in row] for row in B[[0, 4]]]
        #: per carried mode: (lambda, weight, V column, V^-1 row, P row, C column)
        self.modes = []
        pairs = 0
        for i in range(3):
            if lam[i].imag < 0.0:
                pairs -= 1
                continue
            if lam[i].imag > 0.0:
                pairs += 1

            def conv(values, real=lam[i].imag == 0.0):
                return [float(v.real) if real else complex(v) for v in values]

            real = lam[i].imag == 0.0
            self.modes.append((
                float(lam[i].real) if real else complex(lam[i]), 1.0 if real else 2.0,
                conv(V[:, i]), conv(Vinv[i]), conv(P[i]), conv(C[:, i]),
            ))  # fmt: skip
        if pairs != 0:
            raise np.linalg.LinAlgError("eigenvalues not in conjugate pairs")
        self.max_frequency = float(np.max(np.abs(lam.imag)))
        self._lams = tuple(mode[0] for mode in self.modes)
        self._weights: dict = {}

    def prepare(self, y, u0, u1, h, w=None, b0=None):
        """Coefficients (w, b0, db, u0, du) from state ``y`` and the input's values at 0 and ``h`` [s].

        ``w``, ``b0``: those of an earlier call with the same ``y`` and ``u0`` (reused).
        """
        if w is None:
            z0, z1, z2 = float(y[1]), float(y[2]), float(y[3])
            w = [Vi[0] * z0 + Vi[1] * z1 + Vi[2] * z2 for _, _, _, Vi, _, _ in self.modes]
            b0 = [_dot(P, u0) for _, _, _, _, P, _ in self.modes]
        if u1 is u0:
            return w, b0, [0.0] * len(w), u0, [0.0] * len(u0)
        du = [(b - a) / h for a, b in zip(u0, u1)]
        return w, b0, [_dot(P, du) for _, _, _, _, P, _ in self.modes], u0, du

    def _phis(self, tau):
        return [phis(lam * tau) for lam in self._lams]

    def _row_weights(self, row) -> list:
        """``weight_i (row . V_i)`` per carried mode for a row on ``y`` (cached: a guard's rows are fixed)."""
        key = tuple(row)
        r = self._weights.get(key)
        if r is None:
            r = self._weights[key] = [
                weight * (row[1] * Vc[0] + row[2] * Vc[1] + row[3] * Vc[2]) for _, weight, Vc, _, _, _ in self.modes
            ]
        return r

    def guard_function(self, guard, coeffs):
        """``G(tau) = guard.value(y(tau))`` and its derivative, for a guard that reads only z (entries 0 and 4 zero).

        ``row . z = sum_i weight_i Re((row . V_i) zeta_i(tau))``, likewise the speed row.
        """
        if guard.row[0] or guard.row[4] or (guard.speed is not None and (guard.speed[0] or guard.speed[4])):
            raise ValueError("guard reads phi_M or s")
        w, b0, db = coeffs[0], coeffs[1], coeffs[2]

        def amplitudes(row):
            return [(r * w[k], r * b0[k], r * db[k]) for k, r in enumerate(self._row_weights(row))]

        a = list(zip(self._lams, amplitudes(guard.row)))
        quad = guard.quad if guard.speed is not None else 0.0
        sp = amplitudes(guard.speed) if quad else None
        absolute, bound = guard.absolute, guard.bound

        def G(tau):
            """(G, dG/dtau) at tau: d/dtau of (e, tau phi_1, tau^2 phi_2) is (lambda e, e, tau phi_1)."""
            t2 = tau * tau
            v = wv = dv = dwv = 0.0
            for k, (lam, (a0, a1, a2)) in enumerate(a):
                e, p1, p2, _ = phis(lam * tau)
                tp1 = tau * p1
                v += (a0 * e + tp1 * a1 + t2 * p2 * a2).real
                dv += (a0 * lam * e + a1 * e + a2 * tp1).real
                if sp is not None:
                    s0, s1, s2 = sp[k]
                    wv += (s0 * e + tp1 * s1 + t2 * p2 * s2).real
                    dwv += (s0 * lam * e + s1 * e + s2 * tp1).real
            if absolute and v < 0.0:
                v, dv = -v, -dv
            return v - (bound - quad * wv * wv), dv + 2.0 * quad * wv * dwv

        return G

    def state(self, y, coeffs, tau: float, ph=None) -> list:
        """The whole state (5 floats) at ``tau`` [s] (``ph``: :meth:`_phis` of ``tau`` if known)."""
        w, b0, db, u0, du = coeffs
        ph = ph or self._phis(tau)
        t2 = tau * tau
        z0 = z1 = z2 = i0 = i4 = 0.0
        for k, (_, weight, Vc, _, _, Cc) in enumerate(self.modes):
            e, p1, p2, p3 = ph[k]
            zeta = weight * (e * w[k] + tau * p1 * b0[k] + t2 * p2 * db[k])
            integral = weight * (tau * p1 * w[k] + t2 * p2 * b0[k] + t2 * tau * p3 * db[k])
            z0 += (Vc[0] * zeta).real
            z1 += (Vc[1] * zeta).real
            z2 += (Vc[2] * zeta).real
            i0 += (Cc[0] * integral).real
            i4 += (Cc[1] * integral).real
        B0, B4 = self.B04
        for q in range(self.m):
            ramp = tau * u0[q] + 0.5 * t2 * du[q]
            i0 += B0[q] * ramp
            i4 += B4[q] * ramp
        return [float(y[0]) + i0, z0, z1, z2, float(y[4]) + i4]

    def step(self, y, t: float, h: float, u: Callable, method: str) -> list:
        """One ``exact`` (input held at ``u(t, y)``), ``etd2`` or ``etd4`` step of length ``h`` [s].

        etd2 (Cox-Matthews): ``a`` = the held-input flow, ``u_1 = u(t + h, a)``,
        then the flow with the input ramping from ``u_0`` to ``u_1``. etd4:
        :meth:`step_etd4`.
        """
        return self.step_from(y, t, h, u, method, u(t, y))

    def step_from(self, y, t: float, h: float, u: Callable, method: str, u0, w=None, b0=None) -> list:
        """:meth:`step` with the input at the start ``u0 = u(t, y)`` known (and ``w``, ``b0`` of :meth:`prepare` for it)."""
        if method == "etd4":
            return self.step_etd4(y, t, h, u, u0, w)
        ph = self._phis(h)
        held = self.prepare(y, u0, u0, h, w, b0)
        a = self.state(y, held, h, ph)
        if method != "etd2":
            return a
        return self.state(y, self.prepare(y, u0, u(t + h, a), h, held[0], held[1]), h, ph)

    def _w(self, y) -> list:
        """Modal coordinates ``V^-1 z`` of state ``y``."""
        z0, z1, z2 = float(y[1]), float(y[2]), float(y[3])
        return [Vi[0] * z0 + Vi[1] * z1 + Vi[2] * z2 for _, _, _, Vi, _, _ in self.modes]

    def _held(self, w, u) -> tuple:
        """:meth:`prepare`'s coefficients of modal coordinates ``w`` and the input ``u`` held."""
        return w, [_dot(P, u) for _, _, _, _, P, _ in self.modes], [0.0] * len(w), u, [0.0] * len(u)

    def step_etd4(self, y, t: float, h: float, u: Callable, u0, w=None) -> list:
        """The ``etd4`` step (Cox-Matthews ETDRK4, as :class:`~belt_drive_ros.core.integrators.ExponentialRK4`) of length ``h``.

        Its stages are held-input flows over ``h/2``: ``a`` from y with
        ``U_0``, ``b`` from y with ``U_a = u(t + h/2, a)``, ``c`` from ``a``
        with ``2 U_b - U_0`` (``U_b = u(t + h/2, b)``); the end is the exact
        flow from y over ``h`` with the input polynomial
        ``p(s) = c_0 + c_1 s/h + c_2 (s/h)^2``, ``c_0 = U_0``,
        ``c_1 = -3 U_0 + 2 (U_a + U_b) - U_c``, ``c_2 = 2 (U_0 - U_a - U_b + U_c)``
        (``U_c = u(t + h, c)``): its Duhamel integral
        ``h [phi_1 c_0 + phi_2 c_1 + 2 phi_3 c_2] B`` is the method's
        ``h [(phi_1 - 3 phi_2 + 4 phi_3) U_0 + 2 (phi_2 - 2 phi_3) (U_a + U_b) + (4 phi_3 - phi_2) U_c] B``.
        """
        half = 0.5 * h
        ph2 = self._phis(half)
        w = self._w(y) if w is None else w
        y0, y4 = float(y[0]), float(y[4])
        a = self._held_state(y0, y4, w, u0, half, ph2)
        ua = u(t + half, a)
        b = self._held_state(y0, y4, w, ua, half, ph2)
        ub = u(t + half, b)
        c = self._held_state(a[0], a[4], self._w(a), [2.0 * q - p for p, q in zip(u0, ub)], half, ph2)
        uc = u(t + h, c)
        c1 = [-3.0 * p + 2.0 * (qa + qb) - qc for p, qa, qb, qc in zip(u0, ua, ub, uc)]
        c2 = [2.0 * (p - qa - qb + qc) for p, qa, qb, qc in zip(u0, ua, ub, uc)]
        return self.state_quadratic(y, w, u0, [v / h for v in c1], [v / (h * h) for v in c2], h)

    def _held_state(self, y0: float, y4: float, w, u, tau: float, ph) -> list:
        """:meth:`state` at ``tau`` [s] from phi_M = ``y0``, modal coordinates ``w``, s = ``y4`` with the input ``u`` held.

        The same sums as :meth:`state` with ``db = du = 0`` (those terms left out, not added as zeros).
        """
        t2 = tau * tau
        z0 = z1 = z2 = i0 = i4 = 0.0
        three = self.m == 3
        for (_, weight, Vc, _, P, Cc), wk, (e, p1, p2, _) in zip(self.modes, w, ph):
            b0 = P[0] * u[0] + P[1] * u[1] + P[2] * u[2] if three else P[0] * u[0] + P[1] * u[1]
            tp1 = tau * p1
            zeta = weight * (e * wk + tp1 * b0)
            integral = weight * (tp1 * wk + t2 * p2 * b0)
            z0 += (Vc[0] * zeta).real
            z1 += (Vc[1] * zeta).real
            z2 += (Vc[2] * zeta).real
            i0 += (Cc[0] * integral).real
            i4 += (Cc[1] * integral).real
        B0, B4 = self.B04
        for q in range(self.m):
            ramp = tau * u[q]
            i0 += B0[q] * ramp
            i4 += B4[q] * ramp
        return [y0 + i0, z0, z1, z2, y4 + i4]

    def state_quadratic(self, y, w, u0, d1, d2, tau: float) -> list:
        """The state at ``tau`` [s] from ``y`` (modal coordinates ``w``) with the input ``u0 + d1 s + d2 s^2``.

        ``zeta_i = e^(l tau) w_i + tau phi_1 b0_i + tau^2 phi_2 b1_i + 2 tau^3 phi_3 b2_i``
        (``b_k = V^-1 B_z d_k``), its integral adds one power of tau and one
        phi index; the direct input terms integrate to
        ``tau u0 + tau^2 d1 / 2 + tau^3 d2 / 3``.
        """
        t2 = tau * tau
        t3 = t2 * tau
        z0 = z1 = z2 = i0 = i4 = 0.0
        three = self.m == 3
        for (lam, weight, Vc, _, P, Cc), wk in zip(self.modes, w):
            e, p1, p2, p3, p4 = phis4(lam * tau)
            if three:
                b0 = P[0] * u0[0] + P[1] * u0[1] + P[2] * u0[2]
                b1 = P[0] * d1[0] + P[1] * d1[1] + P[2] * d1[2]
                b2 = P[0] * d2[0] + P[1] * d2[1] + P[2] * d2[2]
            else:
                b0, b1, b2 = P[0] * u0[0] + P[1] * u0[1], P[0] * d1[0] + P[1] * d1[1], P[0] * d2[0] + P[1] * d2[1]
            zeta = weight * (e * wk + tau * p1 * b0 + t2 * p2 * b1 + 2.0 * t3 * p3 * b2)
            integral = weight * (tau * p1 * wk + t2 * p2 * b0 + t3 * p3 * b1 + 2.0 * t2 * t2 * p4 * b2)
            z0 += (Vc[0] * zeta).real
            z1 += (Vc[1] * zeta).real
            z2 += (Vc[2] * zeta).real
            i0 += (Cc[0] * integral).real
            i4 += (Cc[1] * integral).real
        B0, B4 = self.B04
        for q in range(self.m):
            ramp = tau * u0[q] + 0.5 * t2 * d1[q] + t3 * d2[q] / 3.0
            i0 += B0[q] * ramp
            i4 += B4[q] * ramp
        return [float(y[0]) + i0, z0, z1, z2, float(y[4]) + i4]
