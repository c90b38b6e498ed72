"""Stability guard: whether a fixed-step method is stable, predicted before a run (``docs/model.md``, "Numerics").

Per step a method multiplies the mode ``y' = lambda y`` by ``R(h lambda)``; stable when ``|R(h lambda)| <= 1`` for
every eigenvalue of the model's A, read off the method's own one-step map
(:meth:`~.integrators.FixedStepIntegrator.mode_growths`). State-dependent torques are not part of A: the accuracy
guard (:mod:`.accuracy`) checks the closed loop, the run's divergence check catches what they destabilise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Callable

import numpy as np

from .errors import UnstableStepError
from .integrators import REGISTRY, FixedStepIntegrator, method_class

#: |R| may exceed 1 by GROWTH_TOLERANCE * h * omega_n: rounding of R(0) = 1 and of the
#: eigenvalues (~1e-16 h |lambda|), but not Euler's genuine growth (h omega)^2 / 2.
GROWTH_TOLERANCE = 1e-12


@dataclass(frozen=True, eq=False, repr=False)
class StabilityReport:
    """Outcome of :func:`check_step`: ``stable``; the ``method`` and step ``dt`` [s] checked; ``omega_n`` the fastest
    mode's |lambda| [rad/s] (the belt mode when flexible), ``h_omega_n = dt omega_n`` [-]; ``growth`` max |R(h lambda)|
    over the eigenvalues [-] (> 1: unstable); ``limit`` the method's ``h omega_n`` boundary on an undamped oscillator
    (None: none); ``max_stable_dt`` the largest stable step [s] (inf: any; 0: none; None: adaptive), a value or a
    function (:func:`max_stable_step`) computed at its first read (a refusal names it, a stable check need not)."""

    stable: bool
    method: str
    dt: float
    omega_n: float
    h_omega_n: float
    growth: float
    limit: float | None
    max_stable_dt: float | None | Callable[[], float]

    def __getattribute__(self, name: str):
        value = object.__getattribute__(self, name)
        if name == "max_stable_dt" and callable(value):  # (made once; the same number for every reader)
            value = value()
            object.__setattr__(self, "max_stable_dt", value)
        return value

    def _values(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self))

    def __repr__(self) -> str:
        return f"StabilityReport({', '.join(f'{f.name}={getattr(self, f.name)!r}' for f in fields(self))})"

    def __eq__(self, other) -> bool:
        return self._values() == other._values() if type(other) is type(self) else NotImplemented

    def __hash__(self) -> int:
        return hash(self._values())

    def __reduce__(self):  # pickled and copied with its value (a function is not sent along)
        return (type(self), self._values())

    def describe(self) -> str:
        """One line for logs, diagnostics and errors."""
        state = "stable" if self.stable else "UNSTABLE"
        lim = "none" if self.limit is None else f"{self.limit:.4g}"
        return (
            f"{self.method} at dt={self.dt:.4g} s: {state} (h*omega_n={self.h_omega_n:.4g}, "
            f"boundary {lim}, growth/step {self.growth:.6g}, omega_n={self.omega_n:.4g} rad/s)"
        )


def _eigenvalues(A: np.ndarray) -> np.ndarray:
    """Eigenvalues of A with the rigid-body mode snapped to exactly 0.

    Without bearing damping the zero eigenvalue is defective (a Jordan block:
    angle grows linearly with speed) and comes out as +/-1e-8 numerically;
    |lambda| below 1e-7 of the fastest mode is that rigid-body mode.
    """
    lams = np.linalg.eigvals(A)
    scale = float(np.max(np.abs(lams))) or 1.0
    return np.where(np.abs(lams) <= 1e-7 * scale, 0.0, lams)


def spectral_radius(M: np.ndarray) -> float:
    """max |eigenvalue| of a one-step map, the rigid-body Jordan block at 1 (eigenvalues 1 +/- sqrt(eps)) snapped to 1."""
    return spectral_radii(np.asarray(M)[None])[0]


def spectral_radii(Ms: np.ndarray) -> list[float]:
    """:func:`spectral_radius` of each map of a stack ``Ms`` (k, n, n), finite, in one ``eigvals`` call: LAPACK's
    routine matrix by matrix, each as alone (a stack's eigenvalues are complex when any matrix's are: a real one
    then carries imaginary part 0, whose modulus is its absolute value, so each radius is the same float)."""
    mu = np.linalg.eigvals(Ms)
    return [float(r) for r in np.max(np.abs(np.where(np.abs(mu - 1.0) <= 1e-6, 1.0, mu)), axis=-1)]


def _growth(cls, A, B, dt, eigenvalues) -> float:
    if cls.second_order_form:
        # A partitioned method: per-eigenvalue oscillators are exact only for proportional
        # damping, so use the spectral radius of its one-step map.
        return spectral_radius(cls(A, B, dt).linear_step().Phi)
    return float(np.max(cls.mode_growths(eigenvalues, dt)))


#: Absolute rounding floor of a computed |eigenvalue| that is exactly 1 (a few eps).
ROUNDING_FLOOR = 1e-15


def _is_stable(growth: float, dt: float, omega: float) -> bool:
    return growth <= 1.0 + ROUNDING_FLOOR + GROWTH_TOLERANCE * dt * omega


def max_stable_step(A: np.ndarray, B: np.ndarray, method: str, upper: float = 1.0) -> float:
    """Largest step [s] for which ``method`` is stable on x' = A x (bisection on |R|).

    Returns ``inf`` for methods stable at any step up to ``upper`` and 0.0
    when no step is stable (Euler on an undamped belt).
    """
    cls = method_class(method)
    if not issubclass(cls, FixedStepIntegrator):
        return math.inf
    lams = _eigenvalues(A)
    omega = float(np.max(np.abs(lams))) or 1.0
    if _is_stable(_growth(cls, A, B, upper, lams), upper, omega):
        return math.inf
    # Smallest probe: a step far below any boundary of interest.
    lo, hi = 1e-6 / omega, upper
    if not _is_stable(_growth(cls, A, B, lo, lams), lo, omega):
        return 0.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if _is_stable(_growth(cls, A, B, mid, lams), mid, omega):
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-9 * hi:
            break
    return lo


#: reports already computed, by (A, B, method, dt): the same numbers give the same report
_REPORTS: dict = {}


def check_step(A: np.ndarray, B: np.ndarray, method: str, dt: float) -> StabilityReport:
    """Predict stability of ``method`` at step ``dt`` [s] on x' = A x + B u (cached per A, B, method, dt)."""
    A = np.asarray(A, dtype=float)
    key = (A.tobytes(), A.shape, None if B is None else np.asarray(B, dtype=float).tobytes(), method, float(dt))
    report = _REPORTS.get(key)
    if report is None:
        if len(_REPORTS) >= 256:
            _REPORTS.pop(next(iter(_REPORTS)))
        cls = method_class(method)
        lams = _eigenvalues(A)
        omega_n = float(np.max(np.abs(lams)))
        if not issubclass(cls, FixedStepIntegrator):
            report = StabilityReport(True, cls.name, dt, omega_n, dt * omega_n, 1.0, None, None)
        else:
            growth = _growth(cls, A, B, dt, lams)
            A_, B_ = A.copy(), None if B is None else np.array(B, dtype=float)  # (the caller's arrays may change)
            report = StabilityReport(_is_stable(growth, dt, omega_n), cls.name, dt, omega_n, dt * omega_n, growth,
                                     cls.imag_axis_limit, lambda: max_stable_step(A_, B_, method))  # fmt: skip
        _REPORTS[key] = report
    return report


def require_stable(A: np.ndarray, B: np.ndarray, method: str, dt: float) -> StabilityReport:
    """:func:`check_step`, raising :class:`UnstableStepError` that names a stable step or method."""
    report = check_step(A, B, method, dt)
    if report.stable:
        return report
    if report.max_stable_dt and math.isfinite(report.max_stable_dt):
        fix = f"use dt <= {0.9 * report.max_stable_dt:.3g} s (boundary {report.max_stable_dt:.4g} s)"
    else:
        fix = "no step is stable for this method on this belt"
    exact = ", ".join(repr(name) for name, cls in REGISTRY.items() if cls.fixed_step and cls.exact_linear)
    error = UnstableStepError(f"{report.describe()}; {fix}, or a method exact for the belt mode ({exact}): stable at any step")
    error.stability = report  # a caller that knows the closed loop names a step both guards accept instead
    raise error
