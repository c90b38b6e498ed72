"""Runs of the slipping belt: one compiled hybrid loop over stick and slip phases.

A stick or slip phase of the hybrid model is a linear plant with a guard
(:class:`~belt_drive_ros.core.stage_scheme.Guard`): the mode's switching
function, checked by the linear kernel's loop after every step. The
compiled hybrid loop (:func:`~belt_drive_ros.core.kernel_hybrid.hybrid_steps`)
runs each phase until the guard turns positive, redoes that step with the
event located (:func:`~belt_drive_ros.core.kernel_slip.event_step`) and goes
on in the new mode's phase, in one call. A step split at a breakpoint off
the grid, and runs whose phases have no compiled loop, are handed back to
the phases' steppers (:meth:`SlippingSimulator._advance_steps`), each event
step redone by the same compiled event step (:class:`~belt_drive_ros.core.slip.EventStep`).

The plants:

* sticking without slip so far (``s = 0``): the flexible model itself, in
  its own coordinates, so a run that never reaches the limit gives the
  flexible model's states bit for bit;
* sticking after slip (``s`` constant): the flexible model's loop too, the
  load's angle shifted by ``-s / r_3`` (it sees ``phi_3 = i phi_M - theta_e - s / r_3``);
  a step handed back to the steppers takes the stick mode's (5 states);
* slipping, massless belt: the slip mode with the constant force
  ``sigma Q_max`` as a sixth state (one plant per direction sigma);
* slipping with a belt mass (``Q_max`` varies with speed) and span damping:
  the slip mode with ``Q = sigma Q_max(omega_M)`` as a third input of the
  drive speed, evaluated at every stage in the compiled loop;
* slipping with a belt mass and ``c = 0`` (the stretch is projected onto
  the limit after each step): step by step by the hybrid stepper on the
  stepper's step plan.

:meth:`SlippingSimulator.advance` is the one entry: an offline run is one
advance from 0 to the duration with recording, the node's tick an advance
from the last tick to the next; each step is computed the same way in both
(bit-identical states).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from .errors import IntegratorError
from .identity_cache import built_once
from .integrators import REGISTRY, method_class
from .kernel_loop import FrictionForce
from .model import make_model
from .profile_data import DIVERGED, NOT_CONVERGED
from .slip import SLIP, STICK, Event, EventStep, SlipError, SlippingBeltModel
from .stability import require_stable
from .stage_scheme import Guard
from .step_plan import snap_tolerance, step_arrays
from .stepper import SPEED_LIMIT, Plant, Stepper, is_shared, shared_plant

#: grid steps per window of :meth:`SlippingSimulator.windows` (memory is bounded by a window, not the run)
RUN_WINDOW_STEPS = 16384


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
        self.wheel_coordinates = model.wheel_coordinates  # (of y = x[:5]: Q is not a wheel coordinate)


class _MassSlipPhase:
    """The slip mode of a belt with mass (c > 0) as a model for the stepper: ``y``, inputs ``[drive, load, Q]``.

    ``Q = sigma Q_max(omega_M)`` varies with the belt speed (centrifugal
    tension): the stepper's loop evaluates it at every stage like a
    state-dependent torque (:class:`~belt_drive_ros.core.stepper.Plant` ``extra``),
    as the hybrid stepper's flow does.
    """

    name = "slipping"

    def __init__(self, model: SlippingBeltModel):
        self.A, self.B, self.params = model.A_slip, model.B_slip, model.params
        self.wheel_coordinates = model.wheel_coordinates


def _mapped(guard: Guard, Y: np.ndarray) -> Guard:
    """``guard`` (on the slipping state y) as a guard on states x with ``y = Y x``."""
    speed = None if guard.speed is None else tuple(float(v) for v in np.asarray(guard.speed) @ Y)
    return Guard(tuple(float(v) for v in np.asarray(guard.row) @ Y), guard.bound, guard.absolute, speed, guard.quad)


@dataclass
class SlipState:
    """The hybrid state: mode, slip direction sigma, and the state vector in its phase's own coordinates.

    ``kind``: ``flexible`` (sticking, no slip yet: the flexible model's
    ``[phi_M, theta, omega_M, omega_3]``), ``stick`` (``y``, 5 states),
    ``slip`` (``[y, Q]``, massless belt), ``mass`` (``y`` while a belt with
    mass and span damping slips) or ``hybrid`` (``y`` while a belt with mass
    and no span damping slips: step by step).
    """

    mode: int
    sigma: float
    kind: str
    x: np.ndarray


def require_first_order_method(method: str) -> None:
    """Refuse (:class:`~belt_drive_ros.core.errors.IntegratorError`) a method the slip mode cannot be stepped with.

    A ``second_order_form`` method (``symplectic_euler``) needs the state as
    [coordinates, speeds] with ``q' = T omega``; the slip mode's span
    relaxation ``theta_e' = (Q - 2 k r_3 theta_e) / (2 c r_3)`` is a
    first-order equation in a coordinate, so that split does not exist.
    """
    cls = method_class(method)
    if getattr(cls, "second_order_form", False):
        usable = ", ".join(n for n, c in REGISTRY.items() if c.fixed_step and not getattr(c, "second_order_form", False))
        raise IntegratorError(
            f"{cls.name}: cannot step the slipping model (its slip mode relaxes the span stretch by a first-order "
            f"equation, not [coordinates, speeds]); use one of {usable}, or model rigid/flexible"
        )


class SlippingSimulator:
    """Runs the slipping model with one fixed-step method (``Simulator``-like interface).

    Parameters
    ----------
    params : BeltDriveParams; drive, load : torque profiles.
    method, dt, method_options : the fixed-step method and step [s].
    check_stability : refuse a step the guard predicts unstable (stick mode).
    origin : scene time [s] of grid index 0.
    integrator : a flexible-model integrator of ``method`` and ``dt`` to reuse (the node's).
    lazy : build the stick and slip phases' steppers and the hybrid stepper when a run first needs
        them (offline runs: a scene within the limit never does); False (the node) builds them
        here, so no tick pays for a set-up when the belt first slips. A lazy one without ``integrator``
        shares its steppers with the scene's other lazy simulators (:meth:`_built`).
    """

    def __init__(self, params, drive, load, method="etd2", dt=1e-3, method_options=None, check_stability=True,
                 origin=0.0, integrator=None, lazy=False):  # fmt: skip
        require_first_order_method(method)
        self.flexible = make_model("flexible", params)
        self.drive, self.load = drive, load
        self.method, self.dt = method, float(dt)
        self.method_options = dict(method_options or {})
        self.plant = shared_plant(self.flexible, drive, load)
        self._shared = _shared_phases(params, drive, load, self.plant)
        self.model = m = self._shared["model"]
        self._M_inv, flexible_guard, stick = self._shared["maps"]
        self._share = lazy and integrator is None
        self.stepper = self._built("flexible", lambda: Stepper(self.plant, method, self.dt, self.method_options, origin,
                                                               integrator, flexible_guard))  # fmt: skip
        self.stepper.origin, self.stepper.breakpoints = float(origin), self.plant.breakpoints  # (a shared one's too)
        self.integrator = self.stepper.integrator
        self.stability = require_stable(self.flexible.A, self.flexible.B, method, dt) if check_stability else None
        self._hybrid: EventStep | None = None
        self._steppers = {"flexible": self.stepper}
        # the other phases' steppers are built when a run first needs them (a scene within the limit never does)
        self._factories: dict = {"stick": lambda: Stepper(self._phase_plant("stick"), method, self.dt, self.method_options, guard=stick)}
        if params.belt_mass == 0.0:  # Q_max constant: the slip mode is linear with Q as a constant state
            for sigma in (1.0, -1.0):
                self._factories[("slip", sigma)] = lambda sigma=sigma: Stepper(
                    self._phase_plant(("slip", sigma)), method, self.dt, self.method_options, 0.0,
                    self._sibling(("slip", -sigma)), _mapped(m.guard(SLIP, sigma), np.eye(5, 6)),
                )  # fmt: skip
        elif params.c > 0.0:  # Q_max falls with the belt speed: Q an input of the drive speed, in the loop
            for sigma in (1.0, -1.0):
                self._factories[("mass", sigma)] = lambda sigma=sigma: Stepper(
                    self._phase_plant(("mass", sigma), (FrictionForce(sigma, params),)), method, self.dt, self.method_options, 0.0,
                    self._sibling(("mass", -sigma)), m.guard(SLIP, sigma),
                )  # fmt: skip
        self.events: list = []
        self._event_rows = np.zeros((1024, 8))
        self._free_cache: dict = {}
        if not lazy:
            for key in self._factories:
                self.phase_stepper(key)
            self._prime()

    def _prime(self) -> None:
        """Load the compiled hybrid loop and event step now (a call of no step), so no tick pays for it."""
        compiled = self._compiled()
        if compiled is None:
            return
        kh = _kernel_hybrid()
        have, reals, ints, offsets, Yflex, Minv, arrays = compiled
        none, x = np.zeros(0), np.zeros(6)
        kh.hybrid_steps(np.zeros(1), np.zeros(1), none, none, np.zeros(0, dtype=np.int64), 0, 0, x, self.dt, SPEED_LIMIT,
                        np.empty((0, 5)), np.empty(0, dtype=np.int64), none, np.empty((0, 6)), reals, ints, offsets, have,
                        Yflex, Minv, *arrays, self._event_rows, 0)  # fmt: skip
        self.hybrid.advance(0.0, 0.0, np.zeros(5), STICK, 0.0)

    @property
    def hybrid(self) -> EventStep:
        """The compiled event step that redoes a step with an event (built at the first event)."""
        if self._hybrid is None:
            data, shared = (*self.plant.data, self.plant.uses_angle), self._shared
            key = ("pack", self.method)
            if key not in shared:  # the packed arrays are read-only: one per method for every simulator of the scene
                shared[key] = EventStep(self.model, self.method, data)._kernel
            self._hybrid = EventStep(self.model, self.method, data, shared[key])
        return self._hybrid

    def _phase_plant(self, key, extra=()) -> Plant:
        """The plant of phase ``key`` (``"stick"``, ``("slip", sigma)``, ``("mass", sigma)``; ``extra`` its friction
        input): the same for every step length, built once per scene (:func:`_shared_phases`)."""
        if key not in self._shared:
            model = self.model if key == "stick" else (_SlipPhase if key[0] == "slip" else _MassSlipPhase)(self.model)
            self._shared[key] = Plant(model, self.drive, self.load, extra)
        return self._shared[key]

    def phase_stepper(self, key) -> Stepper:
        """The stepper of phase ``key`` (``"flexible"``, ``"stick"``, ``("slip", sigma)``, ``("mass", sigma)``), built once."""
        st = self._steppers.get(key)
        if st is None:
            st = self._steppers[key] = self._built(key, self._factories[key])
            st.origin, st.breakpoints = self.stepper.origin, self.stepper.breakpoints
        return st

    def _built(self, key, build):
        """``build()`` (phase ``key``'s stepper, or ``("loops", ...)``: the packed loops); a lazy simulator's kept
        in the scene's :func:`_shared_phases` per method, step, options and thread (the run, its reruns and the next
        runs take the same; each sets a stepper's origin and breakpoints, and every run starts from its state)."""
        if not self._share:
            return build()
        k = (key, self.method, self.dt, repr(sorted(self.method_options.items())), threading.get_ident())
        value = self._shared.pop(k, None)  # (put back last: the most recently used, see _kept)
        return _kept(self._shared, k, build() if value is None else value, value is None)

    def slip_phases(self) -> None:
        """Build every slip phase's stepper now, so the hybrid loop packs them at once (not one by one as the run
        enters each); sticking after slip runs on the flexible loop (the stick stepper is not needed)."""
        for key in self._factories:
            if key != "stick":
                self.phase_stepper(key)

    def _sibling(self, key):
        """The integrator of phase ``key`` when built (the two slip directions share one), else None."""
        st = self._steppers.get(key)
        return None if st is None else st.integrator

    # ------------------------------------------------------ conversions
    @property
    def breakpoints(self) -> list:
        """Times [s] where steps are split or bounded (settable: applies to every phase's stepper)."""
        return self.stepper.breakpoints

    @breakpoints.setter
    def breakpoints(self, value) -> None:
        value = tuple(value)  # (immutable: one object every phase's stepper keeps)
        for st in self._steppers.values():
            st.breakpoints = value

    @property
    def origin(self) -> float:
        return self.stepper.origin

    @origin.setter
    def origin(self, value: float) -> None:
        for st in self._steppers.values():
            st.origin = float(value)

    def reset(self) -> None:
        """Forget the steppers' partial-step integrators."""
        for st in self._steppers.values():
            st.reset()

    def grid_time(self, k: int) -> float:
        """Grid time ``origin + k dt`` [s] (the stepper's)."""
        return self.stepper.grid_time(k)

    def inputs(self, t: float, y) -> np.ndarray:
        """u = [drive, load] [N m] at time ``t`` [s] and slipping state ``y`` (the load at phi_3 with the slip part)."""
        i, r3 = self.model.params.ratio, self.model.params.r_3
        return np.array([self.plant.scalar_drive(t, y[0], y[2]), self.plant.scalar_load(t, i * y[0] - y[1] - y[4] / r3, y[3])])

    def from_flexible(self, xs):
        """Slipping states of flexible states ``xs`` (N, 4) (no accumulated slip)."""
        phi_M, omega_M, phi_3, omega_3 = self.flexible.wheel_coordinates(np.asarray(xs, dtype=float))
        ys = np.empty((len(phi_M), 5))
        ys[:, 0], ys[:, 2], ys[:, 3], ys[:, 4] = phi_M, omega_M, omega_3, 0.0
        ys[:, 1] = self.flexible.relative_deflection(np.asarray(xs, dtype=float))  # a state coordinate: no rounding
        return ys

    def initial(self, y0, t0=0.0) -> SlipState:
        """The hybrid state of slipping state ``y0`` at ``t0`` (sliding at once when it starts beyond the limit)."""
        y = np.asarray(y0, dtype=float).copy()
        mode, sigma = STICK, 0.0
        if abs(float(self.model.q_row @ y)) - self.model.params.friction_limit(float(y[2])) > 0.0:  # the stick switching
            mode, sigma, y = self.hybrid.onset(y)
        return self._native(y, mode, sigma)

    def _native(self, y, mode, sigma) -> SlipState:
        if mode == STICK:
            if y[4] == 0.0:
                # the flexible state with the same motion and a deflection theta_e (phi_3 without the slip part)
                return SlipState(mode, 0.0, "flexible", self._M_inv @ np.asarray(y, dtype=float)[:4])
            return SlipState(mode, 0.0, "stick", y)
        if ("slip", sigma) in self._factories:
            return SlipState(mode, sigma, "slip", np.append(y, sigma * self.model.limit(0.0)))
        if ("mass", sigma) in self._factories:
            return SlipState(mode, sigma, "mass", y)
        return SlipState(mode, sigma, "hybrid", y)

    def ys(self, kind, xs) -> np.ndarray:
        """Slipping states ``y`` (N, 5) of states ``xs`` (N, n) of a phase of ``kind``."""
        if kind == "flexible":
            return self.from_flexible(xs)
        return xs[:, :5]

    def state_y(self, state: SlipState) -> np.ndarray:
        """The slipping state ``y`` (5,) of a hybrid state."""
        return self.ys(state.kind, state.x[None, :])[0]

    # -------------------------------------------------------------- run
    def advance(self, state: SlipState, t0: float, t1: float, record=None, events=None) -> SlipState:
        """The hybrid state at ``t1`` [s] from ``state`` at ``t0`` (``t1 >= t0``).

        ``record``: a list that receives ``(times, ys, modes, sigmas)`` per
        piece (the knots after ``t0``; modes and sigmas a value or one per knot);
        ``events``: a list that receives the mode switches (:class:`~belt_drive_ros.core.slip.Event`).
        The whole grid steps run in the compiled hybrid loop
        (:func:`~belt_drive_ros.core.kernel_hybrid.hybrid_steps`); a partial
        step or one split at a breakpoint, and every step where the torques
        or the method are not the kernel's, by :meth:`_advance_steps`.
        Raises :class:`~belt_drive_ros.core.errors.SimulationDivergedError`.
        """
        if t1 > t0 and state.kind == "flexible" and self._hybrid is None and self.stepper.loop is not None:
            # no slip so far and the hybrid loop not packed yet: the flexible model's own guarded loop (the same
            # steps and guard), so a scene within the limit never packs it; from the step the guard stops in on,
            # the hybrid loop takes over
            state, t0 = self._flexible_until_guard(state, t0, t1, record)
            if t0 >= t1:
                return state
        compiled = self._compiled()
        if compiled is None or t1 <= t0:
            return self._advance_steps(state, t0, t1, record, events)
        st = self.stepper
        k0, k1 = st._snap(t0), st._snap(t1)
        if k0 is not None and k1 is not None and k1 > k0 and not st._near_breakpoint(t0, t1, k0, k1):
            N = k1 - k0  # whole grid steps away from breakpoints (the node's usual tick): no plan needed
            grid = st._grid(k0, k1 + 1)
            lo, hi, special = self._free_steps(N)
        else:
            plan = st._run_plan(float(t0), float(t1))  # (a repeated advance's plan kept: the run's reruns)
            if plan["empty"]:
                return self._advance_steps(state, t0, t1, record, events)
            first, last = plan["first"], plan["last"]
            N = last - first + 1
            if "grid" not in plan:  # (kept with the plan: read-only to the loop, which writes into knots only)
                plan["grid"] = st._grid(first, last + 2)
            if "arrays" not in plan:
                plan["arrays"] = step_arrays(plan)
            grid, (lo, hi, special) = plan["grid"], plan["arrays"]
        knots = grid.copy()
        knots[0], knots[-1] = t0, t1
        kh = _kernel_hybrid()
        out_y, out_native = np.empty((N, 5)), np.empty((N, 6))
        out_mode, out_sigma = np.empty(N, dtype=np.int64), np.empty(N)
        x = np.zeros(6)
        kind, sigma = _kind_code(state), state.sigma
        x[: state.x.size] = state.x
        if state.kind == "hybrid":
            x[5] = sigma
        k, n_ev = 0, 0
        ev = self._event_rows
        while True:
            have, reals, ints, offsets, Yflex, Minv, arrays = compiled
            k1, status, kind, sigma, n_ev = kh.hybrid_steps(
                grid, knots, lo, hi, special, k, kind, x, self.dt, SPEED_LIMIT, out_y, out_mode, out_sigma, out_native,
                reals, ints, offsets, have, Yflex, Minv, *arrays, ev, n_ev,
            )  # fmt: skip
            if record is not None and k1 > k:  # samples k .. k1 - 1 of the compiled stretch (views: this call's arrays,
                # never written again: later calls write from k1 on)
                record.append((knots[k + 1 : k1 + 1], out_y[k:k1], out_mode[k:k1].astype(np.int8), out_sigma[k:k1]))
            if events is not None:
                events.extend(_events(ev[:n_ev]))
            n_ev = 0
            n = kh.PHASE_SIZE[kind]
            if status == 0:
                break
            if status == DIVERGED:
                raise self.stepper.diverged_error(float(knots[k1]), out_native[k1 - 1, :n], "slipping")
            if status == NOT_CONVERGED:
                self.stepper._not_converged(float(knots[k1]))
            if status == kh.CHATTER:
                raise SlipError(f"slip: more than 64 mode switches in one step at t={knots[k1]:.9g} s (chattering); reduce dt")
            if status == kh.NO_PHASE:
                self.phase_stepper(kh.PHASE_KEYS[kind])
                compiled = self._compiled()
                if compiled is None:
                    here = SlipState(STICK if kind <= kh.STICKING else SLIP, sigma, kh.KIND_NAMES[kind], x[:n].copy())
                    return self._advance_steps(here, float(knots[k1]), t1, record, events)
            elif status == kh.SPECIAL:
                here = SlipState(STICK if kind <= kh.STICKING else SLIP, sigma, kh.KIND_NAMES[kind], x[:n].copy())
                here = self._advance_steps(here, float(knots[k1]), float(knots[k1 + 1]), record, events)
                kind, sigma = _kind_code(here), here.sigma
                x[:] = 0.0
                x[: here.x.size] = here.x
                if here.kind == "hybrid":
                    x[5] = here.sigma
                k1 += 1
            k = k1
            if k >= N:
                break
        n = kh.PHASE_SIZE[kind]
        return SlipState(STICK if kind <= kh.STICKING else SLIP, float(sigma), kh.KIND_NAMES[kind], x[:n].copy())

    def _flexible_until_guard(self, state: SlipState, t0: float, t1: float, record) -> tuple:
        """The flexible phase from ``t0`` by the flexible stepper (guarded by the stick check): ``(state, t)`` at
        ``t1``, or at the start of the step the guard stopped in (not recorded: the caller steps it again)."""
        times, xs = self.stepper.run(state.x, t0, t1)
        stop = self.stepper.stopped
        n = len(times) - 1 if stop is None else stop[0]
        if record is not None and n:
            record.append((times[1 : n + 1], self.from_flexible(xs[1 : n + 1]), state.mode, state.sigma))
        if stop is None:
            return SlipState(state.mode, state.sigma, state.kind, xs[n]), t1
        self.slip_phases()  # the belt slips in this step
        return SlipState(state.mode, state.sigma, state.kind, xs[n]), float(times[n])

    def _free_steps(self, N: int) -> tuple:
        """(lo, hi, special) of ``N`` whole steps without clamps or splits (read-only, kept per N)."""
        cached = self._free_cache.get(N)
        if cached is None:
            if len(self._free_cache) > 64:
                self._free_cache.clear()
            cached = self._free_cache[N] = (np.full(N, -math.inf), np.full(N, math.inf), np.zeros(N, dtype=np.int64))
        return cached

    def _compiled(self):
        """The compiled hybrid loop's arrays (every built phase's kernel loop packed), or None where it cannot run."""
        built = tuple(k for k in self._steppers)
        cached = self.__dict__.get("_packed")
        if cached is not None and cached[0] == built:
            return cached[1]
        arrays = self.hybrid._kernel  # (the event step: built at the first call)
        self._packed = (built, self._built(("loops", built), lambda: self._pack(arrays)))
        return self._packed[1]

    def _pack(self, arrays):
        """:meth:`_compiled`'s arrays of the steppers built so far and the event step's ``arrays``, or None."""
        kh = _kernel_hybrid()
        packed = None
        loops = {key: st.loop for key, st in self._steppers.items()}
        base = loops.get("flexible")
        if arrays is not None and base is not None and all(
            lp is not None and lp._dp is arrays[7] and lp._lp is arrays[11] for lp in loops.values()
        ):
            have = np.zeros(len(kh.PHASE_SIZE), dtype=np.int64)
            offsets = np.zeros((len(kh.PHASE_SIZE), 4), dtype=np.int64)
            reals, ints, r, i = [], [], 0, 0
            for code, key in enumerate(kh.PHASE_KEYS):
                if key == "stick":  # sticking after slip runs on the flexible loop (hybrid_steps)
                    have[code] = 2
                elif key in loops:
                    have[code] = 2
                    lp = loops[key]
                    offsets[code] = r, r + lp.reals.size, i, i + lp.ints.size
                    reals.append(lp.reals)
                    ints.append(lp.ints)
                    r, i = r + lp.reals.size, i + lp.ints.size
                elif key in self._factories:
                    have[code] = 1
            have[kh.STEPWISE] = 2
            Yflex = np.zeros((5, 4))
            W = self.plant.wheel_map
            Yflex[0], Yflex[1, 1], Yflex[2], Yflex[3] = W[0], 1.0, W[1], W[3]
            packed = (have, np.concatenate(reals), np.concatenate(ints), offsets, Yflex,
                      np.ascontiguousarray(self._M_inv), arrays)  # fmt: skip
        return packed

    def _advance_steps(self, state: SlipState, t0: float, t1: float, record=None, events=None) -> SlipState:
        """:meth:`advance` phase by phase through the steppers, each event step by the hybrid stepper."""
        t = float(t0)
        while t < t1:
            if state.kind == "hybrid":  # a belt with mass slipping: step by step on the stepper's plan
                a, e, whole, lo, hi, cuts = self.stepper.next_step(t, t1)
                y, mode, sigma = self.hybrid.advance(a, e, state.x, state.mode, state.sigma, cuts, events,
                                                     self.dt if whole else None, hi)  # fmt: skip
                self._check(e, y)
                if record is not None:
                    record.append((np.array([e]), y[None, :], mode, sigma))
                state, t = self._native(y, mode, sigma), e
                continue
            st = self.phase_stepper((state.kind, state.sigma) if state.kind in ("slip", "mass") else state.kind)
            times, xs = st.run(state.x, t, t1)  # (it stops at the step its guard fires in)
            stop = st.stopped
            n = len(times) - 1 if stop is None else stop[0]
            if record is not None and n:
                record.append((times[1 : n + 1], self.ys(state.kind, xs[1 : n + 1]), state.mode, state.sigma))
            if stop is None:
                state, t = SlipState(state.mode, state.sigma, state.kind, xs[-1]), float(times[-1])
                continue
            # the guard fired in step j: the hybrid stepper redoes it with the event located
            j, a, e, whole, lo, hi, cuts = stop
            y0 = self.ys(state.kind, xs[j : j + 1])[0]
            y1 = None if cuts else self.ys(state.kind, xs[j + 1 : j + 2])[0]
            y, mode, sigma = self.hybrid.advance(a, e, y0, state.mode, state.sigma, cuts, events, self.dt if whole else None,
                                                 hi, y1)  # fmt: skip
            self._check(e, y)
            if record is not None:
                record.append((np.array([e]), y[None, :], mode, sigma))
            state, t = self._native(y, mode, sigma), e
        return state

    def _check(self, t, y) -> None:
        if not (np.all(np.isfinite(y)) and max(abs(y[2]), abs(y[3])) <= SPEED_LIMIT):
            raise self.stepper.diverged_error(t, y, "slipping")

    def run(self, duration, y0, t0=0.0, progress=None):
        """Integrate ``duration`` [s] from the slipping state ``y0``; returns (time, states, mode, sigma) (the
        :meth:`windows` put together; :attr:`events` the mode switches)."""
        windows = list(self.windows(duration, y0, t0, progress, events=[]))
        return windows[0] if len(windows) == 1 else _joined(windows)  # (one window: already joined)

    def windows(self, duration, y0, t0=0.0, progress=None, window_steps: int | None = None, events=None):
        """:meth:`run` in pieces: yields (time, states, mode, sigma) of consecutive windows.

        The first window starts with the sample at ``t0``; each later one
        starts after the previous one's last sample, so the windows put
        together are :meth:`run`'s arrays. A window spans ``window_steps``
        grid steps (default :data:`RUN_WINDOW_STEPS`, with ``progress`` about 1 %
        of the run, at least 64 steps) plus the event samples in
        it: memory is bounded by the window, not the run. ``events``
        receives the mode switches.
        """
        self.origin = float(t0)
        t1 = float(t0) + float(duration)
        steps = int(window_steps or RUN_WINDOW_STEPS)
        if progress and not window_steps:  # report about every 1 % (as the stepper's chunks do), at least every 64 steps
            steps = min(steps, max(64, int(float(duration) / self.dt) // 100))
        state = self.initial(y0, t0)
        events = [] if events is None else events
        self.events = events  # filled as the run goes (a caller sees them also when the run raises)
        y = self.state_y(state)
        pieces: list = [(np.array([float(t0)]), y[None, :], state.mode, state.sigma)]
        t = float(t0)
        while t < t1:  # progress between windows
            k = math.floor((t - self.origin) / self.dt) + steps
            while self.stepper.grid_time(k) <= t:  # (t a rounding past its knot: a window of 1 step still advances)
                k += 1
            t_next = self.stepper.grid_time(k) if self.stepper.grid_time(k) < t1 - snap_tolerance(t1, self.dt) else t1
            state = self.advance(state, t, t_next, pieces, events)
            t = t_next
            if pieces:  # (a window whose one step ended on the last one's last sample holds none)
                yield _joined(pieces)
            pieces = []
            if progress:
                progress((t - t0) / max(duration, 1e-300))
        if pieces:
            yield _joined(pieces)
        self.events = events
        if progress:
            progress(1.0)

    def input_array(self, time, states):
        """u = [drive, load] per sample (the load at phi_3 with the slip part)."""
        phi_M, omega_M = states[:, 0], states[:, 2]
        t = np.asarray(time, dtype=float)
        u = np.empty(t.shape + (2,))  # (each column written once: no stacked copy converted again)
        u[..., 0] = self.plant.drive.torque(t, phi_M, omega_M)
        u[..., 1] = self.plant.load.torque(t, self.model.phi_3(states), states[:, 3])
        return u


#: per (parameter set, drive, load) objects: the slipping model, its phases' plants, the packed event-step arrays
#: per method and the lazy simulators' steppers (:func:`_shared_phases`); the least recently used of more than :data:`_SHARED_SIZE` is dropped
_SHARED: dict = {}
_SHARED_SIZE = 8


def _shared_phases(params, drive, load, plant) -> dict:
    """The read-only parts of one scene's slipping engine, ``{"model": SlippingBeltModel, "maps": ..., phase key: Plant,
    ("pack", method): event-step arrays}`` and the steppers of :meth:`SlippingSimulator._built`, filled as simulators
    need them and shared by all of them (the run, its rerun at 2 dt, the next run): matrices, profile data and
    steppers, never a state or a verdict. Kept on the rule
    of :func:`~belt_drive_ros.core.stepper.shared_plant` for the flexible ``plant``, else a fresh dict."""
    return built_once(_SHARED, _SHARED_SIZE, (params, drive, load), lambda: _scene_parts(params, plant),
                      keep=lambda _: is_shared(plant))


def rerun_simulator(params, drive, load, method: str, dt: float, method_options=None) -> SlippingSimulator:
    """A lazy unguarded :class:`SlippingSimulator` of ``method`` at ``dt`` for the accuracy rerun
    (:func:`~belt_drive_ros.core.accuracy.slip_run_error`), kept in the scene's :func:`_shared_phases` per method,
    step, options and thread: what it holds (steppers, packed loops, work arrays) are numbers of the scene, never a
    state or a result between advances. Each call gives its steppers origin 0 and the plant's breakpoints, as a new
    one's constructor does (a simulator sharing them may have moved them); the caller sets its event step
    (``_hybrid``). A scene whose plant is not kept gets a new one."""
    plant = shared_plant(make_model("flexible", params), drive, load)
    shared = _shared_phases(params, drive, load, plant)
    key = ("rerun", method, float(dt), repr(sorted(dict(method_options or {}).items())), threading.get_ident())
    sim = shared.pop(key, None)  # (put back last: the most recently used, see _kept)
    if sim is None:
        sim = SlippingSimulator(params, drive, load, method, dt, method_options, check_stability=False, lazy=True)
        return _kept(shared, key, sim, True) if is_shared(plant) else sim
    for st in sim._steppers.values():
        st.origin, st.breakpoints = 0.0, sim.plant.breakpoints
    return _kept(shared, key, sim, False)


#: per-step entries (keys of 5 items: a lazy simulator's steppers and packed loops, the rerun's simulators) one
#: scene's :func:`_shared_phases` keeps: the least recently used beyond these are dropped (a study of one scene over
#: many steps adds ~4 a step, ~250 kB; a step used again builds its own anew: the same numbers)
_STEP_ENTRIES = 96


def _kept(shared: dict, key: tuple, value, new: bool):
    """``value``, kept as ``shared[key]`` (a per-step entry, taken out by the caller: it goes back last); when
    ``new``, the least recently used per-step entries beyond :data:`_STEP_ENTRIES` are dropped."""
    shared[key] = value
    if new:
        steps = [k for k in list(shared) if type(k) is tuple and len(k) == 5]  # (in use order, oldest first)
        for k in steps[: max(0, len(steps) - _STEP_ENTRIES)]:
            shared.pop(k, None)  # (another thread may drop the same one meanwhile)
    return value


def _scene_parts(params, plant) -> dict:
    """:func:`_shared_phases`' first entries: the model and ``"maps"``, ``(M^-1, the capstan check as a guard on the
    flexible state, the stick guard on y)`` with ``[phi_M, theta_e, omega_M, omega_3] = M x`` of a flexible state x."""
    model = SlippingBeltModel(params)
    # wheel map rows: phi_M, omega_M, phi_3, omega_3
    M = np.array([[1, 0, 0, 0], [params.ratio, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float) @ plant.wheel_map
    stick = model.guard(STICK)
    return {"model": model, "maps": (np.linalg.inv(M), _mapped(stick, np.vstack([M, np.zeros((1, 4))])), stick)}


def _kernel_hybrid():
    """The compiled hybrid loop's module :mod:`~belt_drive_ros.core.kernel_hybrid` (imported at a run's first use, so
    importing this module imports no compiler; then kept: a relative import costs ~7 us at every call)."""
    global _KH
    if _KH is None:
        from . import kernel_hybrid

        _KH = kernel_hybrid
    return _KH


_KH = None


def _kind_code(state: SlipState) -> int:
    """The compiled loop's phase kind of a hybrid state."""
    kh = _kernel_hybrid()
    if state.kind in ("slip", "mass"):
        return kh.PHASE_KEYS.index((state.kind, 1.0 if state.sigma > 0.0 else -1.0))
    return kh.KIND_NAMES.index(state.kind)  # flexible, stick, hybrid: one kind each


def _events(rows) -> list:
    """:class:`~belt_drive_ros.core.slip.Event` of the compiled loop's event rows."""
    rows = rows.copy()  # one copy: each event's state a row of it
    kinds = ["onset" if k else "restick" for k in rows[:, 1].tolist()]
    return list(map(Event, rows[:, 0].tolist(), kinds, rows[:, 2].tolist(), rows[:, 3:]))


def _joined(pieces):
    """(time, states, mode, sigma) of recorded pieces (``advance``'s, or :meth:`~SlippingSimulator.windows`') joined."""
    time = np.concatenate([p[0] for p in pieces])
    states = np.concatenate([p[1] for p in pieces])
    modes = np.concatenate([np.full(len(p[0]), p[2], dtype=np.int8) for p in pieces])
    sigmas = np.concatenate([np.full(len(p[0]), p[3]) for p in pieces])
    return time, states, modes, sigmas


def warm_hybrid() -> None:
    """Compile (or load from the disk cache) :func:`~.kernel_slip.event_step`, :func:`~.kernel_slip.locate_event`
    (:func:`warm_events`) and :func:`~.kernel_hybrid.hybrid_steps` with the one signature runs use (a short run that
    slips at once, a drive torque far past the capstan limit, takes the entry points every run takes)."""
    warm_events().run(5e-3, np.zeros(5))


def warm_events() -> SlippingSimulator:
    """Compile (or load) the event step (:func:`~.kernel_slip.event_step`, and with it the ``_event_step`` the hybrid
    loop calls) and :func:`~.kernel_slip.locate_event`: they call no linear loop, so the warm compiles them while the
    linear loops are still being compiled elsewhere (a lazy simulator: one built eagerly loads the hybrid loop, and
    with it the linear loops). Returns the simulator of :func:`warm_hybrid`'s run."""
    from . import kernel_slip as ks
    from .params import BeltDriveParams
    from .sources import Constant

    sim = SlippingSimulator(BeltDriveParams(), Constant(5000.0), Constant(0.0), "etd4", 1e-3, check_stability=False,
                            lazy=True)  # fmt: skip
    sim.hybrid.advance(0.0, 1e-3, np.zeros(5), STICK, 0.0)
    arrays = sim.hybrid._kernel
    ks.locate_event(STICK, 0.0, 0.0, np.zeros(5), 1e-3, math.inf, np.zeros(5), *arrays[:3], *arrays[4:])
    return sim
