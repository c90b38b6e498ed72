"""Integrators behind one step protocol, chosen by name from one registry.

Every integrator advances ``x' = A x + B u(t, x)`` by one step::

    x_next = integrator.step(t, x, inputs)      # inputs(t, x) -> u [N m]

A fixed-step method is written once, as data: its :class:`StageScheme`
(affine maps between torque samples; a Runge-Kutta method gives only its
Butcher tableau). Derived from it (:mod:`belt_drive_ros.core.stage_scheme`):
:meth:`~FixedStepIntegrator.step` on numpy arrays, the compiled loop's
arrays (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`), the linear
one-step map ``x_{n+1} = Phi x_n + sum_j G_j u(t_n + c_j h)`` for a torque of
time only (:meth:`~FixedStepIntegrator.linear_step`) and each mode's growth
per step (:meth:`~FixedStepIntegrator.mode_growths`, the stability guard's).

:data:`REGISTRY` maps names to classes; each carries ``name``, ``order``,
``fixed_step``, ``exact_linear`` (the linear belt mode integrated exactly:
unconditionally stable for it) and a one-line ``summary``, which the CLI
help, the node's ``method`` parameter and the stability guard read
(:func:`describe_methods`). A new method is one class under :func:`register`.
"""

from __future__ import annotations

import math
import threading
from functools import lru_cache
from typing import Callable, ClassVar

import numpy as np

from . import stage_scheme as _scheme
from .batch_expm import expm_stack  # one routine for one model and a stack of variants: bit-identical matrices
from .errors import IntegratorError
from .identity_cache import built_once
from .stage_scheme import LinearStep, StageScheme

__all__ = [
    "ADAPTIVE_METHODS", "ALIASES", "FIXED_STEP_METHODS", "REGISTRY", "FixedStepIntegrator", "Integrator",
    "LinearStep", "StageScheme", "describe_methods", "make_integrator", "method_class",
    "register",
]  # fmt: skip

Inputs = Callable[[float, np.ndarray], np.ndarray]

#: name -> integrator class, in the order help texts list them (filled by :func:`register`).
REGISTRY: dict[str, type["Integrator"]] = {}
ALIASES = {"zoh": "exact", "semi_implicit_euler": "symplectic_euler", "crank_nicolson": "trapezoidal"}


def register(cls: type["Integrator"]) -> type["Integrator"]:
    """Class decorator: make the method available by its ``name`` everywhere a method is chosen."""
    if not cls.name or not cls.summary or cls.name in REGISTRY:
        raise TypeError(f"{cls.__name__}: a registered method needs a new name and a summary")
    REGISTRY[cls.name] = cls
    return cls


class Integrator:
    """Protocol: ``step(t, x, inputs) -> x_next`` over a step ``dt`` [s].

    Class attributes (the registry entry): ``name``; ``order`` (None:
    adaptive); ``fixed_step``; ``exact_linear`` (the linear belt mode is
    integrated exactly); ``summary`` (one line for help texts).
    """

    name: ClassVar[str] = ""
    order: ClassVar[int | None] = None
    fixed_step: ClassVar[bool] = False
    exact_linear: ClassVar[bool] = False
    summary: ClassVar[str] = ""
    explicit: ClassVar[bool] = True
    #: h*omega_n stability boundary for an undamped oscillator (None: no limit).
    imag_axis_limit: ClassVar[float | None] = None
    #: ``dt`` may be a (K, 1, 1) stack of steps on ``A``, ``B`` stacked alike (K, ...): the matrices of K integrators
    #: at once, slice k the floats of the integrator of step k (:func:`stacked_scheme`)
    stacked_steps: ClassVar[bool] = False

    def __init__(self, A: np.ndarray, B: np.ndarray, dt: float, **options):
        stack = isinstance(dt, np.ndarray) and dt.ndim == 3 and dt.shape[1:] == (1, 1) and self.stacked_steps
        ok = (bool(np.all(np.isfinite(dt)) and np.all(dt > 0)) if stack
              else isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0)
        if not ok:
            raise IntegratorError(f"dt: must be a finite step > 0 s, got {dt!r}")
        if options:
            raise IntegratorError(f"{self.name}: unknown option(s) {', '.join(sorted(options))}")
        self.A = np.asarray(A)
        self.A = self.A.astype(complex if np.iscomplexobj(self.A) else float)
        self.B = np.asarray(B, dtype=float)
        self.dt = np.asarray(dt, dtype=float) if stack else float(dt)

    def step(self, t: float, x: np.ndarray, inputs: Inputs) -> np.ndarray:
        raise NotImplementedError

    def reset(self) -> None:
        """Forget any history (adaptive solvers restart at the next step)."""


class FixedStepIntegrator(Integrator):
    """A one-step method of fixed step, defined by its :meth:`stage_scheme`; the rest is derived.

    A subclass builds its matrices in ``__init__`` and returns them as a
    :class:`StageScheme`. ``second_order_form``: the method uses the state's
    split into [angles, speeds] (symplectic Euler), so a mode's growth is
    taken on an oscillator, not on the scalar equation y' = lambda y.
    """

    fixed_step = True
    second_order_form: ClassVar[bool] = False

    def stage_scheme(self) -> StageScheme:
        """The step as affine maps between torque samples (see :class:`StageScheme`)."""
        raise NotImplementedError

    @property
    def scheme(self) -> StageScheme:
        """:meth:`stage_scheme`, built once per integrator."""
        cached = self.__dict__.get("_scheme")
        if cached is None:
            cached = self._scheme = self.stage_scheme()
        return cached

    def step(self, t, x, inputs):
        return _scheme.step(self.scheme, self.dt, t, np.asarray(x, dtype=float), inputs, self.name)

    def linear_step(self) -> LinearStep:
        """``x+ = Phi x + sum_j G_j u(t + c_j h)`` for a torque of time only (from the scheme)."""
        return _scheme.linear_step(self.scheme, self.A.shape[0])

    @classmethod
    def prepare(cls, A, B, steps, **options) -> None:
        """Compute the matrices of the method's integrators on ``(A, B)`` for many ``steps`` [s] at once, held for
        their construction (one stacked matrix exponential where the method has one; else nothing to do)."""

    @classmethod
    def mode_growths(cls, lams, dt: float) -> np.ndarray:
        """|growth factor| per step of step ``dt`` [s] of each mode with continuous eigenvalue ``lams[i]`` [1/s].

        Read off the method's own one-step map (:meth:`linear_step`) on the
        smallest system with those modes, all at once: ``y_i' = lam_i y_i``
        (A diagonal, so Phi is diagonal with ``R(h lam_i)``: the stability
        polynomial of a Runge-Kutta method, ``e^{h lam_i}`` of an exponential
        one), or for a ``second_order_form`` method the oscillators
        ``q_i'' - 2 Re(lam_i) q_i' + |lam_i|^2 q_i = 0`` (spectral radius of
        each 2x2 block).
        """
        lams = np.asarray(lams, dtype=complex).ravel()
        k = lams.size
        if cls.second_order_form:
            A = np.zeros((2 * k, 2 * k))
            A[:k, k:] = np.eye(k)
            A[k:, :k] = np.diag(-np.abs(lams) ** 2)
            A[k:, k:] = np.diag(2.0 * lams.real)
            Phi = cls(A, np.zeros((2 * k, 1)), dt).linear_step().Phi
            blocks = [Phi[np.ix_((i, k + i), (i, k + i))] for i in range(k)]
            return np.array([np.max(np.abs(np.linalg.eigvals(block))) for block in blocks])
        A = np.diag(lams if np.any(lams.imag) else lams.real)
        Phi = cls(A, np.zeros((k, 1)), dt).linear_step().Phi
        return np.abs(np.diag(Phi))


def describe_methods() -> str:
    """One line per registered method: name, order, and its summary (for help texts)."""
    lines = []
    for name, cls in REGISTRY.items():
        order = f"order {cls.order}" if cls.order else "adaptive"
        lines.append(f"  {name:<17s}{order:<9s}{cls.summary}")
    return "\n".join(lines)


# ------------------------------------------------------------- exponential
def _key(a: np.ndarray) -> tuple:
    a = np.ascontiguousarray(a)
    return (a.tobytes(), a.dtype.str, a.shape)


def _unkey(key: tuple) -> np.ndarray:
    data, dtype, shape = key
    return np.frombuffer(data, dtype=dtype).reshape(shape)


def _hcat(*blocks) -> np.ndarray:
    """Blocks side by side (last axis), broadcast over any leading batch axes (a stack of variants' matrices)."""
    if all(np.ndim(b) == 2 for b in blocks):  # one model (the common case): no broadcasting to set up
        return np.concatenate(blocks, axis=-1)
    batch = np.broadcast_shapes(*(np.shape(b)[:-2] for b in blocks))
    return np.concatenate([np.broadcast_to(b, batch + np.shape(b)[-2:]) for b in blocks], axis=-1)


def _expm_blocks_of(A: np.ndarray, B: np.ndarray, h: float):
    """Phi = e^{Ah}, G0 = int_0^h e^{As} ds B, G1 = int_0^h e^{A(h-s)} s ds B / h (A, B may carry batch axes)."""
    n, m = B.shape[-2:]
    M = np.zeros(A.shape[:-2] + (n + 2 * m, n + 2 * m), dtype=np.result_type(A, B))
    M[..., :n, :n] = A
    M[..., :n, n : n + m] = B
    M[..., n : n + m, n + m :] = np.eye(m)
    E = expm_stack(M * h)  # Van Loan: one exponential gives all three blocks
    return E[..., :n, :n].copy(), E[..., :n, n : n + m].copy(), E[..., :n, n + m :].copy() / h


#: matrices :meth:`_PerSystem.prepare` holds for the calls to come (all dropped when more would be held)
READY_SIZE = 8192


class _PerSystem:
    """``of(*arrays, h)`` cached per (arrays, h) for one system (2-D first array); a stack of variants is not cached.

    :meth:`prepare` computes ``of`` for many steps ``h`` of one system in one stacked call and holds each result
    for the first call that asks for it (the pieces of steps split by off-grid torque samples: one new length per
    piece). ``of`` is elementwise in ``h`` and :func:`~belt_drive_ros.core.batch_expm.expm_stack` gives each
    matrix of a stack what it gives that matrix alone, so a prepared result is the same floats as one computed
    alone.
    """

    def __init__(self, of, size: int = 64):
        self.of = of
        self._cached = lru_cache(maxsize=size)(lambda keys, h: of(*(_unkey(k) for k in keys), h))
        self._ready: dict = {}

    def __call__(self, *args):
        if args[0].ndim != 2 or np.ndim(args[-1]):  # a stack of systems or of steps: computed, not cached
            return self.of(*args)
        keys = tuple(_key(a) for a in args[:-1])
        held = self._ready.pop((keys, args[-1]), None)  # (a dict's pop is atomic: threads may share a system)
        return held if held is not None else self._cached(keys, args[-1])

    def prepare(self, *args) -> None:
        """Compute ``of(*args[:-1], h)`` for every ``h`` of ``args[-1]`` (steps [s]) at once and hold the results."""
        *arrays, hs = args
        hs = np.asarray(hs, dtype=float).ravel()
        if hs.size == 0:
            return
        keys = tuple(_key(a) for a in arrays)
        blocks = self.of(*(np.broadcast_to(a, (hs.size,) + a.shape) for a in arrays), hs[:, None, None])
        if len(self._ready) + hs.size > READY_SIZE:
            self._ready.clear()
        for k, h in enumerate(hs.tolist()):
            self._ready[(keys, h)] = tuple(b[k].copy() for b in blocks)


_per_system = _PerSystem


#: :func:`_expm_blocks_of`, cached per (A, B, h)
_expm_blocks = _per_system(_expm_blocks_of)


@register
class Exact(FixedStepIntegrator):
    """Exact zero-order-hold discretization: x+ = e^{Ah} x + Gamma u(t, x).

    ``Gamma = int_0^h e^{As} ds B``. Exact to rounding for a torque held
    constant over the step, for any h (unconditionally stable). A torque that
    varies within the step is sampled at its start: first order then.
    """

    stacked_steps = True

    name = "exact"
    order = 1
    exact_linear = True
    summary = "zero-order hold, Phi = expm(A h): exact for held torque at any step"

    def __init__(self, A, B, dt, **options):
        super().__init__(A, B, dt, **options)
        self.Phi, self.Gamma, _ = _expm_blocks(self.A, self.B, self.dt)

    @classmethod
    def prepare(cls, A, B, steps, **options) -> None:
        _expm_blocks.prepare(A, B, steps)

    def stage_scheme(self):
        # u_0 = u(t, x);  x+ = Phi x + Gamma u_0
        return StageScheme((0.0,), (None,), _hcat(self.Phi, self.Gamma))


@register
class ExponentialRK2(FixedStepIntegrator):
    """Exponential time differencing RK2 (Cox & Matthews 2002, ETD2RK).

    ``a = Phi x + G0 u_n``; ``x+ = a + G1 (u(t+h, a) - u_n)`` with
    ``G1 = int_0^h e^{A(h-s)} (s/h) ds B``. The belt mode is integrated
    exactly (unconditionally stable); the torque is taken as linear in time
    over the step, so piecewise-linear inputs are exact and smooth
    state-dependent torques converge with order 2.
    """

    stacked_steps = True

    name = "etd2"
    order = 2
    exact_linear = True
    summary = "exponential RK2 (Cox-Matthews): belt mode and piecewise-linear torque exact"

    def __init__(self, A, B, dt, **options):
        super().__init__(A, B, dt, **options)
        self.Phi, self.G0, self.G1 = _expm_blocks(self.A, self.B, self.dt)

    @classmethod
    def prepare(cls, A, B, steps, **options) -> None:
        _expm_blocks.prepare(A, B, steps)

    def stage_scheme(self):
        # u_0 = u(t, x);  a = Phi x + G0 u_0;  u_1 = u(t + h, a);  x+ = a + G1 (u_1 - u_0)
        predictor = _hcat(self.Phi, self.G0)
        final = _hcat(np.eye(self.A.shape[-1]), -self.G1, self.G1)
        return StageScheme((0.0, 1.0), (None, predictor), final, final_base=1)


def _phi_blocks_of(A: np.ndarray, B: np.ndarray, h: float):
    """e^{hA} and h phi_k(hA) B for k = 1, 2, 3 from one exponential (cached per h).

    ``expm([[hA, hB, 0, 0], [0, 0, I, 0], [0, 0, 0, I], [0, 0, 0, 0]])`` has the
    top block row ``[e^{hA}, h phi_1 B, h phi_2 B, h phi_3 B]`` with
    ``phi_k(z) = (e^z - sum_{j<k} z^j/j!) / z^k`` (works for singular A: the
    rigid-body mode).
    """
    n, m = B.shape[-2:]
    M = np.zeros(A.shape[:-2] + (n + 3 * m, n + 3 * m), dtype=np.result_type(A, B))
    M[..., :n, :n] = h * A
    M[..., :n, n : n + m] = h * B
    M[..., n : n + m, n + m : n + 2 * m] = np.eye(m)
    M[..., n + m : n + 2 * m, n + 2 * m :] = np.eye(m)
    E = expm_stack(M)
    return tuple(E[..., :n, :n].copy() if k == 0 else E[..., :n, n + (k - 1) * m : n + k * m].copy() for k in range(4))


#: :func:`_phi_blocks_of`, cached per (A, B, h)
_phi_blocks = _per_system(_phi_blocks_of)


@register
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

    stacked_steps = True

    name = "etd4"
    order = 4
    exact_linear = True
    summary = "exponential RK4 (Cox-Matthews ETDRK4): belt mode exact, large steps on smooth scenes"

    def __init__(self, A, B, dt, **options):
        super().__init__(A, B, dt, **options)
        self.E, hp1, hp2, hp3 = _phi_blocks(self.A, self.B, self.dt)
        self.E2, self.P, _, _ = _phi_blocks(self.A, self.B, 0.5 * self.dt)
        self.W0 = hp1 - 3.0 * hp2 + 4.0 * hp3
        self.W1 = 2.0 * (hp2 - 2.0 * hp3)
        self.W2 = 4.0 * hp3 - hp2

    @classmethod
    def prepare(cls, A, B, steps, **options) -> None:
        steps = np.asarray(steps, dtype=float)
        _phi_blocks.prepare(A, B, np.concatenate([steps, 0.5 * steps]))

    def stage_scheme(self):
        Z = np.zeros_like(self.P)
        stage_a = _hcat(self.E2, self.P)  # a = E2 x + P U0            [x, U0]
        stage_b = _hcat(self.E2, Z, self.P)  # b = E2 x + P Ua         [x, U0, Ua]
        # c = E2 a + P (2 Ub - U0) = E2 (E2 x + P U0) + P (2 Ub - U0)         [x, U0, Ua, Ub]
        stage_c = _hcat(self.E2 @ self.E2, self.E2 @ self.P - self.P, Z, 2.0 * self.P)
        final = _hcat(self.E, self.W0, self.W1, self.W1, self.W2)
        return StageScheme((0.0, 0.5, 0.5, 1.0), (None, stage_a, stage_b, stage_c), final)


def _expm_at_of(A: np.ndarray, taus: tuple) -> np.ndarray:
    """``e^{tau A}`` for each ``tau`` of ``taus``, stacked on a first axis (the products ``tau A`` as ``A * tau``).

    One system: one :func:`expm_stack` call for all offsets (its result per matrix is that matrix's alone, bit
    for bit). A stack of variants: one call per offset (a (offsets, variants, n, n) stack would multiply the
    memory of the largest ensemble chunk by the number of offsets)."""
    if A.ndim == 2:
        return expm_stack(A[None] * np.asarray(taus, dtype=float)[:, None, None])
    return np.stack([expm_stack(A * tau) for tau in taus])


#: e^{tau A} for a tuple of offsets, by (A, offsets) for one system (a Lawson method needs one per distinct stage
#: offset: all of a step's at once)
_EXPM_AT: dict = {}
_EXPM_AT_SIZE = 64
_EXPM_AT_LOCK = threading.Lock()


def _expm_at(A: np.ndarray, taus: tuple, halves: bool = False) -> np.ndarray:
    """:func:`_expm_at_of`, kept per (A, offsets) for one system (a stack of variants: not kept). ``halves``: on a
    miss, the offsets halved too, in the same :func:`expm_stack` call (its result per matrix is that matrix's alone,
    bit for bit), kept as their own entry: the accuracy guard's half-step runs of a Lawson method read them (``c h/2``
    is ``(c h)/2`` exactly, so its offsets are the same floats)."""
    if A.ndim != 2:
        return _expm_at_of(A, taus)
    key = (_key(A), taus)
    hit = _EXPM_AT.get(key)
    if hit is not None:
        return hit
    half = tuple(tau / 2.0 for tau in taus)
    both = halves and (key[0], half) not in _EXPM_AT
    exps = _expm_at_of(A, taus + half if both else taus)
    exps.flags.writeable = False  # (shared by every integrator of these numbers)
    kept = {key: exps[: len(taus)], **({(key[0], half): exps[len(taus) :]} if both else {})}
    with _EXPM_AT_LOCK:  # (threads: the oldest entry's eviction reads the dict another could change)
        for k, value in kept.items():
            if len(_EXPM_AT) >= _EXPM_AT_SIZE:
                _EXPM_AT.pop(next(iter(_EXPM_AT)), None)
            _EXPM_AT[k] = value
    return kept[key]


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

    exact_linear = True
    C: ClassVar[tuple]
    A_tab: ClassVar[tuple]
    B_tab: ClassVar[tuple]

    @classmethod
    def mode_growths(cls, lams, dt: float) -> np.ndarray:
        """|e^{h lam_i}|: the one-step map of a torque of time only is the scheme's ``e^{h A}`` (its final map's
        x block; the stage terms all go through B), here on the diagonal system of
        :meth:`FixedStepIntegrator.mode_growths` without the scheme's other exponentials (the same floats:
        ``expm_stack`` is per matrix)."""
        lams = np.asarray(lams, dtype=complex).ravel()
        A = np.diag(lams if np.any(lams.imag) else lams.real)
        return np.abs(np.diag(_expm_at(A, (1.0 * dt,))[0]))

    def stage_scheme(self):
        n, h = self.A.shape[-1], self.dt
        C, s = self.C, len(self.C)
        offsets = [C[i] for i in range(s)] + [C[i] - C[j] for i in range(s) for j in range(i)] + [1.0 - c for c in C]
        offsets = [c for c in dict.fromkeys(offsets) if c != 0.0]  # (distinct, in order)
        # every e^{c h A} in one call, and (a new system) e^{c h A / 2} with them: the guard's half-step runs'
        exps = _expm_at(self.A, tuple(c * h for c in offsets), halves=True)
        memo, memo_b = dict(zip(offsets, exps)), dict(zip(offsets, exps @ self.B))  # (and e^{c h A} B: one matmul)

        def E(c):
            return np.eye(n) if c == 0.0 else memo[c]

        def EB(c):
            return np.eye(n) @ self.B if c == 0.0 else memo_b[c]

        stages = tuple(
            None if i == 0 and C[0] == 0.0
            else _hcat(E(C[i]), *(h * self.A_tab[i][j] * EB(C[i] - C[j]) for j in range(i)))
            for i in range(s)
        )  # fmt: skip
        final = _hcat(E(1.0), *(h * self.B_tab[i] * EB(1.0 - C[i]) for i in range(s)))
        return StageScheme(tuple(float(c) for c in C), stages, final)


@register
class Lawson5(LawsonRungeKutta):
    """Lawson method on the Dormand-Prince 5(4) tableau (the 5th-order weights; no step control).

    Six torque samples per step; order 5 for smooth state-dependent torques,
    the belt mode exact. On the ``paper`` scene it reaches 4e-7 at a 10 ms
    step (docs/performance.md): the cheapest of the package's methods at
    errors of 1e-5 and below on smooth scenes.
    """

    name = "lawson5"
    order = 5
    summary = "integrating-factor Dormand-Prince 5: belt mode exact; cheapest at errors <= 1e-5"
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
    """Explicit Runge-Kutta method given by its Butcher tableau (class attributes C, A_tab, B_tab).

    With ``k_i = A x_i + B U_i`` and ``x_i = x + h sum_{j<i} a_ij k_j`` each
    stage state and the step are affine in x and the stage torques
    ``U_0 .. U_{s-1}``: ``x_i = Px_i x + sum_m Qx_im U_m``, ``k_i = P_i x +
    sum_m Q_im U_m``, ``x+ = Phi x + sum_m G_m U_m``; those matrices are the
    scheme.
    """

    stacked_steps = True

    C: ClassVar[np.ndarray]
    A_tab: ClassVar[np.ndarray]
    B_tab: ClassVar[np.ndarray]

    def stage_scheme(self):
        h, n, m, s = self.dt, self.A.shape[-1], self.B.shape[-1], len(self.C)
        dtype = self.A.dtype
        P, Q, stages = [], [], []
        for i in range(s):
            Px = np.eye(n, dtype=dtype) + h * sum((self.A_tab[i, j] * P[j] for j in range(i)), np.zeros((n, n), dtype))
            Qx = [h * sum((self.A_tab[i, j] * Q[j][mm] for j in range(i)), np.zeros((n, m), dtype)) for mm in range(s)]
            stages.append(None if i == 0 and not self.A_tab[0].any() else _hcat(Px, *Qx[:i]))
            P.append(self.A @ Px)
            Q.append([self.A @ Qx[mm] + (self.B if mm == i else 0.0) for mm in range(s)])
        Phi = np.eye(n, dtype=dtype) + h * sum(self.B_tab[i] * P[i] for i in range(s))
        G = [h * sum(self.B_tab[i] * Q[i][mm] for i in range(s)) for mm in range(s)]
        return StageScheme(tuple(float(c) for c in self.C), tuple(stages), _hcat(Phi, *G))


@register
class ExplicitEuler(ExplicitRungeKutta):
    """x+ = x + h f(t, x). Order 1; |1 + h lambda| <= 1 needs damping: never stable on an undamped belt."""

    name = "euler"
    order = 1
    summary = "explicit Euler; unstable on an undamped belt at any step"
    imag_axis_limit = 0.0
    C = np.array([0.0])
    A_tab = np.array([[0.0]])
    B_tab = np.array([1.0])


@register
class SymplecticEuler(FixedStepIntegrator):
    """Semi-implicit (symplectic) Euler for the second-order system, velocity first.

    ``omega+ = omega + h a(t, phi, omega)``, ``phi+ = phi + h omega+``, with the
    state ordered [angles, speeds]. Order 1 (2 for the phase error of an
    undamped oscillator, whose energy it keeps bounded); stable for
    h omega_n < 2.
    """

    stacked_steps = True

    name = "symplectic_euler"
    order = 1
    summary = "semi-implicit Euler (velocity first); stable for h omega_n < 2"
    imag_axis_limit = 2.0
    second_order_form = True

    def stage_scheme(self):
        # u_0 = u(t, x);  omega+ = omega + h (L x + B_w u_0);  q+ = q + h T omega+   (x = [q, omega])
        # T = A[:n2, n2:] is the kinematics block (q' = T omega: the identity for [phi_M, phi_3],
        # [[1, 0], [i, -1]] for the flexible model's [phi_M, delta]); A[:n2, :n2] must be 0.
        # Stacked matrices (a leading variant axis) are stepped alike.
        h, n = self.dt, self.A.shape[-1]
        n2 = n // 2
        if np.any(self.A[..., :n2, :n2]):
            raise ValueError("symplectic_euler: the state must be [coordinates, speeds] with q' = T omega")
        T = self.A[..., :n2, n2:]
        L, BL = self.A[..., n2:, :], self.B[..., n2:, :]  # acceleration rows
        Phi = np.zeros(self.A.shape, dtype=self.A.dtype)
        Phi[..., n2:, :] = np.eye(n)[n2:] + h * L
        Phi[..., :n2, :] = np.eye(n)[:n2] + h * (T @ Phi[..., n2:, :])
        G = np.concatenate([h * h * (T @ BL), h * BL], axis=-2)
        return StageScheme((0.0,), (None,), _hcat(Phi, G))


@register
class RK4(ExplicitRungeKutta):
    """Classical 4th-order Runge-Kutta. Stable on the imaginary axis for h omega <= 2 sqrt(2)."""

    name = "rk4"
    order = 4
    summary = "classical Runge-Kutta; stable for h omega_n <= 2 sqrt(2) (undamped)"
    imag_axis_limit = 2.0 * math.sqrt(2.0)
    C = np.array([0.0, 0.5, 0.5, 1.0])
    A_tab = np.array([[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1.0, 0]], dtype=float)
    B_tab = np.array([1, 2, 2, 1], dtype=float) / 6.0


@register
class Trapezoidal(FixedStepIntegrator):
    """Trapezoidal rule (Crank-Nicolson), implicit and A-stable, order 2.

    ``(I - h/2 A) x+ = (I + h/2 A) x + h/2 B (u(t, x) + u(t+h, x+))``. The
    linear part is solved exactly; a state-dependent torque at the new point
    is found by fixed-point iteration (contracting for h |du/dx| / I << 1),
    to ``tol`` relative, at most ``max_iter`` sweeps.
    """

    stacked_steps = True

    name = "trapezoidal"
    order = 2
    explicit = False
    summary = "implicit, A-stable (Crank-Nicolson); state-dependent torque by fixed point"

    def __init__(self, A, B, dt, tol: float = 1e-13, max_iter: int = 50):
        super().__init__(A, B, dt)
        self.tol, self.max_iter = tol, max_iter

    def stage_scheme(self):
        # u_0 = u(t, x);  x+ = Phi x + G u_0 + G u_1 with u_1 = u(t + h, x+) by fixed point
        n, h = self.A.shape[-1], self.dt
        lhs = np.eye(n) - 0.5 * h * self.A
        Phi = np.linalg.solve(lhs, np.eye(n) + 0.5 * h * self.A)
        G = np.linalg.solve(lhs, 0.5 * h * self.B)
        return StageScheme((0.0, 1.0), (None, None), _hcat(Phi, G, G), implicit=(self.tol, self.max_iter))


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
    #: name of the scipy.integrate.OdeSolver subclass (public API: scipy.integrate.RK45, ...)
    solver_name: ClassVar[str]
    #: the options' defaults: relative and absolute tolerance of each step's local error
    RTOL: ClassVar[float] = 1e-6
    ATOL: ClassVar[float] = 1e-9

    def __init__(self, A, B, dt, rtol: float = RTOL, atol: float = ATOL, max_step: float = np.inf):
        import scipy.integrate  # here, not at import: the registry is read by --help texts

        super().__init__(A, B, dt)
        #: the solver class, scipy.integrate.<name>
        self.solver_class = getattr(scipy.integrate, self.solver_name)
        self._lsoda = self.solver_class is scipy.integrate.LSODA
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

            kwargs = dict(rtol=self.rtol, atol=self.atol, max_step=self.max_step)
            # LSODA with t_bound = inf takes an infinite first step when the rhs is 0 at the start
            # (a drive at rest with a soft start); a finite horizon avoids it (restart beyond it).
            horizon = t + 1e4 * self.dt if self._lsoda else np.inf
            self._solver = self.solver_class(rhs, t, np.array(x, dtype=float), t_bound=horizon, **kwargs)
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


def _scipy_method(name: str, summary: str) -> type:
    """Register scipy's public solver class ``scipy.integrate.<name>`` under its own name."""
    doc = f"scipy.integrate.{name} advanced to each output time (options rtol, atol, max_step)."
    return register(type(name, (ScipyAdaptive,), {"name": name, "solver_name": name, "summary": summary, "__doc__": doc}))


_scipy_method("RK45", "scipy Runge-Kutta 5(4) reference (options rtol, atol)")
_scipy_method("DOP853", "scipy Dormand-Prince 8(5,3) reference (options rtol, atol)")
_scipy_method("Radau", "scipy implicit Radau IIA order 5 (options rtol, atol)")
_scipy_method("BDF", "scipy variable-order BDF (options rtol, atol)")
_scipy_method("LSODA", "scipy LSODA, Adams/BDF switching (options rtol, atol)")

#: registered names by kind (read from the classes' ``fixed_step``)
FIXED_STEP_METHODS = tuple(name for name, cls in REGISTRY.items() if cls.fixed_step)
ADAPTIVE_METHODS = tuple(name for name, cls in REGISTRY.items() if not cls.fixed_step)


def method_class(name: str) -> type[Integrator]:
    """Integrator class by name (or alias); the error lists the valid names."""
    name = ALIASES.get(name, name)
    try:
        return REGISTRY[name]
    except KeyError:
        raise IntegratorError(
            f"method: unknown integrator {name!r}; choose one of {', '.join(REGISTRY)}"
        ) from None


#: fixed-step integrators by (method, step, options, A, B): read-only once built (their matrices and stage
#: scheme), so every run of one model shares them; the least recently used of more than 64 is dropped
_FIXED: dict = {}


def prepare_integrators(name: str, A: np.ndarray, B: np.ndarray, steps, **options) -> None:
    """Ready the matrices of :func:`make_integrator`'s integrators ``name`` on ``(A, B)`` for every step of ``steps``
    [s] in one stacked call (:meth:`FixedStepIntegrator.prepare`): the same floats as each built alone."""
    cls = method_class(name)
    if issubclass(cls, FixedStepIntegrator) and np.ndim(A) == 2 and not np.iscomplexobj(A):
        cls.prepare(np.asarray(A, dtype=float), np.asarray(B, dtype=float), steps, **options)


def stacked_scheme(name: str, A: np.ndarray, B: np.ndarray, steps, **options) -> StageScheme | None:
    """The :class:`StageScheme` of method ``name`` on ``(A, B)`` for every step of ``steps`` [s] at once: its matrices
    carry a leading axis of ``len(steps)``, slice k the same floats as ``make_integrator(name, A, B, steps[k]).scheme``
    (elementwise in the step; the exponentials by :func:`~belt_drive_ros.core.batch_expm.expm_stack`, matrix by matrix;
    products and solves matrix by matrix). None for a method that is not built so (adaptive, Lawson) or a complex A."""
    cls = method_class(name)
    if not (issubclass(cls, FixedStepIntegrator) and cls.stacked_steps) or np.ndim(A) != 2 or np.iscomplexobj(A):
        return None
    hs = np.asarray(steps, dtype=float).reshape(-1, 1, 1)
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    K = hs.shape[0]
    return cls(np.broadcast_to(A, (K,) + A.shape), np.broadcast_to(B, (K,) + B.shape), hs, **options).scheme


def make_integrator(name: str, A: np.ndarray, B: np.ndarray, dt: float, **options) -> Integrator:
    """Build integrator ``name`` for x' = A x + B u with step ``dt`` [s].

    A fixed-step method on one model (2-D real ``A``) is built once per
    ``(name, dt, options, A, B)`` and shared (it holds only matrices; a run
    repeated on the same model skips its matrices and stage scheme). scipy's
    adaptive methods keep a solver's state: a new one each call.
    """
    cls = method_class(name)
    if not issubclass(cls, FixedStepIntegrator) or np.ndim(A) != 2 or np.iscomplexobj(A):
        return cls(A, B, dt, **options)
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    key = (name, float(dt), repr(sorted(options.items())), A.shape, B.shape, A.tobytes(), B.tobytes())
    return built_once(_FIXED, 64, (), lambda: cls(A, B, dt, **options), key)  # by value: no object to hold
