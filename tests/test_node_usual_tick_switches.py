"""The node's usual tick (``BeltDriveNode._tick`` calling ``NodeSimulation.plain_tick`` itself) where the slipping
belt switches mode inside a tick, and where the node's readers change mid-run.

The usual tick counts a compiled tick's flags from the kernel's answer (``-done & 7``, with ``_EVENT`` per located
mode switch on top) without reading its outputs; the general path counts them from the outputs
(``BeltDriveNode._count``) and notes each switch from an :class:`~belt_drive_ros.core.slip.Event`. A node whose
tick kernel is taken away (the engine's path) must publish the same bytes and end with the same counters, the same
diagnostics window and the same noted switches, through the truck's own stick/slip events, through a reader of a
Float64 output appearing and leaving mid-run (the usual tick turned off and on again) and through ``~/reset``.
"""

from __future__ import annotations

import pytest


@pytest.mark.ros
def test_the_usual_tick_counts_mode_switches_and_flags_as_the_general_path():
    import time

    from rclpy.parameter import Parameter

    from belt_drive_ros.ros.executors import ros_session
    from belt_drive_ros.ros.node import BeltDriveNode
    from belt_drive_ros.ros.simulation import _EVENT

    params = (("scene", "truck_compressor"), ("model", "slipping"), ("drive_source", "scene"))
    with ros_session() as ctx:
        over = [Parameter("tick_thread", value=False)] + [Parameter(k, value=v) for k, v in params]
        nodes = [BeltDriveNode(context=ctx, parameter_overrides=over) for _ in range(2)]
        try:
            nodes[1].sim._tick_kernel = None  # the general path: the engine, model.outputs
            plain = {"calls": 0, "switch_ticks": 0}
            sim = nodes[0].sim
            original = sim.plain_tick

            def counted(now_ns):
                done = original(now_ns)
                plain["calls"] += 1
                plain["switch_ticks"] += done <= -_EVENT  # a mode switch located in the kernel
                return done

            sim.plain_tick = counted

            def readers(shaft_speed: int):
                for node in nodes:
                    node.refresh_subscriber_counts()
                    node._readers["joint_states"] = 1
                    node._readers["shaft_speed"] = shaft_speed
                    node._count_listeners()

            readers(0)
            tick_ns = sim.settings.tick_ns
            t0 = time.time_ns() // tick_ns * tick_ns
            for k in range(3000):
                if k in (700, 1900):
                    readers(1)  # a reader of a Float64 output appears: not the usual tick
                elif k in (900, 2100):
                    readers(0)  # and leaves again
                if k == 1500:
                    for node in nodes:
                        with node.drive.lock:
                            node._resets_pending += 1
                now = t0 + k * tick_ns
                sent = []
                for node in nodes:
                    with node.timing.lock:
                        sent.append(node._tick(now, True))
                assert [data for _, data in sent[0]] == [data for _, data in sent[1]], k
                assert list(nodes[0]._last[0]) == list(nodes[1]._last[0]), k
            a, b = nodes
            assert a.sim.slip_events == b.sim.slip_events and len(a.sim.slip_events) > 20
            assert a.counters == b.counters
            assert a.counters["slip_events"] > 20 and a.counters["slip_ticks"] > 0 and a.counters["published_slip"] == 3000
            assert (a.stats.window.slack, a.stats.window.slip) == (b.stats.window.slack, b.stats.window.slip)
            # the usual tick took most ticks, mode switches among them
            assert plain["calls"] > 2000 and plain["switch_ticks"] > 10, plain
        finally:
            for node in nodes:
                node.destroy_node()
