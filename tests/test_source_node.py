"""TorqueSourceNode and ``belt-drive source``: profiles, angle integration, CSV input, CLI."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from belt_drive_ros.core.sources import Engine, Table

pytestmark = pytest.mark.ros


@pytest.fixture
def context(ros_domain_id):
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def test_engine_torque_follows_speed_and_integrated_crank_angle(context):
    from std_msgs.msg import Float64

    from belt_drive_ros.ros.source_node import TorqueSourceNode

    engine = Engine(mean_torque=20.0, harmonics=(15.0, 5.0), cylinders=6, speed_setpoint=80.0, governor_gain=2.0)
    node = TorqueSourceNode(engine, context=context, autostart=False, initial_speed=50.0)
    try:
        assert node._sub is not None  # closed loop: subscribes to shaft_speed
        t0 = 3_000_000_000
        torques, angle = [], 0.0
        speeds = (50.0, 60.0, 61.0, 75.0)
        for k, speed in enumerate(speeds):
            if k:
                node._on_speed(Float64(data=speed))
                angle += 0.5 * (speeds[k - 1] + speed) * 0.002  # trapezoidal over the last 2 ms
            torques.append(node.publish_at(t0 + k * 2_000_000))
            expect = engine.torque(k * 0.002, angle, speed)
            assert torques[-1] == pytest.approx(expect, rel=1e-12, abs=1e-12)
        node._on_speed(Float64(data=math.nan))
        assert node.counters["speed_rejected"] == 1 and node.speed == 75.0
        assert node.counters["published"] == 4
    finally:
        node.destroy_node()


def test_open_loop_profile_does_not_subscribe(context):
    from belt_drive_ros.ros.source_node import TorqueSourceNode

    table = Table(times=(0.0, 0.5), values=(1.0, 4.0), interpolation="previous")
    node = TorqueSourceNode(table, context=context, autostart=False)
    try:
        assert node._sub is None
        assert node.publish_at(10**9) == 1.0
        assert node.publish_at(10**9 + 600_000_000) == 4.0
    finally:
        node.destroy_node()


def test_rate_parameter_is_validated_at_runtime(context):
    from rclpy.parameter import Parameter

    from belt_drive_ros.ros.source_node import TorqueSourceNode

    node = TorqueSourceNode(Table(times=(0.0,), values=(1.0,)), context=context, rate_hz=200.0)
    try:
        assert not node.set_parameters([Parameter("rate_hz", value=-3.0)])[0].successful
        assert node.set_parameters([Parameter("rate_hz", value=400)])[0].successful
        assert node.rate_hz == 400.0 and node._timer.timer_period_ns == 2_500_000
    finally:
        node.destroy_node()


def test_sim_time_ticks_once_per_clock_step_on_the_grid(context):
    """On ``use_sim_time`` the ``/clock`` messages tick the source: one publish per grid point reached, at the
    message's time, none for a repeated or in-between ``/clock``, one for a jump of many periods, a new grid after
    a jump back; the rclpy timer stays silent on simulated time."""
    from rclpy.parameter import Parameter
    from rosgraph_msgs.msg import Clock

    from belt_drive_ros.ros.source_node import TorqueSourceNode

    node = TorqueSourceNode(Table(times=(0.0, 0.01), values=(1.0, 2.0), interpolation="previous"), context=context,
                            rate_hz=1000.0,
                            parameter_overrides=[Parameter("use_sim_time", value=True)])
    times = []
    publish_at = node.publish_at
    node.publish_at = lambda now: times.append(now) or publish_at(now)
    try:
        assert node.get_clock().ros_time_is_active
        ms = 1_000_000
        clock = [1000 * ms, 1000 * ms, 1001 * ms, 1001 * ms + ms // 2, 1002 * ms, 1012 * ms + 300_000, 1013 * ms,
                 1013 * ms, 1500 * ms, 1500 * ms + 999_999, 1501 * ms]  # fmt: skip
        for ns in clock:
            node._on_clock(Clock(clock=divmod_time(ns)))
        assert times == [1000 * ms, 1001 * ms, 1002 * ms, 1012 * ms + 300_000, 1013 * ms, 1500 * ms, 1501 * ms]
        assert node.counters["published"] == len(times)
        node._on_tick()  # the timer on simulated time: silent
        assert len(times) == 7
        node._on_clock(Clock(clock=divmod_time(900 * ms)))  # back in time: starts over, a new grid from there
        node._on_clock(Clock(clock=divmod_time(900 * ms + ms // 2)))
        node._on_clock(Clock(clock=divmod_time(901 * ms)))
        assert times[7:] == [900 * ms, 901 * ms] and node.last_torque == 1.0
        assert node.set_parameters([Parameter("rate_hz", value=500.0)])[0].successful  # 2 ms from the last tick
        for ns in (902 * ms, 903 * ms):
            node._on_clock(Clock(clock=divmod_time(ns)))
        assert times[9:] == [903 * ms]
    finally:
        node.destroy_node()


def divmod_time(ns: int):
    from builtin_interfaces.msg import Time

    sec, nanosec = divmod(ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def test_source_loads_its_compiled_profile_before_it_runs():
    """The node evaluates its profile at construction: the first tick does not load the compiled kernel (under
    load that took 3-12 s, during which no drive_torque was published)."""
    code = (
        "import rclpy\n"
        "from rclpy.context import Context\n"
        "from belt_drive_ros.core import kernel_profiles\n"
        "from belt_drive_ros.io.scenes import load_scene\n"
        "from belt_drive_ros.ros.source_node import TorqueSourceNode\n"
        "profile = load_scene('truck_compressor').drive\n"
        "assert not kernel_profiles.profile_torque.signatures\n"
        "ctx = Context(); rclpy.init(context=ctx, domain_id=int(__import__('sys').argv[1]))\n"
        "node = TorqueSourceNode(profile, context=ctx)\n"
        "print(len(kernel_profiles.profile_torque.signatures))\n"
        "node.destroy_node(); rclpy.try_shutdown(context=ctx)\n"
    )
    from belt_drive_ros.ros import environment as ros_env

    domain = ros_env.process_domain_id(offset=91)
    out = subprocess.run([sys.executable, "-c", code, str(domain)], capture_output=True, text=True, timeout=120,
                         env=ros_env.child_environment(domain))
    assert out.returncode == 0, out.stderr[-2000:]
    assert int(out.stdout.split()[-1]) >= 1


def test_csv_profiles(tmp_path):
    from belt_drive_ros.commands.source import read_csv_profile
    from belt_drive_ros.core.errors import SceneError

    plain = tmp_path / "plain.csv"
    plain.write_text("0.0, 1.0\n0.5, 2.0\n1.0, 3.0\n")
    table = read_csv_profile(plain)
    assert table.interpolation == "previous" and table.torque(0.7, 0, 0) == 2.0
    sim = tmp_path / "sim.csv"  # the layout of 'belt-drive sim --out'
    sim.write_text("time,phi_M,omega_M,drive_torque\n0,0,0,5\n0.1,0,1,6\n")
    assert np.array_equal(read_csv_profile(sim, interpolation="linear").values, [5.0, 6.0])
    with pytest.raises(SceneError, match="no column 'torque'"):
        read_csv_profile(sim, column="torque")


def test_cli_prints_the_profile_without_ros():
    out = subprocess.run(
        [sys.executable, "-m", "belt_drive_ros.cli", "source", "engine", "--scene", "truck_compressor",
         "--mean-torque", "25", "--harmonics", "40,12", "--print"],
        capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert "type: engine" in out.stdout and "mean_torque: 25.0" in out.stdout and "initial_speed: 73.3" in out.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "belt_drive_ros.cli", "source", "motor", "--scene", "truck_compressor", "--print"],
        capture_output=True, text=True, timeout=60,
    )
    assert bad.returncode == 2 and "not 'motor'" in bad.stderr


def test_a_stopping_source_publishes_zero_once_so_a_holding_node_coasts(context):
    """The source stopped before the node (the README's two terminals, stopped in that order): the node held the
    last torque it got (a 326 N m firing pulse, timeout_behavior hold) and the drive ran away. A source that has
    published publishes 0 N m once as it stops; one that never published says nothing."""
    import time

    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from belt_drive_ros.ros.source_node import TorqueSourceNode

    table = Table(times=(0.0, 0.5), values=(326.0, 4.0), interpolation="previous")
    probe = __import__("rclpy").create_node("probe", context=context)
    got = []
    probe.create_subscription(Float64, "drive_torque", lambda m: got.append(m.data),
                              QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(probe)
    silent = TorqueSourceNode(table, node_name="silent", context=context, autostart=False)
    silent.stop_torque()
    silent.destroy_node()
    node = TorqueSourceNode(table, context=context, autostart=False)
    try:
        deadline = time.monotonic() + 10
        while not node._pub.get_subscription_count() and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        node.publish_at(10**9)
        node.stop_torque()
    finally:
        node.destroy_node()
    deadline = time.monotonic() + 10
    while len(got) < 2 and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.01)
    probe.destroy_node()
    assert got == [326.0, 0.0]
