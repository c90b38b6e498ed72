"""Offline runs of the slipping belt: stick phases on the flexible model's compiled loop, events in :mod:`.slip`.

While the belt sticks, the slipping model *is* the flexible model (with the
load angle shifted by the accumulated slip, ``phi_3 = i phi_M - theta_e -
s / r_3``). So a stick phase runs in chunks of the flexible model's compiled
float loop (:meth:`~belt_drive_ros.core.simulate.Plant.scalar_loop`); after
each chunk the stick switching function ``|Q| - Q_max`` is checked on all its
states at once (numpy), the chunk is cut before the first step that crosses,
and that step is redone by :class:`~belt_drive_ros.core.slip.HybridStepper`,
which locates the onset and goes on in slip mode step by step until the belt
re-sticks. A run that never reaches the limit gives the flexible model's
states bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from .model import FlexibleBeltModel
from .slip import SLIP, STICK, HybridStepper, SlippingBeltModel
from .simulate import SPEED_LIMIT, Simulator, _check_finite


class SlippingSimulator:
    """Runs the slipping model with one fixed-step method (``Simulator``-like interface)."""

    def __init__(self, params, drive, load, method="etd2", dt=1e-3, method_options=None, check_stability=True, chunk=4096):
        self.model = SlippingBeltModel(params)
        self.flexible = FlexibleBeltModel(params)
        self.flex_sim = Simulator(self.flexible, drive, load, method, dt, method_options, check_stability)
        self.plant = self.flex_sim.plant
        self.integrator = self.flex_sim.integrator
        self.stability = self.flex_sim.stability
        self.method, self.dt, self.chunk = method, float(dt), int(chunk)
        self.hybrid = HybridStepper(self.model, self.plant.scalar_drive, self.plant.scalar_load, method)
        self.events: list = []
        self.vectorized = False
        W = self.plant.wheel_map  # [phi_M, omega_M, phi_3, omega_3] = W x
        self._W_inv = np.linalg.inv(W)
        self._loops: dict = {}

    # ------------------------------------------------------ conversions
    def to_flexible(self, y):
        """Flexible state with the same motion and a deflection theta_e (phi_3 without the slip part)."""
        i = self.model.params.ratio
        return self._W_inv @ np.array([y[0], y[2], i * y[0] - y[1], y[3]])

    def from_flexible(self, xs, s):
        """Slipping states of flexible states ``xs`` (N, 4) with accumulated slip ``s``."""
        phi_M, omega_M, phi_3, omega_3 = self.flexible.wheel_coordinates(xs)
        i = self.model.params.ratio
        return np.column_stack([phi_M, i * phi_M - phi_3, omega_M, omega_3, np.full(len(phi_M), s)])

    def _loop(self, s):
        """The compiled flexible loop with the load angle shifted by -s / r_3 (and its load closure)."""
        off = s / self.model.params.r_3
        key = off
        if key not in self._loops:
            plant = self.plant
            load, src = plant.scalar_load, plant.sources[1]
            if off != 0.0:
                load = (lambda f, o: (lambda t, a, w: f(t, a - o, w)))(plant.scalar_load, off)
                if src is not None:
                    src = (lambda f, o: (lambda t, a, w: f(t, f"({a} - {o!r})", w)))(src, off)
            loop = self.integrator.scalar_loop(plant.wheel_map, plant.uses_angle, (plant.sources[0], src))
            if len(self._loops) > 64:
                self._loops.clear()
            self._loops[key] = (loop, load)
        return self._loops[key]

    def _slip_loop(self):
        """Compiled loop of the slip mode with the friction force as a 6th, constant state (massless belt only).

        ``[y, Q]' = [[A_slip, b_Q], [0, 0]] [y, Q] + [B_drive, B_load] u``: with
        ``m' = 0`` the force ``sigma Q_max`` is constant over a slip phase, so
        the slip mode fits the compiled loops' two-torque form and stays
        exact for ``exact`` and the exponential methods. None with a belt mass.
        """
        if self.model.params.belt_mass != 0.0:
            return None
        if "slip" not in self._loops:
            from .integrators import make_integrator

            m = self.model
            A = np.zeros((6, 6))
            A[:5, :5] = m.A_slip
            A[:5, 5] = m.B_slip[:, 2]
            B = np.zeros((6, 2))
            B[:5] = m.B_slip[:, :2]
            i, r3 = m.params.ratio, m.params.r_3
            W = np.zeros((4, 6))
            W[0, 0], W[1, 2], W[3, 3] = 1.0, 1.0, 1.0
            W[2, 0], W[2, 1], W[2, 4] = i, -1.0, -1.0 / r3  # phi_3 = i phi_M - theta_e - s / r_3
            integ = make_integrator(self.method, A, B, self.dt, **self.flex_sim.method_options)
            plant = self.plant
            self._loops["slip"] = integ.scalar_loop(W, plant.uses_angle, plant.sources)
        return self._loops["slip"]

    def _crossing(self, ys):
        """Index of the first state of ``ys`` beyond the friction limit, or None."""
        m = self.model
        g = np.abs(ys @ m.q_row) - m.limit(ys[:, 2])
        bad = np.flatnonzero(g > 0.0)
        return int(bad[0]) if bad.size else None

    # -------------------------------------------------------------- run
    def run(self, duration, y0, t0=0.0, progress=None):
        """Integrate ``duration`` [s] from the slipping state ``y0``; returns (time, states, mode, sigma)."""
        dt = self.dt
        n = int(round(duration / dt))
        if abs(n * dt - duration) > 1e-9 * max(duration, 1.0):
            n = int(math.ceil(duration / dt))
        time = t0 + dt * np.arange(n + 1)
        splits = self.flex_sim._splits(time)
        self.flex_sim.split_steps = splits
        hs = self.hybrid
        states = np.empty((n + 1, 5))
        modes = np.zeros(n + 1, dtype=np.int8)
        sigmas = np.zeros(n + 1)
        y = np.asarray(y0, dtype=float).copy()
        mode, sigma = STICK, 0.0
        if hs.switching(mode, sigma, y) > 0.0:
            mode, sigma, y = hs.switch(mode, sigma, time[0], y)
            self.events.append(("onset", time[0], sigma))
        states[0], modes[0], sigmas[0] = y, mode, sigma
        x = self.to_flexible(y)  # running flexible state while sticking (no round trips)
        times = time.tolist()
        drive = self.plant.scalar_drive
        k = 0
        events = []
        chunk = 16  # grows x2 per chunk without an event, back to 16 after one (an onset wastes < chunk steps)
        while k < n:
            if mode == STICK:
                s = float(y[4])
                if k in splits:  # a torque breakpoint inside the step
                    if s == 0.0:
                        x1 = self.flex_sim._split_step(time[k], time[k + 1], x, splits[k])
                        y1 = self.from_flexible(x1[None, :], s)[0]
                        if hs.switching(STICK, 0.0, y1) <= 0.0:
                            x, y = x1, y1
                            states[k + 1], modes[k + 1] = y, STICK
                            k += 1
                            continue
                    y, mode, sigma = hs.advance(time[k], time[k + 1], y, mode, sigma, splits[k], events, dt)
                    states[k + 1], modes[k + 1], sigmas[k + 1] = y, mode, sigma
                    x = self.to_flexible(y)
                    k += 1
                    continue
                stop = min(k + chunk, n, min((j for j in splits if j > k), default=n))
                chunk = min(2 * chunk, self.chunk)
                loop, load = self._loop(s)
                flat = loop(times[k : stop + 1], tuple(x.tolist()), drive, load, SPEED_LIMIT)
                xs = np.array(flat).reshape(-1, 4)
                ys = self.from_flexible(xs, s)
                cross = self._crossing(ys)
                done = len(xs) if cross is None else cross
                states[k + 1 : k + 1 + done] = ys[:done]
                if done:
                    x, y = xs[done - 1], ys[done - 1]
                k += done
                if cross is None:
                    if done < stop - (k - done):  # the loop stopped on a runaway state
                        _check_finite(states[: k + 1], time[: k + 1], "slipping", self.method, dt)
                    if progress:
                        progress(k / n)
                    continue
                # the step k -> k+1 crosses the limit: locate the onset there
                y, mode, sigma = hs.advance(time[k], time[k + 1], y, STICK, 0.0, (), events, dt)
                states[k + 1], modes[k + 1], sigmas[k + 1] = y, mode, sigma
                x = self.to_flexible(y)
                k += 1
                chunk = 16
            else:
                slip_loop = None if k in splits else self._slip_loop()
                if slip_loop is not None:
                    stop = min(k + chunk, n, min((j for j in splits if j > k), default=n))
                    chunk = min(2 * chunk, self.chunk)
                    Q = sigma * float(self.model.limit(0.0))
                    flat = slip_loop(times[k : stop + 1], (*y.tolist(), Q), drive, self.plant.scalar_load, SPEED_LIMIT)
                    ys = np.array(flat).reshape(-1, 6)[:, :5]
                    g = -sigma * self.model.slip_speed(ys, Q)
                    bad = np.flatnonzero(g > 0.0)
                    done = len(ys) if not bad.size else int(bad[0])
                    states[k + 1 : k + 1 + done] = ys[:done]
                    modes[k + 1 : k + 1 + done], sigmas[k + 1 : k + 1 + done] = SLIP, sigma
                    if done:
                        y = ys[done - 1].copy()
                    k += done
                    if not bad.size:
                        if done < stop - (k - done):
                            _check_finite(states[: k + 1], time[: k + 1], "slipping", self.method, dt)
                        continue
                    chunk = 16
                y, mode, sigma = hs.advance(time[k], time[k + 1], y, mode, sigma, splits.get(k, ()), events, dt)
                states[k + 1], modes[k + 1], sigmas[k + 1] = y, mode, sigma
                if not (np.all(np.isfinite(y)) and abs(y[2]) <= SPEED_LIMIT and abs(y[3]) <= SPEED_LIMIT):
                    _check_finite(states[: k + 2], time[: k + 2], "slipping", self.method, dt)
                if mode == STICK:
                    x = self.to_flexible(y)
                    chunk = 16
                k += 1
        self.events = events
        _check_finite(states, time, "slipping", self.method, dt)
        if progress:
            progress(1.0)
        return time, states, modes, sigmas

    def input_array(self, time, states):
        """u = [drive, load] per sample (the load at phi_3 with the slip part)."""
        phi_M, omega_M = states[:, 0], states[:, 2]
        t = np.asarray(time, dtype=float)
        d = np.broadcast_to(self.plant.drive.torque(t, phi_M, omega_M), t.shape)
        l = np.broadcast_to(self.plant.load.torque(t, self.model.phi_3(states), states[:, 3]), t.shape)
        return np.stack([d, l], axis=-1).astype(float)


# ------------------------------------------------------------ model choice
def limit_exceedance(params, time, outputs) -> tuple[float, float]:
    """(peak |Q| / Q_max, time of the peak [s]) of a rigid or flexible run's outputs."""
    q = np.abs(np.asarray(outputs["belt_torque"], dtype=float)) / params.r_3
    qmax = np.broadcast_to(params.friction_limit(np.asarray(outputs["omega_M"], dtype=float)), q.shape)
    ratio = np.divide(q, qmax, out=np.full(q.shape, np.inf), where=qmax > 0)
    k = int(np.argmax(ratio))
    return float(ratio[k]), float(time[k])


def slipping_reason(params, time, outputs, model: str) -> str | None:
    """Why ``auto`` goes on to the slipping model, or None when the run stays within the friction limit."""
    ratio, t_peak = limit_exceedance(params, time, outputs)
    if ratio <= 1.0:
        return None
    return (
        f"slipping: peak transmitted force {ratio:.2f} x the capstan limit "
        f"(Q_max = {params.friction_limit(0.0):.0f} N at rest) at t = {t_peak:.3g} s in the {model} run"
    )


def simulate_slipping(scene, choice=None, progress=None, check_stability=True):
    """Run ``scene`` on the slipping model; a :class:`~belt_drive_ros.core.simulate.SimResult` with its outputs.

    ``result.outputs`` has every signal of the other models plus
    :data:`~belt_drive_ros.core.slip.SLIP_OUTPUT_UNITS`; ``result.events``
    lists the mode switches (kind, time [s], direction).
    """
    import time as _time

    from .simulate import SimResult

    sim = SlippingSimulator(scene.params, scene.drive, scene.load, scene.method, scene.dt, scene.method_options, check_stability)
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    start = _time.perf_counter()
    time, states, modes, sigmas = sim.run(scene.duration, y0, progress=progress)
    wall = _time.perf_counter() - start
    m = sim.model
    u = sim.input_array(time, states)
    outputs = m.outputs(states, u, modes, sigmas)
    p_in = m.input_power(states, u)
    p_d = m.damping_power(states, modes, sigmas)
    p_f = m.friction_power(states, modes, sigmas)
    dt_grid = np.diff(time)

    def integral(p):
        return np.concatenate([[0.0], np.cumsum(0.5 * (p[1:] + p[:-1]) * dt_grid)])

    energy = {
        "kinetic": m.kinetic_energy(states),
        "potential": m.potential_energy(states),
        "input_work": integral(p_in),
        "dissipated": integral(p_d),
        "friction": integral(p_f),
    }
    result = SimResult(
        scene=scene, model="slipping", method=sim.integrator.name, dt=scene.dt, time=time, states=states,
        inputs=u, outputs=outputs, choice=choice, stability=sim.stability, wall_time=wall, vectorized=False, energy=energy,
    )
    result.events = [(e.kind, e.time, e.sigma) for e in sim.events]
    return result
