"""The plan of an advance from t0 to t1: grid steps, partial steps, and the clamps and splits at torque breakpoints.

:class:`StepPlanner` (the base of :class:`~belt_drive_ros.core.stepper.Stepper`, which marches the plan) holds the
grid and the breakpoints; its plans are what every executor of a run steps (the stepper's compiled runs, the
slipping loop's arrays :func:`step_arrays`, the ensemble's steps :meth:`StepPlanner.steps`).

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
strictly inside a step splits the step there (a *split*: sub-steps by integrators of the sub-step's length); one
on a knot (within the snap tolerance) bounds the steps on either side (a *clamp*). Every torque sample of a
(sub-)step is taken at a time clamped into the step's side: the step that ends at breakpoint ``b`` samples at most
at ``plant.left_of(b)`` (the left limit), the step that starts there at least at ``b``, so no step integrates
across a jump or a kink and each method keeps its order. A breakpoint at ``t0`` (``t1``) bounds the first (last)
step. The breakpoints of an advance are classified by one rule (:meth:`StepPlanner._clamps`; with numpy from
:data:`VECTOR_MIN` on: a torque recorded at the step rate puts one on every knot), the clamps kept as one sorted
array form ``(cells, lo, hi)``, the splits as ``{cell: [cuts]}``.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right

import numpy as np

#: a time this close to a grid time, relative to dt, is on the grid
GRID_TOLERANCE = 1e-9
#: an advance over at least this many breakpoints classifies them with numpy (fewer: one at a time in Python, the
#: same floats; numpy's fixed cost is ~40 times the loop's for one breakpoint, which a node's tick across one plans)
VECTOR_MIN = 32
#: plans of :meth:`StepPlanner._run_plan` kept per planner (the guards' windows, the run and the slipping run's
#: reruns repeat theirs), of so many clamped or split steps at most
PLAN_CACHE_SIZE, PLAN_SPECIAL = 8, 64
_NO_CELLS = np.empty(0, dtype=np.int64)
_NO_TIMES = np.empty(0, dtype=np.float64)
_NO_CLAMPS = (_NO_CELLS, _NO_TIMES, _NO_TIMES)  # (writeable, as every plan's arrays: one compiled signature)


def snap_tolerance(t: float, dt: float) -> float:
    """Distance [s] within which time ``t`` counts as on a grid time or a breakpoint: max(1e-9 dt, 8 ulp(t))."""
    return max(GRID_TOLERANCE * dt, 8.0 * math.ulp(abs(t)))


def _reduced(keys: np.ndarray, values: np.ndarray, ufunc) -> tuple[np.ndarray, np.ndarray]:
    """(distinct ``keys`` (sorted), ``ufunc`` (np.maximum, np.minimum) of the ``values`` of each)."""
    if keys.size == 0 or not np.any(keys[1:] <= keys[:-1]):  # (all distinct, ascending: each its own value)
        return keys, values
    if np.any(keys[1:] < keys[:-1]):
        order = np.argsort(keys, kind="stable")
        keys, values = keys[order], values[order]
    at = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    return keys[at], ufunc.reduceat(values, at)


def _search(bps, x: float, right: bool) -> int:
    """:func:`bisect.bisect_left` (``right``: ``bisect_right``) of ``x`` in the sorted ``bps`` (list or array)."""
    if isinstance(bps, np.ndarray):
        return int(bps.searchsorted(x, side="right" if right else "left"))
    return bisect_right(bps, x) if right else bisect_left(bps, x)


def step_arrays(plan: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lo, hi, special)`` per step of a non-empty plan (cells ``first .. last``): each step's torque-time bounds
    [s] (``-inf``/``inf`` where none) and 1 where the step is partial or split (int64), else 0."""
    first, n = plan["first"], plan["last"] - plan["first"] + 1
    cells, clo, chi = plan["clamps"]
    lo, hi = np.full(n, -math.inf), np.full(n, math.inf)
    lo[cells - first], hi[cells - first] = clo, chi
    special = np.zeros(n, dtype=np.int64)
    special[0] |= plan["lead"]
    special[-1] |= plan["trail"]
    special[np.fromiter(plan["splits"], dtype=np.int64, count=len(plan["splits"])) - first] = 1
    return lo, hi, special


class StepPlanner:
    """The grid ``origin + k dt`` and the breakpoints of a plant, and the plans of advances on them (see the module
    docstring). The base of :class:`~belt_drive_ros.core.stepper.Stepper`; ``plant`` gives ``left_of_array``.

    Attributes
    ----------
    breakpoints : sorted times [s] where steps are split or bounded (the plant's; a caller assigns new ones), a
    tuple or a read-only float64 array (a list or writable array assigned is copied): plans are kept by it.
    split_steps : ``{grid index k: [breakpoints inside step k]}`` of the last plan.
    """

    def __init__(self, plant, dt: float, origin: float = 0.0):
        self.plant, self.dt, self.origin = plant, float(dt), float(origin)
        self.breakpoints = plant.breakpoints
        self.split_steps: dict = {}
        self._free: tuple | None = None  # the breakpoint-free interval the last tick fell in (_near_breakpoint)
        self._plans: dict = {}  # (t0, t1, origin, id(breakpoints)) -> (breakpoints, plan) of _run_plan()

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

    def grid_time(self, k: int) -> float:
        """Grid time ``origin + k dt`` [s] (the float every caller computes)."""
        return self.origin + k * self.dt

    def _grid(self, k0: int, k1: int) -> np.ndarray:
        """Grid times ``origin + k dt`` for k0 <= k < k1 (the float product and sum every caller computes)."""
        return self.origin + self.dt * np.arange(k0, k1, dtype=float)

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

    def _cells(self, t: np.ndarray) -> np.ndarray:
        """:meth:`_cell` of each time of ``t`` (int64; the same grid floats)."""
        k = np.floor((t - self.origin) / self.dt)
        while True:
            down = self.origin + k * self.dt > t
            if not down.any():
                break
            k[down] -= 1.0
        while True:
            up = self.origin + (k + 1.0) * self.dt <= t
            if not up.any():
                break
            k[up] += 1.0
        return k.astype(np.int64)

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

    # ------------------------------------------------------------ plans
    def _plan(self, t0: float, t1: float) -> dict:
        """Steps from ``t0`` to ``t1``: grid cells first..last, ends, and the steps that touch breakpoints.

        Returns a dict: ``first``, ``last`` (cell indices), ``start``, ``end`` (the times of the first and last
        knot: the grid time when ``t0``/``t1`` snap to the grid, else themselves), ``lead``/``trail`` (whether the
        first/last step is partial), ``t0``/``t1`` as given, ``empty`` (no step), ``clamps = (cells, lo, hi)`` (the
        steps whose torque samples are clamped to ``[lo, hi]`` [s], cells sorted, ``-inf``/``inf`` where a side has
        none) and ``splits = {cell: [cuts]}`` (steps split at breakpoints inside them).
        """
        k0, k1 = self._snap(t0), self._snap(t1)
        start = self.grid_time(k0) if k0 is not None else t0
        end = self.grid_time(k1) if k1 is not None else t1
        first = k0 if k0 is not None else self._cell(t0)
        last = k1 - 1 if k1 is not None else self._cell(t1)
        empty = last < first  # t0 and t1 on the same grid time (or within its tolerance)
        clamps, splits = _NO_CLAMPS, {}
        if not (empty or (k0 is not None and k1 is not None and not self._near_breakpoint(t0, t1, k0, k1))):
            # (else whole grid steps in a breakpoint-free interval the last run or tick found: no search)
            bps = self.breakpoints
            tol0, tol1 = snap_tolerance(start, self.dt), snap_tolerance(end, self.dt)
            near = bps[_search(bps, min(t0, start) - tol0, False) : _search(bps, max(t1, end) + tol1, True)]
            if len(near):
                clamps, splits = self._clamps(np.asarray(near, dtype=np.float64), t0, t1, start, end, first, last)
        self.split_steps = {c: list(cuts) for c, cuts in splits.items()}
        return dict(
            t0=t0, t1=t1, start=start, end=end, first=first, last=last, empty=empty,
            lead=k0 is None, trail=k1 is None, clamps=clamps, splits=splits,
        )  # fmt: skip

    def _clamps(self, bps: np.ndarray, t0: float, t1: float, start: float, end: float, first: int, last: int) -> tuple:
        """``((cells, lo, hi), splits)`` of the breakpoints ``bps`` (sorted, float64) of an advance with these ends:

        * within the snap tolerance of ``start`` or ``t0``: the first step samples from the latest (``lo``);
        * else of ``end`` or ``t1``: the last step samples up to the earliest's left limit (``hi``);
        * strictly between, on a knot ``k``: step ``k - 1`` up to its left limit, step ``k`` from it;
        * strictly between, off the grid: a cut of the step holding it (``splits``, cuts sorted).

        Each step's ``lo`` the latest, its ``hi`` the earliest of those. Fewer than
        :data:`VECTOR_MIN` breakpoints one at a time, more with numpy (:meth:`_classified`: the same floats).
        """
        if bps.size >= VECTOR_MIN:
            return self._classified(bps, t0, t1, start, end, first, last)
        dt = self.dt
        tol0, tol1 = snap_tolerance(start, dt), snap_tolerance(end, dt)
        lo, hi, splits = {}, {}, {}
        for b in bps.tolist():
            if abs(b - start) <= max(tol0, snap_tolerance(b, dt)) or abs(b - t0) <= tol0:
                lo[first] = max(lo.get(first, -math.inf), b)
            elif abs(b - end) <= max(tol1, snap_tolerance(b, dt)) or abs(b - t1) <= tol1:
                hi[last] = min(hi.get(last, math.inf), self.plant.left_of(b))
            elif start < b < end:
                k = self._snap(b)
                if k is None:
                    splits.setdefault(min(max(self._cell(b), first), last), []).append(b)
                    continue
                if first <= k - 1:
                    hi[k - 1] = min(hi.get(k - 1, math.inf), self.plant.left_of(b))
                if k <= last:
                    lo[k] = max(lo.get(k, -math.inf), b)
        if not (lo or hi):
            return _NO_CLAMPS, splits
        cells = sorted(lo.keys() | hi.keys())
        return (np.array(cells, dtype=np.int64), np.array([lo.get(c, -math.inf) for c in cells], dtype=np.float64),
                np.array([hi.get(c, math.inf) for c in cells], dtype=np.float64)), splits  # fmt: skip

    def _classified(self, bps: np.ndarray, t0: float, t1: float, start: float, end: float, first: int, last: int) -> tuple:
        """:meth:`_clamps` of many breakpoints, all at once with numpy (a torque recorded at the step rate has one on
        every knot): the clamps as sorted sets when a few lie among many steps (memory of the breakpoints' size),
        else through arrays by cell.

        ``bps`` is sorted, so the rules' tests run where they can hold: those within a tolerance of the start (and
        ``t0``) on a few first breakpoints, of the end (and ``t1``) on a few last ones (each tolerance is at most
        ``wide``: twice it bounds every candidate), the knots on those strictly between ``start`` and ``end``; and
        the knots, ascending with the breakpoints, are cut into the steps' sides by two searches. The same floats
        as each test made on every breakpoint."""
        dt, origin = self.dt, self.origin
        n = bps.size
        tol0, tol1 = snap_tolerance(start, dt), snap_tolerance(end, dt)
        wide = max(GRID_TOLERANCE * dt, 8.0 * math.ulp(max(abs(float(bps[0])), abs(float(bps[-1])))))  # >= each tol_b

        def near(a: float, b: float, tol: float) -> tuple[int, np.ndarray]:
            """(index of the first, its breakpoints) of those that may lie within a tolerance of ``a`` or ``b``."""
            w = 2.0 * max(tol, wide)
            i, j = int(bps.searchsorted(min(a, b) - w, "left")), int(bps.searchsorted(max(a, b) + w, "right"))
            return i, bps[i:j]

        def tol_of(b: np.ndarray) -> np.ndarray:  # snap_tolerance of each
            return np.maximum(GRID_TOLERANCE * dt, 8.0 * np.spacing(np.abs(b)))

        i0, s = near(start, t0, tol0)
        at_start = np.zeros(n, dtype=bool)
        at_start[i0 : i0 + s.size] = (np.abs(s - start) <= np.maximum(tol0, tol_of(s))) | (np.abs(s - t0) <= tol0)
        i1, e = near(end, t1, tol1)
        at_end = np.zeros(n, dtype=bool)
        at_end[i1 : i1 + e.size] = ~at_start[i1 : i1 + e.size] & (
            (np.abs(e - end) <= np.maximum(tol1, tol_of(e))) | (np.abs(e - t1) <= tol1))
        # strictly between start and end (sorted: one range), neither at the start nor at the end
        a, b_ = int(bps.searchsorted(start, "right")), int(bps.searchsorted(end, "left"))
        inside = np.zeros(n, dtype=bool)
        inside[a:b_] = True
        inside &= ~at_start
        inside &= ~at_end
        kf = np.rint((bps - origin) / dt)  # _snap: round half to even
        miss = np.abs(origin + kf * dt - bps)
        on = miss <= GRID_TOLERANCE * dt  # on the grid within every tolerance; the rest against their own
        rest = np.flatnonzero(~on)
        if rest.size:
            on[rest] = miss[rest] <= tol_of(bps[rest])
        on &= inside
        k, b = kf[on].astype(np.int64), bps[on]
        # k ascends with the breakpoints: the steps from a knot (k <= last) a prefix, those up to one (k - 1 >= first)
        # a suffix
        n_lo, n_hi = int(k.searchsorted(last, "right")), int(k.searchsorted(first + 1, "left"))
        b_end = bps[at_end]
        left = self.plant.left_of_array(np.concatenate([b[n_hi:], b_end]))
        # the step starting at a knot (or the first step) samples from its latest breakpoint ...
        kl, vl = _reduced(np.concatenate([np.full(int(np.count_nonzero(at_start)), first, dtype=np.int64), k[:n_lo]]),
                          np.concatenate([bps[at_start], b[:n_lo]]), np.maximum)  # fmt: skip
        # ... the one ending there (or the last step) up to the first one's left limit
        kh, vh = _reduced(np.concatenate([k[n_hi:] - 1, np.full(b_end.size, last, dtype=np.int64)]), left, np.minimum)
        if kl.size + kh.size == 0:
            clamps = _NO_CLAMPS
        elif 4 * (kl.size + kh.size) < last - first + 1:  # a few among many steps: sorted sets
            cells = np.union1d(kl, kh)
            lo, hi = np.full(cells.size, -math.inf), np.full(cells.size, math.inf)
            lo[np.searchsorted(cells, kl)], hi[np.searchsorted(cells, kh)] = vl, vh
            clamps = (cells, lo, hi)
        else:  # by cell (first .. last)
            lo, hi = np.full(last - first + 1, -math.inf), np.full(last - first + 1, math.inf)
            lo[kl - first], hi[kh - first] = vl, vh
            cells = np.flatnonzero((lo != -math.inf) | (hi != math.inf))
            clamps = (cells + first, lo[cells], hi[cells])
        splits: dict = {}
        off = inside & ~on
        if off.any():
            cut = bps[off]
            for c, t in zip(np.clip(self._cells(cut), first, last).tolist(), cut.tolist()):
                splits.setdefault(c, []).append(t)
        return clamps, splits

    def _run_plan(self, t0: float, t1: float) -> dict:
        """:meth:`_plan` of a run (or of a slipping run's advance); the last :data:`PLAN_CACHE_SIZE` kept by their ends,
        origin and (immutable) breakpoints, those of at most :data:`PLAN_SPECIAL` clamped or split steps. What its
        executors derive from it (``grid``, ``groups``, ``bounds``, ``arrays``) is kept in it, read-only to them."""
        key = (t0, t1, self.origin, id(self.breakpoints))
        hit = self._plans.get(key)
        if hit is not None and hit[0] is self.breakpoints:
            self.split_steps = {c: list(cuts) for c, cuts in hit[1]["splits"].items()}
            return hit[1]
        plan = self._plan(t0, t1)
        if plan["clamps"][0].size + len(plan["splits"]) <= PLAN_SPECIAL:
            if len(self._plans) >= PLAN_CACHE_SIZE:
                self._plans.pop(next(iter(self._plans)))
            self._plans[key] = (self.breakpoints, plan)
        return plan

    def _groups(self, plan: dict) -> tuple:
        """``(cells, lo, hi, ends)`` of a plan (kept in it): its clamps and ``ends``, the cells that end a group of
        :func:`~belt_drive_ros.core.kernel.clamped_steps` (a finite hi, the cell before a finite lo, the last)."""
        if "groups" not in plan:
            (cells, lo, hi), first, last = plan["clamps"], plan["first"], plan["last"]
            if 4 * cells.size < last - first + 1:  # a few clamped steps among many: a sorted set
                ends = np.unique(np.concatenate([cells[hi != math.inf], cells[lo != -math.inf] - 1, [last]]))
            else:  # one a step or so: marks by cell, first - 1 .. last (no sort)
                ends = np.zeros(last - first + 2, dtype=bool)
                ends[cells[hi != math.inf] - first + 1] = True
                ends[cells[lo != -math.inf] - first] = True
                ends[last - first + 1] = True
                ends = np.flatnonzero(ends) + (first - 1)
            plan["groups"] = (cells, lo, hi, ends.astype(np.int64))
        return plan["groups"]

    def _step(self, plan: dict, c: int) -> tuple:
        """``(a, e, whole, lo, hi, cuts)`` of the step in cell ``c``: from ``a`` to ``e`` [s] (``whole``: a full grid
        step), torque samples clamped to ``[lo, hi]``, split at ``cuts``."""
        a = plan["start"] if c == plan["first"] else self.grid_time(c)
        e = plan["end"] if c == plan["last"] else self.grid_time(c + 1)
        whole = not ((c == plan["first"] and plan["lead"]) or (c == plan["last"] and plan["trail"]))
        cells, clo, chi = plan["clamps"]
        i = int(cells.searchsorted(c))
        lo, hi = (float(clo[i]), float(chi[i])) if i < cells.size and cells[i] == c else (-math.inf, math.inf)
        return a, e, whole, lo, hi, plan["splits"].get(c, ())

    def _knots(self, plan: dict) -> np.ndarray:
        """Times of the recorded states: t0, the interior grid times, t1."""
        if plan["empty"]:
            return np.array([plan["t0"]] if plan["t0"] == plan["t1"] else [plan["t0"], plan["t1"]])
        return np.concatenate(([plan["t0"]], self._grid(plan["first"] + 1, plan["last"] + 1), [plan["t1"]]))

    # ------------------------------------------------------------ the plan for other executors
    def next_step(self, t0: float, t1: float) -> tuple:
        """The first step ``(a, e, whole, lo, hi, cuts)`` of an advance from ``t0`` to ``t1`` [s] (see :meth:`steps`)."""
        plan = self._plan(t0, t1)
        if plan["empty"]:
            return t0, t1, False, -math.inf, math.inf, []
        a, e, whole, lo, hi, cuts = self._step(plan, plan["first"])
        return a, e, whole, lo, hi, list(cuts)

    def steps(self, t0: float, t1: float) -> tuple[np.ndarray, list]:
        """The plan a run executes from ``t0`` to ``t1`` [s], for another executor of it.

        Returns ``(times, steps)``: the knot times (N+1,) [s] of a run, and per step ``(a, e, whole, lo, hi, cuts)``:
        from ``a`` to ``e`` [s] (``whole``: a full grid step of ``dt``), torque samples clamped to ``[lo, hi]``, split
        at ``cuts`` (each piece's samples clamped to its side, as a run does). Empty when ``t0`` and ``t1`` share a
        knot. :class:`~belt_drive_ros.core.ensemble.Ensemble` steps many variants of a plant along it.
        """
        plan = self._plan(t0, t1)
        times = self._knots(plan)
        if plan["empty"]:
            return times, []
        first, last, splits = plan["first"], plan["last"], plan["splits"]
        lo, hi, _ = step_arrays(plan)
        grid = self._grid(first, last + 2).tolist()
        grid[0], grid[-1] = plan["start"], plan["end"]
        whole = [True] * (last - first + 1)
        whole[0] = whole[0] and not plan["lead"]
        whole[-1] = whole[-1] and not plan["trail"]
        return times, [(grid[j], grid[j + 1], whole[j], lo_j, hi_j, tuple(sorted(splits.get(first + j, ()))))
                       for j, (lo_j, hi_j) in enumerate(zip(lo.tolist(), hi.tolist()))]
