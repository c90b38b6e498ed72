"""The belt-drive ROS 2 node: the model core stepped on the node's clock.

:class:`BeltDriveNode` is a plain ``rclpy.node.Node`` (composable into any
executor, any number per process). Topic names are relative, so namespaces
and remaps apply.

Interface (SI units, REP 103)
-----------------------------
=====================  ======  ==============================================
topic                  dir     type / meaning
=====================  ======  ==============================================
``drive_torque``       sub     ``std_msgs/Float64``: torque on drive wheel M [N m]
``shaft_speed``        pub     ``std_msgs/Float64``: omega_M [rad/s]
``load_torque``        pub     ``std_msgs/Float64``: load torque at wheel 3 [N m]
``belt_torque``        pub     ``std_msgs/Float64``: torque of the belt on wheel 3 [N m]
``relative_deflection`` pub    ``std_msgs/Float64``: ``i phi_M - phi_3`` [rad]
``joint_states``       pub     ``sensor_msgs/JointState``, stamped with the tick's time
``/diagnostics``       pub     ``diagnostic_msgs/DiagnosticArray`` (~1 Hz wall clock)
``/clock``             pub     ``rosgraph_msgs/Clock``, only with ``publish_clock``
``~/reset``            srv     ``std_srvs/Trigger``: restart from the scene's initial state
=====================  ======  ==============================================

``joint_states`` carries the joints ``wheel_M, wheel_1, wheel_2, wheel_3``:
position [rad] and velocity [rad/s] of each wheel, and as *effort* the
external torque on the wheel along its positive rotation [N m]: the drive
torque on ``wheel_M``, 0 on the idler gears ``wheel_1`` and ``wheel_2`` (they
carry only internal mesh forces), and minus the load torque on ``wheel_3``.
The belt's own torque on wheel 3 is on ``belt_torque``.

Time
----
A timer on the node's clock (never a wall timer) ticks at ``step_rate_hz``.
Each tick integrates from the last integrated time *exactly to*
``clock.now()``: whole substeps of ``dt = 1 / (step_rate_hz * substeps)``
(truncated to whole nanoseconds) plus one final partial step, then publishes
every output stamped with that time. A late tick therefore integrates a
longer interval; lateness never accumulates into drift. On the system clock
"now" is truncated to whole microseconds (far below the timer's jitter), so
the partial steps repeat and their matrices come from a cache instead of a
fresh matrix exponential per tick; simulated time is used to the nanosecond.

* real time (default): the system clock.
* ``use_sim_time:=true``: the node follows ``/clock``. A ``/clock`` jump past
  a tick makes the timer fire (once, however far it jumps) and the tick
  integrates to the clock's new time, so the outputs are a deterministic
  function of the ``/clock`` and torque sequences (bit-identical reruns).
  :mod:`belt_drive_ros.ros.harness` drives a node this way.
* ``publish_clock:=true``: the node is the time master. It keeps its own
  simulated time, advances it by whole ticks, paced by a wall (steady) timer
  at ``real_time_factor`` (0: as fast as the CPU allows, in 2 ms slices of
  back-to-back ticks between which inputs are served), and after each
  step publishes the outputs and then ``/clock`` with the *same* time, so a
  node that steps on that ``/clock`` always finds the matching outputs. A
  late wall timer catches up by several whole ticks in one step (at most
  1 s of simulated time; beyond that the pacing re-anchors instead of
  bursting). Stamps and input timeouts use the simulated time. Other nodes
  should run with ``use_sim_time:=true``.

Scene time (what the scene's load profile sees as ``t``) starts at 0 on the
node's first tick and on every restart (``~/reset``, a change of ``scene``,
the clock jumping backwards or switching between system and simulated time).

Inputs
------
The drive torque is the zero-order hold of the latest valid message: the
value held at a tick acts over the interval that tick closes (a message thus
takes effect on the tick grid, less than one tick period from its arrival).
``drive_source:=scene`` instead drives wheel M with the scene's drive profile
(messages then are counted and ignored). Before the first message the torque
is 0 N m. After ``input_timeout`` seconds (node clock; 0 disables) without a
message the torque is held or zeroed (``timeout_behavior``) and a WARN
diagnostic is raised. NaN/Inf messages are rejected and counted; with
``torque_limit`` > 0 the torque is clamped to +/- the limit and counted. The
subscription keeps only the latest message (``KEEP_LAST``, depth 1) and its
callback does constant work, so a burst cannot build a backlog.

A tick sends each output only to topics that have subscribers (tracked with
the publishers' "matched" events; DDS would deliver to nobody otherwise),
which saves most of the publishing cost when only a few outputs are used.

Outputs that depend on the drive torque itself (``joint_states`` effort,
and the rigid model's belt torque, which includes wheel 3's inertial share)
use the torque held at the tick, i.e. the one that acted over the step just
integrated.

Failures
--------
The node never publishes a non-finite value. If the state becomes
non-finite, exceeds :data:`~belt_drive_ros.core.simulate.SPEED_LIMIT`, or the
integrator raises, the node *halts*: it keeps the last finite state, stops
integrating and stops publishing state topics (no stale value is re-stamped
as new), reports ERROR on ``/diagnostics`` with the reason, and keeps
serving parameters and ``~/reset``, which restarts it.

Executors
---------
:func:`make_executor` picks rclpy's ``EventsExecutor`` where present (spun
from the main thread with :func:`spin_until_signal`) and falls back to the
``SingleThreadedExecutor``; lockstep drivers need the latter (see
:mod:`belt_drive_ros.ros.harness`).

Parameters
----------
Every field of :class:`~belt_drive_ros.core.params.BeltDriveParams` (defaults from
the scene) plus the node parameters in :data:`NODE_PARAMETERS`, all with
descriptors and ranges, loadable with ``--ros-args --params-file``. Changes
at runtime are validated as a whole (model, integrator, stability guard) and
rejected with a reason, keeping the old values; accepted changes apply at
once without a restart: the model and integrator are rebuilt, the state is
kept (mapped across a rigid <-> flexible switch; ``model:=auto`` chooses from
the scene's drive and load profiles, i.e. the excitation the scene expects,
and may switch when parameters change), a new ``scene`` resets the
model parameters, ``model``, ``method`` and ``substeps`` to the new scene's values (unless
set in the same request) and restarts from its initial state. ``substeps``
defaults to the scene's ``dt`` at the default 1 kHz tick.
"""

from __future__ import annotations

import gc
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from . import environment as ros_env

ros_env.configure_environment()  # loopback discovery, before any context is initialised

import rclpy  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rcl_interfaces.msg import (  # noqa: E402
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType, JumpThreshold  # noqa: E402
from rclpy.event_handler import PublisherEventCallbacks  # noqa: E402
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.task import Future  # noqa: E402
from rosgraph_msgs.msg import Clock as ClockMsg  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from .qos import CLOCK_QOS, INPUT_QOS, OUTPUT_QOS  # noqa: E402,F401 - re-exported
from ..core.errors import BeltDriveError, ParameterError  # noqa: E402
from ..core.fidelity import choose_model  # noqa: E402
from ..core.integrators import make_integrator  # noqa: E402
from ..core.model import make_model  # noqa: E402
from ..core.params import FIELD_DOCS, BeltDriveParams  # noqa: E402
from ..core.scene import MODELS, Scene, load_scene  # noqa: E402
from ..core.simulate import SPEED_LIMIT, Plant  # noqa: E402
from ..core.sources import TorqueProfile  # noqa: E402
from ..core.stability import StabilityReport, require_stable  # noqa: E402

NODE_NAME = "belt_drive"
JOINT_NAMES = ("wheel_M", "wheel_1", "wheel_2", "wheel_3")
#: Float64 output topics, in publishing order (joint_states is published first).
OUTPUT_TOPICS = ("shaft_speed", "load_torque", "belt_torque", "relative_deflection")
DRIVE_SOURCES = ("topic", "scene")
TIMEOUT_BEHAVIORS = ("hold", "zero")
DEFAULT_SCENE = "paper"


#: [from, to] advertised in the descriptors and enforced on every change
#: (fields that must be > 0 are also checked by BeltDriveParams).
MODEL_PARAM_RANGES: dict[str, tuple[float, float]] = {
    "I_M": (0.0, 1.0e3),
    "I_1": (0.0, 1.0e3),
    "I_2": (0.0, 1.0e3),
    "I_3": (0.0, 1.0e3),
    "r_M": (0.0, 10.0),
    "R_1": (0.0, 10.0),
    "r_1": (0.0, 10.0),
    "R_2": (0.0, 10.0),
    "r_2": (0.0, 10.0),
    "r_3": (0.0, 10.0),
    "k": (0.0, 1.0e10),
    "c": (0.0, 1.0e7),
    "b_M": (0.0, 1.0e4),
    "b_1": (0.0, 1.0e4),
    "b_2": (0.0, 1.0e4),
    "b_3": (0.0, 1.0e4),
    "F_0": (0.0, 1.0e7),
    "mu": (0.0, 10.0),
    "wrap_angle": (0.0, 2.0 * math.pi),
    "groove_angle": (0.0, math.pi),
    "belt_mass": (0.0, 100.0),
}


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
    ParamSpec("model", "str", None, "belt model: rigid, flexible or auto (chosen from the scene's excitation)", choices=MODELS),
    ParamSpec("method", "str", None, "integrator: exact, etd2, etd4, lawson5, euler, symplectic_euler, rk4, trapezoidal, RK45, DOP853, Radau, BDF, LSODA"),
    ParamSpec("step_rate_hz", "float", 1000.0, "tick rate on the node's clock [Hz]; outputs are published once per tick", range=(1.0, 20000.0)),
    ParamSpec("substeps", "int", None, "integrator steps per tick (dt = 1/(step_rate_hz*substeps), whole ns); default: the scene's dt at 1 kHz", range=(1, 1000)),
    ParamSpec("input_timeout", "float", 1.0, "seconds (node clock) without drive_torque before timeout_behavior applies; 0 = never", range=(0.0, 3600.0)),
    ParamSpec("timeout_behavior", "str", "hold", "after input_timeout: 'hold' the last torque or 'zero' it", choices=TIMEOUT_BEHAVIORS),
    ParamSpec("drive_source", "str", "topic", "'topic': ZOH of drive_torque (0 before the first message); 'scene': the scene's drive profile", choices=DRIVE_SOURCES),
    ParamSpec("torque_limit", "float", 0.0, "clamp |drive_torque| to this [N m]; 0 = off", range=(0.0, 1.0e7)),
    ParamSpec("publish_clock", "bool", False, "publish /clock from the node's own simulated time (time master)"),
    ParamSpec("real_time_factor", "float", 1.0, "with publish_clock: simulated seconds per wall second; 0 = as fast as possible", range=(0.0, 1.0e4)),
    ParamSpec("record_path", "str", "", "MCAP file to record the node's input and outputs to ('' = off); set at start only, an existing file is never overwritten"),
)
_NODE_SPECS = {s.name: s for s in NODE_PARAMETERS}
MODEL_PARAMETERS: tuple[str, ...] = tuple(FIELD_DOCS)
#: every parameter the node owns (use_sim_time belongs to rclpy's TimeSource)
OWN_PARAMETERS: tuple[str, ...] = tuple(_NODE_SPECS) + MODEL_PARAMETERS
#: parameters whose default comes from the scene and that a new scene resets
SCENE_DERIVED: tuple[str, ...] = ("model", "method", "substeps") + MODEL_PARAMETERS
#: on the system clock a tick integrates to now truncated to whole microseconds
#: (the timer's own jitter is larger), so the partial-step matrices repeat
SYSTEM_TIME_QUANTUM_NS = 1000
#: partial-step integrators kept (one per distinct remainder) before the cache is dropped
PARTIAL_CACHE_SIZE = 4096
#: publish_clock as fast as possible: ticks run back to back for this much wall
#: time per callback of a wall timer of this period, then the executor serves inputs
FREE_RUN_SLICE_S = 0.002
FREE_RUN_PERIOD_S = 0.0005
#: a publish_clock tick may catch up at most this much simulated time [ns]
#: after the wall timer was late; beyond it the pacing re-anchors.
MAX_CATCH_UP_NS = 1_000_000_000


class NodeConfigError(ParameterError):
    """A node parameter (or the combination) is invalid; ``field`` names the parameter."""


# ----------------------------------------------------------------- settings
class HeldTorque(TorqueProfile):
    """Zero-order hold of the latest drive-torque message: a profile whose value the node sets [N m].

    Mutable on purpose (unlike the scene's frozen profiles): the plant's
    input function reads :attr:`value` at every call.
    """

    kind = "held"
    state_dependent = False

    def __init__(self, value: float = 0.0):
        self.value = float(value)

    def torque(self, t, angle=0.0, speed=0.0):
        return self.value + 0.0 * np.asarray(t, dtype=float) if np.ndim(t) else self.value

    __call__ = torque

    def scalar_torque(self):
        held = self
        return lambda t, angle, speed: held.value

    def excitation_frequencies(self, speed):
        return []

    def to_dict(self):
        return {"type": "constant", "value": self.value}


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
    publish_clock: bool
    real_time_factor: float
    record_path: str
    method_options: dict = field(default_factory=dict)
    output_map: tuple = ()

    @property
    def dt(self) -> float:
        """Integrator substep [s]."""
        return self.dt_ns / 1e9


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


def _choice(name: str, value: Any, choices: tuple) -> str:
    if value not in choices:
        raise NodeConfigError(name, f"must be one of {', '.join(choices)}, got {value!r}")
    return value


class SceneCache:
    """Scenes by name or path, each loaded once (a node changing back and forth stays cheap)."""

    def __init__(self, preload: Mapping[str, Scene] | None = None):
        self._scenes: dict[str, Scene] = dict(preload or {})

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
    default_tick = 1.0 / _NODE_SPECS["step_rate_hz"].default
    out = {"model": scene.model, "method": scene.method, "substeps": max(1, int(round(default_tick / scene.dt)))}
    out.update(scene.params.field_values())
    return out


def default_values(scene: Scene) -> dict[str, Any]:
    """All node parameter values as a fresh node with ``scene`` would have them."""
    values = {s.name: s.default for s in NODE_PARAMETERS}
    values["scene"] = scene.name
    values.update(scene_defaults(scene))
    return values


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
    step_rate = _number("step_rate_hz", values["step_rate_hz"], *_NODE_SPECS["step_rate_hz"].range)
    substeps = _number("substeps", values["substeps"], *_NODE_SPECS["substeps"].range, integer=True)
    timeout = _number("input_timeout", values["input_timeout"], *_NODE_SPECS["input_timeout"].range)
    limit = _number("torque_limit", values["torque_limit"], *_NODE_SPECS["torque_limit"].range)
    rtf = _number("real_time_factor", values["real_time_factor"], *_NODE_SPECS["real_time_factor"].range)
    behavior = _choice("timeout_behavior", values["timeout_behavior"], TIMEOUT_BEHAVIORS)
    drive_source = _choice("drive_source", values["drive_source"], DRIVE_SOURCES)
    kind = _choice("model", values["model"], MODELS)
    publish_clock = values["publish_clock"]
    if not isinstance(publish_clock, bool):
        raise NodeConfigError("publish_clock", f"must be true or false, got {publish_clock!r}")
    record_path = values["record_path"]
    if not isinstance(record_path, str):
        raise NodeConfigError("record_path", f"must be a string, got {record_path!r}")
    model_values = {}
    for name in MODEL_PARAMETERS:
        model_values[name] = _number(name, values[name], *MODEL_PARAM_RANGES[name])
    try:
        params = BeltDriveParams(**model_values)
    except ParameterError as exc:
        raise NodeConfigError(exc.field, exc.detail) from None
    tick_ns = int(round(1e9 / step_rate))
    dt_ns = tick_ns // substeps
    if dt_ns < 1000:
        raise NodeConfigError("substeps", f"step_rate_hz*substeps gives dt={dt_ns} ns; keep dt >= 1 us")
    scene = scene.with_overrides(params=params, output_rate=step_rate)
    if kind == "auto":
        choice = choose_model(scene)
        kind, reason = choice.model, choice.reason
    else:
        reason = f"{kind}: set by parameter 'model'"
    if kind == "slipping":  # the slipping tier runs offline (belt-drive sim); the node's tick has no events yet
        raise NodeConfigError("model", "slipping runs offline only (belt-drive sim); choose rigid, flexible or auto")
    model = make_model(kind, params)
    method = values["method"]
    if not isinstance(method, str):
        raise NodeConfigError("method", f"must be an integrator name, got {method!r}")
    options = dict(scene.method_options) if method == scene.method else {}
    try:
        integrator = make_integrator(method, model.A, model.B, dt_ns / 1e9, **options)
        stability = require_stable(model.A, model.B, method, dt_ns / 1e9)
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
        step_rate_hz=step_rate,
        substeps=substeps,
        input_timeout_ns=int(round(timeout * 1e9)),
        timeout_behavior=behavior,
        drive_source=drive_source,
        torque_limit=limit,
        publish_clock=publish_clock,
        real_time_factor=rtf,
        record_path=record_path,
        method_options=options,
        output_map=output_map(model),
    )


#: the signals of one tick, in the order of :func:`output_map`'s rows
TICK_OUTPUTS = (
    "phi_M", "phi_1", "phi_2", "phi_3", "omega_M", "omega_1", "omega_2", "omega_3",
    "drive_torque", "load_torque", "belt_torque", "relative_deflection",
)


def output_map(model) -> tuple[np.ndarray, np.ndarray]:
    """(C, D) with ``y = C x + D u`` for the signals :data:`TICK_OUTPUTS` of ``model``.

    Every one of them is linear in the state and the torques, so the model's
    own :meth:`outputs` evaluated on unit vectors gives the matrices exactly;
    per tick the node then needs one small product instead of a dozen numpy
    scalar operations (the equality tests against the offline simulator cover
    the identity to rounding).
    """
    n, m = model.n_states, model.B.shape[1]
    basis = np.vstack([np.hstack([np.eye(n), np.zeros((n, m))]), np.hstack([np.zeros((m, n)), np.eye(m)])])
    out = model.outputs(basis[:, :n], basis[:, n:])
    Y = np.column_stack([np.asarray(out[name], dtype=float) for name in TICK_OUTPUTS]).T  # (12, n + m)
    return np.ascontiguousarray(Y[:, :n]), np.ascontiguousarray(Y[:, n:])


def _descriptor(name: str) -> ParameterDescriptor:
    if name in MODEL_PARAM_RANGES:
        unit, text = FIELD_DOCS[name]
        lo, hi = MODEL_PARAM_RANGES[name]
        return ParameterDescriptor(
            name=name,
            type=ParameterType.PARAMETER_DOUBLE,
            description=f"{text} [{unit}]",
            additional_constraints=f"finite, in [{lo:g}, {hi:g}] {unit}; integers accepted",
            floating_point_range=[FloatingPointRange(from_value=lo, to_value=hi, step=0.0)],
            dynamic_typing=True,  # so `-p k:=300000` (an integer) is accepted
        )
    spec = _NODE_SPECS[name]
    d = ParameterDescriptor(name=name, description=spec.description)
    if spec.kind == "float":
        d.type = ParameterType.PARAMETER_DOUBLE
        d.floating_point_range = [FloatingPointRange(from_value=spec.range[0], to_value=spec.range[1], step=0.0)]
        d.additional_constraints = f"in [{spec.range[0]:g}, {spec.range[1]:g}]; integers accepted"
        d.dynamic_typing = True
    elif spec.kind == "int":
        d.type = ParameterType.PARAMETER_INTEGER
        d.integer_range = [IntegerRange(from_value=spec.range[0], to_value=spec.range[1], step=1)]
    elif spec.kind == "bool":
        d.type = ParameterType.PARAMETER_BOOL
    else:
        d.type = ParameterType.PARAMETER_STRING
        if spec.choices:
            d.additional_constraints = "one of " + ", ".join(spec.choices)
    return d


def _stamp(msg_time, ns: int) -> None:
    msg_time.sec, msg_time.nanosec = divmod(int(ns), 1_000_000_000)


class _Window:
    """Counters of one diagnostics window (reset after each publish)."""

    def __init__(self):
        self.ticks = 0
        self.overruns = 0
        self.late_ticks = 0
        self.slack = 0
        self.slip = 0
        self.wall = time.perf_counter()


# --------------------------------------------------------------------- node
class BeltDriveNode(Node):
    """The belt drive as a ROS 2 node (see the module docstring for its interface).

    Parameters
    ----------
    node_name : str
        Default ``belt_drive``.
    scene : str, optional
        Scene name or path; overrides the ``scene`` parameter (and a params file).
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``namespace``,
        ``parameter_overrides``, ``cli_args``, ...).

    Raises
    ------
    NodeConfigError
        When the parameters given at start are invalid (the message names
        the parameter); the node is destroyed again before raising.

    Example
    -------
    >>> node = BeltDriveNode(context=ctx, parameter_overrides=[Parameter("use_sim_time", value=True)])
    >>> executor = make_executor(ctx); executor.add_node(node); executor.spin()
    """

    def __init__(self, node_name: str = NODE_NAME, *, scene: str | None = None, **kwargs):
        if scene is not None:
            overrides = [p for p in kwargs.pop("parameter_overrides", None) or [] if p.name != "scene"]
            kwargs["parameter_overrides"] = overrides + [Parameter("scene", value=str(scene))]
        super().__init__(node_name, **kwargs)
        self._recorder = None  # recording.NodeRecorder when record_path is set (created below)
        self._scenes = SceneCache()
        self._pending: tuple[NodeSettings, set] | None = None
        self._tick_timer = None
        self._pace_timer = None
        self._free_run = None
        try:
            self._settings = self._declare_all()
        except BaseException:
            self.destroy_node()
            raise
        s = self._settings

        # -- simulation state (owned here; the model is stateless) --
        self._held = HeldTorque(0.0)
        self._plant = self._make_plant(s)
        self._x = s.scene.initial_state.vector(s.model.name, s.params.ratio)
        self._t_ns: int | None = None  # integrated-to time [ns on the node's time base]; None: not started
        self._origin_ns = 0  # scene time 0
        self._sim_ns = 0  # publish_clock: the node's own simulated time
        self._anchor = (0, 0)  # publish_clock pacing: (sim ns, monotonic ns)
        self._partials: dict[int, Any] = {}
        self._halted: str | None = None
        self._last: dict[str, float] = {}
        # -- input state --
        self._last_input_ns: int | None = None
        self._stale = False
        self.counters = dict.fromkeys(
            (
                "ticks", "published", "received", "rejected_nonfinite", "clamped", "ignored",
                "timeouts", "overruns", "late_ticks", "restarts", "clock_jumps", "halts",
                "slack_ticks", "slip_ticks",
            ),
            0,
        )
        self._window = _Window()
        self._periods = np.zeros(4096)  # the last 4096 tick intervals [s of wall time]
        self._n_periods = 0
        self._prev_tick_wall: float | None = None

        # -- interface --
        # readers per output topic, kept by "matched" events: a tick serializes and sends only
        # to topics somebody subscribes to (DDS would deliver to nobody anyway)
        self._readers = dict.fromkeys(("joint_states",) + OUTPUT_TOPICS, 0)

        def matched(name):
            def on_matched(info):
                self._readers[name] = info.current_count

            return PublisherEventCallbacks(matched=on_matched)

        self._pub_joint = self.create_publisher(
            JointState, "joint_states", OUTPUT_QOS, event_callbacks=matched("joint_states")
        )
        self._pub_float = {
            name: self.create_publisher(Float64, name, OUTPUT_QOS, event_callbacks=matched(name))
            for name in OUTPUT_TOPICS
        }
        self.refresh_subscriber_counts()
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._pub_clock = None
        self._msg_joint = JointState(name=list(JOINT_NAMES))
        self._msg_float = {name: Float64() for name in OUTPUT_TOPICS}
        self._sub_torque = self.create_subscription(Float64, "drive_torque", self._on_drive_torque, INPUT_QOS)
        self._srv_reset = self.create_service(Trigger, "~/reset", self._on_reset)
        self._diag_timer = self.create_timer(1.0, self.publish_diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=None, on_clock_change=True), post_callback=self._on_clock_change
        )
        self.add_pre_set_parameters_callback(self._on_pre_set)
        self.add_on_set_parameters_callback(self._on_validate)
        self.add_post_set_parameters_callback(self._on_post_set)
        self._configure_timing()
        self.get_logger().info(
            f"scene '{s.scene.name}', model {s.model.name} ({s.model_reason}); {s.stability.describe()}; "
            f"{s.step_rate_hz:g} Hz x {s.substeps} substep(s)"
            + (", publishing /clock" if s.publish_clock else "")
            + (", use_sim_time" if self._use_sim_time() else "")
        )
        if s.record_path:
            from ..io.recording import BagError
            from .recorder import NodeRecorder

            try:
                self._recorder = NodeRecorder(self, s.record_path)
                self.get_logger().info(f"recording to {s.record_path}")
            except BagError as exc:  # file exists (never overwritten) or cannot be created
                self.get_logger().error(f"record_path: {exc}; not recording")

    # ------------------------------------------------------------ parameters
    def _declare_all(self) -> NodeSettings:
        scene_desc = _descriptor("scene")
        scene_name = self.declare_parameter("scene", DEFAULT_SCENE, scene_desc).value
        scene = self._scenes.get(scene_name)
        defaults = default_values(scene)
        for name in OWN_PARAMETERS:
            if name == "scene":
                continue
            try:
                self.declare_parameter(name, defaults[name], _descriptor(name))
            except InvalidParameterValueException as exc:  # outside the descriptor's range
                text = str(exc).removesuffix(f": {name}").split("Reason: ", 1)[-1]
                raise NodeConfigError(name, text) from None
            except InvalidParameterTypeException as exc:
                raise NodeConfigError(name, f"wrong type: {str(exc).removesuffix(f': {name}')}") from None
        return build_settings(self._current_values(), self._scenes)

    def _current_values(self) -> dict[str, Any]:
        return {name: self.get_parameter(name).value for name in OWN_PARAMETERS}

    def _on_pre_set(self, parameters: list[Parameter]) -> list[Parameter]:
        """A new ``scene`` brings its model parameters, model and method unless set alongside."""
        new_scene = next((p for p in parameters if p.name == "scene"), None)
        if new_scene is None or new_scene.value == self.get_parameter("scene").value:
            return parameters
        try:
            scene = self._scenes.get(new_scene.value)
        except BeltDriveError:
            return parameters  # _on_validate reports it
        named = {p.name for p in parameters}
        extra = [Parameter(n, value=v) for n, v in scene_defaults(scene).items() if n not in named]
        return list(parameters) + extra

    def _on_validate(self, parameters: list[Parameter]) -> SetParametersResult:
        self._pending = None
        values = self._current_values()
        changed = set()
        for p in parameters:
            if p.name not in values:
                continue  # not ours (use_sim_time, qos overrides, ...)
            if p.type_ == Parameter.Type.NOT_SET:
                return SetParametersResult(successful=False, reason=f"{p.name}: cannot be undeclared")
            if p.name == "record_path" and p.value != values[p.name]:
                return SetParametersResult(
                    successful=False, reason="record_path: set at start only (restart the node to record elsewhere)"
                )
            values[p.name] = p.value
            changed.add(p.name)
        if not changed:
            return SetParametersResult(successful=True)
        try:
            settings = build_settings(values, self._scenes)
        except (BeltDriveError, ValueError) as exc:
            self.get_logger().warn(f"rejected parameter change: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        self._pending = (settings, changed)
        return SetParametersResult(successful=True)

    def _on_post_set(self, parameters: list[Parameter]) -> None:
        if self._pending is None:
            return
        settings, changed = self._pending
        self._pending = None
        self._apply_settings(settings, changed)

    def _apply_settings(self, new: NodeSettings, changed: set) -> None:
        old = self._settings
        self._settings = new
        self._plant = self._make_plant(new)
        self._partials.clear()
        if new.scene.name != old.scene.name or "scene" in changed:
            self._restart("scene changed")
        elif new.model.name != old.model.name:
            self._x = self._map_state(self._x, old.model, new.model)
        else:
            new.integrator.reset()
        if changed & {"step_rate_hz", "publish_clock", "real_time_factor"}:
            self._configure_timing(was_publishing_clock=old.publish_clock)
        self.get_logger().info(
            f"parameters {', '.join(sorted(changed))} applied: model {new.model.name} ({new.model_reason}); "
            f"{new.stability.describe()}"
        )

    def _map_state(self, x: np.ndarray, old_model, new_model) -> np.ndarray:
        """State of ``old_model`` expressed for ``new_model`` (rigid <-> flexible)."""
        if old_model.name == new_model.name:
            return x
        if new_model.name == "rigid":
            return new_model.state_from_flexible(x)
        return new_model.state_from_rigid(x, load_torque=self._last.get("load_torque", 0.0))

    def _make_plant(self, s: NodeSettings) -> Plant:
        drive = s.scene.drive if s.drive_source == "scene" else self._held
        return Plant(s.model, drive, s.scene.load)

    @property
    def settings(self) -> NodeSettings:
        """The validated settings in force (read-only view)."""
        return self._settings

    # ------------------------------------------------------------------ time
    def _use_sim_time(self) -> bool:
        """True while the node's clock follows /clock (cached; updated on clock changes)."""
        cached = getattr(self, "_sim_time_active", None)
        if cached is None:
            cached = self._sim_time_active = bool(self.get_clock().ros_time_is_active)
        return cached

    def _now_ns(self) -> int:
        """Now on the node's time base: simulated time with publish_clock, else the node's clock."""
        if self._settings.publish_clock:
            return self._sim_ns
        return self.get_clock().now().nanoseconds

    def _configure_timing(self, was_publishing_clock: bool = False) -> None:
        """(Re)create the tick source for the current settings."""
        for attr in ("_tick_timer", "_pace_timer", "_free_run"):
            timer = getattr(self, attr)
            if timer is not None:
                self.destroy_timer(timer)
                setattr(self, attr, None)
        s = self._settings
        if s.publish_clock:
            if self._pub_clock is None:
                self._pub_clock = self.create_publisher(ClockMsg, "/clock", CLOCK_QOS)
            if self._t_ns is not None:
                self._sim_ns = self._t_ns  # continue from where the node's time base was
            self._anchor = (self._sim_ns, time.monotonic_ns())
            if s.real_time_factor > 0:
                period = s.tick_ns / s.real_time_factor / 1e9
                self._pace_timer = self.create_timer(period, self._on_pace, clock=Clock(clock_type=ClockType.STEADY_TIME))
            else:  # as fast as possible: slices of ticks from a short wall timer (no guard
                # conditions: the events executor does not support them)
                self._free_run = self.create_timer(
                    FREE_RUN_PERIOD_S, self._on_free_run, clock=Clock(clock_type=ClockType.STEADY_TIME)
                )
        else:
            if was_publishing_clock and self._t_ns is not None:
                self._t_ns = None  # leaving our own time base: restart on the node clock at its next tick
            self._tick_timer = self.create_timer(s.tick_ns / 1e9, self._on_tick)
        self._prev_tick_wall = None

    def _on_clock_change(self, jump) -> None:
        """ROS time (de)activated (use_sim_time toggled): restart on the new time base."""
        self._sim_time_active = None  # re-read on the next use
        if not self._settings.publish_clock and self._t_ns is not None:
            self._t_ns = None
            self.counters["clock_jumps"] += 1

    def refresh_subscriber_counts(self) -> dict[str, int]:
        """Query the readers of each output topic now (the "matched" events keep them current
        afterwards); a driver that has just subscribed calls this before the next tick."""
        self._readers["joint_states"] = self._pub_joint.get_subscription_count()
        for name, pub in self._pub_float.items():
            self._readers[name] = pub.get_subscription_count()
        return dict(self._readers)

    def tick_pending(self) -> bool:
        """True while the tick timer is due but its callback has not run yet (for lockstep drivers)."""
        timer = self._tick_timer
        if timer is None or timer.is_canceled():
            return False
        remaining = timer.time_until_next_call()
        return remaining is not None and remaining <= 0

    @property
    def integrated_ns(self) -> int | None:
        """Time [ns, node time base] the state is integrated to (None before the first tick)."""
        return self._t_ns

    @property
    def origin_ns(self) -> int:
        """Node time [ns] of scene time 0."""
        return self._origin_ns

    @property
    def halted(self) -> str | None:
        """Reason the node halted (diverged), or None while it runs."""
        return self._halted

    @property
    def drive_torque(self) -> float:
        """The zero-order-held drive torque [N m] (after limit and timeout rules)."""
        return self._held.value

    @property
    def state(self) -> np.ndarray:
        """Copy of the model state (ordering: :mod:`belt_drive_ros.core.model`)."""
        return np.array(self._x, copy=True)

    # ----------------------------------------------------------------- ticks
    def _on_tick(self) -> None:
        start = time.perf_counter()
        now = self.get_clock().now().nanoseconds
        if not self._use_sim_time():
            now -= now % SYSTEM_TIME_QUANTUM_NS  # see the module docstring (Time)
        self._advance_to(now)
        self._tick_timing(start)

    def _on_pace(self) -> None:
        """publish_clock with real_time_factor > 0: simulated time follows the wall clock x factor."""
        start = time.perf_counter()
        s = self._settings
        anchor_sim, anchor_wall = self._anchor
        elapsed = int((time.monotonic_ns() - anchor_wall) * s.real_time_factor)
        target = anchor_sim + (elapsed // s.tick_ns) * s.tick_ns
        if target <= self._sim_ns:
            return
        if target - self._sim_ns > MAX_CATCH_UP_NS:  # wall timer starved: re-anchor, do not burst
            self.counters["late_ticks"] += 1
            target = self._sim_ns + s.tick_ns
            self._anchor = (target, time.monotonic_ns())
        self._sim_ns = target
        self._advance_to(target)
        self._tick_timing(start)

    def _on_free_run(self) -> None:
        """publish_clock with real_time_factor = 0: whole ticks back to back for one slice of wall time.

        Between slices the executor serves inputs, services and parameters.
        """
        end = time.perf_counter() + FREE_RUN_SLICE_S
        tick_ns = self._settings.tick_ns
        while True:
            start = time.perf_counter()
            self._sim_ns += tick_ns
            self._advance_to(self._sim_ns)
            self._tick_timing(start)
            if start >= end or self._halted is not None:
                break

    def _tick_timing(self, start: float) -> None:
        end = time.perf_counter()
        w = self._window
        w.ticks += 1
        self.counters["ticks"] += 1
        if self._prev_tick_wall is not None:
            interval = start - self._prev_tick_wall
            self._periods[self._n_periods % self._periods.size] = interval
            self._n_periods += 1
            nominal = self._settings.tick_ns / 1e9
            if self._settings.publish_clock and self._settings.real_time_factor > 0:
                nominal /= self._settings.real_time_factor
            if not self._use_sim_time() and not (self._settings.publish_clock and self._settings.real_time_factor == 0):
                if interval > 1.5 * nominal:
                    w.late_ticks += 1
                    self.counters["late_ticks"] += 1
                if end - start > nominal:
                    w.overruns += 1
                    self.counters["overruns"] += 1
        self._prev_tick_wall = start

    def _advance_to(self, now_ns: int) -> None:
        """Integrate from the last integrated time exactly to ``now_ns`` and publish."""
        if self._t_ns is None:
            if now_ns == 0 and self._use_sim_time() and not self._settings.publish_clock:
                return  # no /clock received yet
            self._start(now_ns)
            self._publish(now_ns)
            return
        if now_ns < self._t_ns:
            self.counters["clock_jumps"] += 1
            self.get_logger().warn(
                f"clock jumped back {(self._t_ns - now_ns) / 1e9:.6g} s: restarting from the initial state"
            )
            self._start(now_ns)
            self._publish(now_ns)
            return
        if now_ns == self._t_ns:
            return
        if self._halted is not None:
            self._t_ns = now_ns  # follow the clock, integrate nothing
            return
        self._update_input(now_ns)
        try:
            x = self._integrate(self._t_ns, now_ns)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
            self._halt(f"integrator failed at t={(self._t_ns - self._origin_ns) / 1e9:.6g} s: {exc}")
            self._t_ns = now_ns
            return
        values = x.tolist()
        if not (all(map(math.isfinite, values)) and max(map(abs, values[len(values) // 2 :])) <= SPEED_LIMIT):
            self._halt(
                f"state diverged at t={(now_ns - self._origin_ns) / 1e9:.6g} s: {np.array2string(x, precision=4)} "
                f"is non-finite or beyond {SPEED_LIMIT:g} rad/s (method {self._settings.method}, "
                f"dt={self._settings.dt:g} s, drive torque {self._held.value:g} N m)"
            )
            self._t_ns = now_ns
            return
        self._x = x
        self._t_ns = now_ns
        self._publish(now_ns)

    def _integrate(self, t0_ns: int, t1_ns: int) -> np.ndarray:
        """Whole substeps of dt_ns, then one partial step to land exactly on ``t1_ns``."""
        s = self._settings
        x = self._x
        t = t0_ns
        origin = self._origin_ns
        inputs = self._plant.inputs
        full = s.integrator
        dt_ns = s.dt_ns
        with np.errstate(all="ignore"):
            n_full = (t1_ns - t) // dt_ns
            fast = self._compiled_loop() if n_full else None
            if fast is not None:  # the whole substeps in the compiled float loop (same maths as step())
                loop, drive, load = fast
                times = [(t + j * dt_ns - origin) / 1e9 for j in range(n_full + 1)]
                try:
                    flat = loop(times, tuple(x.tolist()), drive, load, SPEED_LIMIT)
                except (ValueError, OverflowError, ZeroDivisionError):
                    flat = None  # a math domain error on a runaway state: redo with numpy, which gives inf/nan
                if flat is not None and len(flat) == n_full * x.size:
                    x = np.array(flat[-x.size :])
                    t += n_full * dt_ns
            while t1_ns - t >= dt_ns:
                x = full.step((t - origin) / 1e9, x, inputs)
                t += dt_ns
            rest = t1_ns - t
            if rest > 0:
                x = self._partial(rest).step((t - origin) / 1e9, x, inputs)
        return x

    def _compiled_loop(self):
        """(loop, drive, load) of the integrator's compiled float loop for the current plant, or None."""
        plant, integrator = self._plant, self._settings.integrator
        cached = self.__dict__.get("_loop_cache")  # (plant, integrator, fast): the objects, so a replaced one never matches
        if cached is None or cached[0] is not plant or cached[1] is not integrator:
            loop = plant.scalar_loop(integrator)
            cached = self._loop_cache = (plant, integrator, None if loop is None else (loop, plant.scalar_drive, plant.scalar_load))
        return cached[2]

    def _partial(self, rest_ns: int):
        """Integrator for a partial step of ``rest_ns`` (exact/etd2 share their expm cache)."""
        it = self._partials.get(rest_ns)
        if it is None:
            if len(self._partials) >= PARTIAL_CACHE_SIZE:
                self._partials.clear()
            s = self._settings
            it = make_integrator(s.method, s.model.A, s.model.B, rest_ns / 1e9, **s.method_options)
            self._partials[rest_ns] = it
        return it

    def _start(self, now_ns: int) -> None:
        s = self._settings
        self._origin_ns = now_ns
        self._t_ns = now_ns
        self._x = s.scene.initial_state.vector(s.model.name, s.params.ratio)
        self._halted = None
        s.integrator.reset()
        self._partials.clear()
        self.counters["restarts"] += 1

    def _restart(self, why: str) -> None:
        """Restart from the initial state now (or at the first tick if not started)."""
        if self._t_ns is None:
            s = self._settings
            self._x = s.scene.initial_state.vector(s.model.name, s.params.ratio)
            self._halted = None
            return
        now = self._now_ns()
        self._start(now)
        self.get_logger().info(f"restarted from the initial state ({why})")
        self._publish(now)

    def _halt(self, reason: str) -> None:
        self._halted = reason
        self.counters["halts"] += 1
        self.get_logger().error(f"simulation halted: {reason}; call ~/reset to restart")
        self.publish_diagnostics()

    # ---------------------------------------------------------------- inputs
    def _on_drive_torque(self, msg: Float64) -> None:
        """Constant-time: validate, clamp, hold. Applied at the next tick."""
        self.counters["received"] += 1
        value = msg.data
        if not math.isfinite(value):
            self.counters["rejected_nonfinite"] += 1
            return
        s = self._settings
        if s.drive_source != "topic":
            self.counters["ignored"] += 1
            return
        if s.torque_limit > 0.0 and abs(value) > s.torque_limit:
            value = math.copysign(s.torque_limit, value)
            self.counters["clamped"] += 1
        self._held.value = value
        self._last_input_ns = self._now_ns()
        self._stale = False

    def _update_input(self, now_ns: int) -> None:
        """Apply input_timeout at tick time ``now_ns``."""
        s = self._settings
        if s.drive_source != "topic" or s.input_timeout_ns <= 0:
            self._stale = False
            return
        since = self._last_input_ns if self._last_input_ns is not None else self._origin_ns
        stale = now_ns - since > s.input_timeout_ns
        if stale and not self._stale:
            self.counters["timeouts"] += 1
            what = "no drive_torque received" if self._last_input_ns is None else "drive_torque stale"
            self.get_logger().warn(
                f"{what} for {(now_ns - since) / 1e9:.3g} s > input_timeout: "
                + ("holding the last value" if s.timeout_behavior == "hold" else "drive torque set to 0")
            )
        if stale and s.timeout_behavior == "zero":
            self._held.value = 0.0
        self._stale = stale

    # -------------------------------------------------------------- outputs
    def _publish(self, now_ns: int) -> None:
        s = self._settings
        model = s.model
        x = self._x
        t = (now_ns - self._origin_ns) / 1e9
        C, D = s.output_map
        with np.errstate(all="ignore"):
            u = self._plant.inputs(t, x)
            values = (C @ x + D @ u).tolist()
        if not all(map(math.isfinite, values)):
            self._halt(f"non-finite output at t={t:.6g} s (drive {values[8]!r}, load {values[9]!r} N m)")
            return
        (phi_M, phi_1, phi_2, phi_3, w_M, w_1, w_2, w_3, drive, load, belt, deflection) = values
        tight, slack_force, slack, slip = model._span_forces(belt)
        slack, slip = bool(slack), bool(slip)
        if slack:
            self._window.slack += 1
            self.counters["slack_ticks"] += 1
        if slip:
            self._window.slip += 1
            self.counters["slip_ticks"] += 1
        js = self._msg_joint
        _stamp(js.header.stamp, now_ns)
        js.position = [phi_M, phi_1, phi_2, phi_3]
        js.velocity = [w_M, w_1, w_2, w_3]
        js.effort = [drive, 0.0, 0.0, -load]
        readers = self._readers
        if readers["joint_states"]:
            self._pub_joint.publish(js)
        msgs = self._msg_float
        for name, v in zip(OUTPUT_TOPICS, (w_M, load, belt, deflection)):
            m = msgs[name]
            m.data = v
            if readers[name]:
                self._pub_float[name].publish(m)
        if self._pub_clock is not None and s.publish_clock:
            c = ClockMsg()
            _stamp(c.clock, now_ns)
            self._pub_clock.publish(c)
        self._last = {
            "time": t,
            "stamp_ns": now_ns,
            "omega_M": w_M,
            "omega_3": w_3,
            "drive_torque": drive,
            "load_torque": load,
            "belt_torque": belt,
            "relative_deflection": deflection,
            "span_force_tight": float(tight),
            "span_force_slack": float(slack_force),
            "slack": slack,
            "slip": slip,
        }
        if self._recorder is not None:
            self._recorder.record(now_ns, js, {name: msgs[name] for name in OUTPUT_TOPICS})
        self.counters["published"] += 1

    # ------------------------------------------------------------ diagnostics
    def diagnostic_status(self) -> list[DiagnosticStatus]:
        """The node's health now: simulation, input and belt statuses (also resets the window counters)."""
        s = self._settings
        c = self.counters
        w = self._window
        now_wall = time.perf_counter()
        span = max(now_wall - w.wall, 1e-9)
        self._window = _Window()
        prefix = self.get_name()
        OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR

        def kv(**items):
            return [KeyValue(key=k, value=str(v)) for k, v in items.items()]

        # period error statistics over the ring buffer
        n = min(self._n_periods, self._periods.size)
        nominal = s.tick_ns / 1e9
        if s.publish_clock and s.real_time_factor > 0:
            nominal /= s.real_time_factor
        if n:
            err = np.abs(self._periods[:n] - nominal) * 1e3
            p50, p99, pmax = (float(v) for v in np.percentile(err, [50, 99, 100]))
        else:
            p50 = p99 = pmax = float("nan")
        rate = w.ticks / span
        realtime = not self._use_sim_time() and not s.publish_clock
        sim_level, sim_msg = OK, "running"
        if self._halted is not None:
            sim_level, sim_msg = ERROR, f"halted: {self._halted}"
        elif self._t_ns is None:
            sim_level, sim_msg = OK, "waiting for the first tick" + (" (no /clock yet)" if self._use_sim_time() else "")
        elif w.overruns > max(1, 0.01 * w.ticks):
            sim_level, sim_msg = WARN, f"{w.overruns} of {w.ticks} ticks took longer than the period"
        elif realtime and w.ticks and rate < 0.95 * s.step_rate_hz and span > 0.5:
            sim_level, sim_msg = WARN, f"achieved {rate:.1f} Hz < 95% of {s.step_rate_hz:g} Hz"
        elif self._recorder is not None and self._recorder.failed:
            sim_level, sim_msg = WARN, f"simulating; {self._recorder.status}"
        sim = DiagnosticStatus(
            level=sim_level,
            name=f"{prefix}: simulation",
            message=sim_msg,
            hardware_id=s.scene.name,
            values=kv(
                scene=s.scene.name,
                model=s.model.name,
                model_reason=s.model_reason,
                method=s.method,
                dt=f"{s.dt:.9g}",
                substeps=s.substeps,
                step_rate_hz=f"{s.step_rate_hz:g}",
                achieved_rate_hz=f"{rate:.2f}",
                stability=s.stability.describe(),
                time_base="publish_clock" if s.publish_clock else ("sim_time" if self._use_sim_time() else "system"),
                sim_time=f"{self._last.get('time', 0.0):.6f}",
                ticks=c["ticks"],
                published=c["published"],
                overruns=c["overruns"],
                late_ticks=c["late_ticks"],
                period_error_ms_p50=f"{p50:.4f}",
                period_error_ms_p99=f"{p99:.4f}",
                period_error_ms_max=f"{pmax:.4f}",
                restarts=c["restarts"],
                clock_jumps=c["clock_jumps"],
                halts=c["halts"],
                recording="off" if self._recorder is None else self._recorder.status,
            ),
        )
        in_level, in_msg = OK, "ok"
        if s.drive_source == "scene":
            in_msg = "drive from the scene's profile; drive_torque ignored"
        elif self._stale:
            in_level = WARN
            in_msg = ("no drive_torque received" if self._last_input_ns is None else "drive_torque stale") + (
                ": holding last value" if s.timeout_behavior == "hold" else ": torque set to 0"
            )
        elif self._last_input_ns is None:
            in_msg = "no drive_torque received yet: 0 N m"
        age = (self._now_ns() - self._last_input_ns) / 1e9 if self._last_input_ns is not None else float("nan")
        inp = DiagnosticStatus(
            level=in_level,
            name=f"{prefix}: input",
            message=in_msg,
            hardware_id=s.scene.name,
            values=kv(
                drive_source=s.drive_source,
                drive_torque=f"{self._held.value:.6g}",
                received=c["received"],
                rejected_nonfinite=c["rejected_nonfinite"],
                clamped=c["clamped"],
                ignored=c["ignored"],
                timeouts=c["timeouts"],
                stale=self._stale,
                last_input_age_s=f"{age:.3f}",
                input_timeout_s=f"{s.input_timeout_ns / 1e9:g}",
                timeout_behavior=s.timeout_behavior,
                torque_limit=f"{s.torque_limit:g}",
            ),
        )
        belt_level, belt_msg = OK, "no slack, no slip"
        if w.slack or w.slip:
            belt_level = WARN
            belt_msg = (
                f"belt {'slack' if w.slack else 'slips'} in {max(w.slack, w.slip)} of {max(w.ticks, 1)} ticks: "
                "the linear model is outside its validity"
            )
        belt = DiagnosticStatus(
            level=belt_level,
            name=f"{prefix}: belt",
            message=belt_msg,
            hardware_id=s.scene.name,
            values=kv(
                slack=self._last.get("slack", False),
                slip=self._last.get("slip", False),
                slack_ticks=c["slack_ticks"],
                slip_ticks=c["slip_ticks"],
                span_force_tight_N=f"{self._last.get('span_force_tight', float('nan')):.6g}",
                span_force_slack_N=f"{self._last.get('span_force_slack', float('nan')):.6g}",
                belt_torque_Nm=f"{self._last.get('belt_torque', float('nan')):.6g}",
                relative_deflection_rad=f"{self._last.get('relative_deflection', float('nan')):.6g}",
                belt_mode_hz=f"{s.params.belt_natural_frequency / (2 * math.pi):.3f}",
            ),
        )
        return [sim, inp, belt]

    def publish_diagnostics(self) -> None:
        """Publish ``/diagnostics`` now (the 1 Hz wall timer calls this too)."""
        msg = DiagnosticArray()
        _stamp(msg.header.stamp, self._now_ns())
        msg.status = self.diagnostic_status()
        self._pub_diag.publish(msg)

    # ------------------------------------------------------------- services
    def _on_reset(self, request, response):
        self.reset()
        response.success = True
        response.message = f"restarted scene '{self._settings.scene.name}' from its initial state"
        return response

    def reset(self) -> None:
        """Restart from the scene's initial state at the current time (clears a halt)."""
        self._halted = None
        self._restart("reset requested")

    def destroy_node(self):
        if getattr(self, "_recorder", None) is not None:
            try:
                self._recorder.close()
            finally:
                self._recorder = None
        return super().destroy_node()


# ------------------------------------------------------------- executors
def make_executor(context=None, kind: str = "auto"):
    """Executor for ``context``: ``events`` (rclpy.experimental.EventsExecutor), ``single`` or ``auto``.

    ``auto`` takes the events executor where this rclpy has it and falls back
    to ``SingleThreadedExecutor``. Spin either from the main thread (the
    events executor ran no callbacks when spun from a background thread in
    the Jazzy wheels). Measured at 1 kHz: events ~998 Hz at ~24 % CPU,
    single-threaded ~992 Hz at ~77 %, multi-threaded collapses (11-40 Hz).
    """
    if kind not in ("auto", "events", "single"):
        raise ValueError(f"executor: must be auto, events or single, got {kind!r}")
    if kind in ("auto", "events"):
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            if kind == "events":
                raise
        else:
            return EventsExecutor(context=context)
    return rclpy.executors.SingleThreadedExecutor(context=context)


def executor_name(executor) -> str:
    """Short name of an executor made by :func:`make_executor`."""
    return "single" if isinstance(executor, rclpy.executors.SingleThreadedExecutor) else "events"


def spin_until(executor, predicate: Callable[[], bool], timeout: float, step: float = 0.01) -> bool:
    """Spin ``executor`` one callback at a time until ``predicate()`` or ``timeout`` [s] of wall time."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=step)
    return True


def spin_until_signal(executor, context=None, poll: float = 0.25) -> int:
    """Spin ``executor`` from the main thread until SIGINT/SIGTERM or context shutdown.

    Returns the signal number (0 if the context was shut down otherwise).
    The handlers only complete a future: shutting down from inside a
    callback hung the Jazzy events executor, so shutdown happens after the
    spin returns. ``poll`` [s] bounds how long a signal can wait for the
    interpreter when no callback runs.
    """
    import signal

    from rclpy.executors import ExternalShutdownException

    context = context or rclpy.get_default_context()
    stop = Future()

    def on_signal(signum, frame):
        if not stop.done():
            stop.set_result(signum)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while not stop.done() and context.ok():
            executor.spin_until_future_complete(stop, timeout_sec=poll)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return int(stop.result()) if stop.done() else 0


def run(
    ros_args: list[str] | None = None,
    scene: str | None = None,
    executor: str = "auto",
    node_name: str = NODE_NAME,
) -> int:
    """Run one :class:`BeltDriveNode` until SIGINT/SIGTERM; return the exit code (0).

    ``ros_args`` are ROS command-line arguments (``--ros-args -p k:=1e5
    --params-file f.yaml -r __ns:=/truck``). Invalid parameters raise
    :class:`NodeConfigError` after rclpy is shut down again.
    """
    from rclpy.signals import SignalHandlerOptions

    ros_env.configure_environment()
    ros_env.limit_blas_threads()
    argv = ["belt-drive-node"] + list(ros_args or [])
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    ex = None
    try:
        node = BeltDriveNode(node_name, scene=scene)
        ex = make_executor(kind=executor)
        ex.add_node(node)
        node.get_logger().info(f"spinning with the {executor_name(ex)} executor")
        gc.collect()
        gc.freeze()  # start-up objects (rclpy, numpy, scipy) leave the collector's scans: shorter GC pauses
        signum = spin_until_signal(ex)
        node.get_logger().info(f"shutting down (signal {signum})" if signum else "shutting down")
        return 0
    finally:
        if ex is not None:
            try:
                ex.shutdown()
            except Exception:  # noqa: BLE001 - shutting down anyway
                pass
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def main(argv: list[str] | None = None) -> int:
    """``python -m belt_drive_ros.ros.node [SCENE] [--ros-args ...]``."""
    import sys

    args = list(sys.argv[1:] if argv is None else argv)
    scene = None
    if args and not args[0].startswith("-"):
        scene = args.pop(0)
    try:
        return run(args, scene=scene)
    except BeltDriveError as exc:
        print(f"belt-drive node: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
