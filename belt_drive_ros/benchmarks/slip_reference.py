"""Python references of the slipping belt (outside the core: the package runs the compiled kernels only).

The charts (``belt-drive bench slip``, ``workprecision``, ``stability``) and
the tests measure the compiled hybrid run
(:class:`~belt_drive_ros.core.slip_run.SlippingSimulator`,
:mod:`~belt_drive_ros.core.kernel_slip`) against these:

* :class:`HybridStepper`: the hybrid model stepped in Python by the
  method's own flow (an integrator of each partial step's length), events
  located by Brent's method on it (or, with the torques as data, by the
  compiled location); ``locate=False`` switches the mode at the end of the
  step instead (the charts' ``no_location`` curve);
* :class:`RegularisedFriction`: ``Q = Q_max tanh(s' / v_eps)`` in series
  with the belt span, one smooth but stiff ODE (what users of tools without
  events know);
* :func:`reference_hybrid`: scipy DOP853 per mode with terminal events, the
  independent reference.

All use :class:`~belt_drive_ros.core.slip.SlippingBeltModel` (``docs/slip.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..core.integrators import make_integrator
from ..core.slip import SLIP, STICK, Event, EventStep, SlipError, SlippingBeltModel


def regularised_matrices(model: SlippingBeltModel) -> tuple[np.ndarray, np.ndarray]:
    """(A_reg (5, 5), B_reg (5, 4)) of the regularised ODE: ``Q`` and the slip speed ``v_s`` are inputs,
    ``theta_e' = (v_rel - v_s) / r_3``, ``s' = v_s``; inputs ``[M_drive, M_load, Q, v_s]``."""
    A = model.A_slip.copy()
    A[1] = model.rel_row / model.params.r_3
    A[4] = 0.0
    B = np.zeros((5, 4))
    B[:, :3] = model.B_slip
    B[1, 2] = B[4, 2] = 0.0
    B[1, 3], B[4, 3] = -1.0 / model.params.r_3, 1.0
    return A, B


@dataclass
class HybridResult:
    """States on the grid, the mode and slip direction at each grid time, and the events."""

    time: np.ndarray
    states: np.ndarray
    mode: np.ndarray
    sigma: np.ndarray
    events: list = field(default_factory=list)


class HybridStepper:
    """Steps the stick/slip model with one fixed-step method, switching modes at located events.

    Parameters
    ----------
    model : SlippingBeltModel.
    drive, load : scalar torque functions ``f(t, angle, speed)`` [N m] (the
        profiles' ``scalar_torque()``); the load sees ``phi_3``, ``omega_3``.
    method : fixed-step method name (``exact``, ``etd2``, ``etd4``, ``lawson5``, ``rk4``, ...).
    locate : True: events located by root finding on the method's flow over a
        partial step; False: the mode is switched at the end of the step in
        which the switching function changed sign (sampling on the grid; for
        comparison only).
    """

    def __init__(self, model: SlippingBeltModel, drive: Callable, load: Callable, method: str = "exact", locate: bool = True,
                 data=None):  # fmt: skip
        self.model, self.drive, self.load, self.method, self.locate = model, drive, load, method, locate
        self._steps: dict = {}
        self._guards: dict = {}
        p = model.params
        self._i, self._r3 = p.ratio, p.r_3
        self._two_k_r3 = 2.0 * p.k * p.r_3
        self.n_located = 0
        #: exact, etd2 and etd4 steps of any length by the compiled modal flow (no matrix exponential per length)
        self._modal_steps = method in ("exact", "etd2", "etd4")
        self._project_slip = p.c == 0.0 and p.belt_mass > 0.0
        self._limit = p.scalar_friction_limit()
        self._rel2, self._rel3 = float(model.rel_row[2]), float(model.rel_row[3])
        self._q1, self._q2, self._q3 = model._q[1:4]
        # dQ_max/dt = dlim * omega_M * omega_M' (the centrifugal part), and |q|, |A|, |B| of stick for the rounding scale
        self._dlim = -2.0 * p.belt_mass * (p.r_2 * p.gear_ratio) ** 2 * p.capstan_factor
        self._abs_stick = (np.abs(model.q_row), np.abs(model.A_stick), np.abs(model.B_stick))
        #: the compiled event step's arrays (:func:`~belt_drive_ros.core.kernel_slip.pack`) when the torques are
        #: data (``data`` = (drive data, load data, uses_angle)) and the method steps on the modal flow
        #: (the method's partial steps then in Python, the events located by the compiled location on the same
        #: continuous extension: ``_located``)
        self._kernel = self._located = None
        if data is not None and None not in data[:2] and locate:
            from ..core import kernel_slip

            if self._modal_steps:  # the package's own event step
                self._compiled = EventStep(model, method, data)
                self._kernel = self._compiled._kernel
            elif (arrays := kernel_slip.pack(model, method, *data)) is not None:
                locate_event, Z, R, c, _, guards, uses = kernel_slip.locate_event, *arrays[:6]
                rest = arrays[6:]
                self._located = lambda mode, sigma, t, y, h, hi, y1: locate_event(
                    int(mode), float(sigma), float(t), np.ascontiguousarray(y, dtype=float), float(h), float(hi),
                    np.ascontiguousarray(y1, dtype=float), Z, R, c, guards, uses, *rest)  # C arrays: one signature  # fmt: skip

    # ---------------------------------------------------------- the flows
    def _integrator(self, mode: int, h: float):
        key = (mode, h)
        integ = self._steps.get(key)
        if integ is None:
            if len(self._steps) > 512:
                self._steps.clear()
            m = self.model
            A, B = (m.A_stick, m.B_stick) if mode == STICK else (m.A_slip, m.B_slip)
            integ = self._steps[key] = make_integrator(self.method, A, B, h)
        return integ

    def inputs(self, mode: int, sigma: float, hi: float = math.inf) -> Callable:
        """u(t, y) of ``mode``; times are clipped at ``hi`` (torque read from the left of a cut)."""
        drive, load, i, r3, limit = self.drive, self.load, self._i, self._r3, self.model.limit

        if mode == STICK:

            def u(t, y):
                t = t if t < hi else hi
                return np.array([drive(t, y[0], y[2]), load(t, i * y[0] - y[1] - y[4] / r3, y[3])])

        else:

            def u(t, y):
                t = t if t < hi else hi
                return np.array(
                    [drive(t, y[0], y[2]), load(t, i * y[0] - y[1] - y[4] / r3, y[3]), sigma * limit(y[2])]
                )

        return u

    def flow(self, mode, sigma, t, y, h, hi=math.inf):
        """The method's step of length ``h`` in ``mode`` from (t, y), by an integrator of step ``h`` (cached per length)."""
        y1 = self._integrator(mode, h).step(t, y, self.inputs(mode, sigma, hi))
        return self._project(mode, sigma, y1)

    def _project(self, mode, sigma, y):
        """c = 0 slip: the stretch follows sigma Q_max(omega_M) (keeps the total deflection)."""
        p = self.model.params
        if mode == SLIP and p.c == 0.0 and p.belt_mass > 0.0:
            te = sigma * self.model.limit(y[2]) / self._two_k_r3
            y = y.copy()
            y[4] += self._r3 * (y[1] - te)
            y[1] = te
        return y

    # ------------------------------------------------- switching functions
    def switching(self, mode, sigma, y) -> float:
        """> 0 once the mode must end: ``|Q| - Q_max`` sticking, ``-sigma s'`` slipping [N or m/s]."""
        m = self.model
        if mode == STICK:
            return abs(float(m.q_row @ y)) - self._limit(float(y[2]))
        return -sigma * float(m.slip_speed(y, sigma * self._limit(float(y[2]))))

    def _stick_keeps(self, t, y) -> bool:
        """True if the stick mode's |Q| does not at once grow past Q_max from (t, y).

        Decided by the sign of sigma dQ/dt - dQ_max/dt in stick mode; where that
        vanishes to rounding (c = 0: dQ/dt = 2 k v_rel = 2 k s' = 0 at the
        switch) by the second derivative sigma d2Q/dt2 = sigma q . A y'
        (inputs held over the instant).
        """
        m = self.model
        Q = float(m.q_row @ y)
        if abs(Q) < self._limit(float(y[2])) * (1.0 - 1e-9):
            return True
        sig = math.copysign(1.0, Q)
        u = self.inputs(STICK, 0.0)(t, y)
        dy = m.A_stick @ y + m.B_stick @ u
        dlim = self._dlim * y[2] * dy[2]
        rate = sig * float(m.q_row @ dy) - dlim
        q_abs, A_abs, B_abs = self._abs_stick
        scale = float(q_abs @ (A_abs @ np.abs(y) + B_abs @ np.abs(u))) + abs(dlim)
        if abs(rate) > 1e-8 * scale:
            return rate < 0.0
        return sig * float(m.q_row @ (m.A_stick @ dy)) <= 0.0

    def switch(self, mode, sigma, t, y):
        """New (mode, sigma, y) after an event at (t, y)."""
        m = self.model
        if mode == STICK:
            sigma = 1.0 if float(m.q_row @ y) >= 0.0 else -1.0
            if m.params.c == 0.0:  # the stretch sits at the limit exactly
                te = sigma * self._limit(float(y[2])) / self._two_k_r3
                y = y.copy()
                y[4] += self._r3 * (y[1] - te)
                y[1] = te
            return SLIP, sigma, y
        if self._stick_keeps(t, y):
            return STICK, 0.0, y
        return SLIP, sigma, y

    # ------------------------------------------------------------ stepping
    def _locate(self, mode, sigma, t, y, h, hi, y1=None):
        """First tau in (0, h] where the switching function turns positive along the step.

        With the torques as data, located on the step's continuous extension
        (the mode's exact flow with the torques linear in time between the
        step's ends) by the compiled location
        (:func:`~belt_drive_ros.core.kernel_slip.locate_event`, as the
        compiled event step does): a method unstable for the slip mode's
        fast creep at this step (rk4 at 1 ms) would give a meaningless flow
        over partial steps. Torques given as Python functions: located on
        the method's flow over a partial step, a sign scan on 8 points
        finding the first crossing (the flow may cross and return within a
        step), then Brent's method to ~1e-15 s.
        """
        if self._located is not None and y1 is not None:  # torques as data: on the step's modal extension, compiled
            tau = self._located(mode, sigma, t, y, h, hi, y1)
            if tau != tau:
                return None
            self.n_located += tau > 0.0
            return tau

        def G(tau):
            return self.switching(mode, sigma, y if tau == 0.0 else self.flow(mode, sigma, t, y, tau, hi))

        lo, g_lo = self._inside(G, self.switching(mode, sigma, y), h)
        if lo is None:
            return 0.0
        bracket = self._scan(G, lo, g_lo, h, 8)
        if bracket is None:
            return None
        self.n_located += 1
        import scipy.optimize  # here, at the first event located: a run without one never loads it

        return scipy.optimize.brentq(G, bracket[0], bracket[2], xtol=1e-15, rtol=_EPS4, maxiter=200)

    @staticmethod
    def _inside(G, g_lo, h):
        """(lo, G(lo)): 0 when the step starts inside (G < 0), else the first h 2^-k inside, or (None, None)."""
        if g_lo < 0.0:
            return 0.0, g_lo
        for k in range(1, 40):  # starts on the surface (just switched): find where it is inside
            tau = h * 0.5**k
            g = G(tau)
            if g < 0.0:
                return tau, g
        return None, None

    @staticmethod
    def _scan(G, lo, g_lo, h, n_scan):
        """(lo, G(lo), hi, G(hi)) around the first sign change on n_scan points from lo to h, or None."""
        for j in range(1, n_scan + 1):
            tau = lo + (h - lo) * j / n_scan if j < n_scan else h
            g = G(tau)
            if g > 0.0:
                return lo, g_lo, tau, g
            lo, g_lo = tau, g
        return None

    def advance(self, t0, t1, y, mode, sigma, cuts=(), events=None, dt=None, hi_end=math.inf, y1=None):
        """Integrate from t0 to t1: sub-steps end at each cut, then at each located event.

        A sub-step whose end state has a positive switching function holds an
        event; it is located (:meth:`_locate`), the flow is taken to it, the
        mode switched (:meth:`switch`) and the rest of the sub-step integrated
        in the new mode. ``y1``: the method's state at ``t1`` in ``mode``
        when already known (a step without cuts that a compiled loop took).
        """
        if self._kernel is not None:
            return self._compiled.advance(t0, t1, y, mode, sigma, cuts, events, dt, hi_end, y1)
        edges = [t0, *cuts, t1]
        n_events = 0
        given = None if cuts else y1
        for j in range(len(edges) - 1):
            a, b = edges[j], edges[j + 1]
            hi = math.nextafter(b, -math.inf) if j < len(edges) - 2 else hi_end
            while a < b:
                h = dt if (dt is not None and a == t0 and b == t1) else b - a  # a whole grid step: the grid's dt
                if given is None:
                    y1 = self.flow(mode, sigma, a, y, h, hi)
                given = None
                if self.switching(mode, sigma, y1) <= 0.0:
                    y, a = y1, b
                    break
                if self.locate:
                    tau = self._locate(mode, sigma, a, y, h, hi, y1)
                    if tau is None:
                        y, a = y1, b
                        break
                    if tau > 0.0:
                        y = self.flow(mode, sigma, a, y, tau, hi)
                    a = a + tau if tau < h else b
                else:  # switch at the end of the step (grid sampling, for comparison)
                    y, a = y1, b
                mode, sigma, y = self._switched(mode, sigma, a, y, events)
                n_events += 1
                if n_events > 64:
                    raise SlipError(f"slip: more than 64 mode switches in one step at t={a:.9g} s (chattering); reduce dt")
        return y, mode, sigma

    def _switched(self, mode, sigma, a, y, events):
        """:meth:`switch` at an event at (a, y), recorded in ``events`` when the mode changes."""
        old = mode
        mode, sigma, y = self.switch(mode, sigma, a, y)
        if events is not None and mode != old:
            events.append(Event(a, "onset" if mode == SLIP else "restick", sigma, y.copy()))
        return mode, sigma, y

    def run(self, time, y0, mode0=STICK, sigma0=0.0, breakpoints=()) -> HybridResult:
        """Integrate over the grid ``time``; steps are split at ``breakpoints`` and at events."""
        time = np.asarray(time, dtype=float)
        n = time.size - 1
        states = np.empty((n + 1, 5))
        modes = np.empty(n + 1, dtype=int)
        sigmas = np.empty(n + 1)
        y = np.asarray(y0, dtype=float).copy()
        mode, sigma = mode0, sigma0
        if mode == STICK and self.switching(mode, sigma, y) > 0.0:  # starts beyond the limit
            mode, sigma, y = self.switch(mode, sigma, time[0], y)
        states[0], modes[0], sigmas[0] = y, mode, sigma
        events: list = []
        bps = sorted(float(b) for b in breakpoints)
        dt = float(time[1] - time[0]) if n else 0.0
        uniform = n > 0 and bool(np.allclose(np.diff(time), dt, rtol=1e-9, atol=0.0))
        tol = 1e-9 * dt
        for k in range(n):
            a, b = time[k], time[k + 1]
            cuts = [c for c in bps if a + tol < c < b - tol]
            # a step ending on a breakpoint samples the torque's left limit there (as the stepper does)
            hi_end = math.nextafter(b, -math.inf) if any(abs(c - b) <= tol for c in bps) else math.inf
            y, mode, sigma = self.advance(a, b, y, mode, sigma, cuts, events, dt if uniform else None, hi_end)
            states[k + 1], modes[k + 1], sigmas[k + 1] = y, mode, sigma
        return HybridResult(time, states, modes, sigmas, events)


#: relative tolerance of the event location (4 machine epsilons)
_EPS4 = 4.0 * float(np.finfo(float).eps)


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
                cache[h] = make_integrator(method, *regularised_matrices(m), h)
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
