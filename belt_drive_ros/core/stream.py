"""Streamed runs: a scene's run in windows, in memory that does not grow with its duration.

:func:`simulate` keeps every sample (~300 bytes each: a day of ``paper`` at 5 ms would be 5 GB);
:func:`stream` yields the same run as consecutive :class:`~belt_drive_ros.core.simulate.SimResult` windows of
``window_steps`` grid steps, each later one from the sample after the previous window's last: their states
together are :func:`simulate`'s bit for bit, the energy terms to rounding (the trapezoidal quadrature runs on
across the seams). ``model: auto`` streams too: the chosen linear run is checked against the capstan limit
window by window; past it the stream yields a :class:`Restart` and starts over on the slipping model, as
:func:`~belt_drive_ros.core.fidelity.choose_model` decides on the whole run.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, replace
from typing import Callable, Iterator

import numpy as np

from .accuracy import require_accurate
from .method_choice import resolve as resolve_method
from .fidelity import ModelChoice, _linear_choice, choose_model, limit_exceedance
from .model import make_model
from .scene import Scene
from .simulate import SimResult, Simulator, _linear_result, _slipping_accuracy, _slipping_result
from .slip_run import SlippingSimulator
from .step_plan import snap_tolerance
from .stepper import PAGE_MARGIN

__all__ = ["WINDOW_STEPS", "Restart", "stream"]

#: grid steps per window (~15 MB of arrays per window)
WINDOW_STEPS = 50_000


@dataclass(frozen=True)
class Restart:
    """Yielded by :func:`stream` when an ``auto`` run turns out to slip: discard the windows so far."""

    choice: ModelChoice


def stream(
    scene: Scene,
    model: str | None = None,
    method: str | None = None,
    dt: float | None = None,
    duration: float | None = None,
    progress: Callable[[float], None] | None = None,
    check_stability: bool = True,
    window_steps: int | None = None,
) -> Iterator[SimResult | Restart]:
    """Windows of the run of ``scene`` (overrides as for :func:`~belt_drive_ros.core.simulate.simulate`;
    ``window_steps`` default :data:`WINDOW_STEPS`), and for ``model='auto'`` at most one :class:`Restart`, after
    which the windows start again at t = 0 on the slipping model. Each window's ``choice`` is the one in force."""
    scene = scene.with_overrides(model=model, method=method, dt=dt, duration=duration)
    kind = _linear_choice(scene).model if scene.model == "auto" and scene.method == "auto" else None
    scene, method_choice = resolve_method(scene, kind)
    if method_choice is not None:  # method: auto, chosen once: every window says how
        for window in stream(scene, progress=progress, check_stability=check_stability, window_steps=window_steps):
            if not isinstance(window, Restart):
                window.method_choice = method_choice
            yield window
        return
    window_steps = WINDOW_STEPS if window_steps is None else int(window_steps)
    if window_steps < 1:
        raise ValueError(f"window_steps must be >= 1, got {window_steps}")
    if scene.model == "slipping":
        yield from _slipping(scene, None, progress, check_stability, window_steps)
        return
    if scene.model != "auto":
        yield from _linear(scene, scene.model, None, progress, check_stability, window_steps)
        return
    choice = _linear_choice(scene)
    choice = replace(choice, linear=choice.model)
    peak, t_peak = 0.0, 0.0
    guards: list = []
    for window in _linear(scene, choice.model, choice, progress, check_stability, window_steps, guards):
        ratio, t_at = limit_exceedance(scene.params, window.time, window.outputs)
        if ratio > peak:
            peak, t_peak = ratio, t_at
        checked = choose_model(scene, linear=choice, limit=(peak, t_peak))  # the capstan check on the run so far
        if checked.model == "slipping":
            for guard in guards:  # the linear run's guard refuses an unstable step before anything else is said
                guard.result()
            yield Restart(checked)
            yield from _slipping(scene, checked, progress, check_stability, window_steps)
            return
        window.choice = checked
        yield window


def _ends(stepper, duration: float, window_steps: int) -> Iterator[tuple[float, float]]:
    """(t0, t1) of consecutive windows of ``window_steps`` grid steps over [0, duration]."""
    t, k = 0.0, 0
    while t < duration:
        k += window_steps
        t_next = stepper.grid_time(k)
        if t_next >= duration - snap_tolerance(duration, stepper.dt):
            t_next = duration
        yield t, t_next
        t = t_next


def _beside(call, *args, **kwargs):
    """A future of ``call(*args, **kwargs)`` run in a daemon thread of its own (an interrupted run does not wait)."""
    import threading
    from concurrent.futures import Future

    future = Future()

    def run():
        try:
            future.set_result(call(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread by result()
            future.set_exception(exc)

    threading.Thread(target=run, name="accuracy-guard", daemon=True).start()
    return future


def _linear(scene, kind, choice, progress, check_stability, window_steps, guards=None) -> Iterator[SimResult]:
    """The linear model's windows. ``guards``: a list that receives the future of the run's accuracy guard
    (the ``auto`` choice confirms it before it restarts on the slipping model)."""
    mdl = make_model(kind, scene.params)
    sim = Simulator(mdl, scene.drive, scene.load, scene.method, scene.dt, scene.method_options, check_stability)
    stepper = sim.stepper
    stepper.origin = 0.0
    x = scene.initial_state.vector(kind, scene.params.ratio)
    ends = list(_ends(stepper, scene.duration, window_steps)) or [(0.0, 0.0)]
    # closed loop (torque slopes): refuses an unstable step, reports an inaccurate one (as simulate does); a run
    # of several windows checks beside them (its own steppers: a stepper notes the run it makes), the last
    # window carries the report, and a refusal is raised in place of anything the run raised meanwhile
    check = (sim.plant, scene.method, scene.dt, scene.duration, x, scene.tolerance)
    guard = _beside(require_accurate, *check, method_options=scene.method_options) if check_stability and len(ends) > 1 else None
    accuracy = (require_accurate(*check, method_options=scene.method_options, stepper=stepper)
                if check_stability and guard is None else None)
    if guard is not None and guards is not None:
        guards.append(guard)
    totals: dict = {}
    for k, (t0, t1) in enumerate(ends):
        start = _time.perf_counter()
        try:
            time, states = stepper.run(x, t0, t1)
        except Exception:
            if guard is not None:
                guard.result()
            raise
        wall, x = _time.perf_counter() - start, states[-1]
        if guard is not None:
            accuracy = guard.result() if k == len(ends) - 1 or guard.done() else None
        yield _linear_result(scene, mdl, sim.plant, time, states, sim.stability, accuracy, wall, totals, choice)
        if progress:
            progress(t1 / scene.duration)


class _PagedSlipping(SlippingSimulator):
    """The slipping run of a drive read a page at a time (``drive.page``): the hybrid stepper holds its
    torque's table, so each advance runs on a simulator of the page of its times, widened by
    :data:`~belt_drive_ros.core.stepper.PAGE_MARGIN` steps each side (the same torques and breakpoints
    there: the same steps, events and states as on the whole table)."""

    def __init__(self, *args):
        super().__init__(*args, lazy=True)  # (its own steppers step no drive: the pages' do)

    def _page(self, t0: float, t1: float) -> SlippingSimulator:
        m = PAGE_MARGIN * self.dt
        return SlippingSimulator(self.model.params, self.drive.page(t0 - m, t1 + m), self.load, self.method, self.dt,
                                 self.method_options, False, self.origin)

    def initial(self, y0, t0=0.0):
        return self._page(t0, t0).initial(y0, t0)

    def advance(self, state, t0, t1, record=None, events=None):
        return self._page(t0, t1).advance(state, t0, t1, record, events)


def _slipping(scene, choice, progress, check_stability, window_steps) -> Iterator[SimResult]:
    paged = getattr(scene.drive, "page", None) is not None
    sim = (_PagedSlipping if paged else SlippingSimulator)(scene.params, scene.drive, scene.load, scene.method, scene.dt,
                                                          scene.method_options, check_stability)
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    accuracy = _slipping_accuracy(scene, sim) if check_stability else None
    totals: dict = {}
    last = None  # (time, state, mode, sigma) of the previous window's last sample: the quadrature's seam
    events: list = []
    between = [0.0, math.nan]  # the largest excursion between samples so far and its time (_slipping_result)
    start = _time.perf_counter()
    for time, states, modes, sigmas in sim.windows(scene.duration, y0, 0.0, progress, window_steps, events):
        wall = _time.perf_counter() - start
        if last is not None:
            time = np.concatenate([[last[0]], time])
            states = np.concatenate([last[1][None, :], states])
            modes = np.concatenate([[last[2]], modes]).astype(np.int8)
            sigmas = np.concatenate([[last[3]], sigmas])
        last = (float(time[-1]), states[-1].copy(), int(modes[-1]), float(sigmas[-1]))
        # (the excursions between samples as the whole run's guard finds them, window by window: ``between``)
        yield _slipping_result(scene, sim, time, states, modes, sigmas, wall, choice, accuracy, events, totals, between)
        events.clear()
        start = _time.perf_counter()
