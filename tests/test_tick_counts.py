"""The node counts its ticks' flags (slack, slip, the slipping model's outputs) from the compiled tick's return.

The usual tick does not read its outputs: the tick kernels return the flags of
the outputs they wrote (``core.tick``: SLACK, SLIPS, SLIPPING) and the node
counts those (``published_slip``, ``slack_ticks``, ``slip_ticks`` and the
diagnostics window's ``slack``, ``slip``). They must be the counts of the
published values themselves, tick by tick, as the general path counts them.
"""

from __future__ import annotations

import time

import pytest

from belt_drive_ros.core import tick
from belt_drive_ros.ros import simulation
from belt_drive_ros.ros.simulation import SLACK, SLIPPING, SLIPS

pytestmark = pytest.mark.ros


def test_the_flags_are_the_tick_kernels():
    assert (SLACK, SLIPS, SLIPPING, simulation._EVENT) == (tick.SLACK, tick.SLIPS, tick.SLIPPING, tick.EVENT)
    assert SLACK | SLIPS | SLIPPING == tick.EVENT - 1


def _counted(params, ticks: int, torque=None) -> tuple[dict, dict, int]:
    """The node's counters and diagnostics window after ``ticks`` usual ticks, the same counts made from each
    published tick's values, and how many ticks the compiled tick took."""
    from rclpy.parameter import Parameter

    from belt_drive_ros.ros.executors import ros_session
    from belt_drive_ros.ros.node import BeltDriveNode

    with ros_session() as ctx:
        over = [Parameter("tick_thread", value=False)] + [Parameter(k, value=v) for k, v in params]
        node = BeltDriveNode(context=ctx, parameter_overrides=over)
        try:
            node.refresh_subscriber_counts()
            node._readers["joint_states"] = 1  # the usual tick: joint_states only
            node._count_listeners()
            keys = ("published_slip", "slack_ticks", "slip_ticks")
            before = {k: node.counters[k] for k in keys}
            window = node.stats.window
            w0 = (window.slack, window.slip)
            tick_ns = node.sim.settings.tick_ns
            t0 = time.time_ns() // tick_ns * tick_ns
            expected = dict.fromkeys(keys, 0)
            compiled = 0
            for k in range(ticks):
                now = t0 + k * tick_ns
                if torque is not None:
                    node.drive.receive(torque(k), now - 1, node.sim.settings)
                with node.timing.lock:
                    node._tick(now)
                compiled += node.sim._fresh_ns == now
                v = list(node._last[0])
                expected["published_slip"] += len(v) > len(simulation.TICK_OUTPUTS)
                expected["slack_ticks"] += v[14] != 0.0
                expected["slip_ticks"] += v[15] != 0.0
            got = {k: node.counters[k] - before[k] for k in keys}
            got["window"] = (window.slack - w0[0], window.slip - w0[1])
            expected["window"] = (expected["slack_ticks"], expected["slip_ticks"])
            return got, expected, compiled
        finally:
            node.destroy_node()


def test_slipping_ticks_counted_by_their_flags():
    got, expected, compiled = _counted((("scene", "truck_compressor"), ("model", "slipping"),
                                        ("drive_source", "scene")), 1500)
    assert got == expected and compiled > 1400
    assert expected["published_slip"] == 1500 and 0 < expected["slip_ticks"] < 1500


def test_slack_and_slip_of_the_linear_model_counted_by_their_flags():
    # a drive torque far beyond the capstan limit on and off: slip and slack ticks, most of them compiled
    got, expected, compiled = _counted((("drive_source", "topic"), ("input_timeout", 0.0), ("torque_bound", 1.0e4)), 1200,
                                       lambda k: 900.0 if (k // 100) % 2 else -900.0)
    assert got == expected and compiled > 1000
    assert expected["published_slip"] == 0 and expected["slip_ticks"] > 100 and expected["slack_ticks"] > 100
