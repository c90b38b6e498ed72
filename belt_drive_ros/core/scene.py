"""Scenes: parameters, drive, load, duration, initial state: what one run needs (the shipped ones'
defaults are justified in ``docs/model.md``; :func:`belt_drive_ros.io.scenes.load_scene` reads a file).
"""

from __future__ import annotations

import copy
import inspect
import math
import threading
from dataclasses import dataclass, field, fields, is_dataclass, replace
from importlib import resources
from typing import Any, Callable, Mapping

import numpy as np

from .errors import ParameterError, SceneError, real, short, unknown_key
from .integrators import method_class
from .params import OPTIONAL_DEFAULTS, BeltDriveParams
from .sources import SPEED_MAX, Constant, TorqueProfile, make_profile

MODELS = ("rigid", "flexible", "slipping", "auto")
#: models whose runs carry the slip outputs (span forces, friction use, slip state and speed, slip angle)
SLIP_MODELS = ("slipping",)
#: keys a scene must state unless it ``extends`` a shipped scene (every parameter too, but the
#: optional belt fields of :data:`~belt_drive_ros.core.params.OPTIONAL_DEFAULTS`)
REQUIRED_KEYS = ("params", "drive", "load", "duration", "dt")
#: plausible ranges (SI units) of the scene's time settings: a step below 0.1 us is below any
#: clock the node or a recording can represent, a 1 s step resolves no belt mode; an output rate
#: above 1 MHz is no consumer's; 1e7 s (116 days) is beyond any run this package is meant for
RANGES: dict[str, tuple[float, float, str]] = {
    "dt": (1.0e-7, 1.0, "s"),
    "duration": (1.0e-6, 1.0e7, "s"),
    "output_rate": (1.0e-3, 1.0e6, "Hz"),
    # accuracy the guard and method: auto aim at, relative to each signal's peak: below 1e-12 is rounding,
    # above 0.5 no accuracy at all
    "tolerance": (1.0e-12, 0.5, "of the peak"),
}
#: default ``tolerance``: relative error of drive speed and belt torque (to their peaks) the guard aims at
TOLERANCE_DEFAULT = 1e-4
#: the method name that lets the accuracy guard choose method and step (:mod:`belt_drive_ros.core.method_choice`)
AUTO_METHOD = "auto"
#: largest initial angle [rad]: a double resolves 1e9 rad to 1.2e-7 rad (1e20 rad to 16 kilo-radians: every
#: harmonic of the crank angle frozen); a wheel at 1e4 rad/s needs a day to turn that far
ANGLE_MAX = 1.0e9
#: most steps one run may take (duration / dt): ~1e9 steps is hours of computation already
MAX_STEPS = 1.0e9
#: most steps a scipy (adaptive) method's ``max_step`` may force (duration / max_step): its steps run in Python,
#: ~10-50 us each, so 1e7 is minutes to hours
ADAPTIVE_MAX_STEPS = 1.0e7


def _finite(v) -> float | None:
    """``v`` as a finite float if it is a real number (numpy scalars too, never a bool), else None."""
    v = real(v)
    try:
        return float(v) if v is not None and math.isfinite(v) else None
    except OverflowError:  # an integer beyond the float range
        return None


def _check_options(method: str, cls: type, options: Mapping) -> None:
    """``options`` against the keyword options of ``method``'s class (scipy's rtol, atol, max_step; the
    trapezoidal rule's tol, max_iter): known names, numbers > 0. A class taking ``**options`` checks its own."""
    params = inspect.signature(cls.__init__).parameters
    if not options or any(p.kind is p.VAR_KEYWORD for p in params.values()):
        return
    known = [n for n, p in params.items() if p.default is not p.empty]
    for key, value in options.items():
        if key not in known:
            raise SceneError(f"method_options.{str(key)[:60]}: not an option of {method} (its options: {', '.join(known)})")
        v = real(value)
        if v is None or not v > 0:
            raise SceneError(f"method_options.{key}: must be a number > 0, got {type(value).__name__} {short(value)}")


@dataclass(frozen=True)
class InitialState:
    """Initial condition: wheel M angle [rad] and speed [rad/s], belt deflection [rad] and its rate [rad/s]:
    wheel 3 starts at ``phi_3 = i phi_M - relative_deflection``, ``omega_3 = i omega_M - relative_speed`` (the rigid
    model has no deflection: its wheel 3 starts at ``i phi_M``, ``i omega_M``; ``belt-drive sim`` warns)."""

    phi_M: float = 0.0
    omega_M: float = 0.0
    relative_deflection: float = 0.0
    relative_speed: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            x = _finite(v)
            if x is None:
                raise SceneError(f"initial_state.{f.name}: must be a finite number, got {type(v).__name__} {short(v)}")
            if f.name in ("omega_M", "relative_speed") and abs(x) > SPEED_MAX:  # (beyond it every run diverges)
                raise SceneError(f"initial_state.{f.name}: {x:g} rad/s is outside the plausible range "
                                 f"[-{SPEED_MAX:g}, {SPEED_MAX:g}] rad/s")
            if f.name in ("phi_M", "relative_deflection") and abs(x) > ANGLE_MAX:
                raise SceneError(f"initial_state.{f.name}: {x:g} rad is outside the plausible range "
                                 f"[-{ANGLE_MAX:g}, {ANGLE_MAX:g}] rad (beyond it a double cannot resolve the angle a "
                                 "torque's harmonics read)")
            object.__setattr__(self, f.name, x)

    def vector(self, model_name: str, ratio: float) -> np.ndarray:
        """State vector for ``model_name`` (see :mod:`belt_drive_ros.core.model` for the ordering)."""
        if model_name == "rigid":
            return np.array([self.phi_M, self.omega_M])
        if model_name == "slipping":  # [phi_M, theta_e, omega_M, omega_3, s]: no slip yet
            return np.array([self.phi_M, self.relative_deflection, self.omega_M, ratio * self.omega_M - self.relative_speed, 0.0])
        return np.array([self.phi_M, self.relative_deflection, self.omega_M, ratio * self.omega_M - self.relative_speed])


@dataclass(frozen=True)
class Scene:
    """Everything one run needs (SI units): ``drive`` torque on wheel M, ``load`` on wheel 3, ``duration`` [s];
    ``model`` rigid, flexible, slipping or ``auto`` (:mod:`~.fidelity`); ``method`` a name of
    :data:`~.integrators.REGISTRY` or ``auto`` (:mod:`~.method_choice`), ``dt`` its step [s] (the output interval
    of adaptive methods), ``method_options`` (e.g. rtol); ``output_rate`` [Hz] the rate outputs are consumed at
    (node, recording); ``tolerance`` [-] the relative error of drive speed and belt torque the guard checks."""

    name: str = "custom"
    description: str = ""
    params: BeltDriveParams = field(default_factory=BeltDriveParams)
    drive: TorqueProfile = field(default_factory=Constant)
    load: TorqueProfile = field(default_factory=Constant)
    duration: float = 1.0
    initial_state: InitialState = field(default_factory=InitialState)
    model: str = "auto"
    method: str = AUTO_METHOD
    dt: float = 1e-3
    output_rate: float = 1000.0
    method_options: Mapping[str, Any] = field(default_factory=dict)
    tolerance: float = TOLERANCE_DEFAULT

    def __post_init__(self):
        for name, (low, high, unit) in RANGES.items():
            v = getattr(self, name)
            x = _finite(v)
            if x is None or x <= 0:
                raise SceneError(f"{name}: must be a finite number > 0, got {type(v).__name__} {short(v)}")
            v = x
            if not low <= v <= high:
                raise SceneError(f"{name}: {v:g} {unit} is outside the plausible range [{low:g}, {high:g}] {unit}")
            object.__setattr__(self, name, v)
        for name, kind in (("params", BeltDriveParams), ("drive", TorqueProfile), ("load", TorqueProfile),
                           ("initial_state", InitialState)):
            v = getattr(self, name)
            if not isinstance(v, kind):
                raise SceneError(f"{name}: expected {kind.__name__}, got {type(v).__name__} {short(v)}")
        for name in ("name", "description", "model", "method"):
            v = getattr(self, name)
            if not isinstance(v, str):
                raise SceneError(f"{name}: must be a string, got {type(v).__name__} {short(v)}")
        if not isinstance(self.method_options, Mapping):
            raise SceneError(
                f"method_options: expected a mapping of option: number, got {type(self.method_options).__name__} "
                f"{short(self.method_options)}"
            )
        steps = self.duration / self.dt
        if steps > MAX_STEPS:
            raise SceneError(
                f"duration: {self.duration:g} s at dt = {self.dt:g} s is {steps:.3g} steps, more than the "
                f"{MAX_STEPS:.0e} one run may take; shorten the run or lengthen the step"
            )
        if self.model not in MODELS:
            raise SceneError(f"model: must be one of {', '.join(MODELS)}, got {short(self.model)}")
        try:
            if self.method != AUTO_METHOD:
                _check_options(self.method, method_class(self.method), self.method_options)
        except ValueError as exc:
            if isinstance(exc, SceneError):
                raise
            raise SceneError(f"{exc} (or {AUTO_METHOD!r}: chosen by accuracy)") from None
        if self.dt > self.duration:
            raise SceneError(f"dt: must not exceed duration ({self.duration} s), got {self.dt}")
        max_step = _finite(self.method_options.get("max_step")) if self.method != AUTO_METHOD else None
        if max_step and not method_class(self.method).fixed_step and self.duration / max_step > ADAPTIVE_MAX_STEPS:
            raise SceneError(
                f"method_options.max_step: {max_step:g} s forces {self.method} to at least {self.duration / max_step:.3g} "
                f"steps over {self.duration:g} s, more than {ADAPTIVE_MAX_STEPS:.0e} (its solver steps in Python, ~10-50 us "
                "a step); raise max_step or use a fixed-step method"
            )

    # ------------------------------------------------------------ mapping
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], name: str | None = None,
                     shipped: Callable[[str], "Scene"] | None = None) -> "Scene":
        """Scene from a mapping (parsed YAML); errors name the key path. The mapping states :data:`REQUIRED_KEYS`
        and every required parameter, or ``extends: NAME`` (a shipped scene, ``shipped(NAME)`` its Scene:
        :func:`belt_drive_ros.io.scenes.scene_from_mapping`) and gives only what differs (:func:`_extended`:
        ``params``, ``initial_state``, ``method_options`` merged key by key; new torques without a ``method``
        get ``method: auto``)."""
        if not isinstance(data, Mapping):
            raise SceneError(f"scene: expected a mapping at the top level, got {type(data).__name__} {short(data)}")
        data = dict(data)
        known = {f.name for f in fields(cls)} | {"extends"}
        unknown = unknown_key(data, known)
        if unknown:
            raise SceneError(f"scene.{unknown}: unknown key; known keys: {', '.join(sorted(known))}")
        if "extends" in data:
            data = _extended(data, shipped)
        else:
            missing = [k for k in REQUIRED_KEYS if k not in data]
            if missing:
                raise SceneError(
                    f"scene: missing required key {missing[0]!r}; a scene states {', '.join(REQUIRED_KEYS)} "
                    f"or extends a shipped scene ('extends: paper', then only what differs)"
                )
            for key in REQUIRED_KEYS:
                if data[key] is None:
                    raise SceneError(f"{key}: is empty (null); state it or extend a shipped scene")
            params = data["params"]
            if isinstance(params, Mapping):
                required = [f.name for f in fields(BeltDriveParams) if f.name not in OPTIONAL_DEFAULTS]
                absent = [k for k in required if k not in params]
                if absent:
                    raise ParameterError(
                        absent[0], f"missing (in scene.params); a scene states every parameter "
                        f"({', '.join(absent)} missing) or extends a shipped scene"
                    )
        for key in ("params", "initial_state", "method_options"):
            value = data.get(key)
            if value is not None and not isinstance(value, Mapping):
                raise SceneError(f"{key}: expected a mapping, got {type(value).__name__} {short(value)}")
        try:
            params = BeltDriveParams.from_mapping(data.pop("params", None)).check_plausible()
        except ParameterError as exc:
            raise ParameterError(exc.field, f"{exc.detail} (in scene.params)") from None
        init = data.pop("initial_state", None) or {}
        bad = unknown_key(init, [f.name for f in fields(InitialState)])
        if bad:
            raise SceneError(f"initial_state.{bad}: unknown key; known: phi_M, omega_M, relative_deflection, relative_speed")
        drive = make_profile(data.pop("drive", 0.0), "drive")
        load = make_profile(data.pop("load", 0.0), "load")
        if name is not None and "name" not in data:
            data["name"] = name
        options = dict(data.get("method_options") or {})
        for key, value in options.items():
            if real(value) is None:
                raise SceneError(f"method_options.{str(key)[:60]}: must be a number, got {type(value).__name__} {short(value)}")
        data["method_options"] = options
        params, drive, load = _shared(params), _shared(drive), _shared(load)
        return cls(params=params, drive=drive, load=load, initial_state=InitialState(**init), **data)

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping, YAML-ready (:func:`belt_drive_ros.io.scenes.scene_yaml`); ``Scene.from_mapping(s.to_dict()) == s``."""
        return {
            "name": self.name,
            "description": self.description,
            "model": self.model,
            "method": self.method,
            "dt": self.dt,
            "duration": self.duration,
            "output_rate": self.output_rate,
            "method_options": dict(self.method_options),
            **({"tolerance": self.tolerance} if self.tolerance != TOLERANCE_DEFAULT else {}),
            "initial_state": {f.name: getattr(self.initial_state, f.name) for f in fields(InitialState)},
            "params": self.params.to_dict(),
            "drive": self.drive.to_dict(),
            "load": self.load.to_dict(),
        }

    def with_overrides(self, **changes: Any) -> "Scene":
        """Copy with top-level fields replaced (``None`` values are ignored)."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    def with_params(self, params: BeltDriveParams) -> "Scene":
        """Copy with other parameters (a campaign's variant): nothing of :meth:`__post_init__` reads them and
        they validated themselves, so the copy skips re-checking (a sweep builds thousands of these)."""
        if not isinstance(params, BeltDriveParams):
            raise SceneError(f"params: expected BeltDriveParams, got {type(params).__name__} {short(params)}")
        scene = copy.copy(self)
        object.__setattr__(scene, "params", params)
        return scene


#: parameter sets and torque profiles of scenes read from mappings, by their values: a scene read again (a new
#: ``Scene`` of the same file) holds the very objects an earlier one held, so what the core built from them by
#: identity (models, plants, steppers, kernel loops: :mod:`~belt_drive_ros.core.identity_cache`) is built once
_SHARED: dict = {}
_SHARED_LOCK = threading.Lock()
#: entries kept (the oldest dropped)
SHARED_SIZE = 32
#: longest tuple field of a profile (a table's points) that is compared by value; a longer one is never shared
SHARED_TUPLE_MAX = 4096


def _shared(obj):
    """``obj`` (frozen :class:`BeltDriveParams` or torque profile) or the earlier one of the very same values: the same
    class and every field the same, a float to the bit (``float.hex``: signed zeros apart; NaN never shared), an int,
    text or None equal and of the same type, tuples and nested profiles field by field. Any other field (an array, a
    mutable profile) leaves ``obj`` its own. Both objects are frozen, so which of the two a scene holds changes
    nothing it computes."""
    key = _value_key(obj, 0)
    if key is None:
        return obj
    with _SHARED_LOCK:  # (scenes may be read in several threads: a campaign's workers)
        hit = _SHARED.get(key)
        if hit is not None:
            return hit
        if len(_SHARED) >= SHARED_SIZE:
            _SHARED.pop(next(iter(_SHARED)))
        _SHARED[key] = obj
    return obj


def _value_key(v, depth: int):
    """A hashable key of ``v``'s exact value for :func:`_shared` (None: not compared by value)."""
    t = type(v)
    if t is float:
        return None if v != v else ("f", v.hex())
    if v is None or t in (int, bool, str):
        return (t.__name__, v)
    if depth > 4:
        return None
    if t is tuple:
        if len(v) > SHARED_TUPLE_MAX:
            return None
        keys = tuple(_value_key(x, depth + 1) for x in v)
        return None if None in keys else ("t", keys)
    if is_dataclass(v) and t.__dataclass_params__.frozen and isinstance(v, (BeltDriveParams, TorqueProfile)):
        keys = tuple(_value_key(getattr(v, f.name), depth + 1) for f in fields(v))
        return None if None in keys else (t, keys)
    return None


def shipped_scenes(folder: str = "") -> list[str]:
    """Names of the scenes shipped in the package (``belt_drive_ros/scenes``; network scenes: ``folder="networks"``)."""
    return sorted(p.name[:-5] for p in (resources.files("belt_drive_ros") / "scenes" / folder).iterdir()
                  if p.name.endswith(".yaml"))


def _extended(data: dict, shipped: Callable[[str], Scene] | None) -> dict:
    """``data`` merged into the shipped scene it ``extends`` (see :meth:`Scene.from_mapping`)."""
    base_name = data.pop("extends")
    names = shipped_scenes()
    if not isinstance(base_name, str) or base_name not in names:
        raise SceneError(f"extends: must name a shipped scene ({', '.join(names)}), got {short(base_name)}")
    if shipped is None:
        raise SceneError("extends: a scene that extends another is read by belt_drive_ros.io.scenes")
    merged = shipped(base_name).to_dict()
    merged["description"] = f"{base_name} with changes"
    del merged["name"]  # the file's own name, unless it states one
    if ("drive" in data or "load" in data) and "method" not in data:
        # the base's method and its options were chosen for the base's torques: new torques get the method
        # chosen for them (method: auto, at the inherited dt), unless the file states one
        merged["method"], merged["method_options"] = AUTO_METHOD, {}
    for key, value in data.items():
        if key in ("params", "initial_state", "method_options"):
            if not isinstance(value, Mapping):
                raise SceneError(f"{key}: expected a mapping, got {type(value).__name__} {short(value)}")
            merged[key] = {**merged[key], **value}
        else:
            merged[key] = value
    return merged
