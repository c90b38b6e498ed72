"""A tick computing does not hold up the node's input callbacks (issue 20: "the tick thread computes while the
executor serves callbacks").

A tick holds the tick source's lock through its compute; the input callbacks (``drive_torque``, ``~/reset``, a
network's load inputs) hand their message over under a lock of their own, which the tick takes at its start
only. The rule that follows: a message received before a tick starts acts from that tick on; one received while
it computes acts from the next tick (as one received after the tick's start always did).

Each test holds a tick of many grid steps inside its compute (a gate in the compiled call, as long as the test
needs, whatever the machine's load) and calls an input callback from another thread: it must return while the
tick is still inside its compute. Before, the callback waited for the tick's lock, i.e. for the tick to end.
"""

from __future__ import annotations

import struct
import threading

import pytest

pytestmark = pytest.mark.ros

#: a callback that waits this long [s] waits for the tick (the gate holds the tick until the callback is back)
WAIT_S = 10.0


def float64_cdr(value: float) -> bytes:
    """A ``std_msgs/Float64``'s serialized bytes (little-endian CDR), as a raw subscription hands them over."""
    return b"\x00\x01\x00\x00" + struct.pack("<d", value)


class Gate:
    """Wraps the callables ``names`` of ``obj`` (its compiled tick calls): a call signals ``inside`` and waits
    for ``release`` before it computes."""

    def __init__(self, obj, names):
        self.inside, self.release = threading.Event(), threading.Event()
        self.calls = 0
        for name in names:
            real = getattr(obj, name)

            def gated(*args, _real=real, **kwargs):
                self.calls += 1
                self.inside.set()
                self.release.wait(60.0)
                return _real(*args, **kwargs)

            setattr(obj, name, gated)


def served_while_held(gate: Gate, tick, *callbacks) -> list[bool]:
    """Run ``tick()`` in a thread, held inside its compute by ``gate``; call each callback from a thread of its own
    meanwhile: for each, whether it returned while the tick was held. Then let the tick finish."""
    worker = threading.Thread(target=tick)
    worker.start()
    try:
        assert gate.inside.wait(WAIT_S), "the tick never reached its compute"
        served = []
        for callback in callbacks:
            t = threading.Thread(target=callback)
            t.start()
            t.join(WAIT_S)
            served.append(not t.is_alive() and worker.is_alive())
    finally:
        gate.release.set()
        worker.join(60.0)
    assert not worker.is_alive()
    return served


def test_drive_torque_and_reset_are_served_while_a_long_tick_computes_and_act_from_the_next_tick(ros_domain_id):
    from belt_drive_ros.ros.harness import BeltDriveHarness

    with BeltDriveHarness(use_sim_time=True, domain_id=ros_domain_id, input_timeout=0.0) as h:
        node = h.node
        h.publish_torque(2.0)
        h.advance(0.003)
        assert node.drive_torque == 2.0
        t0 = node.integrated_ns
        target = t0 + 2_000_000_000  # 2,000 grid steps in one tick (/clock jumped 2 s)
        gate = Gate(node.sim._tick_kernel, ("step",))

        def tick():
            with node.timing.lock:  # as the executor's timer and the tick thread hold it
                node._tick(target)

        class Response:
            success, message = False, ""

        resets = node.counters["reset_calls"]
        served = served_while_held(gate, tick, lambda: node._on_drive_torque(float64_cdr(5.0)),
                                   lambda: node._on_reset(None, Response()))
        assert served == [True, True]
        assert gate.calls == 1 and node.counters["reset_calls"] == resets + 1
        # the long tick took its inputs at its start: 2 N m held through it, no restart yet
        assert node.integrated_ns == target and node.drive_torque == 2.0
        assert node.last["drive_torque"] == 2.0 and node.last["time"] > 2.0
        restarts = node.counters["restarts"]
        with node.timing.lock:
            node._tick(target + 1_000_000)
        # the next tick: the torque received during the compute, and the reset (the restart is this tick: scene
        # time 0 here, the initial state published)
        assert node.drive_torque == 5.0 and node.last["drive_torque"] == 5.0
        assert node.counters["restarts"] == restarts + 1 and node.last["time"] == 0.0


def test_a_network_input_is_served_while_a_long_tick_computes_and_acts_from_the_next_tick(ros_domain_id):
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64

    from belt_drive_ros.ros.network_node import NetworkNode

    context = Context()
    rclpy.init(context=context, domain_id=ros_domain_id)
    try:
        node = NetworkNode(scene="fead_i4", context=context,
                           parameter_overrides=[Parameter("use_sim_time", value=True)])
        try:
            sim, tick_ns = node.sim, node.settings.tick_ns
            (topic, crank), *_ = [(t, i) for t, i in node.layout.inputs if i == node.settings.scene.driver]
            on_drive = node._input_callback(topic, crank)
            with node.timing.lock:
                node._tick(0)
            on_drive(Float64(data=3.0))
            with node.timing.lock:
                node._tick(tick_ns)
            assert dict(sim.applied)[topic + "_applied"] == 3.0
            gate = Gate(sim.stepper, ("tick",))
            target = tick_ns + 2_000 * tick_ns  # 2,000 ticks' steps in one tick

            def tick():
                with node.timing.lock:
                    node._tick(target)

            served = served_while_held(gate, tick, lambda: on_drive(Float64(data=4.0)))
            assert served == [True] and gate.calls == 1
            assert sim.t_ns == target and dict(sim.applied)[topic + "_applied"] == 3.0
            assert sim.stepper.held[crank] is not None
            held = sim.stepper.held[crank]
            with node.timing.lock:
                node._tick(target + tick_ns)
            assert dict(sim.applied)[topic + "_applied"] == 4.0  # from the next tick on
            assert sim.stepper.held[crank] != held
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
