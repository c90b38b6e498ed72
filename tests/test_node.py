"""BeltDriveNode in-process, in lockstep with /clock (belt_drive_ros.ros.harness).

Tolerances: the node and the offline simulator run the same integrator on
the same steps with the same held torques, so states and outputs agree to
rounding; 1e-9 (relative and absolute, SI units) leaves room for the
offline path's compiled float loop summing in a different order.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.scene import load_scene
from belt_drive_ros.core.simulate import Simulator
from belt_drive_ros.core.sources import Table
from belt_drive_ros.ros.harness import BeltDriveHarness

pytestmark = pytest.mark.ros

TOL = dict(rtol=1e-9, atol=1e-9)
#: (time [s], drive torque [N m]) published at that simulated time
SCHEDULE = ((0.0, 6.0), (0.15, 12.0), (0.3, -3.0), (0.4, 0.0))
DURATION = 0.5
TICK = 1e-3


def run_node(domain, scene="paper", schedule=SCHEDULE, duration=DURATION, step=None, **params):
    params.setdefault("input_timeout", 0.0)
    with BeltDriveHarness(scene, domain_id=domain, **params) as h:
        ends = [t for t, _ in schedule[1:]] + [duration]
        for (t, value), end in zip(schedule, ends):
            h.publish_torque(value)
            h.advance(end - t, step=step)
        return h.outputs(), h.node.settings


def run_offline(scene, model, method, dt, schedule=SCHEDULE, duration=DURATION):
    """Offline reference: the torque sequence as a zero-order-hold Table.

    Switch times are the grid times ``dt * k`` of the publish times, the
    very floats the simulator's grid holds: the table lookup at that step's
    start sees the new value, and no switch lies inside a step (the
    simulator would split such a step there, unlike the node's tick).
    """
    times = tuple(dt * round(t / dt) for t, _ in schedule)
    drive = Table(times=times, values=tuple(v for _, v in schedule), interpolation="previous")
    mdl = make_model(model, scene.params)
    sim = Simulator(mdl, drive, scene.load, method, dt)
    time, states = sim.run(duration, scene.initial_state.vector(model, scene.params.ratio))
    outputs = mdl.outputs(states, sim.plant.input_array(time, states))
    return time, states, outputs


@pytest.mark.parametrize(
    "model, method, substeps",
    [("flexible", "exact", 1), ("flexible", "exact", 4), ("flexible", "etd2", 1), ("rigid", "exact", 1)],
)
def test_outputs_equal_offline_simulator(ros_domain_id, model, method, substeps):
    scene = load_scene("paper")
    schedule = SCHEDULE if method == "exact" else ((0.0, 8.0),)  # etd2 samples the torque at the step end too
    out, settings = run_node(ros_domain_id, model=model, method=method, substeps=substeps, schedule=schedule)
    assert settings.model.name == model and settings.method == method
    time, states, ref = run_offline(scene, model, method, TICK / substeps, schedule)
    time, states = time[::substeps], states[::substeps]
    ref = {k: v[::substeps] for k, v in ref.items()}
    assert out["time"].shape == time.shape
    np.testing.assert_allclose(out["time"], time, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out["phi_M"], ref["phi_M"], **TOL)
    np.testing.assert_allclose(out["omega_M"], ref["omega_M"], **TOL)
    np.testing.assert_allclose(out["shaft_speed"], ref["omega_M"], **TOL)
    np.testing.assert_allclose(out["phi_3"], ref["phi_3"], **TOL)
    np.testing.assert_allclose(out["omega_3"], ref["omega_3"], **TOL)
    np.testing.assert_allclose(out["phi_1"], ref["phi_1"], **TOL)
    np.testing.assert_allclose(out["omega_2"], ref["omega_2"], **TOL)
    np.testing.assert_allclose(out["load_torque"], ref["load_torque"], **TOL)
    if model == "flexible":  # rigid: belt torque depends on the torque held *at* a switch tick
        np.testing.assert_allclose(out["belt_torque"], ref["belt_torque"], **TOL)
        np.testing.assert_allclose(out["relative_deflection"], ref["relative_deflection"], **TOL)
    assert out["omega_M"][-1] > 10.0  # it actually moved


def test_partial_steps_land_on_the_clock(ros_domain_id, tmp_path):
    """/clock in 1.5 ms jumps with a 1 ms tick: each tick integrates 1 ms + a 0.5 ms partial step.

    With a constant load the exact method is exact for any partition, so the
    node equals the offline run on a 0.5 ms grid at the common times.
    """
    scene = load_scene("paper").with_overrides(load=Table(times=(0.0,), values=(2.0,)), name="const_load")
    path = tmp_path / "const_load.yaml"
    path.write_text(scene.to_yaml())
    schedule = ((0.0, 6.0), (0.06, -2.0))
    out, settings = run_node(ros_domain_id, scene=str(path), model="flexible", method="exact", substeps=1,
                             schedule=schedule, duration=0.12, step=0.0015)
    assert np.allclose(np.diff(out["time"]), 0.0015)
    time, _, ref = run_offline(load_scene(str(path)), "flexible", "exact", 0.0005, schedule, duration=0.12)
    idx = np.rint(out["time"] / 0.0005).astype(int)
    for name in ("phi_M", "omega_M", "phi_3", "omega_3", "belt_torque", "relative_deflection"):
        np.testing.assert_allclose(out[name], ref[name][idx], rtol=1e-9, atol=1e-9, err_msg=name)


def _lockstep_run(domain):
    # closed loop: the scene's diesel (governor on shaft_speed) through a source node, compressor load
    with BeltDriveHarness("truck_compressor", domain_id=domain, source="scene", input_timeout=0.0) as h:
        h.advance(0.1)
        h.advance(0.0125, step=0.0025)  # jumps over ticks, partial steps
        h.set_parameters(model="rigid")  # a runtime switch mid-run
        h.advance(0.03)
        h.set_parameters(model="flexible", k=2.5e5)
        h.advance(0.03)
        return h.outputs()


def test_clock_lockstep_is_deterministic(ros_domain_id):
    first = _lockstep_run(ros_domain_id)
    second = _lockstep_run(ros_domain_id)
    assert first["time"].size > 150
    assert set(first) == set(second)
    for name in first:
        assert np.array_equal(first[name], second[name]), name
    assert np.ptp(first["drive_torque"]) > 1.0  # the engine's pulsating torque really was in the loop


def test_nonfinite_input_rejected_and_counted(ros_domain_id):
    with BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:
        h.publish_torque(5.0)
        for bad in (math.nan, math.inf, -math.inf):
            h.publish_torque(bad)
        h.advance(0.01)
        assert h.node.drive_torque == 5.0
        out = h.outputs()
        assert np.all(out["drive_torque"][1:] == 5.0)
        diag = h.diagnostics()["input"]
        assert diag["values"]["rejected_nonfinite"] == "3"
        assert diag["values"]["received"] == "4"


def test_torque_limit_clamps_and_counts(ros_domain_id):
    with BeltDriveHarness(domain_id=ros_domain_id, torque_limit=5.0) as h:
        h.publish_torque(100.0)
        h.advance(0.002)
        h.publish_torque(-7.0)
        h.advance(0.002)
        out = h.outputs()
        assert out["drive_torque"][2] == 5.0 and out["drive_torque"][-1] == -5.0
        assert h.diagnostics()["input"]["values"]["clamped"] == "2"


@pytest.mark.parametrize("behavior", ["zero", "hold"])
def test_stale_input_times_out_with_warning(ros_domain_id, behavior):
    with BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.05, timeout_behavior=behavior) as h:
        h.publish_torque(10.0)
        h.advance(0.04)
        assert h.diagnostics()["input"]["level"] == "OK"
        h.advance(0.03)  # now 70 ms after the message
        diag = h.diagnostics()["input"]
        assert diag["level"] == "WARN" and "stale" in diag["message"]
        out = h.outputs()
        expect_late = 0.0 if behavior == "zero" else 10.0
        assert out["drive_torque"][40] == 10.0 and out["drive_torque"][-1] == expect_late
        h.publish_torque(3.0)  # fresh input clears the warning
        h.advance(0.002)
        assert h.diagnostics()["input"]["level"] == "OK"
        assert h.outputs()["drive_torque"][-1] == 3.0


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def test_burst_of_10000_messages_does_not_queue(ros_domain_id):
    import time

    with BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:
        h.publish_torque(1.0)
        h.advance(0.005)
        rss0 = _rss_mb()
        received0 = h.node.counters["received"]
        pub = h._pub_torque
        from std_msgs.msg import Float64

        msg = Float64()
        for i in range(10_000):
            msg.data = float(i)
            pub.publish(msg)
        msg.data = 77.0
        start = time.perf_counter()
        pub.publish(msg)
        h._spin_until(lambda: h.node.drive_torque == 77.0, "the burst's last message")
        latency = time.perf_counter() - start
        processed = h.node.counters["received"] - received0
        h.advance(0.002)
        assert h.outputs()["drive_torque"][-1] == 77.0
        assert processed <= 100, f"{processed} messages processed: the input queue is not bounded"
        assert latency < 0.5, f"last message of the burst applied after {latency:.3f} s"
        assert _rss_mb() - rss0 < 30.0


def test_invalid_runtime_parameters_rejected_with_reason(ros_domain_id):
    with BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:
        h.publish_torque(6.0)
        h.advance(0.01)
        before = {n: h.node.get_parameter(n).value for n in ("k", "r_3", "method", "model", "step_rate_hz", "scene")}
        cases = {
            "k": (-1.0, "range"),
            "r_3": (0.0, "r_3: must be > 0"),
            "method": ("nope", "unknown integrator"),
            "model": ("stiff", "must be one of"),
            "step_rate_hz": (0.0, "range"),
            "scene": ("no_such_scene", "unknown scene"),
            "timeout_behavior": ("maybe", "hold, zero"),
            "substeps": (1.5, "type"),
        }
        for name, (value, why) in cases.items():
            result = h.set_parameters(**{name: value})
            assert not result.successful, name
            assert why in result.reason, (name, result.reason)
        unstable = h.set_parameters(method="euler")
        assert not unstable.successful and "UNSTABLE" in unstable.reason and "exact" in unstable.reason
        assert {n: h.node.get_parameter(n).value for n in before} == before
        h.advance(0.01)  # still alive and stepping
        out = h.outputs()
        assert out["time"][-1] == pytest.approx(0.02)
        assert all(np.all(np.isfinite(v)) for v in out.values())
        assert h.diagnostics()["simulation"]["level"] == "OK"


def test_runtime_changes_apply_without_restart(ros_domain_id):
    with BeltDriveHarness(domain_id=ros_domain_id, model="flexible", input_timeout=0.0) as h:
        h.publish_torque(8.0)
        h.advance(0.2)
        assert h.set_parameters(k=4.0e4, c=3.0).successful
        assert h.node.settings.params.k == 4.0e4
        assert h.set_parameters(k=50000).successful  # an integer is accepted for a double parameter
        speed = h.outputs()["shaft_speed"][-1]
        assert h.set_parameters(model="rigid").successful  # state mapped, not restarted
        h.advance(0.001)
        assert h.node.settings.model.name == "rigid"
        assert h.outputs()["shaft_speed"][-1] == pytest.approx(speed, rel=0.02)
        assert h.set_parameters(model="flexible").successful
        h.advance(0.001)
        assert h.outputs()["shaft_speed"][-1] == pytest.approx(speed, rel=0.02)
        # a new scene brings its own parameters and restarts from its initial state
        assert h.set_parameters(scene="truck_compressor").successful
        truck = load_scene("truck_compressor")
        assert h.node.get_parameter("k").value == truck.params.k
        assert h.node.get_parameter("substeps").value == 2  # truck dt = 0.5 ms at 1 kHz
        h.advance(0.001)
        assert h.outputs()["shaft_speed"][-1] == pytest.approx(truck.initial_state.omega_M, rel=0.05)
        assert h.set_parameters(step_rate_hz=500).successful
        n = h.outputs()["time"].size
        h.advance(0.01, step=0.002)
        assert h.outputs()["time"].size == n + 5


def test_divergence_halts_without_publishing_nonfinite_values(ros_domain_id):
    with BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:
        h.publish_torque(2.0)
        h.advance(0.01)
        h.publish_torque(1e300)  # finite, accepted, and the state runs away
        h.advance(0.01)
        diag = h.diagnostics()["simulation"]
        assert diag["level"] == "ERROR" and "diverged" in diag["message"]
        assert h.node.halted
        n = h.outputs()["time"].size
        h.advance(0.01)
        out = h.outputs()
        assert out["time"].size == n  # halted: nothing new published
        assert all(np.all(np.isfinite(v)) for v in out.values())
        assert np.max(np.abs(out["omega_M"])) < 1e5
        h.publish_torque(1.0)
        assert "restarted" in h.reset()
        h.advance(0.01)
        assert h.node.halted is None
        assert h.outputs()["time"].size > n
        assert h.diagnostics()["simulation"]["level"] == "OK"


@pytest.mark.parametrize("factor", [0.0, 2.0])
def test_publish_clock_time_master(ros_domain_id, factor):
    """The node drives /clock: whole ticks, /clock after the outputs of the same time, paced by the factor."""
    import time

    from rosgraph_msgs.msg import Clock

    with BeltDriveHarness(domain_id=ros_domain_id, use_sim_time=False, publish_clock=True, real_time_factor=factor,
                          input_timeout=0.0) as h:
        clocks = []
        h.probe.create_subscription(Clock, "/clock", lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec), 10000)
        h._spin_until(lambda: len(clocks) >= 5, "/clock")
        wall0, sim0 = time.perf_counter(), h.node._sim_ns
        h.spin(0.4)
        ratio = (h.node._sim_ns - sim0) / 1e9 / (time.perf_counter() - wall0)
        assert h.set_parameters(real_time_factor=1e-4).successful  # all but stop, then drain
        h.spin(0.2)
        stamps = {row[0] for row in h._rows}
        clocks = np.array(clocks, dtype=np.int64)
        steps = np.diff(clocks)
        assert np.all(steps > 0) and np.all(steps % 1_000_000 == 0)  # whole ticks, increasing
        if factor:
            assert ratio == pytest.approx(factor, rel=0.25)
            assert steps.max() <= 10_000_000  # a late wall timer catches up by whole ticks, no leaps
            assert set(clocks.tolist()) <= stamps  # every /clock time has its outputs
        else:
            assert ratio > 1.0  # faster than real time even with this probe in the process
        assert h.diagnostics()["simulation"]["values"]["time_base"] == "publish_clock"


def test_parameters_from_a_params_file(ros_domain_id, tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(
        "belt_drive:\n  ros__parameters:\n    k: 30000\n    c: 2.5\n    model: rigid\n    step_rate_hz: 500\n"
        "    timeout_behavior: zero\n"
    )
    with BeltDriveHarness(domain_id=ros_domain_id, ros_args=["--ros-args", "--params-file", str(path)], c=4.0) as h:
        s = h.node.settings
        assert (s.params.k, s.params.c, s.model.name, s.step_rate_hz, s.timeout_behavior) == (3e4, 4.0, "rigid", 500.0, "zero")
        h.advance(0.01)
        assert h.outputs()["time"].size == 6  # 500 Hz: the initial sample + 5 ticks
