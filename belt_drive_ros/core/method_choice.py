"""Method and step by accuracy: what a scene that names no method (or ``method: auto``) runs with (``docs/model.md``,
"How accurate a fixed step is, and how `method: auto` picks one").

The cheapest of :data:`CANDIDATES` (exact for the belt mode; 1, 2, 4, 6 torque evaluations per step) the accuracy
guard rates stable and within :data:`~.accuracy.SUGGEST_MARGIN` of the tolerance on this scene (the slipping model:
both modes) at the scene's ``dt``, else at the fewest substeps ``n`` of :data:`SUBSTEPS` (step ``dt / n``, one a scene
takes: :func:`~.accuracy.scene_takes`); when none is, the smallest estimate found, its reason saying the tolerance is not
met.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .accuracy import ACCURACY_TOLERANCE, SUGGEST_MARGIN, check_accuracy, check_slipping, probe_scene, scene_takes

#: the method name that asks for this choice
AUTO = "auto"
#: candidates, cheapest first (torque evaluations per step)
CANDIDATES = ("exact", "etd2", "etd4", "lawson5")
#: substeps tried when no candidate is accurate at the scene's dt
SUBSTEPS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)


@dataclass(frozen=True)
class MethodChoice:
    """Outcome of :func:`choose_method`: ``method`` and its step ``dt`` [s] (the scene's dt / ``substeps``);
    ``tolerance`` aimed at and the guard's ``error`` for the choice [-], ``met`` when within it; ``reason`` (one
    sentence a person can check); ``tried`` ((method, dt [s], estimated error [-]), ...) in the order checked;
    ``report``: the guard's report of the choice on a rigid or flexible plant (None: slipping), which the run's own
    guard reuses when it is stable and accurate (the same check, not made twice)."""

    method: str
    dt: float
    substeps: int
    tolerance: float
    error: float
    met: bool
    reason: str
    tried: tuple = ()
    report: object = None


def _rate(report) -> float:
    return report.error if report is not None and report.stable else math.inf


def choose_method(plant, duration: float, x0, dt: float, tolerance: float = ACCURACY_TOLERANCE, stated_inputs: bool = True,
                  slipping: tuple | None = None, survey=None) -> MethodChoice:  # fmt: skip
    """The cheapest candidate (and fewest substeps) the guard rates accurate on ``plant`` (module docstring).

    ``plant``: the model the run uses (rigid or flexible; for the slipping
    model its flexible plant with ``slipping = (params, drive, load)``).
    ``x0``: the plant model's initial state; ``dt`` [s]: the scene's step; ``survey``: the scene's
    :class:`~belt_drive_ros.core.fidelity.RigidSurvey` the probes are read from (shared with the run's guard).
    """
    bar = SUGGEST_MARGIN * tolerance
    tried, reports = [], {}
    probes = probe_scene(plant, duration, x0, dt, stated_inputs, survey)

    def rate(method, h):
        if slipping is not None:
            report = check_slipping(*slipping, method, h, duration, x0, tolerance, suggest=False,
                                    stated_inputs=stated_inputs, probes=probes)  # fmt: skip
        else:
            report = check_accuracy(plant, method, h, duration, x0, tolerance, suggest=False, probes=probes,
                                    stated_inputs=stated_inputs)  # fmt: skip
        error = _rate(report)
        tried.append((method, h, error))
        reports[method, h] = report if slipping is None else None
        return error

    for n in SUBSTEPS:
        h = dt / n
        if n > 1 and not scene_takes(h, duration):  # a step (or step count) the scene itself would refuse
            break
        # the most accurate first: when neither passes, the cheaper ones are not checked at this step
        best = {m: rate(m, h) for m in ("etd4", "lawson5")}
        if min(best.values()) > bar:
            continue
        for method in CANDIDATES:
            error = best[method] if method in best else rate(method, h)
            if error <= bar:
                return MethodChoice(method, h, n, tolerance, error, True, _reason(method, h, n, dt, error, tolerance, tried),
                                    tuple(tried), reports[method, h])  # fmt: skip
    method, h, error = min(tried, key=lambda r: (r[2], -r[1]))
    n = round(dt / h)
    reason = (
        f"{method} at dt={h:.3g} s ({n} substep(s) of {dt:.3g} s): no candidate ({', '.join(CANDIDATES)}) is rated within "
        f"{bar:.2g} (a quarter of the tolerance {tolerance:.2g}) down to {min(r[1] for r in tried):.3g} s; this is the most "
        f"accurate found (estimated {error:.2g} of the peak)"
    )
    return MethodChoice(method, h, n, tolerance, error, error <= tolerance, reason, tuple(tried))


def _reason(method, h, n, dt, error, tolerance, tried) -> str:
    cheaper = [f"{m} {e:.2g}" for m, hh, e in tried if hh == h and CANDIDATES.index(m) < CANDIDATES.index(method)]
    step = f"dt={h:.3g} s" + (f" ({n} substeps of the scene's {dt:.3g} s: none is accurate at {dt:.3g} s)" if n > 1 else " (the scene's)")
    line = (
        f"{method} at {step}: the cheapest of {', '.join(CANDIDATES)} the accuracy guard rates within a quarter of the "
        f"tolerance {tolerance:.2g} on this scene (estimated {error:.2g} of the peak)"
    )
    if cheaper:
        line += f"; cheaper ones rate {', '.join(cheaper)}"
    return line


def choose_for_scene(scene, kind: str, survey=None) -> MethodChoice:
    """:func:`choose_method` for ``scene`` on the model ``kind`` (rigid, flexible, slipping or regularised).

    Slipping: the flexible plant with both modes checked; regularised: the flexible plant (its own
    stability guard still checks the chosen step on the regularised contact).
    """
    plant, x0 = _plant(scene, kind)
    slipping = (scene.params, scene.drive, scene.load) if kind == "slipping" else None
    return choose_method(plant, scene.duration, x0, scene.dt, scene.tolerance, slipping=slipping, survey=survey)


def _plant(scene, kind: str):
    """(plant, initial state) of the linear model a run on ``kind`` is rated on: rigid, else flexible."""
    from .model import make_model
    from .stepper import Plant

    base = "rigid" if kind == "rigid" else "flexible"
    return Plant(make_model(base, scene.params), scene.drive, scene.load), scene.initial_state.vector(base, scene.params.ratio)


def resolve(scene, kind: str | None = None, survey=None):
    """``(scene, choice)``: the scene with method and dt chosen when it says ``method: auto``, else ``(scene, None)``.

    ``kind``: the model the run uses (rigid, flexible, slipping, regularised); default the scene's own.
    For ``model: auto`` the caller passes the frequency rule's rigid or flexible
    (:func:`~belt_drive_ros.core.fidelity.choose_model` with ``check_slip=False``); a run that then slips is
    checked in both modes after it. ``survey``: the scene's rigid survey, shared (see :func:`choose_method`).
    """
    if scene.method != AUTO:
        return scene, None
    kind = kind or scene.model
    if kind == "auto":
        raise ValueError("resolve: model auto needs the linear tier the frequency rule chose (kind)")
    choice = choose_for_scene(scene, kind, survey)
    return scene.with_overrides(method=choice.method, dt=choice.dt), choice


def good_step_error(scene, kind: str, error):
    """The stability guard's refusal ``error`` for ``scene`` on ``kind``, naming a step both guards accept: the
    stability guard sees the free belt only, so the accuracy guard's search (halvings, then another method:
    :func:`~.accuracy.check_accuracy`) names one stable for both and within a quarter of the tolerance. The
    original ``error`` when that search names nothing."""
    from .errors import UnstableStepError

    report = getattr(error, "stability", None)
    if report is None:
        return error
    plant, x0 = _plant(scene, kind)
    if kind == "slipping":
        rated = check_slipping(scene.params, scene.drive, scene.load, scene.method, scene.dt, scene.duration, x0,
                               scene.tolerance, scene.method_options)  # fmt: skip
    else:
        rated = check_accuracy(plant, scene.method, scene.dt, scene.duration, x0, scene.tolerance, scene.method_options)
    if rated is None or (rated.suggestion is None and rated.alternative is None):
        return error
    where = f"stable and accurate to {scene.tolerance:.2g} on this scene's closed loop (both guards)"
    if rated.suggestion is not None:
        fix = f"dt = {rated.suggestion:.3g} s is {where}"
        if rated.alternative is not None:
            fix += f"; so is {rated.alternative[0]} at dt = {rated.alternative[1]:.3g} s"
    else:
        fix = f"no step of {rated.method} is accurate down to {rated.searched_to:.2g} s; {rated.alternative[0]} at dt = " \
              f"{rated.alternative[1]:.3g} s is {where}"
    fresh = UnstableStepError(f"{report.describe()}; {fix}")
    fresh.stability = report
    return fresh
