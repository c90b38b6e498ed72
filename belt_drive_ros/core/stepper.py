"""The one engine that advances time: a plant from scene time t0 to t1.

Every caller that moves a simulation forward (offline runs, replay, the guards' runs, the node's tick where its
compiled tick does not serve it) goes through :class:`Stepper`: it plans the steps (grid, partial steps, steps split
or clamped at torque breakpoints) and hands them to the one compiled time loop
(:func:`~belt_drive_ros.core.kernel.linear_steps`), which steps, clamps the torque times, checks divergence and the
guard. :meth:`Stepper.advance` gives the state at ``t1``, :meth:`Stepper.run` every knot from ``t0`` to ``t1``.
States are 1-D float arrays in the model's own ordering; the **second half of the state holds speeds** [rad/s] (a
slipping belt's phase state: its entries 2 and 3, then the slip and its force; :func:`speed_columns`, the entries the
divergence check holds to the limit). Torques [N m], times [s].

The plan
--------
The grid, partial steps and the clamps and splits at torque breakpoints are planned by
:class:`~belt_drive_ros.core.step_plan.StepPlanner` (its module docstring has the rules), the base of
:class:`Stepper`, which marches the plan: runs of whole steps, clamped ones included, are one compiled call
(:func:`~belt_drive_ros.core.kernel.clamped_steps`, the plan's clamps as its arrays); split steps (a recording's
off-grid samples) in blocks, each block's pieces one compiled call (:meth:`Stepper._split_block`,
:func:`~belt_drive_ros.core.kernel.piece_steps`: each piece with the numbers of its own length, a block's new lengths
from one stacked scheme); each piece of a partial step (or of a split step of a guarded stepper, or of a method
without a stacked scheme) is one kernel call; an adaptive method (scipy's references) steps through
``integrator.step``. A torque profile without a data form is refused.

Integrators of partial-step lengths are cached per stepper (at most :data:`PARTIAL_CACHE_SIZE`); their kernel loop
is the stepper's loop with the piece's numbers written into one buffer
(:meth:`~belt_drive_ros.core.kernel_loop.KernelLoop.piece`: no copy of a recording's table per length); plant
torques are read at every call (a held torque may change between advances).

Divergence
----------
A state that is non-finite or has a speed beyond :data:`SPEED_LIMIT` raises
:class:`~belt_drive_ros.core.errors.SimulationDivergedError` naming the time, model, method and step (the kernel
checks after every step and stops there; :meth:`run` reports the first bad sample).
"""

from __future__ import annotations

import math
import threading
from bisect import bisect_left
from typing import Callable

import numpy as np

from .errors import SceneError, SimulationDivergedError
from .identity_cache import built_once
from .integrators import FixedStepIntegrator, make_integrator, prepare_integrators, stacked_scheme
from .kernel_loop import DIVERGED, GUARDED, NOT_CONVERGED
from .model import WHEEL_ROWS, _LinearModel
from .step_plan import StepPlanner, step_arrays

#: Speeds beyond this [rad/s] (~955,000 rpm) mean the numerics, not the physics, blew up.
SPEED_LIMIT = 1.0e5


def speed_columns(n: int) -> slice:
    """The entries of an ``n``-state vector held to :data:`SPEED_LIMIT` (the rest only finite): the speeds [rad/s],
    the second half of a linear model's ``[angles, speeds]`` (n = 2, 4); of a slipping belt's phase state
    ``[phi_M, theta_e, omega_M, omega_3, s]`` (n = 5; with the friction force ``Q`` [N], n = 6) everything from
    ``omega_M`` on: the speeds, and a slip distance [m] or belt force [N] that no sound run brings near 1e5 either
    (a phase whose step is unstable shows there first). The compiled loops test the same entries."""
    return slice(n // 2, n) if n <= 4 else slice(2, n)
#: partial-step integrators kept per stepper (one per distinct length)
PARTIAL_CACHE_SIZE = 4096
#: split steps whose pieces' integrators are readied together (:meth:`Stepper._prepare_pieces`), or whose pieces
#: are stepped in one compiled call (:meth:`Stepper._split_block`)
PREPARE_BLOCK = 512
#: plain whole steps between two split steps that join their block (:meth:`Stepper._split_block`) when at most so
#: many lie in a row (more: a compiled run of their own)
BLOCK_GAP = 8
#: split steps a plan needs for its blocks (fewer: each split step alone, its pieces' integrators kept by length)
BLOCK_MIN = 2
#: steps per call of the compiled loop between divergence checks and progress reports
CHUNK = 4096
#: steps of a paged drive's page beyond each end of a run (:meth:`Stepper._paged`)
PAGE_MARGIN = 4
#: state rows a guarded run (it may stop at its first steps) allocates first; twice as many each time they are full
GUARDED_ROWS = 1024


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
        return np.minimum(_left_of_array(self.drive, b), _left_of_array(self.load, b))

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


def _left_of_array(profile, b: np.ndarray) -> np.ndarray:
    """``profile.left_of`` of each time of ``b`` [s]: its ``left_of_array`` if it has one, the default's
    float below as an array, a schedule's from its parts', else one call per time."""
    from .sources import Schedule, TorqueProfile

    own = getattr(profile, "left_of_array", None)
    if own is not None:
        return np.asarray(own(b), dtype=np.float64)
    if type(profile).left_of is TorqueProfile.left_of:
        return np.nextafter(b, -np.inf)
    if type(profile) is Schedule:  # Schedule.left_of: the least of the float below and both parts' (min of equal floats)
        below = np.nextafter(b, -np.inf)
        return np.minimum(np.minimum(below, _left_of_array(profile.active, b)), _left_of_array(profile.inactive, b))
    return np.array([profile.left_of(v) for v in b.tolist()], dtype=np.float64)


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


def _edges(a: float, e: float, cuts) -> list:
    """The times [s] a step from ``a`` to ``e`` split at ``cuts`` is cut into pieces at: its pieces' lengths
    ``q - p`` are the steps of their integrators (those :meth:`Stepper._prepare_pieces` readies, the same floats)."""
    return [a, *sorted(cuts), e]


def _healthy(x) -> bool:
    """Finite state with every speed (:func:`speed_columns`) within :data:`SPEED_LIMIT`."""
    values = x.tolist() if isinstance(x, np.ndarray) else list(x)
    # the sum is finite only when every entry is (a NaN or an inf propagates; a finite overflow is beyond the limit)
    return math.isfinite(sum(values)) and max(map(abs, values[speed_columns(len(values))])) <= SPEED_LIMIT


class Stepper(StepPlanner):
    """Advances one plant with one method on the grid ``origin + k dt``: marches the plans of its base
    :class:`~belt_drive_ros.core.step_plan.StepPlanner` (see the module docstring).

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
    breakpoints, split_steps : the planner's (``split_steps`` of the last :meth:`run` or :meth:`advance`).
    loop : the compiled loop of whole steps (None: each step through ``integrator.step``).
    stopped : after a :meth:`run` the guard stopped, ``(j, a, e, whole, lo, hi, cuts)``: its step ``j`` as
        :meth:`steps` describes one; else None.
    """

    def __init__(
        self, plant: Plant, method: str, dt: float, method_options=None, origin: float = 0.0, integrator=None, guard=None
    ):
        super().__init__(plant, dt, origin)
        self.method = method
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
        self.stopped: tuple | None = None
        self._partials: dict = {}
        self._loops: dict = {}  # kernel loops of the partial-step integrators, by step length
        #: the loop's numbers of pieces of split steps (:meth:`Stepper._split_block`), by step length (None: the
        #: pieces are not in the loop's layout, or the stepper is guarded: each split step alone)
        self._rows: dict | None = {} if self.loop is not None and guard is None else None
        self._clean = False  # the last grouped march ran every step to the end without a failing status

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
        plan = self._plan(t0, t1)
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
                and not self.split_steps):
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
            bad = ~np.all(np.isfinite(states), axis=1) | np.any(np.abs(states[:, speed_columns(states.shape[1])]) > SPEED_LIMIT,
                                                                axis=1)  # fmt: skip
            if np.any(bad):
                k = int(np.argmax(bad))
                raise self.diverged_error(float(times[k]), states[k])
        if progress:
            progress(1.0)
        return times, states

    def _paged(self, t0: float, t1: float) -> "Stepper":
        """A stepper of this one's settings on the plant's page over ``[t0, t1]`` widened by
        :data:`PAGE_MARGIN` steps each side (every breakpoint a plan there looks at)."""
        m = PAGE_MARGIN * self.dt
        page = Stepper(self.plant.page(t0 - m, t1 + m), self.method, self.dt, self.method_options, self.origin,
                       self.integrator, self.guard)
        page._partials = self._partials  # (the partial steps' integrators depend on the model only)
        if page._rows is not None and self._rows is not None:  # (so do the pieces' numbers)
            page._rows = self._rows
        return page

    def reset(self) -> None:
        """Forget adaptive solver history and the partial-step integrators."""
        self.integrator.reset()
        self._partials.clear()
        if self._rows is not None:
            self._rows.clear()

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

    def _prepare_pieces(self, plan: dict, splits: list, start: int) -> int:
        """Ready the integrators of the pieces of split steps ``splits[start:]`` (up to :data:`PREPARE_BLOCK` steps)
        whose lengths are new to this stepper: their matrices in one stacked call (the same floats as each built
        alone: :func:`~belt_drive_ros.core.integrators.prepare_integrators`); returns the index after them."""
        end = min(start + PREPARE_BLOCK, len(splits))
        lengths = set()
        for c in splits[start:end]:
            a, e, whole, lo, hi, cuts = self._step(plan, c)
            edges = _edges(a, e, cuts)
            lengths.update(q - p for p, q in zip(edges[:-1], edges[1:]))
        new = [h for h in lengths if h not in self._partials]
        if len(new) > 1:
            model = self.plant.model
            prepare_integrators(self.method, model.A, model.B, sorted(new), **self.method_options)
        return end

    def _split_block(self, x: np.ndarray, plan: dict, splits: list, c: int, states):
        """Split steps from cell ``c`` on (up to :data:`PREPARE_BLOCK`, with the whole steps between them where at most
        :data:`BLOCK_GAP` lie in a row; the trailing partial step not) stepped piece by piece in one compiled call
        (:meth:`~belt_drive_ros.core.kernel_loop.KernelLoop.pieces`): each piece as :meth:`_special_step` steps it
        (the numbers of the loop of its length, here all new lengths' from one stacked scheme,
        :func:`~belt_drive_ros.core.integrators.stacked_scheme`, the same floats; its torque times clamped as
        there), each whole step with its own clamps (as a compiled run steps it). The steps' states go to
        ``states`` (None: not recorded). Returns ``(x, the cell after the last step done, healthy)``: stopped at the
        first step whose state is non-finite or too fast (a failing piece's step ends its pieces first, as
        :meth:`_special_step`); None where the pieces are not in the loop's layout."""
        first, last = plan["first"], plan["last"]
        i = bisect_left(splits, c)
        end, j, top = c, i, last - 1 if plan["trail"] else last
        while j + 1 < len(splits) and j + 1 - i < PREPARE_BLOCK and splits[j + 1] <= top and splits[j + 1] - end <= BLOCK_GAP + 1:
            j += 1
            end = splits[j]
        times, sets, plo, phi, ends = [], [], [], [], []
        index: dict = {}  # a piece's length -> its row (0: the loop's own, whole steps)
        lefts, cuts_of = [], plan["splits"]  # lefts: the pieces that end at a cut (their hi its left limit)
        if "bounds" not in plan:  # each step's clamps (kept with the plan: its blocks read them)
            plan["bounds"] = tuple(b.tolist() for b in step_arrays(plan)[:2])
        bounds_lo, bounds_hi = plan["bounds"]
        grid = self._grid(c, end + 2).tolist()  # the steps' ends, as _step gives them
        if c == first:
            grid[0] = plan["start"]
        if end == last:
            grid[-1] = plan["end"]
        for cell in range(c, end + 1):
            a, e, lo, hi = grid[cell - c], grid[cell - c + 1], bounds_lo[cell - first], bounds_hi[cell - first]
            cuts = cuts_of.get(cell)
            if not cuts:
                times.append(a), sets.append(0), plo.append(lo), phi.append(hi)
            else:
                edges = _edges(a, e, cuts)
                n = len(edges) - 1
                for k in range(n):
                    p, q = edges[k], edges[k + 1]
                    row = index.get(q - p)
                    if row is None:
                        row = index[q - p] = len(index) + 1
                    times.append(p), sets.append(row), plo.append(lo if k == 0 else p)
                    if k < n - 1:
                        lefts.append(len(phi))
                    phi.append(hi if k == n - 1 else q)
            ends.append(len(sets) - 1)
        times.append(e)
        rows = self._piece_rows(list(index))
        if rows is None:
            return None
        times, sets, plo, phi = np.array(times), np.array(sets, dtype=np.int64), np.array(plo), np.array(phi)
        if lefts:  # plant.left_of of each cut, all at once (the same floats)
            phi[lefts] = self.plant.left_of_array(phi[lefts])
        out = np.empty((len(sets), x.size))
        done, status, t = self.loop.pieces(times, np.ascontiguousarray(x, dtype=np.float64), out, sets, plo, phi, rows,
                                           SPEED_LIMIT)  # fmt: skip
        if status == NOT_CONVERGED:
            self._not_converged(t)
        ends = np.array(ends, dtype=np.int64)
        if status == DIVERGED:  # the failing piece's step: its other pieces stepped on, as _special_step; then stop
            p = done - 1
            stop = int(ends[np.searchsorted(ends, p)])
            while p < stop:
                more, status, t = self.loop.pieces(times[p + 1 : stop + 2], out[p], out[p + 1 : stop + 1], sets[p + 1 : stop + 1],
                                                   plo[p + 1 : stop + 1], phi[p + 1 : stop + 1], rows, SPEED_LIMIT)  # fmt: skip
                if status == NOT_CONVERGED:
                    self._not_converged(t)
                p += more
            ends = ends[: np.searchsorted(ends, stop) + 1]
        steps = out[ends]
        # _healthy of each state (a finite state's sum is finite: its angles grow by at most SPEED_LIMIT dt a step)
        bad = ~np.isfinite(steps).all(axis=1) | (np.abs(steps[:, speed_columns(x.size)]) > SPEED_LIMIT).any(axis=1)
        count = int(np.argmax(bad)) + 1 if bad.any() else len(ends)
        if states is not None:
            states[c - first + 1 : c - first + 1 + count] = steps[:count]
        return steps[count - 1].copy(), c + count, not bad[count - 1]

    def _piece_rows(self, lengths: list):
        """(len(lengths) + 1, R) rows of the loop's numbers: row 0 its own, row r that of a piece of ``lengths[r - 1]``
        [s] (kept by length; new ones from one stacked scheme); None where those are not in the loop's layout."""
        cache = self._rows
        new = [h for h in lengths if h not in cache]
        if new and len(cache) + len(new) > PARTIAL_CACHE_SIZE:  # (full: all this block's lengths built anew)
            cache.clear()
            new = lengths
        if new:
            model = self.plant.model
            got = self.loop.piece_rows(stacked_scheme(self.method, model.A, model.B, new, **self.method_options), new)
            if got is None:
                self._rows = None
                return None
            cache.update(zip(new, got))
        size = self.loop.reals.size - self.loop.tables.size
        rows = np.empty((len(lengths) + 1, size))
        rows[0] = self.loop.reals[:size]
        if new and (new is lengths or new == lengths):  # (every length new: a jittered recording's) the rows as built
            rows[1:] = got
        else:
            for r, h in enumerate(lengths, 1):
                rows[r] = cache[h]
        return rows

    def _loop_of(self, integrator):
        """The kernel loop of ``integrator`` (the stepper's own or a partial step's) for this plant, or None: a
        partial step's is the stepper's loop's :meth:`~belt_drive_ros.core.kernel_loop.KernelLoop.piece` (its
        numbers written into one loop, the plant's tables not copied), to be called before the next one is asked
        for; a layout it does not hold, a loop of its own, kept by step length."""
        if integrator is self.integrator or self.loop is None:
            return self.loop
        piece = self.loop.piece(integrator.scheme, integrator.dt)
        if piece is not None:
            return piece
        key = integrator.dt
        if key not in self._loops:
            self._loops[key] = self.plant.kernel_loop(integrator)
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
        edges = _edges(a, e, cuts)
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
        first, last = plan["first"], plan["last"]
        n_cells = last - first + 1
        states = np.empty((n_cells + 1, size)) if record else None
        if record:
            states[0] = x
        chunk = CHUNK if not progress else min(CHUNK, max(64, n_cells // 100))
        # the steps taken alone: split ones, the partial ones at the ends (clamps alone: in the compiled runs)
        stops = sorted([*plan["splits"], *[first] * plan["lead"], *[last] * plan["trail"]])
        hard = set(stops)
        splits = sorted(plan["splits"]) if self.loop is not None else []
        ready = 0  # splits[:ready]: their pieces' integrators prepared
        groups = self._groups(plan) if self.loop is not None else None
        blocks = self._rows is not None and len(splits) >= BLOCK_MIN  # split steps in blocks (_split_block)
        si = 0
        c = first
        with np.errstate(all="ignore"):
            while c <= last:
                if blocks and c in plan["splits"] and not (c == first and plan["lead"]) and not (c == last and plan["trail"]):
                    block = self._split_block(x, plan, splits, c, states)
                    if block is not None:
                        x, c, healthy = block
                        if not healthy:
                            if record:  # (the rows not reached: not left as they were allocated)
                                states[c - first + 1 :] = np.nan
                            break
                        if progress:
                            progress((c - first) / n_cells)
                        continue
                    blocks = False  # (not in the loop's layout: each split step alone)
                if c in hard or self.loop is None:
                    if ready < len(splits) and c >= splits[ready]:  # (from this step on: those passed are done)
                        ready = self._prepare_pieces(plan, splits, max(ready, bisect_left(splits, c)))
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
                stop = min(c + chunk, stops[si] if si < len(stops) else last + 1, last + 1 if not plan["trail"] else last)
                out = states[c - first + 1 : stop - first + 1] if record else np.empty((stop - c, size))
                x = np.ascontiguousarray(x, dtype=np.float64)
                done, status, t = self.loop.clamped(self._grid(c, stop + 1), x if x.flags.writeable else x.copy(), out,
                                                    0, stop - c, c, *groups, 0.5 * self.dt, SPEED_LIMIT)  # fmt: skip
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
        below (above) that bound already, so each step is clamped to its own ``lo`` and ``hi`` (an explicit
        method on 2, 4, 5 or 6 states: one compiled loop reading every step's bounds; otherwise a group of steps from one
        starting on a breakpoint to one ending on the next is one stepping call with that group's bounds).
        """
        first, last = plan["first"], plan["last"]
        cells, lo, hi, ends = self._groups(plan)
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

    def diverged_error(self, t: float, x: np.ndarray, model: str | None = None) -> SimulationDivergedError:
        """The error a run raises when state ``x`` at ``t`` [s] is non-finite or too fast (one message for every caller;
        ``model``: the model named, else the plant's: the slipping engine names its own).
        Its advice: another method where the method's step can be the cause; with an exponential method (exact on the
        linear part at any step) the torques and parameters first."""
        exponential = self.method in ("exact", "etd2", "etd4", "lawson5")
        advice = "check the torques and parameters, or reduce dt" if exponential else \
            "reduce dt or use method 'exact' or 'etd2'"
        return SimulationDivergedError(
            f"simulation diverged at t={t:.6g} s (model {model or self.plant.model.name}, method {self.method}, dt={self.dt:g} s): "
            f"state {np.array2string(np.asarray(x), precision=4)} is non-finite or beyond {SPEED_LIMIT:g} rad/s; "
            f"{advice}"
        )
