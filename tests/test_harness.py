"""belt_drive_ros.ros.harness.BeltDriveHarness: the documented API, as a user's test would use it."""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.ros.harness import BeltDriveHarness

pytestmark = pytest.mark.ros


def test_docstring_example(ros_domain_id):
    with BeltDriveHarness(scene="paper", model="flexible", method="exact", domain_id=ros_domain_id) as h:
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
        result = h.set_parameters(k=-1.0)
        assert not result.successful and "k" in result.reason


def test_real_time_mode(ros_domain_id):
    with BeltDriveHarness(use_sim_time=False, domain_id=ros_domain_id, step_rate_hz=500.0) as h:
        h.publish_torque(10.0)
        h.advance(0.3)  # wall seconds
        h.spin(0.02)
        out = h.outputs()
        assert 60 <= out["time"].size <= 200  # ~150 ticks at 500 Hz; generous for a loaded machine
        assert np.all(np.diff(out["stamp"]) > 0)
        assert out["shaft_speed"][-1] > 0.0 and out["drive_torque"][-1] == 10.0


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
