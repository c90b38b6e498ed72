"""A fixed-step method as data (:class:`StageScheme`) and the three ways it is run.

Every fixed-step method of the package on ``x' = A x + B u(t, x)`` is a
sequence of affine maps between torque samples (A is constant, so stage
sums collapse into fixed matrices). A method states that scheme once
(:meth:`~belt_drive_ros.core.integrators.FixedStepIntegrator.stage_scheme`);
this module derives from it

* :func:`step` -- one step on numpy arrays (state columns may be a matrix: the
  closed-loop maps of the accuracy probes and the forced response are read off it),
* :func:`linear_step` -- the one-step map ``x+ = Phi x + sum_j G_j u(t + c_j h)``
  for a torque of time only (the stability guard reads ``Phi``), and
* the compiled time loop's matrices (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .errors import IntegratorError

Inputs = Callable[[float, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class StageScheme:
    """A fixed-step method on x' = A x + B u(t, x) as affine maps between torque samples.

    With the stage torques ``U_i = u(t + nodes[i] h, X_i)`` (m values each)::

        X_i = stages[i] @ [x, U_0, ..., U_{i-1}]      (None: X_i = x)
        x+  = final @ [x, U_0, ..., U_{s-1}]          (final_base = j: [X_j, U_0, ...])

    Every method here has this form because A is constant: the Runge-Kutta
    stage sums collapse into fixed matrices, the exponential methods are
    already written so. ``implicit = (tol, max_iter)`` marks a method whose
    last stage is evaluated at x+ itself (the trapezoidal rule), solved by
    fixed-point iteration on U_{s-1} from the guess U_{s-2}, to ``tol``
    relative, at most ``max_iter`` sweeps. ``final_base = j`` starts the last
    map from stage j's state instead of x (etd2: x+ = a + G1 (U_1 - U_0), 16
    products instead of 32).
    """

    nodes: tuple
    stages: tuple
    final: np.ndarray
    implicit: tuple | None = None
    final_base: int | None = None


@dataclass(frozen=True)
class LinearStep:
    """One step of a method on x' = A x + B u(t): x+ = Phi x + sum_j gains[j] u(t + nodes[j] h)."""

    Phi: np.ndarray
    nodes: tuple
    gains: tuple


@dataclass(frozen=True)
class Guard:
    """A stop rule for a compiled loop: it stops after the first step whose end state has ``g(x) > 0``.

    ``g(x) = f(row . x) - (bound - quad (speed . x)^2)`` with ``f = abs`` when
    ``absolute`` else the identity. The slipping belt's switching functions
    have this form (``|Q| - Q_max(omega_M)`` with ``Q`` linear in the state and
    ``Q_max = 2 (F_0 - m' v^2) tanh(mu_eff beta / 2)``; ``-sigma s'`` with ``s'``
    linear), so a stick or slip phase runs in the compiled loop
    (:func:`~belt_drive_ros.core.kernel_loop.guard_array`) and only the step in
    which the switching function turns positive is redone with event
    location. The check costs a few multiply-adds per step.
    """

    row: tuple
    bound: float = 0.0
    absolute: bool = False
    speed: tuple | None = None
    quad: float = 0.0

    def value(self, x) -> float:
        """g(x) for one state (plain floats)."""
        v = sum(c * float(xi) for c, xi in zip(self.row, x))
        v = abs(v) if self.absolute else v
        bound = self.bound
        if self.speed is not None and self.quad:
            w = sum(c * float(xi) for c, xi in zip(self.speed, x))
            bound -= self.quad * w * w
        return v - bound


def not_converged(name: str, t: float, max_iter: int, dt: float) -> IntegratorError:
    """The error of an implicit stage whose fixed-point iteration failed (one message for every path)."""
    return IntegratorError(
        f"{name}: fixed-point iteration for the state-dependent torque did not converge "
        f"at t={t:.6g} s in {max_iter} sweeps; reduce dt (now {dt:g} s)"
    )


def affine(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``M @ v`` summed column by column from the left: ``((M[:, 0] v[0] + M[:, 1] v[1]) + ...)``, the order of
    the compiled loops' sums (a BLAS product may sum in another; ``cumsum`` is sequential). ``v`` may be (k, c)."""
    if np.ndim(v) == 2:
        return np.cumsum(M[:, :, None] * v[None, :, :], axis=1)[:, -1, :]
    return np.cumsum(M * v, axis=-1)[..., -1]


def step(scheme: StageScheme, dt: float, t: float, x: np.ndarray, inputs: Inputs, name: str = "method") -> np.ndarray:
    """One step of ``scheme`` (step ``dt`` [s]) from state ``x`` at time ``t`` [s] with torques ``inputs(t, x)`` [N m].

    Sums run column by column from the left (:func:`affine`), as in the compiled loop.
    """
    s = len(scheme.nodes)
    explicit = s - 1 if scheme.implicit else s
    states, U = [], []
    for i in range(explicit):
        M = scheme.stages[i]
        xi = x if M is None else affine(M, np.concatenate([x, *U]))
        states.append(xi)
        U.append(np.asarray(inputs(t + scheme.nodes[i] * dt if scheme.nodes[i] else t, xi), dtype=float))
    base = x if scheme.final_base is None else states[scheme.final_base]
    if not scheme.implicit:
        return affine(scheme.final, np.concatenate([base, *U]))
    tol, max_iter = scheme.implicit
    known = np.concatenate([base, *U])
    free = affine(scheme.final[:, : known.size], known)  # x+ without the implicit stage
    gain = scheme.final[:, known.size :]
    t_last = t + scheme.nodes[-1] * dt
    guess = U[-1]  # first guess: the previous stage's torque
    for _ in range(max_iter):
        u_new = np.asarray(inputs(t_last, free + affine(gain, guess)), dtype=float)
        if np.all(np.abs(u_new - guess) <= tol * (1.0 + np.abs(u_new))):
            return free + affine(gain, u_new)
        guess = u_new
    raise not_converged(name, t, max_iter, dt)


def linear_step(scheme: StageScheme, n: int) -> LinearStep:
    """The scheme's one-step map for a torque of time only: every U_i = u(t + c_i h) is then an input.

    ``x+ = final @ [base, U_0, ...]`` with ``base = x`` or stage j's affine
    state; samples at equal nodes merge, zero gains drop.
    """
    s = len(scheme.nodes)
    m = (scheme.final.shape[1] - n) // s
    full = np.zeros((n, n + m * s), dtype=scheme.final.dtype)
    full[:, n:] += scheme.final[:, n:]
    j = scheme.final_base
    if j is None or scheme.stages[j] is None:
        full[:, :n] += scheme.final[:, :n]
    else:
        full[:, : scheme.stages[j].shape[1]] += scheme.final[:, :n] @ scheme.stages[j]
    merged: dict[float, np.ndarray] = {}
    for i, c in enumerate(scheme.nodes):
        G = full[:, n + m * i : n + m * (i + 1)]
        merged[float(c)] = merged[float(c)] + G if float(c) in merged else G
    nodes = tuple(c for c in sorted(merged) if np.any(merged[c]))
    return LinearStep(full[:, :n].copy(), nodes, tuple(merged[c].copy() for c in nodes))
