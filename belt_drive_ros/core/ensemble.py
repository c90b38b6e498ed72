"""Many variants of one plant stepped together: the compiled loop over a variant axis (``docs/campaigns.md``,
"The ensemble, and what runs singly").

The variants share torque profiles, method, step and duration, not their parameters. :class:`Ensemble` steps them
with the single run's own plan (:meth:`~belt_drive_ros.core.stepper.Stepper.steps`), stage schemes built from the
stacked ``A`` (V, n, n) and ``B`` (V, n, m) (:func:`~belt_drive_ros.core.batch_expm.expm_stack`) and loop
(:func:`~belt_drive_ros.core.kernel_variants.variant_steps`), so ensemble and single runs agree bit for bit
(tests/test_ensemble.py). Covered: rigid and flexible models, any explicit fixed-step method; the rest
(:class:`EnsembleUnsupported`: slipping, implicit, adaptive, profiles without a data form) runs singly.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import BeltDriveError
from .integrators import FixedStepIntegrator, Integrator, method_class
from .model import ModelStack
from .stepper import SPEED_LIMIT, Plant, Stepper


class EnsembleUnsupported(BeltDriveError, ValueError):
    """These variants cannot be stepped together (the reason says why); run them singly."""


class Ensemble:
    """The V variants of ``models`` (a :class:`~belt_drive_ros.core.model.ModelStack`, rigid or flexible) stepped
    together with the torque profiles ``drive``, ``load``, the explicit fixed-step ``method`` at step ``dt`` [s]
    they share; :class:`EnsembleUnsupported` for what the ensemble does not cover (the module docstring)."""

    def __init__(self, models: ModelStack, drive, load, method: str, dt: float, method_options=None):
        if not len(models):
            raise EnsembleUnsupported("ensemble: no variants")
        cls = method_class(method)
        if not issubclass(cls, FixedStepIntegrator):
            raise EnsembleUnsupported(f"ensemble: {cls.name} is adaptive (a step size per variant)")
        self.method_class = cls
        self.models = models  # a ModelStack: the variants' matrices stacked
        self.method, self.dt = cls.name, float(dt)
        self.method_options = dict(method_options or {})
        self.A = np.ascontiguousarray(models.A, dtype=float)
        self.B = np.ascontiguousarray(models.B, dtype=float)
        self.n, self.m = self.B.shape[1:]
        self.plant = Plant(models.model(0), drive, load)  # the profiles, breakpoints and plan all variants share
        self.W = np.ascontiguousarray(models.W, dtype=float)  # (V, 4, n)
        self.drive, self.load = drive, load
        if None in self.plant.data:
            raise EnsembleUnsupported("ensemble: a torque profile without a data form (steps in Python)")
        self._loops: dict = {}
        self.status = np.zeros(len(models), dtype=np.int64)  # the compiled loop's, per variant (windows)
        self._loop(self.dt)  # also validates the options; implicit methods are refused here

    def __len__(self) -> int:
        return len(self.models)

    def _loop(self, h: float):
        """The kernel arrays of all variants for a step of ``h`` [s] (cached per length; see the module docstring)."""
        from .kernel_loop import KernelLoop

        cached = self._loops.get(h)
        if cached is None:
            scheme = self.method_class(self.A, self.B, h, **self.method_options).scheme
            if scheme.implicit:
                raise EnsembleUnsupported(f"ensemble: {self.method} is implicit (a fixed-point iteration per variant)")
            if not KernelLoop.usable(scheme):
                raise EnsembleUnsupported(f"ensemble: {self.method}'s matrices are complex")
            if len(self._loops) >= 64:
                self._loops.clear()
            cached = self._loops[h] = KernelLoop(scheme, h, self.W, self.plant.uses_angle, *self.plant.data)
        return cached

    def run(self, x0: np.ndarray, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """``(times (N+1,), states (N+1, n, V))`` from states ``x0`` (V, n) at ``t0`` to ``t1`` [s]: a single run's
        knots (:meth:`~belt_drive_ros.core.stepper.Stepper.run`), variant v's run ``states[:, :, v]``. A variant that
        diverges gets non-finite states after its first bad one (:meth:`first_bad`); the others are unaffected."""
        return next(self.windows(x0, t0, t1, None))

    def windows(self, x0: np.ndarray, t0: float, t1: float, size: int | None = 256):
        """:meth:`run` in windows of at most ``size`` steps (None: one), ``(times (K+1,), states (K+1, n, V))`` each;
        consecutive windows share their end knot (together :meth:`run`'s floats; memory holds one window).

        ``self.status`` (V,) int64 (:data:`~belt_drive_ros.core.kernel_loop.OK` for a variant still running) is the
        compiled loop's, updated as the windows come: a variant whose knots went bad (non-finite, or a speed beyond
        :data:`~belt_drive_ros.core.stepper.SPEED_LIMIT`: the checks of :meth:`first_bad`) has another status from
        the window that holds its first bad knot on; the initial state ``x0`` is not checked."""
        from .kernel_variants import variant_steps

        x0 = np.asarray(x0, dtype=float)
        V = len(self.models)
        if x0.shape != (V, self.n):
            raise ValueError(f"ensemble: x0 must be ({V}, {self.n}), got {x0.shape}")
        self.status = status = np.zeros(V, dtype=np.int64)
        stepper = Stepper(self.plant, self.method, self.dt, self.method_options, origin=t0, integrator=_NoIntegrator())
        times, steps = stepper.steps(float(t0), float(t1))
        if not steps:  # t0 and t1 on one grid time (two knots, nothing to integrate) or no step at all
            yield times, np.repeat(x0.T[None], len(times), axis=0)
            return
        size = len(steps) if size is None else max(int(size), 1)
        # the kernel's layout, the variants last: each window is yielded as it is (a fresh array per window)
        knots = np.empty((min(size, len(steps)) + 1, self.n, V))
        knots[0] = x0.T
        piece = np.empty((2, self.n, V))

        def call(loop, t, j, lo, hi, where):
            variant_steps(t, where, j, lo, hi, SPEED_LIMIT, loop.reals, loop.tables, loop.ints, loop._dp, loop._lp, status)

        first, j, k = 0, 0, 0  # knot index of knots[0]; knots filled after it; next step
        while k < len(steps):
            a, e, whole, lo, hi, cuts = steps[k]
            if _plain(steps[k]):  # a run of whole steps: one call
                r = k + 1
                while r < len(steps) and r - k < knots.shape[0] - 1 - j and _plain(steps[r]):
                    r += 1
                call(self._loop(self.dt), np.array(times[first + j : first + j + r - k + 1], dtype=np.float64), j, lo, hi, knots)
                j, k = j + r - k, r
            else:  # a partial or clamped step, or one split at breakpoints: one call per piece
                edges = [a, *cuts, e]
                piece[0] = knots[j]
                for q in range(len(edges) - 1):
                    p, r = edges[q], edges[q + 1]
                    lo_q = lo if q == 0 else p
                    hi_q = hi if q == len(edges) - 2 else self.plant.left_of(r)
                    h = self.dt if whole and not cuts else r - p
                    call(self._loop(h), np.array([p, r]), 0, lo_q, hi_q, piece)
                    piece[0] = piece[1]
                j, k = j + 1, k + 1
                knots[j] = piece[0]
            if k == len(steps) or j == knots.shape[0] - 1:
                yield times[first : first + j + 1], knots[: j + 1]
                if k < len(steps):  # the next window starts at this window's last knot
                    last, knots = knots[j], np.empty_like(knots)
                    knots[0] = last
                    first, j = first + j, 0

    def first_bad(self, times: np.ndarray, states: np.ndarray, found: dict) -> dict:
        """``{variant: (time, state)}``: each variant's first bad sample (non-finite, or a speed beyond
        :data:`~belt_drive_ros.core.stepper.SPEED_LIMIT`); ``found``: what earlier windows of the run found
        (updated in place; a variant found there keeps its sample)."""
        half = states.shape[1] // 2
        with np.errstate(invalid="ignore"):
            bad = ~np.all(np.isfinite(states), axis=1) | np.any(np.abs(states[:, half:]) > SPEED_LIMIT, axis=1)  # (N+1, V)
        for v in np.flatnonzero(bad.any(axis=0)):
            if int(v) not in found:
                k = int(np.argmax(bad[:, v]))
                found[int(v)] = (float(times[k]), states[k, :, v].copy())
        return found

    def diverged_errors(self, found: dict) -> dict:
        """``{variant: SimulationDivergedError}`` of :meth:`first_bad`'s samples, as a single run reports them."""
        out = {}
        for v, (t, x) in sorted(found.items()):
            stepper = Stepper(Plant(self.models.model(v), self.drive, self.load), self.method, self.dt, self.method_options)
            out[v] = stepper.diverged_error(t, x)
        return out

    def inputs(self, times: np.ndarray, states: np.ndarray) -> np.ndarray:
        """Torques ``u`` (N+1, m, V) [N m] at the knots, as :meth:`Plant.input_array` gives a single run."""
        from .kernel_variants import knot_torques

        times = np.ascontiguousarray(times, dtype=float)
        shape = (len(times), states.shape[2])
        u = np.empty((shape[0], self.m, shape[1]))
        out, zeros = np.empty(shape), None
        for q, (data, uses) in enumerate(zip(self.plant.data, self.plant.uses_angle)):
            # the profile's formulas on all variants of a knot at once, as the variant loop's lanes evaluate them (what
            # profile.torque computes per sample); a profile that ignores its angle gets 0.0, as in the kernel's stages
            speed = np.ascontiguousarray(self._coordinate(states, 2 * q + 1))
            if uses:
                angle = np.ascontiguousarray(self._coordinate(states, 2 * q))
            else:
                angle = zeros = np.zeros(shape) if zeros is None else zeros
            knot_torques(data.kinds, data.params, data.tx, data.ty, times, angle, speed, out)
            u[:, q] = out
        return u

    def _coordinate(self, states: np.ndarray, r: int) -> np.ndarray:
        """Wheel coordinate ``r`` of W (phi_M, omega_M, phi_3, omega_3) at every knot: (N+1, V)."""
        out = weighted_columns(states, self.W[:, r, :].T)
        return out if out is not None else np.zeros(states[:, 0, :].shape)


def weighted_columns(block: np.ndarray, rows: np.ndarray):
    """``sum_k rows[k] * block[:, k, :]`` (block (N+1, K, V), rows (K, V): a weight per column and variant), summed
    from the left over the columns whose weights are not all zero; a column weighted 1.0 for every variant is taken
    as it is (None: every weight zero).

    For finite states the same floats as summing every column (a zero product adds nothing but the sign of a zero
    sum); a run whose states are not finite is a diverged one, reported and not used.
    """
    out = None
    for k in range(rows.shape[0]):
        w = rows[k]
        if not np.any(w):
            continue
        term = block[:, k, :] if np.all(w == 1.0) else w * block[:, k, :]
        out = term if out is None else out + term
    return out


def _plain(step) -> bool:
    """Whether a planned step is a whole step, neither split nor clamped (the kernel's run of steps)."""
    _, _, whole, lo, hi, cuts = step
    return whole and not cuts and lo == -math.inf and hi == math.inf


class _NoIntegrator(Integrator):
    """Stands in for the integrator of the planning stepper (the ensemble steps with its own batched schemes)."""

    name = "plan only"

    def __init__(self):  # nothing to build: the planning stepper never steps
        self.dt = math.nan
