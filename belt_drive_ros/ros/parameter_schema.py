"""The belt-drive node's parameters: schema, defaults and validation (no rclpy).

Everything here is plain Python on top of :mod:`belt_drive_ros.core`, so
``belt-drive node --list-parameters`` and tests read the schema without
starting ROS; :mod:`belt_drive_ros.ros.parameters` turns it into rclpy
descriptors and callbacks.

The model parameters are the fields of
:class:`~belt_drive_ros.core.params.BeltDriveParams`; their ranges are that
class's rules (:func:`model_range`), and :func:`build_settings` validates
them by constructing it. The node's own parameters are in
:data:`NODE_PARAMETERS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from ..core import params as core_params
from ..core.errors import BeltDriveError, ParameterError
from ..core.fidelity import choose_model
from ..core.integrators import REGISTRY, make_integrator
from ..core.model import make_model
from ..core.params import FIELD_DOCS, BeltDriveParams
from ..core.scene import AUTO_METHOD as AUTO, MODELS, Scene
from ..io.scenes import load_scene
from ..core.accuracy import AccuracyReport, require_accurate, require_accurate_slipping
from ..core.stability import StabilityReport, require_stable
from ..core.stepper import Plant

__all__ = [
    "DEFAULT_SCENE",
    "DRIVE_SOURCES",
    "MODEL_PARAMETERS",
    "NODE_PARAMETERS",
    "NodeConfigError",
    "NodeSettings",
    "OWN_PARAMETERS",
    "RCLPY_PARAMETERS",
    "ParamSpec",
    "SCENE_DERIVED",
    "START_ONLY",
    "SceneCache",
    "TIMEOUT_BEHAVIORS",
    "build_settings",
    "default_values",
    "describe_parameters",
    "model_range",
    "record_path_exists",
    "scene_defaults",
    "scene_torque_bound",
    "section_matches",
]

DEFAULT_SCENE = "paper"
DRIVE_SOURCES = ("topic", "scene")
TIMEOUT_BEHAVIORS = ("hold", "zero")


class NodeConfigError(ParameterError):
    """A node parameter (or the combination) is invalid; ``field`` names the parameter."""


def check_record_path(record_path: str, split: bool, scene) -> None:
    """Refuse (:class:`NodeConfigError` naming ``record_path``) a recording either node cannot write as asked: a
    split one (``split``) named ``.mcap`` (it is a folder), one file named with another extension (``run.csv``: an
    MCAP under a CSV's name), or the scene file the node reads (``--record scene.yaml --force`` replaced the scene
    with the recording; an output never replaces an input of its own run)."""
    if not record_path:
        return
    import os

    from ..io.inputs import input_replaced

    if isinstance(scene, str) and input_replaced(record_path, [scene]) is not None:
        raise NodeConfigError("record_path", f"{record_path!r} is the scene file the node reads; record elsewhere")
    suffix = os.path.splitext(record_path)[1].lower()
    if split and suffix == ".mcap":
        raise NodeConfigError(
            "record_path", f"{record_path!r}: a split recording (max_bag_duration/max_bag_size) is a bag "
            "folder NAME/NAME_0.mcap, ...; give a folder name without .mcap")
    if not split and suffix and suffix != ".mcap":
        raise NodeConfigError("record_path", f"{record_path!r}: a recording is an MCAP file; name it .mcap")


def record_path_exists(path) -> NodeConfigError:
    """The refusal of a ``record_path`` that exists while ``record_overwrite`` is false (either node's): the
    house's one sentence for an output that exists (``belt-drive sim``'s "PATH exists; pass --force to overwrite
    it"), naming the parameter to set."""
    return NodeConfigError("record_path", f"{path} exists; set record_overwrite:=true to overwrite it")


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: type, default, range or choices, description."""

    name: str
    kind: str  # "float", "int", "str", "bool"
    default: Any
    description: str
    range: tuple | None = None
    choices: tuple | None = None


#: Node parameters besides the model parameters. ``None`` defaults come from the scene.
NODE_PARAMETERS: tuple[ParamSpec, ...] = (
    ParamSpec("scene", "str", DEFAULT_SCENE, "shipped scene name or path to a scene YAML: parameters, load, initial state"),
    ParamSpec("model", "str", None, "belt model: rigid, flexible, slipping or auto (chosen from the scene's excitation)", choices=MODELS),
    ParamSpec("method", "str", None, "integrator: auto (the cheapest method and fewest substeps the accuracy guard rates within the scene's tolerance) or " + ", ".join(REGISTRY)),
    ParamSpec("step_rate_hz", "float", 1000.0, "tick rate on the node's clock [Hz]; outputs are published once per tick", range=(1.0, 20000.0)),
    ParamSpec("substeps", "int", None, "integrator steps per tick (dt = 1/(step_rate_hz*substeps), whole ns); default: the scene's dt at 1 kHz", range=(1, 1000)),
    ParamSpec("input_timeout", "float", 1.0, "seconds (node clock) without drive_torque before timeout_behavior applies, counted from the run's start for one received before it; 0 = never", range=(0.0, 3600.0)),
    ParamSpec("timeout_behavior", "str", "hold", "after input_timeout: 'hold' the last torque or 'zero' it", choices=TIMEOUT_BEHAVIORS),
    ParamSpec("drive_source", "str", "topic", "'topic': drive_torque sampled at each tick and held (0 before the first message); 'scene': the scene's drive profile", choices=DRIVE_SOURCES),
    ParamSpec("torque_limit", "float", 0.0, "clamp |drive_torque| to this [N m]; 0 = off", range=(0.0, 1.0e7)),
    ParamSpec("torque_bound", "float", 0.0, "reject drive_torque messages with |value| above this [N m] (counted); 0 = derived from the scene (10x the largest torque of its drive and load profiles)", range=(0.0, 1.0e12)),
    ParamSpec("publish_clock", "bool", False, "publish /clock from the node's own simulated time (time master)"),
    ParamSpec("tick_thread", "bool", True, "on the system clock: tick from a thread of the node's own that sleeps to each tick's deadline and publishes every tick (a late wake catches up, at most 50 ms); false: from an executor timer (a tick more than a period late is integrated but not published)"),
    ParamSpec("tick_lead", "float", 0.0003, "with tick_thread: each tick is computed at least this long before its due time [s] and published at it (a drive_torque received within the lead acts from the next tick); the thread leads by more when its recent ticks took longer (their 99.9th percentile + 0.1 ms); at most 3/4 of a period", range=(0.0, 0.1)),
    ParamSpec("real_time_factor", "float", 1.0, "with publish_clock: simulated seconds per wall second; 0 = as fast as possible", range=(0.0, 1.0e4)),
    ParamSpec("record_path", "str", "", "MCAP file (or, split, a rosbag2 bag folder) to record the node's input and outputs to ('' = off); set at start only; an existing one refuses the start unless record_overwrite"),
    ParamSpec("record_overwrite", "bool", False, "replace an existing record_path (belt-drive node --force); set at start only"),
    ParamSpec("max_bag_duration", "float", 0.0, "split the recording into a rosbag2 bag folder (NAME/NAME_0.mcap, NAME_1.mcap, ..., metadata.yaml), a new file every this many seconds of log time; 0 = no split by time; set at start only", range=(0.0, 1.0e7)),
    ParamSpec("max_bag_size", "int", 0, "split the recording into a bag folder, a new file once one holds this many bytes; 0 = no split by size; set at start only", range=(0, 2**50)),
)
#: parameters that take effect at start only: declared read-only (rclpy refuses a runtime change, naming it)
START_ONLY: tuple[str, ...] = ("record_path", "record_overwrite", "max_bag_duration", "max_bag_size")
NODE_SPECS: dict[str, ParamSpec] = {s.name: s for s in NODE_PARAMETERS}
MODEL_PARAMETERS: tuple[str, ...] = tuple(FIELD_DOCS)
#: every parameter the node owns (use_sim_time belongs to rclpy's TimeSource)
OWN_PARAMETERS: tuple[str, ...] = tuple(NODE_SPECS) + MODEL_PARAMETERS
#: parameters every rclpy node declares
RCLPY_PARAMETERS = ("use_sim_time", "start_type_description_service")
#: why a name the node does not declare is refused (rclpy drops it without a word: a misspelt name ran the default)
NOT_A_PARAMETER = "not a parameter of the node (belt-drive node --list-parameters)"


def refuse_undeclared(node, parameters, why: str = NOT_A_PARAMETER) -> None:
    """Raise rclpy's ParameterNotDeclaredException naming each of ``parameters`` the ``node`` does not have, as ``name:
    why`` (rclpy raises it next anyway, its message naming nothing: 'undeclared parameter(s): []'; it is the one
    exception rclpy's parameter services answer with its text as the reason). A pre-set callback of both nodes."""
    unknown = [p.name for p in parameters if not node.has_parameter(p.name)]
    if unknown:
        from rclpy.exceptions import ParameterNotDeclaredException

        raise ParameterNotDeclaredException(f"{', '.join(unknown)}: {why}")


def unknown_parameter_rule(ros_args: list[str], names, node_name: str | None = None,
                           namespace: str = "/") -> str | None:
    """The first parameter ``ros_args`` set that is neither in ``names`` nor :data:`RCLPY_PARAMETERS` (rclpy drops
    it without a word), or None: a ``-p NAME:=VALUE`` (``--param``; a rule scoped to a node, ``other:NAME:=VALUE``,
    is not checked), then a name under ``ros__parameters`` of a ``--params-file`` section for this node: a
    section whose name matches its fully qualified name as rcl matches it (``belt_drive:`` is ``/belt_drive``;
    ``/**/belt_drive:`` is belt_drive in any namespace, :func:`section_matches`; ``node_name`` in ``namespace``,
    as ``-r __ns:=``, ``-r __node:=`` / ``__name:=`` and their ``belt_drive:``-scoped forms remap them), given as
    ``NAME (params file FILE)``. A section for another node, or one whose node name is a wildcard (``/**:``,
    ``/fleet/*:``, which may hold other nodes' parameters), is not checked."""
    for flag, rule in zip(ros_args, ros_args[1:]):
        if flag in ("-p", "--param"):
            name = rule.split(":=", 1)[0]
            if ":" not in name and name not in names and name not in RCLPY_PARAMETERS:
                return name
    if node_name is None:
        return None
    given = node_name
    for flag, rule in zip(ros_args, ros_args[1:]):
        if flag in ("-r", "--remap") and ":=" in rule:
            lhs, _, rhs = rule.partition(":=")
            scope, _, what = lhs.rpartition(":")
            if scope and scope != given:
                continue
            if what in ("__node", "__name"):
                node_name = rhs
            elif what == "__ns":
                namespace = rhs
    fqn = "/" + "/".join(part for part in (*str(namespace).split("/"), node_name) if part)
    from ..io.inputs import parse_yaml, read_text

    for flag, path in zip(ros_args, ros_args[1:]):
        if flag != "--params-file":
            continue
        data = parse_yaml(read_text(path, what="params file"), label=f"params file {path}")
        for section, body in (data.items() if isinstance(data, dict) else ()):
            if not section_matches(str(section), fqn) or str(section).rstrip("/").rsplit("/", 1)[-1] in ("*", "**"):
                continue  # (another node's section, or one for any node)
            values = body.get("ros__parameters") if isinstance(body, dict) else None
            for name in _flat_names(values if isinstance(values, dict) else {}):
                if name not in names and name not in RCLPY_PARAMETERS:
                    return f"{name} (params file {path})"
    return None


def section_matches(section: str, fqn: str) -> bool:
    """Whether rcl applies the params file section ``section`` to the node of fully qualified name ``fqn``.

    A section is a node's fully qualified name (``belt_drive`` is ``/belt_drive``) in which a token ``*`` stands
    for any one token and ``**`` for any number of them, none included: ``/**/belt_drive`` is belt_drive in
    any namespace, ``/**`` every node (ROS 2 command line arguments design, "Wildcards")."""
    want = [part for part in section.split("/") if part]
    have = [part for part in fqn.split("/") if part]

    def match(i: int, j: int) -> bool:
        if i == len(want):
            return j == len(have)
        if want[i] == "**":
            return any(match(i + 1, k) for k in range(j, len(have) + 1))
        return j < len(have) and want[i] in ("*", have[j]) and match(i + 1, j + 1)

    return match(0, 0)


def _flat_names(values: dict, prefix: str = "") -> list:
    """The parameter names of a params file's ``ros__parameters`` mapping (nested mappings: ``a.b``, as rcl reads)."""
    out = []
    for key, value in values.items():
        name = f"{prefix}{key}"
        out += _flat_names(value, name + ".") if isinstance(value, dict) else [name]
    return out


#: parameters whose default comes from the scene and that a new scene resets
SCENE_DERIVED: tuple[str, ...] = ("model", "method", "substeps") + MODEL_PARAMETERS
#: parameters of type double (an integer given for one is stored as a double)
DOUBLE_PARAMETERS: frozenset[str] = frozenset(MODEL_PARAMETERS) | {s.name for s in NODE_PARAMETERS if s.kind == "float"}


def model_range(name: str) -> tuple[float, float]:
    """[lower, upper] of model parameter ``name`` as :class:`BeltDriveParams` enforces it (SI units).

    Read from the one rule table, :data:`core.params.RULES` and
    :data:`core.params.PLAUSIBLE_RULES` (the constructor's checks and the
    plausible maxima): the strictest of the ends the field's rules are written
    with, as the closed range a ROS descriptor states (an open end, e.g.
    ``> 0``, is given as its end, 0, and refused there by the class itself).
    A side no rule bounds is an infinity.
    """
    rules = [r for r in core_params.RULES + core_params.PLAUSIBLE_RULES if r.field == name]
    low = max((r.written[0] for r in rules), default=-math.inf)
    high = min((r.written[1] for r in rules), default=math.inf)
    return low + 0.0, high + 0.0


@dataclass
class NodeSettings:
    """Everything the node derives from its parameters, validated together.

    Built by :func:`build_settings`; a new instance replaces the old one on
    every accepted parameter change.
    """

    values: dict
    scene: Scene
    params: BeltDriveParams
    model: Any
    model_reason: str
    method: str
    tick_ns: int
    dt_ns: int
    integrator: Any
    stability: StabilityReport
    step_rate_hz: float
    substeps: int
    input_timeout_ns: int
    timeout_behavior: str
    drive_source: str
    torque_limit: float
    torque_bound: float
    publish_clock: bool
    real_time_factor: float
    record_path: str
    method_options: dict = field(default_factory=dict)
    #: the accuracy guard's verdict (core/accuracy.py) on the node's model, method and step; None: adaptive method
    accuracy: AccuracyReport | None = None
    #: how method and step were chosen (method auto, core/method_choice.py), or that they were set
    method_reason: str = ""
    record_overwrite: bool = False
    max_bag_duration: float = 0.0
    max_bag_size: int = 0
    #: on the system clock, tick from the node's own thread (timing.TickThread) instead of an executor timer
    tick_thread: bool = True
    #: with tick_thread: compute each tick at least this long before its due time [ns] (at most 3/4 of a period)
    tick_lead_ns: int = 0

    @property
    def record_split(self) -> bool:
        """True when the recording is a split bag folder (``max_bag_duration`` or ``max_bag_size`` set)."""
        return bool(self.max_bag_duration or self.max_bag_size)

    @property
    def dt(self) -> float:
        """Integrator substep [s]."""
        return self.dt_ns / 1e9

    @property
    def steps(self) -> str:
        """How the node steps, for its start line: rate and substeps, and where that is not the scene's ``dt``, the
        step it takes and how ``belt-drive sim`` runs the same (the node steps ``tick / substeps``)."""
        line = f"{self.step_rate_hz:g} Hz x {self.substeps} substep(s)"
        if self.dt_ns == round(self.scene.dt * 1e9):
            return line
        if self.tick_ns % self.dt_ns == 0:
            return (f"{line} of {self.dt_ns} ns (the scene's dt is {self.scene.dt:g} s; belt-drive sim --dt "
                    f"{self.dt_ns / 1e9:g} steps as this node does)")
        return (f"{line} of {self.dt_ns} ns (the scene's dt is {self.scene.dt:g} s; a tick of {self.tick_ns} ns is no "
                "whole number of them: the steps are split at the ticks)")


def _number(name: str, value: Any, lo: float, hi: float, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise NodeConfigError(name, f"must be a number, got {value!r}")
    if integer and int(value) != value:
        raise NodeConfigError(name, f"must be an integer, got {value!r}")
    if not math.isfinite(value):
        raise NodeConfigError(name, f"must be finite, got {value!r}")
    if not lo <= value <= hi:
        raise NodeConfigError(name, f"must be in [{lo:g}, {hi:g}], got {value!r}")
    return int(value) if integer else float(value)


def _spec_number(name: str, values: Mapping[str, Any]) -> float:
    spec = NODE_SPECS[name]
    return _number(name, values[name], *spec.range, integer=spec.kind == "int")


def _choice(name: str, value: Any, choices: tuple) -> str:
    if value not in choices:
        raise NodeConfigError(name, f"must be one of {', '.join(choices)}, got {value!r}")
    return value


class SceneCache:
    """Scenes by name or path, each loaded once (a node changing back and forth stays cheap),
    and the ``auto`` model choice per scene, parameters and tick rate (its check runs the scene once)."""

    def __init__(self, preload: Mapping[str, Scene] | None = None):
        self._scenes: dict[str, Scene] = dict(preload or {})
        self._choices: dict = {}

    def model_choice(self, name: str, scene: Scene, params: BeltDriveParams, step_rate: float):
        """:func:`~belt_drive_ros.core.fidelity.choose_model` of ``scene`` (scene ``name`` with ``params`` and
        ``step_rate``), computed once per such triple: a runtime change of another parameter (a real-time
        factor, a torque limit) does not rerun the scene inside the executor's callback."""
        key = (name, params, float(step_rate))
        if key not in self._choices:
            if len(self._choices) >= 32:
                self._choices.clear()
            self._choices[key] = choose_model(scene)
        return self._choices[key]

    def get(self, name: str) -> Scene:
        if not isinstance(name, str) or not name:
            raise NodeConfigError("scene", f"must be a scene name or YAML path, got {name!r}")
        if name not in self._scenes:
            try:
                self._scenes[name] = load_scene(name)
            except BeltDriveError as exc:
                raise NodeConfigError("scene", str(exc)) from None
        return self._scenes[name]


def scene_defaults(scene: Scene) -> dict[str, Any]:
    """Values of the scene-derived parameters for ``scene``.

    The model parameters, ``model`` and ``method`` are the scene's; ``substeps``
    is chosen so that at the default 1 kHz tick the integrator step is the
    scene's ``dt`` (at least 1), e.g. 2 for a scene with dt = 0.5 ms.
    """
    default_tick = 1.0 / NODE_SPECS["step_rate_hz"].default
    out = {"model": scene.model, "method": scene.method, "substeps": max(1, int(round(default_tick / scene.dt)))}
    out.update(scene.params.field_values())
    return out


#: the derived torque bound is this many times the scene's largest torque
TORQUE_BOUND_FACTOR = 10.0
#: ... and at least this [N m]
TORQUE_BOUND_FLOOR = 1.0


def scene_torque_bound(scene: Scene, samples: int = 1000) -> float:
    """The plausible drive-torque bound of ``scene`` [N m].

    ``TORQUE_BOUND_FACTOR`` times the largest |torque| of the scene's drive
    and load profiles, sampled at ``samples`` times over its duration (the
    angle swept over four revolutions, the speed at 0 and at the initial
    speed), at least ``TORQUE_BOUND_FLOOR``. A message beyond it is an
    error of the sender, not a load the drive could see; the state would
    only run away on it.
    """
    import numpy as np

    t = np.linspace(0.0, max(scene.duration, 1e-3), samples)
    angle = np.linspace(0.0, 8.0 * math.pi, samples)
    peak = 0.0
    for speed in (0.0, scene.initial_state.omega_M):
        for profile in (scene.drive, scene.load):
            with np.errstate(all="ignore"):
                values = np.abs(np.broadcast_to(profile.torque(t, angle, np.full(samples, speed)), t.shape))
            finite = values[np.isfinite(values)]
            if finite.size:
                peak = max(peak, float(finite.max()))
    return max(TORQUE_BOUND_FACTOR * peak, TORQUE_BOUND_FLOOR)


def default_values(scene: Scene) -> dict[str, Any]:
    """All node parameter values as a fresh node with ``scene`` would have them."""
    values = {s.name: s.default for s in NODE_PARAMETERS}
    values["scene"] = scene.name
    values.update(scene_defaults(scene))
    return values


#: accuracy verdicts by (scene, model, drive source, method, step, options): a change of another parameter reuses it
_ACCURACY: dict = {}


_CHOICES: dict = {}


def node_method_choice(scene: Scene, model, drive_source: str, dt: float):
    """:func:`~belt_drive_ros.core.method_choice.choose_method` on the node's model, drive and step (cached).

    With ``drive_source`` topic the drive is read as 0 plus held steps (as :func:`node_accuracy` does).
    """
    from ..core.method_choice import choose_method
    from ..core.sources import Constant

    drive = scene.drive if drive_source == "scene" else Constant(0.0)
    key = (scene.name, repr(scene.params), model.name, drive_source, dt, repr(drive), repr(scene.load), scene.duration,
           repr(scene.initial_state), scene.tolerance)  # fmt: skip
    if key not in _CHOICES:
        if len(_CHOICES) > 64:
            _CHOICES.clear()
        base = "rigid" if model.name == "rigid" else "flexible"
        x0 = scene.initial_state.vector(base, scene.params.ratio)
        plant = Plant(make_model(base, scene.params), drive, scene.load)
        slipping = (scene.params, drive, scene.load) if model.name == "slipping" else None
        _CHOICES[key] = choose_method(plant, scene.duration, x0, dt, scene.tolerance, drive_source == "scene", slipping)
    return _CHOICES[key]


def node_accuracy(scene: Scene, model, drive_source: str, method: str, dt: float, options: dict) -> AccuracyReport | None:
    """The accuracy guard on the node's model, method and step (raises ``UnstableStepError`` when unstable).

    Rigid and flexible models: :func:`~belt_drive_ros.core.accuracy.require_accurate`
    (closed loop and forcing windows over the scene's duration); the slipping
    model: :func:`~belt_drive_ros.core.accuracy.require_accurate_slipping`
    (stick and slip modes). With ``drive_source`` topic the drive torque is
    held between messages (steps, which the closed-loop check's step response
    covers): the guard reads the drive as 0 plus those steps, rated as unit steps (``stated_inputs=False``;
    the scene's own torques weigh the step response by their steps).
    """
    from ..core.sources import Constant

    drive = scene.drive if drive_source == "scene" else Constant(0.0)
    key = (scene.name, repr(scene.params), model.name, drive_source, method, dt, repr(sorted(options.items())),
           repr(drive), repr(scene.load), scene.duration, repr(scene.initial_state), scene.tolerance)  # fmt: skip
    if key not in _ACCURACY:
        if len(_ACCURACY) > 64:
            _ACCURACY.clear()
        if model.name == "slipping":
            x0 = scene.initial_state.vector("flexible", scene.params.ratio)
            report = require_accurate_slipping(scene.params, drive, scene.load, method, dt, scene.duration, x0,
                                               scene.tolerance, method_options=options, stated_inputs=drive_source == "scene")  # fmt: skip
        else:
            x0 = scene.initial_state.vector(model.name, scene.params.ratio)
            report = require_accurate(Plant(model, drive, scene.load), method, dt, scene.duration, x0, scene.tolerance,
                                      method_options=options,
                                      stated_inputs=drive_source == "scene")  # fmt: skip
        _ACCURACY[key] = report
    return _ACCURACY[key]


def build_settings(values: Mapping[str, Any], scenes: SceneCache | None = None) -> NodeSettings:
    """Validate a full set of parameter values and derive the node's settings.

    Raises
    ------
    NodeConfigError (a ParameterError, ValueError)
        naming the parameter and the reason; the stability guard's refusal
        (``UnstableStepError``) is reported against ``method``.
    """
    scenes = scenes or SceneCache()
    scene = scenes.get(values["scene"])
    step_rate = _spec_number("step_rate_hz", values)
    substeps = _spec_number("substeps", values)
    timeout = _spec_number("input_timeout", values)
    limit = _spec_number("torque_limit", values)
    bound = _spec_number("torque_bound", values)
    rtf = _spec_number("real_time_factor", values)
    behavior = _choice("timeout_behavior", values["timeout_behavior"], TIMEOUT_BEHAVIORS)
    drive_source = _choice("drive_source", values["drive_source"], DRIVE_SOURCES)
    kind = _choice("model", values["model"], MODELS)
    publish_clock = values["publish_clock"]
    if not isinstance(publish_clock, bool):
        raise NodeConfigError("publish_clock", f"must be true or false, got {publish_clock!r}")
    tick_lead = _spec_number("tick_lead", {"tick_lead": values.get("tick_lead", NODE_SPECS["tick_lead"].default)})
    tick_thread = values.get("tick_thread", NODE_SPECS["tick_thread"].default)
    if not isinstance(tick_thread, bool):
        raise NodeConfigError("tick_thread", f"must be true or false, got {tick_thread!r}")
    record_path = values["record_path"]
    if not isinstance(record_path, str):
        raise NodeConfigError("record_path", f"must be a string, got {record_path!r}")
    overwrite = values.get("record_overwrite", False)
    if not isinstance(overwrite, bool):
        raise NodeConfigError("record_overwrite", f"must be true or false, got {overwrite!r}")
    bag_duration = _spec_number("max_bag_duration", {"max_bag_duration": values.get("max_bag_duration", 0.0)})
    bag_size = _spec_number("max_bag_size", {"max_bag_size": values.get("max_bag_size", 0)})
    check_record_path(record_path, bool(bag_duration or bag_size), values.get("scene"))
    model_values = {name: values[name] for name in MODEL_PARAMETERS}
    for name, value in model_values.items():  # BeltDriveParams checks the rest of its rules
        upper = model_range(name)[1]
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value > upper:
            raise NodeConfigError(name, f"must be <= {upper:g} {FIELD_DOCS[name][0]}, got {value!r}")
    try:
        params = BeltDriveParams(**model_values).check_plausible()  # (the lower ends too: r_3 = 1e-300 m overflowed)
    except ParameterError as exc:
        raise NodeConfigError(exc.field, exc.detail) from None
    tick_ns = int(round(1e9 / step_rate))
    dt_ns = tick_ns // substeps
    if dt_ns < 1000:
        raise NodeConfigError("substeps", f"step_rate_hz*substeps gives dt={dt_ns} ns; keep dt >= 1 us")
    scene = scene.with_overrides(params=params, output_rate=step_rate)
    if kind == "auto":
        choice = scenes.model_choice(values["scene"], scene, params, step_rate)  # the scene's run decides on slipping
        kind, reason = choice.model, choice.reason
    else:
        reason = f"{kind}: set by parameter 'model'"
    model = make_model(kind, params)
    method = values["method"]
    if not isinstance(method, str):
        raise NodeConfigError("method", f"must be an integrator name, got {method!r}")
    method_reason = f"{method}: set by parameter 'method'" if method != AUTO else ""
    if method == AUTO:  # the guard chooses method and substeps at this tick (core/method_choice.py)
        choice = node_method_choice(scene, model, drive_source, dt_ns / 1e9)
        method, method_reason = choice.method, choice.reason
        if choice.substeps > 1 and tick_ns // (substeps * choice.substeps) >= 1000:
            substeps *= choice.substeps
            dt_ns = tick_ns // substeps
    options = dict(scene.method_options) if method == scene.method else {}
    try:
        integrator = make_integrator(method, model.A, model.B, dt_ns / 1e9, **options)
        stability = require_stable(model.A, model.B, method, dt_ns / 1e9)
        accuracy = node_accuracy(scene, model, drive_source, method, dt_ns / 1e9, options)
    except ValueError as exc:  # IntegratorError, UnstableStepError
        raise NodeConfigError("method", str(exc).removeprefix("method: ")) from None
    return NodeSettings(
        values=dict(values),
        scene=scene,
        params=params,
        model=model,
        model_reason=reason,
        method=integrator.name,
        tick_ns=tick_ns,
        dt_ns=dt_ns,
        integrator=integrator,
        stability=stability,
        accuracy=accuracy,
        method_reason=method_reason,
        step_rate_hz=step_rate,
        substeps=substeps,
        input_timeout_ns=int(round(timeout * 1e9)),
        timeout_behavior=behavior,
        drive_source=drive_source,
        torque_limit=limit,
        torque_bound=bound if bound > 0 else scene_torque_bound(scene),
        publish_clock=publish_clock,
        tick_thread=tick_thread,
        tick_lead_ns=min(int(round(tick_lead * 1e9)), tick_ns * 3 // 4),
        real_time_factor=rtf,
        record_path=record_path,
        method_options=options,
        record_overwrite=overwrite,
        max_bag_duration=bag_duration,
        max_bag_size=int(bag_size),
    )


def describe_parameters(scene_name: str = DEFAULT_SCENE) -> str:
    """Text table of the node's parameters (defaults for ``scene_name``): what ``--list-parameters`` prints."""
    scene = load_scene(scene_name)
    values = default_values(scene)
    lines = [f"parameters of belt-drive node (defaults for scene '{scene.name}'):"]
    for spec in NODE_PARAMETERS:
        extra = ""
        if spec.range:
            extra = f" range [{spec.range[0]:g}, {spec.range[1]:g}]"
        elif spec.choices:
            extra = f" one of {', '.join(spec.choices)}"
        lines.append(f"  {spec.name:<18} = {values[spec.name]!r:<14}{extra}  {spec.description}")
    lines.append("model parameters (BeltDriveParams, SI units):")
    for name, (unit, text) in FIELD_DOCS.items():
        lo, hi = model_range(name)
        lines.append(f"  {name:<18} = {values[name]!r:<14} [{unit}] range [{lo:g}, {hi:g}]  {text}")
    lines.append("  use_sim_time       = False          follow /clock (rclpy)")
    return "\n".join(lines)
