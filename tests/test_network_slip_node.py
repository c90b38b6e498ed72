"""The slipping tier stepped tick by tick (ros/network_stepper.py over core/network/slip.py).

A slipping network (fead_i4 at 150 N installed tension, a greasy alternator
pulsing its load) advanced one node tick at a time equals the whole offline
slipping run bit for bit: states, stick/slip modes, span tensions, slip
speeds and works, with the scene's profiles and with torques held per tick
(against a whole run whose profile is the held values as a table); the node
on ``/clock`` publishes the slip per pulley, and its recording re-simulates
bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from belt_drive_ros.core.network.scene import NetworkScene
from belt_drive_ros.core.network.simulate import simulate
from belt_drive_ros.core.network.slip import simulate_slipping
from belt_drive_ros.ros.network_stepper import NetworkStepper

from test_network_slip import shipped


def slipping_fead(dt=1e-3, duration=0.2):
    data = shipped("fead_i4")
    data["belt"]["installed_tension"] = 150.0
    data.update(dt=dt, duration=duration)
    for p in data["pulleys"]:
        if p["name"] == "alternator":
            p["mu"] = 0.3
            p["torque"] = {"type": "sine", "mean": 2.0, "amplitude": 3.0, "frequency": 40.0}
    return data


def _parts(stepper, X):
    """(states, modes, tensions, slip speeds, friction work, input work) of packed stepper states (N, .)."""
    N, n = stepper.loop.N, stepper.n
    return (X[:, :N], X[:, N:N + n], X[:, N + 4 * n:N + 5 * n], X[:, N + 5 * n:], X[:, N + 2 * n:N + 3 * n],
            X[:, N + 3 * n:N + 4 * n])


@pytest.mark.parametrize("dt", [1e-3, 2.5e-4])
def test_ticks_equal_the_whole_slipping_run_bit_for_bit(dt):
    """Auto picks the slipping tier for the stepper as offline; 1 ms ticks (1 or 4 steps each) == simulate()."""
    scene = NetworkScene.from_mapping(slipping_fead(dt))
    whole = simulate(scene)
    assert whole.tier == "slipping" and len(whole.events) >= 6
    stepper = NetworkStepper(scene)
    assert stepper.tier == "slipping"
    sub = int(round(1e-3 / dt))
    x = stepper.initial()
    rows = [x]
    for tick in range((len(whole.time) - 1) // sub):
        x = stepper.advance(x, tick * sub, (tick + 1) * sub)
        rows.append(x)
    states, modes, T, sd, wf, win = _parts(stepper, np.array(rows))
    m = stepper.m
    for ours, theirs in ((states[:, :2 * m], whole.states), (states[:, 2 * m:], whole.slip_distance),
                         (modes, whole.slip_state), (T, whole.tension), (sd, whole.slip_speed),
                         (wf, whole.friction_work), (win, whole.input_work)):
        assert np.array_equal(ours, theirs[::sub])
    assert modes.any() and not modes.all()  # it slid and stuck
    one, _ = stepper.sample(len(rows) - 1, x)  # the node's one-sample outputs: the run's, with the slip
    assert np.array_equal(one.slip[0], (whole.slip_state[-1] != 0).astype(float))
    assert np.array_equal(one.hub_load[0], whole.hub_load[-1]) and np.array_equal(one.friction_use[0], whole.friction_use[-1])


def test_held_torques_equal_a_whole_run_of_the_held_values():
    """Ticks with the crank and the alternator held at new values each tick == one run whose profiles are those
    values held (a table with the previous value): the held inputs act through the same kernel rows."""
    data = slipping_fead(duration=0.12)
    rng = np.random.default_rng(7)
    ticks = 120
    crank = 12.0 + 25.0 * rng.standard_normal(ticks)
    alt = 2.0 + 3.5 * np.sin(2 * np.pi * 40.0 * np.arange(ticks) * 1e-3) + 0.5 * rng.standard_normal(ticks)
    stepper = NetworkStepper(NetworkScene.from_mapping(data), tier="slipping")
    x = stepper.initial()
    rows = [x]
    names = [p.name for p in stepper.scene.pulleys]
    for k in range(ticks):
        stepper.hold(names.index("crank"), crank[k])
        stepper.hold(names.index("alternator"), alt[k])
        x = stepper.advance(x, k, k + 1)
        rows.append(x)
    times = [k * 1e-3 for k in range(ticks)]
    for p in data["pulleys"]:
        if p["name"] in ("crank", "alternator"):
            values = crank if p["name"] == "crank" else alt
            p["torque"] = {"type": "table", "interpolation": "previous", "times": times, "values": values.tolist()}
    whole = simulate_slipping(None, NetworkScene.from_mapping(data))
    states, modes, T, sd, _, _ = _parts(stepper, np.array(rows))
    assert modes.any()
    m = stepper.m
    assert np.array_equal(states[:, :2 * m], whole.states) and np.array_equal(modes, whole.slip_state)
    assert np.array_equal(T, whole.tension) and np.array_equal(sd, whole.slip_speed)
    stepper.hold(names.index("alternator"), None)  # back to its profile: the kernel reads the scene's rows again
    again = stepper.advance(x, ticks, ticks + 5)
    assert np.all(np.isfinite(again))


@pytest.mark.ros
def test_slipping_node_records_publishes_slip_and_resimulates_bit_for_bit(tmp_path, ros_domain_id):
    from belt_drive_ros.cli import main
    from test_network_node import START_NS, TICK_NS, Lockstep, _decode

    path = tmp_path / "slipping_fead.yaml"
    path.write_text(yaml.safe_dump(slipping_fead(duration=0.2)))
    rec = tmp_path / "node.mcap"
    h = Lockstep(ros_domain_id, scene=str(path), record_path=str(rec), drive_source="scene")
    try:
        assert h.node.sim.stepper.tier == "slipping"
        h.step(START_NS)
        for k in range(1, 61):
            if k == 20:
                h.send(h.load, 7.0)  # a heavier alternator load than its profile's
            if k == 40:
                h.send(h.load, 0.5)
            h.step(START_NS + k * TICK_NS)
    finally:
        h.close()
    recorded = _decode(rec)
    slip = np.array(recorded["/alternator/slip"][1])
    assert slip.any() and not slip.all()  # it slid and stuck, and the node said so
    assert np.any(np.array(recorded["/alternator/slip_speed"][1]) != 0.0)
    # the scene-driven first 20 ticks equal the offline slipping run written as the node publishes it
    off = tmp_path / "offline.mcap"
    assert main(["sim", str(path), "--duration", "0.019", "--out", str(off)]) == 0
    b = _decode(off)
    for topic in b:
        assert recorded[topic][1][:20] == b[topic][1], topic
    out = tmp_path / "resim.mcap"
    assert main(["sim", str(rec), "--out", str(out)]) == 0
    again = _decode(out)
    outputs = [t for t in recorded if t != "/alternator/load_torque"]
    for topic in outputs:
        assert again[topic] == recorded[topic], topic  # time stamps and values, bit for bit
    # the recording names what the tier stepped (it said the scene's etd2 where the slipping tier steps exact)
    from belt_drive_ros.io.network_bag import read_network_recording

    meta = read_network_recording(rec)
    assert (meta.method, meta.tier) == ("exact", "slipping")
