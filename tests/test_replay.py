"""Replay of recorded torque: offline through the model (no ROS) and live on ROS 2."""

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from belt_drive_ros.io.recording import BagReadError
from belt_drive_ros.io.torque_bag import RecordedTorque, scene_with_torque_bag
from belt_drive_ros.ros.replay import replay_schedule
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import simulate
from msg_tools import Ros2McapWriter, read_topic

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _torque_bag(path, times_ns, values, topic="/drive_torque"):
    with Ros2McapWriter(path, force=True) as w:
        for t, v in zip(times_ns, values):
            w.write(topic, "std_msgs/msg/Float64", {"data": float(v)}, int(t))
    return path


# ------------------------------------------------------------------ offline
def test_drive_is_the_zero_order_hold_of_the_messages(tmp_path):
    t0 = 5 * 10**9  # absolute receive times: the table starts at the first message
    times = [t0, t0 + 1_000_000, t0 + 1_000_000, t0 + 2_500_000, t0 + 4_000_000]
    bag = _torque_bag(tmp_path / "t.mcap", times, [1.0, 2.0, 3.0, 4.0, 5.0])
    scene = scene_with_torque_bag(load_scene("paper").with_overrides(dt=1e-3), bag)
    drive = scene.drive
    assert isinstance(drive, RecordedTorque)
    np.testing.assert_array_equal(drive.times, [0.0, 0.001, 0.0025, 0.004])
    np.testing.assert_array_equal(drive.values, [1.0, 3.0, 4.0, 5.0])  # equal times: the later message wins
    assert scene.duration == pytest.approx(0.004) and scene.dt == 1e-3
    probe = [0.0, 0.0005, 0.001, 0.0024999, 0.0025, 0.0039, 0.004, 1.0, -1.0]
    expect = [1.0, 1.0, 3.0, 3.0, 4.0, 4.0, 5.0, 5.0, 1.0]
    np.testing.assert_array_equal(drive.torque(np.array(probe)), expect)
    scalar = drive.scalar_torque()
    assert [scalar(t, 0.0, 0.0) for t in probe] == expect
    # a step that starts at a message's time uses it, even when the grid time dt*k rounds below it
    grid = _torque_bag(tmp_path / "grid.mcap", np.arange(40) * 1_000_000, np.arange(40.0))
    held = scene_with_torque_bag(load_scene("paper"), grid).drive
    assert 0.001 * 11 < held.times[11]  # float grid a hair below the message time
    assert held.scalar_torque()(0.001 * 11, 0.0, 0.0) == 11.0 and held.torque(0.001 * 11) == 11.0
    assert drive.reference()["bag"] == "t.mcap" and drive.reference()["samples"] == 4
    assert scene_with_torque_bag(load_scene("paper"), bag, duration=2.0).duration == 2.0


def test_bag_problems_are_one_line_errors(tmp_path):
    with Ros2McapWriter(tmp_path / "js.mcap") as w:
        w.write("/joint_states", "sensor_msgs/msg/JointState", {"name": ["a"], "position": [1.0]}, 0)
        w.write("/drive_torque", "sensor_msgs/msg/JointState", {"name": ["a"], "position": [1.0]}, 0)
    with pytest.raises(BagReadError, match="has type sensor_msgs/msg/JointState, expected std_msgs/msg/Float64"):
        scene_with_torque_bag(load_scene("paper"), tmp_path / "js.mcap")
    with pytest.raises(BagReadError, match=r"no topic /torque \(topics: /drive_torque, /joint_states\)"):
        scene_with_torque_bag(load_scene("paper"), tmp_path / "js.mcap", topic="torque")
    with pytest.raises(BagReadError, match="bag not found"):
        scene_with_torque_bag(load_scene("paper"), tmp_path / "nope.mcap")
    _torque_bag(tmp_path / "nan.mcap", [0, 1000], [1.0, float("nan")])
    with pytest.raises(BagReadError, match="non-finite"):
        scene_with_torque_bag(load_scene("paper"), tmp_path / "nan.mcap")


def test_a_torque_bag_cut_off_before_its_first_message_is_named_damaged(tmp_path):
    """A file cut short before any torque message could be read: the error says the recording is damaged or
    incomplete and where to look (before: "topic /drive_torque has no messages", as for an empty topic)."""
    bag = _torque_bag(tmp_path / "whole.mcap", np.arange(3000) * 1_000_000, np.sin(np.arange(3000)))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bag.read_bytes()[:3000])  # inside the first chunk (its channel record with it)
    with pytest.raises(BagReadError, match=r"cut\.mcap: damaged or incomplete recording \(.*\): no /drive_torque "
                                           r"message could be read before the damage; 'msg-tools info .*cut\.mcap'"):
        scene_with_torque_bag(load_scene("paper"), cut)
    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.recording import write_result_mcap

    run = tmp_path / "run.mcap"  # a run's recording: every channel up front, the cut before its first chunk ends
    write_result_mcap(simulate(load_scene("paper").with_overrides(duration=1.0)), run)
    cut.write_bytes(run.read_bytes()[:5000])
    with pytest.raises(BagReadError, match=r"cut\.mcap: damaged or incomplete recording \(.*\): no /drive_torque "):
        scene_with_torque_bag(load_scene("paper"), cut)
    empty = tmp_path / "empty.mcap"
    with Ros2McapWriter(empty, force=True) as w:  # a whole file whose topic has no message: as before
        w.write("/other", "std_msgs/msg/Float64", {"data": 1.0}, 0)
    with pytest.raises(BagReadError, match=r"no topic /drive_torque \(topics: /other\)"):
        scene_with_torque_bag(load_scene("paper"), empty)


def test_namespaced_drive_torque_is_found(tmp_path):
    bag = _torque_bag(tmp_path / "ns.mcap", [0, 10**6, 2 * 10**6], [1.0, 2.0, 3.0], topic="/truck/drive_torque")
    scene = scene_with_torque_bag(load_scene("paper"), bag)
    assert scene.drive.topic == "/truck/drive_torque"


def test_a_long_stretch_without_torque_messages_is_named_by_both_reads(tmp_path, capsys):
    """A bag at 1 kHz that then falls silent for 2.8 s: the whole read and the paged read name the same stretch
    (the drive holds the last torque through it); a bag of a few steps far apart is held by design, no note."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.io.torque_bag import paged_torque_bag, silence_note

    times = np.r_[np.arange(200) * 1_000_000, 3_000_000_000]
    bag = _torque_bag(tmp_path / "stall.mcap", times, 5.0 + np.arange(201) % 7)
    scene = load_scene("paper")
    whole = silence_note(scene_with_torque_bag(scene, bag).drive)
    paged = paged_torque_bag(scene, bag)
    assert paged is not None and silence_note(paged.drive) == whole
    assert whole.startswith("note: stall.mcap has no torque message for 2.801 s (from 0.199 s after its first")
    steps = _torque_bag(tmp_path / "steps.mcap", [0, 2_000_000_000, 4_000_000_000], [1.0, 3.0, 2.0])
    assert silence_note(scene_with_torque_bag(scene, steps).drive) == ""
    assert silence_note(paged_torque_bag(scene, steps).drive) == ""
    assert main(["sim", "paper", "--torque-bag", str(bag), "--out", str(tmp_path / "run.csv")]) == 0
    assert whole in capsys.readouterr().out


def test_a_run_longer_than_the_torque_bag_says_so(tmp_path, capsys):
    """--duration past the bag's last message: the drive holds the last torque to the end, and the run says so in
    one line (both reads alike); a run that ends within the recording (its own length, the default) says nothing."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.io.torque_bag import paged_torque_bag, tail_note

    bag = _torque_bag(tmp_path / "short.mcap", np.arange(1001) * 1_000_000, 2.0 + np.arange(1001) % 5)  # 1 s at 1 kHz
    scene = load_scene("paper")
    whole = tail_note(scene_with_torque_bag(scene, bag).drive, 3.0)
    paged = paged_torque_bag(scene, bag)
    assert paged is not None and tail_note(paged.drive, 3.0) == whole
    assert whole == ("note: short.mcap's last torque message is at 1 s and the run lasts 3 s: the drive holds that "
                     "torque for the last 2 s")
    assert tail_note(paged.drive, 1.0) == tail_note(paged.drive, 1.0005) == ""  # within one spacing of the end
    assert main(["sim", "paper", "--torque-bag", str(bag), "--duration", "3", "--out", str(tmp_path / "long.csv")]) == 0
    assert whole in capsys.readouterr().out
    assert main(["sim", "paper", "--torque-bag", str(bag), "--out", str(tmp_path / "own.csv")]) == 0
    assert "last torque message" not in capsys.readouterr().out


def test_sim_torque_bag_is_deterministic_and_needs_no_ros(tmp_path):
    """`belt-drive sim SCENE --torque-bag BAG --out X.mcap` twice: identical files, rclpy never imported."""
    rng = np.random.default_rng(0)
    times = np.cumsum(rng.integers(500_000, 1_500_000, size=300))  # irregular, ~1 kHz
    bag = _torque_bag(tmp_path / "profile.mcap", times, 20 + 5 * rng.normal(size=300))
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    code = (
        "import sys\n"
        "from belt_drive_ros.cli import main\n"
        "for d in ('a', 'b'):\n"
        f"    assert main(['sim', 'paper', '--dt', '0.001', '--torque-bag', {str(bag)!r}, '--quiet', '--start-time', '0',\n"
        f"                 '--out', {str(tmp_path)!r} + '/' + d + '/out.mcap']) == 0\n"
        "assert 'rclpy' not in sys.modules, 'rclpy was imported'\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    a, b = (tmp_path / d / "out.mcap" for d in ("a", "b"))
    assert a.read_bytes() == b.read_bytes()
    torque = read_topic(a, "/drive_torque")
    assert torque.log_time_ns[-1] == pytest.approx(times[-1] - times[0], abs=1e6)  # duration = bag span


def test_replay_schedule_rate_offset_loop():
    t = np.array([10, 11, 13, 16]) * 10**9  # seconds in ns
    plain = list(replay_schedule(t))
    assert plain == [(0.0, t[0], 0), (1.0, t[1], 1), (3.0, t[2], 2), (6.0, t[3], 3)]
    fast = list(replay_schedule(t, rate=2.0))
    assert [f[0] for f in fast] == [0.0, 0.5, 1.5, 3.0] and [f[1] for f in fast] == list(t)
    late = list(replay_schedule(t, start_offset=1.5))
    assert [(w, k) for w, _c, k in late] == [(0.0, 2), (3.0, 3)]
    looped = list(replay_schedule(t, loop=True, max_loops=3))
    clocks = [c for _w, c, _k in looped]
    assert [k for *_, k in looped] == [0, 1, 2, 3] * 3
    assert np.all(np.diff(clocks) > 0)  # /clock keeps increasing across passes
    assert clocks[4] - clocks[3] == 2 * 10**9  # one median spacing between passes
    with pytest.raises(ValueError, match="past the end"):
        list(replay_schedule(t, start_offset=7.0))
    with pytest.raises(ValueError, match="rate"):
        list(replay_schedule(t, rate=0.0))


def test_replay_loop_of_a_bag_spanning_no_time_is_refused():
    """A loop of messages sharing one time stamp has no period: it used to republish them endlessly, /clock
    creeping 1 ns per pass. It is refused at once (before any ROS start); a single pass still plays."""
    same = np.full(5, 7 * 10**9)
    assert [k for *_, k in replay_schedule(same)] == [0, 1, 2, 3, 4]  # no loop: one pass, all at wall offset 0
    for times in (same, same[:1], np.array([1, 2, 2, 2]) * 10**9):
        offset = 0.5 if times[0] != times[-1] else 0.0  # the part after the offset spans no time
        with pytest.raises(ValueError, match="spans no time"):
            replay_schedule(times, loop=True, start_offset=offset)
    looped = list(replay_schedule(np.array([3, 3, 4]) * 10**9, loop=True, max_loops=2))  # shared stamps, span > 0
    assert [k for *_, k in looped] == [0, 1, 2] * 2 and np.all(np.diff([c for _w, c, _k in looped]) >= 0)


def test_replay_command_refuses_loop_of_a_bag_spanning_no_time(tmp_path, capsys):
    from belt_drive_ros.cli import main

    bag = _torque_bag(tmp_path / "flat.mcap", np.full(4, 2 * 10**9), np.ones(4))
    assert main(["replay", str(bag), "--loop", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "spans no time" in err and "Traceback" not in err


# ---------------------------------------------------------------------- ROS
def _replay(bag, domain_id, *extra):
    from belt_drive_ros.ros import environment as ros_env

    env = ros_env.child_environment(domain_id)  # UDP only: nothing left in /dev/shm if killed
    cmd = [os.path.join(os.path.dirname(sys.executable), "belt-drive"), "replay", str(bag), "--quiet", *extra]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.ros
def test_replay_publishes_the_recorded_sequence_with_clock(tmp_path, ros_domain_id):
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64

    n = 120
    times = 2 * 10**9 + np.arange(n) * 2_000_000  # 500 Hz from t = 2 s
    values = np.sin(np.arange(n) / 7.0) * 50
    bag = _torque_bag(tmp_path / "profile.mcap", times, values)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    got = {"torque": [], "clock": []}
    proc = None
    try:
        node = rclpy.create_node("replay_probe", context=ctx)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(Float64, "/drive_torque", lambda b: got["torque"].append(b), qos, raw=True)
        node.create_subscription(Clock, "/clock", lambda m: got["clock"].append(m), qos)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        proc = _replay(bag, ros_domain_id, "--clock", "--rate", "2", "--wait-subscribers", "1", "--delay", "1.0")
        deadline = time.monotonic() + 30
        while (len(got["torque"]) < n or len(got["clock"]) < n) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.02)
        assert proc.wait(timeout=20) == 0, proc.stderr.read()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        rclpy.try_shutdown(context=ctx)
    assert len(got["torque"]) == n and len(got["clock"]) == n
    assert [deserialize_message(b, Float64).data for b in got["torque"]] == values.tolist()
    assert got["torque"][5] == b"\x00\x01\x00\x00" + np.float64(values[5]).tobytes()  # the recorded bytes
    clock_ns = [m.clock.sec * 10**9 + m.clock.nanosec for m in got["clock"]]
    assert clock_ns == times.tolist()  # /clock = each message's recorded time


@pytest.mark.ros
def test_node_in_sim_time_following_replay_equals_the_offline_replay(tmp_path, ros_domain_id):
    """replay --clock --sync -> BeltDriveNode(use_sim_time) -> NodeRecorder equals the offline replay bit for bit.

    The replay publishes message k, then /clock t_k, and (``--sync
    /joint_states``) waits for the node's outputs stamped t_k: the node
    samples message k at t_k and holds it over [t_k, t_k+1), which is the
    zero-order hold of ``sim --torque-bag`` (scene_with_torque_bag), so the
    node's recording equals the offline run at the message times exactly,
    however loaded the machine is, at 10x real time.
    """
    n = 60
    truck = load_scene("truck_compressor")
    torque = simulate(truck.with_overrides(duration=0.1)).outputs["drive_torque"][:: round(1e-3 / truck.dt)][:n]
    times = np.arange(n) * 1_000_000  # 1 kHz from /clock = 0
    bag = _torque_bag(tmp_path / "profile.mcap", times, torque)
    ticks, js, settings = _node_following_replay(bag, tmp_path / "live.mcap", ros_domain_id)
    assert ticks == n
    np.testing.assert_array_equal(js.stamp_ns, times)
    np.testing.assert_array_equal(js.effort[:, 0], torque)  # message k is applied from t_k on
    scene = scene_with_torque_bag(load_scene("truck_compressor"), bag)
    ref = simulate(scene, model=settings.model.name, method=settings.method, dt=settings.dt)
    o = {k: np.asarray(v)[:: settings.substeps] for k, v in ref.outputs.items()}
    assert o["phi_M"].size == n
    for j, wheel in enumerate(("M", "1", "2", "3")):
        np.testing.assert_array_equal(js.position[:, j], o[f"phi_{wheel}"])
        np.testing.assert_array_equal(js.velocity[:, j], o[f"omega_{wheel}"])
    np.testing.assert_array_equal(js.effort[:, 3], -o["load_torque"])


def _node_following_replay(bag, out, domain_id):
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from belt_drive_ros.ros.executors import make_executor
    from belt_drive_ros.ros.node import BeltDriveNode
    from belt_drive_ros.ros.recorder import NodeRecorder

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    proc = node = None
    try:
        node = BeltDriveNode(context=ctx, scene="truck_compressor",
                             parameter_overrides=[Parameter("use_sim_time", value=True)])
        node.recorder = NodeRecorder(node, out)
        ex = make_executor(ctx, "single")
        ex.add_node(node)
        proc = _replay(bag, domain_id, "--clock", "--sync", "/joint_states", "--rate", "10",
                       "--wait-subscribers", "2", "--delay", "1.0")
        deadline = time.monotonic() + 30
        while proc.poll() is None and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.005)
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.01)
        assert proc.wait(timeout=5) == 0, proc.stderr.read()
        ticks = node.counters["published"]
        settings = node.settings
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        if node is not None:
            node.destroy_node()  # closes the recorder
        rclpy.try_shutdown(context=ctx)
    return ticks, read_topic(out, "/joint_states"), settings


@pytest.mark.ros
def test_a_sync_replay_that_nothing_answers_fails_after_a_few_ticks(tmp_path):
    """--clock --sync /joint_states with no node on the domain: after 3 /clock ticks unanswered (2 s each) the replay
    stops with exit 1 and one line saying what was missing (before: 2 s per message, half an hour for a 1,001-message
    bag, then exit 0)."""
    import subprocess

    from belt_drive_ros.ros import environment as ros_env

    bag = _torque_bag(tmp_path / "t.mcap", np.arange(1001) * 1_000_000, np.ones(1001))
    proc = subprocess.run([sys.executable, "-m", "belt_drive_ros.cli", "replay", str(bag), "--clock", "--sync",
                           "/joint_states"], env=ros_env.child_environment(ros_env.process_domain_id(offset=75)),
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 1, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.startswith("belt-drive: error:")]
    assert len(lines) == 1 and "--sync /joint_states: no sensor_msgs/JointState stamped at the /clock time in 3 tries" in lines[0]
    assert "Traceback" not in proc.stderr


@pytest.mark.ros
def test_an_interrupted_replay_ends_with_the_signals_status(tmp_path):
    """SIGINT during a replay: it stops, says after how many messages, and exits 130 as every other command does
    (before: exit 0, as if the whole bag had gone out)."""
    import signal as signals

    from belt_drive_ros.ros import environment as ros_env

    bag = _torque_bag(tmp_path / "t.mcap", np.arange(1001) * 1_000_000, np.ones(1001))
    proc = subprocess.Popen([sys.executable, "-m", "belt_drive_ros.cli", "replay", str(bag), "--rate", "0.01"],
                            env=ros_env.child_environment(ros_env.process_domain_id(offset=76)), stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    lines = []
    while not any(line.startswith("replaying ") for line in lines):
        line = proc.stderr.readline()
        assert line, "the replay ended before it started"
        lines.append(line)
    time.sleep(0.3)
    proc.send_signal(signals.SIGINT)
    err = "".join(lines) + proc.stderr.read()
    assert proc.wait(timeout=30) == 130, err
    assert "belt-drive: interrupted (SIGINT) after" in err and "Traceback" not in err


@pytest.mark.ros
def test_replay_of_the_applied_torque_reaches_the_node_in_its_namespace_and_ends_when_it_does(tmp_path, ros_domain_id):
    """``replay node_run.mcap --topic /drive_torque_applied`` published on /drive_torque_applied, which no node reads
    (exit 0, "published 2001 messages"), and a ``-r __ns:=/truck1`` left the absolute bag topic where it was. It
    publishes on drive_torque (--to), in its namespace. A --sync replay whose node ended waited 2 s for each message
    left (--loop: for ever); it ends after a few ticks unanswered, exit 1, saying so."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    n = 400
    times = np.arange(n) * 1_000_000
    bag = _torque_bag(tmp_path / "run.mcap", times, np.arange(n, dtype=float), topic="/drive_torque_applied")
    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    got, proc = [], None
    try:
        node = rclpy.create_node("fake_node", namespace="/truck1", context=ctx)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(Float64, "drive_torque", lambda m: got.append(m.data), qos)
        joints = node.create_publisher(JointState, "joint_states", qos)

        def answer(m):  # the node's tick: joint_states stamped at the /clock time, for 20 ticks
            if len(got) <= 20 and joints is not None:
                msg = JointState()
                msg.header.stamp = m.clock
                joints.publish(msg)

        node.create_subscription(Clock, "/clock", answer, qos)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        proc = _replay(bag, ros_domain_id, "--topic", "/drive_torque_applied", "--clock", "--sync",
                       "/truck1/joint_states", "--wait-subscribers", "1", "--ros-args", "-r", "__ns:=/truck1")
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
            if len(got) > 20 and joints is not None:  # the node ends
                node.destroy_publisher(joints)
                joints = None
        assert proc.wait(timeout=5) == 1
        err = proc.stderr.read()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        rclpy.try_shutdown(context=ctx)
    assert got[:21] == list(np.arange(21, dtype=float))  # on /truck1/drive_torque, in order
    assert "--sync /truck1/joint_states: no publisher any more (its node ended)" in err or \
        "--sync /truck1/joint_states: no answer to 3 /clock times in a row" in err, err
    assert len(got) < 30  # it stopped, not 2 s per message for the 379 left


def test_replay_loop_of_a_pass_under_a_millisecond_is_refused():
    """Two messages 1 ns apart looped published 4.7 M messages in 15 s (a single message was refused, 1 ns not)."""
    from belt_drive_ros.ros.replay import replay_schedule

    with pytest.raises(ValueError, match="a loop floods the topic"):
        replay_schedule(np.array([0, 1]), loop=True)
    with pytest.raises(ValueError, match="a pass of 0.5 ms at rate 1000"):
        replay_schedule(np.arange(6) * 100_000_000, loop=True, rate=1000.0)
    schedule = replay_schedule(np.arange(6) * 100_000_000, loop=True, rate=100.0)  # 5 ms a pass
    assert [next(schedule)[2] for _ in range(7)] == [0, 1, 2, 3, 4, 5, 0]
    assert len(list(replay_schedule(np.array([0, 1])))) == 2  # (once: as recorded)


def test_a_torque_bag_spanning_under_a_microsecond_is_named_and_an_explicit_duration_runs_it(tmp_path, capsys):
    """A bag whose two messages are 999 ns apart: the run's duration became its span, and the scene's check named
    'duration: 9.99e-07 s is outside the plausible range', even with --duration 0.5 given. Now the bag is named,
    and a --duration given runs."""
    from belt_drive_ros.cli import main

    bag = _torque_bag(tmp_path / "short.mcap", [10**18, 10**18 + 999], [5.0, 6.0])
    assert main(["sim", "paper", "--torque-bag", str(bag), "--quiet"]) == 2
    assert f"{bag}: its torque spans 9.99e-07 s, less than the shortest run (1e-06 s)" in capsys.readouterr().err
    assert main(["sim", "paper", "--torque-bag", str(bag), "--duration", "0.05", "--method", "etd4", "--quiet"]) == 0
