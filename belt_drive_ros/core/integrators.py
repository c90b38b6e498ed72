"""Integrators behind one step protocol, chosen by name.

Every integrator advances ``x' = A x + B u(t, x)`` (the model's matrices,
torques from the drive and load profiles) by one step::

    x_next = integrator.step(t, x, inputs)      # inputs(t, x) -> u [N m]

Fixed-step methods also expose their *linear one-step map*
(:meth:`FixedStepIntegrator.linear_step`): applied to the LTI model with a
torque that depends on time only, every one of them is exactly::

    x_{n+1} = Phi x_n + sum_j G_j u(t_n + c_j h)

That map drives the vectorized open-loop propagation
(:func:`propagate_linear`), the stability guard (its amplification of each
eigenvalue of A) and the tests that check each method's order.

Methods (``REGISTRY``; order for smooth, state-dependent torques):

=================  =====  ==========================================================
name               order  notes
=================  =====  ==========================================================
exact              1      ZOH: Phi = expm(A h); exact for piecewise-constant torque
                          (the ROS node's held messages), any step, unconditionally
                          stable; torque sampled at step start (exponential Euler)
etd2               2      exponential RK2 (Cox-Matthews): exact for the belt mode
                          and for piecewise-*linear* torque, unconditionally stable
etd4               4      exponential RK4 (Cox-Matthews ETDRK4): belt mode exact,
                          unconditionally stable, large steps on smooth scenes
lawson5            5      integrating-factor Dormand-Prince 5: belt mode exact,
                          6 torque samples per step; cheapest at errors <= 1e-5
                          on smooth scenes for h omega_n up to ~1
euler              1      explicit Euler; unstable on an undamped belt for any h
symplectic_euler   1      semi-implicit Euler (velocity first); h omega_n < 2
rk4                4      classical Runge-Kutta; h omega_n <= 2 sqrt(2) (undamped)
trapezoidal        2      implicit, A-stable; state-dependent torque by fixed point
RK45, DOP853,      adapt. scipy.integrate.solve_ivp methods as adaptive references
Radau, BDF, LSODA         (``rtol``, ``atol`` options)
=================  =====  ==========================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable, ClassVar

import numpy as np
import scipy.integrate
import scipy.linalg

from .errors import IntegratorError

Inputs = Callable[[float, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class LinearStep:
    """One step of a method on x' = A x + B u(t): x+ = Phi x + sum_j gains[j] u(t + nodes[j] h)."""

    Phi: np.ndarray
    nodes: tuple
    gains: tuple


class Integrator:
    """Protocol: ``step(t, x, inputs) -> x_next`` over a step ``dt`` [s]."""

    name: ClassVar[str] = ""
    order: ClassVar[int | None] = None
    explicit: ClassVar[bool] = True
    adaptive: ClassVar[bool] = False
    #: h*omega_n stability boundary for an undamped oscillator (None: no limit).
    imag_axis_limit: ClassVar[float | None] = None

    def __init__(self, A: np.ndarray, B: np.ndarray, dt: float, **options):
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise IntegratorError(f"dt: must be a finite step > 0 s, got {dt!r}")
        if options:
            raise IntegratorError(f"{self.name}: unknown option(s) {', '.join(sorted(options))}")
        self.A = np.asarray(A, dtype=float)
        self.B = np.asarray(B, dtype=float)
        self.dt = float(dt)

    def step(self, t: float, x: np.ndarray, inputs: Inputs) -> np.ndarray:
        raise NotImplementedError

    def reset(self) -> None:
        """Forget any history (adaptive solvers restart at the next step)."""


class FixedStepIntegrator(Integrator):
    """A one-step method with a step of fixed size and a linear one-step map."""

    def linear_step(self) -> LinearStep:
        raise NotImplementedError

    def stage_scheme(self) -> "StageScheme | None":
        """The step as affine maps between torque samples (see :class:`StageScheme`); None: not available."""
        return None

    def scalar_loop(self, wheel_map: np.ndarray, uses_angle=(True, True), sources=(None, None)) -> "Callable | None":
        """Compiled fast loop of :meth:`step` for one plant (see :func:`compile_scalar_loop`), cached per plant."""
        scheme = self.stage_scheme()
        if scheme is None:
            return None
        wheel_map = np.asarray(wheel_map, dtype=float)
        probe = tuple(None if f is None else f("t", "a", "w") for f in sources)
        key = (wheel_map.tobytes(), tuple(bool(u) for u in uses_angle), probe)
        cache = self.__dict__.setdefault("_scalar_loops", {})
        if key not in cache:
            cache[key] = compile_scalar_loop(scheme, wheel_map, self.dt, self.name, uses_angle, sources)
        return cache[key]

    def amplification(self, lam: complex) -> float:
        """|growth factor| per step of the mode with continuous eigenvalue ``lam`` [1/s]."""
        raise NotImplementedError


# ------------------------------------------------------------- exponential
@lru_cache(maxsize=64)
def _expm_blocks(a_bytes: bytes, b_bytes: bytes, n: int, m: int, h: float):
    """Phi = e^{Ah}, G0 = int_0^h e^{As} ds B, G1 = int_0^h e^{A(h-s)} s ds B / h (cached per h)."""
    A = np.frombuffer(a_bytes).reshape(n, n)
    B = np.frombuffer(b_bytes).reshape(n, m)
    M = np.zeros((n + 2 * m, n + 2 * m))
    M[:n, :n] = A
    M[:n, n : n + m] = B
    M[n : n + m, n + m :] = np.eye(m)
    E = scipy.linalg.expm(M * h)  # Van Loan: one exponential gives all three blocks
    return E[:n, :n].copy(), E[:n, n : n + m].copy(), E[:n, n + m :].copy() / h


class Exact(FixedStepIntegrator):
    """Exact zero-order-hold discretization: x+ = e^{Ah} x + Gamma u(t, x).

    ``Gamma = int_0^h e^{As} ds B``. Exact to rounding for a torque held
    constant over the step, for any h (unconditionally stable). A torque that
    varies within the step is sampled at its start: first order then.
    """

    name = "exact"
    order = 1
    explicit = True

    def __init__(self, A, B, dt, **options):
        super().__init__(A, B, dt, **options)
        self.Phi, self.Gamma, _ = _expm_blocks(
            self.A.tobytes(), self.B.tobytes(), self.A.shape[0], self.B.shape[1], self.dt
        )

    def step(self, t, x, inputs):
        return self.Phi @ x + self.Gamma @ inputs(t, x)

    def linear_step(self):
        return LinearStep(self.Phi, (0.0,), (self.Gamma,))

    def stage_scheme(self):
        # u_0 = u(t, x);  x+ = Phi x + Gamma u_0
        return StageScheme((0.0,), (None,), np.hstack([self.Phi, self.Gamma]))

    def amplification(self, lam):
        return abs(np.exp(lam * self.dt))


class ExponentialRK2(FixedStepIntegrator):
    """Exponential time differencing RK2 (Cox & Matthews 2002, ETD2RK).

    ``a = Phi x + G0 u_n``; ``x+ = a + G1 (u(t+h, a) - u_n)`` with
    ``G1 = int_0^h e^{A(h-s)} (s/h) ds B``. The belt mode is integrated
    exactly (unconditionally stable); the torque is taken as linear in time
    over the step, so piecewise-linear inputs are exact and smooth
    state-dependent torques converge with order 2.
    """

    name = "etd2"
    order = 2

    def __init__(self, A, B, dt, **options):
        super().__init__(A, B, dt, **options)
        self.Phi, self.G0, self.G1 = _expm_blocks(
            self.A.tobytes(), self.B.tobytes(), self.A.shape[0], self.B.shape[1], self.dt
        )

    def step(self, t, x, inputs):
        u0 = inputs(t, x)
        a = self.Phi @ x + self.G0 @ u0
        return a + self.G1 @ (inputs(t + self.dt, a) - u0)

    def linear_step(self):
        return LinearStep(self.Phi, (0.0, 1.0), (self.G0 - self.G1, self.G1))

    def stage_scheme(self):
        # u_0 = u(t, x);  a = Phi x + G0 u_0;  u_1 = u(t + h, a);  x+ = a + G1 (u_1 - u_0)
        predictor = np.hstack([self.Phi, self.G0])
        final = np.hstack([np.eye(self.A.shape[0]), -self.G1, self.G1])
        return StageScheme((0.0, 1.0), (None, predictor), final, final_base=1)

    def amplification(self, lam):
        return abs(np.exp(lam * self.dt))


@lru_cache(maxsize=64)
def _phi_blocks(a_bytes: bytes, b_bytes: bytes, n: int, m: int, h: float):
    """e^{hA} and h phi_k(hA) B for k = 1, 2, 3 from one exponential (cached per h).

    ``expm([[hA, hB, 0, 0], [0, 0, I, 0], [0, 0, 0, I], [0, 0, 0, 0]])`` has the
    top block row ``[e^{hA}, h phi_1 B, h phi_2 B, h phi_3 B]`` with
    ``phi_k(z) = (e^z - sum_{j<k} z^j/j!) / z^k`` (works for singular A: the
    rigid-body mode).
    """
    A = np.frombuffer(a_bytes).reshape(n, n)
    B = np.frombuffer(b_bytes).reshape(n, m)
    M = np.zeros((n + 3 * m, n + 3 * m))
    M[:n, :n] = h * A
    M[:n, n : n + m] = h * B
    M[n : n + m, n + m : n + 2 * m] = np.eye(m)
    M[n + m : n + 2 * m, n + 2 * m :] = np.eye(m)
    E = scipy.linalg.expm(M)
    return tuple(E[:n, :n].copy() if k == 0 else E[:n, n + (k - 1) * m : n + k * m].copy() for k in range(4))


class ExponentialRK4(FixedStepIntegrator):
    """Exponential time differencing RK4 (Cox & Matthews 2002, ETDRK4).

    With ``N(t, x) = B u(t, x)``, ``E = e^{hA}``, ``E2 = e^{hA/2}`` and
    ``P = (h/2) phi_1(hA/2) B``::

        a  = E2 x + P u(t, x)
        b  = E2 x + P u(t + h/2, a)
        c  = E2 a + P (2 u(t + h/2, b) - u(t, x))
        x+ = E x + h [(phi_1 - 3 phi_2 + 4 phi_3) u(t, x)
                      + 2 (phi_2 - 2 phi_3) (u(t+h/2, a) + u(t+h/2, b))
                      + (4 phi_3 - phi_2) u(t + h, c)] B          (phi_k = phi_k(hA))

    The belt mode is integrated exactly (unconditionally stable for it, like
    ``exact`` and ``etd2``); smooth time- and state-dependent torques converge
    with order 4, so non-stiff scenes can take steps of several ms.
    """

    name = "etd4"
    order = 4

    def __init__(self, A, B, dt, **options):
        super().__init__(A, B, dt, **options)
        n, m = self.A.shape[0], self.B.shape[1]
        ab, bb = self.A.tobytes(), self.B.tobytes()
        self.E, hp1, hp2, hp3 = _phi_blocks(ab, bb, n, m, self.dt)
        self.E2, self.P, _, _ = _phi_blocks(ab, bb, n, m, 0.5 * self.dt)
        self.W0 = hp1 - 3.0 * hp2 + 4.0 * hp3
        self.W1 = 2.0 * (hp2 - 2.0 * hp3)
        self.W2 = 4.0 * hp3 - hp2

    def step(self, t, x, inputs):
        h = self.dt
        u0 = inputs(t, x)
        e2x = self.E2 @ x
        a = e2x + self.P @ u0
        ua = inputs(t + 0.5 * h, a)
        b = e2x + self.P @ ua
        ub = inputs(t + 0.5 * h, b)
        c = self.E2 @ a + self.P @ (2.0 * ub - u0)
        uc = inputs(t + h, c)
        return self.E @ x + self.W0 @ u0 + self.W1 @ (ua + ub) + self.W2 @ uc

    def linear_step(self):
        # time-only torque: u(a) = u(b) = u(t + h/2), u(c) = u(t + h)
        return LinearStep(self.E, (0.0, 0.5, 1.0), (self.W0, 2.0 * self.W1, self.W2))

    def stage_scheme(self):
        n, m = self.A.shape[0], self.B.shape[1]
        Z = np.zeros((n, m))
        stage_a = np.hstack([self.E2, self.P])  # [x, U0]
        stage_b = np.hstack([self.E2, Z, self.P])  # [x, U0, Ua]
        # c = E2 (E2 x + P U0) + P (2 Ub - U0)
        stage_c = np.hstack([self.E2 @ self.E2, self.E2 @ self.P - self.P, Z, 2.0 * self.P])
        final = np.hstack([self.E, self.W0, self.W1, self.W1, self.W2])
        return StageScheme((0.0, 0.5, 0.5, 1.0), (None, stage_a, stage_b, stage_c), final)

    def amplification(self, lam):
        return abs(np.exp(lam * self.dt))


@lru_cache(maxsize=256)
def _expm_at(a_bytes: bytes, n: int, tau: float) -> np.ndarray:
    """e^{tau A} (cached per tau: a Lawson method needs one per distinct stage offset)."""
    return scipy.linalg.expm(np.frombuffer(a_bytes).reshape(n, n) * tau)


class LawsonRungeKutta(FixedStepIntegrator):
    """Integrating-factor (Lawson) Runge-Kutta on a classical explicit tableau (C, A_tab, B_tab).

    The tableau is applied to ``v = e^{-tA} x``, whose equation
    ``v' = e^{-tA} B u(t, e^{tA} v)`` has no linear part; back in x::

        X_i = e^{c_i h A} x + h sum_{j<i} a_ij e^{(c_i - c_j) h A} B U_j,   U_j = u(t + c_j h, X_j)
        x+  = e^{h A} x + h sum_i b_i e^{(1 - c_i) h A} B U_i

    The belt mode is integrated exactly (unconditionally stable for it, like
    the ETD methods) and the torques with the tableau's classical order. The
    price of the transformation: the error constant grows with
    ``(h omega_n)^p`` (the transformed torque oscillates at the belt
    frequency), so these methods suit steps up to about ``h omega_n ~ 1``.
    """

    C: ClassVar[tuple]
    A_tab: ClassVar[tuple]
    B_tab: ClassVar[tuple]

    def __init__(self, A, B, dt, **options):
        super().__init__(A, B, dt, **options)
        n, h = self.A.shape[0], self.dt
        key = self.A.tobytes()

        def E(c):
            return np.eye(n) if c == 0.0 else _expm_at(key, n, c * h)

        C, s = self.C, len(self.C)
        #: per stage: (e^{c_i h A}, [h a_ij e^{(c_i - c_j) h A} B for j < i]) (zero blocks where a_ij = 0)
        self.stage_maps = tuple(
            (E(C[i]), tuple(h * self.A_tab[i][j] * (E(C[i] - C[j]) @ self.B) for j in range(i))) for i in range(s)
        )
        self.Phi = E(1.0)
        self.gains = tuple(h * self.B_tab[i] * (E(1.0 - C[i]) @ self.B) for i in range(s))

    def step(self, t, x, inputs):
        h, U = self.dt, []
        for i, (Ex, G) in enumerate(self.stage_maps):
            xi = Ex @ x
            for j, Gj in enumerate(G):
                if self.A_tab[i][j]:
                    xi = xi + Gj @ U[j]
            U.append(inputs(t + self.C[i] * h, xi))
        out = self.Phi @ x
        for bi, Gi, Ui in zip(self.B_tab, self.gains, U):
            if bi:
                out = out + Gi @ Ui
        return out

    def linear_step(self):
        merged: dict[float, np.ndarray] = {}
        for c, b, G in zip(self.C, self.B_tab, self.gains):
            if b:
                merged[float(c)] = merged.get(float(c), 0.0) + G
        nodes = tuple(sorted(merged))
        return LinearStep(self.Phi, nodes, tuple(merged[c] for c in nodes))

    def stage_scheme(self):
        stages = tuple(None if i == 0 and self.C[0] == 0.0 else np.hstack([Ex, *G]) for i, (Ex, G) in enumerate(self.stage_maps))
        return StageScheme(tuple(float(c) for c in self.C), stages, np.hstack([self.Phi, *self.gains]))

    def amplification(self, lam):
        return abs(np.exp(lam * self.dt))


class Lawson5(LawsonRungeKutta):
    """Lawson method on the Dormand-Prince 5(4) tableau (the 5th-order weights; no step control).

    Six torque samples per step; order 5 for smooth state-dependent torques,
    the belt mode exact. On the ``paper`` scene it reaches 4e-7 at a 10 ms
    step (docs/performance.md): the cheapest of the package's methods at
    errors of 1e-5 and below on smooth scenes.
    """

    name = "lawson5"
    order = 5
    C = (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0)
    A_tab = (
        (),
        (1 / 5,),
        (3 / 40, 9 / 40),
        (44 / 45, -56 / 15, 32 / 9),
        (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
        (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
    )
    B_tab = (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84)


# -------------------------------------------------------------- Runge-Kutta
class ExplicitRungeKutta(FixedStepIntegrator):
    """Explicit Runge-Kutta method given by its Butcher tableau (class attributes C, A_tab, B_tab)."""

    C: ClassVar[np.ndarray]
    A_tab: ClassVar[np.ndarray]
    B_tab: ClassVar[np.ndarray]

    def step(self, t, x, inputs):
        h = self.dt
        k = []
        for i in range(len(self.C)):
            xi = x
            for j in range(i):
                if self.A_tab[i, j]:
                    xi = xi + (h * self.A_tab[i, j]) * k[j]
            k.append(self.A @ xi + self.B @ inputs(t + self.C[i] * h, xi))
        out = x
        for bi, ki in zip(self.B_tab, k):
            if bi:
                out = out + (h * bi) * ki
        return out

    def _tableau_maps(self):
        """Stage states and the step as linear maps of x and the stage torques U_0 .. U_{s-1}.

        ``k_i = P_i x + sum_m Q_im U_m`` with the stage state
        ``x_i = x + h sum_j a_ij k_j = Px_i x + sum_m Qx_im U_m``; the step is
        ``x+ = Phi x + sum_m G_m U_m``. Returns (Px, Qx, Phi, G).
        """
        h, n, m, s = self.dt, self.A.shape[0], self.B.shape[1], len(self.C)
        P, Q, Pxs, Qxs = [], [], [], []
        for i in range(s):
            Px = np.eye(n) + h * sum((self.A_tab[i, j] * P[j] for j in range(i)), np.zeros((n, n)))
            Qx = [h * sum((self.A_tab[i, j] * Q[j][mm] for j in range(i)), np.zeros((n, m))) for mm in range(s)]
            Pxs.append(Px)
            Qxs.append(Qx)
            P.append(self.A @ Px)
            Q.append([self.A @ Qx[mm] + (self.B if mm == i else 0.0) for mm in range(s)])
        Phi = np.eye(n) + h * sum(self.B_tab[i] * P[i] for i in range(s))
        G = [h * sum(self.B_tab[i] * Q[i][mm] for i in range(s)) for mm in range(s)]
        return Pxs, Qxs, Phi, G

    def linear_step(self):
        _, _, Phi, G = self._tableau_maps()
        merged: dict[float, np.ndarray] = {}
        for mm in range(len(self.C)):
            merged[float(self.C[mm])] = merged.get(float(self.C[mm]), 0.0) + G[mm]
        nodes = tuple(sorted(merged))
        return LinearStep(Phi, nodes, tuple(merged[c] for c in nodes))

    def stage_scheme(self):
        # x_i = Px_i x + sum_{j<i} Qx_ij U_j,  U_i = u(t + c_i h, x_i);  x+ = Phi x + sum_j G_j U_j
        Pxs, Qxs, Phi, G = self._tableau_maps()
        stages = tuple(
            None if i == 0 and not self.A_tab[0].any() else np.hstack([Pxs[i], *Qxs[i][:i]])
            for i in range(len(self.C))
        )
        return StageScheme(tuple(float(c) for c in self.C), stages, np.hstack([Phi, *G]))

    def amplification(self, lam):
        z = lam * self.dt
        s = len(self.C)
        R = 1.0 + z * self.B_tab @ np.linalg.solve(np.eye(s) - z * self.A_tab, np.ones(s))
        return abs(R)


class ExplicitEuler(ExplicitRungeKutta):
    """x+ = x + h f(t, x). Order 1; |1 + h lambda| <= 1 needs damping: never stable on an undamped belt."""

    name = "euler"
    order = 1
    imag_axis_limit = 0.0
    C = np.array([0.0])
    A_tab = np.array([[0.0]])
    B_tab = np.array([1.0])


class RK4(ExplicitRungeKutta):
    """Classical 4th-order Runge-Kutta. Stable on the imaginary axis for h omega <= 2 sqrt(2)."""

    name = "rk4"
    order = 4
    imag_axis_limit = 2.0 * math.sqrt(2.0)
    C = np.array([0.0, 0.5, 0.5, 1.0])
    A_tab = np.array([[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1.0, 0]], dtype=float)
    B_tab = np.array([1, 2, 2, 1], dtype=float) / 6.0


class SymplecticEuler(FixedStepIntegrator):
    """Semi-implicit (symplectic) Euler for the second-order system, velocity first.

    ``omega+ = omega + h a(t, phi, omega)``, ``phi+ = phi + h omega+``, with the
    state ordered [angles, speeds]. Order 1 (2 for the phase error of an
    undamped oscillator, whose energy it keeps bounded); stable for
    h omega_n < 2.
    """

    name = "symplectic_euler"
    order = 1
    imag_axis_limit = 2.0

    def __init__(self, A, B, dt, **options):
        super().__init__(A, B, dt, **options)
        self.half = self.A.shape[0] // 2

    def step(self, t, x, inputs):
        h, n2 = self.dt, self.half
        acc = (self.A @ x + self.B @ inputs(t, x))[n2:]
        w = x[n2:] + h * acc
        return np.concatenate([x[:n2] + h * w, w])

    def linear_step(self):
        h, n, n2 = self.dt, self.A.shape[0], self.half
        L, BL = self.A[n2:], self.B[n2:]  # acceleration rows
        Phi = np.zeros((n, n))
        Phi[n2:] = np.eye(n)[n2:] + h * L
        Phi[:n2] = np.eye(n)[:n2] + h * Phi[n2:]
        G = np.vstack([h * h * BL, h * BL])
        return LinearStep(Phi, (0.0,), (G,))

    def stage_scheme(self):
        # u_0 = u(t, x);  x+ = Phi x + G u_0 (the velocity-first update written as one affine map)
        step = self.linear_step()
        return StageScheme((0.0,), (None,), np.hstack([step.Phi, step.gains[0]]))

    def amplification(self, lam):
        # Mode as the oscillator q'' + 2 zeta w q' + w^2 q = 0 with eigenvalue lam.
        w2, two_zw = abs(lam) ** 2, -2.0 * lam.real
        h = self.dt
        M = np.array([[1.0 - h * h * w2, h * (1.0 - h * two_zw)], [-h * w2, 1.0 - h * two_zw]])
        return float(np.max(np.abs(np.linalg.eigvals(M))))


class Trapezoidal(FixedStepIntegrator):
    """Trapezoidal rule (Crank-Nicolson), implicit and A-stable, order 2.

    ``(I - h/2 A) x+ = (I + h/2 A) x + h/2 B (u(t, x) + u(t+h, x+))``. The
    linear part is solved exactly; a state-dependent torque at the new point
    is found by fixed-point iteration (contracting for h |du/dx| / I << 1),
    to ``tol`` relative, at most ``max_iter`` sweeps.
    """

    name = "trapezoidal"
    order = 2
    explicit = False

    def __init__(self, A, B, dt, tol: float = 1e-13, max_iter: int = 50):
        super().__init__(A, B, dt)
        n = self.A.shape[0]
        h = self.dt
        lhs = np.eye(n) - 0.5 * h * self.A
        self.Phi = np.linalg.solve(lhs, np.eye(n) + 0.5 * h * self.A)
        self.G = np.linalg.solve(lhs, 0.5 * h * self.B)
        self.tol, self.max_iter = tol, max_iter

    def step(self, t, x, inputs):
        u0 = inputs(t, x)
        free = self.Phi @ x + self.G @ u0
        u1 = u0
        for _ in range(self.max_iter):
            x1 = free + self.G @ u1
            u_new = inputs(t + self.dt, x1)
            if np.all(np.abs(u_new - u1) <= self.tol * (1.0 + np.abs(u_new))):
                return free + self.G @ u_new
            u1 = u_new
        raise IntegratorError(
            f"trapezoidal: fixed-point iteration for the state-dependent torque did not converge "
            f"at t={t:.6g} s in {self.max_iter} sweeps; reduce dt (now {self.dt:g} s)"
        )

    def linear_step(self):
        return LinearStep(self.Phi, (0.0, 1.0), (self.G, self.G))

    def stage_scheme(self):
        # u_0 = u(t, x);  x+ = Phi x + G u_0 + G u_1 with u_1 = u(t + h, x+) by fixed point
        return StageScheme(
            (0.0, 1.0), (None, None), np.hstack([self.Phi, self.G, self.G]), implicit=(self.tol, self.max_iter)
        )

    def amplification(self, lam):
        z = lam * self.dt
        return abs((1 + z / 2) / (1 - z / 2))


# ------------------------------------------------- compiled scalar loops
@dataclass(frozen=True)
class StageScheme:
    """A fixed-step method on x' = A x + B u(t, x) as affine maps between torque samples.

    With the stage torques ``U_i = u(t + nodes[i] h, X_i)`` (m values each)::

        X_i = stages[i] @ [x, U_0, ..., U_{i-1}]      (None: X_i = x)
        x+  = final @ [x, U_0, ..., U_{s-1}]          (final_base = j: [X_j, U_0, ...])

    Every method here has this form because A is constant: the Runge-Kutta
    stage sums collapse into fixed matrices (:meth:`ExplicitRungeKutta._tableau_maps`),
    the exponential methods are already written so. ``implicit = (tol,
    max_iter)`` marks the trapezoidal rule, whose last stage is evaluated at
    x+ itself and solved by fixed-point iteration as :meth:`Trapezoidal.step` does.
    ``final_base = j`` starts the last map from stage j's state instead of x
    (etd2: x+ = a + G1 (U_1 - U_0), 16 products instead of 32).
    """

    nodes: tuple
    stages: tuple
    final: np.ndarray
    implicit: tuple | None = None
    final_base: int | None = None


def _linear_expression(coefficients, names) -> str:
    """Source of sum_j c_j * names[j], dropping zero terms (floats printed exactly by repr)."""
    terms = []
    for c, v in zip(coefficients, names):
        c = float(c)
        if c == 0.0:
            continue
        terms.append(v if c == 1.0 else f"-{v}" if c == -1.0 else f"{c!r} * {v}")
    return " + ".join(terms) if terms else "0.0"


def compile_scalar_loop(
    scheme: StageScheme,
    wheel_map: np.ndarray,
    dt: float,
    name: str = "method",
    uses_angle: tuple = (True, True),
    sources: tuple = (None, None),
) -> Callable:
    """Generate and compile a Python loop that runs ``scheme`` on plain floats.

    Per step, numpy spends ~1 us per call on a 4-vector, more than the
    arithmetic itself; a closed-loop run of the belt model makes ~10 such
    calls per step. The loop below unrolls every matrix-vector product into
    float arithmetic with the matrix entries as literals (zeros dropped) and
    calls the torque profiles' :meth:`~belt_drive_ros.core.sources.TorqueProfile.scalar_torque`
    closures: 10-20x faster than looping over :meth:`FixedStepIntegrator.step`
    on the shipped scenes (docs/performance.md), and equal to it to rounding
    (same maths, another summation order).

    Parameters
    ----------
    scheme : the method's :class:`StageScheme`.
    wheel_map : (4, n) matrix W with ``[phi_M, omega_M, phi_3, omega_3] = W x``;
        the drive torque sees (phi_M, omega_M), the load (phi_3, omega_3).
    dt : step h [s] (stage times are ``t + c_i h``, as in :meth:`step`).
    uses_angle : (drive, load): False when that torque ignores its angle
        argument (:attr:`~belt_drive_ros.core.sources.TorqueProfile.uses_angle`);
        then only the speeds of the intermediate stages are computed (the
        stages exist only to feed the torques) and the angle passed is 0.0.
    sources : (drive, load): ``f(t, angle, speed) -> str`` giving the torque
        as a Python expression in those variable names
        (:meth:`~belt_drive_ros.core.sources.TorqueProfile.scalar_source`), inlined
        instead of a call (a call costs about as much as 5 multiply-adds), or
        None to call ``drive``/``load``.

    Returns
    -------
    ``loop(times, x, drive, load, limit) -> list`` integrating ``len(times) - 1``
    steps from state ``x`` (tuple) at ``times[0]`` with scalar torque
    functions ``drive(t, angle, speed)`` and ``load(...)``; returns the states
    after each step, flattened. Every 64 steps it checks that the state is
    finite and the speeds (second half of x) within ``limit``, and stops early
    (a shorter list) if not, for the caller to report. The generated source
    is the function's ``__source__`` attribute.
    """
    W = np.asarray(wheel_map, dtype=float)
    sources = tuple(f if f is not None and f("t", "a", "w") is not None else None for f in sources)
    n = W.shape[1]
    s = len(scheme.nodes)
    m = (scheme.final.shape[1] - n) // s
    if W.shape[0] != 4 or m != 2 or scheme.final.shape != (n, n + m * s):
        raise IntegratorError(f"{name}: scalar loop needs 4 wheel coordinates and 2 torques")
    xs = [f"x{r}" for r in range(n)]
    lines = [
        "def loop(times, x, drive, load, limit, abs=abs):",
        f'    """{name}: {n} states, {s} torque sample(s) per step (generated by compile_scalar_loop)."""',
        f"    {', '.join(xs)}, = x",
        "    out = []",
        "    extend = out.extend",
        "    for k in range(len(times) - 1):",
        "        t = times[k]",
    ]

    def torques(i, wheel_rows, inputs, at):
        """Lines computing u{i}_0, u{i}_1 from the wheel coordinates ``wheel_rows @ inputs``."""
        lines = [] if at == "t" else [f"        t{i} = {at}"]
        at = "t" if at == "t" else f"t{i}"
        for q, fn in enumerate(("drive", "load")):
            args = []
            for role, row in (("a", 2 * q), ("w", 2 * q + 1)):
                if role == "a" and not uses_angle[q]:
                    args.append("0.0")
                    continue
                expr = _linear_expression(wheel_rows[row], inputs)
                if sources[q] is not None and not expr.isidentifier():  # inlined: named once, used maybe twice
                    lines.append(f"        {role}{i}_{q} = {expr}")
                    expr = f"{role}{i}_{q}"
                args.append(expr)
            call = f"{fn}({at}, {args[0]}, {args[1]})" if sources[q] is None else f"({sources[q](at, args[0], args[1])})"
            lines.append(f"        u{i}_{q} = {call}")
        return lines

    def at(c):
        return "t" if c == 0.0 else f"t + {float(c * dt)!r}"

    n_explicit = s - 1 if scheme.implicit else s
    for i in range(n_explicit):
        lines.append(f"        # stage {i}: torques at t + {scheme.nodes[i]:g} h")
        if scheme.stages[i] is None:
            lines += torques(i, W, xs, at(scheme.nodes[i]))
        elif scheme.final_base == i:  # the whole stage state is needed again at the end of the step
            state = [f"s{i}_{r}" for r in range(n)]
            inputs = xs + [f"u{j}_{q}" for j in range(i) for q in range(m)]
            lines += [f"        {state[r]} = {_linear_expression(scheme.stages[i][r], inputs)}" for r in range(n)]
            lines += torques(i, W, state, at(scheme.nodes[i]))
        else:  # only its wheel coordinates: W @ stage map, straight from x and the earlier torques
            inputs = xs + [f"u{j}_{q}" for j in range(i) for q in range(m)]
            lines += torques(i, W @ scheme.stages[i], inputs, at(scheme.nodes[i]))
    known = xs + [f"u{j}_{q}" for j in range(n_explicit) for q in range(m)]
    if scheme.implicit:
        tol, max_iter = scheme.implicit
        last = s - 1
        free = [f"f{r}" for r in range(n)]
        guess = [f"u{last}_{q}" for q in range(m)]
        lines += [f"        # free response Phi x + G u_0, then u_{last} = u(t + h, x+) by fixed point"]
        lines += [f"        {free[r]} = {_linear_expression(scheme.final[r, : len(known)], known)}" for r in range(n)]
        lines += [  # first guess: the torque at the step's start, as Trapezoidal.step
            f"        g0, g1 = u{last - 1}_0, u{last - 1}_1",
            f"        for _ in range({int(max_iter)}):",
        ]
        state = [f"y{r}" for r in range(n)]
        gain = scheme.final[:, len(known) :]
        lines += [f"            {state[r]} = {free[r]} + {_linear_expression(gain[r], ['g0', 'g1'])}" for r in range(n)]
        lines += ["    " + line for line in torques(last, W, state, at(scheme.nodes[last]))]
        lines += [
            f"            if abs({guess[0]} - g0) <= {tol!r} * (1.0 + abs({guess[0]})) and "
            f"abs({guess[1]} - g1) <= {tol!r} * (1.0 + abs({guess[1]})):",
            "                break",
            f"            g0, g1 = {guess[0]}, {guess[1]}",
            "        else:",
            "            _not_converged(t)",
        ]
        lines += [f"        x{r} = {free[r]} + {_linear_expression(gain[r], guess)}" for r in range(n)]
    else:
        base = "x"
        if scheme.final_base is not None and scheme.stages[scheme.final_base] is not None:
            base = f"s{scheme.final_base}"
            known = [f"{base}_{r}" for r in range(n)] + known[n:]
        lines.append(f"        # end of step: x+ = final @ [{base}, U_0, ...]")
        lines.append(f"        {', '.join(xs)} = " + ", ".join(_linear_expression(scheme.final[r], known) for r in range(n)))
    half = n // 2
    finite = " and ".join([f"abs(x{r}) <= limit" for r in range(half, n)] + [f"x{r} - x{r} == 0.0" for r in range(half)])
    lines += [
        f"        extend(({', '.join(xs)},))",
        f"        if k & 63 == 63 and not ({finite}):",
        "            break",
        "    return out",
    ]
    source = "\n".join(lines) + "\n"
    key = (source, name, dt)
    if key not in _COMPILED_LOOPS:
        if len(_COMPILED_LOOPS) >= 256:  # sweeps over many steps: keep the cache small
            _COMPILED_LOOPS.clear()
        _COMPILED_LOOPS[key] = _compile_loop(source, scheme, dt, name)
    return _COMPILED_LOOPS[key]


#: generated loops by (source, method name, dt): a Simulator per run need not recompile (~0.5 ms).
_COMPILED_LOOPS: dict = {}


def _compile_loop(source: str, scheme: StageScheme, dt: float, name: str) -> Callable:
    def _not_converged(t):
        raise IntegratorError(
            f"{name}: fixed-point iteration for the state-dependent torque did not converge "
            f"at t={t:.6g} s in {scheme.implicit[1]} sweeps; reduce dt (now {dt:g} s)"
        )

    namespace = {"_not_converged": _not_converged}
    exec(compile(source, f"<{name} scalar loop>", "exec"), namespace)
    loop = namespace["loop"]
    loop.__source__ = source
    return loop


# ------------------------------------------------------------------ scipy
class ScipyAdaptive(Integrator):
    """A ``scipy.integrate`` adaptive solver advanced to each output time.

    The solver object persists across steps while the caller continues from
    the state it returned with the same torque it saw there; otherwise (a
    reset, a changed state, a torque that jumped at the step boundary, such
    as a newly held ROS message) it restarts at ``t``, which is correct for a
    discontinuous input: the solver never integrates across the jump with
    the old torque.
    """

    explicit = True
    adaptive = True
    method: ClassVar[str] = ""

    def __init__(self, A, B, dt, rtol: float = 1e-6, atol: float = 1e-9, max_step: float = np.inf):
        super().__init__(A, B, dt)
        for nm, v in (("rtol", rtol), ("atol", atol)):
            if not (math.isfinite(v) and v > 0):
                raise IntegratorError(f"{self.name}.{nm}: must be > 0, got {v!r}")
        self.rtol, self.atol, self.max_step = float(rtol), float(atol), max_step
        self._solver = None
        self._last = None
        self._dense = None
        self.n_rhs = 0

    def reset(self):
        self._solver = None
        self._last = None

    def step(self, t, x, inputs):
        t_end = t + self.dt
        # Continue when the caller resumes where the last step ended. Its time may differ by
        # rounding (a grid t0 + k dt against the sum t + dt): that is still a continuation.
        if (
            self._solver is None
            or self._last is None
            or abs(self._last[0] - t) > 1e-9 * self.dt
            or not np.array_equal(self._last[1], x)
            or self._last[2] is not inputs
            or self._solver.t_bound < t_end
            or not np.array_equal(self._last[3], inputs(t, x))  # torque jumped (held message changed)
        ):
            A, B = self.A, self.B

            def rhs(tt, xx):
                self.n_rhs += 1
                return A @ xx + B @ inputs(tt, xx)

            cls = scipy.integrate._ivp.ivp.METHODS[self.method]
            kwargs = dict(rtol=self.rtol, atol=self.atol, max_step=self.max_step)
            if self.method in ("Radau", "BDF", "LSODA"):
                kwargs["jac"] = None
            # LSODA with t_bound = inf takes an infinite first step when the rhs is 0 at the start
            # (a drive at rest with a soft start); a finite horizon avoids it (restart beyond it).
            horizon = t + 1e4 * self.dt if self.method == "LSODA" else np.inf
            self._solver = cls(rhs, t, np.array(x, dtype=float), t_bound=horizon, **kwargs)
        solver = self._solver
        while solver.t < t_end:
            msg = solver.step()
            if solver.status == "failed":
                raise IntegratorError(f"{self.name}: solver failed at t={solver.t:.6g} s: {msg}")
        if solver.t == t_end:
            out = solver.y.copy()
        else:  # one interpolant per solver step, shared by the output times inside it
            if self._dense is None or self._dense[0] is not solver or self._dense[1] != solver.t:
                self._dense = (solver, solver.t, solver.dense_output())
            out = self._dense[2](t_end)
        self._last = (t_end, out.copy(), inputs, np.array(inputs(t_end, out), dtype=float))
        return out


def _scipy_class(method: str) -> type:
    return type(method, (ScipyAdaptive,), {"name": method, "method": method, "__doc__": f"scipy.integrate {method}."})


REGISTRY: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (Exact, ExponentialRK2, ExponentialRK4, Lawson5, ExplicitEuler, SymplecticEuler, RK4, Trapezoidal)
}
for _m in ("RK45", "DOP853", "Radau", "BDF", "LSODA"):
    REGISTRY[_m] = _scipy_class(_m)
ALIASES = {"zoh": "exact", "semi_implicit_euler": "symplectic_euler", "crank_nicolson": "trapezoidal"}

FIXED_STEP_METHODS = ("exact", "etd2", "etd4", "lawson5", "euler", "symplectic_euler", "rk4", "trapezoidal")
ADAPTIVE_METHODS = ("RK45", "DOP853", "Radau", "BDF", "LSODA")


def method_class(name: str) -> type[Integrator]:
    """Integrator class by name (or alias); the error lists the valid names."""
    name = ALIASES.get(name, name)
    try:
        return REGISTRY[name]
    except KeyError:
        raise IntegratorError(
            f"method: unknown integrator {name!r}; choose one of {', '.join(REGISTRY)}"
        ) from None


def make_integrator(name: str, A: np.ndarray, B: np.ndarray, dt: float, **options) -> Integrator:
    """Build integrator ``name`` for x' = A x + B u with step ``dt`` [s]."""
    return method_class(name)(A, B, dt, **options)


# ------------------------------------------------ vectorized open-loop runs
def propagate_linear(step: LinearStep, x0: np.ndarray, node_inputs: list[np.ndarray], chunk: int = 32) -> np.ndarray:
    """All states of x_{n+1} = Phi x_n + sum_j G_j u_j[n], vectorized in chunks.

    Parameters
    ----------
    step : LinearStep
    x0 : (n,) initial state.
    node_inputs : list of (N, m) arrays, ``u(t_n + c_j h)`` for each node j.
    chunk : block length L; within a block the forced response is one
        Toeplitz product, across blocks a short sequential recursion.

    Returns
    -------
    (N + 1, n) array of states x_0 ... x_N.
    """
    Phi = step.Phi
    n = Phi.shape[0]
    v = sum(u @ G.T for u, G in zip(node_inputs, step.gains))  # (N, n) forcing per step
    N = v.shape[0]
    out = np.empty((N + 1, n))
    out[0] = x0
    if N == 0:
        return out
    L = min(chunk, N)
    powers = np.empty((L + 1, n, n))
    powers[0] = np.eye(n)
    for k in range(1, L + 1):
        powers[k] = Phi @ powers[k - 1]
    # Toeplitz block T[k, j] = Phi^(k-j) for j <= k (forced response y_{k+1} = sum_j Phi^(k-j) v_j)
    T = np.zeros((L, n, L, n))
    for k in range(L):
        for j in range(k + 1):
            T[k, :, j, :] = powers[k - j]
    T = T.reshape(L * n, L * n)
    n_full = N // L
    x = np.array(x0, dtype=float)
    if n_full:
        V = v[: n_full * L].reshape(n_full, L * n)
        Y = (V @ T.T).reshape(n_full, L, n)  # forced responses of all blocks at once
        starts = np.empty((n_full, n))
        for c in range(n_full):  # sequential: only the block boundaries
            starts[c] = x
            x = powers[L] @ x + Y[c, -1]
        free = np.einsum("kij,cj->cki", powers[1:], starts)
        out[1 : n_full * L + 1] = (free + Y).reshape(n_full * L, n)
    for idx in range(n_full * L, N):  # remainder
        x = Phi @ x + v[idx]
        out[idx + 1] = x
    return out
