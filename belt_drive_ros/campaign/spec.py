"""The campaign file: a base scene and what varies, and the variants it expands to.

A campaign is YAML (docs/campaigns.md)::

    name: paper_tolerances
    scene: paper                 # shipped scene name or a path (relative to this file)
    set: {model: auto}           # optional overrides of the base scene (any scene key path)
    grid:                        # a full factorial over key paths
      params.k: [1.5e4, 2.0e4, 2.5e4]
    profiles:                    # a list of drive and/or load profiles (each one variant axis point)
      - {drive: {type: motor, stall_torque: 12.0, no_load_speed: 160.0, soft_start_time: 0.02}}
    monte_carlo:                 # tolerances: `samples` draws per grid point and profile
      samples: 1000
      seed: 1
      vary:
        params.k: {normal: 0.05}          # relative standard deviation about the base value
        params.I_3: {uniform: [0.9, 1.1]} # relative bounds
        params.F_0: {normal: [400.0, 20.0], absolute: true}
    fleet:                       # instead of the above: every torque recording in a folder
      folder: recordings/        # MCAP files with /drive_torque (std_msgs/Float64)
      golden: golden/            # optional: outputs to compare against, same file names
    metrics: [peak_belt_torque, min_slack_force, peak_friction_use]   # default: all
    limits: {min_slack_force: 0.0, peak_friction_use: 1.0}          # drawn on the histograms

A key path names a scene field: ``params.NAME`` (a bare ``NAME`` of
:data:`~belt_drive_ros.core.params.FIELD_DOCS` means the same),
``drive.FIELD``, ``load.FIELD``, ``initial_state.FIELD``, or a top-level
key (``dt``, ``method``, ``model``, ``duration``). The variants are the
product grid x profiles x samples, numbered from 0 in that order; the
variant table (:meth:`Campaign.variants`) holds each one's varied values,
so a campaign and its seed give the same table on every machine.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from ..core.errors import BeltDriveError
from ..core.params import FIELD_DOCS
from ..core.scene import Scene, load_scene
from ..core.sources import make_profile
from .metrics import DEFAULT_LIMITS, METRICS

KEYS = ("name", "description", "scene", "set", "grid", "profiles", "monte_carlo", "fleet", "metrics", "limits")
TOP_LEVEL = ("model", "method", "dt", "duration", "output_rate")


class CampaignError(BeltDriveError, ValueError):
    """A campaign file is malformed (the message names the key)."""


def _path_of(key: str) -> tuple:
    """Canonical key path: ``k`` -> ``("params", "k")``; errors name the key."""
    parts = tuple(str(key).split("."))
    if len(parts) == 1:
        if parts[0] in FIELD_DOCS:
            return ("params", parts[0])
        if parts[0] in TOP_LEVEL:
            return parts
    elif len(parts) == 2 and parts[0] in ("params", "drive", "load", "initial_state"):
        if parts[0] == "params" and parts[1] not in FIELD_DOCS:
            raise CampaignError(f"{key}: unknown parameter; known: {', '.join(FIELD_DOCS)}")
        return parts
    raise CampaignError(
        f"{key}: not a key path; use params.NAME (or NAME), drive.FIELD, load.FIELD, initial_state.FIELD "
        f"or one of {', '.join(TOP_LEVEL)}"
    )


@dataclass(frozen=True)
class Distribution:
    """A tolerance: normal or uniform, relative to the base value unless ``absolute``."""

    kind: str
    a: float
    b: float
    absolute: bool

    @classmethod
    def parse(cls, key: str, spec: Any) -> "Distribution":
        if not isinstance(spec, Mapping):
            raise CampaignError(f"monte_carlo.vary.{key}: expected {{normal: ...}} or {{uniform: ...}}")
        kinds = [k for k in ("normal", "uniform") if k in spec]
        unknown = sorted(set(spec) - {"normal", "uniform", "absolute"})
        if len(kinds) != 1 or unknown:
            raise CampaignError(f"monte_carlo.vary.{key}: give exactly one of normal, uniform (and optionally absolute)")
        kind, value = kinds[0], spec[kinds[0]]
        absolute = bool(spec.get("absolute", False))
        if kind == "normal":
            if isinstance(value, (int, float)) and not absolute:
                a, b = 1.0, float(value)  # relative standard deviation about the base value
            elif isinstance(value, (list, tuple)) and len(value) == 2:
                a, b = float(value[0]), float(value[1])
            else:
                raise CampaignError(f"monte_carlo.vary.{key}.normal: a relative std, or [mean, std]")
            if not b >= 0:
                raise CampaignError(f"monte_carlo.vary.{key}.normal: std must be >= 0, got {b}")
        else:
            if not (isinstance(value, (list, tuple)) and len(value) == 2):
                raise CampaignError(f"monte_carlo.vary.{key}.uniform: [low, high]")
            a, b = float(value[0]), float(value[1])
            if not b >= a:
                raise CampaignError(f"monte_carlo.vary.{key}.uniform: high must be >= low, got [{a}, {b}]")
        if not (math.isfinite(a) and math.isfinite(b)):
            raise CampaignError(f"monte_carlo.vary.{key}: values must be finite")
        return cls(kind, a, b, absolute)

    def sample(self, rng: np.random.Generator, base: float, size: int) -> np.ndarray:
        """``size`` draws [unit of the field]: normal(mean, std) or uniform(low, high), times ``base`` when relative."""
        x = rng.normal(self.a, self.b, size) if self.kind == "normal" else rng.uniform(self.a, self.b, size)
        return x if self.absolute else base * x


@dataclass
class Campaign:
    """A parsed campaign file (see the module docstring)."""

    name: str
    base: Scene
    base_mapping: dict
    grid: dict = field(default_factory=dict)
    profiles: list = field(default_factory=list)
    samples: int = 0
    seed: int = 0
    vary: dict = field(default_factory=dict)
    fleet_folder: Path | None = None
    golden_folder: Path | None = None
    metrics: tuple = tuple(METRICS)
    limits: dict = field(default_factory=lambda: dict(DEFAULT_LIMITS))
    text: str = ""

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(cls, path) -> "Campaign":
        """Parse a campaign file; every error names the key."""
        path = Path(path)
        if not path.is_file():
            raise CampaignError(f"campaign file not found: {path}")
        text = path.read_text()
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise CampaignError(f"{path}: not valid YAML: {str(exc).splitlines()[0]}") from None
        return cls.from_mapping(data, base_dir=path.parent, text=text)

    @classmethod
    def from_mapping(cls, data: Mapping, base_dir=".", text: str | None = None) -> "Campaign":
        if not isinstance(data, Mapping):
            raise CampaignError("campaign: expected a mapping at the top level")
        unknown = sorted(set(data) - set(KEYS))
        if unknown:
            raise CampaignError(f"{unknown[0]}: unknown key; known keys: {', '.join(KEYS)}")
        base_dir = Path(base_dir)
        scene_ref = data.get("scene")
        if not scene_ref:
            raise CampaignError("scene: a shipped scene name or a scene file is required")
        if isinstance(scene_ref, Mapping):  # inline (what a worker receives)
            base = Scene.from_mapping(scene_ref)
        else:
            candidate = base_dir / str(scene_ref)
            base = load_scene(candidate if candidate.suffix in (".yaml", ".yml") else scene_ref)
        mapping = base.to_dict()
        for key, value in (data.get("set") or {}).items():
            _assign(mapping, _path_of(key), value)
        base = Scene.from_mapping(mapping)
        grid = {}
        for key, values in (data.get("grid") or {}).items():
            if not isinstance(values, (list, tuple)) or not values:
                raise CampaignError(f"grid.{key}: a non-empty list of values")
            grid[".".join(_path_of(key))] = list(values)
        profiles = list(data.get("profiles") or [])
        for j, entry in enumerate(profiles):
            if not isinstance(entry, Mapping) or not entry or set(entry) - {"drive", "load"}:
                raise CampaignError(f"profiles[{j}]: a mapping with drive and/or load")
            for role, spec in entry.items():
                make_profile(spec, role)  # validated here, by the profile's own rules
        mc = data.get("monte_carlo") or {}
        bad = sorted(set(mc) - {"samples", "seed", "vary"})
        if bad:
            raise CampaignError(f"monte_carlo.{bad[0]}: unknown key; known: samples, seed, vary")
        samples = int(mc.get("samples", 0) or 0)
        if mc and samples < 1:
            raise CampaignError("monte_carlo.samples: must be >= 1")
        vary = {".".join(_path_of(k)): Distribution.parse(k, v) for k, v in (mc.get("vary") or {}).items()}
        if mc and not vary:
            raise CampaignError("monte_carlo.vary: name at least one key path and its distribution")
        fleet = data.get("fleet")
        fleet_folder = golden = None
        if fleet is not None:
            if not isinstance(fleet, Mapping) or "folder" not in fleet or set(fleet) - {"folder", "golden"}:
                raise CampaignError("fleet: a mapping with folder (and optionally golden)")
            if grid or profiles or mc:
                raise CampaignError("fleet: a fleet campaign has no grid, profiles or monte_carlo")
            fleet_folder = (base_dir / str(fleet["folder"])).resolve()
            if not fleet_folder.is_dir():
                raise CampaignError(f"fleet.folder: not a folder: {fleet_folder}")
            if fleet.get("golden"):
                golden = (base_dir / str(fleet["golden"])).resolve()
                if not golden.is_dir():
                    raise CampaignError(f"fleet.golden: not a folder: {golden}")
        metrics = tuple(data.get("metrics") or METRICS)
        for name in metrics:
            if name not in METRICS:
                raise CampaignError(f"metrics: unknown metric {name!r}; known: {', '.join(METRICS)}")
        limits = dict(DEFAULT_LIMITS)
        for name, value in (data.get("limits") or {}).items():
            if name not in METRICS:
                raise CampaignError(f"limits.{name}: not a metric; known: {', '.join(METRICS)}")
            limits[name] = float(value)
        if text is None:
            text = yaml.safe_dump(dict(data), sort_keys=True)
        return cls(
            name=str(data.get("name") or base.name), base=base, base_mapping=mapping, grid=grid, profiles=profiles,
            samples=samples, seed=int(mc.get("seed", 0) or 0), vary=vary, fleet_folder=fleet_folder,
            golden_folder=golden, metrics=metrics, limits=limits, text=text,
        )  # fmt: skip

    # ------------------------------------------------------------------ variants
    def fleet_files(self) -> list[Path]:
        """The fleet's recordings (``*.mcap`` in the folder, sorted by name)."""
        return sorted(p for p in self.fleet_folder.iterdir() if p.suffix == ".mcap") if self.fleet_folder else []

    def variants(self):
        """The variant table: one row per variant, a column per varied key path (a pandas DataFrame).

        Fleet campaigns have one column, ``recording`` (file name). Others:
        the grid's key paths, ``profile`` (index into ``profiles``) when
        profiles are listed, and the Monte Carlo key paths; ``variant`` is
        the row number. Monte Carlo draws come from one
        ``numpy.random.default_rng(seed)``, key by key in file order, so
        the table is reproducible.
        """
        import pandas as pd

        if self.fleet_folder is not None:
            files = self.fleet_files()
            return pd.DataFrame({"variant": np.arange(len(files)), "recording": [p.name for p in files]})
        points = list(itertools.product(*self.grid.values())) if self.grid else [()]
        profiles = list(range(len(self.profiles))) if self.profiles else [None]
        samples = self.samples if self.vary else 1
        n = len(points) * len(profiles) * samples
        columns: dict = {"variant": np.arange(n)}
        combos = list(itertools.product(points, profiles))
        for j, key in enumerate(self.grid):
            columns[key] = np.repeat([c[0][j] for c in combos], samples)
        if self.profiles:
            columns["profile"] = np.repeat([c[1] for c in combos], samples)
        rng = np.random.default_rng(self.seed)
        for key, dist in self.vary.items():
            base = _lookup(self.base_mapping, tuple(key.split(".")))
            if not dist.absolute and not isinstance(base, (int, float)):
                raise CampaignError(f"monte_carlo.vary.{key}: relative tolerance needs a numeric base value, got {base!r}")
            columns[key] = dist.sample(rng, float(base or 0.0), n)
        return pd.DataFrame(columns)

    def scene_of(self, row: Mapping) -> Scene:
        """The scene of one variant (a row of :meth:`variants`); invalid values raise the scene's own error.

        Variants share the base scene's profile objects unless their drive or
        load changes (equal profiles are shared too, :func:`_profile`): a
        profile compiles its formula once, and variants with one profile can
        run in one ensemble.
        """
        if self.fleet_folder is not None:
            from ..io.torque_bag import scene_with_torque_bag

            return scene_with_torque_bag(self.base, self.fleet_folder / str(row["recording"]))
        parts: dict = {"params": {}, "initial_state": {}, "drive": {}, "load": {}, "top": {}}
        roles = {}
        profile = row.get("profile")
        if profile is not None and not (isinstance(profile, float) and math.isnan(profile)):
            roles = dict(self.profiles[int(profile)])
        for key, value in row.items():
            if key in ("variant", "profile"):
                continue
            value = value.item() if hasattr(value, "item") else value
            path = key.split(".")
            parts["top" if len(path) == 1 else path[0]][path[-1]] = value
        changes = {k: v for k, v in parts["top"].items()}
        if parts["params"]:
            changes["params"] = self.base.params.replace(**parts["params"])
        if parts["initial_state"]:
            changes["initial_state"] = dataclasses.replace(self.base.initial_state, **parts["initial_state"])
        for role in ("drive", "load"):
            if role in roles or parts[role]:
                spec = dict(roles.get(role) or self.base_mapping[role])
                spec.update(parts[role])
                changes[role] = _profile(spec, role)
        if set(changes) == {"params"}:  # a tolerance sweep: only the (self-validating) parameters change
            return self.base.with_params(changes["params"])
        return dataclasses.replace(self.base, **changes) if changes else self.base

    def digest(self) -> str:
        """Identity of the campaign (its file text and base scene): a resumed run must match it."""
        blob = json.dumps([self.text, self.base_mapping], sort_keys=True, default=str)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


_PROFILES: dict = {}


def _profile(spec: Mapping, role: str):
    """``make_profile(spec, role)``, one object per distinct spec in this process (its formula compiles once)."""
    key = (role, json.dumps(spec, sort_keys=True, default=str))
    found = _PROFILES.get(key)
    if found is None:
        if len(_PROFILES) >= 1024:
            _PROFILES.clear()
        found = _PROFILES[key] = make_profile(spec, role)
    return found


def _lookup(mapping: Mapping, path: tuple):
    node = mapping
    for part in path:
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return node


def _assign(mapping: dict, path: tuple, value) -> None:
    """Set ``mapping[path]`` (scene mapping), creating the inner mapping when needed."""
    node = mapping
    for part in path[:-1]:
        inner = node.get(part)
        if not isinstance(inner, dict):
            inner = node[part] = {}
        node = inner
    node[path[-1]] = value
