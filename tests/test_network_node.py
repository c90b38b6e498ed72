"""The belt-network node: inputs by topic, outputs by pulley and span, recording and its exact re-simulation.

A probe node steps ``/clock`` tick by tick (lockstep), publishes the crank's
``drive_torque`` and the alternator's ``alternator/load_torque`` at chosen
ticks and subscribes to outputs. Checks: the decoded topics the probe got
equal the recording; the recording re-simulated offline (``belt-drive sim
REC.mcap``) gives the same values bit for bit; the inputs act from the tick
after they are received, as documented; the file reads with ``mcap`` and
``rosbags``; a scene-driven node equals ``belt-drive sim NETWORK --out``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.ros

SCENE = "fead_i4"
START_NS = 1_000_000_000
TICK_NS = 1_000_000


class Lockstep:
    """A NetworkNode and a probe on a private context, /clock stepped by the probe."""

    def __init__(self, domain_id: int, namespace: str = "", scene: str = SCENE,
                 topics=("alternator/speed", "spans/tensioner_alternator/tension"), joints: bool = False, **params):
        import rclpy
        from rclpy.context import Context
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import Float64

        from belt_drive_ros.ros.executors import make_executor
        from belt_drive_ros.ros.network_node import NetworkNode

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        overrides = [Parameter(k, value=v) for k, v in params.items()] + [Parameter("use_sim_time", value=True)]
        self.node = NetworkNode(scene=scene, context=self.context, parameter_overrides=overrides, namespace=namespace)
        self.probe = Node("probe", context=self.context, namespace=namespace)
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.clock = self.probe.create_publisher(Clock, "/clock", reliable)
        self.drive = self.probe.create_publisher(Float64, "drive_torque", reliable)
        self.load = self.probe.create_publisher(Float64, "alternator/load_torque", reliable)
        self.got = {topic: [] for topic in topics}
        self.subs = [self.probe.create_subscription(Float64, topic, lambda m, t=topic: self.got[t].append(m.data),
                                                    reliable) for topic in topics]
        if joints:
            from sensor_msgs.msg import JointState

            self.got["joint_states"] = []
            self.joint_stamps = []  # (each message's header stamp [ns])

            def on_joints(m):
                self.joint_stamps.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)
                self.got["joint_states"].append(tuple(m.position) + tuple(m.velocity) + tuple(m.effort))

            self.subs.append(self.probe.create_subscription(JointState, "joint_states", on_joints, reliable))
        self.executor = make_executor(self.context, "single")
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self.until(lambda: self.drive.get_subscription_count() and self.load.get_subscription_count()
                   and all(s.get_publisher_count() for s in self.subs) and self.clock.get_subscription_count() >= 2
                   and all(self.node._readers[t] for t in self.got), "discovery")
        self.now = None

    def until(self, predicate, what: str, timeout: float = 20.0) -> None:
        end = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < end, f"timed out waiting for {what}"
            self.executor.spin_once(timeout_sec=0.005)

    def step(self, t_ns: int) -> None:
        from rosgraph_msgs.msg import Clock

        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(t_ns, 1_000_000_000)
        self.clock.publish(msg)
        published = self.node.counters["published"]
        self.until(lambda: self.node.sim.t_ns == t_ns and self.node.counters["published"] > published
                   and all(len(v) >= self.node.counters["published"] for v in self.got.values()), f"tick {t_ns}")

    def send(self, publisher, value: float) -> None:
        from std_msgs.msg import Float64

        received = self.node.counters["received"]
        publisher.publish(Float64(data=value))
        self.until(lambda: self.node.counters["received"] > received, "the node to take the input")

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        self.probe.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _decode(path) -> dict:
    """topic -> (log times [ns], values) of every Float64 topic; joint_states as (times, [position|velocity|effort])."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict = {}
    with open(path, "rb") as f:
        for _, channel, message, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic.endswith("/joint_states"):
                value = tuple(decoded.position) + tuple(decoded.velocity) + tuple(decoded.effort)
            elif hasattr(decoded, "data") and isinstance(decoded.data, float):
                value = decoded.data
            else:
                continue
            times, values = out.setdefault(channel.topic, ([], []))
            times.append(message.log_time)
            values.append(value)
    return out


def _lockstep_run(h: Lockstep, ticks, sends: dict) -> dict:
    """Step ``h`` to START_NS, then to each tick of ``ticks`` (sending ``sends[k] = (publisher, value)`` before tick
    k); what the probe got per topic. Closes ``h``."""
    try:
        h.step(START_NS)
        for k in ticks:
            if k in sends:
                h.send(getattr(h, sends[k][0]), sends[k][1])
            h.step(START_NS + k * TICK_NS)
        return {topic: list(values) for topic, values in h.got.items()}
    finally:
        h.close()


def test_network_node_records_and_resimulates_bit_for_bit(tmp_path, ros_domain_id):
    from belt_drive_ros.cli import main

    rec = tmp_path / "node.mcap"
    # /clock jumps 31, 32: integrated over, not published; from tick 12 the alternator takes 6 N m from the belt
    # instead of its profile
    got = _lockstep_run(Lockstep(ros_domain_id, record_path=str(rec)), [*range(1, 31), *range(33, 41)],
                        {3: ("drive", 14.0), 12: ("load", 6.0), 25: ("drive", 9.5)})
    recorded = _decode(rec)
    assert len(recorded["/alternator/speed"][1]) == 39
    for topic, values in got.items():  # what subscribers got is what was recorded
        assert values == recorded["/" + topic][1]
    # the inputs act from the tick after they were received (joint_states effort: u = +drive, -load)
    effort = np.array(recorded["/joint_states"][1])[:, 2 * 8: 3 * 8]
    crank, alternator = 0, 2
    assert effort[:3, crank].tolist() == [0.0, 0.0, 0.0] and effort[3, crank] == 14.0 and effort[25, crank] == 9.5
    assert effort[11, alternator] != -6.0 and effort[12:, alternator].tolist() == [-6.0] * 27
    # the arm and every pulley are joints; the belt moved the alternator
    assert np.ptp(recorded["/alternator/speed"][1]) > 0.0
    out = tmp_path / "resim.mcap"
    assert main(["sim", str(rec), "--out", str(out)]) == 0
    again = _decode(out)
    outputs = [t for t in recorded if t not in ("/drive_torque", "/alternator/load_torque")]
    assert len(outputs) == 1 + 7 * 7 + 7 * 2 + 1 + 2  # joint_states, pulleys, spans, arm, applied inputs
    for topic in outputs + ["/drive_torque", "/alternator/load_torque"]:  # (the inputs as received: passed through,
        assert again[topic][0] == recorded[topic][0], topic  # same time stamps      so msg-tools compare passes)
        assert again[topic][1] == recorded[topic][1], topic  # bit for bit
    from msg_tools.cli import main as msg_tools

    assert msg_tools(["compare", str(out), str(rec), "--rtol", "0", "--atol", "0"]) == 0
    # rosbags reads it too (its own CDR decoder, the file's schemas)
    from rosbags.highlevel import AnyReader

    with AnyReader([rec]) as reader:
        connections = [c for c in reader.connections if c.topic == "/spans/alternator_water_pump/tension"]
        values = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages(connections=connections)]
    assert values == recorded["/spans/alternator_water_pump/tension"][1]
    # the outputs' channels say what the node's publishers offered (reliable, transient local, keep last 10), so a
    # replay latches them as the node did; the re-simulation is an offline file: reliable, volatile
    from mcap.reader import make_reader
    from msg_tools.qos import parse_offered_qos_yaml

    def offered(path):
        with open(path, "rb") as f:
            channels = make_reader(f).get_summary().channels.values()
            return {c.topic: parse_offered_qos_yaml(c.metadata["offered_qos_profiles"])[0] for c in channels}

    node_qos, offline_qos = offered(rec), offered(out)
    for topic in ("/joint_states", "/spans/alternator_water_pump/tension"):
        assert (node_qos[topic].durability, node_qos[topic].depth, node_qos[topic].reliability) == (
            "transient_local", 10, "reliable"), topic
        assert offline_qos[topic].durability == "volatile", topic


def test_scene_driven_node_equals_offline_sim(tmp_path, ros_domain_id):
    from diagnostic_msgs.msg import DiagnosticArray

    from belt_drive_ros.cli import main
    from msg_tools.compare import compare

    rec = tmp_path / "node.mcap"
    h = Lockstep(ros_domain_id, namespace="car1", record_path=str(rec), drive_source="scene")
    diagnostics = []
    h.probe.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
    try:
        for k in range(0, 31):
            h.step(START_NS + k * TICK_NS)
        h.node._diagnostics()  # its 1 Hz timer's call, now
        h.until(lambda: diagnostics, "/diagnostics")
    finally:
        h.close()
    status = diagnostics[-1].status[0]
    assert status.level == b"\x00" and status.name == "car1/belt_drive: simulation" and status.hardware_id == "fead_i4"
    assert {kv.key for kv in status.values} >= {"published", "received", "friction_use_max", "tick_compute_us_p50",
                                                "tick_compute_us_p99", "period_error_ms_p99"}
    off = tmp_path / "offline.mcap"
    assert main(["sim", SCENE, "--duration", "0.03", "--out", str(off)]) == 0
    a, b = _decode(rec), _decode(off)
    assert set(a) == {"/car1" + topic for topic in b}  # the node's topics under its namespace
    for topic in b:  # equal to the offline run bit for bit
        assert a["/car1" + topic][1] == b[topic][1], topic
    again = tmp_path / "again.mcap"  # a namespaced recording re-simulates under its namespace
    assert main(["sim", str(rec), "--out", str(again)]) == 0
    c = _decode(again)
    assert all(c[t] == a[t] for t in a), [t for t in a if c.get(t) != a[t]]
    report = compare(again, rec, rtol=0.0, atol=0.0)
    assert report.passed, [str(f) for f in report.failures]


def test_a_tick_without_float_readers_publishes_the_same_joint_states(tmp_path, ros_domain_id):
    """No Float64 reader, no recording: the ticks compute the joint states alone; they equal the offline run's bit for
    bit, and the 1 Hz diagnostics still report the capstan use (computed there from the tick's state)."""
    from diagnostic_msgs.msg import DiagnosticArray

    from belt_drive_ros.cli import main

    h = Lockstep(ros_domain_id, topics=(), joints=True, drive_source="scene")
    diagnostics = []
    h.probe.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
    try:
        for k in range(0, 31):
            h.step(START_NS + k * TICK_NS)
        assert h.node.last_run is None  # the per-pulley outputs were skipped
        h.node._diagnostics()
        h.until(lambda: diagnostics, "/diagnostics")
        got = list(h.got["joint_states"])
    finally:
        h.close()
    values = {kv.key: kv.value for kv in diagnostics[-1].status[0].values}
    assert 0.0 < float(values["friction_use_max"].split()[0]) < 1.0
    off = tmp_path / "offline.mcap"
    assert main(["sim", SCENE, "--duration", "0.03", "--out", str(off)]) == 0
    assert got == _decode(off)["/joint_states"][1]  # bit for bit


def test_runup_chart_takes_the_crank_through_the_engine_speed_range(tmp_path, capsys):
    """``belt-drive modes fead_i4 --runup``: the crank starts at the bottom of the engine's range and ends near
    its top (the mean torque is chosen for it), a tension line per span is summarised, the chart is a PNG."""
    import math

    from belt_drive_ros.cli import main
    from belt_drive_ros.commands.modes import runup_scene
    from belt_drive_ros.core.network.model import NetworkModel
    from belt_drive_ros.core.network.simulate import simulate
    from belt_drive_ros.io.scenes import load_network

    scene = load_network(SCENE)
    ramp = runup_scene(SCENE, scene, NetworkModel.build(scene), 1.0)
    run = simulate(ramp, model="flexible")
    lo, hi = scene.engine.speed_range
    crank = run.speed[:, ramp.driver]
    assert crank[0] == lo and abs(crank[-1] - hi) < 0.15 * (hi - lo)
    png = tmp_path / "runup.png"
    assert main(["modes", SCENE, "--runup", str(png), "--runup-time", "0.5"]) == 0
    out = capsys.readouterr().out
    assert all(f"span {span}" in out for span in scene.span_names()) and "tensioner arm" in out
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["modes", SCENE, "--runup", str(png), "--runup-time", "0.5"]) == 2  # exists, no --force
    assert main(["modes", SCENE, "--runup", str(tmp_path / "x.png"), "--runup-time", "nan"]) == 2
    assert math.isfinite(float(ramp.pulleys[ramp.driver].torque.mean_torque))


def test_a_split_network_recording_starts_every_file_with_the_urdf_and_resimulates_bit_for_bit(tmp_path, ros_domain_id):
    """``max_bag_duration`` splits a network node's recording into a rosbag2 folder as the paper node's: every file
    starts with the layout's ``/robot_description``, ``metadata.yaml`` states what the files hold (the mcap library
    and rosbags agree), and ``belt-drive sim FOLDER`` re-simulates it bit for bit (split bags were refused)."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.ros.parameter_schema import NodeConfigError
    from test_node_recording import check_split_folder

    from belt_drive_ros.ros.network_node import PARAMETERS, NetworkSettings

    values = {name: default for name, default, _ in PARAMETERS}
    with pytest.raises(NodeConfigError, match="record_path: .*bag folder"):
        NetworkSettings.from_values({**values, "record_path": str(tmp_path / "x.mcap"), "max_bag_duration": 1.0})
    folder = tmp_path / "run"
    got = _lockstep_run(Lockstep(ros_domain_id, record_path=str(folder), max_bag_duration=0.01), range(1, 36),
                        {3: ("drive", 14.0), 17: ("load", 6.0)})
    check_split_folder(folder, "/robot_description")
    files = sorted(folder.glob("run_*.mcap"))
    assert len(files) >= 3
    recorded = {}
    for f in sorted(files, key=lambda p: int(p.stem.split("_")[-1])):
        for topic, (times, values) in _decode(f).items():
            recorded.setdefault(topic, ([], []))
            recorded[topic][0].extend(times)
            recorded[topic][1].extend(values)
    assert len(recorded["/alternator/speed"][1]) == 36
    for topic, values in got.items():
        assert values == recorded["/" + topic][1]
    out = tmp_path / "resim.mcap"
    assert main(["sim", str(folder), "--out", str(out)]) == 0
    again = _decode(out)
    for topic in recorded:
        if topic in ("/drive_torque", "/alternator/load_torque"):
            continue
        assert again[topic] == (recorded[topic][0], recorded[topic][1]), topic


def test_a_network_node_refuses_an_existing_record_path_and_a_bag_folder_another_run_writes(tmp_path, ros_domain_id):
    """An existing ``record_path`` refuses the start in the house's one sentence (as the paper node's), the file
    left as it was; a split recording holds its bag folder's lock (``.NAME.lock`` beside it, this pid in it, as the
    paper node's and ``belt-drive sim --bag-folder``) until the node is destroyed: a second network node recording
    into the folder, even with ``record_overwrite``, is refused naming the holder's pid and writes nothing."""
    import os

    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from belt_drive_ros.ros.network_node import NetworkNode
    from belt_drive_ros.ros.parameter_schema import NodeConfigError

    context = Context()
    rclpy.init(context=context, domain_id=ros_domain_id)

    def node(**params):
        return NetworkNode(scene=SCENE, context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])

    try:
        bag = tmp_path / "keep.mcap"
        bag.write_bytes(b"precious")
        with pytest.raises(NodeConfigError) as info:
            node(record_path=str(bag))
        assert str(info.value) == f"record_path: {bag} exists; set record_overwrite:=true to overwrite it"
        assert bag.read_bytes() == b"precious"
        folder, lock = tmp_path / "run", tmp_path / ".run.lock"
        first = node(record_path=str(folder), max_bag_duration=0.01)
        try:
            assert lock.read_text() == f"{os.getpid()}\n"
            files = sorted(os.listdir(folder))
            with pytest.raises(NodeConfigError) as info:
                node(record_path=str(folder), max_bag_duration=0.01, record_overwrite=True)
            assert str(info.value).startswith(f"record_path: {folder}: another run (pid {os.getpid()}) is writing "
                                              "this bag folder"), str(info.value)
            assert sorted(os.listdir(folder)) == files and lock.read_text() == f"{os.getpid()}\n"
        finally:
            first.destroy_node()
        assert (folder / "metadata.yaml").is_file() and not lock.exists()
        node(record_path=str(folder), max_bag_duration=0.01, record_overwrite=True).destroy_node()  # let go: it writes
    finally:
        rclpy.try_shutdown(context=context)


def test_node_command_with_a_network_scene_refuses_what_it_cannot_do(capsys):
    from belt_drive_ros.cli import main

    assert main(["node", SCENE, "--list-parameters"]) == 0
    listed = capsys.readouterr().out
    assert "drive_source" in listed and "record_path" in listed and "substeps" not in listed
    assert main(["node", SCENE, "--ros-args", "-p", "step_rate_hz:=3000.0"]) == 2  # 1/3 ms is no whole number of steps
    assert "step_rate_hz" in capsys.readouterr().err


def test_a_recording_cut_off_mid_write_resimulates_up_to_its_last_complete_sample(tmp_path):
    """A node killed while recording leaves no summary: the re-simulation reads the file as a stream."""
    from belt_drive_ros.cli import main

    full, cut, again = tmp_path / "full.mcap", tmp_path / "cut.mcap", tmp_path / "again.mcap"
    assert main(["sim", SCENE, "--duration", "0.6", "--out", str(full), "--start-time", "0"]) == 0
    data = full.read_bytes()
    cut.write_bytes(data[: len(data) * 6 // 10])
    assert main(["sim", str(cut), "--out", str(again)]) == 0
    a, b = _decode(full), _decode(again)
    rows = len(b["/joint_states"][1])
    assert 0 < rows < len(a["/joint_states"][1])
    for topic in b:  # the samples the cut file still has, re-made bit for bit
        assert b[topic][1] == a[topic][1][: len(b[topic][1])] and len(b[topic][1]) == rows, topic
    cut.write_bytes(data[:200])  # nothing but the header: one line, exit 2
    assert main(["sim", str(cut), "--out", str(tmp_path / "x.mcap")]) == 2


@pytest.mark.parametrize("tier", ["flexible", "rigid", "slipping"])
def test_joint_values_alone_equal_those_of_the_whole_outputs(tier):
    """The tick's joint-states-only path (stepper.pulley_state + layout.joint_values) gives the values of the one-sample
    outputs bit for bit, in every tier, with a held crank torque and an accessory on its profile."""
    from belt_drive_ros.io.scenes import load_network
    from belt_drive_ros.io.network_bag import NetworkLayout
    from belt_drive_ros.ros.network_stepper import NetworkStepper

    scene = load_network(SCENE)
    stepper, layout = NetworkStepper(scene, tier=tier), NetworkLayout(scene)
    x = stepper.initial()
    stepper.hold(scene.driver, 25.0)
    for k in range(0, 60, 3):
        x = stepper.advance(x, k, k + 3)
        run, u = stepper.sample(k + 3, x)
        alone = layout.joint_values(*stepper.pulley_state(k + 3, x))
        assert alone == layout.values(run, u)[0]
    assert len(alone) == 3 * len(layout.joints) and np.ptp(alone[len(layout.joints): 2 * len(layout.joints)]) > 0.0


def _clock(h: Lockstep, t_ns: int, expect_ns: int) -> None:
    """Publish /clock = ``t_ns`` and wait until the node's tick time is ``expect_ns`` and its outputs are in."""
    from rosgraph_msgs.msg import Clock

    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(t_ns, 1_000_000_000)
    h.clock.publish(msg)
    h.until(lambda: h.node.sim.t_ns == expect_ns and all(len(v) >= h.node.counters["published"] for v in h.got.values()),
            f"tick {expect_ns}")


def test_a_clock_between_grid_points_publishes_the_last_grid_points_state_at_its_time(ros_domain_id):
    """/clock at 4.5 and 7.6 ticks: the node steps whole steps, so it publishes the state of ticks 4 and 7 stamped at
    their own times (it rounded: 7.6 published the state of 8 stamped 7.6, then again at 8), and a /clock with no
    new grid point since the last tick publishes nothing. The samples are an on-grid run's, no stamp twice."""
    h = Lockstep(ros_domain_id, joints=True)
    try:
        h.step(START_NS)
        for k, t in ((1, 1.0), (2, 2.0), (3, 3.0), (4, 4.5), (4, 4.7), (5, 5.0), (6, 6.0), (7, 7.6), (8, 8.0)):
            _clock(h, START_NS + int(t * TICK_NS), START_NS + k * TICK_NS)
        published = h.node.counters["published"]
        odd = list(h.got["joint_states"])
        stamps = list(h.joint_stamps)
    finally:
        h.close()
    assert published == 9 and len(odd) == 9  # start and ticks 1-8, each once (4.7 published nothing)
    # each stamped at its grid point, as /tf and the recording (joint_states said 7.6 ms for the state of 7 ms)
    assert stamps == [START_NS + k * TICK_NS for k in range(9)]
    on_grid = _lockstep_run(Lockstep(ros_domain_id, joints=True), range(1, 9), {})
    assert odd == on_grid["joint_states"]


def test_a_network_recording_whose_node_restarted_is_refused(tmp_path, ros_domain_id, capsys):
    """/clock back from tick 6 to tick 2: the node restarts there (scene time 0) and records the restart; the
    re-simulation stepped the file as one run and exited 0 with a different run. It refuses it now, naming the
    restart and its time."""
    from belt_drive_ros.cli import main

    rec = tmp_path / "node.mcap"
    _lockstep_run(Lockstep(ros_domain_id, record_path=str(rec)), [1, 2, 3, 4, 5, 6, 2, 3, 4], {})
    capsys.readouterr()
    assert main(["sim", str(rec), "--out", str(tmp_path / "re.mcap")]) == 2
    err = capsys.readouterr().err
    assert "cannot re-simulate: the node restarted from the initial state (clock jumped back)" in err, err
    assert not (tmp_path / "re.mcap").exists()


def test_a_network_node_takes_an_integer_for_a_float_and_names_an_undeclared_parameter(ros_domain_id):
    """`-p step_rate_hz:=500` (an integer) was refused at start ('wrong type INTEGER, expecting DOUBLE') where the
    paper node stores it as a double; and a SetParameters request for a name the node does not have was answered
    'undeclared parameter(s): []'. It names it now."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    h = Lockstep(ros_domain_id, step_rate_hz=500)
    try:
        assert h.node.get_parameter("step_rate_hz").value == 500.0 and h.node.sim.settings.tick_ns == 2_000_000
        assert h.node.get_parameter("step_rate_hz").type_ == Parameter.Type.DOUBLE  # (it stayed an INTEGER)
        client = h.probe.create_client(SetParameters, f"{h.node.get_fully_qualified_name()}/set_parameters")
        h.until(client.service_is_ready, "the set_parameters service")
        future = client.call_async(SetParameters.Request(parameters=[Parameter("modle", value="rigid").to_parameter_msg()]))
        h.until(future.done, "the answer")
        (result,) = future.result().results
        assert not result.successful and "modle: not a parameter of the node" in result.reason, result.reason
    finally:
        h.close()


def test_the_network_nodes_parameters_are_read_only_as_ros_tools_see_them(ros_domain_id):
    """The network node takes every parameter at start and refused every change, but its descriptors said
    read_only false (rqt_reconfigure and ``ros2 param describe`` offered them for editing). Declared read-only: a
    change is refused by name over the parameter service; use_sim_time stays rclpy's, writable."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    from belt_drive_ros.ros.network_node import NetworkNode

    h = Lockstep(ros_domain_id)
    try:
        described = h.node.describe_parameters([*NetworkNode.PARAMETER_NAMES, "use_sim_time"])
        assert [d.name for d in described if not d.read_only] == ["use_sim_time"]
        client = h.probe.create_client(SetParameters, f"{h.node.get_fully_qualified_name()}/set_parameters")
        h.until(client.service_is_ready, "the set_parameters service")
        future = client.call_async(SetParameters.Request(parameters=[
            Parameter("step_rate_hz", value=500.0).to_parameter_msg(), Parameter("model", value="rigid").to_parameter_msg()]))
        h.until(future.done, "the answer")
        reasons = [(r.successful, r.reason) for r in future.result().results]
        assert reasons == [(False, "Trying to set a read-only parameter: step_rate_hz."),
                           (False, "Trying to set a read-only parameter: model.")], reasons
        assert h.node.get_parameter("step_rate_hz").value == 1000.0 and h.node.settings.tick_ns == 1_000_000
    finally:
        h.close()
    # docs/serpentine.md quotes the refusal as the node answers it (it said 'refused with the reason: restart the
    # node', the node's own check before the parameters were declared read-only)
    doc = " ".join((Path(__file__).resolve().parents[1] / "docs" / "serpentine.md").read_text(encoding="utf-8").split())
    assert f"`{reasons[1][1]}`" in doc and "refused with the reason: restart the node" not in doc


def test_the_network_node_has_a_reset_whose_next_tick_is_the_initial_state(tmp_path, ros_domain_id, capsys):
    """~/reset (std_srvs/Trigger), as the paper node's: answered at once; the next tick is scene time 0 and
    publishes the initial state, the ticks after it repeat the run from its start; the recording names the restart
    and its re-simulation refuses it (it had no reset: only a /clock jumped back restarted it)."""
    from std_srvs.srv import Trigger

    from belt_drive_ros.cli import main

    rec = tmp_path / "node.mcap"
    h = Lockstep(ros_domain_id, joints=True, record_path=str(rec))
    try:
        h.step(START_NS)
        for k in range(1, 5):
            h.step(START_NS + k * TICK_NS)
        client = h.probe.create_client(Trigger, f"{h.node.get_fully_qualified_name()}/reset")
        h.until(client.service_is_ready, "the reset service")
        futures = [client.call_async(Trigger.Request()) for _ in range(3)]  # a burst: one restart
        h.until(lambda: all(f.done() for f in futures), "the answers")
        assert all(f.result().success for f in futures)
        restarts = h.node.counters["restarts"]
        for k in range(5, 9):
            _clock(h, START_NS + k * TICK_NS, START_NS + k * TICK_NS)
        assert h.node.counters["restarts"] == restarts + 1
        rows = list(h.got["joint_states"])
    finally:
        h.close()
    assert rows[5] == rows[0]  # the reset tick: the initial state
    assert rows[6:9] == rows[1:4]  # then the run from its start again
    capsys.readouterr()
    assert main(["sim", str(rec), "--out", str(tmp_path / "re.mcap")]) == 2
    assert "restarted from the initial state (~/reset, 3 call(s) since the last tick)" in capsys.readouterr().err


def test_a_diverging_network_node_reports_error_on_diagnostics(ros_domain_id):
    """The paper node's convention: a divergence in the window since the last /diagnostics is ERROR with its reason
    (the network node restarted ~36 times a second at 1e6 N m and said OK or WARN); a window without one is not."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    h = Lockstep(ros_domain_id)
    try:
        got = []
        h.probe.create_subscription(DiagnosticArray, "/diagnostics", got.append, 10)

        def diagnostics():
            n = len(got)
            h.node._diagnostics()
            h.until(lambda: len(got) > n, "/diagnostics")
            return got[-1].status[0]

        h.step(START_NS)
        h.send(h.drive, 1.0e6)
        t = START_NS
        while h.node.counters["divergences"] == 0:
            t += TICK_NS
            assert t < START_NS + 2_000 * TICK_NS, "no divergence at 1e6 N m"
            h.step(t)
        status = diagnostics()
        assert status.level == DiagnosticStatus.ERROR
        assert status.message.startswith(f"{h.node.counters['divergences']} divergence(s), restarted from the initial state")
        h.send(h.drive, 0.0)
        h.step(t + TICK_NS)  # (the restart's tick; 0 N m from the next)
        diverged = h.node.counters["divergences"]
        for k in range(2, 6):
            h.step(t + k * TICK_NS)
        assert h.node.counters["divergences"] == diverged
        diagnostics()  # (the window of the last divergence, if it came after the first report)
        assert diagnostics().level != DiagnosticStatus.ERROR
    finally:
        h.close()


def test_the_network_node_takes_a_model_and_its_recording_resimulates_on_that_tier(tmp_path, ros_domain_id, capsys):
    """The network node had no model parameter: its tier came from the scene's own profiles, even with the crank
    driven from a topic (a constant crank profile picks rigid for a pulsating topic torque). model:=rigid runs the
    rigid tier; the recording says so and its re-simulation steps that tier, bit for bit; a bad name is refused."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.ros.network_node import NetworkSettings, PARAMETERS
    from belt_drive_ros.ros.parameter_schema import NodeConfigError

    with pytest.raises(NodeConfigError, match="model: one of auto, flexible, rigid, slipping, got 'stiff'"):
        NetworkSettings.from_values({**{n: d for n, d, _ in PARAMETERS}, "scene": SCENE, "model": "stiff"})
    rec = tmp_path / "rigid.mcap"
    h = Lockstep(ros_domain_id, record_path=str(rec), model="rigid")
    assert h.node.sim.stepper.tier == "rigid"
    rigid = _lockstep_run(h, range(1, 21), {3: ("drive", 14.0)})
    flexible = _lockstep_run(Lockstep(ros_domain_id, model="flexible"), range(1, 21), {3: ("drive", 14.0)})
    assert rigid["alternator/speed"] != flexible["alternator/speed"]
    out = tmp_path / "re.mcap"
    assert main(["sim", str(rec), "--out", str(out)]) == 0
    from msg_tools.cli import main as msg_tools

    capsys.readouterr()
    assert msg_tools(["compare", str(out), str(rec), "--rtol", "0", "--atol", "0"]) == 0
