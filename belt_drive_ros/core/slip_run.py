"""Offline runs of the slipping belt, stepped by the single :class:`~belt_drive_ros.core.stepper.Stepper`.

While the belt sticks, the slipping model *is* the flexible model (with the
load angle shifted by the accumulated slip, ``phi_3 = i phi_M - theta_e -
s / r_3``). While a massless belt slips, the slip mode is linear with the
constant force ``sigma Q_max``, carried as a sixth, constant state. So both
phases run in chunks through the stepper (compiled loop, breakpoints
handled exactly); after each chunk the mode's switching function is checked
on all its states at once (numpy), the chunk is cut before the first step
that crosses, and that step is redone by
:class:`~belt_drive_ros.core.slip.HybridStepper`, which locates the event,
splits the step there and switches the mode. A run that never reaches the
limit gives the flexible model's states bit for bit (closed-loop scenes:
the same compiled loop over the same steps).
"""

from __future__ import annotations

import math

import numpy as np

from .model import FlexibleBeltModel
from .slip import SLIP, STICK, HybridStepper, SlippingBeltModel
from .stability import require_stable
from .stepper import SPEED_LIMIT, Plant, Stepper, snap_tolerance
from .sources import ProfileForms


class _ShiftedLoad:
    """A load profile seen at ``angle - offset`` (the wheel-3 angle lost to slip), for the flexible plant."""

    def __init__(self, inner, offset: float):
        self.inner, self.offset = inner, float(offset)
        self.state_dependent = inner.state_dependent
        self.uses_angle = inner.uses_angle

    def torque(self, t, angle, speed):
        return self.inner.torque(t, np.asarray(angle) - self.offset, speed)

    def scalar_torque(self):
        f, off = self.inner.scalar_torque(), self.offset
        return lambda t, a, w: f(t, a - off, w)

    def forms(self):
        # no formula: the compiled loops call the closure (one loop serves every offset)
        return ProfileForms(None, self.scalar_torque(), None)

    def breakpoints(self):
        return self.inner.breakpoints()

    def left_of(self, t):
        return self.inner.left_of(t)


class _SlipPhase:
    """The slip mode of a massless belt as a linear model for the stepper: ``[y, Q]`` with ``Q' = 0``."""

    name = "slipping"

    def __init__(self, model: SlippingBeltModel):
        A = np.zeros((6, 6))
        A[:5, :5] = model.A_slip
        A[:5, 5] = model.B_slip[:, 2]
        B = np.zeros((6, 2))
        B[:5] = model.B_slip[:, :2]
        self.A, self.B, self.params = A, B, model.params
        i, r3 = model.params.ratio, model.params.r_3
        W = np.zeros((4, 6))
        W[0, 0], W[1, 2], W[3, 3] = 1.0, 1.0, 1.0
        W[2, 0], W[2, 1], W[2, 4] = i, -1.0, -1.0 / r3  # phi_3 = i phi_M - theta_e - s / r_3
        self._W = W

    def wheel_coordinates(self, x):
        y = x @ self._W.T
        return y[..., 0], y[..., 1], y[..., 2], y[..., 3]


class SlippingSimulator:
    """Runs the slipping model with one fixed-step method (``Simulator``-like interface)."""

    def __init__(self, params, drive, load, method="etd2", dt=1e-3, method_options=None, check_stability=True, chunk=4096):
        self.model = SlippingBeltModel(params)
        self.flexible = FlexibleBeltModel(params)
        self.drive, self.load = drive, load
        self.method, self.dt, self.chunk = method, float(dt), int(chunk)
        self.method_options = dict(method_options or {})
        self.plant = Plant(self.flexible, drive, load)
        self.stepper = Stepper(self.plant, method, self.dt, self.method_options)
        self.integrator = self.stepper.integrator
        self.stability = require_stable(self.flexible.A, self.flexible.B, method, dt) if check_stability else None
        self.hybrid = HybridStepper(self.model, self.plant.scalar_drive, self.plant.scalar_load, method)
        self.events: list = []
        self.vectorized = False
        self._W_inv = np.linalg.inv(self.plant.wheel_map)  # [phi_M, omega_M, phi_3, omega_3] = W x
        self._steppers: dict = {}

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

    def _stick_stepper(self, s: float) -> Stepper:
        """The stepper of the stick phase after slip ``s`` (the flexible plant itself while s = 0)."""
        if s == 0.0:
            return self.stepper
        if len(self._steppers) > 64:
            self._steppers.clear()
        key = ("stick", s)
        if key not in self._steppers:
            plant = Plant(self.flexible, self.drive, _ShiftedLoad(self.load, s / self.model.params.r_3))
            self._steppers[key] = Stepper(plant, self.method, self.dt, self.method_options, origin=self.stepper.origin)
        return self._steppers[key]

    def _slip_stepper(self) -> Stepper | None:
        """The stepper of the slip phase of a massless belt (None with a belt mass: Q_max varies)."""
        if self.model.params.belt_mass != 0.0:
            return None
        if "slip" not in self._steppers:
            plant = Plant(_SlipPhase(self.model), self.drive, self.load)
            self._steppers["slip"] = Stepper(plant, self.method, self.dt, self.method_options, origin=self.stepper.origin)
        return self._steppers["slip"]

    def _grid(self, t0: float, t1: float) -> list:
        """The stepper's knots: grid times ``t0 + k dt`` and ``t1`` exactly."""
        st = self.stepper
        times = [t0]
        k = 1
        while True:
            t = st.grid_time(k)
            if t >= t1 - snap_tolerance(t1, self.dt):
                break
            times.append(t)
            k += 1
        times.append(t1)
        return times

    def _cuts(self, a: float, b: float):
        """Breakpoints strictly inside (a, b), and whether b is one (the step then ends at its left limit)."""
        tol = snap_tolerance(b, self.dt)
        bps = self.stepper.breakpoints
        inside = [c for c in bps if a + tol < c < b - tol]
        return inside, any(abs(c - b) <= tol for c in bps)

    # -------------------------------------------------------------- run
    def run(self, duration, y0, t0=0.0, progress=None):
        """Integrate ``duration`` [s] from the slipping state ``y0``; returns (time, states, mode, sigma)."""
        self.stepper.origin = float(t0)
        times = self._grid(float(t0), float(t0) + float(duration))
        time = np.array(times)
        n = len(times) - 1
        hs = self.hybrid
        states = np.empty((n + 1, 5))
        modes = np.zeros(n + 1, dtype=np.int8)
        sigmas = np.zeros(n + 1)
        y = np.asarray(y0, dtype=float).copy()
        mode, sigma = STICK, 0.0
        events: list = []
        if hs.switching(mode, sigma, y) > 0.0:  # starts beyond the limit
            mode, sigma, y = hs.switch(mode, sigma, times[0], y)
        states[0], modes[0], sigmas[0] = y, mode, sigma
        x = self.to_flexible(y)  # the running flexible state while sticking (no round trips)
        k, chunk = 0, 16  # chunks grow x2 without an event, back to 16 after one
        while k < n:
            stop = min(k + chunk, n)
            chunk = min(2 * chunk, self.chunk)
            if mode == STICK:
                s = float(y[4])
                _, xs = self._stick_stepper(s).run(x, times[k], times[stop], vectorize=False)
                ys = self.from_flexible(xs[1:], s)
                g = np.abs(ys @ self.model.q_row) - self.model.limit(ys[:, 2])
            else:
                st = self._slip_stepper()
                if st is None:
                    ys = np.empty((0, 5))
                    g = np.empty(0)
                else:
                    Q = sigma * float(self.model.limit(0.0))
                    _, zs = st.run(np.append(y, Q), times[k], times[stop], vectorize=False)
                    ys = zs[1:, :5]
                    g = -sigma * self.model.slip_speed(ys, Q)
            bad = np.flatnonzero(g > 0.0)
            done = len(ys) if not bad.size else int(bad[0])
            states[k + 1 : k + 1 + done] = ys[:done]
            modes[k + 1 : k + 1 + done], sigmas[k + 1 : k + 1 + done] = mode, sigma
            if done:
                y = ys[done - 1].copy()
                if mode == STICK:
                    x = xs[done]
            k += done
            if progress:
                progress(k / n)
            if k >= n or (done == len(ys) and len(ys)):
                continue
            # step k -> k+1 holds an event (or the slip mode has a belt mass): the hybrid stepper takes it
            cuts, ends_on_breakpoint = self._cuts(times[k], times[k + 1])
            hi_end = self.plant.left_of(times[k + 1]) if ends_on_breakpoint else math.inf
            y, new_mode, sigma = hs.advance(times[k], times[k + 1], y, mode, sigma, cuts, events, self.dt, hi_end)
            if not (np.all(np.isfinite(y)) and max(abs(y[2]), abs(y[3])) <= SPEED_LIMIT):
                raise self.stepper._diverged(times[k + 1], y)
            if new_mode != mode or events:
                chunk = 16
            mode = new_mode
            states[k + 1], modes[k + 1], sigmas[k + 1] = y, mode, sigma
            if mode == STICK:
                x = self.to_flexible(y)
            k += 1
        self.events = events
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
