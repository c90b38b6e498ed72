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
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from ..core.errors import BeltDriveError, InputError, real, short, unknown_key
from ..io.inputs import MAX_DEPTH, check_path, parse_yaml, read_text
from .values import boolean, number, sequence
from .values import mapping as as_mapping
from .values import text as string
from ..core.params import FIELD_DOCS
from ..core.scene import InitialState, Scene
from ..io.scenes import is_network, load_scene, scene_from_mapping, shipped_networks, shipped_scenes
from ..core.sources import make_profile, profile_fields
from .metrics import DEFAULT_LIMITS, METRICS

KEYS = ("name", "description", "scene", "set", "grid", "profiles", "monte_carlo", "fleet", "metrics", "limits")
TOP_LEVEL = ("model", "method", "dt", "duration", "output_rate")


class CampaignError(BeltDriveError, ValueError):
    """A campaign file is malformed (the message names the key)."""


#: largest campaign file [bytes]: a campaign is a page of YAML (profiles inline included)
CAMPAIGN_LIMIT = 1 << 20
#: most variants one campaign may hold (:mod:`.limits` refuses more with an estimate of their time and memory)
MAX_VARIANTS = 1_000_000
#: largest ``monte_carlo.seed`` (numpy's generators take any non-negative integer; YAML's stop at 2^63)
MAX_SEED = 2**63


def _path_of(key, where: str = "") -> tuple:
    """Canonical key path: ``k`` -> ``("params", "k")``; errors name the key (under ``where``)."""
    label = f"{where}{short(key, 60) if not isinstance(key, str) else key[:80]}"
    if not isinstance(key, str):
        raise CampaignError(f"{label}: a key path must be text (params.NAME, drive.FIELD, ...)")
    parts = tuple(key.split("."))
    if len(parts) == 1:
        if parts[0] in FIELD_DOCS:
            return ("params", parts[0])
        if parts[0] in TOP_LEVEL:
            return parts
    elif len(parts) == 2 and parts[0] in ("params", "drive", "load", "initial_state"):
        if parts[0] == "params" and parts[1] not in FIELD_DOCS:
            raise CampaignError(f"{label}: unknown parameter; known: {', '.join(FIELD_DOCS)}")
        if parts[1]:
            return parts
    raise CampaignError(
        f"{label}: not a key path; use params.NAME (or NAME), drive.FIELD, load.FIELD, initial_state.FIELD "
        f"or one of {', '.join(TOP_LEVEL)}"
    )


def _check_field(key: str, where: str, mapping: Mapping, profiles: list) -> None:
    """Refuse a varied ``drive.FIELD``, ``load.FIELD`` or ``initial_state.FIELD`` that no variant's scene has
    (the base scene's profile, or each listed profile of that role): every variant would fail alike."""
    section, _, name = key.partition(".")
    if section == "initial_state":
        known = {f.name for f in dataclasses.fields(InitialState)}
        if name not in known:
            raise CampaignError(f"{where}{key}: unknown initial state; known: {', '.join(sorted(known))}")
    elif section in ("drive", "load"):
        for spec in [entry.get(section, mapping[section]) for entry in profiles] or [mapping[section]]:
            kind = spec.get("type") if isinstance(spec, Mapping) else "constant"
            known = profile_fields(kind)
            if name not in known:
                raise CampaignError(f"{where}{key}: unknown key for a {kind!r} {section} profile; "
                                    f"known: {', '.join(sorted(known))}")


def _key_paths(entries: Mapping, where: str) -> list:
    """``(canonical key path, key as given, value)`` of a mapping of key paths; ``k`` and ``params.k`` both
    given is an error."""
    out, given = [], {}
    for key, value in entries.items():
        path = ".".join(_path_of(key, where))
        if path in given:
            raise CampaignError(f"{where}{path}: given twice (as {given[path]} and {key})")
        given[path] = key
        out.append((path, key, value))
    return out


@dataclass(frozen=True)
class Distribution:
    """A tolerance: normal or uniform, relative to the base value unless ``absolute``."""

    kind: str
    a: float
    b: float
    absolute: bool

    @classmethod
    def parse(cls, key: str, spec: Any) -> "Distribution":
        where = f"monte_carlo.vary.{key}"
        if not isinstance(spec, Mapping):
            raise CampaignError(f"{where}: expected {{normal: ...}} or {{uniform: ...}}, got {type(spec).__name__} {short(spec)}")
        kinds = [k for k in ("normal", "uniform") if k in spec]
        if len(kinds) != 1 or unknown_key(spec, ("normal", "uniform", "absolute")):
            raise CampaignError(f"{where}: give exactly one of normal, uniform (and optionally absolute)")
        kind, value = kinds[0], spec[kinds[0]]
        absolute = boolean(spec.get("absolute", False), f"{where}.absolute", CampaignError)
        if kind == "normal":
            if isinstance(value, (int, float)) and not isinstance(value, bool) and not absolute:
                a, b = 1.0, number(value, f"{where}.normal", low=0.0, error=CampaignError)  # relative std
            elif isinstance(value, (list, tuple)) and len(value) == 2:
                a = number(value[0], f"{where}.normal[0] (mean)", error=CampaignError)
                b = number(value[1], f"{where}.normal[1] (std)", low=0.0, error=CampaignError)
            else:
                form = "[mean, std]" if absolute else "a relative std, or [mean, std]"
                raise CampaignError(f"{where}.normal: {form}, got {type(value).__name__} {short(value)}")
            if not math.isfinite(abs(a) + 10.0 * b):
                raise CampaignError(f"{where}.normal: mean and std too large (|mean| + 10 std overflows)")
        else:
            if not (isinstance(value, (list, tuple)) and len(value) == 2):
                raise CampaignError(f"{where}.uniform: [low, high], got {type(value).__name__} {short(value)}")
            a = number(value[0], f"{where}.uniform[0] (low)", error=CampaignError)
            b = number(value[1], f"{where}.uniform[1] (high)", error=CampaignError)
            if not b >= a:
                raise CampaignError(f"{where}.uniform: high must be >= low, got [{a:g}, {b:g}]")
            if not math.isfinite(b - a):
                raise CampaignError(f"{where}.uniform: [{a:g}, {b:g}] is wider than a float can hold")
        return cls(kind, a, b, absolute)

    def sample(self, rng: np.random.Generator, base: float, size: int) -> np.ndarray:
        """``size`` draws [unit of the field]: normal(mean, std) or uniform(low, high), times ``base`` when relative."""
        x = rng.normal(self.a, self.b, size) if self.kind == "normal" else rng.uniform(self.a, self.b, size)
        return x if self.absolute else base * x


def _column(key: str, values: list) -> tuple[list, dict | None]:
    """A grid key's values as a column of one type: numbers, booleans or strings as they are; anything else
    (a mix of types, null, lists, mappings) as each value's JSON text, with the map back to the values."""
    kinds = {bool if isinstance(v, bool) else (float if isinstance(v, (int, float)) else type(v)) for v in values}
    if len(kinds) == 1 and kinds <= {bool, float, str}:
        return list(values), None
    texts = [json.dumps(v, sort_keys=True, default=str) for v in values]
    return texts, dict(zip(texts, values))


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
    #: per grid key whose values mix types: the table's JSON text -> the value (:func:`_column`)
    decode: dict = field(default_factory=dict)
    #: fleet campaigns: (name, size, mtime_ns) of every recording and golden file, for the digest
    fleet_state: list = field(default_factory=list)
    #: the files it was read from (the campaign file, a scene file): no output of its run may replace one
    sources: tuple = ()

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(cls, path) -> "Campaign":
        """Parse a campaign file; every error names the key.

        The file is read through :mod:`belt_drive_ros.io.inputs` as a scene
        file is: a regular UTF-8 file of at most :data:`CAMPAIGN_LIMIT` bytes
        (its size checked before anything is read), YAML without aliases,
        anchors, deep nesting or duplicate keys, YAML 1.2 numbers.
        """
        path = Path(path)
        label = f"campaign file {short(str(path), 200)}"
        try:
            text = read_text(path, "campaign file", limit=CAMPAIGN_LIMIT)
            data = parse_yaml(text, label)
        except InputError as exc:
            raise CampaignError(str(exc)) from None
        campaign = cls.from_mapping(data, base_dir=path.parent, text=text)
        campaign.sources = (path,) + campaign.sources
        return campaign

    @classmethod
    def from_mapping(cls, data: Mapping, base_dir=".", text: str | None = None) -> "Campaign":
        if not isinstance(data, Mapping):
            raise CampaignError(f"campaign: expected a mapping at the top level, got {type(data).__name__} {short(data)}")
        data = _plain(data, "")
        unknown = unknown_key(data, KEYS)
        if unknown:
            raise CampaignError(f"{unknown}: unknown key; known keys: {', '.join(KEYS)}")
        base_dir = Path(base_dir)
        for key in ("name", "description"):
            if data.get(key) is not None:
                value = string(data[key], key, CampaignError)
                if len(value) > 200 or any(c in value for c in "\n\r\0/"):
                    raise CampaignError(f"{key}: one line of at most 200 characters, without '/', got {short(value)}")
        scene_ref = data.get("scene")
        sources = ()
        if isinstance(scene_ref, Mapping):  # inline (what a worker receives)
            if scene_ref.get("kind") == "network":
                raise CampaignError(_NETWORK.format(given="the inline scene", what="a belt network scene",
                                                    names=", ".join(shipped_scenes())))
            base = scene_from_mapping(scene_ref)
        elif isinstance(scene_ref, str) and scene_ref:
            candidate = base_dir / scene_ref
            # a path: a YAML name, a folder in it, or a file next to this one that is no shipped scene's name (relative
            # to this file, not to the working directory)
            by_path = (candidate.suffix in (".yaml", ".yml") or os.sep in scene_ref
                       or (scene_ref not in shipped_scenes() and os.path.lexists(candidate)))
            _refuse_network(candidate if by_path else scene_ref, scene_ref)
            base = load_scene(candidate if by_path else scene_ref)
            sources = (candidate,) if by_path else ()
        else:
            raise CampaignError(f"scene: a shipped scene name or a scene file is required, got {short(scene_ref)}")
        mapping = base.to_dict()
        given = _key_paths(_mapping(data, "set"), "set.")
        for path, _, value in given:
            _assign(mapping, tuple(path.split(".")), value)
        try:
            base = scene_from_mapping(mapping)
        except BeltDriveError as exc:  # the scene itself read before: what set changed is named as set's
            if not given:
                raise
            raise CampaignError(f"set: {exc}") from None
        grid, decode = {}, {}
        for key, given, values in _key_paths(_mapping(data, "grid"), "grid."):
            column, back = _column(key, sequence(values, f"grid.{given}", CampaignError, nonempty=True))
            seen = set()
            for value in column:  # a value twice: the same variants twice (nothing new, twice the time)
                if value in seen or (value != value and any(v != v for v in seen)):
                    raise CampaignError(f"grid.{given}: {short(back[value] if back else value)} is given twice")
                seen.add(value)
            grid[key] = column
            if back is not None:
                decode[key] = back
        # (an empty list: no profiles, the base scene's torques; what a campaign's own mapping holds without any)
        profiles = [] if data.get("profiles") is None else sequence(data["profiles"], "profiles", CampaignError)
        for j, entry in enumerate(profiles):
            if not isinstance(entry, Mapping) or not entry or set(entry) - {"drive", "load"}:
                raise CampaignError(f"profiles[{j}]: a mapping with drive and/or load, got {short(entry)}")
            for role, spec in entry.items():
                try:
                    make_profile(spec, role)  # validated here, by the profile's own rules
                except BeltDriveError as exc:
                    raise CampaignError(f"profiles[{j}].{exc}") from None
                if not isinstance(spec, Mapping):  # a number: a constant (scene_of merges grid fields into a mapping)
                    entry[role] = {"type": "constant", "value": spec}
        mc = _mapping(data, "monte_carlo")
        bad = unknown_key(mc, ("samples", "seed", "vary"))
        if bad:
            raise CampaignError(f"monte_carlo.{bad}: unknown key; known: samples, seed, vary")
        samples = seed = 0
        vary = {}
        if mc:
            samples = number(mc.get("samples"), "monte_carlo.samples", low=1, high=MAX_SEED, integer=True, error=CampaignError)
            seed = number(mc.get("seed", 0), "monte_carlo.seed", low=0, high=MAX_SEED, integer=True, error=CampaignError)
            entries = _key_paths(_mapping(mc, "vary", "monte_carlo."), "monte_carlo.vary.")
            vary = {path: Distribution.parse(given, spec) for path, given, spec in entries}
            if not vary:
                raise CampaignError("monte_carlo.vary: name at least one key path and its distribution")
        for key in grid:
            _check_field(key, "grid.", mapping, profiles)
        for key in vary:
            _check_field(key, "monte_carlo.vary.", mapping, profiles)
        for key, dist in vary.items():
            if key in grid:
                raise CampaignError(
                    f"monte_carlo.vary.{key}: also a grid key; a key varies by the grid or by the Monte Carlo "
                    "draws, not both (a draw would replace the grid value)"
                )
            base_value = _lookup(mapping, tuple(key.split(".")))
            own = [_lookup(entry, tuple(key.split("."))) for entry in profiles] if key.split(".")[0] in (
                "drive", "load") else []  # fmt: skip
            numeric = [v for v in (base_value, *own) if isinstance(v, (int, float)) and not isinstance(v, bool)]
            if base_value is not None and not numeric:  # (text, a boolean, a list of harmonics)
                raise CampaignError(  # (absolute: true raised float()'s internal error on the text; every draw fails)
                    f"monte_carlo.vary.{key}: draws numbers, and the scene's {key} is {short(base_value)}; vary it by "
                    "the grid"
                )
            if not dist.absolute and (isinstance(base_value, bool) or not isinstance(base_value, (int, float))):
                raise CampaignError(
                    f"monte_carlo.vary.{key}: a relative tolerance needs a numeric base value, got {short(base_value)}; "
                    "give absolute: true"
                )
            if not dist.absolute and base_value == 0 and not any(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and v != 0 for v in own):
                raise CampaignError(  # (every variant drew 0 times a factor: identical variants, exit 0)
                    f"monte_carlo.vary.{key}: a relative tolerance of a base value 0 varies nothing; give an absolute "
                    "one (normal: [mean, std] or uniform: [low, high], absolute: true)"
                )
        fleet = data.get("fleet")
        fleet_folder = golden = None
        if fleet is not None:
            if not isinstance(fleet, Mapping) or "folder" not in fleet or set(fleet) - {"folder", "golden"}:
                raise CampaignError(f"fleet: a mapping with folder (and optionally golden), got {short(fleet)}")
            if grid or profiles or mc:
                raise CampaignError("fleet: a fleet campaign has no grid, profiles or monte_carlo")
            fleet_folder = _folder(base_dir, fleet["folder"], "fleet.folder")
            if fleet.get("golden") is not None:
                golden = _folder(base_dir, fleet["golden"], "fleet.golden")
        names = data.get("metrics")
        metrics = tuple(METRICS) if names is None else tuple(sequence(names, "metrics", CampaignError, nonempty=True))
        for name in metrics:
            if not isinstance(name, str) or name not in METRICS:
                raise CampaignError(f"metrics: unknown metric {short(name)}; known: {', '.join(METRICS)}")
        if len(set(metrics)) != len(metrics):
            raise CampaignError(f"metrics: a metric named twice in {short(list(metrics))}")
        limits = dict(DEFAULT_LIMITS)
        for name, value in _mapping(data, "limits").items():
            if not isinstance(name, str) or name not in METRICS:
                raise CampaignError(f"limits.{short(name, 60)}: not a metric; known: {', '.join(METRICS)}")
            limits[name] = number(value, f"limits.{name}", error=CampaignError)
        if text is None:
            text = yaml.safe_dump(dict(data), sort_keys=True)
        campaign = cls(
            name=data.get("name") or base.name, base=base, base_mapping=mapping, grid=grid, profiles=profiles,
            samples=samples, seed=seed, vary=vary, fleet_folder=fleet_folder, golden_folder=golden,
            metrics=metrics, limits=limits, text=text, decode=decode, sources=sources,
        )  # fmt: skip
        if fleet_folder is not None:
            campaign.fleet_state = _fleet_state(campaign.fleet_files(), golden)
        return campaign

    @property
    def size(self) -> int:
        """Number of variants (grid points x profiles x samples; fleet: recordings), without building the table."""
        if self.fleet_folder is not None:
            return sum(1 for entry in self.fleet_state if entry[0] == "recording")
        n = math.prod(len(v) for v in self.grid.values())
        return n * max(len(self.profiles), 1) * (self.samples if self.vary else 1)

    # ------------------------------------------------------------------ variants
    def fleet_files(self) -> list[Path]:
        """The fleet's recordings (``*.mcap`` in the folder, sorted by name; each checked to be a regular file)."""
        return _recordings(self.fleet_folder, "fleet.folder") if self.fleet_folder else []

    def variants(self):
        """The variant table: one row per variant, a column per varied key path (a pandas DataFrame).

        Fleet campaigns have one column, ``recording`` (file name). Others:
        the grid's key paths, ``profile`` (index into ``profiles``) when
        profiles are listed, and the Monte Carlo key paths; ``variant`` is
        the row number. Variants are grid points (the last grid key
        varying fastest) x profiles x samples. Monte Carlo draws come from one
        ``numpy.random.default_rng(seed)``, key by key in file order, so
        the table is reproducible. Every column holds one type (a grid key
        whose values mix types holds their JSON text: :func:`_column`).
        """
        import pandas as pd

        if self.fleet_folder is not None:
            names = [name for role, name, *_ in self.fleet_state if role == "recording"]
            return pd.DataFrame({"variant": np.arange(len(names)), "recording": pd.Series(names, dtype=object)})
        if self.size > MAX_VARIANTS:  # (numpy's own refusal: 'Maximum allowed size exceeded', or memory)
            raise CampaignError(f"campaign: {self.size:.3g} variants, more than the {MAX_VARIANTS:,} variants one campaign "
                                "may hold")
        lengths = [len(v) for v in self.grid.values()]
        profiles = len(self.profiles)
        samples = self.samples if self.vary else 1
        n = self.size
        columns: dict = {"variant": np.arange(n)}
        combo = np.arange(n) // samples  # the grid point and profile of each row
        point = combo // max(profiles, 1)
        index = np.unravel_index(point, lengths) if lengths else ()
        for j, (key, values) in enumerate(self.grid.items()):
            column = _array(values)
            columns[key] = column[index[j]]
        if self.profiles:
            columns["profile"] = combo % profiles
        rng = np.random.default_rng(self.seed)
        for key, dist in self.vary.items():
            path = tuple(key.split("."))
            base = _lookup(self.base_mapping, path)
            base = float(base) if isinstance(base, (int, float)) and not isinstance(base, bool) else 0.0  # (text: absolute)
            if dist.absolute or not self.profiles or path[0] not in ("drive", "load"):
                columns[key] = dist.sample(rng, base, n)
                continue
            # a relative draw on a profile's field is relative to the row's profile's own value where it names one
            # (it scaled the base scene's, and the draw replaced the profile's value: two profiles became one)
            x = dist.sample(rng, 1.0, n)  # (the factors: base * x as before, the same floats)
            column = base * x
            for j, entry in enumerate(self.profiles):
                own = _lookup(entry, path)
                if isinstance(own, (int, float)) and not isinstance(own, bool):
                    rows = columns["profile"] == j
                    column[rows] = float(own) * x[rows]
            columns[key] = column
        return pd.DataFrame(columns)

    def scene_of(self, row: Mapping, warn=None) -> Scene:
        """The scene of one variant (a row of :meth:`variants`); invalid values raise the scene's own error.

        Variants share the base scene's profile objects unless their drive or
        load changes (equal profiles are shared too, :func:`_profile`): a
        profile compiles its formula once, and variants with one profile can
        run in one ensemble. ``warn``: receives a fleet recording's one-line note that it was cut off (default:
        ``warnings.warn``).
        """
        if self.fleet_folder is not None:
            from ..io.torque_bag import scene_with_torque_bag

            return scene_with_torque_bag(self.base, self.fleet_folder / str(row["recording"]), warn=warn)
        parts: dict = {"params": {}, "initial_state": {}, "drive": {}, "load": {}, "top": {}}
        roles = {}
        profile = row.get("profile")
        if profile is not None and not (isinstance(profile, float) and math.isnan(profile)):
            roles = dict(self.profiles[int(profile)])
        for key, value in row.items():
            if key in ("variant", "profile"):
                continue
            value = value.item() if hasattr(value, "item") else value
            if key in self.decode:
                value = self.decode[key][value]
            path = key.split(".")
            parts["top" if len(path) == 1 else path[0]][path[-1]] = value
        changes = {k: v for k, v in parts["top"].items()}
        if parts["params"]:
            changes["params"] = self.base.params.replace(**parts["params"]).check_plausible()
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

    def scenes_of(self, rows) -> list:
        """:meth:`scene_of` of every row of ``rows`` (a slice of :meth:`variants`, or row mappings): per row its scene,
        or the exception :meth:`scene_of` raises for it (the same type and text).

        A tolerance sweep (a table whose columns are ``variant`` and parameters as numbers) is checked column-wise
        (:meth:`~belt_drive_ros.core.params.BeltDriveParams.replace_rows`, numpy over all rows at once): a row that
        passes gets its parameters without a second check, a row that fails the error :meth:`scene_of` raises for it
        (the parameters' scalar check, which names what is wrong). Other tables go row by row.
        """
        import pandas as pd

        if isinstance(rows, pd.DataFrame):
            found = self._parameter_scenes(rows)
            if found is not None:
                return found
            rows = rows.to_dict("records")
        return [_scene_or_error(self, row) for row in rows]

    def _parameter_scenes(self, frame) -> list | None:
        """:meth:`scenes_of` of a tolerance sweep's rows, column-wise (None: not such a table)."""
        keys = [key for key in frame.columns if key != "variant"]
        if self.fleet_folder is not None or not keys or len(frame) == 0:
            return None
        names = [key[len("params.") :] for key in keys]
        if any(not key.startswith("params.") or key in self.decode or name not in FIELD_DOCS for key, name in zip(keys, names)):
            return None
        columns = {}
        for key, name in zip(keys, names):
            values = frame[key].to_numpy()
            if values.dtype.kind not in "fi":  # (booleans, text: refused by the row's own check)
                return None
            columns[name] = values
        params = self.base.params.replace_rows(columns, plausible=True)
        return [p if isinstance(p, Exception) else self.base.with_params(p) for p in params]

    def digest(self) -> str:
        """Identity of the campaign: its file text, base scene and, for a fleet, the name, size and modification
        time of every recording and golden file. A resumed run must match it (a recording renamed, added,
        removed or rewritten since the interrupted run is another campaign)."""
        blob = json.dumps([self.text, self.base_mapping, self.fleet_state], sort_keys=True, default=str)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _refuse_network(where, given: str) -> None:
    """A belt network scene (shipped, or a file stating ``kind: network``) is refused by name: a campaign varies the
    four-wheel drive (its ``params``, profiles and recordings), which a network scene does not have."""
    if is_network(where):
        what = "the shipped belt network scene" if str(where) in shipped_networks() else "a belt network scene file"
        raise CampaignError(_NETWORK.format(given=short(given), what=what, names=", ".join(shipped_scenes())))


_NETWORK = ("scene: {given} is {what} (belt-drive sim runs it); campaigns run drive scenes only: "
            "a shipped one ({names}) or a drive scene file")


def _scene_or_error(campaign: Campaign, row: Mapping):
    """``campaign.scene_of(row)``, or the exception it raises (whatever a variant's values break is its row's)."""
    try:
        return campaign.scene_of(row)
    except Exception as exc:  # noqa: BLE001 - reported as that variant's error
        return exc


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


def _array(values: list) -> np.ndarray:
    """A grid key's values (one type, :func:`_column`) as an array: int64, float64, bool or str objects."""
    if isinstance(values[0], str):
        return np.asarray(values, dtype=object)
    if isinstance(values[0], bool):
        return np.asarray(values, dtype=bool)
    if all(isinstance(v, int) and -(2**63) <= v < 2**63 for v in values):
        return np.asarray(values, dtype=np.int64)
    return np.asarray([float(v) for v in values], dtype=float)


def _plain(value, where: str, depth: int = 0):
    """``value`` (a campaign mapping from Python) as YAML's plain types: numpy scalars as Python numbers, booleans
    and text, arrays and tuples as lists, mappings as dicts; anything else, or nesting deeper than
    :data:`~belt_drive_ros.io.inputs.MAX_DEPTH` (a structure that holds itself included), a
    :class:`CampaignError` naming where. A parsed campaign file is plain already."""
    label = where.rstrip(".")[:80] or "campaign"
    if depth > MAX_DEPTH:
        raise CampaignError(f"{label}: nested deeper than {MAX_DEPTH} levels")
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.generic) and not isinstance(value, np.number):  # np.bool_, np.str_
        return value.item()
    number = real(value)
    if isinstance(number, int) and abs(number) > 2**63:  # (no float holds it: a grid column or seed overflowed)
        raise CampaignError(f"{label}: an integer beyond 2^63")
    if number is not None:  # (np.float64 is a float: made one)
        return float(number) if isinstance(number, float) else int(number)
    if isinstance(value, Mapping):  # (a key stays as it is: the checks below refuse a key that is not text)
        return {k.item() if isinstance(k, np.generic) else k: _plain(v, f"{where}{str(k)[:60]}.", depth + 1)
                for k, v in value.items()}
    if isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
        return value.tolist()
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v, f"{label}[{j}]", depth + 1) for j, v in enumerate(value)]
    raise CampaignError(f"{label}: {type(value).__name__} {short(value)} is not a campaign value (numbers, text, "
                        "booleans, lists and mappings)")


def _mapping(data: Mapping, key: str, where: str = "") -> dict:
    """``data[key]`` as a dict ({} when absent or null), else an error naming ``where + key``."""
    return as_mapping(data.get(key), f"{where}{key}", CampaignError, empty={})


def _checked(path: Path, key: str, what: str, folder: bool = False) -> None:
    """``io.inputs.check_path`` (``os.stat`` only, nothing opened) with the error naming ``key``."""
    try:
        check_path(path, what, folder=folder)
    except InputError as exc:
        raise CampaignError(f"{key}: {exc}") from None


def _folder(base_dir: Path, value, key: str) -> Path:
    """The folder ``value`` (relative to the campaign file), which must exist and be a folder."""
    if not isinstance(value, str) or not value:
        raise CampaignError(f"{key}: a folder path, got {type(value).__name__} {short(value)}")
    folder = (base_dir / value).resolve()
    _checked(folder, key, "folder", folder=True)
    if not folder.is_dir():
        raise CampaignError(f"{key}: {short(str(folder), 200)} is a file, not a folder")
    return folder


def _recordings(folder: Path, key: str, *, empty_ok: bool = False) -> list[Path]:
    """The ``*.mcap`` files of ``folder`` by name, each checked (``os.stat``, nothing opened) to be a regular file:
    a FIFO would block its reader forever, a device never end."""
    try:
        names = sorted(entry.name for entry in os.scandir(folder) if entry.name.endswith(".mcap"))
    except OSError as exc:
        raise CampaignError(f"{key}: {short(str(folder), 200)}: {exc.strerror or exc}") from None
    for name in names:
        _checked(folder / name, key, "recording")
    if not names and not empty_ok:
        raise CampaignError(f"{key}: no .mcap recordings in {short(str(folder), 200)}")
    return [folder / name for name in names]


def _fleet_state(recordings: list[Path], golden: Path | None) -> list:
    """(role, name, size, mtime_ns) of every recording and golden file: what a fleet's digest covers."""
    out = []
    for role, files in (("recording", recordings), ("golden", _recordings(golden, "fleet.golden", empty_ok=True) if golden else [])):
        for path in files:
            st = os.stat(path)
            out.append((role, path.name, st.st_size, st.st_mtime_ns))
    return out


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
