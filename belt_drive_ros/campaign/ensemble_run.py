"""``simulate`` for many scenes at once: variants that can share an ensemble run together, the rest singly.

:func:`simulate_many` gives, per scene, what :func:`~belt_drive_ros.core.simulate.simulate` gives (the same
model choice, states and outputs to rounding; no energy terms, stability or accuracy reports) or the error
it raises. Scenes sharing all but their parameters and initial state (profiles, model, method, step,
duration, output rate) form a group, run as one :class:`~belt_drive_ros.core.ensemble.Ensemble` per linear
model; ``model: auto`` first runs the rigid estimate of the operating speeds as one ensemble (``exact`` at
:func:`~belt_drive_ros.core.fidelity.operating_run_step`), applies the frequency rule and then the capstan
check per variant (:func:`~belt_drive_ros.core.fidelity.choose_model`), a variant past the limit going on to
the slipping model singly. The slipping model, methods the ensemble does not cover and groups smaller than
:data:`MIN_GROUP` run singly through ``simulate``; each outcome says which way it ran and why.

:func:`run_groups` yields the same runs as :class:`GroupRun` blocks (variant axis last) for callers that
reduce over the variants at once (campaign metrics).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from ..core.accuracy_probes import belt_change, change_frequency
from ..core.ensemble import Ensemble, EnsembleUnsupported, weighted_columns
from ..core.errors import BeltDriveError
from ..core.fidelity import choose_model, friction_use, operating_run_step
from ..core.integrators import method_class
from ..core.kernel_loop import OK
from ..core.method_choice import good_step_error
from ..core.model import LINEAR_OUTPUTS, OUTPUT_UNITS, ModelStack, span_forces
from ..core.params import ParamColumns, centrifugal_tension, friction_limit_array
from ..core.scene import AUTO_METHOD, Scene
from ..core.simulate import SimResult, simulate
from ..core.stability import require_stable

#: groups of fewer variants run singly (an ensemble's per-step overhead is that of ~8 single runs)
MIN_GROUP = 8


@dataclass
class Outcome:
    """What scene ``index`` (its position in the input) gave: its ``result`` or its ``error`` as one line
    (``"ErrorType: message"``); ``ensemble`` whether it ran in one, else ``single_reason`` why not."""

    index: int
    result: SimResult | None
    error: str | None
    ensemble: bool
    single_reason: str | None = None


class GroupRun:
    """Variants of one group run together on one linear model (``kind``, ``method``), the variant axis last:
    ``indices`` (positions in the input), ``scenes``, ``models``, ``times`` (N+1,) [s], ``states`` (N+1, n, V),
    ``inputs`` (N+1, m, V) [N m], per variant its ``choices`` (model auto: the ModelChoice, else None)."""

    def __init__(self, indices, scenes, models, kind, method, times, states, inputs, choices=None):
        self.indices, self.scenes = list(indices), list(scenes)
        self.models = models
        self.kind, self.method = kind, method
        self.times, self.states, self._inputs = times, states, inputs
        self.choices = list(choices) if choices is not None else [None] * len(self.indices)
        self._outputs: dict = {}
        self._params: dict = {}
        self._fixed: dict = {}  # numbers of the variants the windows share (:meth:`peaks`)
        self._C = np.ascontiguousarray(self.models.C.transpose(1, 2, 0))  # (O, n, V)
        self._D = np.ascontiguousarray(self.models.D.transpose(1, 2, 0))  # (O, m, V)

    def __len__(self) -> int:
        return len(self.indices)

    @property
    def inputs(self) -> np.ndarray:
        """Torques u (N+1, m, V) [N m] at the knots (computed on first use when given as a function of the run)."""
        if callable(self._inputs):
            self._inputs = self._inputs(self.times, self.states)
        return self._inputs

    def window(self, times, states, inputs) -> "GroupRun":
        """The same variants over the knots of a window (:meth:`~belt_drive_ros.core.ensemble.Ensemble.windows`), its
        outputs computed afresh; ``inputs``: an array, or ``inputs(times, states)`` called when an output needs them."""
        out = copy.copy(self)
        out.times, out.states, out._inputs = times, states, inputs
        out._outputs = {}
        return out

    def param(self, name: str) -> np.ndarray:
        """Parameter or derived quantity ``name`` of :class:`~belt_drive_ros.core.params.BeltDriveParams` per variant: (V,)."""
        cached = self._params.get(name)
        if cached is None:
            column = getattr(self.models.columns, name, None)  # the fields and the arithmetic derived quantities
            if column is None:  # others (exp, tanh of fields) per variant, by the parameters' own properties
                column = [getattr(p, name) for p in self.models.params]
            cached = self._params[name] = np.asarray(column, dtype=float)
        return cached

    def output(self, name: str) -> np.ndarray:
        """Output signal ``name`` of :data:`~belt_drive_ros.core.model.OUTPUT_UNITS` for every variant: (N+1, V).

        The model's :meth:`outputs` per element (``y = C x + D u`` summed column by column from the left, columns
        zero for every variant skipped: :func:`~belt_drive_ros.core.ensemble.weighted_columns`; the span forces
        from the belt torque), so column v is ``models[v].outputs(...)[name]`` bit for bit.
        """
        cached = self._outputs.get(name)
        if cached is not None:
            return cached
        if name in ("drive_torque", "load_torque"):  # the inputs themselves, as the model reports them
            out = self.inputs[:, 0 if name == "drive_torque" else 1, :]
        elif name in LINEAR_OUTPUTS:
            j = LINEAR_OUTPUTS.index(name)
            out = weighted_columns(self.states, self._C[j])
            if np.any(self._D[j]):  # the inputs' part (the run's torques only when an output reads them)
                y = weighted_columns(self.inputs, self._D[j])
                out = y if out is None else out + y
            if out is None:
                out = np.zeros(self.states[:, 0, :].shape)
        elif name in ("span_force_tight", "span_force_slack", "slack", "slip"):
            mass = self.param("belt_mass")
            F_c = centrifugal_tension(self._belt_speed_ratio(), mass, self.output("omega_M")) if mass.any() else 0.0
            forces = span_forces(self.param("F_0"), self.param("r_3"), self.param("capstan_ratio"), self.output("belt_torque"),
                                 F_c)  # fmt: skip
            for key, value in zip(("span_force_tight", "span_force_slack", "slack", "slip"), forces):
                self._outputs[key] = value
            return self._outputs[name]
        else:
            raise KeyError(f"output: unknown signal {name!r}; known: {', '.join(OUTPUT_UNITS)}")
        self._outputs[name] = out
        return out

    def _belt_speed_ratio(self) -> np.ndarray:
        """r_2 g [m] per variant (V,): the belt speed per drive speed."""
        ratio = self._params.get("r_2 g")
        if ratio is None:
            ratio = self._params["r_2 g"] = self.param("r_2") * self.param("gear_ratio")
        return ratio

    def friction_limit(self) -> np.ndarray:
        """Q_max [N] at every knot of every variant (N+1, V) (:meth:`~belt_drive_ros.core.params.BeltDriveParams.friction_limit`)."""
        return friction_limit_array(
            self.param("F_0"), self._belt_speed_ratio(), self.param("belt_mass"), self.param("capstan_factor"),
            self.output("omega_M"),
        )  # fmt: skip

    def friction_use(self) -> np.ndarray:
        """|Q| / Q_max at every knot of every variant (N+1, V) (:func:`~belt_drive_ros.core.fidelity.friction_use`),
        computed once for the capstan check and the metrics."""
        cached = self._outputs.get(" friction_use")
        if cached is None:
            cached = self._outputs[" friction_use"] = friction_use(self.output("belt_torque"), self.param("r_3"), self.friction_limit())
        return cached

    def peaks(self) -> dict:
        """The reductions over this block's knots a campaign needs: ``belt`` max |belt torque| (V,), ``deflection``
        max |relative deflection| (V,) and ``use`` (peak, its first time) of :meth:`friction_use`
        (:func:`peak_over_time`). One compiled pass over the states
        (:func:`~belt_drive_ros.core.kernel_variants.window_peaks`: the same floats as these reductions of the
        outputs) where those outputs read no input (no row of D); else the outputs' numpy reductions."""
        cached = self._outputs.get(" peaks")
        if cached is not None:
            return cached
        fixed = self._fixed.get("peaks")
        if fixed is None:
            rows = [LINEAR_OUTPUTS.index(name) for name in ("belt_torque", "relative_deflection", "omega_M")]
            fixed = self._fixed["peaks"] = False if any(np.any(self._D[j]) for j in rows) else (
                np.ascontiguousarray(self._C[rows]),
                np.array([[bool(np.any(w)) for w in self._C[j]] for j in rows], dtype=np.int64),
                np.ascontiguousarray(np.stack([np.ones(len(self)), self.param("F_0"), self.param("belt_mass"),
                                               self._belt_speed_ratio(), self.param("capstan_factor"),
                                               self.param("r_3")], axis=1)),
            )  # fmt: skip
        if fixed is False:
            with np.errstate(invalid="ignore"):
                cached = {"belt": np.max(np.abs(self.output("belt_torque")), axis=0),
                          "deflection": np.max(np.abs(self.output("relative_deflection")), axis=0),
                          "use": peak_over_time(self.friction_use(), self.times)}  # fmt: skip
        else:
            from ..core.kernel_variants import window_peaks

            out = np.empty((4, len(self)))
            window_peaks(np.ascontiguousarray(self.times, dtype=np.float64), np.ascontiguousarray(self.states), *fixed, out)
            cached = {"belt": out[0], "deflection": out[1], "use": (out[2], out[3])}
        self._outputs[" peaks"] = cached
        return cached

    def result(self, v: int) -> SimResult:
        """Variant v's run as :func:`~belt_drive_ros.core.simulate.simulate` gives it (see the module docstring)."""
        scene, model = self.scenes[v], self.models.model(v)
        x_v = np.ascontiguousarray(self.states[:, :, v])
        u_v = np.ascontiguousarray(self.inputs[:, :, v])
        return SimResult(
            scene=scene, model=self.kind, method=self.method, dt=scene.dt, time=self.times, states=x_v, inputs=u_v,
            outputs=model.outputs(x_v, u_v), choice=self.choices[v], wall_time=math.nan,
        )  # fmt: skip


class Reductions:
    """Reductions over the time axis of an ensemble run, merged window by window (windows share their end knots).

    ``kinds``: name -> ``"max"``, ``"min"`` (NaN propagates, as ``np.max`` over the whole run), ``"first"``,
    ``"last"`` or ``"argmax"`` (``(values, times)``: the peak and its first time, as ``np.argmax`` over the whole
    run, a NaN counting as the peak). ``values``: name -> (V,) array (``argmax``: a pair of arrays).
    """

    def __init__(self, kinds: dict):
        self.kinds = dict(kinds)
        self.values: dict = {}

    def update(self, window: dict) -> None:
        """Merge one window's reductions (name -> (V,) array, or ``(values, times)`` for argmax)."""
        for name, new in window.items():
            kind = self.kinds[name]
            old = self.values.get(name)
            if old is None or kind == "last":
                self.values[name] = tuple(np.array(a, dtype=float) for a in new) if kind == "argmax" else np.array(new)
            elif kind == "max":
                self.values[name] = np.maximum(old, new)
            elif kind == "min":
                self.values[name] = np.minimum(old, new)
            elif kind == "argmax":
                (v_old, t_old), (v_new, t_new) = old, new
                with np.errstate(invalid="ignore"):
                    better = (v_new > v_old) | (np.isnan(v_new) & ~np.isnan(v_old))
                self.values[name] = (np.where(better, v_new, v_old), np.where(better, t_new, t_old))

    def subset(self, keep: list) -> dict:
        """``values`` of the variants ``keep`` (positions)."""
        return {k: tuple(a[keep] for a in v) if isinstance(v, tuple) else v[keep] for k, v in self.values.items()}


def peak_over_time(values: np.ndarray, times: np.ndarray) -> tuple:
    """(peak (V,), its time (V,) [s]) of ``values`` (N+1, V) over the time axis: the first ``np.argmax``."""
    k = np.argmax(values, axis=0)
    cols = np.arange(values.shape[1])
    return values[k, cols], np.asarray(times, dtype=float)[k]


@dataclass
class GroupSummary:
    """What :func:`run_groups` yields for a group instead of a :class:`GroupRun` when given ``reduce``: ``values``
    the reductions over time it asked for (name -> (V,) array, in the order of ``indices``)."""

    indices: list
    scenes: list
    kind: str
    method: str
    choices: list
    values: dict

    def __len__(self) -> int:
        return len(self.indices)


def _error_line(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _profile_key(profile, memo: dict):
    key = memo.get(id(profile))
    if key is None:
        key = memo[id(profile)] = (type(profile).__name__, repr(profile.to_dict()))
    return key


def _group_key(scene: Scene, memo: dict) -> tuple:
    return (
        scene.model, scene.method if scene.method == AUTO_METHOD else method_class(scene.method).name, scene.dt, scene.duration, scene.output_rate,
        tuple(sorted((k, repr(v)) for k, v in scene.method_options.items())),
        _profile_key(scene.drive, memo), _profile_key(scene.load, memo),
    )  # fmt: skip


def simulate_many(scenes: Sequence[Scene], check_stability: bool = True, min_group: int = MIN_GROUP) -> Iterator[Outcome]:
    """One :class:`Outcome` per scene, in an order of its own (``index`` says which): ``simulate(scene)``'s result
    (<= 1e-12 relative, tests/test_ensemble.py) or its error; results are built as they are yielded."""
    for item in run_groups(scenes, check_stability, min_group):
        if isinstance(item, Outcome):
            yield item
            continue
        for v, i in enumerate(item.indices):
            yield Outcome(i, item.result(v), None, True)


def run_groups(
    scenes: Sequence[Scene], check_stability: bool = True, min_group: int = MIN_GROUP, reduce=None, window: int = 64,
) -> Iterator:  # fmt: skip
    """:func:`simulate_many` by blocks: yields :class:`Outcome` (single runs, failures) and :class:`GroupRun` (ensembles).

    ``reduce``: a pair ``(kinds, values)`` (:class:`Reductions` kinds, and ``values(run)`` the reductions of one
    window's :class:`GroupRun`, name -> (V,) array): the runs then go ``window`` steps at a time and yield
    :class:`GroupSummary` blocks (each variant's values those of its whole run) in memory of one window.
    """
    memo: dict = {}
    groups: dict = {}
    for i, scene in enumerate(scenes):
        try:
            key = _group_key(scene, memo)
        except BeltDriveError as exc:  # an unknown method name, say
            yield Outcome(i, None, _error_line(exc), False, "invalid scene")
            continue
        groups.setdefault(key, []).append(i)
    for members in groups.values():
        first = scenes[members[0]]
        reason = None
        if len(members) < min_group:
            reason = f"group of {len(members)} < {min_group} variants sharing profiles and settings"
        elif first.model == "slipping":
            reason = "slipping model (mode switches differ per variant)"
        else:
            reason = _unsupported(first)
        if reason is not None:
            for i in members:
                yield _single(i, scenes[i], check_stability, reason)
            continue
        yield from _run_group([(i, scenes[i]) for i in members], check_stability, reduce, window)


def _unsupported(scene: Scene) -> str | None:
    """Why ``scene``'s method cannot run in an ensemble, or None."""
    if scene.method == AUTO_METHOD:  # method and step are chosen per variant (core/method_choice.py)
        return "method auto (chosen per variant by the accuracy guard)"
    cls = method_class(scene.method)
    if not cls.fixed_step:
        return f"{cls.name} is adaptive (a step size per variant)"
    if not cls.explicit:
        return f"{cls.name} is implicit (a fixed-point iteration per variant)"
    return None


def _single(i: int, scene: Scene, check_stability: bool, reason: str) -> Outcome:
    try:
        return Outcome(i, simulate(scene, check_stability=check_stability), None, False, reason)
    except BeltDriveError as exc:
        return Outcome(i, None, _error_line(exc), False, reason)


def _stable(members: list, models: ModelStack, check_stability: bool) -> tuple[list, list]:
    """(positions of ``members`` ``[(i, scene)]`` that may run, failed Outcomes): the single run's stability guard."""
    ok, failed = [], []
    for v, (i, scene) in enumerate(members):
        if check_stability and not method_class(scene.method).exact_linear:  # exact-linear methods pass at any step
            try:
                require_stable(models.A[v], models.B[v], scene.method, scene.dt)
            except BeltDriveError as exc:  # named as the single run names it: a step both guards accept
                failed.append(Outcome(i, None, _error_line(good_step_error(scene, models.name, exc)), True))
                continue
        ok.append(v)
    return ok, failed


def _run_group(members: list, check_stability: bool, reduce=None, window: int = 64) -> Iterator:
    """One group (shared profiles and settings): see the module docstring and :func:`run_groups`."""
    first = members[0][1]
    drive, load, T = first.drive, first.load, first.duration
    size = window if reduce is not None else None
    columns = ParamColumns([s.params for _, s in members])  # every model stack of the group is built from these
    ratios = dict(zip((i for i, _ in members), columns.ratio.tolist()))  # (BeltDriveParams.ratio on the columns)
    if first.model in ("rigid", "flexible"):
        kinds = {i: first.model for i, _ in members}
        linear: dict = {}
    else:  # auto: the rigid estimate of the operating speeds, for all variants at once
        rigid = ModelStack("rigid", [s.params for _, s in members], columns)
        ens = Ensemble(rigid, drive, load, "exact", operating_run_step(T))
        x0 = _initial_states(members, "rigid", ratios)
        block = GroupRun([i for i, _ in members], [s for _, s in members], rigid, "rigid", "exact", None, None, None)
        # as fidelity's rigid estimate: max |omega_M|, max |omega_3|, max |belt torque|; and the belt torque
        # the start needs: the rigid belt torque at t = 0 (fidelity.start_mismatch)
        # and, as the survey's change_frequency, its belt torque's fastest change and swing (windows share their end
        # knots: every step is inside one)
        estimate = Reductions({"w": "max", "peak": "max", "start": "first", "rate": "max", "lo": "min", "hi": "max"})
        for times, states in ens.windows(x0, 0.0, T, size):
            belt = block.window(times, states, ens.inputs(times, states)).output("belt_torque")
            rate, lo, hi = belt_change(times, belt)
            with np.errstate(invalid="ignore"):
                estimate.update(
                    {"w": np.max(np.abs(states[:, 1, :]), axis=0), "peak": np.max(np.abs(belt), axis=0), "start": belt[0],
                     "rate": rate, "lo": lo, "hi": hi}
                )
        w, peak = estimate.values["w"], estimate.values["peak"]
        start = estimate.values["start"].tolist()
        change = change_frequency(estimate.values["rate"], estimate.values["lo"], estimate.values["hi"])
        kinds, linear = {}, {}
        for v, (i, s) in enumerate(members):
            if not math.isfinite(w[v]):  # the estimate diverged: simulate reports it
                yield _single(i, s, check_stability, "the rigid estimate of the operating speeds diverged")
                continue
            speeds = (float(w[v]), float(w[v]) * s.params.ratio, float(peak[v]))
            try:
                linear[i] = choose_model(s, check_slip=False, speeds=speeds, start_torque=start[v],
                                         change_frequency=float(change[v]))
                kinds[i] = linear[i].model
            except BeltDriveError as exc:
                yield Outcome(i, None, _error_line(exc), True)
    for kind in ("rigid", "flexible"):
        picked = [v for v, (i, _) in enumerate(members) if kinds.get(i) == kind]
        if not picked:
            continue
        chosen = [members[v] for v in picked]
        models = ModelStack(kind, [s.params for _, s in chosen], columns.subset(picked))
        ok, failed = _stable(chosen, models, check_stability)
        yield from failed
        if not ok:
            continue
        if len(ok) < len(chosen):
            chosen, models = [chosen[v] for v in ok], models.subset(ok)
        try:
            ens = Ensemble(models, drive, load, first.method, first.dt, first.method_options)
        except EnsembleUnsupported as exc:
            for i, s in chosen:
                yield _single(i, s, check_stability, str(exc))
            continue
        x0 = _initial_states(chosen, kind, ratios)
        block = GroupRun([i for i, _ in chosen], [s for _, s in chosen], models, kind, ens.method, None, None, None)
        found: dict = {}
        capstan = Reductions({"use": "argmax"})
        reduced = Reductions(reduce[0]) if reduce is not None else None
        run = None
        for w, (times, states) in enumerate(ens.windows(x0, 0.0, T, size)):
            if w == 0 or np.any(ens.status != OK):  # the first window (x0 too), and any after the loop found a bad knot
                ens.first_bad(times, states, found)
            run = block.window(times, states, ens.inputs)  # the torques only if an output needs them
            with np.errstate(all="ignore"):  # diverged variants (dropped below) give NaN
                if first.model == "auto":  # the capstan check of each variant's linear run (fidelity.limit_exceedance)
                    capstan.update({"use": run.peaks()["use"]})
                if reduced is not None:
                    reduced.update(reduce[1](run))
        diverged = ens.diverged_errors(found)
        for v, (i, _) in enumerate(chosen):
            if v in diverged:
                yield Outcome(i, None, _error_line(diverged[v]), True)
        keep = [v for v in range(len(chosen)) if v not in diverged]
        if first.model == "auto":  # the single run's choice per variant
            ratios, peaks = capstan.values["use"]
            limits = list(zip(ratios.tolist(), peaks.tolist()))
            choices = {}
            for v in keep:
                i, scene = chosen[v]
                choice = choose_model(scene, linear=linear[i], limit=limits[v])
                if choice.model == "slipping":
                    yield _single(i, scene, check_stability, "slipping model (the capstan limit is passed)")
                    continue
                choices[v] = choice
            keep = [v for v in keep if v in choices]
            block.choices = [choices.get(v) for v in range(len(chosen))]
        if not keep:
            continue
        if reduced is not None:
            yield GroupSummary([block.indices[v] for v in keep], [block.scenes[v] for v in keep], kind, ens.method,
                               [block.choices[v] for v in keep], reduced.subset(keep))  # fmt: skip
            continue
        run.choices = block.choices
        yield run if len(keep) == len(chosen) else _subset(run, keep)


def _initial_states(members: list, kind: str, ratios: dict) -> np.ndarray:
    """(V, n) the initial states of ``members`` ``[(i, scene)]`` on model ``kind``: each the scene's
    ``initial_state.vector(kind, ratio)`` with ``ratios[i]`` its parameters' ratio i, made once per initial state and
    ratio (a tolerance sweep's variants share both)."""
    made: dict = {}
    rows = []
    for i, s in members:
        ratio = ratios[i]
        key = (id(s.initial_state), ratio)
        row = made.get(key)
        if row is None:
            row = made[key] = s.initial_state.vector(kind, ratio)
        rows.append(row)
    return np.stack(rows)


def _subset(run: GroupRun, keep: list) -> GroupRun:
    """The variants ``keep`` of ``run`` (a new block; outputs are recomputed on demand)."""
    return GroupRun(
        [run.indices[v] for v in keep], [run.scenes[v] for v in keep], run.models.subset(keep), run.kind,
        run.method, run.times, run.states[:, :, keep], run.inputs[:, :, keep], [run.choices[v] for v in keep],
    )  # fmt: skip
