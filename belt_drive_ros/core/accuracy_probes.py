"""The accuracy guard's probes and its closed-loop step-response term (see :mod:`belt_drive_ros.core.accuracy`).

Probes: speeds, times and torque slopes along a cheap rigid run of the scene (:class:`RigidSurvey`, which the
``auto`` model choice reads too); the step-response term: the method's one-step map on the linearized closed
loop against the exact map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from . import stage_scheme as _scheme
from .errors import IntegratorError
from .forced_response import ORBIT_SAMPLES, orbit_error, profile_harmonics
from .identity_cache import built_once
from .model import _BELT, LINEAR_OUTPUTS, RigidBeltModel, make_model
from .stability import spectral_radii, spectral_radius
from .step_plan import snap_tolerance
from .stepper import is_shared, shared_plant, shared_stepper

#: default relative tolerance of the guard (speed and belt torque, relative to peak)
ACCURACY_TOLERANCE = 1e-4
#: step-response samples compared (beyond them the horizon is sampled in strides, see step_response_error)
MAX_STEPS = ORBIT_SAMPLES
#: times along the scene at which the torques' slopes are probed
N_PROBES = 5
#: steps of the method in each forcing window (run at dt and dt / 2, Richardson)
WINDOW_STEPS = 48
#: a smaller step (the search for one that works) keeps the window's length up to this many of its steps
MAX_WINDOW_STEPS = 8 * WINDOW_STEPS
#: a step named as working has an estimated error at most this fraction of the tolerance (the estimate's spread)
SUGGEST_MARGIN = 0.25
#: probe windows closer than this in drive speed (relative to the run's top speed) to another: one of them
SPEED_SPREAD = 0.1
#: torque breakpoints inside the run that get a forcing window of their own (the first ones)
MAX_BREAKPOINT_WINDOWS = 4
#: growth beyond max(1, exact growth) by this much (relative) is instability, not rounding
GROWTH_TOLERANCE = 1e-9
#: least weight of the step response (perturbations the scene does not state: torques from the node, re-excitation)
MIN_INPUT_WEIGHT = 0.05
#: halvings tried when naming a step that is both stable and accurate
MAX_HALVINGS = 16
#: when the method itself needs more halvings than this, another method is named as well
ALTERNATIVE_HALVINGS = 3
#: methods tried as the alternative, in this order (exact for the belt mode, high order)
ALTERNATIVES = ("etd4", "lawson5", "etd2")

#: profile kinds never periodic at a steady speed (monotone or constant in time): they excite no harmonic
APERIODIC_KINDS = frozenset({"constant", "step", "ramp", "motor", "polynomial"})
#: steps per piece of the rigid survey run (a run of any length in bounded memory)
SURVEY_CHUNK = 50_000


def operating_run_step(duration: float) -> float:
    """Step [s] of the cheap rigid run (method ``exact``) that estimates the operating speeds: ``min(duration / 500,
    5 ms)``, max(500, duration / 5 ms) steps (a long run's survey grows with it: 2e7 steps for 1e5 s)."""
    return min(duration / 500.0, 5e-3)


def _survey_step(pieces, rdt: float, duration: float | None = None) -> float:
    """The survey's step [s]: ``rdt``, or the spacing ``h`` of a sampled torque whose breakpoints inside
    the run (``pieces()``: consecutive sorted arrays of them) are denser than ``rdt`` and all lie on the
    grid ``k h`` (a recording at a fixed rate): there the stepper runs the record's steps as whole steps, each
    clamped to its own sample (:func:`~belt_drive_ros.core.kernel.clamped_steps`); ``exact`` integrates held samples
    exactly either way. Not where the run of ``duration`` [s] at ``h`` would take far more steps than the record has
    samples (a table of three points 1 ns apart: 5e9 steps, a hang): ``rdt``, whose steps are clamped at them.
    """
    def on_grid(inner, h) -> bool:
        d = np.abs(np.rint(inner / h) * h - inner)
        return bool(np.all((d <= 1e-9 * h) | (d <= 8.0 * np.spacing(inner))))

    # one pass: each piece is checked on the grid of the spacing so far, which is the final one once the
    # densest spacing was seen (a recording's first piece); a second pass only if it moved after a check
    n, first, last, gap, checked = 0, None, None, math.inf, set()
    ok = True
    for inner in pieces():
        if inner.size:
            if last is not None:
                gap = min(gap, float(inner[0] - last))
            if inner.size > 1:
                gap = min(gap, float(np.min(np.diff(inner))))
            first = float(inner[0]) if first is None else first
            n, last = n + inner.size, float(inner[-1])
            h = float(f"{gap:.9g}")  # the rate's period as written (0.001 for 1 kHz), not a float difference
            checked.add(h)
            ok = ok and 0.0 < h < rdt and on_grid(inner, h)
    if n < 2 or n * rdt <= last - first + rdt:
        return rdt
    h = float(f"{gap:.9g}")
    if not 0.0 < h < rdt:
        return rdt
    if duration is not None and duration / h > 2.0 * n + duration / rdt:  # (a record covering the run: ~n steps)
        return rdt
    if checked == {h}:
        return h if ok else rdt
    return h if all(on_grid(inner, h) for inner in pieces()) else rdt


#: plants of rigid models by their matrices and the torques (:func:`rigid_plant`)
_RIGID_PLANTS: dict = {}


def rigid_plant(model, drive, load):
    """The plant of the rigid model ``model`` with ``drive`` and ``load``: :func:`~belt_drive_ros.core.stepper.shared_plant`'s,
    or the one already made for a rigid model of the same matrices (A, B, C, D to the bit) and the same torque objects.

    A rigid model's numbers do not depend on the belt's damping (nor, but for the deflection rows, its stiffness), so
    a scene edited there (a sweep's variant) steps its rigid survey and a rigid run on the plant, stepper and compiled
    loop of the scene before it, not on new ones: everything a plant gives (inputs, breakpoints, the steppers' maps)
    is made of those numbers and torques only. Frozen inputs, never a result. One that ``shared_plant`` no longer
    keeps (whose steppers it would not keep either) is replaced by the plant it makes now."""
    key = (model.A.tobytes(), model.B.tobytes(), model.C.tobytes(), model.D.tobytes())
    plant = built_once(_RIGID_PLANTS, 8, (drive, load), lambda: shared_plant(model, drive, load), key)
    if not is_shared(plant):
        plant = shared_plant(model, drive, load)
        _RIGID_PLANTS[(id(drive), id(load), *key)] = ((drive, load), plant)
    else:
        shared_plant(plant.model, drive, load)  # (a hit: used now, so shared_plant drops it last)
    return plant


class _SurveyPlan:
    """Where the rigid survey of a plant over ``[0, duration]`` stops, for the scene's step ``dt`` (numbers of the
    scene only, no state): ``rdt`` its step (:func:`_survey_step`), ``t_probe`` the probe times, ``early`` the
    window starts before the first breakpoints, ``plain`` the probe times before the end, ``stops`` all of them
    sorted; :meth:`ends` the ends of its pieces."""

    def __init__(self, plant, duration: float, dt: float):
        self.duration = duration
        # the stops: probe times, then a quarter window before breakpoints; np.linspace(0, duration, N_PROBES)'s
        # floats (k step, the last the duration itself) without its overhead
        step = duration / (N_PROBES - 1)
        self.t_probe = np.array([k * step for k in range(N_PROBES - 1)] + [duration]) if duration > 0 else np.array([0.0])

        def pieces():  # the breakpoints inside the run (page by page for a recording read in pages)
            return plant.breakpoint_pieces(0.0, duration, SURVEY_CHUNK * dt)

        self.rdt = _survey_step(pieces, operating_run_step(duration) if duration > 0 else 1e-3, duration)
        inner = []
        for piece in pieces():
            inner += piece[: MAX_BREAKPOINT_WINDOWS - len(inner)].tolist()
            if len(inner) == MAX_BREAKPOINT_WINDOWS:
                break
        self.early = {b: max(0.0, dt * math.floor((b - 0.25 * WINDOW_STEPS * dt) / dt)) for b in inner}
        self.plain = [float(t) for t in self.t_probe[1:] if t < duration - 2.0 * dt]
        self.stops = sorted(set(self.plain) | set(self.early.values()) | {float(t) for t in self.t_probe})
        self._ends = None

    def ends(self, stepper) -> set:
        """The survey's piece ends on ``stepper`` (method ``exact`` at :attr:`rdt`, origin 0; the same grid for every
        such stepper): the stops off its grid, every :data:`SURVEY_CHUNK` steps (memory does not grow with the
        duration) and the duration; a stop on the grid is read off the run's knots. Made at the first call."""
        if self._ends is None:
            rdt = self.rdt

            def on_grid(t):
                return abs(stepper.grid_time(round(t / rdt)) - t) <= snap_tolerance(t, rdt)

            ends = {t for t in self.stops if t > 0.0 and not on_grid(t)} | {self.duration}
            ends |= {stepper.grid_time(k) for k in range(SURVEY_CHUNK, math.ceil(self.duration / rdt), SURVEY_CHUNK)}
            self._ends = frozenset(ends)
        return self._ends


#: survey plans by (plant, duration, step): :func:`_survey_plan`
_SURVEY_PLANS: dict = {}


def _survey_plan(plant, duration: float, dt: float) -> _SurveyPlan:
    """The :class:`_SurveyPlan` of ``plant`` over ``duration`` [s] for the scene's step ``dt`` [s], made once for a plant
    ``shared_plant`` keeps (a repeated call's survey stops where the last one did: numbers of the scene, not a run)."""
    return built_once(_SURVEY_PLANS, 32, (plant,), lambda: _SurveyPlan(plant, float(duration), float(dt)),
                      (float(duration), float(dt)), keep=lambda _: is_shared(plant))


class RigidSurvey:
    """One cheap rigid run of a scene that the model choice and the accuracy guard both read.

    Method ``exact`` at :func:`operating_run_step` from the scene's initial motion ``(phi_M, omega_M)`` over
    ``[0, duration]``, advanced from stop to stop: the guard's probe times ``linspace(0, duration, N_PROBES)`` and,
    for a scene step ``dt``, a quarter forcing window (``WINDOW_STEPS dt / 4``, on the grid ``k dt``) before each of
    the first ``MAX_BREAKPOINT_WINDOWS`` torque breakpoints inside the run. It records

    * ``states``: ``{stop time [s]: (phi_M [rad], omega_M [rad/s])}``;
    * ``speeds``: (max |omega_M|, max |omega_3| [rad/s], max |belt torque| [N m])
      over every knot, what the frequency rule reads the operating point from;
    * ``change_frequency``: the belt torque's fastest change over its swing, ``max |dT_b/dt| / (max T_b - min
      T_b)`` [1/s] (a ramp of duration tau: 1/tau), which a torque that changes with the speed shows and its
      profile's own excitation frequencies do not (a motor curve that cuts off within a few rad/s).

    Run on first use, in pieces of at most :data:`SURVEY_CHUNK` steps (bounded memory); a run that
    diverges sets ``error`` (the probes fall back to the start, ``speeds`` raises it).
    """

    def __init__(self, params, drive, load, motion, duration: float, dt: float):
        self.params, self.drive, self.load = params, drive, load
        self.motion = (float(motion[0]), float(motion[1]))
        self.duration, self.dt = float(duration), float(dt)
        self._done = False
        #: the accuracy guard's probes made from this run, by plant (:func:`~belt_drive_ros.core.accuracy.probe_scene`)
        self.probes: dict = {}

    @classmethod
    def of_scene(cls, scene) -> "RigidSurvey":
        x0 = scene.initial_state.vector("rigid", scene.params.ratio)
        return cls(scene.params, scene.drive, scene.load, x0, scene.duration, scene.dt)

    @property
    def rigid(self) -> RigidBeltModel:
        """The rigid model of the survey's parameters (made once; the probes and the start check read it too)."""
        found = self.__dict__.get("_rigid")
        if found is None:
            found = self._rigid = make_model("rigid", self.params)
        return found

    @property
    def plant(self):
        """The rigid model's plant with the survey's torques (:func:`rigid_plant`, made once; the run of a scene on the
        rigid model steps on it too)."""
        found = self.__dict__.get("_plant")
        if found is None:
            found = self._plant = rigid_plant(self.rigid, self.drive, self.load)
        return found

    @property
    def start_torque(self) -> float:
        """The quasi-static belt torque [N m] the torques at t = 0 need from the initial motion (:func:`start_mismatch`)."""
        if not self._done:
            self._run()
        return self._start_torque

    def _run(self) -> None:
        self._done = True
        model, plant = self.rigid, self.plant
        x0 = np.array(self.motion)
        self._start_torque = float(model.belt_torque(x0, plant.inputs(0.0, x0)))
        plan = _survey_plan(plant, self.duration, self.dt)
        rdt, stops = plan.rdt, plan.stops
        self.t_probe, self.early, self.plain = plan.t_probe.copy(), dict(plan.early), list(plan.plain)
        self.states = {0.0: self.motion}
        self.error, self._speeds = None, None
        w, peak = abs(self.motion[1]), 0.0
        try:
            stepper = shared_stepper(plant, "exact", rdt)
            ends = plan.ends(stepper)
            x, t, pending = np.array(self.motion), 0.0, [s for s in stops if s > 0.0]
            held = []  # pieces whose speeds and belt torques are not read yet: one evaluation for up to a chunk's knots

            change = [0.0, math.inf, -math.inf]  # max |dT_b/dt| [N m/s], min and max T_b [N m]

            def read(held):  # the largest |omega_M| and |belt torque| so far (a max is exact: the same floats in one go)
                time, states = (held[0] if len(held) == 1 else
                                (np.concatenate([h[0] for h in held]), np.concatenate([h[1] for h in held])))  # fmt: skip
                held.clear()
                u = plant.input_array(time, states)
                belt = _rigid_belt_torque(model, states[:, 0], states[:, 1], u[:, 0], u[:, 1])
                rate, lo, hi = belt_change(time, belt)
                change[0], change[1], change[2] = max(change[0], float(rate)), min(change[1], float(lo)), max(change[2], float(hi))
                return max(w, float(np.abs(states[:, 1]).max())), max(peak, float(np.abs(belt).max()))

            for e in sorted(ends):
                if e <= t:
                    continue
                time, states = stepper.run(x, t, e)
                held.append((time, states))
                if sum(h[0].size for h in held) >= SURVEY_CHUNK:
                    w, peak = read(held)
                while pending and pending[0] <= e + snap_tolerance(e, rdt):  # its nearest knot (the first of two)
                    s = pending.pop(0)
                    j = min(max(int(time.searchsorted(s)), 1), time.size - 1)
                    k = j - 1 if abs(time[j - 1] - s) <= abs(time[j] - s) else j
                    self.states[s] = (float(states[k, 0]), float(states[k, 1]))
                x, t = states[-1], e
            if held:
                w, peak = read(held)
            if self.duration <= 0:
                peak = abs(self._start_torque)
            self._speeds = (w, w * self.params.ratio, peak)
            self._change = float(change_frequency(*change))
        except Exception as exc:  # noqa: BLE001 - a rigid estimate that diverges: the probes fall back to the start
            self.error = exc

    @property
    def speeds(self) -> tuple[float, float, float]:
        """(max |omega_M|, max |omega_3| [rad/s], max |belt torque| [N m]) of the run."""
        if not self._done:
            self._run()
        if self.error is not None:
            raise self.error
        return self._speeds

    @property
    def change_frequency(self) -> float:
        """The rigid belt torque's fastest change over its swing [1/s] (see the class; 0.0: it never changed)."""
        if not self._done:
            self._run()
        if self.error is not None:
            raise self.error
        return self._change

    def probe_states(self):
        """``(probe times, plain, early, states)`` for the guard's probes (start only when the run diverged)."""
        if not self._done:
            self._run()
        if self.error is not None:
            return np.array([0.0]), [], {}, {0.0: self.motion}
        return self.t_probe, self.plain, self.early, self.states


def _probe_torques(plant, rigid, times, speeds_M, points) -> tuple[list, list]:
    """(the speed slopes (d drive/d omega_M, d load/d omega_3) [N m s/rad] at each of ``times`` and ``speeds_M``,
    central differences at (t, 0, omega_M) and (t, 0, i omega_M) (:func:`feedback_gain` makes a probe's K from them);
    the rigid model ``rigid``'s quasi-static belt torques [N m] at ``points`` ``(t, phi_M, omega_M)``, the plant's
    torques there): one torque call per profile for both (each sample the profile's own: the same floats as apart)."""
    i = plant.model.params.ratio
    t = np.asarray(times, dtype=float)
    n = t.size
    qt, qphi, qw = (np.array(c, dtype=float) for c in zip(*points))
    slopes, torques = [], []
    with np.errstate(all="ignore"):
        speed = np.asarray(speeds_M, dtype=float)
        for profile, w, phi, omega in ((plant.drive, speed, qphi, qw), (plant.load, i * speed, i * qphi, i * qw)):
            d = 1e-6 * np.maximum(1.0, np.abs(w))  # every probe and both sides, and the points: one array call
            both = np.asarray(profile.torque(np.concatenate([t, t, qt]), np.concatenate([np.zeros(2 * n), phi]),
                                             np.concatenate([w + d, w - d, omega])), dtype=float)  # fmt: skip
            slopes.append(((both[:n] - both[n : 2 * n]) / (2.0 * d)).tolist())
            torques.append(both[2 * n :])
        return list(zip(*slopes)), _rigid_belt_torque(rigid, qphi, qw, *torques).tolist()


def belt_change(time, belt) -> tuple:
    """``(max |dT_b/dt| [N m/s], min T_b, max T_b)`` of belt torques ``belt`` [N m] at the samples ``time`` [s]: (N,),
    or (N, V) for V variants (per column). Steps of zero length (pieces repeat their ends) are left out."""
    step = np.diff(time)
    moved = step > 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = (np.max(np.abs(np.diff(belt, axis=0))[moved] / (step[moved] if belt.ndim == 1 else step[moved, None]),
                       axis=0) if np.any(moved) else np.zeros(belt.shape[1:]))  # fmt: skip
    return rate, np.min(belt, axis=0), np.max(belt, axis=0)


def change_frequency(rate, lo, hi):
    """:attr:`RigidSurvey.change_frequency` from :func:`belt_change`'s figures: ``rate / (hi - lo)`` [1/s], 0.0 where
    the swing is zero or not finite (scalars or per-variant arrays)."""
    swing = np.asarray(hi) - np.asarray(lo)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((swing > 0.0) & np.isfinite(swing), np.asarray(rate) / np.where(swing > 0.0, swing, 1.0), 0.0)


def _rigid_belt_torque(rigid, phi, omega, drive, load) -> np.ndarray:
    """The rigid model's belt torque [N m] at samples ``phi_M``, ``omega_M`` with torques ``drive``, ``load`` (1-D
    arrays): ``rigid.belt_torque(column_stack([phi, omega]), column_stack([drive, load]))``'s operations."""
    (c0, c1), (d0, d1) = rigid._rows[_BELT]
    return (phi * c0 + omega * c1) + (drive * d0 + load * d1)


def feedback_gain(plant, slopes) -> np.ndarray:
    """K (2, n): the drive's slope acting on omega_M, the load's on omega_3 (rows of the plant's wheel map)."""
    W = plant.wheel_map
    return np.array([slopes[0] * W[1], slopes[1] * W[3]])


@dataclass(frozen=True)
class Probes:
    """What the guard reads off a cheap rigid run of the scene (:func:`probe_scene`).

    gains : distinct ``(K, slopes)`` of the torques' speed slopes at the probes (see :func:`_probe_torques`).
    x0 : the scene's initial state (the first forcing window starts there at t = 0).
    windows : further forcing windows as ``(t [s], phi_M [rad], omega_M [rad/s], anchor)``: the rigid run's
        motion at t; ``anchor`` a torque breakpoint [s] the window straddles (None: it starts at t).
    duration : the scene's duration [s].
    window : length [s] of a forcing window (:data:`WINDOW_STEPS` steps of the step probed with; :meth:`span`).
    input_weight : what the unit step response's error is scaled by for this scene (:func:`input_weight`).
    harmonics : ``(input, frequency [Hz], amplitude [N m])`` the torques excite (``forced_response.profile_harmonics``).
    peaks : estimated peaks of drive speed [rad/s] and quasi-static belt torque [N m] at the probes.
    """

    gains: tuple
    x0: np.ndarray
    windows: tuple
    duration: float
    window: float
    input_weight: float = 1.0
    harmonics: tuple = ()
    peaks: tuple = (0.0, 0.0)

    def span(self, dt: float) -> float:
        """Window length [s] for step ``dt``: :attr:`window`, at most :data:`MAX_WINDOW_STEPS` steps."""
        return min(self.window, MAX_WINDOW_STEPS * dt)

    def window_starts(self, plant, dt: float):
        """``(t0, x)`` of every window for step ``dt``: t0 on the grid k dt, x the plant model's state. A breakpoint's
        window starts a quarter window before it, the rigid motion carried there at constant speed, the deflection
        the quasi-static one."""
        yield 0.0, self.x0
        for t, phi, omega, anchor in self.windows:
            t0 = t if anchor is None else max(0.0, dt * math.floor((anchor - 0.25 * self.span(dt)) / dt))
            if t0 > 0.0:
                yield t0, _model_state(plant, t0, phi + omega * (t0 - t), omega)


def _model_state(plant, t: float, phi: float, omega: float) -> np.ndarray:
    """The plant model's state with the rigid motion (phi_M, omega_M) at time t and the quasi-static deflection."""
    model = plant.model
    if model.A.shape[0] == 2:
        return np.array([phi, omega])
    i = model.params.ratio
    drive = plant.scalar_drive(t, phi, omega)
    load = plant.scalar_load(t, i * phi, i * omega)
    return model.state_from_rigid(np.array([phi, omega]), load_torque=load, drive_torque=drive)


def probe_scene(plant, duration: float, x0, dt: float, stated_inputs: bool = True, survey=None) -> Probes:
    """Speed slopes at :data:`N_PROBES` times and the forcing windows' starts, from one cheap rigid run.

    Windows start at t = 0 (from ``x0``), at the probe times before the end and about each of the first
    :data:`MAX_BREAKPOINT_WINDOWS` torque breakpoints inside the run (:meth:`Probes.window_starts`).
    ``stated_inputs``: the plant's torques are all the inputs (the step response is weighted by their steps,
    :func:`input_weight`); False (torques from outside, a node's topic): unit steps, weight 1.
    ``survey``: the scene's :class:`RigidSurvey` at this ``dt`` (the model choice's; default: one is run here).
    """
    x0 = np.asarray(x0, dtype=float)
    wm = plant.wheel_map
    motion = (float(wm[0] @ x0), float(wm[1] @ x0))
    if (survey is None or survey.dt != float(dt) or survey.duration != float(duration) or survey.motion != motion
            or survey.drive is not plant.drive or survey.load is not plant.load):
        survey = RigidSurvey(plant.model.params, plant.drive, plant.load, motion, duration, dt)
    key = (plant.model.name, x0.tobytes(), bool(stated_inputs))
    made = survey.probes.get(key)  # the model choice, the method choice and the run's guard read the same probes
    if made is None:
        made = survey.probes[key] = _probes(plant, duration, x0, dt, stated_inputs, survey.rigid, *survey.probe_states())
    return made


def _probes(plant, duration, x0, dt, stated_inputs, rigid, probe_times, plain, early, states) -> Probes:
    """:func:`probe_scene` from the rigid survey's states at its stops."""
    gains, seen = [], set()
    speeds = [states[float(t)][1] for t in probe_times]
    at = [(float(t), *states[float(t)]) for t in probe_times]
    jumps = [(b, *states[t]) for b, t in early.items()]
    # the slopes and the quasi-static belt torques at the weight's points (the probes among them) in one evaluation
    points = _weight_points(plant, x0, dt, at, jumps) if stated_inputs else at
    slopes_at, qs = _probe_torques(plant, rigid, probe_times, speeds, points)
    for slopes in slopes_at:
        key = tuple(float(f"{s:.3g}") for s in slopes)  # slopes equal to 3 digits: the same verdict
        if key not in seen:
            seen.add(key)
            gains.append((feedback_gain(plant, slopes), slopes))
    # a probe window at a speed within SPEED_SPREAD of one already windowed sees the same harmonics: skipped
    kept, scale = [0.0], max(abs(w) for _, w in states.values()) or 1.0
    for t in plain:
        if all(abs(states[t][1] - states[k][1]) > SPEED_SPREAD * scale for k in kept):
            kept.append(t)
    windows = [(t, *states[t], None) for t in kept[1:]] + [(t, *states[t], b) for b, t in early.items()]
    here = qs[1 : 1 + len(at)] if stated_inputs else qs  # the probes' quasi-static belt torques
    weight = 1.0 if not stated_inputs else input_weight(plant, x0, dt, at, jumps, qs)
    # a torque that, the wheel turning steadily, only rises, falls or holds repeats nothing: no harmonic to find
    harmonics = () if {plant.drive.kind, plant.load.kind} <= APERIODIC_KINDS else tuple(profile_harmonics(plant, at))
    return Probes(tuple(gains), x0, tuple(windows), float(duration), WINDOW_STEPS * dt, weight, harmonics,
                  _peaks(at, here))  # fmt: skip


def _peaks(at, here) -> tuple[float, float]:
    """(max |omega_M| [rad/s], max |quasi-static belt torque| [N m]) over the probes ``at`` ``(t, phi_M, omega_M)``
    with their quasi-static belt torques ``here`` (:func:`_probe_torques`)."""
    omega = np.array([w for _, _, w in at], dtype=float)
    w = float(np.fmax.reduce(np.abs(omega), initial=0.0))  # a NaN probe is passed over
    tb = float(np.fmax.reduce(np.abs(np.array(here, dtype=float)), initial=0.0))
    return (w if math.isfinite(w) else 0.0, tb if math.isfinite(tb) else 0.0)


def _weight_points(plant, x0, dt: float, probes, jumps) -> list:
    """The points ``(t, phi_M, omega_M)`` :func:`input_weight` reads the quasi-static belt torque at: the start, each
    probe and a step after it, each jump's two sides."""
    wm = plant.wheel_map
    x0 = np.asarray(x0, dtype=float)
    eps = 1e-6 * dt
    pts = [(0.0, float(wm[0] @ x0), float(wm[1] @ x0)), *probes] + [(t + dt, phi, omega) for t, phi, omega in probes]
    return pts + [(b + side, phi, omega) for b, phi, omega in jumps for side in (-eps, eps)]


def input_weight(plant, x0, dt: float, probes, jumps, qs: list) -> float:
    """Scale [-] of the unit step response's error for this scene: ``min(1, 2 dB / T_peak)``, at least
    :data:`MIN_INPUT_WEIGHT`.

    The step response (:func:`step_response_error`) switches a unit torque on at once; its error relative to its own
    peak (``2`` steps of belt torque: the undamped overshoot) becomes, in the scene, that times ``2 dB / T_peak``,
    with ``dB`` [N m] the largest step of belt torque the scene's inputs make:

    * at the start, the quasi-static belt torque the torques at t = 0 need (rigid model) less what the initial
      state carries (:func:`~belt_drive_ros.core.fidelity.start_mismatch`'s sizes);
    * at each torque breakpoint ``jumps`` ``(b, phi_M, omega_M)``, the jump of the rigid belt torque across it;
    * a ramp of the quasi-static belt torque at rate ``R`` [N m/s] (a soft
      start, a motor curve) moves the belt mode by ``R / omega_n``: an
      equivalent step (forward difference over ``dt`` at each probe
      ``(t, phi_M, omega_M)``, the start included).

    ``T_peak``: the largest |quasi-static belt torque| at the probes. Rigid model (no belt mode): 1. The floor keeps
    perturbations the scene does not state (a node's torques) rated. ``qs``: the quasi-static belt torques [N m] at
    :func:`_weight_points` (the rigid model of the plant's parameters, :func:`_probe_torques`).
    """
    model = plant.model
    p = model.params
    x0 = np.asarray(x0, dtype=float)
    rigid_model = model.A.shape[0] == 2
    j = LINEAR_OUTPUTS.index("belt_torque")
    carried = 0.0 if rigid_model else float(model.C[j] @ x0)  # rigid: the torques at t = 0 switch on from none
    omega_n = 1.0 / dt if rigid_model else p.belt_natural_frequency  # rigid: a ramp held over a step is a step R dt
    n = len(probes)
    here, ahead, sides = qs[1 : 1 + n], qs[1 + n : 1 + 2 * n], qs[1 + 2 * n :]
    steps = [abs(qs[0] - carried)] + [abs(a - h) / dt / omega_n for h, a in zip(here, ahead)]
    levels = [abs(qs[0])] + [abs(h) for h in here] + [abs(v) for v in sides]
    steps += [abs(after - before) for before, after in zip(sides[::2], sides[1::2])]
    peak, step = max(levels), max(steps)  # (Python's max, in this order: a NaN after the first is passed over)
    if not (math.isfinite(peak) and math.isfinite(step)) or peak <= 0.0:
        return 1.0
    return float(min(1.0, max(MIN_INPUT_WEIGHT, 2.0 * step / peak)))


def closed_loop_maps(integrator, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, G): the method's step on x' = A x + B (K x + u_0) is ``x+ = M x + G u_0`` (from its stage scheme)."""
    return closed_loop_maps_of(integrator, (K,))[0]


def closed_loop_maps_of(integrator, Ks) -> list:
    """:func:`closed_loop_maps` of each gain of ``Ks``: an explicit scheme steps every gain's unit columns side by
    side in one call (the stage sums run column by column, :func:`~belt_drive_ros.core.stage_scheme.affine`, and
    each gain's ``K @ y`` reads its own columns: each (M, G) the same floats as alone); an implicit one gain by gain
    (its fixed point iterates on all columns at once)."""
    n = integrator.A.shape[0]
    scheme, h = integrator.scheme, integrator.dt
    if scheme.implicit:
        out = []
        for K in Ks:
            m = K.shape[0]
            zero_u = np.zeros(m)

            def run(x, u0, K=K):
                return _scheme.step(scheme, h, 0.0, x, lambda t, y: K @ y + u0, integrator.name)

            M = np.column_stack([run(e, zero_u) for e in np.eye(n)])
            G = np.column_stack([run(np.zeros(n), e) for e in np.eye(m)])
            out.append((M, G))
        return out
    # affine in (x, u_0): every unit column of every gain in one call, gain j's n + m columns the j-th block
    widths = [n + K.shape[0] for K in Ks]
    cuts = np.cumsum([0] + widths)
    x = np.concatenate([np.eye(n, w) for w in widths], axis=1)
    u0 = [np.eye(K.shape[0], w, n) for K, w in zip(Ks, widths)]

    def inputs(t, y):
        return np.concatenate([K @ y[:, a:b] + u for K, u, a, b in zip(Ks, u0, cuts[:-1], cuts[1:])], axis=1)

    MG = _scheme.step(scheme, h, 0.0, x, inputs, integrator.name)
    return [(MG[:, a : a + n], MG[:, a + n : b]) for a, b in zip(cuts[:-1], cuts[1:])]


def exact_maps(A_cl: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(E, F): the exact step of x' = A_cl x + B u_0 with constant u_0 (augmented matrix exponential). ``A_cl`` may be
    a stack (..., n, n): ``scipy.linalg.expm`` takes its matrices one by one, each as alone."""
    n, m = B.shape
    aug = np.zeros(A_cl.shape[:-2] + (n + m, n + m))
    aug[..., :n, :n], aug[..., :n, n:] = A_cl, B
    expo = scipy.linalg.expm(aug * h)
    return expo[..., :n, :n], expo[..., :n, n:]


def step_response_error(M, G, E, F, rows: np.ndarray, n_steps: int) -> float:
    """Max over unit inputs and output rows of max_k |y_k - y*_k| / max_k |y*_k|, k = 1 .. ``n_steps``.

    From rest with a unit drive and a unit load torque (two columns at once), ``X_{k+1} = M X_k + G`` against
    ``Z_{k+1} = E Z_k + F``. The first :data:`MAX_STEPS` / 2 steps are taken one by one; the rest, when there are
    more, in strides of ``s`` steps with the s-th powers of the augmented maps (exact, only samples between strides
    are skipped). Both recurrences are evaluated at once by doubling
    (:func:`~belt_drive_ros.core.forced_response.orbit_error`).
    """
    n = M.shape[0]
    Ma, Ea = _augmented(M, G), _augmented(E, F)
    err, peak = orbit_error(Ma, Ea, n, rows, n_steps)
    if not np.all(np.isfinite(err)):
        return math.inf
    return _relative(err, peak)


def _relative(err: np.ndarray, peak: np.ndarray) -> float:
    """max of ``err / peak`` (a unit input that does not move an output at all, peak 0, carries no error either)."""
    return float(np.max(np.where(peak > 0, err / np.where(peak > 0, peak, 1.0), 0.0)))


def _augmented(M: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``[[M, G], [0, I]]`` (the map of ``(x, u)`` with ``u`` held), the entries of ``np.block``'s without its overhead."""
    n, m = G.shape
    out = np.zeros((n + m, n + m), dtype=np.result_type(M, G, 0.0))
    out[:n, :n], out[:n, n:] = M, G
    out[n:, n:] = np.eye(m)
    return out


_ROWS: dict = {}


def _output_rows(model) -> tuple[np.ndarray, np.ndarray]:
    """(C rows, D rows) of drive speed and belt torque (the guard's two signals; made once per model, read-only)."""
    j = [LINEAR_OUTPUTS.index("omega_M"), LINEAR_OUTPUTS.index("belt_torque")]
    return built_once(_ROWS, 32, (model,), lambda: (model.C[j], model.D[j]))


#: the linear (belt mode and slopes) verdicts already computed: key -> (stable, error, growth, exact growth, h omega)
_LINEAR_CACHE: dict = {}
_LINEAR_CACHE_SIZE = 512


def _maps_of(integrator, gains, E, F) -> list:
    """(M, G) of each gain (:func:`closed_loop_maps_of`); a gain whose implicit stage does not converge: maps of
    inf (each gain on its own then, so one that fails does not take the others with it)."""
    try:
        return closed_loop_maps_of(integrator, gains)
    except IntegratorError:
        pass
    out = []
    for j, K in enumerate(gains):
        try:
            out.append(closed_loop_maps(integrator, K))
        except IntegratorError:
            out.append((np.full_like(E[j], np.inf), np.full_like(F[j], np.inf)))
    return out


def _radii(maps: list) -> list:
    """:func:`~belt_drive_ros.core.stability.spectral_radius` of each map of ``maps``, the finite float64 ones in one
    stacked call (:func:`~belt_drive_ros.core.stability.spectral_radii`: each as alone); None for a map not finite
    or of another type (its radius is made, or refused, as before)."""
    ok = [j for j, M in enumerate(maps) if M.dtype == np.float64 and np.all(np.isfinite(M))]
    out = [None] * len(maps)
    if ok and all(maps[j].shape == maps[ok[0]].shape for j in ok):
        for j, r in zip(ok, spectral_radii(np.stack([maps[j] for j in ok]))):
            out[j] = r
    return out


def linear_verdicts(integrator, A, B, rows, Ks, n_steps: int) -> list:
    """(stable, error, growth, exact growth, h omega) of the method's closed-loop map ``A + B K`` of each gain of ``Ks``
    on one integrator (cached: the key is every number the verdict depends on, matrices, method and its options
    through the integrator's one-step map, step, gains, horizon, so a hit is the same computation), the gains not
    cached yet made together:
    their exact maps one stacked exponential (:func:`exact_maps`), their closed loops' eigenvalues one stacked call
    and their step responses one :func:`~belt_drive_ros.core.forced_response.orbit_error` call with the gains on a
    leading axis. Each is computed matrix by matrix with the same operations as alone (the same floats; a
    non-finite orbit among them: each gain's alone, as :func:`step_response_error` does)."""
    dt = integrator.dt
    common = (integrator.name, dt, A.tobytes(), B.tobytes(), rows.tobytes())
    # a fixed-step method's options are its implicit stage's (tol, max_iter): they change the map where it converges
    # and whether it does (a key without them gave a max_iter of 50 the verdict made at 2)
    options = repr(integrator.scheme.implicit)
    keys = [(*common, K.tobytes(), n_steps, options) for K in Ks]
    found, todo = {}, {}  # key -> its verdict; key -> its first gain not cached
    for key, K in zip(keys, Ks):
        hit = _LINEAR_CACHE.get(key)
        if hit is not None:
            found[key] = hit
        elif key not in todo:
            todo[key] = K
    if todo:
        gains = list(todo.values())
        A_cl = np.stack([A + B @ K for K in gains])
        E, F = exact_maps(A_cl, B, dt)
        lams = _eigenvalues(A, B, gains, A_cl)
        parts = []  # (stable, M, G, growth, exact growth) per gain
        maps = _maps_of(integrator, gains, E, F)
        radii = _radii([M for M, _ in maps] + list(E))  # (a map not finite: None)
        for j, (M, G) in enumerate(maps):
            growth = radii[j] if radii[j] is not None else spectral_radius(M) if np.all(np.isfinite(M)) else math.inf
            exact_growth = radii[len(maps) + j] if radii[len(maps) + j] is not None else spectral_radius(E[j])
            parts.append((growth <= max(1.0, exact_growth) * (1.0 + GROWTH_TOLERANCE) + 1e-15, M, G, growth, exact_growth))
        stepped = [j for j, part in enumerate(parts) if part[0]]
        errors = {}
        if len(stepped) > 1:
            err, peak = orbit_error(np.stack([_augmented(parts[j][1], parts[j][2]) for j in stepped]),
                                    np.stack([_augmented(E[j], F[j]) for j in stepped]), A.shape[0], rows, n_steps)  # fmt: skip
            if np.all(np.isfinite(err)):
                errors = {j: _relative(err[i], peak[i]) for i, j in enumerate(stepped)}
        for j, key in enumerate(todo):
            stable, M, G, growth, exact_growth = parts[j]
            error = (errors[j] if j in errors else step_response_error(M, G, E[j], F[j], rows, n_steps)) if stable else math.inf
            found[key] = (stable, error, growth, exact_growth, dt * float(np.max(np.abs(lams[j]))))
            if len(_LINEAR_CACHE) >= _LINEAR_CACHE_SIZE:
                _LINEAR_CACHE.pop(next(iter(_LINEAR_CACHE)), None)
            _LINEAR_CACHE[key] = found[key]
    return [found[key] for key in keys]


#: eigenvalues of closed loops ``A + B K`` already computed, by the matrices' bytes
_EIGENVALUES: dict = {}


def closed_loop_eigenvalues(A, B, K) -> np.ndarray:
    """Eigenvalues of ``A + B K`` [1/s], computed once per matrices (the same numbers, the same values; read-only)."""
    return _eigenvalues(A, B, (K,))[0]


def _eigenvalues(A, B, Ks, A_cl=None) -> list:
    """:func:`closed_loop_eigenvalues` of each gain of ``Ks`` (``A_cl``: their ``A + B K`` stacked, when made), the
    ones not kept yet one stacked ``eigvals`` call (LAPACK's routine matrix by matrix: each as alone)."""
    keys = [(A.tobytes(), B.tobytes(), K.tobytes(), A.shape, K.shape) for K in Ks]
    found = [_EIGENVALUES.get(key) for key in keys]
    new = [j for j, lams in enumerate(found) if lams is None]
    if new:
        stack = A_cl[new] if A_cl is not None else np.stack([A + B @ Ks[j] for j in new])
        for j, lams in zip(new, np.linalg.eigvals(stack)):
            # real when all of its own are (eigvals of a stack is complex when any matrix's is): as alone
            found[j] = lams.real.copy() if np.iscomplexobj(lams) and not np.any(lams.imag) else lams.copy()
            if len(_EIGENVALUES) >= _LINEAR_CACHE_SIZE:
                _EIGENVALUES.pop(next(iter(_EIGENVALUES)), None)
            _EIGENVALUES[keys[j]] = found[j]
    return found
