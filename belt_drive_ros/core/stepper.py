"""The one engine that advances time: a plant from scene time t0 to t1.

Every caller that moves a simulation forward (offline runs, replay, the guards' runs, the node's tick where its
compiled tick does not serve it) goes through :class:`Stepper`: it plans the steps (grid, partial steps, steps split
or clamped at torque breakpoints) and hands them to the one compiled time loop
(:func:`~belt_drive_ros.core.kernel.linear_steps`), which steps, clamps the torque times, checks divergence and the
guard. :meth:`Stepper.advance` gives the state at ``t1``, :meth:`Stepper.run` every knot from ``t0`` to ``t1``.
States are 1-D float arrays in the model's own ordering; the **second half of the state holds speeds** [rad/s] (the
divergence check reads them). Torques [N m], times [s].

The grid
--------
Whole steps lie on the fixed grid ``g_k = origin + k dt`` (``k`` integer; the float product and sum, computed the
same way for every caller, so a node ticking on grid times and an offline run see bit-identical times). An advance
from ``t0`` to ``t1`` takes a partial step from ``t0`` to the next grid time when ``t0`` is off the grid, whole
steps up to the last grid time not after ``t1``, and a partial step to ``t1`` when ``t1`` is off the grid: a run of
``duration`` ends at ``duration`` exactly, its last step shortened. A time within :func:`snap_tolerance` of a grid
time (``1e-9 dt`` or 8 ulps, whichever is larger) counts as that grid time.

Breakpoints
-----------
``plant.breakpoints`` (times where a torque jumps or kinks) are handled exactly wherever they fall. A breakpoint
strictly inside a step splits the step there (sub-steps by integrators of the sub-step's length); one on a knot
(within the snap tolerance) bounds the steps on either side. Every torque sample of a (sub-)step is taken at a time
clamped into the step's side: the step that ends at breakpoint ``b`` samples at most at ``plant.left_of(b)`` (the
left limit), the step that starts there at least at ``b``, so no step integrates across a jump or a kink and each
method keeps its order. Runs of whole steps, clamped ones included, are one compiled call
(:func:`~belt_drive_ros.core.kernel.clamped_steps`: a torque recorded at the step rate, a breakpoint on every knot,
is planned by numpy and stepped in one call, each step with its own clamps); each piece of a split or partial step is
one kernel call; an adaptive method (scipy's references) steps through ``integrator.step``. A torque profile without
a data form is refused.

Integrators (and kernel loops) of partial-step lengths are cached per stepper (at most :data:`PARTIAL_CACHE_SIZE`);
plant torques are read at every call (a held torque may change between advances).

Divergence
----------
A state that is non-finite or has a speed beyond :data:`SPEED_LIMIT` raises
:class:`~belt_drive_ros.core.errors.SimulationDivergedError` naming the time, model, method and step (the kernel
checks after every step and stops there; :meth:`run` reports the first bad sample).
"""

from __future__ import annotations

import math
import threading
from bisect import bisect_left, bisect_right
from typing import Callable

import numpy as np

from .errors import SceneError, SimulationDivergedError
from .identity_cache import built_once
from .integrators import FixedStepIntegrator, make_integrator
from .kernel_loop import DIVERGED, GUARDED, NOT_CONVERGED
from .model import WHEEL_ROWS, _LinearModel

#: Speeds beyond this [rad/s] (~955,000 rpm) mean the numerics, not the physics, blew up.
SPEED_LIMIT = 1.0e5
#: partial-step integrators kept per stepper (one per distinct length)
PARTIAL_CACHE_SIZE = 4096
#: a time this close to a grid time, relative to dt, is on the grid
GRID_TOLERANCE = 1e-9
#: steps per call of the compiled loop between divergence checks and progress reports
CHUNK = 4096
#: steps of a paged drive's page beyond each end of a run (:meth:`Stepper._paged`)
PAGE_MARGIN = 4
#: an advance over at least this many breakpoints looks for steps it can absorb (:mod:`~belt_drive_ros.core.absorb`)
ABSORB_MIN = 16
#: plans of :meth:`Stepper.run` kept per stepper (the guards' windows and the run repeat theirs), of so many special steps
PLAN_CACHE_SIZE, PLAN_SPECIAL = 8, 64
#: state rows a guarded run (it may stop at its first steps) allocates first; twice as many each time they are full
GUARDED_ROWS = 1024
_NO_CELLS = np.empty(0, dtype=np.int64)


def snap_tolerance(t: float, dt: float) -> float:
    """Distance [s] within which time ``t`` counts as on a grid time or a breakpoint: max(1e-9 dt, 8 ulp(t))."""
    return max(GRID_TOLERANCE * dt, 8.0 * math.ulp(abs(t)))


class Plant:
    """Model + drive + load: the input function ``u(t, x) = [drive, load]`` [N m].

    ``inputs(t, x)`` takes one state (1-D) and returns a (2,) array; it calls the profiles' scalar closures
    (:meth:`~belt_drive_ros.core.sources.TorqueProfile.scalar_torque`), which skip numpy's per-call overhead.
    ``wheel_map`` is the (4, n) matrix W with ``[phi_M, omega_M, phi_3, omega_3] = W x`` (the kernel loop reads it
    as a matrix and :meth:`inputs` applies it, so any state ordering works).
    """

    def __init__(self, model, drive, load, extra=()):
        self.model, self.drive, self.load = model, drive, load
        #: inputs after the two torques, functions of the drive speed (:class:`~belt_drive_ros.core.kernel_loop.FrictionForce`)
        self.extra = tuple(extra)
        self.scalar_drive = drive_torque = drive.scalar_torque()
        self.scalar_load = load_torque = load.scalar_torque()
        # a rigid or flexible model's wheel map is its C rows (built once, the same floats); another model's is read
        self.wheel_map = W = (model.wheel_map if isinstance(model, _LinearModel) and np.ndim(model.A) == 2
                              else np.array(model.wheel_coordinates(np.eye(model.A.shape[0])), dtype=float))
        #: (drive, load): whether each torque reads its angle; their kernel data (None: a Python-only profile)
        self.uses_angle = (bool(drive.uses_angle), bool(load.uses_angle))
        #: a drive read a page at a time (``drive.page(t0, t1)``, a recording too long to hold): steppers
        #: run on the plant of the page of each run (:meth:`page`); the plant itself has no data nor breakpoints
        self.paged = getattr(drive, "page", None) is not None
        self.data = (None if self.paged else drive.data(), load.data())
        #: sorted distinct finite times [s] at which either torque jumps or kinks (TorqueProfile.breakpoints), float64
        #: (a recorded drive has one per sample: an array, never a list of floats); None for a paged drive
        self.breakpoints = None if self.paged else _merged(drive.breakpoints(), load.breakpoints())
        if self.breakpoints is not None:  # read-only: steppers keep plans by it (Stepper.breakpoints)
            self.breakpoints.flags.writeable = False
        array = np.array
        angle_M, speed_M, angle_3, speed_3 = (_coordinate(row) for row in W)

        def inputs(t, x):
            return array([drive_torque(t, angle_M(x), speed_M(x)), load_torque(t, angle_3(x), speed_3(x))])

        if self.extra:  # the same operations as the kernel's, as functions of omega_M
            extras = [f.value for f in self.extra]

            def inputs(t, x):  # noqa: F811
                w = speed_M(x)
                return array([drive_torque(t, angle_M(x), w), load_torque(t, angle_3(x), speed_3(x)), *(f(w) for f in extras)])

        self.inputs = inputs

    def page(self, t0: float, t1: float) -> "Plant":
        """This plant with the drive's page on ``[t0, t1]`` [s] (the same torques and breakpoints there)."""
        return Plant(self.model, self.drive.page(t0, t1), self.load, self.extra)

    def breakpoint_pieces(self, lo: float, hi: float, span: float):
        """The breakpoints strictly between ``lo`` and ``hi`` [s] as consecutive sorted arrays (one for a plain
        plant; a paged one: page by page, pages of ``span`` [s]), so a whole run's are never held at once."""
        if not self.paged:
            b = self.breakpoints
            yield b[(b > lo) & (b < hi)]
            return
        load = np.asarray(self.load.breakpoints(), dtype=np.float64).ravel()
        a = lo
        while a < hi:
            b = min(hi, a + span)
            both = _merged(self.drive.page(a, b).breakpoints(), load)
            yield both[(both > a) & ((both <= b) if b < hi else (both < hi))]
            a = b

    def kernel_loop(self, integrator, guard=None):
        """The compiled loop (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`) of ``integrator`` for this plant, or None.

        None for an adaptive method, a Python-only profile (a stepper refuses it) or complex matrices: those step
        through ``integrator.step``. An implicit method's stage is solved in the loop with the extra inputs (the
        slip force) among its fixed point's unknowns, as ``integrator.step`` solves it (the same floats).
        ``guard``: a :class:`~belt_drive_ros.core.stage_scheme.Guard` the loop checks after every step.
        """
        if not isinstance(integrator, FixedStepIntegrator) or None in self.data:
            return None
        from .kernel_loop import KernelLoop

        scheme = integrator.scheme
        if not KernelLoop.usable(scheme):
            return None
        return KernelLoop(scheme, integrator.dt, self.wheel_map, self.uses_angle, *self.data, self.extra, guard)

    def left_of(self, b: float) -> float:
        """Latest time [s] before breakpoint ``b`` at which both torques still give their values from the left."""
        return min(self.drive.left_of(b), self.load.left_of(b))

    def left_of_array(self, b: np.ndarray) -> np.ndarray:
        """:meth:`left_of` of each breakpoint of ``b`` (float64), the same floats."""
        from .absorb import left_of_array

        return np.minimum(left_of_array(self.drive, b), left_of_array(self.load, b))

    def input_array(self, t: np.ndarray, x: np.ndarray, cx: np.ndarray | None = None) -> np.ndarray:
        """Vectorized u for samples ``t`` (N,), ``x`` (N, n) -> (N, 2) (``cx``: a linear model's
        :meth:`~belt_drive_ros.core.model._LinearModel.state_part` of ``x``, its wheel coordinates read off it)."""
        if cx is None:
            phi_M, omega_M, phi_3, omega_3 = self.model.wheel_coordinates(x)
        else:
            phi_M, omega_M, phi_3, omega_3 = (cx[..., j] for j in WHEEL_ROWS)
        t = np.asarray(t, dtype=float)
        u = np.empty(t.shape + (2,))
        u[..., 0] = self.drive.torque(t, phi_M, omega_M)
        u[..., 1] = self.load.torque(t, phi_3, omega_3)
        return u


#: plants by (model, drive, load) of a linear model shared by :func:`~belt_drive_ros.core.model.make_model`: their
#: closures and arrays depend on those objects only (a held torque's value is read live), so the model choice,
#: the guards and the run of one scene share one; a recorded profile's (many breakpoints) is not kept
_PLANTS: dict = {}
_PLANT_CACHE_SIZE = 8


def shared_plant(model, drive, load) -> Plant:
    """``Plant(model, drive, load)``, built once per (model, drive, load) objects (see :data:`_PLANTS`)."""
    return built_once(_PLANTS, _PLANT_CACHE_SIZE, (model, drive, load), lambda: Plant(model, drive, load),
                      keep=lambda plant: plant.breakpoints is not None and len(plant.breakpoints) <= 64)  # None: paged


def is_shared(plant) -> bool:
    """Whether ``plant`` is one :func:`shared_plant` keeps (what is built from it may be kept too)."""
    return any(value is plant for _, value in list(_PLANTS.values()))


#: steppers of a shared plant (:func:`shared_stepper`), by (plant, method, dt, options)
_STEPPERS: dict = {}


def shared_stepper(plant, method: str, dt: float, method_options=None) -> "Stepper":
    """``Stepper(plant, method, dt, method_options)`` (origin 0, no guard), built once per plant of
    :func:`shared_plant` and method, step and options: what the guards' runs (the rigid survey, the forcing
    windows) step with. Read-only to them: they never set its origin or breakpoints, and every run starts
    from the state it is given (a run's outcome does not depend on the runs before it). One per thread: a
    stepper notes the run it makes (``stopped``, ``split_steps``), so two threads never share one."""
    options = dict(method_options or {})
    extra = (method, float(dt), repr(sorted(options.items())), threading.get_ident())
    return built_once(_STEPPERS, 4 * _PLANT_CACHE_SIZE, (plant,), lambda: Stepper(plant, method, dt, options), extra,
                      keep=lambda _: is_shared(plant))  # (a plant made once for one caller: not kept)


def _merged(drive, load) -> np.ndarray:
    """Sorted distinct finite times [s] of two profiles' breakpoints (float64)."""
    if type(drive) is tuple and type(load) is tuple:  # a few times (the formula profiles'): in Python, the same floats
        values = [float(b) for b in (*drive, *load)]
        values = [b for b in values if math.isfinite(b)]
        both = np.array(values, dtype=np.float64)
        return both if all(a < b for a, b in zip(values, values[1:])) else np.unique(both)
    both = np.concatenate([np.asarray(drive, dtype=np.float64).ravel(), np.asarray(load, dtype=np.float64).ravel()])
    both = both[np.isfinite(both)]
    return both if np.all(both[1:] > both[:-1]) else np.unique(both)  # a table's: sorted already


def _reduced(keys: np.ndarray, values: np.ndarray, ufunc) -> tuple[np.ndarray, np.ndarray]:
    """(distinct ``keys`` (sorted), ``ufunc`` (np.maximum, np.minimum) of the ``values`` of each)."""
    if keys.size == 0:
        return keys, values
    at = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    return keys[at], ufunc.reduceat(values, at)


def _clamp_count(plan: dict) -> int:
    """Special steps of a plan, counting those of its knots' arrays (:meth:`Stepper._knot_clamps`): an upper bound."""
    return len(plan["special"]) + (plan["knots"][0].size if plan["knots"] is not None else 0)


def _search(bps, x: float, right: bool) -> int:
    """:func:`bisect.bisect_left` (``right``: ``bisect_right``) of ``x`` in the sorted ``bps`` (list or array)."""
    if isinstance(bps, np.ndarray):
        return int(bps.searchsorted(x, side="right" if right else "left"))
    return bisect_right(bps, x) if right else bisect_left(bps, x)


def _coordinate(row: np.ndarray) -> Callable:
    """``x -> row @ x`` for one wheel coordinate, as a plain index or a scaled index when it is one."""
    nonzero = [(j, c) for j, c in enumerate(np.asarray(row, dtype=float).tolist()) if c != 0.0]
    if len(nonzero) == 1:
        j, c = nonzero[0]
        return (lambda x: x[j]) if c == 1.0 else (lambda x: c * x[j])

    def coordinate(x):  # summed from the left, as the compiled loop's expression (a BLAS dot may pair terms)
        total = 0.0
        for j, c in nonzero:
            total = total + c * float(x[j])
        return total

    return coordinate


def _healthy(x) -> bool:
    """Finite state with every speed (second half) within :data:`SPEED_LIMIT`."""
    values = x.tolist() if isinstance(x, np.ndarray) else list(x)
    # the sum is finite only when every entry is (a NaN or an inf propagates; a finite overflow is beyond the limit)
    return math.isfinite(sum(values)) and max(map(abs, values[len(values) // 2 :])) <= SPEED_LIMIT


class Stepper:
    """Advances one plant with one method on the grid ``origin + k dt`` (see the module docstring).

    Parameters
    ----------
    plant : :class:`Plant`.
    method : integrator name; dt : step [s]; method_options : passed to it.
    origin : scene time [s] of grid index 0.
    integrator : an integrator of ``method`` and ``dt`` built for the plant's model (the node's holds one), else made.
    guard : optional :class:`~belt_drive_ros.core.stage_scheme.Guard`: :meth:`run` stops after the first step whose
        end state makes it positive (a mode switch of the slipping belt lies in that step; see ``stopped``).

    Attributes
    ----------
    breakpoints : sorted times [s] where steps are split or bounded (the plant's; a caller assigns new ones), a
    tuple or a read-only float64 array (a list or writable array assigned is copied): plans are kept by it.
    split_steps : ``{grid index k: [breakpoints inside step k]}`` of the last :meth:`run` or :meth:`advance`.
    loop : the compiled loop of whole steps (None: each step through ``integrator.step``).
    stopped : after a :meth:`run` the guard stopped, ``(j, a, e, whole, lo, hi, cuts)``: its step ``j`` as
        :meth:`steps` describes one; else None.
    """

    #: a breakpoint this close to a grid point (relative to dt) is on the grid (read by :mod:`.absorb`)
    grid_tolerance = GRID_TOLERANCE

    def __init__(
        self, plant: Plant, method: str, dt: float, method_options=None, origin: float = 0.0, integrator=None, guard=None
    ):
        self.plant = plant
        self.method, self.dt, self.origin = method, float(dt), float(origin)
        self.method_options = dict(method_options or {})
        model = plant.model
        python_only = [p.kind or type(p).__name__ for p, d in zip((plant.drive, plant.load), plant.data)
                       if d is None and not (p is plant.drive and plant.paged)]  # fmt: skip
        if python_only:
            raise SceneError(f"torque profile {python_only[0]!r} has no data form (TorqueProfile.encode): the linear "
                             "models step compiled profiles only")  # fmt: skip
        self.integrator = integrator or make_integrator(method, model.A, model.B, self.dt, **self.method_options)
        self.guard = guard
        self.loop = plant.kernel_loop(self.integrator, guard)
        self.breakpoints = plant.breakpoints
        self._end = None  # the loop of absorbed steps (absorb.end_loop)
        self.stopped: tuple | None = None
        self.split_steps: dict = {}
        self._partials: dict = {}
        self._loops: dict = {}  # kernel loops of the partial-step integrators, by step length
        self._free: tuple | None = None  # the breakpoint-free interval the last tick fell in (_near_breakpoint)
        self._plans: dict = {}  # (t0, t1, origin, id(breakpoints)) -> (breakpoints, plan) of run()
        self._clean = False  # the last grouped march ran every step to the end without a failing status

    @property
    def breakpoints(self):
        return self._breakpoints

    @breakpoints.setter
    def breakpoints(self, value) -> None:
        if isinstance(value, np.ndarray) and (value.flags.writeable or value.base is not None):  # (a view's base may)
            value = np.array(value, dtype=np.float64)
            value.flags.writeable = False
        elif not isinstance(value, (np.ndarray, tuple, type(None))):  # (None: a paged plant's, read page by page)
            value = tuple(value)
        self._breakpoints = value

    # ------------------------------------------------------------ public
    def advance(self, x: np.ndarray, t0: float, t1: float) -> np.ndarray:
        """State at ``t1`` [s] from ``x`` at ``t0`` [s] (``t1 >= t0``); raises SimulationDivergedError."""
        if t1 < t0:
            raise ValueError(f"advance: t1 ({t1!r} s) is before t0 ({t0!r} s)")
        x = np.ascontiguousarray(x, dtype=np.float64)
        if t1 == t0:
            return x
        if self.plant.paged:
            return self._paged(t0, t1).advance(x, t0, t1)
        if self.guard is not None:
            raise ValueError("advance: a guarded stepper is run with run() (it may stop early)")
        plan = self._plan(t0, t1, absorb=True)
        out = self._march(x, plan, None, record=False)
        if not _healthy(out):
            raise self.diverged_error(t1, out)
        return out

    def run(self, x0, t0: float, t1: float, progress: Callable[[float], None] | None = None):
        """(times (N+1,), states (N+1, n)) at every knot from ``t0`` to ``t1`` [s] (both exactly, included)."""
        x0 = np.asarray(x0, dtype=float)
        if t1 < t0:
            raise ValueError(f"run: t1 ({t1!r} s) is before t0 ({t0!r} s)")
        if self.plant.paged:
            page = self._paged(t0, t1)
            try:
                return page.run(x0, t0, t1, progress)
            finally:
                self.split_steps, self.stopped = page.split_steps, page.stopped
        plan = self._run_plan(t0, t1)
        self.stopped = None
        if (self.loop is not None and not plan["empty"] and not plan["lead"] and not plan["trail"]
                and not plan["absorbed"].size and not self.split_steps):
            # whole grid steps, breakpoints on knots only: one compiled call (per progress report); the knots the grid's
            states, times = self._march_grouped(x0, plan, progress)
            times[0] = t0
            if times.size == plan["last"] - plan["first"] + 2:
                times[-1] = t1
        else:
            times = self._knots(plan)
            states = self._march(x0, plan, progress, record=True)
        if self.stopped is not None:
            j = self.stopped[0]
            times, states = times[: j + 2], states[: j + 2]
        clean, self._clean = self._clean, False  # the grouped march's kernel checked every step and none failed
        if not (clean and _healthy(states[-1])):
            bad = ~np.all(np.isfinite(states), axis=1) | np.any(np.abs(states[:, states.shape[1] // 2 :]) > SPEED_LIMIT, axis=1)
            if np.any(bad):
                k = int(np.argmax(bad))
                raise self.diverged_error(float(times[k]), states[k])
        if progress:
            progress(1.0)
        return times, states

    def _run_plan(self, t0: float, t1: float) -> dict:
        """:meth:`_plan` of a run (absorbed steps looked for); the last :data:`PLAN_CACHE_SIZE` kept by their ends,
        origin and (immutable) breakpoints, those of at most :data:`PLAN_SPECIAL` special steps."""
        key = (t0, t1, self.origin, id(self.breakpoints))
        hit = self._plans.get(key)
        if hit is not None and hit[0] is self.breakpoints:
            self.split_steps = {c: list(e[2]) for c, e in hit[1]["special"].items() if e[2]}
            return hit[1]
        plan = self._plan(t0, t1, absorb=True)
        if not plan["absorbed"].size and _clamp_count(plan) <= PLAN_SPECIAL:
            if len(self._plans) >= PLAN_CACHE_SIZE:
                self._plans.pop(next(iter(self._plans)))
            self._plans[key] = (self.breakpoints, plan)
        return plan

    def _paged(self, t0: float, t1: float) -> "Stepper":
        """A stepper of this one's settings on the plant's page over ``[t0, t1]`` widened by
        :data:`PAGE_MARGIN` steps each side (every breakpoint a plan or an absorbed step there looks at)."""
        m = PAGE_MARGIN * self.dt
        page = Stepper(self.plant.page(t0 - m, t1 + m), self.method, self.dt, self.method_options, self.origin,
                       self.integrator, self.guard)
        page._partials = self._partials  # (the partial steps' integrators depend on the model only)
        return page

    def _near_breakpoint(self, t0: float, t1: float, k0: int, k1: int) -> bool:
        """Whether a breakpoint lies in the grid steps k0 .. k1 (within the snap tolerance)."""
        bps = self.breakpoints
        if len(bps) == 0:
            return False
        g0, g1 = self.grid_time(k0), self.grid_time(k1)  # (the tolerance at least each end's: what _plan searches)
        tol = snap_tolerance(max(abs(t0), abs(t1), abs(g0), abs(g1)), self.dt)
        a, b = min(t0, g0) - tol, max(t1, g1) + tol
        free = self._free  # (breakpoints, L, R): no breakpoint in the open interval (L, R) of that list
        if free is not None and free[0] is bps and free[1] < a and b < free[2]:
            return False
        i = _search(bps, a, False)
        if i != _search(bps, b, True):
            return True
        self._free = (bps, float(bps[i - 1]) if i else -math.inf, float(bps[i]) if i < len(bps) else math.inf)
        return False

    def reset(self) -> None:
        """Forget adaptive solver history and the partial-step integrators."""
        self.integrator.reset()
        self._partials.clear()

    def next_step(self, t0: float, t1: float) -> tuple:
        """The first step ``(a, e, whole, lo, hi, cuts)`` of an advance from ``t0`` to ``t1`` [s] (see :meth:`steps`)."""
        plan = self._plan(t0, t1)
        if plan["empty"]:
            return t0, t1, False, -math.inf, math.inf, []
        a, e, whole, lo, hi, cuts = self._step(plan, plan["first"])
        return a, e, whole, lo, hi, list(cuts)

    def steps(self, t0: float, t1: float) -> tuple[np.ndarray, list]:
        """The plan :meth:`run` executes from ``t0`` to ``t1`` [s], for another executor of it.

        Returns ``(times, steps)``: the knot times (N+1,) [s] of :meth:`run`, and per step
        ``(a, e, whole, lo, hi, cuts)``: from ``a`` to ``e`` [s] (``whole``: a full grid step of ``dt``), torque
        samples clamped to ``[lo, hi]``, split at ``cuts`` (each piece's samples clamped to its side, as :meth:`run`
        does). Empty when ``t0`` and ``t1`` share a knot. :class:`~belt_drive_ros.core.ensemble.Ensemble` steps many
        variants of a plant along it.
        """
        plan = self._plan(t0, t1)
        times = self._knots(plan)
        if plan["empty"]:
            return times, []
        steps = [self._step(plan, c) for c in range(plan["first"], plan["last"] + 1)]
        return times, [(*step[:5], tuple(sorted(step[5]))) for step in steps]

    def grid_time(self, k: int) -> float:
        """Grid time ``origin + k dt`` [s] (the float every caller computes)."""
        return self.origin + k * self.dt

    # ------------------------------------------------------------ planning
    def _snap(self, t: float) -> int | None:
        """Index k of the grid time within :func:`snap_tolerance` of ``t``, or None."""
        k = round((t - self.origin) / self.dt)
        return k if abs(self.origin + k * self.dt - t) <= snap_tolerance(t, self.dt) else None

    def _cell(self, t: float) -> int:
        """Index k of the grid cell [g_k, g_k+1) holding off-grid time ``t``."""
        k = math.floor((t - self.origin) / self.dt)
        while self.grid_time(k) > t:
            k -= 1
        while self.grid_time(k + 1) <= t:
            k += 1
        return k

    def _plan(self, t0: float, t1: float, absorb: bool = False) -> dict:
        """Steps from ``t0`` to ``t1``: grid cells first..last, ends, and the steps that touch breakpoints.

        Returns a dict: ``first``, ``last`` (cell indices), ``start``, ``end`` (the times of the first and last
        knot: the grid time when ``t0``/``t1`` snap to the grid, else themselves), ``lead``/``trail`` (whether the
        first/last step is partial), ``t0``/``t1`` as given, and ``special = {cell: [lo, hi, cuts]}`` for steps
        whose torque samples are clamped to ``[lo, hi]`` or that are split at ``cuts``; ``absorbed``: the cells
        (sorted int64) :func:`~belt_drive_ros.core.absorb.absorbed_steps` found (``absorb``: look for them);
        ``knots``: with ``absorb`` and many breakpoints, the clamps of those on interior knots as arrays
        ``(cells, lo, hi)`` (:meth:`_knot_clamps`; not in ``special``; :meth:`_step` and :meth:`_clamps` merge them),
        else None.
        """
        k0, k1 = self._snap(t0), self._snap(t1)
        start = self.grid_time(k0) if k0 is not None else t0
        end = self.grid_time(k1) if k1 is not None else t1
        first = k0 if k0 is not None else self._cell(t0)
        last = k1 - 1 if k1 is not None else self._cell(t1)
        empty = last < first  # t0 and t1 on the same grid time (or within its tolerance)
        special: dict = {}
        bps = self.breakpoints
        tol0, tol1 = snap_tolerance(start, self.dt), snap_tolerance(end, self.dt)
        if empty or (k0 is not None and k1 is not None and not self._near_breakpoint(t0, t1, k0, k1)):
            near = ()  # (whole grid steps in a breakpoint-free interval the last run or tick found: no search)
        else:
            near = bps[_search(bps, min(t0, start) - tol0, False) : _search(bps, max(t1, end) + tol1, True)]
        absorbed = _NO_CELLS
        if absorb and len(near) >= ABSORB_MIN:
            from .absorb import absorbed_steps

            absorbed, skip = absorbed_steps(self, np.asarray(near, dtype=np.float64), first, last)
            if absorbed.size:
                near = np.asarray(near, dtype=np.float64)[~skip]
        taken = set(absorbed.tolist())  # an absorbed step's clamps are accounted for: no special entry
        knots = None
        if absorb and len(near) >= ABSORB_MIN:  # the breakpoints on interior knots as arrays, the others below
            knots, near = self._knot_clamps(np.asarray(near, dtype=np.float64), t0, t1, start, end, first, last, absorbed)

        def entry(c):
            return special.setdefault(c, [-math.inf, math.inf, []]) if c not in taken else [-math.inf, math.inf, []]

        for b in near.tolist() if isinstance(near, np.ndarray) else near:
            if abs(b - start) <= max(tol0, snap_tolerance(b, self.dt)) or abs(b - t0) <= tol0:
                e = entry(first)
                e[0] = max(e[0], b)
                continue
            if abs(b - end) <= max(tol1, snap_tolerance(b, self.dt)) or abs(b - t1) <= tol1:
                e = entry(last)
                e[1] = min(e[1], self.plant.left_of(b))
                continue
            if not start < b < end:
                continue
            k = self._snap(b)
            if k is not None:  # on a grid knot inside the advance
                if first <= k - 1:
                    e = entry(k - 1)
                    e[1] = min(e[1], self.plant.left_of(b))
                if k <= last:
                    e = entry(k)
                    e[0] = max(e[0], b)
            else:
                entry(min(max(self._cell(b), first), last))[2].append(b)
        self.split_steps = {c: list(e[2]) for c, e in special.items() if e[2]}
        return dict(
            t0=t0, t1=t1, start=start, end=end, first=first, last=last, empty=empty,
            lead=k0 is None, trail=k1 is None, special=special, absorbed=absorbed, knots=knots,
        )  # fmt: skip

    def _knot_clamps(self, bps: np.ndarray, t0: float, t1: float, start: float, end: float, first: int, last: int,
                     absorbed: np.ndarray) -> tuple:
        """``((cells, lo, hi), the other breakpoints)``: the clamps that the breakpoints ``bps`` (sorted) on interior
        knots put on the steps either side (:meth:`_plan`'s rule, the same floats, as arrays: a torque recorded at
        the step rate has one on every knot), cells sorted, ``-inf``/``inf`` where a side has none; the absorbed
        cells left out. The others (near the ends, off the grid) for :meth:`_plan`'s loop."""
        dt = self.dt
        tol_b = np.maximum(GRID_TOLERANCE * dt, 8.0 * np.spacing(np.abs(bps)))  # snap_tolerance of each
        tol0, tol1 = snap_tolerance(start, dt), snap_tolerance(end, dt)
        kf = np.rint((bps - self.origin) / dt)  # _snap: round half to even
        at_ends = ((np.abs(bps - start) <= np.maximum(tol0, tol_b)) | (np.abs(bps - t0) <= tol0)
                   | (np.abs(bps - end) <= np.maximum(tol1, tol_b)) | (np.abs(bps - t1) <= tol1))  # fmt: skip
        inner = ~at_ends & (bps > start) & (bps < end) & (np.abs(self.origin + kf * dt - bps) <= tol_b)
        k = kf[inner].astype(np.int64)
        b = bps[inner]
        lo_side, hi_side = k <= last, k - 1 >= first
        kl, vl = _reduced(k[lo_side], b[lo_side], np.maximum)  # the step starting at a knot: from its latest breakpoint
        kh, vh = _reduced(k[hi_side] - 1, self.plant.left_of_array(b[hi_side]), np.minimum)  # ending there: the first's left
        if 4 * k.size < last - first + 1:  # a few among many steps: sorted sets (memory of the breakpoints' size)
            cells = np.union1d(kl, kh)
            lo, hi = np.full(cells.size, -math.inf), np.full(cells.size, math.inf)
            lo[np.searchsorted(cells, kl)], hi[np.searchsorted(cells, kh)] = vl, vh
            keep = ~np.isin(cells, absorbed)
            return (cells[keep], lo[keep], hi[keep]), bps[~inner]
        lo, hi = np.full(last - first + 1, -math.inf), np.full(last - first + 1, math.inf)  # by cell (first .. last)
        lo[kl - first], hi[kh - first] = vl, vh
        clamped = (lo != -math.inf) | (hi != math.inf)
        clamped[absorbed - first] = False
        cells = np.flatnonzero(clamped)
        return (cells + first, lo[cells], hi[cells]), bps[~inner]

    def _clamps(self, plan: dict) -> tuple:
        """``(cells, lo, hi, ends)`` of a plan (kept in it): every clamped step's bounds (the special steps' and the
        knots' of :meth:`_knot_clamps`, merged: the latest lo, the earliest hi), cells sorted; ``ends`` the cells that
        end a group of :func:`~belt_drive_ros.core.kernel.clamped_steps` (a finite hi, the cell before a finite lo,
        the last)."""
        if "clamps" not in plan:
            special, knots, first, last = plan["special"], plan["knots"], plan["first"], plan["last"]
            if knots is not None and not special:
                cells, lo, hi = knots
            else:
                cells = np.fromiter(special, dtype=np.int64, count=len(special))
                lo = np.array([e[0] for e in special.values()], dtype=np.float64)
                hi = np.array([e[1] for e in special.values()], dtype=np.float64)
                if knots is not None:
                    cells, lo, hi = (np.concatenate([a, b]) for a, b in zip((cells, lo, hi), knots))
                order = np.argsort(cells, kind="stable")
                cells, lo, hi = cells[order], lo[order], hi[order]
                _, hi = _reduced(cells, hi, np.minimum)
                cells, lo = _reduced(cells, lo, np.maximum)
            if 4 * cells.size < last - first + 1:  # a few clamped steps among many: a sorted set
                ends = np.unique(np.concatenate([cells[hi != math.inf], cells[lo != -math.inf] - 1, [last]]))
            else:  # one a step or so: marks by cell, first - 1 .. last (no sort)
                ends = np.zeros(last - first + 2, dtype=bool)
                ends[cells[hi != math.inf] - first + 1] = True
                ends[cells[lo != -math.inf] - first] = True
                ends[last - first + 1] = True
                ends = np.flatnonzero(ends) + (first - 1)
            plan["clamps"] = (cells, lo, hi, ends.astype(np.int64))
        return plan["clamps"]

    def _step(self, plan: dict, c: int) -> tuple:
        """``(a, e, whole, lo, hi, cuts)`` of the step in cell ``c``: from ``a`` to ``e`` [s] (``whole``: a full grid
        step), torque samples clamped to ``[lo, hi]``, split at ``cuts``."""
        a = plan["start"] if c == plan["first"] else self.grid_time(c)
        e = plan["end"] if c == plan["last"] else self.grid_time(c + 1)
        whole = not ((c == plan["first"] and plan["lead"]) or (c == plan["last"] and plan["trail"]))
        lo, hi, cuts = plan["special"].get(c, (-math.inf, math.inf, ()))
        if plan["knots"] is not None:  # (a clamp of the knots' arrays: merged, as _clamps does)
            cells, klo, khi = plan["knots"]
            i = int(cells.searchsorted(c))
            if i < cells.size and cells[i] == c:
                lo, hi = max(lo, float(klo[i])), min(hi, float(khi[i]))
        return a, e, whole, lo, hi, cuts

    def _knots(self, plan: dict) -> list:
        """Times of the recorded states: t0, the interior grid times, t1."""
        if plan["empty"]:
            return np.array([plan["t0"]] if plan["t0"] == plan["t1"] else [plan["t0"], plan["t1"]])
        return np.concatenate(([plan["t0"]], self._grid(plan["first"] + 1, plan["last"] + 1), [plan["t1"]]))

    def _grid(self, k0: int, k1: int) -> np.ndarray:
        """Grid times ``origin + k dt`` for k0 <= k < k1 (the float product and sum every caller computes)."""
        return self.origin + self.dt * np.arange(k0, k1, dtype=float)

    # ------------------------------------------------------------ stepping
    def _partial(self, h: float):
        """Integrator of ``method`` for a step of ``h`` [s] (cached)."""
        it = self._partials.get(h)
        if it is None:
            if len(self._partials) >= PARTIAL_CACHE_SIZE:
                self._partials.clear()
                self._loops.clear()
            model = self.plant.model
            it = self._partials[h] = make_integrator(self.method, model.A, model.B, h, **self.method_options)
        return it

    def _loop_of(self, integrator):
        """The kernel loop of ``integrator`` (the stepper's own or a partial step's) for this plant, or None."""
        if integrator is self.integrator:
            return self.loop
        key = integrator.dt
        if key not in self._loops:
            self._loops[key] = self.plant.kernel_loop(integrator) if self.loop is not None else None
        return self._loops[key]

    def _clamped(self, lo: float, hi: float):
        """The plant's inputs with the torque time clamped into [lo, hi] (left/right limits at breakpoints; unclamped:
        the plant's own function, which an adaptive method's solver continues with)."""
        inputs = self.plant.inputs
        if lo == -math.inf and hi == math.inf:
            return inputs
        return lambda t, x: inputs(lo if t < lo else hi if t > hi else t, x)

    def _special_step(self, x: np.ndarray, a: float, e: float, whole: bool, lo: float, hi: float, cuts: list) -> np.ndarray:
        """One step from ``a`` to ``e``, split at ``cuts``, torque samples clamped to each piece's side.

        Each piece is one kernel call (the integrator of the piece's length, its torque times clamped into the
        piece's side of the breakpoints); without a kernel loop (adaptive method) the integrator's reference
        ``step``.
        """
        edges = [a, *sorted(cuts), e]
        n = len(edges) - 1
        for j in range(n):
            p, q = edges[j], edges[j + 1]
            lo_j = lo if j == 0 else edges[j]
            hi_j = hi if j == n - 1 else self.plant.left_of(q)
            it = self.integrator if whole and n == 1 else self._partial(q - p)
            loop = self._loop_of(it)
            if loop is not None:
                out = np.empty((1, x.size))
                done, status, t = loop(np.array([p, q]), np.ascontiguousarray(x, dtype=np.float64), out, lo_j, hi_j,
                                       SPEED_LIMIT)  # fmt: skip
                if status == NOT_CONVERGED:
                    self._not_converged(t)
                x = out[0]
            else:
                x = it.step(p, x, self._clamped(lo_j, hi_j))
        return x

    def _not_converged(self, t: float):
        from .stage_scheme import not_converged

        scheme = self.integrator.scheme
        raise not_converged(self.method, t, scheme.implicit[1], self.dt)

    def _march(self, x: np.ndarray, plan: dict, progress, record: bool):
        """Execute ``plan`` from state ``x``: the states at every knot (record) or the last.

        Runs of whole steps, those clamped at breakpoints on their knots included, are one compiled call each
        (:func:`~belt_drive_ros.core.kernel.clamped_steps`, up to :data:`CHUNK` steps); a partial step or one
        split at a breakpoint inside it (and every step of a stepper without a kernel loop: an adaptive method) is
        :meth:`_special_step`.
        """
        size = x.size
        if plan["empty"]:
            if plan["t0"] == plan["t1"]:
                return x[None, :].copy() if record else x
            # t0 and t1 within the snap tolerance of one grid time: nothing to integrate
            return np.vstack([x, x]) if record else x
        first, last, special = plan["first"], plan["last"], plan["special"]
        n_cells = last - first + 1
        states = np.empty((n_cells + 1, size)) if record else None
        if record:
            states[0] = x
        chunk = CHUNK if not progress else min(CHUNK, max(64, n_cells // 100))
        # the steps taken alone: split ones, the partial ones at the ends (clamps alone: in the compiled runs)
        stops = sorted([c for c, e in special.items() if e[2]] + [first] * plan["lead"] + [last] * plan["trail"])
        hard = set(stops)
        clamps = self._clamps(plan) if self.loop is not None else None
        si = 0
        runs = plan["absorbed"]  # absorbed cells as runs [run_from, run_to) of the absorbed loop (absorb.py)
        run_from, run_to = [], []
        if runs.size:
            cut = np.flatnonzero(np.diff(runs) != 1) + 1
            run_from, run_to = runs[np.r_[0, cut]].tolist(), (runs[np.r_[cut - 1, runs.size - 1]] + 1).tolist()
        ri = 0
        c = first
        with np.errstate(all="ignore"):
            while c <= last:
                if c in hard or self.loop is None:
                    a, e, whole, lo, hi, cuts = self._step(plan, c)
                    x = self._special_step(x, a, e, whole, lo, hi, cuts)
                    if record:
                        states[c - first + 1] = x
                    c += 1
                    if not _healthy(x):
                        if record:  # (the rows not reached: not left as they were allocated)
                            states[c - first + 1 :] = np.nan
                        break
                    if self.guard is not None and self.guard.value(x) > 0.0:  # (x healthy: finite)
                        self.stopped = (c - 1 - first, a, e, whole, lo, hi, list(cuts))
                        break
                    if progress and (c - first) % chunk == 0:
                        progress((c - first) / n_cells)
                    continue
                # a run of plain whole steps: up to the next special cell, the last whole cell, or a chunk
                while si < len(stops) and stops[si] < c:
                    si += 1
                while ri < len(run_to) and run_to[ri] <= c:
                    ri += 1
                stop = min(c + chunk, stops[si] if si < len(stops) else last + 1, last + 1 if not plan["trail"] else last)
                absorbed = ri < len(run_from) and run_from[ri] <= c
                if ri < len(run_from):
                    if absorbed:  # absorbed steps (no special cell inside a run)
                        stop = min(c + chunk, run_to[ri])
                    else:
                        stop = min(stop, run_from[ri])
                out = states[c - first + 1 : stop - first + 1] if record else np.empty((stop - c, size))
                x = np.ascontiguousarray(x, dtype=np.float64)
                if absorbed:
                    done, status, t = self._end(self._grid(c, stop + 1), x, out, -math.inf, math.inf, SPEED_LIMIT)
                else:  # (clamped steps grouped as _march_grouped does)
                    done, status, t = self.loop.clamped(self._grid(c, stop + 1), x if x.flags.writeable else x.copy(), out,
                                                        0, stop - c, c, *clamps, 0.5 * self.dt, SPEED_LIMIT)  # fmt: skip
                if status == NOT_CONVERGED:
                    self._not_converged(t)
                if status == GUARDED:  # the guard fired at the end of cell c + done - 1
                    j = c + done - 1
                    self.stopped = (j - first, *self._step(plan, j)[:5], [])  # (a whole cell: no cuts)
                    break
                if status == DIVERGED:
                    out[done:] = np.nan
                x = out[done - 1].copy() if done else x
                c = stop
                if not _healthy(x):
                    break
                if progress:
                    progress((c - first) / n_cells)
            else:  # every step done: each whole-step run in the kernel (which stops at the first unhealthy state),
                # each special step's state checked
                self._clean = record and self.loop is not None
        return states if record else x

    def _march_grouped(self, x: np.ndarray, plan: dict, progress=None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_march` of whole grid steps whose breakpoints all lie on knots: one compiled call
        (:func:`~belt_drive_ros.core.kernel.clamped_steps`; one per progress report, or per block of a guarded run's
        rows, which grow as it goes: it may stop at the first step); returns (states, their grid times).

        A step that ends on a breakpoint samples at most at its left limit (``hi``), the one that starts there
        at least at it (``lo``); every other sample of the steps before the first (after the second) lies
        below (above) that bound already, so a group of steps from one starting on a breakpoint to one ending
        on the next is one :func:`~belt_drive_ros.core.kernel.linear_steps` call with that group's ``lo`` and
        ``hi`` (also when cut in parts).
        """
        first, last = plan["first"], plan["last"]
        cells, lo, hi, ends = self._clamps(plan)
        guarded, total = self.guard is not None, last - first + 2
        states = np.empty((total if not guarded else min(total, GUARDED_ROWS), x.size))
        states[0] = x
        if not guarded and "grid" not in plan:  # (kept with the plan: a copy returned, the caller's to keep)
            plan["grid"] = self._grid(first, last + 2)
        grid = plan["grid"].copy() if not guarded else self._grid(first, first + states.shape[0])
        block = max(64, (last - first + 1) // 100) if progress else total
        c = first
        while c <= last:
            if guarded and c - first + 1 == states.shape[0]:  # the rows held are full: twice as many
                states = np.concatenate([states, np.empty((min(total, 2 * states.shape[0]) - states.shape[0], x.size))])
                grid = self._grid(first, first + states.shape[0])
            stop = min(last + 1, first + states.shape[0] - 1, c + block)
            k, status, t = self.loop.clamped(grid, states[c - first], states[1:], c - first, stop - first, first, cells,
                                             lo, hi, ends, 0.5 * self.dt, SPEED_LIMIT)  # fmt: skip
            if status == NOT_CONVERGED:
                self._not_converged(t)
            if status == GUARDED:  # the guard fired at the end of cell first + k - 1
                j = first + k - 1
                self.stopped = (j - first, *self._step(plan, j)[:5], [])
                break
            if status == DIVERGED:
                states[k + 1 :] = np.nan
                break
            c = first + k
            if progress:
                progress((c - first) / (last - first + 1))
        else:
            self._clean = True
        return states, grid

    def diverged_error(self, t: float, x: np.ndarray) -> SimulationDivergedError:
        """The error a run raises when state ``x`` at ``t`` [s] is non-finite or too fast (one message for every caller).
        Its advice: another method where the method's step can be the cause; with an exponential method (exact on the
        linear part at any step) the torques and parameters first."""
        exponential = self.method in ("exact", "etd2", "etd4", "lawson5")
        advice = "check the torques and parameters, or reduce dt" if exponential else \
            "reduce dt or use method 'exact' or 'etd2'"
        return SimulationDivergedError(
            f"simulation diverged at t={t:.6g} s (model {self.plant.model.name}, method {self.method}, dt={self.dt:g} s): "
            f"state {np.array2string(np.asarray(x), precision=4)} is non-finite or beyond {SPEED_LIMIT:g} rad/s; "
            f"{advice}"
        )
