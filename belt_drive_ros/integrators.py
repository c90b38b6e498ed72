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

    def amplification(self, lam):
        return abs(np.exp(lam * self.dt))


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

    def linear_step(self):
        # k_i = P_i x + sum_m Q_im u_m, with x_i = x + h sum_j a_ij k_j.
        h, n, m, s = self.dt, self.A.shape[0], self.B.shape[1], len(self.C)
        P, Q = [], []
        for i in range(s):
            Px = np.eye(n) + h * sum((self.A_tab[i, j] * P[j] for j in range(i)), np.zeros((n, n)))
            Qx = [h * sum((self.A_tab[i, j] * Q[j][mm] for j in range(i)), np.zeros((n, m))) for mm in range(s)]
            P.append(self.A @ Px)
            Q.append([self.A @ Qx[mm] + (self.B if mm == i else 0.0) for mm in range(s)])
        Phi = np.eye(n) + h * sum(self.B_tab[i] * P[i] for i in range(s))
        merged: dict[float, np.ndarray] = {}
        for mm in range(s):
            G = h * sum(self.B_tab[i] * Q[i][mm] for i in range(s))
            merged[float(self.C[mm])] = merged.get(float(self.C[mm]), 0.0) + G
        nodes = tuple(sorted(merged))
        return LinearStep(Phi, nodes, tuple(merged[c] for c in nodes))

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

    def amplification(self, lam):
        z = lam * self.dt
        return abs((1 + z / 2) / (1 - z / 2))


# ------------------------------------------------------------------ scipy
class ScipyAdaptive(Integrator):
    """A ``scipy.integrate`` adaptive solver advanced to each output time.

    The solver object persists across steps while the caller continues from
    the state it returned; otherwise (a reset, a changed state) it restarts.
    A torque that changes at step boundaries (a held ROS message) therefore
    restarts it at each step, which is correct for a discontinuous input.
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
        self.n_rhs = 0

    def reset(self):
        self._solver = None
        self._last = None

    def step(self, t, x, inputs):
        t_end = t + self.dt
        if (
            self._solver is None
            or self._last is None
            or self._last[0] != t
            or not np.array_equal(self._last[1], x)
            or self._last[2] is not inputs
        ):
            A, B = self.A, self.B

            def rhs(tt, xx):
                self.n_rhs += 1
                return A @ xx + B @ inputs(tt, xx)

            cls = scipy.integrate._ivp.ivp.METHODS[self.method]
            kwargs = dict(rtol=self.rtol, atol=self.atol, max_step=self.max_step)
            if self.method in ("Radau", "BDF", "LSODA"):
                kwargs["jac"] = None
            self._solver = cls(rhs, t, np.array(x, dtype=float), t_bound=np.inf, **kwargs)
        solver = self._solver
        while solver.t < t_end:
            msg = solver.step()
            if solver.status == "failed":
                raise IntegratorError(f"{self.name}: solver failed at t={solver.t:.6g} s: {msg}")
        out = solver.y.copy() if solver.t == t_end else solver.dense_output()(t_end)
        self._last = (t_end, out.copy(), inputs)
        return out


def _scipy_class(method: str) -> type:
    return type(method, (ScipyAdaptive,), {"name": method, "method": method, "__doc__": f"scipy.integrate {method}."})


REGISTRY: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (Exact, ExponentialRK2, ExplicitEuler, SymplecticEuler, RK4, Trapezoidal)
}
for _m in ("RK45", "DOP853", "Radau", "BDF", "LSODA"):
    REGISTRY[_m] = _scipy_class(_m)
ALIASES = {"zoh": "exact", "semi_implicit_euler": "symplectic_euler", "crank_nicolson": "trapezoidal"}

FIXED_STEP_METHODS = ("exact", "etd2", "euler", "symplectic_euler", "rk4", "trapezoidal")
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
