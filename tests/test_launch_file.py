"""launch/belt_drive.launch.py and config/belt_drive.yaml name only what exists.

launch and launch_ros are not installed here (no wheels), so the launch file
runs against a small stand-in of their documented API put into
``sys.modules``: ``launch.LaunchDescription``,
``launch.actions.DeclareLaunchArgument``,
``launch.substitutions.LaunchConfiguration`` and
``launch_ros.actions.Node``, whose keyword arguments are launch_ros's own
(an unknown one is a TypeError, as in launch_ros). The stand-in records
the actions; the test then checks each node's package and executable
against what setup.py installs, every parameter name against the node's
schema (belt_drive_ros/ros/parameter_schema.py), the values by the
node's own validation (``build_settings``), and the source's arguments by
``belt-drive source``'s parser. Launch arguments resolve to their defaults;
parameter values given as substitutions are read as YAML, as launch_ros
reads them.
"""

from __future__ import annotations

import ast
import runpy
import sys
import types
from pathlib import Path

import pytest
import yaml

from belt_drive_ros.cli import build_parser
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.ros.parameter_schema import OWN_PARAMETERS, build_settings, default_values

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILE = ROOT / "launch" / "belt_drive.launch.py"
PARAMS_FILE = ROOT / "config" / "belt_drive.yaml"
#: parameters a node has besides its own (rclpy's)
RCLPY_PARAMETERS = {"use_sim_time"}


def _setup_py_executables() -> dict:
    """``ROS_EXECUTABLES`` of setup.py (read, not run: running it would run setuptools)."""
    tree = ast.parse((ROOT / "setup.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.AnnAssign | ast.Assign):
            targets = [node.target] if isinstance(node, ast.AnnAssign) else node.targets
            if any(getattr(t, "id", None) == "ROS_EXECUTABLES" for t in targets):
                return ast.literal_eval(node.value)
    raise AssertionError("setup.py has no ROS_EXECUTABLES")


class LaunchConfiguration:
    def __init__(self, variable_name, *, default=None):
        self.variable_name, self.default = variable_name, default

    def perform(self, context):
        return context.launch_configurations[self.variable_name]


class OpaqueFunction:
    """launch.actions.OpaqueFunction: ``function(context, *args, **kwargs)`` returns actions when launched."""

    def __init__(self, *, function, args=None, kwargs=None):
        self.function, self.args, self.kwargs = function, list(args or []), dict(kwargs or {})


class DeclareLaunchArgument:
    def __init__(self, name, *, default_value=None, description=None, choices=None, **kwargs):
        self.name, self.default_value, self.description = name, default_value, description


class Node:
    """launch_ros.actions.Node's keywords (its own and ExecuteProcess's that launch files use)."""

    def __init__(self, *, executable, package=None, name=None, namespace=None, exec_name=None, parameters=None,
                 remappings=None, ros_arguments=None, arguments=None, output="log", respawn=False,
                 respawn_delay=None, emulate_tty=False, additional_env=None, sigterm_timeout=None,
                 sigkill_timeout=None, cwd=None, env=None):
        self.executable, self.package, self.name, self.namespace = executable, package, name, namespace
        self.parameters, self.arguments, self.remappings = list(parameters or []), list(arguments or []), remappings


class LaunchDescription:
    def __init__(self, initial_entities=None):
        self.entities = list(initial_entities or [])


@pytest.fixture
def description(monkeypatch):
    """The launch file's LaunchDescription, built against the stand-in modules."""
    modules = {
        "launch": types.ModuleType("launch"),
        "launch.actions": types.ModuleType("launch.actions"),
        "launch.substitutions": types.ModuleType("launch.substitutions"),
        "launch_ros": types.ModuleType("launch_ros"),
        "launch_ros.actions": types.ModuleType("launch_ros.actions"),
        "ament_index_python": types.ModuleType("ament_index_python"),
        "ament_index_python.packages": types.ModuleType("ament_index_python.packages"),
    }
    modules["launch"].LaunchDescription = LaunchDescription
    modules["launch.actions"].DeclareLaunchArgument = DeclareLaunchArgument
    modules["launch.actions"].OpaqueFunction = OpaqueFunction
    modules["launch.substitutions"].LaunchConfiguration = LaunchConfiguration
    modules["launch_ros.actions"].Node = Node

    def share(package):  # the source tree is laid out as the installed share/belt_drive_ros
        assert package == "belt_drive_ros", package
        return str(ROOT)

    modules["ament_index_python.packages"].get_package_share_directory = share
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    return runpy.run_path(str(LAUNCH_FILE))["generate_launch_description"]()


def _resolve(value, defaults: dict):
    """A launch value with every LaunchConfiguration replaced by its argument's default (a string)."""
    if isinstance(value, LaunchConfiguration):
        assert value.variable_name in defaults, f"launch argument {value.variable_name!r} is not declared"
        return defaults[value.variable_name]
    if isinstance(value, list):
        return "".join(str(_resolve(v, defaults)) for v in value)
    return value


def _file_parameters(path: str, node_name: str) -> dict:
    """``ros__parameters`` of ``node_name`` (or of ``/**``) in a ROS 2 parameters file."""
    data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    assert isinstance(data, dict), path
    for key in data:
        assert key in (node_name, f"/{node_name}", f"/**/{node_name}", "/**"), \
            f"{path}: {key!r} matches no node of the launch file"
        assert list(data[key]) == ["ros__parameters"], data[key]
    out = {}
    for key in ("/**", f"/**/{node_name}", node_name, f"/{node_name}"):
        out.update((data.get(key) or {}).get("ros__parameters") or {})
    return out


def _check_node_parameters(values: dict, where: str) -> None:
    unknown = set(values) - set(OWN_PARAMETERS) - RCLPY_PARAMETERS
    assert not unknown, f"{where}: parameters the node does not declare: {sorted(unknown)}"
    own = {k: v for k, v in values.items() if k not in RCLPY_PARAMETERS}
    scene = load_scene(own.get("scene", "paper"))
    build_settings({**default_values(scene), **own})  # raises NodeConfigError naming a bad value


def _launched(description, **arguments) -> tuple[dict, list]:
    """``(launch argument values, actions)``: the declared defaults overridden by ``arguments`` (as
    ``ros2 launch ... name:=value``), every OpaqueFunction run with them (as launch runs it)."""
    import types as _types

    declared = [a for a in description.entities if isinstance(a, DeclareLaunchArgument)]
    values = {a.name: a.default_value for a in declared}
    assert set(arguments) <= set(values), f"undeclared launch arguments {set(arguments) - set(values)}"
    values.update(arguments)
    context = _types.SimpleNamespace(launch_configurations=values)
    actions = []
    for a in description.entities:
        if isinstance(a, OpaqueFunction):
            actions += a.function(context, *a.args, **a.kwargs)
        else:
            actions.append(a)
    return values, actions


def test_launch_file_starts_the_packages_node_and_source_with_parameters_it_declares(description):
    defaults, actions = _launched(description)
    nodes = [a for a in actions if isinstance(a, Node)]
    assert {n.executable for n in nodes} == {"node", "source"}
    executables = _setup_py_executables()
    for n in nodes:
        assert n.package == "belt_drive_ros"
        assert n.executable in executables, f"setup.py installs no lib/belt_drive_ros/{n.executable}"
    (node,) = [n for n in nodes if n.executable == "node"]
    (source,) = [n for n in nodes if n.executable == "source"]

    values = {}
    for entry in node.parameters:
        entry = _resolve(entry, defaults)
        if isinstance(entry, dict):
            values.update({k: yaml.safe_load(_resolve(v, defaults)) if isinstance(v, LaunchConfiguration) else v
                           for k, v in entry.items()})
        else:
            assert Path(entry).is_file(), entry
            values.update(_file_parameters(entry, node.name))
    assert values["record_path"].endswith(".mcap")  # the launch file records the run
    assert values["record_overwrite"] is False
    _check_node_parameters(values, str(LAUNCH_FILE))

    args = build_parser().parse_args(
        [executables[source.executable], *(str(_resolve(a, defaults)) for a in source.arguments)])
    assert args.source_kind == "profile" and args.scene == values["scene"] == "truck_compressor"
    assert node.name == "belt_drive" and source.name == "torque_source"


@pytest.mark.parametrize("scene", ["paper", "e_motor_start", "bsg_start", "truck_compressor"])
def test_the_launch_file_runs_any_scene_with_its_own_belt_and_its_own_drive(description, scene):
    """Every shipped drive scene through the launch file: the node keeps the scene's belt (the parameters file
    used to set truck_compressor's k, c and F_0 for every scene: paper ran at k = 3e5 instead of 2e4), and the
    source publishes the scene's own drive (``source engine --scene paper`` exited 2: a motor, no engine)."""
    from belt_drive_ros.commands.source import build_profile

    defaults, actions = _launched(description, scene=scene)
    (node,) = [n for n in actions if isinstance(n, Node) and n.executable == "node"]
    (source,) = [n for n in actions if isinstance(n, Node) and n.executable == "source"]
    values = {}
    for entry in node.parameters:
        entry = _resolve(entry, defaults)
        values.update(_file_parameters(entry, node.name) if not isinstance(entry, dict) else {
            k: yaml.safe_load(_resolve(v, defaults)) if isinstance(v, LaunchConfiguration) else v
            for k, v in entry.items()})
    assert values["scene"] == scene
    assert not {"k", "c", "F_0"} & set(values)  # the scene's own belt
    settings = build_settings({**default_values(load_scene(scene)), **values})
    assert settings.scene.params == load_scene(scene).params
    args = build_parser().parse_args(["source", *(str(_resolve(a, defaults)) for a in source.arguments)])
    profile, _ = build_profile(args)  # (exits 2 for a profile it cannot publish)
    assert profile == load_scene(scene).drive


def test_parameters_example_is_accepted_by_the_node_schema():
    values = _file_parameters(str(PARAMS_FILE), "belt_drive")
    assert values["scene"] == "truck_compressor" and "k" not in values  # (model parameters: the scene's)
    _check_node_parameters(values, str(PARAMS_FILE))


def test_the_parameters_file_reaches_the_node_in_any_namespace_and_no_other_node(ros_domain_id):
    """rcl reads a section ``belt_drive:`` as ``/belt_drive``: the node launched in a namespace (``-r __ns:=``,
    an including launch file's PushROSNamespace) took nothing of config/belt_drive.yaml, silently. Its section
    applies to the node named belt_drive in any namespace, root included, and to no other node (the source)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node as RclpyNode

    file_values = yaml.safe_load(PARAMS_FILE.read_text(encoding="utf-8"))
    (section,) = file_values.values()
    names = set(section["ros__parameters"])
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain_id)
    try:
        for name, namespace, applies in (("belt_drive", "/", True), ("belt_drive", "/truck1", True),
                                         ("belt_drive", "/fleet/truck2", True), ("torque_source", "/truck1", False)):
            node = RclpyNode(name, namespace=namespace, context=context,
                             cli_args=["--ros-args", "--params-file", str(PARAMS_FILE)],
                             automatically_declare_parameters_from_overrides=True)
            try:
                got = {n for n in names if node.has_parameter(n)}
                assert got == (names if applies else set()), (name, namespace, names - got)
                if applies:
                    assert node.get_parameter("scene").value == section["ros__parameters"]["scene"]
            finally:
                node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_the_check_refuses_a_parameter_the_node_does_not_have(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(PARAMS_FILE.read_text(encoding="utf-8") + "    stiffness: 3.0\n", encoding="utf-8")
    with pytest.raises(AssertionError, match="stiffness"):
        _check_node_parameters(_file_parameters(str(bad), "belt_drive"), str(bad))
    bad.write_text(PARAMS_FILE.read_text(encoding="utf-8").replace("# k: 300000.0", "k: -5.0"), encoding="utf-8")
    with pytest.raises(ValueError, match="k"):
        _check_node_parameters(_file_parameters(str(bad), "belt_drive"), str(bad))


def test_a_network_scene_through_the_launch_file_starts_the_network_node_driven_by_its_scene(description, tmp_path):
    """``scene:=fead_i4`` starts ``belt-drive node fead_i4`` (the network node: the command dispatches on its scene
    argument) with parameters the network node declares and accepts, its crank driven by the scene's engine, no
    torque source and not the paper node's parameters file; a params_file of the user's is passed on."""
    from belt_drive_ros.io.scenes import load_network
    from belt_drive_ros.ros.network_node import PARAMETERS, NetworkSettings

    for extra in ({}, {"params_file": str(tmp_path / "mine.yaml")}):
        if extra:
            (tmp_path / "mine.yaml").write_text("belt_drive:\n  ros__parameters:\n    step_rate_hz: 500.0\n")
        values, actions = _launched(description, scene="fead_i4", **extra)
        nodes = [a for a in actions if isinstance(a, Node)]
        assert [n.executable for n in nodes] == ["node"]
        (node,) = nodes
        assert node.package == "belt_drive_ros" and node.name == "belt_drive"
        args = build_parser().parse_args([_setup_py_executables()[node.executable],
                                          *(str(_resolve(a, values)) for a in node.arguments)])
        assert args.scene == "fead_i4" and load_network(args.scene).name == "fead_i4"
        given = {}
        files = []
        for entry in node.parameters:
            if isinstance(entry, dict):
                given.update({k: yaml.safe_load(_resolve(v, values)) if isinstance(v, LaunchConfiguration) else v
                              for k, v in entry.items()})
            else:
                files.append(_resolve(entry, values))
                given.update(_file_parameters(files[-1], node.name))
        assert files == ([extra["params_file"]] if extra else [])  # never the paper node's config/belt_drive.yaml
        declared = {name: default for name, default, _ in PARAMETERS}
        assert set(given) <= set(declared), sorted(set(given) - set(declared))
        settings = NetworkSettings.from_values({**declared, "scene": args.scene, **given})
        assert settings.drive_source == "scene" and settings.record_path == "belt_drive_run.mcap"
        assert settings.record_overwrite is False
    assert settings.step_rate_hz == 500.0


def test_the_params_file_argument_names_the_section_the_shipped_file_uses(description):
    """params_file's description said '(key: belt_drive)': rcl reads that section as /belt_drive, so a file written
    so took nothing in a namespace (an including launch file's PushROSNamespace), the case config/belt_drive.yaml's
    '/**/belt_drive' was changed for. The description names the shipped file's key."""
    (key,) = yaml.safe_load(PARAMS_FILE.read_text(encoding="utf-8"))
    (argument,) = [a for a in description.entities if isinstance(a, DeclareLaunchArgument) and a.name == "params_file"]
    assert f"key: {key}" in argument.description, argument.description
