"""The network node's topic inputs against absurd values: its simulation
(``NetworkSimulation``) as the node's callbacks and ticks drive it."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros


class _Log:
    def __init__(self):
        self.lines = []

    def error(self, text):
        self.lines.append(text)

    warn = info = error


@pytest.mark.parametrize("value", [1e300, -1e300, 1e9, float("nan"), float("inf")])
def test_an_absurd_input_is_rejected_not_held_into_a_divergence_every_tick(value):
    """Before: |value| up to 1e308 was held; every tick diverged, restarted the run and logged an error (1,000
    lines a second at 1 kHz), the joints stuck at the initial state. Now, as the paper node's bound and a
    profile's plausible range (TORQUE_MAX): rejected and counted, the inputs before it still held."""
    from belt_drive_ros.io.network_bag import NetworkLayout
    from belt_drive_ros.ros.network_node import PARAMETERS, NetworkSettings, NetworkSimulation

    settings = NetworkSettings.from_values(dict({name: default for name, default, _ in PARAMETERS}, scene="fead_i4"))
    layout, counters, log = NetworkLayout(settings.scene), {}, _Log()
    sim = NetworkSimulation(settings, layout, counters, log)
    sim.advance_to(0)
    for _, pulley in layout.inputs:
        assert sim.receive(pulley, 5.0)
    for _, pulley in layout.inputs:
        assert not sim.receive(pulley, value)
    for k in range(1, 11):
        assert sim.advance_to(k * settings.tick_ns)
    assert counters["divergences"] == 0 and log.lines == [] and counters["restarts"] == 1
    counter = "rejected_nonfinite" if value != value or abs(value) == float("inf") else "rejected_bound"
    assert counters[counter] == len(layout.inputs)
    assert [v for _, v in sim.applied] == [5.0] * len(layout.inputs)
