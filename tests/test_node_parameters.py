"""The node's parameter schema without ROS: --list-parameters, ranges from the core's rules, settings."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from belt_drive_ros.core.errors import ParameterError
from belt_drive_ros.core.params import FIELD_DOCS, BeltDriveParams
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.ros.parameter_schema import (
    MODEL_PARAMETERS,
    NodeConfigError,
    build_settings,
    default_values,
    model_range,
    scene_torque_bound,
)


def test_list_parameters_runs_without_rclpy():
    """In a fresh interpreter: the CLI prints every parameter and never imports rclpy."""
    code = (
        "import sys\nfrom belt_drive_ros.cli import main\nrc = main(['node', '--list-parameters'])\n"
        "print('RCLPY', sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rcl_interfaces')))\n"
        "raise SystemExit(rc)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "RCLPY []"
    for name in ("step_rate_hz", "torque_bound", "record_path", *FIELD_DOCS):
        assert f"  {name} " in out.stdout, name


def test_model_range_reads_the_rule_table(monkeypatch):
    """The advertised range is the rule table's (core.params.RULES, PLAUSIBLE_RULES), not a restated bound: a rule
    added to the table moves it (the old code kept the lower bound 0 whatever the table said)."""
    from belt_drive_ros.core import params as core_params

    assert model_range("k") == (core_params.PLAUSIBLE_MIN["k"], core_params.PLAUSIBLE_MAX["k"])  # plausible: >= 1 N/m
    assert model_range("mu") == (0.0, core_params.PLAUSIBLE_MAX["mu"])  # mu > 0: the open end 0 is given as 0
    assert model_range("c") == (0.0, core_params.PLAUSIBLE_MAX["c"])  # c >= 0
    assert model_range("wrap_angle")[1] == 2.0 * math.pi
    stricter = (core_params.rule("k", 1.5e3, None, "[)", "must be >= 1500 N/m, got {value!r}"),  # (above 1 N/m)
                core_params.rule("c", 2.0, 50.0, "(]", "must be in (2, 50], got {value!r}"))
    monkeypatch.setattr(core_params, "RULES", core_params.RULES + stricter)
    assert model_range("k") == (1.5e3, core_params.PLAUSIBLE_MAX["k"])
    assert model_range("c") == (2.0, 50.0)


@pytest.mark.parametrize("name", MODEL_PARAMETERS)
def test_model_ranges_are_the_core_rules(name):
    """Inside the advertised range BeltDriveParams accepts; just outside it refuses (each end)."""
    from belt_drive_ros.core.params import PLAUSIBLE_MIN

    lo, hi = model_range(name)
    base = BeltDriveParams().field_values()
    assert lo == PLAUSIBLE_MIN.get(name, 0.0) and math.isfinite(hi) and hi >= base[name]  # groove_angle: the flat belt (pi) is both default and upper end
    BeltDriveParams(**{**base, name: hi})  # the upper end itself is valid
    with pytest.raises(ParameterError, match=name):
        BeltDriveParams(**{**base, name: -1e-9})
    values = default_values(load_scene("paper"))
    with pytest.raises(NodeConfigError, match=name):
        build_settings({**values, name: hi * 1.0001})
    if lo > 0.0:  # a plausible lower end: the node refuses below it (r_3 = 1e-300 m overflowed at its tick)
        with pytest.raises(NodeConfigError, match=f"{name}: .* is outside the plausible range"):
            build_settings({**values, name: lo * 0.5})


def test_torque_bound_is_derived_from_the_scene_or_set():
    scene = load_scene("paper")
    values = default_values(scene)
    derived = build_settings(values).torque_bound
    assert derived == scene_torque_bound(scene) >= 10.0 * max(abs(scene.load.torque(0.0, 0.0, 0.0)), 1e-3)
    assert build_settings({**values, "torque_bound": 50.0}).torque_bound == 50.0


def test_node_settings_carry_the_accuracy_guard():
    """The node runs the core's accuracy guard on its model, method and step (scene torques)."""
    from belt_drive_ros.benchmarks.common import dop853_reference, run_errors
    from belt_drive_ros.core.model import make_model
    from belt_drive_ros.core.simulate import Simulator

    scene = load_scene("paper")
    values = {**default_values(scene), "drive_source": "scene", "model": "flexible"}
    settings = build_settings(values)
    assert settings.accuracy is not None and settings.accuracy.ok, settings.accuracy.describe()
    # exact holds the motor curve's and the fan's speed slopes over the step: unstable at h*omega_n ~ 4.5
    rate = scene.params.belt_natural_frequency / 4.5
    with pytest.raises(NodeConfigError, match="UNSTABLE") as err:
        build_settings({**values, "method": "exact", "step_rate_hz": rate})
    assert "method" in str(err.value) and "stable and accurate" in str(err.value)
    model = make_model("flexible", scene.params)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    # the refused step: the belt mode grows (1.004 per step) into a sustained swing, 0.8 of the peak off DOP853
    t, x = Simulator(model, scene.drive, scene.load, "exact", 1.0 / rate, check_stability=False).run(scene.duration, x0)
    assert run_errors(dop853_reference(scene.with_overrides(model="flexible"), "flexible"), t, x)["error"] > 0.3
    inaccurate = build_settings({**values, "method": "etd2", "step_rate_hz": 200.0})  # 5 ms: stable, not accurate
    assert inaccurate.accuracy.stable and not inaccurate.accuracy.accurate
    assert "INACCURATE" in inaccurate.accuracy.describe()


def test_node_method_auto_chooses_and_says_why():
    """method auto on the node: the guard's choice at the tick's step (substeps raised when none meets it there)."""
    scene = load_scene("paper")
    values = {**default_values(scene), "drive_source": "scene", "model": "flexible", "method": "auto"}
    settings = build_settings(values)
    assert settings.method in ("exact", "etd2", "etd4", "lawson5") and settings.accuracy.ok
    assert settings.method in settings.method_reason and "tolerance" in settings.method_reason
    coarse = build_settings({**values, "step_rate_hz": 20.0, "substeps": 1})  # 50 ms ticks: one step is not enough
    assert coarse.substeps > 1 and coarse.accuracy.accurate, coarse.method_reason
    stated = build_settings({**values, "method": "etd2"})
    assert stated.method_reason == "etd2: set by parameter 'method'"


def test_an_undeclared_parameter_set_over_the_service_is_named_in_the_reason(ros_domain_id):
    """rclpy answers a SetParameters request for a name the node does not have with 'Invalid access to undeclared
    parameter(s): []' (its generator is used up before the message is made): an external client learned nothing.
    The node names it, and the request beside it in a non-atomic call is answered on its own."""
    from belt_drive_ros.ros.harness import BeltDriveHarness

    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, input_timeout=0.0) as h:
        bogus, good = h.set_parameters_over_the_service(foo=1.0, k=2.5e4)
        assert not bogus.successful and "foo: not a parameter of the node" in bogus.reason, bogus.reason
        assert good.successful and h.node.get_parameter("k").value == 2.5e4
        h.advance(0.01)  # the node ticks on


def test_a_misspelt_name_in_a_params_file_is_refused_as_on_the_command_line(tmp_path, capsys):
    """rclpy drops a parameter a node does not declare without a word: ``-p torque_limt:=5`` was refused (exit 2),
    the same name in a --params-file section for the node ran with no torque limit. Now refused too, naming the
    file as given; a section for another node or a wildcard one (other nodes' parameters) is not the node's."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.ros.parameter_schema import unknown_parameter_rule

    typo = tmp_path / "typo.yaml"
    typo.write_text("belt_drive:\n  ros__parameters:\n    torque_limt: 5.0\n")
    assert main(["node", "paper", "--ros-args", "--params-file", str(typo)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"belt-drive: error: torque_limt (params file {typo}): not a parameter of the node "
        "(belt-drive node --list-parameters)")
    renamed = tmp_path / "truck.yaml"
    renamed.write_text("/fleet/truck1:\n  ros__parameters:\n    model: rigid\n    tick:\n      rate: 5.0\n")
    assert main(["node", "truck_compressor", "--name", "truck1", "--ros-args", "-r", "__ns:=/fleet",
                 "--params-file", str(renamed)]) == 2
    assert "tick.rate (params file" in capsys.readouterr().err  # (a nested name, as rcl reads it)
    names = {"model", "torque_limit"}
    others = tmp_path / "others.yaml"
    others.write_text("/**:\n  ros__parameters:\n    rate: 5.0\nsource:\n  ros__parameters:\n    rate: 500.0\n"
                      "belt_drive:\n  ros__parameters:\n    torque_limit: 5.0\n    use_sim_time: true\n")
    assert unknown_parameter_rule(["--params-file", str(others)], names, "belt_drive") is None
    assert unknown_parameter_rule(["--params-file", str(typo)], names, "belt_drive") == f"torque_limt (params file {typo})"
    assert unknown_parameter_rule(["-r", "__node:=other", "--params-file", str(typo)], names, "belt_drive") is None


def test_the_recording_parameters_are_read_only_as_ros_tools_see_them(tmp_path, ros_domain_id):
    """record_path, record_overwrite, max_bag_duration and max_bag_size take effect at start only, but their
    descriptors said read_only false: rqt_reconfigure and ``ros2 param describe`` offered them for editing, and a
    change came back refused only from the node's own check. Declared read-only, with the value given at start
    (an integer for max_bag_duration a double, as for every double), every other parameter still writable."""
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import Parameter

    from belt_drive_ros.ros.parameter_schema import OWN_PARAMETERS, START_ONLY
    from belt_drive_ros.testing import BeltDriveHarness

    path = tmp_path / "run"
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(path), max_bag_duration=600,
                          input_timeout=0.0) as h:
        described = {d.name: d for d in h.node.describe_parameters(list(OWN_PARAMETERS))}  # (the service's answer)
        assert {name for name, d in described.items() if d.read_only} == set(START_ONLY)
        assert described["max_bag_duration"].type == ParameterType.PARAMETER_DOUBLE
        assert h.node.get_parameter("max_bag_duration").value == 600.0
        assert h.node.get_parameter("max_bag_duration").type_ == Parameter.Type.DOUBLE
        assert h.node.get_parameter("record_path").value == str(path)
        for name, value in (("record_path", str(tmp_path / "other.mcap")), ("max_bag_size", 10**6)):
            (result,) = h.set_parameters_over_the_service(**{name: value})
            assert not result.successful and result.reason == f"Trying to set a read-only parameter: {name}."
        assert h.node.settings.record_path == str(path) and h.node.settings.max_bag_size == 0
        assert h.set_parameters(torque_limit=5.0).successful


def test_a_params_file_section_for_the_node_in_any_namespace_is_checked_as_rcl_applies_it(tmp_path):
    """A section ``/**/belt_drive:`` (the shipped config/belt_drive.yaml's: the node in any namespace) was taken for
    a wildcard one and never checked: a misspelt name in it ran the default without a word. Sections match as rcl
    matches them (``*`` one token, ``**`` any number); one for any node (``/**``, ``/fleet/*``) is not checked."""
    from belt_drive_ros.ros.parameter_schema import section_matches, unknown_parameter_rule

    assert section_matches("belt_drive", "/belt_drive") and not section_matches("belt_drive", "/truck1/belt_drive")
    for fqn in ("/belt_drive", "/truck1/belt_drive", "/a/b/belt_drive"):
        assert section_matches("/**/belt_drive", fqn) and section_matches("/**", fqn)
        assert not section_matches("/**/torque_source", fqn)
    assert section_matches("/*/belt_drive", "/truck1/belt_drive")
    assert not section_matches("/*/belt_drive", "/belt_drive") and not section_matches("/*/belt_drive", "/a/b/belt_drive")
    typo = tmp_path / "typo.yaml"
    typo.write_text("/**/belt_drive:\n  ros__parameters:\n    torque_limt: 5.0\n")
    names = {"torque_limit"}
    for namespace in ("/", "/truck1", "/fleet/truck2"):
        assert unknown_parameter_rule(["--params-file", str(typo)], names, "belt_drive", namespace) == \
            f"torque_limt (params file {typo})", namespace
    assert unknown_parameter_rule(["--params-file", str(typo)], names, "torque_source", "/truck1") is None
    anyone = tmp_path / "anyone.yaml"
    anyone.write_text("/**:\n  ros__parameters:\n    rate: 5.0\n/fleet/*:\n  ros__parameters:\n    rate: 5.0\n")
    assert unknown_parameter_rule(["--params-file", str(anyone)], names, "belt_drive", "/fleet") is None


def test_a_belt_network_as_the_paper_nodes_scene_is_named_for_what_it_is(tmp_path):
    """scene:=fead_i4 on the paper node was "unknown scene 'fead_i4': not a file and not a shipped scene", though it
    is shipped: a belt network, which runs on its own node. A network YAML file likewise."""
    from belt_drive_ros.io.scenes import _shipped_text, load_scene

    values = default_values(load_scene("paper"))
    with pytest.raises(NodeConfigError, match=r"scene 'fead_i4': a belt network \(kind: network\), not a drive scene: "
                                              r"it runs on its own node, started with it \(belt-drive node fead_i4\)"):
        build_settings({**values, "scene": "fead_i4"})
    network = tmp_path / "mine.yaml"
    network.write_text(_shipped_text("fead_i4", "networks"))
    with pytest.raises(Exception, match="a belt network"):
        load_scene(network)


def test_record_path_never_replaces_the_scene_and_is_named_as_mcap(tmp_path):
    """``belt-drive node scene.yaml --record scene.yaml --force`` replaced the scene file with a 3 MB MCAP; ``--record
    x.csv`` wrote an MCAP under a CSV's name. Both refused, by either node (their settings share the check)."""
    from belt_drive_ros.io.scenes import _shipped_text
    from belt_drive_ros.ros.network_node import NetworkSettings, PARAMETERS

    scene = tmp_path / "scene.yaml"
    scene.write_text("extends: paper\n")
    values = {**default_values(load_scene("paper")), "scene": str(scene), "record_overwrite": True}
    for path, why in ((str(scene), "is the scene file the node reads"), (str(tmp_path / "x.csv"), "name it .mcap")):
        with pytest.raises(NodeConfigError, match=f"record_path: .*{why}"):
            build_settings({**values, "record_path": path})
    build_settings({**values, "record_path": str(tmp_path / "run.mcap")})
    build_settings({**values, "record_path": str(tmp_path / "run")})  # (no extension: the file as named)
    network = tmp_path / "net.yaml"
    network.write_text(_shipped_text("fead_i4", "networks"))
    net = {name: default for name, default, _ in PARAMETERS}
    with pytest.raises(NodeConfigError, match="record_path: .*is the scene file the node reads"):
        NetworkSettings.from_values({**net, "scene": str(network), "record_path": str(network)})


def test_the_params_file_check_reads_only_the_section_rcl_applies_to_this_node(tmp_path):
    """rcl applies a section named by the node's fully qualified name: a file shared by two nodes in two namespaces,
    or one whose node was renamed (-r __name:=, -r belt_drive:__node:=), was refused for another node's section
    (a regression of the check's first version, which read only the last part of the name)."""
    from belt_drive_ros.ros.parameter_schema import unknown_parameter_rule

    shared = tmp_path / "shared.yaml"
    shared.write_text("/truck/belt_drive:\n  ros__parameters:\n    k: 3.0e4\n"
                      "/fead/belt_drive:\n  ros__parameters:\n    step_rate_hz: 500.0\n")
    network = {"step_rate_hz", "scene"}
    assert unknown_parameter_rule(["-r", "__ns:=/fead", "--params-file", str(shared)], network, "belt_drive") is None
    assert unknown_parameter_rule(["-r", "__ns:=/truck", "--params-file", str(shared)], network, "belt_drive") == \
        f"k (params file {shared})"
    assert unknown_parameter_rule(["--params-file", str(shared)], network, "belt_drive", "/fead") is None
    renamed = tmp_path / "renamed.yaml"
    renamed.write_text("belt_drive:\n  ros__parameters:\n    model: rigid\nfead:\n  ros__parameters:\n    kk: 1.0\n")
    for remap in ("__name:=fead", "__node:=fead", "belt_drive:__node:=fead"):
        assert unknown_parameter_rule(["-r", remap, "--params-file", str(renamed)], network, "belt_drive") == \
            f"kk (params file {renamed})", remap
    assert unknown_parameter_rule(["-r", "other:__node:=fead", "--params-file", str(renamed)], network, "belt_drive") \
        == f"model (params file {renamed})"  # (a remap scoped to another node: this one keeps its name)


def test_the_node_says_where_its_step_is_not_the_scene_s_dt():
    """The node steps tick / substeps: paper's 5 ms at 1 kHz is 1 ms there, and a dt of 0.3 ms is 333,333 ns, no
    whole part of a tick. Its start line said only '1000 Hz x 3 substep(s)': a user comparing it with belt-drive sim
    of the scene found 0.6 % apart with nothing to say why. Where they agree, nothing more is said."""
    paper = load_scene("paper")
    values = {**default_values(paper), "model": "flexible"}
    assert build_settings(values).steps == (
        "1000 Hz x 1 substep(s) of 1000000 ns (the scene's dt is 0.005 s; belt-drive sim --dt 0.001 steps as this "
        "node does)")
    odd = build_settings({**values, "substeps": 3}).steps
    assert odd.startswith("1000 Hz x 3 substep(s) of 333333 ns") and "no whole number of them" in odd
    bsg = load_scene("bsg_start")
    assert build_settings({**default_values(bsg), "model": "flexible"}).steps == "1000 Hz x 5 substep(s)"
