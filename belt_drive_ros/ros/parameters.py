"""The node's ROS parameters: descriptors, declaration and the set-parameters callbacks.

The schema and the validation are ROS-free
(:mod:`belt_drive_ros.ros.parameter_schema`); this module wires them into
rclpy's three callbacks:

* *pre-set*: a new ``scene`` brings its model parameters, ``model``,
  ``method`` and ``substeps`` (unless set in the same request); an integer
  given for a double parameter is turned into a double (the parameter keeps
  its type);
* *on-set*: the full set of values is validated as a whole
  (:func:`~belt_drive_ros.ros.parameter_schema.build_settings`) and the change
  rejected with the reason, keeping the old values;
* *post-set*: the validated settings are handed to the node.
"""

from __future__ import annotations

from typing import Any, Callable

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.parameter import Parameter

from ..core.errors import BeltDriveError
from ..core.params import FIELD_DOCS
from .parameter_schema import (
    DEFAULT_SCENE,
    DOUBLE_PARAMETERS,
    NODE_SPECS,
    OWN_PARAMETERS,
    NodeConfigError,
    NodeSettings,
    START_ONLY,
    SceneCache,
    build_settings,
    default_values,
    model_range,
    refuse_undeclared,
    scene_defaults,
)

__all__ = ["NodeParameters", "declare_read_only", "descriptor"]


def descriptor(name: str) -> ParameterDescriptor:
    """rclpy descriptor of node parameter ``name`` (type, description, range or choices; read-only: ``START_ONLY``)."""
    if name in FIELD_DOCS:
        unit, text = FIELD_DOCS[name]
        lo, hi = model_range(name)
        return ParameterDescriptor(
            name=name,
            type=ParameterType.PARAMETER_DOUBLE,
            description=f"{text} [{unit}]",
            additional_constraints=f"finite, in [{lo:g}, {hi:g}] {unit}; integers accepted (stored as doubles)",
            floating_point_range=[FloatingPointRange(from_value=lo, to_value=hi, step=0.0)],
            dynamic_typing=True,  # so `-p k:=300000` (an integer) is accepted at start
        )
    spec = NODE_SPECS[name]
    d = ParameterDescriptor(name=name, description=spec.description, read_only=name in START_ONLY)
    if spec.kind == "float":
        d.type = ParameterType.PARAMETER_DOUBLE
        d.floating_point_range = [FloatingPointRange(from_value=spec.range[0], to_value=spec.range[1], step=0.0)]
        d.additional_constraints = f"in [{spec.range[0]:g}, {spec.range[1]:g}]; integers accepted (stored as doubles)"
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


def declare_read_only(node, name: str, default: Any, d: ParameterDescriptor, *, double: bool = False) -> Any:
    """Declare ``name`` read-only (``d.read_only``) with the value given at start, or ``default``; its value.

    An integer given for a ``double`` parameter (``-p max_bag_duration:=600``) is stored as a double, as
    :func:`_as_double` does for the writable ones: declared once to read what was given, undeclared and
    declared again, read-only, with that value (a read-only parameter cannot be set after its declaration).
    """
    d.read_only = False
    value = node.declare_parameter(name, default, d).value
    node.undeclare_parameter(name)
    if double and type(value) is int:
        value = float(value)
    d.read_only = True
    return node.declare_parameter(name, value, d, ignore_override=True).value


def _as_double(p: Parameter) -> Parameter:
    """``p`` with an integer value turned into a double, for a double parameter."""
    if p.name in DOUBLE_PARAMETERS and p.type_ == Parameter.Type.INTEGER:
        return Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
    return p


class NodeParameters:
    """Declares the node's parameters and validates every change (see the module docstring).

    Parameters
    ----------
    node : rclpy.node.Node
    apply : callable
        ``apply(settings, changed)`` after an accepted change (``changed``:
        the names of the parameters set).
    """

    def __init__(self, node, apply: Callable[[NodeSettings, set], None]):
        self.node = node
        self.scenes = SceneCache()
        self._apply = apply
        self._pending: tuple[NodeSettings, set] | None = None

    def declare(self) -> NodeSettings:
        """Declare every parameter (defaults from the scene), register the callbacks; the settings.

        Raises
        ------
        NodeConfigError
            naming the parameter, when a value given at start is invalid.
        """
        node = self.node
        scene_name = node.declare_parameter("scene", DEFAULT_SCENE, descriptor("scene")).value
        defaults = default_values(self.scenes.get(scene_name))
        for name in OWN_PARAMETERS:
            if name == "scene":
                continue
            try:
                if name in START_ONLY:
                    declare_read_only(node, name, defaults[name], descriptor(name), double=name in DOUBLE_PARAMETERS)
                else:
                    node.declare_parameter(name, defaults[name], descriptor(name))
            except InvalidParameterValueException as exc:  # outside the descriptor's range
                text = str(exc).removesuffix(f": {name}").split("Reason: ", 1)[-1]
                raise NodeConfigError(name, text) from None
            except InvalidParameterTypeException as exc:
                raise NodeConfigError(name, f"wrong type: {str(exc).removesuffix(f': {name}')}") from None
        # integers given at start (`-p k:=300000`, a params file) become doubles
        retyped = [_as_double(p) for p in node.get_parameters(sorted(DOUBLE_PARAMETERS - set(START_ONLY)))
                   if p.type_ == Parameter.Type.INTEGER]
        if retyped:
            node.set_parameters(retyped)
        settings = build_settings(self.values(), self.scenes)
        node.add_pre_set_parameters_callback(self._on_pre_set)
        node.add_on_set_parameters_callback(self._on_validate)
        node.add_post_set_parameters_callback(self._on_post_set)
        return settings

    def values(self) -> dict[str, Any]:
        """The current value of every parameter the node owns."""
        return {name: self.node.get_parameter(name).value for name in OWN_PARAMETERS}

    def _on_pre_set(self, parameters: list[Parameter]) -> list[Parameter]:
        """The request with a new scene's defaults added; as given on any failure (:meth:`_on_validate` then
        refuses it with the reason). A name the node does not have is refused by name (:func:`refuse_undeclared`)."""
        refuse_undeclared(self.node, parameters)
        try:
            return self._with_scene_defaults(parameters)
        except Exception:  # noqa: BLE001 - an exception here would end the node's executor
            return parameters

    def _with_scene_defaults(self, parameters: list[Parameter]) -> list[Parameter]:
        parameters = [_as_double(p) for p in parameters]
        new_scene = next((p for p in parameters if p.name == "scene"), None)
        if new_scene is None or new_scene.value == self.node.get_parameter("scene").value:
            return parameters
        try:
            scene = self.scenes.get(new_scene.value)
        except BeltDriveError:
            return parameters  # _on_validate reports it
        named = {p.name for p in parameters}
        extra = [_as_double(Parameter(n, value=v)) for n, v in scene_defaults(scene).items() if n not in named]
        return parameters + extra

    def _on_validate(self, parameters: list[Parameter]) -> SetParametersResult:
        """Accept or refuse the change with a reason; never raises (an exception here would end the
        node's executor, and the SetParameters call would never be answered)."""
        try:
            return self._validate(parameters)
        except Exception as exc:  # noqa: BLE001 - any failure is a refusal with its reason
            self._pending = None
            reason = f"refused: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
            self.node.get_logger().error(f"rejected parameter change: {reason}")
            return SetParametersResult(successful=False, reason=reason)

    def _validate(self, parameters: list[Parameter]) -> SetParametersResult:
        self._pending = None
        values = self.values()
        changed = set()
        for p in parameters:
            if p.name not in values:
                continue  # not ours (use_sim_time, qos overrides, ...)
            if p.type_ == Parameter.Type.NOT_SET:
                return SetParametersResult(successful=False, reason=f"{p.name}: cannot be undeclared")
            values[p.name] = p.value
            changed.add(p.name)
        if not changed:
            return SetParametersResult(successful=True)
        try:
            settings = build_settings(values, self.scenes)
        except (BeltDriveError, ValueError, OSError) as exc:
            self.node.get_logger().warn(f"rejected parameter change: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        self._pending = (settings, changed)
        return SetParametersResult(successful=True)

    def _on_post_set(self, parameters: list[Parameter]) -> None:
        if self._pending is None:
            return
        settings, changed = self._pending
        self._pending = None
        try:
            self._apply(settings, changed)
        except Exception as exc:  # noqa: BLE001 - the values are set: say so, do not end the executor
            self.node.get_logger().error(
                f"parameters {', '.join(sorted(changed))} accepted but not applied: {type(exc).__name__}: {exc}")
