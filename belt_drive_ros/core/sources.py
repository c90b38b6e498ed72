"""Drive-torque sources and load torques: a profile is ``torque(t, angle, speed)`` [s, rad, rad/s -> N m], stated
once as kernel data. A drive acts on wheel M and sees its angle and speed (an engine: the crank angle through
``crank_ratio``), a load on wheel 3 and sees wheel 3's; scalars and arrays alike. :func:`make_profile` builds one
from a mapping (scene YAML): ``type`` selects the class, the other keys are its fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, Callable, ClassVar, Mapping

import numpy as np

from .errors import SceneError, plain_number, real, short
from . import profile_data as D

#: :mod:`~belt_drive_ros.core.kernel_profiles` (numba) once a torque was evaluated (:func:`_kernel_profiles`)
_KERNEL_PROFILES = None


def _kernel_profiles():
    """The compiled profiles' module, imported at the first torque evaluated (numba only where a run starts), then
    kept here: a torque evaluation pays no import statement."""
    global _KERNEL_PROFILES
    from . import kernel_profiles

    _KERNEL_PROFILES = kernel_profiles
    return kernel_profiles

_REGISTRY: dict[str, type["TorqueProfile"]] = {}

# ----------------------------------------------------------- plausible ranges
#: largest plausible magnitude of each kind of profile field (SI units), applied by
#: :func:`make_profile` to profiles from outside (scene files, recordings' scenes, campaigns):
#: past these no belt drive exists and the numbers only make a run meaningless (a 1e300 N m
#: harmonic diverges the state, a 1e300 rad phase leaves no digit of the sine). The
#: constructors alone admit any finite value (idealised studies), as BeltDriveParams does.
#: A torque: no belt transmits 1 MN m (a truck accessory drive carries ~100 N m).
TORQUE_MAX = 1.0e6
#: A speed [rad/s]: ~1 million rpm.
SPEED_MAX = 1.0e5
#: Cylinders of an engine or compressor, harmonics of a profile, periods of a schedule.
COUNT_MAX = {"cylinders": 64, "harmonics": 64, "periods": 1000}
#: the kinds of field: (largest magnitude, unit)
_KINDS: dict[str, tuple[float, str]] = {
    "torque": (TORQUE_MAX, "N m"), "speed": (SPEED_MAX, "rad/s"),
    "frequency": (1.0e6, "Hz"),  # the highest plausible output rate (core.scene.RANGES)
    "time": (1.0e7, "s"),  # a time or period: the longest scene (core.scene.RANGES)
    "phase": (1.0e3, "rad"),  # beyond it sin(phase) keeps few correct digits
    "gain": (1.0e6, "N m s/rad"),  # a speed gain or damping-like coefficient
    "quadratic": (1.0e3, "N m s^2/rad^2"), "ratio": (1.0e2, "1"),  # a quadratic speed coefficient; a transmission ratio
}


def _register(cls):
    _REGISTRY[cls.kind] = cls
    return cls


class TorqueProfile:
    """Base class: a torque [N m] as a function of time, angle and speed, stated once as data (:meth:`encode`: a
    kind code of :mod:`~belt_drive_ros.core.profile_data`, its numbers and tables) that the compiled kernel evaluates
    for :meth:`torque`, :meth:`scalar_torque` and the time loop alike (every stepper refuses one without data)."""

    kind: ClassVar[str] = ""

    #: True when the torque depends on angle or speed (closes a loop); a subclass states its own.
    state_dependent = True
    #: False when the torque ignores its angle argument (the kernel then passes 0.0).
    uses_angle = True

    def encode(self, builder: D.ProfileBuilder) -> int | None:
        """Append this profile's row(s) to ``builder``; its row index (None: no data form, Python only)."""
        return None

    def data(self) -> D.ProfileData | None:
        """The profile as the kernel's data (:mod:`~belt_drive_ros.core.profile_data`), built once; None: Python only."""
        cached = self.__dict__.get("_data", False)
        if cached is False:
            builder = D.ProfileBuilder()
            cached = None if self.encode(builder) is None else builder.build()
            object.__setattr__(self, "_data", cached)
        return cached

    def torque(self, t, angle=0.0, speed=0.0):
        """Torque [N m] at time ``t`` [s], wheel angle [rad], wheel speed [rad/s] (scalars or arrays), evaluated by
        the compiled kernel from :meth:`data` (bitwise the values the time loop computes)."""
        kernel = _KERNEL_PROFILES or _kernel_profiles()
        data = self.data()
        if data is None:
            raise NotImplementedError(f"{type(self).__name__}: define encode() or torque()")
        if (type(t) is type(angle) is type(speed) is np.ndarray and t.ndim == 1 and angle.shape == speed.shape == t.shape
                and t.dtype == angle.dtype == speed.dtype == np.float64):  # a run's samples (the common case)
            out = np.empty(t.size)
            c = np.ascontiguousarray
            kernel.profile_torque_array(data.kinds, data.params, data.tx, data.ty, c(t), c(angle), c(speed), out)
            return out
        if np.ndim(t) or np.ndim(angle) or np.ndim(speed):
            ts, angles, speeds = (np.ascontiguousarray(a, dtype=np.float64).ravel() for a in np.broadcast_arrays(
                np.asarray(t, dtype=float), np.asarray(angle, dtype=float), np.asarray(speed, dtype=float)))
            out = np.empty(ts.size)
            kernel.profile_torque_array(data.kinds, data.params, data.tx, data.ty, ts, angles, speeds, out)
            return out.reshape(np.broadcast(t, angle, speed).shape)
        return float(kernel.profile_torque(data.kinds, data.params, data.tx, data.ty, float(t), float(angle), float(speed)))

    def __call__(self, t, angle=0.0, speed=0.0):
        return self.torque(t, angle, speed)

    def scalar_torque(self) -> Callable[[float, float, float], float]:
        """A fast ``f(t, angle, speed) -> float`` for Python-float arguments (the kernel's dispatcher, data bound)."""
        data = self.data()
        if data is None:
            torque = self.torque
            return lambda t, angle, speed: float(torque(t, angle, speed))
        from .kernel_profiles import profile_torque

        kinds, params, tx, ty = data.kinds, data.params, data.tx, data.ty
        return lambda t, angle, speed: profile_torque(kinds, params, tx, ty, t, angle, speed)

    def breakpoints(self) -> "tuple[float, ...] | np.ndarray":
        """Times [s] at which the torque jumps or kinks in time (a step, a ramp's ends, a soft start's end): the
        stepper splits a step there (a one-step method is first order across one). A tuple or a float64 array."""
        return ()

    def left_of(self, t: float) -> float:
        """Latest time [s] before ``t`` with the torque's value from the left of ``t`` (a step ending at breakpoint
        ``t`` samples no later; default the float just below: every profile here switches at ``t >= time``)."""
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

    def __post_init__(self):
        """Every ``float`` field finite, in field order (a subclass with more checks calls this first)."""
        self._check_finite(*(f.name for f in fields(self) if f.type == "float"))

    def _check_finite(self, *names: str) -> None:
        for name in names:
            value = getattr(self, name)
            if not np.all(np.isfinite(np.asarray(value, dtype=float))):
                raise SceneError(f"{self.kind}.{name}: must be finite, got {short(value)}")

    def _check_positive(self, *names: str) -> None:
        for name in names:
            if not getattr(self, name) > 0:
                raise SceneError(f"{self.kind}.{name}: must be > 0, got {short(getattr(self, name))}")

    #: field -> kind of :data:`_KINDS` (a column of a 2-D field: ``field[j]``)
    PLAUSIBLE: ClassVar[dict[str, str]] = {}

    def check_plausible(self, where: str = "profile") -> "TorqueProfile":
        """``self`` if every field is within its plausible range (:data:`TORQUE_MAX` ...), else
        :class:`SceneError` naming ``where``, the field, its value and the range."""
        for key, kind in self.PLAUSIBLE.items():
            name, _, column = key.partition("[")
            value = getattr(self, name)
            if value is None:
                continue
            values = np.asarray(value, dtype=float)
            if column:
                values = values[:, int(column.rstrip("]"))] if values.ndim == 2 else values
            top, unit = _KINDS[kind]
            if values.size:
                worst = float(np.max(np.abs(values)))
                if worst > top:
                    raise SceneError(f"{where}.{key}: {worst:g} {unit} is outside the plausible range "
                                     f"[-{top:g}, {top:g}] {unit}")
        for name, top in COUNT_MAX.items():
            value = getattr(self, name, None)
            count = len(value) if isinstance(value, (tuple, list)) else value
            if isinstance(count, int) and count > top:
                raise SceneError(f"{where}.{name}: {count} is more than the plausible {top}")
        return self


def _fade_time(value: float) -> float:
    """A fade-in duration for the kernel: 0.0 means none."""
    return float(value) if value > 0 else 0.0


# ---------------------------------------------------------------- open loop
@_register
@dataclass(frozen=True)
class Constant(TorqueProfile):
    """Constant torque ``value`` [N m]."""

    kind: ClassVar[str] = "constant"
    value: float = 0.0
    PLAUSIBLE = {"value": "torque"}

    state_dependent = False
    uses_angle = False

    def encode(self, builder):
        return builder.row(D.CONSTANT, self.value)

@_register
@dataclass(frozen=True)
class Step(TorqueProfile):
    """``initial`` [N m] before ``time`` [s], ``final`` from then on."""

    kind: ClassVar[str] = "step"
    initial: float = 0.0
    final: float = 1.0
    time: float = 0.0
    PLAUSIBLE = {"initial": "torque", "final": "torque", "time": "time"}

    state_dependent = False
    uses_angle = False

    def encode(self, builder):
        # final if t >= time else initial
        return builder.row(D.STEP, self.initial, self.final, self.time)

    def breakpoints(self):
        return (float(self.time),) if self.final != self.initial else ()

    def excitation_frequencies(self, speed):
        return [(math.inf, "step change")] if self.final != self.initial else []


@_register
@dataclass(frozen=True)
class Ramp(TorqueProfile):
    """Linear ramp from ``start_value`` at ``start_time`` to ``end_value`` at ``end_time``, held outside."""

    kind: ClassVar[str] = "ramp"
    start_value: float = 0.0
    end_value: float = 1.0
    start_time: float = 0.0
    end_time: float = 1.0
    PLAUSIBLE = {"start_value": "torque", "end_value": "torque", "start_time": "time", "end_time": "time"}

    def __post_init__(self):
        super().__post_init__()
        if not self.end_time > self.start_time:
            raise SceneError(f"ramp.end_time: must be > start_time ({self.start_time}), got {self.end_time}")

    state_dependent = False
    uses_angle = False

    def encode(self, builder):
        # start_value + clip((t - t0) / span, 0, 1) * rise
        return builder.row(D.RAMP, self.start_value, self.end_value - self.start_value, self.start_time, self.end_time,
                           self.end_time - self.start_time)

    def breakpoints(self):
        return (float(self.start_time), float(self.end_time))

    def excitation_frequencies(self, speed):
        return [(1.0 / (self.end_time - self.start_time), "ramp (1/duration)")]


@_register
@dataclass(frozen=True)
class Sine(TorqueProfile):
    """``mean + amplitude sin(2 pi frequency t + phase)`` [N m, Hz, rad]."""

    kind: ClassVar[str] = "sine"
    mean: float = 0.0
    amplitude: float = 1.0
    frequency: float = 1.0
    phase: float = 0.0
    PLAUSIBLE = {"mean": "torque", "amplitude": "torque", "frequency": "frequency", "phase": "phase"}

    state_dependent = False
    uses_angle = False

    def encode(self, builder):
        # mean + amplitude sin(omega t + phase), omega = 2 pi f [rad/s]
        return builder.row(D.SINE, self.mean, self.amplitude, 2.0 * math.pi * self.frequency, self.phase)

    def excitation_frequencies(self, speed):
        return [(abs(self.frequency), "sine")] if self.amplitude else []


@_register
@dataclass(frozen=True)
class Table(TorqueProfile):
    """Recorded torque: ``times`` [s] (strictly increasing), ``values`` [N m], held outside the table;
    ``interpolation`` ``linear`` or ``previous`` (zero-order hold, as a ROS node sees held messages)."""

    kind: ClassVar[str] = "table"
    times: tuple = (0.0, 1.0)
    values: tuple = (0.0, 0.0)
    interpolation: str = "linear"
    PLAUSIBLE = {"times": "time", "values": "torque"}

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

    state_dependent = False
    uses_angle = False

    def encode(self, builder):
        offset, n = builder.table(self.times, self.values)
        return builder.row(D.TABLE_LINEAR if self.interpolation == "linear" else D.TABLE_HELD, offset, n)

    def breakpoints(self):
        # float64 arrays (a recording has one per sample: no Python float per sample)
        if self.interpolation == "previous":  # a jump only where the held value changes (held before the first)
            return self.times[1:][self.values[1:] != self.values[:-1]]
        return self.times.copy()  # a kink at every sample

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
class _Pulsating(TorqueProfile):
    """What an engine and a compressor share: amplitudes ``harmonics`` [N m] of orders k = 1, 2, ... of the angle,
    faded in over ``ramp_time`` [s] (a breakpoint)."""

    def _check_harmonics(self) -> None:
        h = () if self.harmonics is None else self.harmonics
        if not isinstance(h, (list, tuple, np.ndarray)) or getattr(h, "ndim", 1) != 1:
            raise SceneError(f"{self.kind}.harmonics: expected a list of amplitudes [N m], got {type(h).__name__} {short(h)}")
        values = []
        for j, v in enumerate(h):
            values.append(float(plain_number(v, lambda what, j=j: SceneError(f"{self.kind}.harmonics[{j}]: {what}"))))
        if not all(math.isfinite(v) for v in values):
            raise SceneError(f"{self.kind}.harmonics: harmonic amplitudes must be finite")
        object.__setattr__(self, "harmonics", tuple(values))

    def _harmonic_table(self, builder: D.ProfileBuilder) -> tuple[int, int]:
        """The amplitudes [N m] as a table (offset, count) for the kernel."""
        return builder.table(np.zeros(len(self.harmonics)), np.asarray(self.harmonics, dtype=float))

    @property
    def uses_angle(self):
        return any(self.harmonics)

    def breakpoints(self):
        return (float(self.ramp_time),) if self.ramp_time > 0 else ()

    def _orders(self, per_revolution: float, f_rev: float, label: str) -> list[tuple[float, str]]:
        """``k per_revolution f_rev`` [Hz] of each non-zero harmonic k, at ``f_rev`` revolutions per second, labelled
        by its order (per revolution of the shaft: a 4-cylinder four-stroke's 2nd firing harmonic is order 4)."""
        return [(k * per_revolution * f_rev, f"{label} {k * per_revolution:g}")
                for k, a in enumerate(self.harmonics, start=1) if a]


@_register
@dataclass(frozen=True)
class Engine(_Pulsating):
    """Combustion engine: ``torque = base(speed) + sum_k A_k sin(k n_f theta + k phase)`` [N m], crank angle
    ``theta = crank_ratio angle``, ``n_f = 2 cylinders / strokes`` firing pulses per crank revolution; ``harmonics``
    A_k the firing-order components of the gas + inertia torque. ``base`` is ``mean_torque``, or with
    ``speed_setpoint`` [rad/s of wheel M] the droop governor ``clip(mean_torque + governor_gain (speed_setpoint -
    speed), 0, max_torque)`` [N m, N m s/rad]; ``ramp_time`` [s] fades the whole torque (mean or governor, and pulsations) in from 0 (start-up)."""

    kind: ClassVar[str] = "engine"
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
    #: max_torque is a clip of the governor's torque: its default 1e9 N m (no clip in practice) is allowed
    PLAUSIBLE = {"mean_torque": "torque", "harmonics": "torque", "phase": "phase", "crank_ratio": "ratio",
                 "speed_setpoint": "speed", "governor_gain": "gain", "ramp_time": "time"}

    def __post_init__(self):
        super().__post_init__()
        if int(self.cylinders) != self.cylinders or self.cylinders < 1:
            raise SceneError(f"engine.cylinders: must be a positive integer, got {self.cylinders!r}")
        if self.strokes not in (2, 4):
            raise SceneError(f"engine.strokes: must be 2 or 4, got {self.strokes!r}")
        self._check_positive("crank_ratio")
        for name in ("governor_gain", "max_torque", "ramp_time"):  # (a negative torque limit clips nothing)
            if getattr(self, name) < 0:
                raise SceneError(f"engine.{name}: must be >= 0, got {getattr(self, name)!r}")
        if self.speed_setpoint is not None and not math.isfinite(self.speed_setpoint):
            raise SceneError("engine.speed_setpoint: must be finite")
        object.__setattr__(self, "cylinders", int(self.cylinders))
        self._check_harmonics()

    @property
    def pulses_per_revolution(self) -> float:
        """Firing pulses per crank revolution, 2 cylinders / strokes [-]."""
        return 2.0 * self.cylinders / self.strokes

    @property
    def state_dependent(self):
        return self.uses_angle or self._governed

    @property
    def _governed(self) -> bool:
        return self.speed_setpoint is not None and self.max_torque >= 0.0

    def encode(self, builder):
        # base + sum_k A_k sin(k (n_f theta + phase)), crank angle theta = crank_ratio * angle; base: the mean, the
        # droop governor clip(M + K (w_set - w), 0, M_max), or M_max (clip(., 0, M_max < 0) is M_max)
        mode = 0 if self.speed_setpoint is None else 1 if self.max_torque >= 0.0 else 2
        offset, n = self._harmonic_table(builder)
        return builder.row(D.ENGINE, mode, self.mean_torque, self.governor_gain,
                           0.0 if self.speed_setpoint is None else self.speed_setpoint, self.max_torque,
                           self.pulses_per_revolution, self.crank_ratio, self.phase, _fade_time(self.ramp_time), offset, n)

    def excitation_frequencies(self, speed):
        return self._orders(self.pulses_per_revolution, abs(speed) * self.crank_ratio / (2.0 * math.pi), "engine order")


@_register
@dataclass(frozen=True)
class MotorCurve(TorqueProfile):
    """Electric motor: ``curve`` ``[[speed rad/s, torque N m], ...]`` (linear, held beyond the ends), or without one
    the DC/PMSM line ``stall_torque (1 - speed/no_load_speed)``; ``soft_start_time`` [s] ramps a torque limit from 0
    to full (soft starter or inverter ramp)."""

    kind: ClassVar[str] = "motor"
    stall_torque: float = 60.0
    no_load_speed: float = 300.0
    curve: tuple | None = None
    soft_start_time: float = 0.0
    PLAUSIBLE = {"stall_torque": "torque", "no_load_speed": "speed", "curve[0]": "speed", "curve[1]": "torque",
                 "soft_start_time": "time"}

    def __post_init__(self):
        super().__post_init__()
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

    state_dependent = True
    uses_angle = False

    def encode(self, builder):
        if self.curve is None:  # linear DC/PMSM line
            return builder.row(D.MOTOR_LINE, self.stall_torque, self.no_load_speed, _fade_time(self.soft_start_time))
        offset, n = builder.table(self._pts[:, 0], self._pts[:, 1])
        return builder.row(D.MOTOR_CURVE, offset, n, _fade_time(self.soft_start_time))

    def breakpoints(self):
        return (float(self.soft_start_time),) if self.soft_start_time > 0 else ()

    def excitation_frequencies(self, speed):
        return [(1.0 / self.soft_start_time, "motor soft start (1/ramp time)")] if self.soft_start_time else []


@_register
@dataclass(frozen=True)
class Polynomial(TorqueProfile):
    """Speed-dependent load ``c0 + c1 speed + c2 speed |speed|`` [N m; N m s/rad; N m s^2/rad^2]."""

    kind: ClassVar[str] = "polynomial"
    c0: float = 0.0
    c1: float = 0.0
    c2: float = 0.0
    PLAUSIBLE = {"c0": "torque", "c1": "gain", "c2": "quadratic"}

    uses_angle = False

    @property
    def state_dependent(self):
        return bool(self.c1 or self.c2)

    def encode(self, builder):
        return builder.row(D.POLYNOMIAL, self.c0, self.c1, self.c2)

@_register
@dataclass(frozen=True)
class Compressor(_Pulsating):
    """Reciprocating compressor: ``mean_torque + c1 speed + sum_k A_k sin(k cylinders angle + k phase)`` [N m],
    ``cylinders`` strokes per revolution of wheel 3; ``ramp_time`` [s] fades the load in from 0 at start."""

    kind: ClassVar[str] = "compressor"
    mean_torque: float = 20.0
    c1: float = 0.0
    cylinders: int = 2
    harmonics: tuple = (15.0, 5.0)
    phase: float = 0.0
    ramp_time: float = 0.0
    PLAUSIBLE = {"mean_torque": "torque", "c1": "gain", "harmonics": "torque", "phase": "phase", "ramp_time": "time"}

    def __post_init__(self):
        super().__post_init__()
        if int(self.cylinders) != self.cylinders or self.cylinders < 1:
            raise SceneError(f"compressor.cylinders: must be a positive integer, got {self.cylinders!r}")
        if self.ramp_time < 0:
            raise SceneError("compressor.ramp_time: must be >= 0")
        object.__setattr__(self, "cylinders", int(self.cylinders))
        self._check_harmonics()

    @property
    def state_dependent(self):
        return self.uses_angle or bool(self.c1)

    def encode(self, builder):
        # mean + c1 speed + sum_k A_k sin(k (cylinders angle + phase))
        offset, n = self._harmonic_table(builder)
        return builder.row(D.COMPRESSOR, self.mean_torque, self.c1, self.cylinders, self.phase, _fade_time(self.ramp_time),
                           offset, n)

    def excitation_frequencies(self, speed):
        return self._orders(self.cylinders, abs(speed) / (2.0 * math.pi), "compressor order")


@_register
@dataclass(frozen=True)
class Schedule(TorqueProfile):
    """On/off schedule: ``active`` profile inside ``periods`` [[start, end], ...] [s], ``inactive`` outside (not
    ``on``/``off``: YAML 1.1 reads those as booleans); e.g. an air compressor loading while the governor asks for air."""

    kind: ClassVar[str] = "schedule"
    active: TorqueProfile = field(default_factory=Constant)
    inactive: TorqueProfile = field(default_factory=Constant)
    periods: tuple = ()
    PLAUSIBLE = {"periods": "time"}

    def __post_init__(self):
        for name in ("active", "inactive"):  # a mapping or a number (constant), as for drive and load
            object.__setattr__(self, name, make_profile(getattr(self, name), f"schedule.{name}"))
        periods = []
        if not isinstance(self.periods, (list, tuple)):
            raise SceneError(f"schedule.periods: expected a list of [start, end], got {short(self.periods)}")
        for p in self.periods:
            if (
                not isinstance(p, (list, tuple)) or len(p) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
                or not (math.isfinite(p[0]) and math.isfinite(p[1])) or not p[1] > p[0]
            ):
                raise SceneError(f"schedule.periods: each period must be [start, end] with end > start, got {short(p)}")
            periods.append((float(p[0]), float(p[1])))
        object.__setattr__(self, "periods", tuple(periods))

    def check_plausible(self, where: str = "profile") -> "Schedule":
        super().check_plausible(where)
        self.active.check_plausible(f"{where}.active")
        self.inactive.check_plausible(f"{where}.inactive")
        return self

    @property
    def state_dependent(self):
        return self.inactive.state_dependent or bool(self.periods) and self.active.state_dependent

    @property
    def uses_angle(self):
        return self.inactive.uses_angle or bool(self.periods) and self.active.uses_angle

    def encode(self, builder):
        # the active part inside a period [start, end), the inactive part outside
        row = builder.reserve()
        offset, n = builder.table([p[0] for p in self.periods], [p[1] for p in self.periods])
        active, inactive = self.active.encode(builder), self.inactive.encode(builder)
        if active is None or inactive is None:
            return None
        builder.fill(row, D.SCHEDULE, offset, n, active, inactive)
        return row

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


class HeldTorque(TorqueProfile):
    """Zero-order hold of a sampled torque [N m] the caller sets (the node's drive input). Mutable on purpose:
    :attr:`value` writes the one number of its kernel data in place, so a stepper built once reads the new value at
    its next call (no object of a higher layer inside the time loop)."""

    kind = "held"
    state_dependent = False
    uses_angle = False

    def __init__(self, value: float = 0.0):
        self._data = D.ProfileBuilder()
        self._data.row(D.CONSTANT, 0.0)
        self._data = self._data.build()
        self.value = value

    @property
    def value(self) -> float:
        """The held torque [N m]."""
        return float(self._data.params[0, 0])

    @value.setter
    def value(self, value: float) -> None:
        self._data.params[0, 0] = float(value)

    def encode(self, builder):
        return builder.row(D.CONSTANT, self.value)

    def data(self) -> D.ProfileData:
        return self._data

    def torque(self, t, angle=0.0, speed=0.0):
        return self.value + 0.0 * np.asarray(t, dtype=float) if np.ndim(t) else self.value

    __call__ = torque

    def scalar_torque(self):
        params = self._data.params
        return lambda t, angle, speed: float(params[0, 0])

    def to_dict(self):
        return {"type": "constant", "value": self.value}


def profile_fields(kind: str) -> frozenset:
    """The keys a profile mapping of type ``kind`` may hold besides ``type`` (empty for an unknown type)."""
    cls = _REGISTRY.get(kind)
    return frozenset(f.name for f in fields(cls)) if cls is not None else frozenset()


def make_profile(spec: Mapping[str, Any] | TorqueProfile | float, where: str = "profile") -> TorqueProfile:
    """Profile from a mapping with a ``type`` key (or a number: constant); :class:`SceneError` naming ``where``, the
    bad key and the valid ones, or a value outside its plausible range (:meth:`TorqueProfile.check_plausible`)."""
    if isinstance(spec, TorqueProfile):
        return spec
    if real(spec) is not None:  # a number: a constant, checked as one from a mapping
        spec = {"type": "constant", "value": spec}
    if not isinstance(spec, Mapping):
        raise SceneError(f"{where}: expected a mapping with a 'type' key or a number, got {type(spec).__name__} {short(spec)}")
    spec = dict(spec)
    kind = spec.pop("type", None)
    if not isinstance(kind, str) or kind not in _REGISTRY:
        raise SceneError(f"{where}.type: unknown profile {short(kind)}; known: {', '.join(sorted(_REGISTRY))}")
    cls = _REGISTRY[kind]
    names = profile_fields(kind)
    unknown = sorted(str(k)[:60] for k in set(spec) - names)
    if unknown:
        raise SceneError(f"{where}.{unknown[0]}: unknown key for type {kind!r}; known: {', '.join(sorted(names))}")
    types = {f.name: str(f.type) for f in fields(cls)}
    for key, value in list(spec.items()):
        if "str" not in types[key] and "TorqueProfile" not in types[key] and _has_text(value):
            raise SceneError(f"{where}.{key}: must be a number (or numbers), got {short(value)}")
        if types[key] in ("float", "float | None", "int") and value is not None:  # (an array is not a number)
            number = plain_number(value, lambda text: SceneError(f"{where}.{key}: {text}"))
            spec[key] = number if types[key] == "int" else float(number)
        if isinstance(value, list):
            spec[key] = tuple(tuple(v) if isinstance(v, list) else v for v in value)
    try:
        profile = cls(**spec)
    except SceneError as exc:
        raise SceneError(f"{where}: {exc}") from None
    except (TypeError, ValueError, OverflowError) as exc:  # (an integer beyond the float range: OverflowError)
        raise SceneError(f"{where} ({kind}): {exc}") from None
    return profile.check_plausible(where)


def _has_text(value, depth: int = 0) -> bool:
    """True when ``value`` (a number or nested lists of numbers) holds a string anywhere."""
    if isinstance(value, (str, bytes)):
        return True
    if isinstance(value, (list, tuple)) and depth < 4:
        return any(_has_text(v, depth + 1) for v in value)
    return False
