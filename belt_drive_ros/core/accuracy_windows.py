"""The accuracy guard's forcing-window terms (:mod:`belt_drive_ros.core.accuracy`): the method's error on the
scene's real torques (time, angle, speed) in short windows at the probes, by Richardson, and its drift over the run.
"""

from __future__ import annotations

import math

import numpy as np

from .accuracy_probes import APERIODIC_KINDS, WINDOW_STEPS, Probes, _output_rows, closed_loop_eigenvalues
from .errors import IntegratorError, SimulationDivergedError
from .integrators import method_class
from .stepper import shared_stepper

#: steps of a rigid run's forcing windows where a torque may repeat (its steps are cheap): a ripple's error is seen to
#: stop growing (:func:`_grown`)
RIGID_WINDOW_STEPS = 4 * WINDOW_STEPS


def forcing_error(plant, method: str, dt: float, probes: Probes, method_options=None, stepper=None, head=None) -> float:
    """A posteriori error [-] of the method at ``dt`` on the scene's real torques (time, angle, speed), by Richardson.

    Each window of :data:`WINDOW_STEPS` steps (``probes.windows``) is run at ``dt`` and at ``dt / 2`` from
    the same state; for a method of order p the error of the ``dt`` run is ``|y_dt - y_dt/2| 2^p / (2^p - 1)``.
    Signals: drive speed and belt torque, each relative to its peak over all windows' ``dt / 2`` runs; the
    worst signal and window counts. This sees what the linearization does not: harmonics in crank angle,
    schedules, profiles (their bandwidth against the step). Diverged: inf. ``head``: see :func:`window_errors`.
    """
    windows = window_errors(plant, method, dt, probes, method_options, stepper, head)
    if windows is None:
        return math.inf
    err, peak = windows[0][1], windows[0][2]
    for _, e, p in windows[1:]:  # (np.max over windows, pairwise: no (windows, 2) array made)
        err, peak = np.maximum(err, e), np.maximum(peak, p)
    return float(np.where(peak > 0, err / np.where(peak > 0, peak, 1.0), 0.0).max())


def window_errors(plant, method: str, dt: float, probes: Probes, method_options=None, stepper=None, head=None) -> list | None:
    """``[(t0, Richardson error (2,), peak (2,))]`` per forcing window (see :func:`forcing_error`); None: diverged.

    ``head``: ``() -> (times, states)`` of the scene's own run at ``dt`` from t = 0 (or None); one from ``probes.x0``
    bit for bit is the first window's ``dt`` run up to the window's end (the same steps), not run again."""
    order = method_class(method).order or 1
    factor = 2.0**order / (2.0**order - 1.0)
    rigid = plant.model.name == "rigid"
    C, D = _output_rows(plant.model)
    coarse = stepper or shared_stepper(plant, method, dt, method_options)
    fine = shared_stepper(plant, method, dt / 2.0, method_options)  # (make_integrator shares the half-step integrator)
    runs = []
    span = window_span(plant, probes, dt)
    for t0, x in probes.window_starts(plant, dt):
        t1 = min(t0 + span, probes.duration)
        if t1 <= t0 + 0.5 * dt:
            continue
        own = head() if head is not None and t0 == 0.0 and x is probes.x0 else None
        k = int(own[0].searchsorted(t1)) if own is not None else 0
        try:
            if own is not None and k < own[0].size and own[0][k] == t1 and own[1][0].tobytes() == x.tobytes():
                tc, xc = own[0][: k + 1], own[1][: k + 1]
            else:
                tc, xc = coarse.run(x, t0, t1)
            tf, xf = fine.run(x, t0, t1)
        except (SimulationDivergedError, IntegratorError):  # diverged, or an implicit stage did not converge
            return None
        if tf.size == 2 * tc.size - 1 and (tf[::2] == tc).all():  # every coarse knot is every other fine one
            runs.append((t0, tc, xc, tf[::2], xf[::2]))
            continue
        idx = np.clip(np.searchsorted(tf, tc - 1e-9 * dt), 0, tf.size - 1)
        same = np.abs(tf[idx] - tc) <= 1e-9 * dt + 8.0 * np.spacing(np.abs(tc) + dt)
        runs.append((t0, tc[same], xc[same], tf[idx[same]], xf[idx[same]]))
    if not runs:
        return []
    # the outputs of every window's two runs at once (one input evaluation for all of them)
    t_all = np.concatenate([r[k] for k in (1, 3) for r in runs])
    x_all = np.concatenate([r[k] for k in (2, 4) for r in runs])
    y_all = x_all @ C.T + plant.input_array(t_all, x_all) @ D.T
    if not np.isfinite(y_all).all():
        return None
    half = y_all.shape[0] // 2  # the coarse runs' samples, then the fine runs' at the same times
    starts, a = [], 0
    for r in runs:
        starts.append(a)
        a += r[1].size
    fine = y_all[half:]
    gap = factor * np.abs(y_all[:half] - fine)
    errs = np.maximum.reduceat(gap, starts, axis=0)
    peaks = np.maximum.reduceat(np.abs(fine), starts, axis=0)
    angle = any(plant.uses_angle)
    lasting = _drift_time(plant, probes) if rigid or angle else None
    if rigid:  # no belt mode: the window's error is the drive's, and it builds up over the run
        errs = _grown(starts, gap, t_all[half:], errs, lasting)
    drifts = (
        _phase_drifts(plant, starts, x_all[:half], x_all[half:], t_all[half:], fine, factor, lasting) if angle else {}
    )  # fmt: skip
    return [(r[0], np.maximum(errs[j], drifts[j]) if j in drifts else errs[j], peaks[j]) for j, r in enumerate(runs)]


def _grown(starts, gap, t, errs, duration: float) -> np.ndarray:
    """Each window's Richardson error ``errs`` (windows, signals) grown over the time ``duration`` [s] a speed error
    lasts (:func:`_drift_time`), for a rigid run.

    A window's two runs start from one state, so it sees the error its own steps make, not the error the run has
    built up by then: where the torques keep changing (a ramp at ``exact``, which holds them over each step, is
    first order) each window adds about as much again, and a barely damped drive keeps it (a 1 s ramp at 0.7 ms:
    6.1e-5 in a window, 8.8e-4 at the end of the run). As :func:`_phase_drifts` grows the angle, the growth
    ``g = log2(max over the window / max over its first half)`` in [0, 1] (1: linear, 0: not growing, e.g. a ripple
    whose error is made within a period) sets ``errs (duration / window)^g``. ``gap`` (rows, signals): the error at
    each of the windows' common times ``t``, window ``j``'s from row ``starts[j]``."""
    n = t.size
    ends = list(starts[1:]) + [n]  # (each window's rows: [start, end))
    halves = [a + (e - a) // 2 + 1 if e - a >= 3 else a for a, e in zip(starts, ends)]  # each first half's end
    first = np.maximum.reduceat(gap, [k for a, h in zip(starts, halves) for k in (a, min(h, n - 1))], axis=0)
    first, spans, out = first[::2].tolist(), (t[np.array(ends) - 1] - t[starts]).tolist(), errs.copy()
    for j, (a, e) in enumerate(zip(starts, ends)):  # (a few windows and signals: Python floats)
        span = spans[j]
        if e - a < 3 or not span > 0.0 or not duration > span:
            continue
        for k, whole in enumerate(errs[j].tolist()):
            if whole > 0.0:
                f = first[j][k]
                out[j, k] = whole * (duration / span) ** _growth(whole, f)
    return out


def window_span(plant, probes: Probes, dt: float) -> float:
    """Length [s] of the forcing windows at step ``dt`` [s]: ``probes.span(dt)``; a rigid run's where a torque may
    repeat, :data:`RIGID_WINDOW_STEPS` steps (its steps are cheap: a ripple's bounded error is seen to stop growing,
    :func:`_grown`; a torque that only rises, falls or holds has no ripple to take for a drift)."""
    ripple = plant.model.name == "rigid" and not {plant.drive.kind, plant.load.kind} <= APERIODIC_KINDS
    return RIGID_WINDOW_STEPS * dt if ripple else probes.span(dt)


def _growth(whole: float, first: float) -> float:
    """How an error grows over a window, ``g = log2(whole / first)`` in [0, 1] (its largest over the window against
    its largest over the first half: 1 linear, 0 not growing); 1 where the first half has none."""
    return 1.0 if not first > 0.0 else min(1.0, max(0.0, math.log2(max(whole / first, 1.0))))


def _drift_time(plant, probes) -> float:
    """How long [s] a speed error lasts, at most the run: ``1 / |Re lambda|`` of the slowest decaying closed-loop mode.

    The angle integrates the speed error for as long as it lasts: a governor or a speed-dependent load (``A + B K``,
    the probes' slopes) damps it in ``~1 / (K / I)``; without one it lasts the whole run.
    """
    A, B = plant.model.A, plant.model.B
    longest = 0.0
    for K, _ in probes.gains:
        lams = closed_loop_eigenvalues(A, B, K).tolist()  # (a few Python numbers: no numpy call per value)
        scale = max(abs(lam) for lam in lams) or 1.0
        decaying = [abs(lam.real) for lam in lams if abs(lam) > 1e-7 * scale and lam.real < 0.0]
        moving = [lam for lam in lams if abs(lam) > 1e-7 * scale]
        if len(decaying) < len(moving) or not decaying:
            return probes.duration  # a mode that does not decay: the error stays for the whole run
        longest = max(longest, 1.0 / min(decaying))
    return min(probes.duration, longest) if longest > 0.0 else probes.duration


def _phase_drifts(plant, starts, xc, xf, tf, yf, factor: float, duration: float) -> dict:
    """Error (2,) of the outputs from the angle error a window leaves, grown over the run (torques by crank angle).

    The angle has no restoring force: an error ``d phi`` can stay, and while the speed error that makes it persists
    (a speed transient, a systematic error per firing period) it grows about linearly over the run (measured: 5.6e-5
    rad after 48 steps, 6.8e-4 after 800 on an engine and compressor scene). Torques by angle then run early or late
    by ``d t = d phi / |omega|``, which moves each output by ``|dy/dt| d t``. Here ``d phi(t)`` is the Richardson
    error of the window's angles (drive and wheel 3, each over its top speed in the window: a wheel rocking about
    rest barely turns); its growth over the window, ``g = log2(max over the window / max over its first half)`` in
    [0, 1] (1: linear, 0: not growing), sets the growth over the time a speed error lasts (``duration``,
    :func:`_drift_time`), ``(duration / window)^g``; ``|dy/dt|`` is the fine run's largest rate. ``xc``, ``xf``: the
    window's states at dt and dt / 2 on the common times ``tf``.

    All windows at once: ``xc``, ``xf``, ``tf``, ``yf`` are the windows' rows one after the other, window ``j``'s from
    row ``starts[j]``; ``{j: error (2,)}`` of the windows of two rows or more (the same floats as window by window).
    """
    W = plant.wheel_map
    n = tf.size
    starts = [int(a) for a in starts]
    sizes = [b - a for a, b in zip(starts, starts[1:] + [n])]
    ends = [a + size - 1 for a, size in zip(starts, sizes)]  # each window's last row: its rate row would span two windows
    dy, dt = np.empty_like(yf), np.empty(n)
    dy[:-1], dt[:-1] = np.abs(np.diff(yf, axis=0)), np.diff(tf)
    dy[ends], dt[ends] = 0.0, 1.0  # (|dy/dt| >= 0: a zero row changes no window's largest rate)
    # (per window the few numbers of the loop below as Python floats: the same IEEE operations as numpy's on them)
    rate = np.maximum.reduceat(dy / dt[:, None], starts, axis=0).tolist()
    long = [j for j in range(len(starts)) if sizes[j] > 1]
    worst = {j: [0.0] * len(rate[j]) for j in long}
    if long:
        firsts = [starts[j] + min(max(1, sizes[j] // 2) + 1, sizes[j]) for j in long]
        # per window: its first half's rows, then the rest (a zero row after the last window: every bound indexes a row)
        bounds = [k for j, f in zip(long, firsts) for k in (starts[j], f, starts[j] + sizes[j])]
        gap = xc - xf
        for row_phi, row_w in ((W[0], W[1]), (W[2], W[3])):
            top = np.maximum.reduceat(np.abs(xf @ row_w), starts).tolist()  # each window's top speed
            # max of (factor |d phi| / w) = factor max |d phi| / w (w > 0; rounding keeps the order): the same floats
            dphi = np.maximum.reduceat(np.append(np.abs(gap @ row_phi), 0.0), bounds).tolist()
            for k, j in enumerate(long):
                w = top[j]
                if not w > 1e-9:
                    continue
                first = factor * dphi[3 * k] / w
                rest = dphi[3 * k + 1] if firsts[k] < starts[j] + sizes[j] else dphi[3 * k]
                whole = factor * _maximum(dphi[3 * k], rest) / w
                span = float(tf[starts[j] + sizes[j] - 1] - tf[starts[j]])
                g = _growth(whole, first)
                grown = max(1.0, duration / span) ** g
                worst[j] = [_maximum(a, r * whole * grown) for a, r in zip(worst[j], rate[j])]
    return {j: np.array(v) for j, v in worst.items()}


def _maximum(a: float, b: float) -> float:
    """``np.maximum`` of two floats (a NaN either side is the result: the first when both)."""
    return a if a >= b or a != a else b
