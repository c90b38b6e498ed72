"""Runs of the slipping belt for the charts: cases, the event-located reference, run variants, errors, predicted steps.

One definition used by every chart that has a slipping scene
(``bench workprecision``, ``bench stability``, ``bench slip``).

Variants (``family``)
---------------------
* ``hybrid``: Coulomb friction, modes switched at located events, through the
  package's engine (:class:`~belt_drive_ros.core.slip_run.SlippingSimulator`,
  what ``belt-drive sim`` and the node run);
* ``no_location``: the same hybrid with the mode switched at the end of the
  step in which the switching function changed sign
  (:class:`~belt_drive_ros.benchmarks.slip_reference.HybridStepper` ``locate=False``, in Python);
* ``regularised``: ``Q = Q_max tanh(s' / v_eps)`` in series with the span
  (:class:`~belt_drive_ros.benchmarks.slip_reference.RegularisedFriction`), one
  smooth ODE stepped by the method with ``A_reg`` as its linear part and the
  contact force and slip speed as inputs. Its error includes the modelling
  error of the regularisation against Coulomb friction. Its stepping loop is
  numpy per step (not compiled): its CPU times are an upper bound.

Reference
---------
scipy DOP853 per mode with terminal events (rtol = atol = 1e-13,
:func:`~belt_drive_ros.benchmarks.slip_reference.reference_hybrid`), restarted at
every torque breakpoint, on the finest grid of a sweep; a run's grid must be a
subgrid of it.

Error (the work-precision chart's metric, :mod:`.common`)
----------------------------------------------------------
``e_speed = max |omega_M - omega_M,ref| / max |omega_M,ref|``,
``e_belt = max |T_b - T_b,ref| / max |T_b,ref|`` with the belt torque at
wheel 3 ``T_b = r_3 Q`` (the hybrid's ``Q`` by mode, the regularised
contact's ``Q`` for that model), ``error = max(e_speed, e_belt)``.

Failure
-------
**diverged**: a non-finite state or a speed beyond 1e5 rad/s (the engine's
``SimulationDivergedError``; the regularised loop's states turn NaN);
**failed**: the hybrid cannot make progress (chattering, ``SlipError``) or
another package error. Both are kept apart from runs that finish with a large
error.

Predicted largest stable step
-----------------------------
* ``guard``: :func:`~belt_drive_ros.core.stability.max_stable_step` on the
  stick mode (the flexible model's A): what the run's stability guard checks;
* ``slip mode``: the same on the slip mode's A (with ``c > 0`` it holds the
  span element's relaxation ``-k/c``; the accuracy guard,
  :func:`~belt_drive_ros.core.accuracy.check_slipping`, checks it with the
  friction limit's slope added);
* regularised: the method's one-step map on the regularised ODE linearized
  about states along the reference (``u = K y`` with ``K = du/dy`` by central
  differences of the torques, the contact force and the slip speed), stable
  while its spectral radius stays at most ``max(1, e^(h max Re lambda(J)))``,
  ``J = A_reg + B_reg K``; the smallest over the probes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..core.errors import BeltDriveError, SimulationDivergedError
from ..core.integrators import make_integrator
from ..core.model import FlexibleBeltModel
from ..core.params import BeltDriveParams
from ..core.simulate import Plant
from ..core.slip import SlippingBeltModel
from ..core.slip_run import SlippingSimulator
from ..core.sources import Constant, Sine, TorqueProfile
from ..core.stability import max_stable_step
from .common import cpu_time, relative_error
from .slip_reference import HybridStepper, RegularisedFriction, reference_hybrid, regularised_matrices


def one_step_stable(method: str, model: SlippingBeltModel, K: np.ndarray, h: float) -> bool:
    """True when ``method``'s one-step map at ``h`` [s] on the regularised ODE linearized with gain ``K``
    (``y' = A_reg y + B_reg K y``) grows no faster than its exact flow ``e^(h max Re lambda)``."""
    A_reg, B_reg = regularised_matrices(model)
    integ = make_integrator(method, A_reg, B_reg, h)
    M = np.column_stack([integ.step(0.0, e, lambda t, y: K @ y) for e in np.eye(5)])
    mu = np.linalg.eigvals(M)
    mu = np.where(np.abs(mu - 1.0) <= 1e-6, 1.0, mu)  # the angle and slip integrators' eigenvalue 1
    lam = float(np.max(np.real(np.linalg.eigvals(A_reg + B_reg @ K))))
    return float(np.max(np.abs(mu))) <= max(1.0, math.exp(h * lam)) + 1e-9


FAMILIES = ("hybrid", "no_location", "regularised")
#: DOP853 tolerances of the reference (rtol = atol).
REFERENCE_TOL = 1e-13
#: speed beyond which a run counts as diverged [rad/s] (as the engine's check)
SPEED_LIMIT = 1e5


@dataclass(frozen=True)
class SlipCase:
    """A slipping scene: parameters, torques, duration [s], initial state y0 (5,), own method and step [s]."""

    name: str
    params: BeltDriveParams
    drive: TorqueProfile
    load: TorqueProfile
    duration: float
    y0: tuple
    method: str = "etd4"
    dt: float = 1e-3

    @property
    def model(self) -> SlippingBeltModel:
        return SlippingBeltModel(self.params)

    def plant(self) -> Plant:
        return Plant(FlexibleBeltModel(self.params), self.drive, self.load)

    def with_duration(self, duration: float) -> "SlipCase":
        return replace(self, duration=float(duration))


def case_from_scene(scene, name: str | None = None) -> SlipCase:
    """The slipping case of a :class:`~belt_drive_ros.core.scene.Scene` (its torques, initial state, method, dt)."""
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    return SlipCase(name or scene.name, scene.params, scene.drive, scene.load, scene.duration, tuple(y0), scene.method, scene.dt)


def stick_slip_case() -> SlipCase:
    """Repeated stick-slip (``bench slip``): the ``truck_compressor`` belt with F_0 = 300 N, mu = 0.3
    (Q_max = 253 N), a constant 30 N m drive and a 15 +/- 10 N m, 8 Hz load on wheel 3 (peaks above
    r_3 Q_max = 17.7 N m), 0.3 s from rest: about a dozen events."""
    p = BeltDriveParams(mu=0.3, F_0=300.0)
    return SlipCase("stick_slip", p, Constant(30.0), Sine(mean=15.0, amplitude=10.0, frequency=8.0), 0.3,
                    (0.0,) * 5, "etd2", 5e-4)  # fmt: skip


def grid(case: SlipCase, dt: float) -> np.ndarray:
    """The run grid ``k dt`` over the case's duration."""
    n = int(round(case.duration / dt))
    return np.arange(n + 1) * dt


# ------------------------------------------------------------ reference
@dataclass
class SlipReference:
    """DOP853 with located events on the grid ``k dt`` (module docstring); read at any subgrid."""

    case: SlipCase
    dt: float
    time: np.ndarray
    omega_M: np.ndarray
    belt_torque: np.ndarray
    events: int

    def at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(omega_M, belt torque) at ``times`` (a subgrid of the reference grid)."""
        k = np.rint(np.asarray(times) / self.dt).astype(np.int64)
        if not np.allclose(k * self.dt, times, rtol=0, atol=1e-9 * self.dt) or k[-1] >= self.time.size:
            raise ValueError("run grid is not a subgrid of the reference grid")
        return self.omega_M[k], self.belt_torque[k]


def reference(case: SlipCase, dt: float) -> SlipReference:
    m, plant = case.model, case.plant()
    time = grid(case, dt)
    ref = reference_hybrid(m, plant.scalar_drive, plant.scalar_load, time, np.array(case.y0), breakpoints=plant.breakpoints,
                           rtol=REFERENCE_TOL, atol=REFERENCE_TOL)  # fmt: skip
    belt = case.params.r_3 * m.force(ref.states, ref.mode, ref.sigma)
    return SlipReference(case, dt, time, ref.states[:, 2].copy(), belt, len(ref.events))


# ----------------------------------------------------------------- runs
@dataclass
class SlipRun:
    """One run: ``status`` ok / diverged / failed: ..., CPU seconds of the stepping, outputs on its grid."""

    status: str
    cpu_s: float = math.nan
    time: np.ndarray | None = None
    omega_M: np.ndarray | None = None
    belt_torque: np.ndarray | None = None
    events: int = 0


def _runner(case: SlipCase, family: str, method: str, dt: float, v_eps: float) -> Callable[[], tuple]:
    """A function returning (time, omega_M, belt torque, events) of one run (set-up done here, outside the timing)."""
    m, plant = case.model, case.plant()
    y0 = np.array(case.y0, dtype=float)
    r3 = case.params.r_3
    if family == "hybrid":
        sim = SlippingSimulator(case.params, case.drive, case.load, method, dt, check_stability=False)

        def go():
            t, ys, modes, sigmas = sim.run(case.duration, y0)
            return t, ys[:, 2], r3 * m.force(ys, modes, sigmas), len(sim.events)

        return go
    time = grid(case, dt)
    if family == "no_location":
        hs = HybridStepper(m, plant.scalar_drive, plant.scalar_load, method, locate=False)

        def go():
            r = hs.run(time, y0, breakpoints=plant.breakpoints)
            return time, r.states[:, 2], r3 * m.force(r.states, r.mode, r.sigma), len(r.events)

        return go
    if family == "regularised":
        reg = RegularisedFriction(m, v_eps)

        def go():
            ys = reg.run(time, y0, plant.scalar_drive, plant.scalar_load, method, breakpoints=plant.breakpoints)
            if not np.all(np.isfinite(ys)):
                raise SimulationDivergedError("regularised run: non-finite state")
            return time, ys[:, 2], r3 * reg.outputs_force(ys)[0], 0

        return go
    raise ValueError(f"family: one of {', '.join(FAMILIES)}, got {family!r}")


def run(case: SlipCase, family: str, method: str, dt: float, v_eps: float = 0.0, repeats: int | None = None) -> SlipRun:
    """One run of a variant (module docstring), timed by :func:`.common.cpu_time`; never raises for a failed run."""
    try:
        go = _runner(case, family, method, dt, v_eps)
        with np.errstate(all="ignore"):  # divergence shows as non-finite states: counted, not warned
            cpu, (t, w, tb, events) = cpu_time(go, repeats=repeats)
    except SimulationDivergedError:
        return SlipRun("diverged")
    except (BeltDriveError, FloatingPointError, OverflowError) as exc:
        return SlipRun(f"failed: {type(exc).__name__}")
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(tb))) or np.max(np.abs(w)) > SPEED_LIMIT:
        return SlipRun("diverged", cpu)
    return SlipRun("ok", cpu, t, w, tb, events)


def errors(ref: SlipReference, r: SlipRun) -> dict:
    """e_speed, e_belt, error of an ``ok`` run against the reference (module docstring)."""
    w_ref, tb_ref = ref.at(r.time)
    e = {"e_speed": relative_error(r.omega_M, w_ref), "e_belt": relative_error(r.belt_torque, tb_ref)}
    e["error"] = max(e["e_speed"], e["e_belt"])
    return e


def variant_label(family: str, method: str, v_eps: float = 0.0) -> str:
    """How charts and logs name a variant: ``etd2``, ``etd2 (no event location)``, ``rk4 tanh v_eps=0.001``."""
    if family == "hybrid":
        return method
    if family == "no_location":
        return f"{method} (no event location)"
    return f"{method} tanh v_eps={v_eps:g}"


# ------------------------------------------------------ predicted steps
def guard_step(case: SlipCase, method: str) -> float:
    """Largest stable step [s] the run's guard predicts (stick mode = flexible A; inf: any)."""
    flex = FlexibleBeltModel(case.params)
    return max_stable_step(flex.A, flex.B, method, upper=1.0)


def slip_mode_step(case: SlipCase, method: str) -> float:
    """Largest stable step [s] on the slip mode's A (the span element's relaxation -k/c when c > 0)."""
    m = case.model
    return max_stable_step(m.A_slip, m.B_slip, method, upper=1.0)


def _regularised_jacobian_gains(case: SlipCase, v_eps: float, states: np.ndarray, times: np.ndarray) -> list:
    """K = du/dy (4, 5) of the regularised ODE's inputs [M_drive, M_load, Q, v_s] at each probe (central differences)."""
    reg = RegularisedFriction(case.model, v_eps)
    plant = case.plant()
    u = reg.inputs(plant.scalar_drive, plant.scalar_load)
    gains = []
    for t, y in zip(times, states):
        K = np.zeros((4, 5))
        for j in range(5):
            h = 1e-7 * max(1.0, abs(y[j])) if j != 1 else 1e-9 * max(1e-3, abs(y[j]))
            e = np.zeros(5)
            e[j] = h
            K[:, j] = (u(t, y + e) - u(t, y - e)) / (2.0 * h)
        K[:, 0] = 0.0  # angle slopes of periodic torques average out (as the accuracy guard)
        gains.append(K)
    return gains


def regularised_step(case: SlipCase, method: str, v_eps: float, states: np.ndarray, times: np.ndarray,
                     lo: float = 1e-7, hi: float = 1e-1, iterations: int = 24) -> float:  # fmt: skip
    """Largest step [s] for which ``method`` is stable on the regularised ODE linearized at every probe state."""
    m = case.model
    best = hi
    for K in _regularised_jacobian_gains(case, v_eps, states, times):
        if one_step_stable(method, m, K, best):
            continue
        a, b = lo, best
        if not one_step_stable(method, m, K, a):
            return 0.0
        for _ in range(iterations):
            mid = math.sqrt(a * b)
            if one_step_stable(method, m, K, mid):
                a = mid
            else:
                b = mid
        best = a
    return best


def probe_states(case: SlipCase, v_eps: float, n: int = 40, dt: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """(times, states) of ``n`` probes along a fine regularised run (etd2 at ``dt``): half spread evenly over
    the run, half where the belt slides fastest (where the contact's slope is smallest and the span's
    relaxation ``k / c`` shows)."""
    plant = case.plant()
    time = grid(case, dt)
    reg = RegularisedFriction(case.model, v_eps)
    with np.errstate(all="ignore"):
        ys = reg.run(time, np.array(case.y0), plant.scalar_drive, plant.scalar_load, "etd2", breakpoints=plant.breakpoints)
    ok = np.flatnonzero(np.all(np.isfinite(ys), axis=1))
    even = ok[np.linspace(0, ok.size - 1, n - n // 2).astype(int)]
    speed = np.abs(reg.outputs_force(ys[ok])[1])
    fast = ok[np.argsort(speed)[::-1][: n // 2]]
    idx = np.unique(np.concatenate([even, fast]))
    return time[idx], ys[idx]


def failure_boundary(case: SlipCase, family: str, method: str, v_eps: float, ok_dt: float, bad_dt: float,
                     iterations: int) -> float:  # fmt: skip
    """Bisection (geometric) on dt between a step that runs and one that diverges or fails; the last bracket's midpoint."""
    for _ in range(iterations):
        mid = math.sqrt(ok_dt * bad_dt)
        if run(case, family, method, mid, v_eps, repeats=1).status == "ok":
            ok_dt = mid
        else:
            bad_dt = mid
    return math.sqrt(ok_dt * bad_dt)


def summarise_failures(rows: list) -> list:
    """Per (family, method, v_eps): the largest step of a sweep that ran and the smallest that failed (nan: none).

    A row fails when ``failed`` is true (diverged, failed, or, in the slip chart, an error beyond 1).
    """
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["family"], r["method"], r["v_eps"]), []).append(r)
    out = []
    for (family, method, v_eps), rs in groups.items():
        ran = [r["dt"] for r in rs if not r["failed"]]
        failed = [r["dt"] for r in rs if r["failed"]]
        out.append(dict(family=family, method=method, v_eps=v_eps,
                        largest_running_dt=max(ran) if ran else math.nan,
                        smallest_failing_dt=min(failed) if failed else math.nan))  # fmt: skip
    return out


__all__ = [
    "FAMILIES", "SlipCase", "SlipReference", "SlipRun", "case_from_scene", "errors", "failure_boundary", "grid",
    "guard_step", "probe_states", "reference", "regularised_step", "run", "slip_mode_step", "stick_slip_case",
    "summarise_failures", "variant_label",
]  # fmt: skip
