"""``simulate`` for many scenes at once: variants that can share an ensemble run together, the rest singly.

:func:`simulate_many` gives, for each scene, what
:func:`~belt_drive_ros.core.simulate.simulate` gives (the same model
choice, the same states and outputs to rounding) or the error it raises.
Scenes that share everything but their parameters and initial state (the
torque profiles, model setting, method, step, duration, output rate) form a
group; a group runs as one :class:`~belt_drive_ros.core.ensemble.Ensemble`
per linear model:

* ``model: rigid | flexible``: one ensemble run.
* ``model: auto``: the frequency rule's rigid estimate of the operating
  speeds as one ensemble run (``exact``, the step of
  :func:`~belt_drive_ros.core.fidelity.operating_run_step`), the rule per
  variant, one ensemble run per chosen linear model, then the capstan check
  per variant (:func:`~belt_drive_ros.core.fidelity.choose_model` with the
  speeds and the run passed in); a variant that passes the limit goes on to
  the slipping model, singly, as ``simulate`` does.

Run singly (through ``simulate`` itself): the slipping model, methods the
ensemble does not cover (adaptive, implicit), and groups smaller than
:data:`MIN_GROUP` (a profile that differs per variant, say). Each outcome
says which way it ran and, for a single run, why.

Ensemble results carry states, inputs, outputs and the model choice; not
the energy terms or the stability report of a single run (``energy`` is
empty, ``stability`` None).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from .ensemble import Ensemble, EnsembleUnsupported
from .errors import BeltDriveError
from .fidelity import choose_model, operating_run_step
from .integrators import method_class
from .model import make_model
from .scene import Scene
from .simulate import SimResult, simulate
from .stability import require_stable

#: groups of fewer variants run singly (an ensemble's per-step overhead is that of ~8 single runs)
MIN_GROUP = 8


@dataclass
class Outcome:
    """What one scene's run gave.

    Attributes
    ----------
    index : position of the scene in the input.
    result : the :class:`~belt_drive_ros.core.simulate.SimResult` (None when the run failed).
    error : the failure as one line (``"ErrorType: message"``), or None.
    ensemble : True when the run was part of an ensemble.
    single_reason : why it ran singly (None for an ensemble run).
    """

    index: int
    result: SimResult | None
    error: str | None
    ensemble: bool
    single_reason: str | None = None


def _error_line(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _profile_key(profile, memo: dict):
    key = memo.get(id(profile))
    if key is None:
        key = memo[id(profile)] = (type(profile).__name__, repr(profile.to_dict()))
    return key


def _group_key(scene: Scene, memo: dict) -> tuple:
    return (
        scene.model, method_class(scene.method).name, scene.dt, scene.duration, scene.output_rate,
        tuple(sorted((k, repr(v)) for k, v in scene.method_options.items())),
        _profile_key(scene.drive, memo), _profile_key(scene.load, memo),
    )  # fmt: skip


def simulate_many(scenes: Sequence[Scene], check_stability: bool = True, min_group: int = MIN_GROUP) -> Iterator[Outcome]:
    """Yield one :class:`Outcome` per scene (in an order of its own; ``index`` says which).

    Each successful outcome's result equals ``simulate(scene)`` to rounding
    (<= 1e-12 relative, tests/test_ensemble.py); a failing scene yields the
    error ``simulate`` raises, as one line, and does not stop the others.
    Results are built as they are yielded, so a caller that keeps only
    metrics holds one group's states at a time.
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
        yield from _run_group([(i, scenes[i]) for i in members], check_stability)


def _unsupported(scene: Scene) -> str | None:
    """Why ``scene``'s method cannot run in an ensemble, or None."""
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


def _stable(scenes, kind: str, check_stability: bool) -> tuple[list, list]:
    """Split ``[(i, scene, model)]`` into runnable ones and failed Outcomes (the single run's stability guard)."""
    ok, failed = [], []
    for i, scene, model in scenes:
        if check_stability and not method_class(scene.method).exact_linear:  # exact-linear methods pass at any step
            try:
                require_stable(model.A, model.B, scene.method, scene.dt)
            except BeltDriveError as exc:
                failed.append(Outcome(i, None, _error_line(exc), True))
                continue
        ok.append((i, scene, model))
    return ok, failed


def _run_group(members: list, check_stability: bool) -> Iterator[Outcome]:
    """One group (shared profiles and settings): see the module docstring."""
    first = members[0][1]
    drive, load, T = first.drive, first.load, first.duration
    if first.model in ("rigid", "flexible"):
        kinds = {i: first.model for i, _ in members}
        speeds: dict = {}
        linear: dict = {}
    else:  # auto: the rigid estimate of the operating speeds, for all variants at once
        rigid = [make_model("rigid", s.params) for _, s in members]
        ens = Ensemble(rigid, drive, load, "exact", operating_run_step(T))
        x0 = np.stack([s.initial_state.vector("rigid", s.params.ratio) for _, s in members])
        times, states = ens.run(x0, 0.0, T)
        u = ens.inputs(times, states)
        w = np.max(np.abs(states[:, 1, :]), axis=0)
        speeds = {  # as fidelity's rigid estimate: max |omega_M|, max |omega_3|, max |belt torque|
            i: (float(w[v]), float(w[v]) * s.params.ratio,
                float(np.max(np.abs(rigid[v].belt_torque(states[:, :, v], u[:, :, v])))))
            for v, (i, s) in enumerate(members)
        }  # fmt: skip
        kinds, linear = {}, {}
        for v, (i, s) in enumerate(members):
            if not math.isfinite(w[v]):  # the estimate diverged: simulate reports it
                yield _single(i, s, check_stability, "the rigid estimate of the operating speeds diverged")
                continue
            try:
                linear[i] = choose_model(s, check_slip=False, speeds=speeds[i])
                kinds[i] = linear[i].model
            except BeltDriveError as exc:
                yield Outcome(i, None, _error_line(exc), True)
    for kind in ("rigid", "flexible"):
        chosen = [(i, s, make_model(kind, s.params)) for i, s in members if kinds.get(i) == kind]
        chosen, failed = _stable(chosen, kind, check_stability)
        yield from failed
        if not chosen:
            continue
        try:
            ens = Ensemble([m for _, _, m in chosen], drive, load, first.method, first.dt, first.method_options)
        except EnsembleUnsupported as exc:
            for i, s, _ in chosen:
                yield _single(i, s, check_stability, str(exc))
            continue
        x0 = np.stack([s.initial_state.vector(kind, s.params.ratio) for _, s, _ in chosen])
        times, states = ens.run(x0, 0.0, T)
        u = ens.inputs(times, states)
        diverged = ens.diverged(times, states)
        for v, (i, scene, model) in enumerate(chosen):
            if v in diverged:
                yield Outcome(i, None, _error_line(diverged[v]), True)
                continue
            x_v, u_v = states[:, :, v], u[:, :, v]
            outputs = model.outputs(x_v, u_v)
            choice = None
            if scene.model == "auto":
                choice = choose_model(scene, linear=linear[i], linear_run=lambda _kind: (times, outputs))
                if choice.model == "slipping":
                    yield _single(i, scene, check_stability, "slipping model (the capstan limit is passed)")
                    continue
            result = SimResult(
                scene=scene, model=kind, method=ens.method, dt=scene.dt, time=times, states=x_v, inputs=u_v,
                outputs=outputs, choice=choice, wall_time=math.nan,
            )  # fmt: skip
            yield Outcome(i, result, None, True)
