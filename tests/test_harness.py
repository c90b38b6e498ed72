"""belt_drive_ros.ros.harness.BeltDriveHarness: the documented API, as a user's test would use it."""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.ros.harness import BeltDriveHarness

pytestmark = pytest.mark.ros


def test_docstring_example(ros_domain_id):
    """The example of the harness' docstring and the README: etd4 (``exact`` warned INACCURATE at its first tick on
    this closed loop, a quadratic load: not what a user's first run should show)."""
    with BeltDriveHarness(scene="paper", model="flexible", method="etd4", domain_id=ros_domain_id) as h:
        h.publish_torque(8.0)
        h.advance(0.5)
        h.publish_torque(0.0)
        h.advance(0.25)
        out = h.outputs()
        assert set(out) >= {
            "time", "stamp", "phi_M", "phi_1", "phi_2", "phi_3", "omega_M", "omega_1", "omega_2", "omega_3",
            "drive_torque", "shaft_speed", "load_torque", "belt_torque", "relative_deflection",
        }
        assert all(v.shape == (751,) for v in out.values())
        # one row per 1 ms tick, exactly on the clock
        assert np.array_equal(np.rint(out["time"] * 1e9).astype(np.int64), np.arange(751) * 1_000_000)
        assert out["stamp"][0] == 1.0 and h.now == pytest.approx(1.75)
        assert out["shaft_speed"][500] > 100.0 and out["shaft_speed"][-1] < out["shaft_speed"][500]
        diag = h.diagnostics()
        assert set(diag) == {"simulation", "input", "belt"}
        assert diag["simulation"]["values"]["model_reason"].startswith("flexible")
        assert diag["simulation"]["message"] == "running"  # no inaccurate step
        result = h.set_parameters(k=-1.0)
        assert not result.successful and "k" in result.reason


def test_real_time_mode(ros_domain_id):
    """On the system clock the node ticks on its own grid: system-time stamps whole ticks apart, scene time
    following them. How many ticks a wall second brings is a benchmark figure (``belt-drive bench node``)."""
    import time

    # 50 Hz: the harness's single-threaded spin receives every output of every tick even on a loaded machine
    # (at 500 Hz it falls behind the keep-last-10 queues there, and a dropped message never arrives)
    with BeltDriveHarness(use_sim_time=False, domain_id=ros_domain_id, step_rate_hz=50.0) as h:
        node = h.node
        h.publish_torque(10.0)
        applied_from = len(h._rows) + 1  # the next tick samples it (a tick already under way may not)
        h._spin_until(lambda: len(h._rows) >= applied_from + 30, "30 ticks on the system clock")
        h._spin_until(h._received_all, "the outputs of the last tick")
        stamps = np.array([row[0] for row in h._rows], dtype=np.int64)
        tick_ns = 20_000_000
        assert node.timing.time_base() == "system" and node.counters["restarts"] == 1  # one run, never restarted
        assert stamps[0] == node.origin_ns  # the run starts at its first tick: scene time 0
        assert np.all(np.diff(stamps) > 0) and np.all((stamps - node.origin_ns) % tick_ns == 0)  # on the grid
        assert abs(stamps[-1] - time.time_ns()) < 60e9  # the system clock (not a clock from 0)
        # The tick thread goes on while the test runs (and computes each tick ahead of its due time), so the
        # state may be ahead of the last stamp received; every tick it was integrated to is then published
        # with its own stamp: the state is never integrated past a tick that goes out.
        with node.timing.lock:  # no tick is computed while the time is read
            integrated = node.integrated_ns
        assert integrated >= stamps[-1] and (integrated - node.origin_ns) % tick_ns == 0
        h._spin_until(lambda: h._rows[-1][0] >= integrated, "the tick the state was integrated to")
        stamps = np.array([row[0] for row in h._rows], dtype=np.int64)
        assert integrated in stamps and np.all(np.diff(stamps) > 0)  # published, in order
        sim_time = float(h.diagnostics()["simulation"]["values"]["sim_time"])  # scene time of a tick
        with node.timing.lock:
            latest = node.integrated_ns
        assert (integrated - node.origin_ns) / 1e9 - 1e-6 <= sim_time <= (latest - node.origin_ns) / 1e9 + 1e-6
        assert round(sim_time * 1e9) % tick_ns == 0  # on the grid
        out = h.outputs()
        assert np.all(out["drive_torque"][applied_from + 1:] == 10.0) and out["shaft_speed"][-1] > 0.0


def test_source_in_the_loop_is_stepped_by_the_harness(ros_domain_id):
    from belt_drive_ros.core.sources import MotorCurve

    motor = MotorCurve(stall_torque=12.0, no_load_speed=160.0)
    with BeltDriveHarness(domain_id=ros_domain_id, source=motor, input_timeout=0.0) as h:
        h.advance(0.2)
        out = h.outputs()
        src = h.source
        # the torque applied over each tick is the motor curve at the previous tick's published speed
        np.testing.assert_allclose(out["drive_torque"][2:], 12.0 * (1.0 - out["shaft_speed"][1:-1] / 160.0), rtol=0, atol=1e-12)
        assert src.counters["published"] == out["time"].size
        assert out["shaft_speed"][-1] > 5.0


def test_timeout_is_reported_when_the_node_cannot_progress(ros_domain_id):
    from belt_drive_ros.ros.harness import HarnessTimeout

    with BeltDriveHarness(domain_id=ros_domain_id, timeout=0.3) as h:
        h.node.destroy_subscription(h.node._sub_torque)  # the node no longer listens
        with pytest.raises(HarnessTimeout, match="drive_torque"):
            h.publish_torque(1.0)


def test_the_statuses_of_a_node_in_a_namespace_name_its_namespace(ros_domain_id):
    """Two drives in two namespaces (/truck1/belt_drive, /truck2/belt_drive) both named their statuses
    'belt_drive: simulation', ...: on the one /diagnostics rqt_robot_monitor and the aggregator showed one entry
    flipping between them. The statuses carry the fully qualified name (without its leading slash)."""
    with BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0, namespace="/truck1") as h:
        assert {s.name for s in h.node.diagnostic_status()} == {
            "truck1/belt_drive: simulation", "truck1/belt_drive: input", "truck1/belt_drive: belt"}
        assert set(h.diagnostics()) == {"simulation", "input", "belt"}
    with BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:  # the root namespace: as before
        assert {s.name for s in h.node.diagnostic_status()} == {
            "belt_drive: simulation", "belt_drive: input", "belt_drive: belt"}


def test_a_second_graph_on_the_same_domain_is_reported_not_mixed_in(ros_domain_id):
    """Two harnesses on one domain (what a domain id shared by two test processes does): the second's
    /clock drives the first's node too, whose joint_states reach the second's probe; outputs() says so
    instead of returning the mixed rows; diagnostics() returns the second node's own statuses (an array of
    the first node's, published just before, may arrive in between)."""
    import time

    from belt_drive_ros.ros.harness import DomainShared

    with BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0, node_name="other") as other, \
            BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:
        other.node.publish_diagnostics()
        assert set(h.diagnostics()) == {"simulation", "input", "belt"}  # not "other: simulation", ...
        deadline = time.monotonic() + 60.0
        with pytest.raises(DomainShared, match=f"shares ROS domain {ros_domain_id}"):
            while time.monotonic() < deadline:
                h.advance(0.01)
                other.spin(0.01)
                h.spin(0.01)
                h.outputs()
        assert other.node.counters["published"] > 1  # it did tick on h's /clock


def test_two_harnesses_open_at_once_without_a_domain_each_have_their_own():
    """A user's script that opens two harnesses without naming domains: each chose the process's one domain, so
    each /clock and drive_torque reached the other's node and both runs were wrong with no error (the row counts
    matched). Each open harness now has a domain of its own, and each run equals the same run made alone."""
    def run(h, torque):
        h.publish_torque(torque)
        h.advance(0.05)
        return h.outputs()["omega_M"]

    with BeltDriveHarness(model="flexible", method="etd4", input_timeout=0.0) as a:
        alone = run(a, 8.0)
    with BeltDriveHarness(model="flexible", method="etd4", input_timeout=0.0) as a, \
            BeltDriveHarness(model="flexible", method="etd4", input_timeout=0.0) as b:
        assert a.domain_id != b.domain_id
        first, second = run(a, 8.0), run(b, 2.0)
    np.testing.assert_array_equal(first, alone)
    assert second[-1] < first[-1]  # its own torque, not a's


def test_a_closed_harness_starts_a_new_run_and_keeps_its_rows_readable(ros_domain_id):
    """After close() the run's outputs stay readable; start() again begins a new run (it raised DomainShared,
    blaming another publisher, with the old rows kept); misuse is a RuntimeError saying what to do."""
    h = BeltDriveHarness(model="flexible", method="etd4", domain_id=ros_domain_id, input_timeout=0.0)
    with pytest.raises(RuntimeError, match=r"harness.advance: the harness is not running \(call start\(\) first"):
        h.advance(0.01)
    with h:
        h.publish_torque(8.0)
        h.advance(0.02)
        with pytest.raises(RuntimeError, match="already running"):
            h.start()
    first = h.outputs()  # after close
    assert first["omega_M"].shape == (21,)
    for call in (lambda: h.publish_torque(1.0), lambda: h.diagnostics(), lambda: h.reset(),
                 lambda: h.set_parameters(k=2e4)):
        with pytest.raises(RuntimeError, match="the harness is not running"):
            call()
    with h:
        h.publish_torque(8.0)
        h.advance(0.02)
        np.testing.assert_array_equal(h.outputs()["omega_M"], first["omega_M"])


def test_advance_keeps_the_clock_on_the_tick_grid_and_the_harness_its_time_base(ros_domain_id):
    """advance() by a time that is no whole number of ticks reaches it by one shorter step, then goes back onto
    the grid: three advance(0.0333) tick where advance(0.0999) does (every later tick used to be 0.3 ms off the
    grid, the run 0.2 rad/s off). use_sim_time through set_parameters is refused (the harness then timed out)."""
    def run(steps):
        with BeltDriveHarness(model="flexible", method="etd4", domain_id=ros_domain_id, input_timeout=0.0) as h:
            h.publish_torque(8.0)
            for s in steps:
                h.advance(s)
            refused = h.set_parameters(use_sim_time=False)
            assert not refused.successful and refused.reason.startswith("use_sim_time: the harness's time base")
            h.advance(0.001)
            return h.outputs()

    whole, parts = run([0.0999, 0.0011]), run([0.0333, 0.0333, 0.0333, 0.0011])
    np.testing.assert_array_equal(parts["time"], whole["time"])  # one row per grid tick: 0 .. 0.102 s
    np.testing.assert_array_equal(np.rint(parts["time"] * 1e9).astype(np.int64), np.arange(103) * 1_000_000)
    np.testing.assert_allclose(parts["omega_M"], whole["omega_M"], rtol=1e-12, atol=0)


def test_bad_construction_values_are_one_line_errors():
    for kwargs, match in (({"domain_id": 300}, r"domain_id: must be an integer in \[0, 232\]"),
                          ({"domain_id": 1.5}, "domain_id: must be an integer"),
                          ({"domain_id": "abc"}, "domain_id: must be an integer .* got 'abc'"),
                          ({"start_time": float("nan")}, r"start_time: .* got nan"),
                          ({"start_time": 1e12}, r"start_time: .*\[0, 2147483647\]")):
        with pytest.raises(ValueError, match=match):
            BeltDriveHarness(**kwargs)
