"""Offline simulation: a model, its torques and an integrator over a time grid.

The :class:`Plant` joins a model with its drive and load profiles into the
input function ``u(t, x)`` every integrator calls. :class:`Simulator` owns
the state and the time grid; it takes the vectorized path (one linear
recurrence for the whole run, :func:`~belt_drive_ros.core.integrators.propagate_linear`)
when both torques depend on time only and the method has a fixed step, and
steps one at a time otherwise: fixed-step methods in a loop compiled for the
plant (:func:`~belt_drive_ros.core.integrators.compile_scalar_loop`, plain float
arithmetic, no numpy per step), adaptive ones through ``integrator.step``.
All paths give the same states to rounding.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .errors import SimulationDivergedError
from .fidelity import ModelChoice, choose_model
from .integrators import FixedStepIntegrator, make_integrator
from .model import OUTPUT_UNITS, make_model
from .scene import Scene
from .sources import TorqueProfile
from .stability import StabilityReport, require_stable

#: Speeds beyond this [rad/s] (~955,000 rpm) mean the numerics, not the physics, blew up.
SPEED_LIMIT = 1.0e5
#: CSV columns required by the CLI, SI units.
CSV_COLUMNS = (
    "time",
    "phi_M",
    "omega_M",
    "phi_3",
    "omega_3",
    "drive_torque",
    "load_torque",
    "belt_torque",
    "relative_deflection",
)


class Plant:
    """Model + drive + load: the input function ``u(t, x) = [drive, load]`` [N m].

    ``inputs(t, x)`` takes one state (1-D) and returns a (2,) array; it calls
    the profiles' scalar closures (:meth:`~belt_drive_ros.core.sources.TorqueProfile.scalar_torque`),
    which skip numpy's per-call overhead. ``wheel_map`` is the (4, n) matrix
    W with ``[phi_M, omega_M, phi_3, omega_3] = W x`` (the compiled loops of
    :func:`~belt_drive_ros.core.integrators.compile_scalar_loop` inline it).
    """

    def __init__(self, model, drive: TorqueProfile, load: TorqueProfile):
        self.model, self.drive, self.load = model, drive, load
        self.open_loop = not (drive.state_dependent or load.state_dependent)
        self.scalar_drive = drive_torque = drive.scalar_torque()
        self.scalar_load = load_torque = load.scalar_torque()
        self.wheel_map = np.array(model.wheel_coordinates(np.eye(model.A.shape[0])), dtype=float)
        #: (drive, load): whether each torque reads its angle; their inlinable sources (or None)
        self.uses_angle = (bool(drive.uses_angle), bool(load.uses_angle))
        self.sources = (drive.scalar_source, load.scalar_source)
        #: sorted finite times [s] at which either torque jumps or kinks (TorqueProfile.breakpoints)
        self.breakpoints = sorted({float(b) for b in (*drive.breakpoints(), *load.breakpoints()) if math.isfinite(b)})
        array = np.array
        if model.name == "flexible":

            def inputs(t, x):
                # x = [phi_M, phi_3, omega_M, omega_3]
                return array([drive_torque(t, x[0], x[2]), load_torque(t, x[1], x[3])])

        else:
            i = model.params.ratio

            def inputs(t, x):
                # x = [phi_M, omega_M]; wheel 3 turns i times as far
                return array([drive_torque(t, x[0], x[1]), load_torque(t, i * x[0], i * x[1])])

        self.inputs = inputs

    def scalar_loop(self, integrator) -> Callable | None:
        """``integrator``'s compiled float loop for this plant (inlined torques, unused angles skipped), or None."""
        if not isinstance(integrator, FixedStepIntegrator):
            return None
        return integrator.scalar_loop(self.wheel_map, self.uses_angle, self.sources)

    def input_array(self, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Vectorized u for samples ``t`` (N,), ``x`` (N, n) -> (N, 2)."""
        phi_M, omega_M, phi_3, omega_3 = self.model.wheel_coordinates(x)
        t = np.asarray(t, dtype=float)
        d = np.broadcast_to(self.drive.torque(t, phi_M, omega_M), t.shape)
        l = np.broadcast_to(self.load.torque(t, phi_3, omega_3), t.shape)
        return np.stack([d, l], axis=-1).astype(float)


@dataclass
class SimResult:
    """States, inputs and outputs of one run on the grid ``time`` [s].

    ``outputs`` holds every signal of :data:`belt_drive_ros.core.model.OUTPUT_UNITS`
    as an (N,) array; ``states`` is (N, n) in the model's state ordering.
    """

    scene: Scene
    model: str
    method: str
    dt: float
    time: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    outputs: dict
    choice: ModelChoice | None = None
    stability: StabilityReport | None = None
    wall_time: float = 0.0
    vectorized: bool = False
    energy: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        return self.outputs[name]

    def table(self, columns=CSV_COLUMNS) -> np.ndarray:
        """(N, len(columns)) array of the named signals."""
        return np.column_stack([np.asarray(self[c], dtype=float) for c in columns])

    def to_csv(self, path, columns=CSV_COLUMNS) -> None:
        """CSV with a header line of column names; SI units (rad, rad/s, N m, s)."""
        np.savetxt(path, self.table(columns), delimiter=",", header=",".join(columns), comments="", fmt="%.12g")

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return (self.time[-1] - self.time[0]) / self.wall_time if self.wall_time > 0 else math.inf


def _check_finite(states: np.ndarray, time: np.ndarray, model_name: str, method: str, dt: float) -> None:
    """Raise :class:`SimulationDivergedError` at the first non-finite or runaway sample."""
    n = states.shape[1] // 2
    speeds = states[:, n:]
    bad = ~np.all(np.isfinite(states), axis=1) | np.any(np.abs(speeds) > SPEED_LIMIT, axis=1)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise SimulationDivergedError(
            f"simulation diverged at t={time[k]:.6g} s (model {model_name}, method {method}, dt={dt:g} s): "
            f"state {np.array2string(states[k], precision=4)} is non-finite or beyond {SPEED_LIMIT:g} rad/s; "
            f"reduce dt or use method 'exact' or 'etd2'"
        )


class Simulator:
    """Runs one model with one integrator from an initial state.

    Parameters
    ----------
    model : RigidBeltModel or FlexibleBeltModel.
    drive, load : torque profiles.
    method : integrator name; dt : step [s]; method_options : passed to it.
    check_stability : refuse (``UnstableStepError``) a step the guard predicts unstable.
    """

    def __init__(self, model, drive, load, method="etd2", dt=1e-3, method_options=None, check_stability=True):
        self.model = model
        self.plant = Plant(model, drive, load)
        self.method, self.dt = method, float(dt)
        self.method_options = dict(method_options or {})
        self.integrator = make_integrator(method, model.A, model.B, dt, **self.method_options)
        self.stability = require_stable(model.A, model.B, method, dt) if check_stability else None
        #: where steps are split (the plant's breakpoints; a copy, so a caller may change it for one simulator)
        self.breakpoints = list(self.plant.breakpoints)
        self._partial_steps: dict = {}
        self.split_steps: dict = {}

    def _splits(self, time: np.ndarray) -> dict:
        """{step k: [breakpoints strictly inside (t_k, t_k+1)]} for fixed-step methods (see :meth:`run`)."""
        if not isinstance(self.integrator, FixedStepIntegrator) or not self.breakpoints:
            return {}
        tol = 1e-9 * self.dt  # a breakpoint this close to a grid time is on the grid
        out: dict = {}
        for b in self.breakpoints:
            k = int(np.searchsorted(time, b, side="right")) - 1
            if 0 <= k < time.size - 1 and b - time[k] > tol and time[k + 1] - b > tol:
                out.setdefault(k, []).append(b)
        return out

    def _split_step(self, t0: float, t1: float, x: np.ndarray, cuts: list) -> np.ndarray:
        """One grid step as sub-steps ending at each breakpoint in ``cuts``.

        Each sub-step reads the torque from the left of its end (a jump at a
        cut belongs to the next sub-step), so no sub-step integrates across a
        jump or a kink: the method keeps its order there.
        """
        inputs = self.plant.inputs
        edges = [t0, *cuts, t1]
        for j, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
            h = b - a
            if h not in self._partial_steps:
                self._partial_steps[h] = make_integrator(self.method, self.model.A, self.model.B, h, **self.method_options)
            if j < len(cuts):
                left = math.nextafter(b, -math.inf)
                x = self._partial_steps[h].step(a, x, lambda t, y, hi=left: inputs(t if t < hi else hi, y))
            else:
                x = self._partial_steps[h].step(a, x, inputs)
        return x

    def run(
        self,
        duration: float,
        x0: np.ndarray,
        t0: float = 0.0,
        progress: Callable[[float], None] | None = None,
        vectorize: bool | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Integrate over ``duration`` [s]; return (time (N+1,), states (N+1, n)).

        ``vectorize`` forces (True) or forbids (False) the open-loop path; by
        default it is used whenever it applies.

        A fixed-step method's step that contains a torque breakpoint (the end
        of a soft start or ramp, a step's time, a schedule switch) strictly
        inside is split there (:meth:`_split_step`); the outputs stay on the
        grid. Without it such a step is locally first order: on ``paper`` a
        12.5 ms ``lawson5`` step with the soft start ending inside it makes
        the run 2000x less accurate (tests/test_breakpoints.py).
        ``split_steps`` lists them after the run.
        """
        n_steps = int(round(duration / self.dt))
        if abs(n_steps * self.dt - duration) > 1e-9 * max(duration, 1.0):
            n_steps = int(math.ceil(duration / self.dt))
        time = t0 + self.dt * np.arange(n_steps + 1)
        x0 = np.asarray(x0, dtype=float)
        self.split_steps = self._splits(time)
        can_vectorize = self.plant.open_loop and isinstance(self.integrator, FixedStepIntegrator) and not self.split_steps
        if vectorize and not can_vectorize:
            raise ValueError(
                "vectorize=True needs time-only torques, a fixed-step method and no torque breakpoint inside a step"
            )
        if can_vectorize and vectorize is not False:
            states = self._run_open_loop(time, x0)
            self.vectorized = True
        else:
            states = self._run_stepwise(time, x0, progress)
            self.vectorized = False
        _check_finite(states, time, self.model.name, self.method, self.dt)
        if progress:
            progress(1.0)
        return time, states

    def _run_open_loop(self, time, x0):
        from .integrators import propagate_linear

        step = self.integrator.linear_step()
        t = time[:-1]
        zeros = np.zeros_like(t)
        node_inputs = [
            np.column_stack(
                [
                    np.broadcast_to(self.plant.drive.torque(t + c * self.dt, zeros, zeros), t.shape),
                    np.broadcast_to(self.plant.load.torque(t + c * self.dt, zeros, zeros), t.shape),
                ]
            )
            for c in step.nodes
        ]
        return propagate_linear(step, x0, node_inputs)

    def _run_stepwise(self, time, x0, progress):
        loop = self.plant.scalar_loop(self.integrator)
        if loop is None:
            return self._run_stepwise_generic(time, x0, progress)
        return self._run_compiled(loop, time, x0, progress)

    def _run_compiled(self, loop, time, x0, progress, chunk: int = 4096):
        """Step with the integrator's compiled float loop, ``chunk`` steps per call.

        Between chunks: copy the states into the array, report progress and
        check for divergence (the loop itself stops early within 64 steps of
        a non-finite or runaway state). A chunk the loop cannot finish (a
        ``math`` domain error on an infinite angle) is redone by the generic
        numpy path, which reports the divergence as usual.
        """
        n, size = time.size - 1, x0.size
        states = np.empty((n + 1, size))
        states[0] = x0
        times = time.tolist()
        drive, load = self.plant.scalar_drive, self.plant.scalar_load
        if progress:
            chunk = min(chunk, max(64, n // 100))
        x = tuple(x0.tolist())
        splits = self.split_steps
        k = 0
        while k < n:
            if k in splits:
                states[k + 1] = self._split_step(time[k], time[k + 1], states[k], splits[k])
                x = tuple(states[k + 1].tolist())
                k += 1
                continue
            stop = min(k + chunk, n, min((j for j in splits if j > k), default=n))
            try:
                flat = loop(times[k : stop + 1], x, drive, load, SPEED_LIMIT)
            except (ValueError, OverflowError, ZeroDivisionError):
                states[k:] = self._run_stepwise_generic(time[k:], states[k], None, k)
                return states
            done = len(flat) // size
            states[k + 1 : k + 1 + done] = np.array(flat).reshape(done, size)
            if done < stop - k:  # the loop stopped on a runaway state
                _check_finite(states[: k + 2 + done], time[: k + 2 + done], self.model.name, self.method, self.dt)
            x = tuple(flat[-size:])
            k = stop
            if progress:
                progress(k / n)
        return states

    def _run_stepwise_generic(self, time, x0, progress, offset: int = 0):
        n = time.size - 1
        states = np.empty((n + 1, x0.size))
        states[0] = x0
        x = x0
        step, inputs = self.integrator.step, self.plant.inputs
        splits = self.split_steps
        report_every = max(1, n // 100)
        for k in range(n):
            cuts = splits.get(k + offset)
            x = step(time[k], x, inputs) if cuts is None else self._split_step(time[k], time[k + 1], x, cuts)
            states[k + 1] = x
            if k % 64 == 63 and not (np.all(np.isfinite(x)) and np.max(np.abs(x[x.size // 2 :])) <= SPEED_LIMIT):
                _check_finite(states[: k + 2], time[: k + 2], self.model.name, self.method, self.dt)
            if progress and k % report_every == 0:
                progress(k / n)
        return states


def simulate(
    scene: Scene,
    model: str | None = None,
    method: str | None = None,
    dt: float | None = None,
    duration: float | None = None,
    progress: Callable[[float], None] | None = None,
    check_stability: bool = True,
    vectorize: bool | None = None,
) -> SimResult:
    """Run ``scene`` (overrides for model, method, dt, duration) and compute all outputs.

    With ``model='auto'`` the choice and its reason are in ``result.choice``.
    """
    scene = scene.with_overrides(model=model, method=method, dt=dt, duration=duration)
    choice = None
    kind = scene.model
    if kind == "auto":
        choice = choose_model(scene)
        kind = choice.model
    mdl = make_model(kind, scene.params)
    sim = Simulator(mdl, scene.drive, scene.load, scene.method, scene.dt, scene.method_options, check_stability)
    x0 = scene.initial_state.vector(kind, scene.params.ratio)
    start = _time.perf_counter()
    time, states = sim.run(scene.duration, x0, progress=progress, vectorize=vectorize)
    wall = _time.perf_counter() - start
    u = sim.plant.input_array(time, states)
    outputs = mdl.outputs(states, u)
    # Energy balance terms (trapezoidal quadrature of the powers on the output grid).
    p_in = mdl.input_power(states, u)
    p_d = mdl.dissipation_power(states)
    dt_grid = np.diff(time)
    energy = {
        "kinetic": mdl.kinetic_energy(states),
        "potential": mdl.potential_energy(states),
        "input_work": np.concatenate([[0.0], np.cumsum(0.5 * (p_in[1:] + p_in[:-1]) * dt_grid)]),
        "dissipated": np.concatenate([[0.0], np.cumsum(0.5 * (p_d[1:] + p_d[:-1]) * dt_grid)]),
    }
    return SimResult(
        scene=scene,
        model=kind,
        method=sim.integrator.name,
        dt=scene.dt,
        time=time,
        states=states,
        inputs=u,
        outputs=outputs,
        choice=choice,
        stability=sim.stability,
        wall_time=wall,
        vectorized=sim.vectorized,
        energy=energy,
    )


def output_names() -> list[str]:
    """Names of all output signals (see :data:`belt_drive_ros.core.model.OUTPUT_UNITS`)."""
    return list(OUTPUT_UNITS)
