"""The slipping belt's alternatives to the event-driven hybrid: regularised friction and an independent reference.

* :class:`RegularisedFriction`: ``Q = Q_max tanh(s' / v_eps)`` in series
  with the belt span, one smooth but stiff ODE (what users of tools without
  events know);
* :func:`reference_hybrid`: scipy DOP853 per mode with terminal events, the
  independent reference the tests and ``belt-drive bench slip`` measure the
  hybrid stepper against.

Both use :class:`~belt_drive_ros.core.slip.SlippingBeltModel` (``docs/slip.md``).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .integrators import make_integrator
from .slip import SLIP, STICK, Event, HybridResult, HybridStepper, SlipError, SlippingBeltModel


# ============================================================ regularised
class RegularisedFriction:
    """Smooth friction ``Q = Q_max tanh(s' / v_eps)`` in series with the belt span (one ODE, no modes).

    ``y' = A_reg y + B_reg [M_drive, M_load, Q, v_s]``: the slip speed
    ``v_s`` solves ``2 k r_3 theta_e + 2 c (v_rel - v_s) = Q_max tanh(v_s / v_eps)``
    (unique: the left side falls, the right side rises in ``v_s``; safeguarded
    Newton), or for ``c = 0``, ``v_s = v_eps artanh(2 k r_3 theta_e / Q_max)``.
    The contact is stiff: ``dQ/dv_s = Q_max / v_eps`` at ``v_s = 0``.
    """

    def __init__(self, model: SlippingBeltModel, v_eps: float):
        if not (math.isfinite(v_eps) and v_eps > 0.0):
            raise SlipError(f"v_eps: must be a finite speed > 0 m/s, got {v_eps!r}")
        self.model, self.v_eps = model, float(v_eps)

    def contact(self, y) -> tuple[float, float]:
        """(Q [N], v_s [m/s]) at state ``y``."""
        m, ve = self.model, self.v_eps
        p = m.params
        qmax = float(m.limit(y[2]))
        spring = 2.0 * p.k * p.r_3 * y[1]
        if qmax <= 0.0:
            return 0.0, float(m.rel_row @ y) + (spring / (2.0 * p.c) if p.c > 0 else 0.0)
        if p.c == 0.0:
            ratio = min(max(spring / qmax, -1.0 + 1e-16), 1.0 - 1e-16)
            v = ve * math.atanh(ratio)
            return qmax * math.tanh(v / ve), v
        F = spring + 2.0 * p.c * float(m.rel_row @ y)
        lo, hi = (F - qmax) / (2.0 * p.c), (F + qmax) / (2.0 * p.c)
        v = min(max(0.0, lo), hi)
        for _ in range(100):
            th = math.tanh(v / ve)
            f = F - 2.0 * p.c * v - qmax * th
            if f > 0.0:
                lo = v
            else:
                hi = v
            df = -2.0 * p.c - qmax * (1.0 - th * th) / ve
            v_new = v - f / df
            if not lo < v_new < hi:
                v_new = 0.5 * (lo + hi)
            if abs(v_new - v) <= 1e-15 * (1.0 + abs(v)) or hi - lo <= 1e-15 * (1.0 + abs(v)):
                v = v_new
                break
            v = v_new
        return qmax * math.tanh(v / ve), v

    def inputs(self, drive, load) -> Callable:
        m = self.model
        i, r3 = m.params.ratio, m.params.r_3
        contact = self.contact

        def u(t, y):
            Q, v = contact(y)
            return np.array([drive(t, y[0], y[2]), load(t, i * y[0] - y[1] - y[4] / r3, y[3]), Q, v])

        return u

    def run(self, time, y0, drive, load, method="rk4", breakpoints=()) -> np.ndarray:
        """States on the grid ``time`` with a fixed-step ``method`` (steps split at breakpoints)."""
        m = self.model
        time = np.asarray(time, dtype=float)
        u = self.inputs(drive, load)
        out = np.empty((time.size, 5))
        out[0] = y = np.asarray(y0, dtype=float)
        cache: dict = {}

        def step(a, b, y, hi):
            h = b - a
            if h not in cache:
                cache[h] = make_integrator(method, m.A_reg, m.B_reg, h)
            return cache[h].step(a, y, u if hi == math.inf else (lambda t, x: u(t if t < hi else hi, x)))

        bps = sorted(float(b) for b in breakpoints)
        for k in range(time.size - 1):
            a, b = time[k], time[k + 1]
            edges = [a, *[c for c in bps if a < c < b], b]
            for j in range(len(edges) - 1):
                hi = math.nextafter(edges[j + 1], -math.inf) if j < len(edges) - 2 else math.inf
                y = step(edges[j], edges[j + 1], y, hi)
            out[k + 1] = y
            if not np.all(np.isfinite(y)) or abs(y[2]) > 1e5 or abs(y[3]) > 1e5:
                out[k + 1 :] = np.nan
                break
        return out

    def outputs_force(self, states) -> tuple[np.ndarray, np.ndarray]:
        """(Q, v_s) per sample."""
        qs = np.array([self.contact(y) for y in states])
        return qs[:, 0], qs[:, 1]


# ========================================================= the reference
def reference_hybrid(model: SlippingBeltModel, drive, load, time, y0, mode0=STICK, sigma0=0.0, breakpoints=(), rtol=1e-12, atol=1e-12):
    """Independent reference: scipy DOP853 per mode with terminal events, restarted at events and breakpoints.

    Returns a :class:`HybridResult` on the grid ``time`` (dense output between
    restarts). The mode logic (:meth:`HybridStepper.switch`) is shared, the
    integration and the event location are scipy's.
    """
    import scipy.integrate  # here: a run that never takes the reference never loads it

    hs = HybridStepper(model, drive, load, "exact")
    time = np.asarray(time, dtype=float)
    states = np.empty((time.size, 5))
    modes = np.empty(time.size, dtype=int)
    sigmas = np.empty(time.size)
    events: list = []
    t, y, mode, sigma = float(time[0]), np.asarray(y0, dtype=float).copy(), mode0, sigma0
    if mode == STICK and hs.switching(mode, sigma, y) > 0.0:
        mode, sigma, y = hs.switch(mode, sigma, t, y)
    states[0], modes[0], sigmas[0] = y, mode, sigma
    stops = sorted({float(b) for b in breakpoints if time[0] < b < time[-1]} | {float(time[-1])})
    k_out = 1
    while t < time[-1]:
        t_stop = next(s for s in stops if s > t)
        m = model
        A, B = (m.A_stick, m.B_stick) if mode == STICK else (m.A_slip, m.B_slip)
        u = hs.inputs(mode, sigma, math.nextafter(t_stop, -math.inf))

        def rhs(tt, yy, A=A, B=B, u=u):
            return A @ yy + B @ u(tt, yy)

        def ev(tt, yy, mode=mode, sigma=sigma):
            return hs.switching(mode, sigma, yy)

        ev.terminal, ev.direction = True, 1.0
        # a slip phase starts on the surface (switching = 0): skip the start point
        sol = scipy.integrate.solve_ivp(rhs, (t, t_stop), y, method="DOP853", rtol=rtol, atol=atol, events=ev, dense_output=True)
        t_end = float(sol.t[-1])
        while k_out < time.size and time[k_out] <= t_end:
            states[k_out] = hs._project(mode, sigma, sol.sol(time[k_out]))
            modes[k_out], sigmas[k_out] = mode, sigma
            k_out += 1
        y = hs._project(mode, sigma, sol.y[:, -1].copy())
        if sol.status == 1 and sol.t_events[0].size and t_end < t_stop:
            old = mode
            mode, sigma, y = hs.switch(mode, sigma, t_end, y)
            if mode != old:
                events.append(Event(t_end, "onset" if mode == SLIP else "restick", sigma, y.copy()))
            else:  # stayed: nudge past the grazing point
                pass
        t = t_end
    return HybridResult(time, states, modes, sigmas, events)
