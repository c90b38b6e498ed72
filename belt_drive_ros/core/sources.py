"""Drive-torque sources and load torques.

A torque profile is a function ``torque(t, angle, speed)`` [s, rad, rad/s ->
N m]. Drive sources act on wheel M and see wheel M's angle and speed (for an
engine: the crank angle through ``crank_ratio``); loads act on wheel 3 and
see wheel 3's. Every profile evaluates scalars and numpy arrays alike, so an
open-loop (state-independent) profile can be sampled for a whole run at once.

Profiles are built from plain mappings (scene YAML) by :func:`make_profile`;
the ``type`` key selects the class, the other keys are its fields.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Callable, ClassVar, Mapping, Sequence

import numpy as np

from .errors import SceneError

_REGISTRY: dict[str, type["TorqueProfile"]] = {}


def _register(cls):
    _REGISTRY[cls.kind] = cls
    return cls


class TorqueProfile:
    """Base class: a torque [N m] as a function of time, angle and speed."""

    kind: ClassVar[str] = ""
    #: True when the torque depends on angle or speed (closes a loop).
    state_dependent: ClassVar[bool] = False
    #: False when the torque ignores its angle argument (the compiled loops then skip computing it).
    uses_angle: ClassVar[bool] = True

    def torque(self, t, angle, speed):
        """Torque [N m] at time ``t`` [s], wheel angle [rad], wheel speed [rad/s]."""
        raise NotImplementedError

    __call__ = torque

    def scalar_torque(self) -> Callable[[float, float, float], float]:
        """A fast ``f(t, angle, speed) -> float`` for Python-float arguments.

        Equal to :meth:`torque` on scalars (to rounding: :mod:`math` instead
        of numpy), without numpy's per-call overhead (about 1 us per call on
        a scalar, more than the arithmetic). The closed-loop simulation loop
        calls it once or more per torque and step, so each profile binds its
        constants in a closure; this default wraps :meth:`torque`.
        """
        torque = self.torque
        return lambda t, angle, speed: float(torque(t, angle, speed))

    def scalar_source(self, t: str, angle: str, speed: str) -> str | None:
        """:meth:`scalar_torque` as a Python expression in the variable names given, or None.

        Inlined by :func:`~belt_drive_ros.core.integrators.compile_scalar_loop`
        instead of a call; it must compute exactly what :meth:`scalar_torque`
        computes (same operations in the same order: bitwise equal). The
        names are identifiers or float literals; constants are written with
        ``repr`` (exact). None (the default): the loop calls the closure.
        """
        return None

    def breakpoints(self) -> tuple[float, ...]:
        """Times [s] at which the torque jumps or kinks in time (a step, a ramp's ends, a soft start's end).

        A one-step method that integrates across one is locally first order
        there; :class:`~belt_drive_ros.core.stepper.Stepper` splits such a step
        at it (or ends a step on it). Default: none.
        """
        return ()

    def left_of(self, t: float) -> float:
        """Latest time [s] before ``t`` at which the torque still has its value from the left of ``t``.

        The stepper samples a step that ends at a breakpoint ``t`` no later
        than this, so it sees the torque's left limit there (the jump itself
        belongs to the next step). Default: the float just below ``t``
        (every profile here switches at ``t >= time``).
        """
        return math.nextafter(t, -math.inf)

    def excitation_frequencies(self, speed: float) -> list[tuple[float, str]]:
        """Frequencies [Hz] this profile excites at wheel speed ``speed`` [rad/s].

        Used by the ``auto`` model choice. A list of ``(frequency, reason)``.
        """
        return []

    def to_dict(self) -> dict[str, Any]:
        """Mapping that :func:`make_profile` turns back into an equal profile."""
        out = {"type": self.kind}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, TorqueProfile):
                value = value.to_dict()
            elif isinstance(value, np.ndarray):
                value = value.tolist()
            elif isinstance(value, tuple):
                value = [list(v) if isinstance(v, tuple) else v for v in value]
            out[f.name] = value
        return out

    def _check_finite(self, *names: str) -> None:
        for name in names:
            value = getattr(self, name)
            if not np.all(np.isfinite(np.asarray(value, dtype=float))):
                raise SceneError(f"{self.kind}.{name}: must be finite, got {value!r}")

    def _check_positive(self, *names: str) -> None:
        for name in names:
            if not getattr(self, name) > 0:
                raise SceneError(f"{self.kind}.{name}: must be > 0, got {getattr(self, name)!r}")


def _first_two(harmonics: Sequence[float]) -> tuple:
    """(A_1, A_2, ((3, A_3), ...)) with absent A_1, A_2 as 0.0: the first two terms of a
    harmonic series unrolled in the scalar closures (a loop costs more than the sines)."""
    a1, a2 = (tuple(harmonics) + (0.0, 0.0))[:2]
    return float(a1), float(a2), tuple((float(k), amp) for k, amp in enumerate(harmonics[2:], start=3))


def _interp(x: float, xp: list, fp: list) -> float:
    """``np.interp`` for one float: linear between the points, held beyond the ends."""
    if x <= xp[0]:
        return fp[0]
    if x >= xp[-1]:
        return fp[-1]
    if x != x:  # NaN in, NaN out (as numpy)
        return x
    j = bisect_right(xp, x) - 1
    return (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]) * (x - xp[j]) + fp[j]


# ---------------------------------------------------------------- open loop
@_register
@dataclass(frozen=True)
class Constant(TorqueProfile):
    """Constant torque ``value`` [N m]."""

    kind: ClassVar[str] = "constant"
    uses_angle: ClassVar[bool] = False
    value: float = 0.0

    def __post_init__(self):
        self._check_finite("value")

    def torque(self, t, angle=0.0, speed=0.0):
        return self.value + 0.0 * np.asarray(t, dtype=float) if np.ndim(t) else self.value

    def scalar_torque(self):
        value = float(self.value)
        return lambda t, angle, speed: value

    def scalar_source(self, t, angle, speed):
        return repr(float(self.value))


@_register
@dataclass(frozen=True)
class Step(TorqueProfile):
    """``initial`` [N m] before ``time`` [s], ``final`` from then on."""

    kind: ClassVar[str] = "step"
    uses_angle: ClassVar[bool] = False
    initial: float = 0.0
    final: float = 1.0
    time: float = 0.0

    def __post_init__(self):
        self._check_finite("initial", "final", "time")

    def torque(self, t, angle=0.0, speed=0.0):
        return np.where(np.asarray(t) >= self.time, self.final, self.initial) if np.ndim(t) else (
            self.final if t >= self.time else self.initial
        )

    def scalar_torque(self):
        initial, final, switch = float(self.initial), float(self.final), self.time
        return lambda t, angle, speed: final if t >= switch else initial

    def breakpoints(self):
        return (float(self.time),) if self.final != self.initial else ()

    def excitation_frequencies(self, speed):
        return [(math.inf, "step change")] if self.final != self.initial else []


@_register
@dataclass(frozen=True)
class Ramp(TorqueProfile):
    """Linear ramp from ``start_value`` at ``start_time`` to ``end_value`` at ``end_time``, held outside."""

    kind: ClassVar[str] = "ramp"
    uses_angle: ClassVar[bool] = False
    start_value: float = 0.0
    end_value: float = 1.0
    start_time: float = 0.0
    end_time: float = 1.0

    def __post_init__(self):
        self._check_finite("start_value", "end_value", "start_time", "end_time")
        if not self.end_time > self.start_time:
            raise SceneError(f"ramp.end_time: must be > start_time ({self.start_time}), got {self.end_time}")

    def torque(self, t, angle=0.0, speed=0.0):
        s = np.clip((np.asarray(t, dtype=float) - self.start_time) / (self.end_time - self.start_time), 0.0, 1.0)
        out = self.start_value + s * (self.end_value - self.start_value)
        return out if np.ndim(t) else float(out)

    def scalar_torque(self):
        t0, span = self.start_time, self.end_time - self.start_time
        v0, rise = self.start_value, self.end_value - self.start_value

        def torque(t, angle, speed):
            s = (t - t0) / span
            s = 0.0 if s < 0.0 else 1.0 if s > 1.0 else s  # clip(s, 0, 1)
            return v0 + s * rise

        return torque

    def breakpoints(self):
        return (float(self.start_time), float(self.end_time))

    def excitation_frequencies(self, speed):
        return [(1.0 / (self.end_time - self.start_time), "ramp (1/duration)")]


@_register
@dataclass(frozen=True)
class Sine(TorqueProfile):
    """``mean + amplitude sin(2 pi frequency t + phase)`` [N m, Hz, rad]."""

    kind: ClassVar[str] = "sine"
    uses_angle: ClassVar[bool] = False
    mean: float = 0.0
    amplitude: float = 1.0
    frequency: float = 1.0
    phase: float = 0.0

    def __post_init__(self):
        self._check_finite("mean", "amplitude", "frequency", "phase")

    def torque(self, t, angle=0.0, speed=0.0):
        return self.mean + self.amplitude * np.sin(2.0 * np.pi * self.frequency * np.asarray(t, dtype=float) + self.phase) if np.ndim(t) else (
            self.mean + self.amplitude * math.sin(2.0 * math.pi * self.frequency * t + self.phase)
        )

    def scalar_torque(self):
        mean, amplitude, omega, phase = self.mean, self.amplitude, 2.0 * math.pi * self.frequency, self.phase
        sin = math.sin
        return lambda t, angle, speed: mean + amplitude * sin(omega * t + phase)

    def excitation_frequencies(self, speed):
        return [(abs(self.frequency), "sine")] if self.amplitude else []


@_register
@dataclass(frozen=True)
class Table(TorqueProfile):
    """Recorded torque profile: ``times`` [s] (strictly increasing), ``values`` [N m].

    ``interpolation``: ``linear`` or ``previous`` (zero-order hold, as a ROS
    node sees held messages). Held constant outside the table.
    """

    kind: ClassVar[str] = "table"
    uses_angle: ClassVar[bool] = False
    times: tuple = (0.0, 1.0)
    values: tuple = (0.0, 0.0)
    interpolation: str = "linear"

    def __post_init__(self):
        times = np.asarray(self.times, dtype=float)
        values = np.asarray(self.values, dtype=float)
        if times.ndim != 1 or times.size < 1 or times.shape != values.shape:
            raise SceneError(
                f"table: times and values must be equal-length 1-D lists, got {times.shape} and {values.shape}"
            )
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(values))):
            raise SceneError("table: times and values must be finite")
        if times.size > 1 and np.any(np.diff(times) <= 0):
            raise SceneError("table.times: must be strictly increasing")
        if self.interpolation not in ("linear", "previous"):
            raise SceneError(f"table.interpolation: must be 'linear' or 'previous', got {self.interpolation!r}")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", values)

    def torque(self, t, angle=0.0, speed=0.0):
        ta = np.asarray(t, dtype=float)
        if self.interpolation == "linear":
            out = np.interp(ta, self.times, self.values)
        else:
            idx = np.clip(np.searchsorted(self.times, ta, side="right") - 1, 0, self.times.size - 1)
            out = self.values[idx]
        return out if np.ndim(t) else float(out)

    def scalar_torque(self):
        times, values = self.times.tolist(), self.values.tolist()
        if self.interpolation == "linear":
            return lambda t, angle, speed: _interp(t, times, values)
        last = len(times) - 1

        def held(t, angle, speed):
            # values[clip(searchsorted(times, t, 'right') - 1, 0, last)]
            j = bisect_right(times, t) - 1
            return values[0 if j < 0 else last if j > last else j]

        return held

    def breakpoints(self):
        if self.interpolation == "previous":  # a jump only where the held value changes (held before the first)
            return tuple(float(t) for t in self.times[1:][self.values[1:] != self.values[:-1]])
        return tuple(float(t) for t in self.times)  # a kink at every sample

    def excitation_frequencies(self, speed):
        if self.times.size < 2:
            return []
        if self.interpolation == "previous" and np.any(np.diff(self.values) != 0):
            return [(math.inf, "table with zero-order hold (step changes)")]
        return [(0.5 / float(np.min(np.diff(self.times))), "table (Nyquist of its sample spacing)")]

    def __eq__(self, other):
        return (
            isinstance(other, Table)
            and np.array_equal(self.times, other.times)
            and np.array_equal(self.values, other.values)
            and self.interpolation == other.interpolation
        )

    __hash__ = None


# --------------------------------------------------------------- closed loop
def _harmonics(values: Sequence[float] | None, name: str) -> tuple:
    values = tuple(float(v) for v in (values or ()))
    if not all(math.isfinite(v) for v in values):
        raise SceneError(f"{name}: harmonic amplitudes must be finite")
    return values


@_register
@dataclass(frozen=True)
class Engine(TorqueProfile):
    """Combustion engine: mean torque plus firing pulsations by crank angle.

    ``torque = base(speed) + sum_k A_k sin(k n_f theta + k phase)``, where the
    crank angle ``theta = crank_ratio * angle`` and ``n_f = 2 cylinders /
    strokes`` firing pulses per crank revolution (4-stroke: cylinders/2).

    ``base`` is ``mean_torque``, or, when ``speed_setpoint`` [rad/s of wheel M]
    is given, a droop governor ``clip(mean_torque + governor_gain
    (speed_setpoint - speed), 0, max_torque)`` [N m, N m s/rad]. The
    amplitudes ``harmonics`` [N m] are the first, second, ... firing-order
    components of the gas + inertia torque; ``ramp_time`` [s] fades the
    pulsations and the governor in from 0 at start (engine start-up).
    """

    kind: ClassVar[str] = "engine"
    state_dependent: ClassVar[bool] = True
    mean_torque: float = 20.0
    cylinders: int = 6
    strokes: int = 4
    harmonics: tuple = (15.0, 5.0)
    phase: float = 0.0
    crank_ratio: float = 1.0
    speed_setpoint: float | None = None
    governor_gain: float = 1.0
    max_torque: float = 1.0e9
    ramp_time: float = 0.0

    def __post_init__(self):
        self._check_finite("mean_torque", "phase", "crank_ratio", "governor_gain", "max_torque", "ramp_time")
        if int(self.cylinders) != self.cylinders or self.cylinders < 1:
            raise SceneError(f"engine.cylinders: must be a positive integer, got {self.cylinders!r}")
        if self.strokes not in (2, 4):
            raise SceneError(f"engine.strokes: must be 2 or 4, got {self.strokes!r}")
        self._check_positive("crank_ratio")
        if self.governor_gain < 0 or self.ramp_time < 0:
            raise SceneError("engine.governor_gain and engine.ramp_time: must be >= 0")
        if self.speed_setpoint is not None and not math.isfinite(self.speed_setpoint):
            raise SceneError("engine.speed_setpoint: must be finite")
        object.__setattr__(self, "cylinders", int(self.cylinders))
        object.__setattr__(self, "harmonics", _harmonics(self.harmonics, "engine.harmonics"))

    @property
    def pulses_per_revolution(self) -> float:
        """Firing pulses per crank revolution, 2 cylinders / strokes [-]."""
        return 2.0 * self.cylinders / self.strokes

    def torque(self, t, angle, speed):
        theta = self.crank_ratio * np.asarray(angle, dtype=float)
        if self.speed_setpoint is None:
            base = self.mean_torque + 0.0 * theta
        else:
            base = np.clip(self.mean_torque + self.governor_gain * (self.speed_setpoint - speed), 0.0, self.max_torque)
        pulses = 0.0 * theta
        nf = self.pulses_per_revolution
        for k, amp in enumerate(self.harmonics, start=1):
            pulses = pulses + amp * np.sin(k * (nf * theta + self.phase))
        if self.ramp_time > 0:
            fade = np.clip(np.asarray(t, dtype=float) / self.ramp_time, 0.0, 1.0)
            base, pulses = base * fade, pulses * fade
        out = base + pulses
        return out if np.ndim(out) else float(out)

    def scalar_torque(self):
        mean, gain, setpoint, top = self.mean_torque, self.governor_gain, self.speed_setpoint, self.max_torque
        ratio, nf, phase, ramp = self.crank_ratio, self.pulses_per_revolution, self.phase, self.ramp_time
        a1, a2, higher = _first_two(self.harmonics)
        sin = math.sin

        def torque(t, angle, speed):
            if setpoint is None:
                base = mean
            else:  # droop governor, clip(M + K (w_set - w), 0, M_max)
                base = mean + gain * (setpoint - speed)
                base = 0.0 if base < 0.0 else base
                base = top if base > top else base
            arg = nf * (ratio * angle) + phase  # n_f theta + phase, crank angle theta
            pulses = a1 * sin(arg) + a2 * sin(2.0 * arg)  # sum_k A_k sin(k (n_f theta + phase))
            for k, amp in higher:
                pulses += amp * sin(k * arg)
            if ramp > 0:
                fade = t / ramp
                fade = 0.0 if fade < 0.0 else 1.0 if fade > 1.0 else fade  # clip(t / t_ramp, 0, 1)
                return base * fade + pulses * fade
            return base + pulses

        return torque

    def breakpoints(self):
        return (float(self.ramp_time),) if self.ramp_time > 0 else ()

    def excitation_frequencies(self, speed):
        f_rev = abs(speed) * self.crank_ratio / (2.0 * math.pi)
        return [
            (k * self.pulses_per_revolution * f_rev, f"engine firing order {k}")
            for k, a in enumerate(self.harmonics, start=1)
            if a
        ]


@_register
@dataclass(frozen=True)
class MotorCurve(TorqueProfile):
    """Electric motor torque-speed curve with optional soft start.

    ``curve`` is a list of ``[speed rad/s, torque N m]`` points (linearly
    interpolated, held beyond the ends). Without a curve, the linear DC/PMSM
    line ``stall_torque (1 - speed/no_load_speed)`` is used. ``soft_start_time``
    [s] ramps a torque limit from 0 to full (soft starter or inverter ramp).
    """

    kind: ClassVar[str] = "motor"
    state_dependent: ClassVar[bool] = True
    uses_angle: ClassVar[bool] = False
    stall_torque: float = 60.0
    no_load_speed: float = 300.0
    curve: tuple | None = None
    soft_start_time: float = 0.0

    def __post_init__(self):
        self._check_finite("stall_torque", "no_load_speed", "soft_start_time")
        self._check_positive("no_load_speed")
        if self.soft_start_time < 0:
            raise SceneError("motor.soft_start_time: must be >= 0")
        if self.curve is not None:
            pts = np.asarray(self.curve, dtype=float)
            if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2:
                raise SceneError("motor.curve: must be a list of at least two [speed, torque] pairs")
            if not np.all(np.isfinite(pts)) or np.any(np.diff(pts[:, 0]) <= 0):
                raise SceneError("motor.curve: speeds must be finite and strictly increasing")
            object.__setattr__(self, "curve", tuple(tuple(map(float, p)) for p in pts))
            object.__setattr__(self, "_pts", pts)

    def torque(self, t, angle, speed):
        if self.curve is None:
            out = self.stall_torque * (1.0 - np.asarray(speed, dtype=float) / self.no_load_speed)
        else:
            out = np.interp(speed, self._pts[:, 0], self._pts[:, 1])
        if self.soft_start_time > 0:
            out = out * np.clip(np.asarray(t, dtype=float) / self.soft_start_time, 0.0, 1.0)
        return out if np.ndim(out) else float(out)

    def scalar_torque(self):
        stall, no_load, soft = self.stall_torque, self.no_load_speed, self.soft_start_time
        if self.curve is None:
            speeds = torques = None
        else:
            speeds, torques = self._pts[:, 0].tolist(), self._pts[:, 1].tolist()

        def torque(t, angle, speed):
            if speeds is None:
                out = stall * (1.0 - speed / no_load)  # linear DC/PMSM line
            else:
                out = _interp(speed, speeds, torques)
            if soft > 0:
                fade = t / soft
                out = out * (0.0 if fade < 0.0 else 1.0 if fade > 1.0 else fade)  # clip(t / t_soft, 0, 1)
            return out

        return torque

    def scalar_source(self, t, angle, speed):
        if self.curve is not None:
            return None
        out = f"{float(self.stall_torque)!r} * (1.0 - {speed} / {float(self.no_load_speed)!r})"
        soft = float(self.soft_start_time)
        if soft > 0:  # out * clip(t / t_soft, 0, 1): the closure's value (t < 0 <=> t/T < 0; t/T rounds to 1 near T)
            return f"{out} * (0.0 if {t} < 0.0 else 1.0 if {t} > {soft!r} else {t} / {soft!r})"
        return out

    def breakpoints(self):
        return (float(self.soft_start_time),) if self.soft_start_time > 0 else ()

    def excitation_frequencies(self, speed):
        return [(1.0 / self.soft_start_time, "motor soft start (1/ramp time)")] if self.soft_start_time else []


@_register
@dataclass(frozen=True)
class Polynomial(TorqueProfile):
    """Speed-dependent load ``c0 + c1 speed + c2 speed |speed|`` [N m; N m s/rad; N m s^2/rad^2]."""

    kind: ClassVar[str] = "polynomial"
    state_dependent: ClassVar[bool] = True
    uses_angle: ClassVar[bool] = False
    c0: float = 0.0
    c1: float = 0.0
    c2: float = 0.0

    def __post_init__(self):
        self._check_finite("c0", "c1", "c2")

    def torque(self, t, angle, speed):
        s = np.asarray(speed, dtype=float)
        out = self.c0 + self.c1 * s + self.c2 * s * np.abs(s)
        return out if np.ndim(out) else float(out)

    def scalar_torque(self):
        c0, c1, c2 = self.c0, self.c1, self.c2
        return lambda t, angle, speed: c0 + c1 * speed + c2 * speed * abs(speed)

    def scalar_source(self, t, angle, speed):
        # the closure's sum without its zero terms (value-equal: x + 0.0 == x; only a -0.0 may turn +0.0)
        c0, c1, c2 = (float(v) for v in (self.c0, self.c1, self.c2))
        terms = [f"{c0!r}"] if c0 else []
        terms += [f"{c1!r} * {speed}"] if c1 else []
        terms += [f"{c2!r} * {speed} * abs({speed})"] if c2 else []
        return " + ".join(terms) if terms else "0.0"


@_register
@dataclass(frozen=True)
class Compressor(TorqueProfile):
    """Reciprocating compressor: torque periodic in wheel-3 angle.

    ``torque = mean_torque + c1 speed + sum_k A_k sin(k cylinders angle + k phase)``
    [N m]; ``cylinders`` compression strokes per revolution of wheel 3.
    ``ramp_time`` [s] fades the load in from 0 at start.
    """

    kind: ClassVar[str] = "compressor"
    state_dependent: ClassVar[bool] = True
    mean_torque: float = 20.0
    c1: float = 0.0
    cylinders: int = 2
    harmonics: tuple = (15.0, 5.0)
    phase: float = 0.0
    ramp_time: float = 0.0

    def __post_init__(self):
        self._check_finite("mean_torque", "c1", "phase", "ramp_time")
        if int(self.cylinders) != self.cylinders or self.cylinders < 1:
            raise SceneError(f"compressor.cylinders: must be a positive integer, got {self.cylinders!r}")
        if self.ramp_time < 0:
            raise SceneError("compressor.ramp_time: must be >= 0")
        object.__setattr__(self, "cylinders", int(self.cylinders))
        object.__setattr__(self, "harmonics", _harmonics(self.harmonics, "compressor.harmonics"))

    def torque(self, t, angle, speed):
        a = np.asarray(angle, dtype=float)
        out = self.mean_torque + self.c1 * np.asarray(speed, dtype=float) + 0.0 * a
        for k, amp in enumerate(self.harmonics, start=1):
            out = out + amp * np.sin(k * (self.cylinders * a + self.phase))
        if self.ramp_time > 0:
            out = out * np.clip(np.asarray(t, dtype=float) / self.ramp_time, 0.0, 1.0)
        return out if np.ndim(out) else float(out)

    def scalar_torque(self):
        mean, c1, cylinders, phase, ramp = self.mean_torque, self.c1, self.cylinders, self.phase, self.ramp_time
        a1, a2, higher = _first_two(self.harmonics)
        sin = math.sin

        def torque(t, angle, speed):
            arg = cylinders * angle + phase
            out = mean + c1 * speed + a1 * sin(arg) + a2 * sin(2.0 * arg)  # + sum_k A_k sin(k arg)
            for k, amp in higher:
                out += amp * sin(k * arg)
            if ramp > 0:
                fade = t / ramp
                out = out * (0.0 if fade < 0.0 else 1.0 if fade > 1.0 else fade)  # clip(t / t_ramp, 0, 1)
            return out

        return torque

    def breakpoints(self):
        return (float(self.ramp_time),) if self.ramp_time > 0 else ()

    def excitation_frequencies(self, speed):
        f_rev = abs(speed) / (2.0 * math.pi)
        return [
            (k * self.cylinders * f_rev, f"compressor order {k}") for k, a in enumerate(self.harmonics, start=1) if a
        ]


@_register
@dataclass(frozen=True)
class Schedule(TorqueProfile):
    """On/off schedule: ``active`` profile inside ``periods`` [[start, end], ...] [s], ``inactive`` outside.

    (Not ``on``/``off``: YAML 1.1 reads those keys as booleans.)

    E.g. an air compressor that loads while the governor asks for air and
    unloads (runs with open valves, small torque) otherwise.
    """

    kind: ClassVar[str] = "schedule"
    active: TorqueProfile = field(default_factory=Constant)
    inactive: TorqueProfile = field(default_factory=Constant)
    periods: tuple = ()

    def __post_init__(self):
        if isinstance(self.active, Mapping):
            object.__setattr__(self, "active", make_profile(self.active, "schedule.active"))
        if isinstance(self.inactive, Mapping):
            object.__setattr__(self, "inactive", make_profile(self.inactive, "schedule.inactive"))
        periods = []
        for p in self.periods:
            if len(p) != 2 or not (math.isfinite(p[0]) and math.isfinite(p[1])) or not p[1] > p[0]:
                raise SceneError(f"schedule.periods: each period must be [start, end] with end > start, got {p!r}")
            periods.append((float(p[0]), float(p[1])))
        object.__setattr__(self, "periods", tuple(periods))

    @property
    def state_dependent(self) -> bool:  # type: ignore[override]
        return self.active.state_dependent or self.inactive.state_dependent

    @property
    def uses_angle(self) -> bool:  # type: ignore[override]
        return self.active.uses_angle or self.inactive.uses_angle

    def is_active(self, t):
        """True where the ``active`` profile applies."""
        ta = np.asarray(t, dtype=float)
        mask = np.zeros(ta.shape, dtype=bool)
        for start, end in self.periods:
            mask |= (ta >= start) & (ta < end)
        return mask if np.ndim(t) else bool(mask)

    def torque(self, t, angle, speed):
        if np.ndim(t) or np.ndim(angle) or np.ndim(speed):
            return np.where(self.is_active(t), self.active.torque(t, angle, speed), self.inactive.torque(t, angle, speed))
        return self.active.torque(t, angle, speed) if self.is_active(t) else self.inactive.torque(t, angle, speed)

    def scalar_torque(self):
        periods = self.periods
        active, inactive = self.active.scalar_torque(), self.inactive.scalar_torque()

        if len(periods) == 1:  # the common case, without the loop
            ((start, end),) = periods
            return lambda t, angle, speed: (active if start <= t < end else inactive)(t, angle, speed)

        def torque(t, angle, speed):
            for start, end in periods:
                if start <= t < end:
                    return active(t, angle, speed)
            return inactive(t, angle, speed)

        return torque

    def breakpoints(self):
        edges = {float(v) for period in self.periods for v in period}
        return tuple(sorted(edges | set(self.active.breakpoints()) | set(self.inactive.breakpoints())))

    def left_of(self, t):
        return min(math.nextafter(t, -math.inf), self.active.left_of(t), self.inactive.left_of(t))

    def excitation_frequencies(self, speed):
        out = self.active.excitation_frequencies(speed) + self.inactive.excitation_frequencies(speed)
        if self.periods and self.active != self.inactive:
            out.append((math.inf, "schedule switching (step change)"))
        return out


def make_profile(spec: Mapping[str, Any] | TorqueProfile | float, where: str = "profile") -> TorqueProfile:
    """Profile from a mapping with a ``type`` key (or a number: constant).

    Raises :class:`SceneError` naming ``where``, the bad key and the valid ones.
    """
    if isinstance(spec, TorqueProfile):
        return spec
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return Constant(float(spec))
    if not isinstance(spec, Mapping):
        raise SceneError(f"{where}: expected a mapping with a 'type' key or a number, got {spec!r}")
    spec = dict(spec)
    kind = spec.pop("type", None)
    if kind not in _REGISTRY:
        raise SceneError(f"{where}.type: unknown profile {kind!r}; known: {', '.join(sorted(_REGISTRY))}")
    cls = _REGISTRY[kind]
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(spec) - names)
    if unknown:
        raise SceneError(f"{where}.{unknown[0]}: unknown key for type {kind!r}; known: {', '.join(sorted(names))}")
    for key, value in list(spec.items()):
        if isinstance(value, list):
            spec[key] = tuple(tuple(v) if isinstance(v, list) else v for v in value)
    try:
        return cls(**spec)
    except SceneError as exc:
        raise SceneError(f"{where}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{where} ({kind}): {exc}") from None


def profile_kinds() -> list[str]:
    """Names accepted as ``type`` by :func:`make_profile`."""
    return sorted(_REGISTRY)
