"""Many variants of one plant stepped together: numpy over a variant axis.

A campaign runs thousands of variants of one scene that differ in their
parameters (belt stiffness, inertias, damping, ...) but share the torque
profiles, the method, the step and the duration. One run costs a few ms of
Python per variant (the stepper's compiled float loop); the same arithmetic
done for all variants at once costs a fraction of that per variant.

:class:`Ensemble` is a second executor of the one stepper's plan
(:meth:`~belt_drive_ros.core.stepper.Stepper.steps`: the same knots, the
same steps split and clamped at torque breakpoints) and of the method's one
:class:`~belt_drive_ros.core.stage_scheme.StageScheme`: the integrator class
builds the scheme from the *stacked* matrices ``A`` (V, n, n) and ``B``
(V, n, m) of the V variants (every method's ``stage_scheme`` broadcasts over
a leading batch axis), so each variant steps with exactly the matrices its
single run uses. Per step, with ``U_i`` the stage torques (one per variant)::

    X_i = stages[i] @ [x, U_0, ..., U_{i-1}]          (per variant: einsum over the variant axis)
    U_i = u(t + c_i h, W X_i)                          (the profiles' array formulas on (V,) speeds)
    x+  = final @ [x or X_j, U_0, ..., U_{s-1}]

with the variant axis last (contiguous). Torques are evaluated by the
profiles' array evaluation (:func:`~belt_drive_ros.core.kernel.profile_torque_array`),
the same function the single run's compiled loop calls. Each variant gets the
very floats of its single run:

* the same matrices: one exponential routine for one matrix and for a
  stack (:func:`~belt_drive_ros.core.batch_expm.expm_stack`: each matrix's
  result depends on that matrix alone), and numpy's stacked ``matmul``
  multiplies matrix by matrix;
* the same sums: ``einsum`` over the variant-last layout accumulates
  ``sum_k M[r, k] z[k]`` from k = 0 upwards, the order of the compiled
  loop (:func:`~belt_drive_ros.core.kernel.linear_steps`) and of
  :func:`~belt_drive_ros.core.stage_scheme.affine` (the numpy step);
* the same paths: every step (whole, partial, clamped at a breakpoint)
  computes only the torques' wheel coordinates ``(W S) z`` of the inner
  stages, as the compiled loop does.

This is the one stepping loop outside the kernel: the kernel run once per
variant was measured 2x slower per variant-step than numpy over the
variant axis (465 against 244 ns, ``lawson5`` on ``paper``), so the variant
axis stays here until the kernel takes it innermost.

So ensemble and single runs agree bit for bit in practice
(tests/test_ensemble.py asserts <= 1e-12 relative on every shipped scene,
every explicit method, states, inputs and every output). Not covered: the
vectorized open-loop path of a single run (time-only torques,
:func:`~belt_drive_ros.core.integrators.propagate_linear`), which sums in
blocks; there the two agree to rounding.

Covered: the rigid and flexible models with any explicit fixed-step method
(``exact``, ``etd2``, ``etd4``, ``lawson5``, ``euler``,
``symplectic_euler``, ``rk4``). Not covered (:class:`EnsembleUnsupported`;
:mod:`~belt_drive_ros.core.ensemble_run` runs those variants singly): the
slipping model (its mode switches differ per variant), the implicit
``trapezoidal`` (a fixed-point iteration per variant) and scipy's adaptive
methods (a step size per variant).
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


def _einsum(matrix: np.ndarray, vector: np.ndarray, out=None) -> np.ndarray:
    """Per variant ``matrix @ vector``: (r, k, V) x (k, V) -> (r, V)."""
    return np.einsum("rkv,kv->rv", matrix, vector, out=out)


class _BatchScheme:
    """One step of length ``h`` of a method for all variants, in the variant-last layout.

    As the single run's kernel loop: the inner stages compute only the wheel
    coordinates a torque reads (``rows`` of ``W S``), the stage that starts
    the final map its whole state and then its coordinates; whole, partial
    and clamped steps alike. Each sum runs from the left.
    """

    def __init__(self, scheme, h: float, W: np.ndarray, rows: tuple, n: int, m: int):
        self.nodes, self.h = scheme.nodes, h
        self.n, self.m = n, m
        self.base = scheme.final_base
        Wr = W[:, rows, :]  # (V, R, n)
        self.stages = []
        for i, S in enumerate(scheme.stages):
            if S is None:
                self.stages.append(("x", np.ascontiguousarray(Wr.transpose(1, 2, 0)), None))
            elif self.base == i:  # the whole stage state (needed again at the end of the step)
                self.stages.append(
                    ("full", np.ascontiguousarray(S.transpose(1, 2, 0)), np.ascontiguousarray(Wr.transpose(1, 2, 0)))
                )
            else:
                self.stages.append(("rows", np.ascontiguousarray((Wr @ S).transpose(1, 2, 0)), None))
        #: x+ = final @ [x or the base stage's state, U_0, ...] in one left-to-right sum (as the compiled loop)
        self.final = np.ascontiguousarray(scheme.final.transpose(1, 2, 0))
        self.from_base = self.base is not None and scheme.stages[self.base] is not None


class Ensemble:
    """V variants of one plant (same profiles, method, step) stepped together.

    Parameters
    ----------
    models : V linear models of one kind (rigid or flexible): a
        :class:`~belt_drive_ros.core.model.ModelStack` (matrices built at once
        from the variants' parameters) or a sequence of model objects.
    drive, load : the torque profiles all variants share.
    method : an explicit fixed-step method of the registry; dt : step [s];
        method_options : passed to it.

    Raises
    ------
    EnsembleUnsupported : for a method the ensemble does not cover (the
        module docstring), or models of different kinds.
    """

    def __init__(self, models, drive, load, method: str, dt: float, method_options=None):
        if not isinstance(models, ModelStack):
            models = list(models)
            if not models:
                raise EnsembleUnsupported("ensemble: no variants")
            kinds = {m.name for m in models}
            if len(kinds) != 1 or models[0].name not in ("rigid", "flexible"):
                raise EnsembleUnsupported(
                    f"ensemble: needs variants of one linear model (rigid or flexible), got {sorted(kinds)}"
                )
            models = ModelStack.of_models(models)
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
        self._torques = tuple(p.torque for p in (drive, load))
        rows = []
        for q, profile in enumerate((drive, load)):
            angle = 2 * q if profile.uses_angle else None
            speed = 2 * q + 1 if profile.state_dependent else None
            rows.append((angle, speed))
        used = sorted({r for pair in rows for r in pair if r is not None})
        self._rows = tuple(used)
        self._slot = [tuple(None if r is None else used.index(r) for r in pair) for pair in rows]
        self._schemes: dict = {}
        self._method_schemes: dict = {}
        self._scheme(self.dt)  # also validates the options; implicit methods are refused here

    def __len__(self) -> int:
        return len(self.models)

    def _scheme(self, h: float) -> _BatchScheme:
        """The batched scheme of a step of ``h`` [s] (cached per length)."""
        cached = self._schemes.get(h)
        if cached is None:
            scheme = self._method_schemes.get(h)
            if scheme is None:
                scheme = self.method_class(self.A, self.B, h, **self.method_options).scheme
                if scheme.implicit:
                    raise EnsembleUnsupported(f"ensemble: {self.method} is implicit (a fixed-point iteration per variant)")
                self._method_schemes[h] = scheme
            if len(self._schemes) >= 256:
                self._schemes.clear()
                self._method_schemes.clear()
            cached = self._schemes[h] = _BatchScheme(scheme, h, self.W, self._rows, self.n, self.m)
        return cached

    def run(self, x0: np.ndarray, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """``(times (N+1,), states (N+1, n, V))`` from states ``x0`` (V, n) at ``t0`` to ``t1`` [s].

        States are time-major with the variant axis last (as they were
        computed); variant v's run is ``states[:, :, v]`` (N+1, n).

        The knots are those of a single run on the grid ``t0 + k dt``
        (:meth:`~belt_drive_ros.core.stepper.Stepper.run`). A variant that
        diverges gets non-finite states from there on (:meth:`diverged`
        finds them); the others are unaffected.
        """
        return next(self.windows(x0, t0, t1, None))

    def windows(self, x0: np.ndarray, t0: float, t1: float, size: int | None = 256):
        """:meth:`run` in windows of at most ``size`` steps: yields ``(times (K+1,), states (K+1, n, V))``.

        Consecutive windows share their end knot (the last knot of one is the
        first of the next), so the windows together are :meth:`run`'s knots
        and states, the very same floats (one time loop, the same steps);
        memory holds one window, whatever the duration. ``size=None``: one
        window (:meth:`run`). The arrays are reused: a caller keeps copies.
        """
        x0 = np.asarray(x0, dtype=float)
        V = len(self.models)
        if x0.shape != (V, self.n):
            raise ValueError(f"ensemble: x0 must be ({V}, {self.n}), got {x0.shape}")
        stepper = Stepper(self.plant, self.method, self.dt, self.method_options, origin=t0, integrator=_NoIntegrator())
        times, steps = stepper.steps(float(t0), float(t1))
        size = len(times) - 1 if size is None else max(int(size), 1)
        out = np.empty((min(size, max(len(times) - 1, 1)) + 1, self.n, V))
        out[0] = x0.T
        if len(times) == 2 and not steps:  # t0 and t1 on one grid time: nothing to integrate
            out[1] = out[0]
            yield times, out[:2]
            return
        if not steps:
            yield times, out[:1]
            return
        s_max = max(len(self._scheme(self.dt).nodes), 1)
        Z = np.empty((self.n + self.m * s_max + self.m * 8, V))  # [x, U_0, U_1, ...]
        x = out[0]
        left_of = self.plant.left_of
        first, j = 0, 0  # knot index of out[0]; knots filled after it
        with np.errstate(all="ignore"):  # a diverging variant is reported afterwards
            for k, (a, e, whole, lo, hi, cuts) in enumerate(steps):
                if whole and not cuts and lo == -math.inf and hi == math.inf:  # the compiled loop's steps
                    x = self._step(self._scheme(self.dt), a, x, lo, hi, Z)
                elif not cuts:  # the stepper's special steps: a partial or clamped step
                    x = self._step(self._scheme(self.dt if whole else e - a), a, x, lo, hi, Z)
                else:
                    edges = [a, *cuts, e]
                    for q in range(len(edges) - 1):
                        p, r = edges[q], edges[q + 1]
                        lo_q = lo if q == 0 else p
                        hi_q = hi if q == len(edges) - 2 else left_of(r)
                        x = self._step(self._scheme(r - p), p, x, lo_q, hi_q, Z)
                j += 1
                out[j] = x
                if k == len(steps) - 1:
                    yield times[first : first + j + 1], out[: j + 1]
                elif j == len(out) - 1:
                    yield times[first : first + j + 1], out
                    out[0] = out[j]  # the next window starts at this window's last knot
                    first, j = first + j, 0

    def _step(self, sch: _BatchScheme, t: float, x: np.ndarray, lo: float, hi: float, Z: np.ndarray) -> np.ndarray:
        """One step of ``sch`` from states ``x`` (n, V) at ``t`` [s], torque times clamped to [lo, hi]."""
        n, m = self.n, self.m
        Z[:n] = x
        base_state = None
        for i, (kind, M, Wr) in enumerate(sch.stages):
            c = sch.nodes[i]
            ti = t + c * sch.h if c else t
            ti = lo if ti < lo else hi if ti > hi else ti
            K = n + m * i
            if kind == "x":
                coords = _einsum(M, Z[:n])
            elif kind == "full":
                base_state = _einsum(M, Z[:K])
                coords = _einsum(Wr, base_state)
            else:
                coords = _einsum(M, Z[:K])
            for q, torque in enumerate(self._torques):
                a_slot, w_slot = self._slot[q]
                angle = coords[a_slot] if a_slot is not None else 0.0
                speed = coords[w_slot] if w_slot is not None else 0.0
                Z[K + q] = torque(ti, angle, speed)
        K = n + m * len(sch.stages)
        if sch.from_base:
            Z[:n] = base_state
        return _einsum(sch.final, Z[:K])

    def diverged(self, times: np.ndarray, states: np.ndarray) -> dict:
        """``{variant: SimulationDivergedError}`` for every variant whose run left the finite, plausible range.

        The first bad sample (non-finite, or a speed beyond
        :data:`~belt_drive_ros.core.stepper.SPEED_LIMIT`) names the time, as a
        single run reports it.
        """
        return self.diverged_errors(self.first_bad(times, states))

    def first_bad(self, times: np.ndarray, states: np.ndarray, found: dict | None = None) -> dict:
        """``{variant: (time, state)}``: each variant's first bad sample (see :meth:`diverged`).

        ``found``: what earlier windows of the run found (updated in place;
        a variant found there keeps its sample), so the windows of
        :meth:`windows` give what one whole run gives.
        """
        found = {} if found is None else found
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
        t = np.asarray(times, dtype=float)[:, None]
        u = np.empty((len(times), self.m, states.shape[2]))
        for q, torque in enumerate(self._torques):
            angle, speed = (self._coordinate(states, r) for r in (2 * q, 2 * q + 1))
            u[:, q] = torque(t, angle, speed)
        return u

    def _coordinate(self, states: np.ndarray, r: int) -> np.ndarray:
        """Wheel coordinate ``r`` of W (phi_M, omega_M, phi_3, omega_3) at every knot: (N+1, V)."""
        out = None
        for j in range(self.n):
            w = self.W[:, r, j]
            if not np.any(w):
                continue
            term = states[:, j, :] if np.all(w == 1.0) else w * states[:, j, :]
            out = term if out is None else out + term
        return out if out is not None else np.zeros(states[:, 0, :].shape)


class _NoIntegrator(Integrator):
    """Stands in for the integrator of the planning stepper (the ensemble steps with its own batched schemes)."""

    name = "plan only"

    def __init__(self):  # nothing to build: the planning stepper never steps
        self.dt = math.nan
