"""Scenes: parameters + drive source + load + duration + initial state.

A scene is what one simulation run needs. Scene files are YAML; the package
ships ``paper``, ``truck_compressor`` and ``e_motor_start``
(``belt_drive_ros/scenes/*.yaml``), each with its defaults justified in
``docs/model.md``. :func:`load_scene` accepts a shipped name or a path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from .errors import ParameterError, SceneError
from .integrators import method_class
from .params import BeltDriveParams
from .sources import Constant, TorqueProfile, make_profile

MODELS = ("rigid", "flexible", "slipping", "auto")


@dataclass(frozen=True)
class InitialState:
    """Initial condition: wheel M angle [rad] and speed [rad/s], belt deflection [rad] and its rate [rad/s].

    Wheel 3 starts at ``phi_3 = i phi_M - relative_deflection`` and
    ``omega_3 = i omega_M - relative_speed``.
    """

    phi_M: float = 0.0
    omega_M: float = 0.0
    relative_deflection: float = 0.0
    relative_speed: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise SceneError(f"initial_state.{f.name}: must be a finite number, got {v!r}")
            object.__setattr__(self, f.name, float(v))

    def vector(self, model_name: str, ratio: float) -> np.ndarray:
        """State vector for ``model_name`` (see :mod:`belt_drive_ros.core.model` for the ordering)."""
        if model_name == "rigid":
            return np.array([self.phi_M, self.omega_M])
        if model_name == "slipping":  # [phi_M, theta_e, omega_M, omega_3, s]: no slip yet
            return np.array([self.phi_M, self.relative_deflection, self.omega_M, ratio * self.omega_M - self.relative_speed, 0.0])
        return np.array(
            [
                self.phi_M,
                ratio * self.phi_M - self.relative_deflection,
                self.omega_M,
                ratio * self.omega_M - self.relative_speed,
            ]
        )


@dataclass(frozen=True)
class Scene:
    """Everything one run needs (SI units).

    Attributes
    ----------
    name, description : str
    params : BeltDriveParams
    drive : TorqueProfile on wheel M;  load : TorqueProfile on wheel 3.
    duration : simulated time [s].
    initial_state : InitialState.
    model : ``rigid``, ``flexible``, ``slipping`` (:mod:`belt_drive_ros.core.slip`) or ``auto``
        (see :mod:`belt_drive_ros.core.fidelity`; ``auto`` goes on to ``slipping`` when the
        chosen model's run exceeds the belt's friction limit).
    method : integrator name (:data:`belt_drive_ros.core.integrators.REGISTRY`).
    dt : integrator step [s] (output interval for adaptive methods).
    output_rate : rate [Hz] at which outputs are consumed (node publish or
        recording rate); the ``auto`` choice compares the belt mode with it.
    method_options : extra integrator options (e.g. rtol for scipy methods).
    """

    name: str = "custom"
    description: str = ""
    params: BeltDriveParams = field(default_factory=BeltDriveParams)
    drive: TorqueProfile = field(default_factory=Constant)
    load: TorqueProfile = field(default_factory=Constant)
    duration: float = 1.0
    initial_state: InitialState = field(default_factory=InitialState)
    model: str = "auto"
    method: str = "etd2"
    dt: float = 1e-3
    output_rate: float = 1000.0
    method_options: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        for name in ("duration", "dt", "output_rate"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise SceneError(f"{name}: must be a finite number > 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.model not in MODELS:
            raise SceneError(f"model: must be one of {', '.join(MODELS)}, got {self.model!r}")
        try:
            method_class(self.method)
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        if self.dt > self.duration:
            raise SceneError(f"dt: must not exceed duration ({self.duration} s), got {self.dt}")

    # ------------------------------------------------------------ mapping
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], name: str | None = None) -> "Scene":
        """Scene from a mapping (parsed YAML); errors name the key path."""
        if not isinstance(data, Mapping):
            raise SceneError(f"scene: expected a mapping at the top level, got {type(data).__name__}")
        data = dict(data)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise SceneError(f"scene.{unknown[0]}: unknown key; known keys: {', '.join(sorted(known))}")
        try:
            params = BeltDriveParams.from_mapping(data.pop("params", None))
        except ParameterError as exc:
            raise ParameterError(exc.field, f"{exc.detail} (in scene.params)") from None
        init = data.pop("initial_state", None) or {}
        if not isinstance(init, Mapping):
            raise SceneError("initial_state: expected a mapping")
        bad = sorted(set(init) - {f.name for f in fields(InitialState)})
        if bad:
            raise SceneError(f"initial_state.{bad[0]}: unknown key; known: phi_M, omega_M, relative_deflection, relative_speed")
        drive = make_profile(data.pop("drive", 0.0), "drive")
        load = make_profile(data.pop("load", 0.0), "load")
        if name is not None and "name" not in data:
            data["name"] = name
        data["method_options"] = dict(data.get("method_options") or {})
        return cls(params=params, drive=drive, load=load, initial_state=InitialState(**init), **data)

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping, YAML-ready; ``Scene.from_mapping(s.to_dict()) == s``."""
        return {
            "name": self.name,
            "description": self.description,
            "model": self.model,
            "method": self.method,
            "dt": self.dt,
            "duration": self.duration,
            "output_rate": self.output_rate,
            "method_options": dict(self.method_options),
            "initial_state": {f.name: getattr(self.initial_state, f.name) for f in fields(InitialState)},
            "params": self.params.to_dict(),
            "drive": self.drive.to_dict(),
            "load": self.load.to_dict(),
        }

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    def with_overrides(self, **changes: Any) -> "Scene":
        """Copy with top-level fields replaced (``None`` values are ignored)."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})


def shipped_scenes() -> list[str]:
    """Names of the scenes shipped in the package."""
    folder = resources.files("belt_drive_ros") / "scenes"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_scene(name_or_path: str | Path) -> Scene:
    """Scene by shipped name (``paper``) or by path to a YAML file."""
    text: str
    label = str(name_or_path)
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.exists():
            raise SceneError(f"scene file not found: {path}")
        text, default_name = path.read_text(), path.stem
    else:
        resource = resources.files("belt_drive_ros") / "scenes" / f"{label}.yaml"
        if not resource.is_file():
            raise SceneError(
                f"unknown scene {label!r}: not a file and not a shipped scene ({', '.join(shipped_scenes())})"
            )
        text, default_name = resource.read_text(), label
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SceneError(f"{label}: not valid YAML: {str(exc).splitlines()[0]}") from None
    return Scene.from_mapping(data, name=default_name)
