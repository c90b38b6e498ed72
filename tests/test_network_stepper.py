"""The network node's tick (ros/network_stepper.py) against the whole offline run of the same loop.

A tick of whole steps between the profiles' breakpoints calls the
compiled loop directly with the clamp interval ``advance`` would use; a
tick that crosses a breakpoint, or holds a step split at one inside it,
goes through ``advance``, which cuts there.
Either way the states must be the whole run's bit for bit, also at and
around a torque step, where a wrong clamp interval would sample the
switched torque a step early. The joint values of a tick are Python floats
computed without numpy; a held value is written into the loop only when it
changes, and a held -0.0 N m stays -0.0.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from belt_drive_ros.core.network.scene import NetworkScene
from belt_drive_ros.core.network.simulate import model_of, network_loop, run_loop
from belt_drive_ros.io.network_bag import NetworkLayout
from belt_drive_ros.ros.network_stepper import NetworkStepper

from test_network_slip import shipped


#: the float 43 dt + dt (dt = 1 ms), one ulp above 44 dt: a step there lies on the grid (step 44), and the stage
#: at the end of step 43, t + dt, reaches it only unclamped (clamped to 44 dt it samples the left limit)
STEP_TIME = 43 * 1e-3 + 1e-3
assert STEP_TIME > 44 * 1e-3


def stepped_fead():
    """fead_i4 with the alternator's load stepping 1.5 -> 6 N m at :data:`STEP_TIME`, the water pump's 0.2 -> 2 N m
    at 12.5 ms (inside step 12: that step is split there) and the crank's ramp ending at 0.1 s (breakpoints on
    the grid at steps 44 and 100)."""
    data = shipped("fead_i4")
    for p in data["pulleys"]:
        if p["name"] == "alternator":
            p["torque"] = {"type": "step", "initial": 1.5, "final": 6.0, "time": STEP_TIME}
        if p["name"] == "water_pump":
            p["torque"] = {"type": "step", "initial": 0.2, "final": 2.0, "time": 0.0125}
    return NetworkScene.from_mapping(data, name="stepped_fead")


@pytest.mark.parametrize("tier", ["flexible", "rigid"])
@pytest.mark.parametrize("per_tick", [1, 3, 7])
def test_ticks_equal_the_whole_run_across_breakpoints(tier, per_tick):
    scene = stepped_fead()
    steps = 130
    _, whole = run_loop(network_loop(model_of(scene), tier, scene.method, scene.dt), steps)
    stepper = NetworkStepper(scene, tier=tier)
    x, k = stepper.initial(), 0
    while k < steps:
        k1 = min(k + per_tick, steps)
        x = stepper.advance(x, k, k1)
        k = k1
        assert np.array_equal(x, whole[k]), (tier, per_tick, k)
    assert np.ptp(whole[:, -1]) > 0.0  # the run moved


def test_a_tick_after_a_restart_uses_the_clamp_of_its_own_stretch():
    """Ticks past the step, then back to the start (the node restarts there after a clock jump): each tick
    clamps to its own stretch."""
    scene = stepped_fead()
    _, whole = run_loop(network_loop(model_of(scene), "flexible", scene.method, scene.dt), 60)
    stepper = NetworkStepper(scene, tier="flexible")
    x = stepper.initial()
    for k in range(50, 60):  # a tick in the stretch after the step (state from the whole run)
        x = stepper.advance(whole[k], k, k + 1)
        assert np.array_equal(x, whole[k + 1])
    x = stepper.initial()
    for k in range(45):
        x = stepper.advance(x, k, k + 1)
        assert np.array_equal(x, whole[k + 1]), k


@pytest.mark.parametrize("tier", ["flexible", "rigid", "slipping"])
def test_pulley_state_is_the_absolute_state_as_python_floats(tier):
    scene = stepped_fead()
    stepper = NetworkStepper(scene, tier=tier)
    x = stepper.initial()
    stepper.hold(scene.driver, 20.0)
    for k in range(0, 30, 3):
        x = stepper.advance(x, k, k + 3)
        angle, speed, u = stepper.pulley_state(k + 3, x)
        full = stepper.absolute(x)[0]
        if tier == "rigid":  # the arm at its quasi-static swing (torques needed): the run's own state, as sample gives it
            assert full[stepper.n] == 0.0
            full = stepper.sample(k + 3, x)[0].states[0]
            assert full[stepper.n] != 0.0
        assert angle == full[: stepper.m].tolist() and speed == full[stepper.m :].tolist()
        assert u == stepper.inputs((k + 3) * stepper.dt, x).tolist()
        assert all(type(v) is float for v in angle + speed + u)
    layout = NetworkLayout(scene)
    assert len(layout.joint_values(angle, speed, u)) == 3 * len(layout.joints)


def test_holding_the_same_value_again_changes_nothing_and_minus_zero_is_kept():
    scene = stepped_fead()
    stepper = NetworkStepper(scene, tier="flexible")
    x, d = stepper.initial(), scene.driver
    stepper.hold(d, 0.0)
    stepper.hold(d, 0.0)
    assert math.copysign(1.0, stepper.pulley_state(0, x)[2][d]) == 1.0
    stepper.hold(d, -0.0)  # the same number, another float: published as sent
    assert math.copysign(1.0, stepper.pulley_state(0, x)[2][d]) == -1.0
    row = stepper.loop.start[stepper.loop.active.index(d)]
    assert math.copysign(1.0, stepper.loop.pp[row, 0]) == -1.0  # and the loop integrates it
    stepper.hold(d, 12.0)
    stepper.hold(d, 12.0)
    assert stepper.loop.pp[row, 0] == 12.0 and stepper.pulley_state(0, x)[2][d] == 12.0
    stepper.hold(d, None)  # back to the profile
    assert stepper.loop.pk[row] == stepper._rows[0][row] and stepper.held[d] is None


def _joint_floats(values):
    """The floats as bit patterns (a -0.0 differs from 0.0, a NaN equals itself)."""
    return np.array(values, dtype=float).view(np.int64).tolist()


def shipped_fead():
    return NetworkScene.from_mapping(shipped("fead_i4"), name="fead_i4")


@pytest.mark.parametrize("scene_of", [stepped_fead, shipped_fead])
@pytest.mark.parametrize("tier", ["flexible", "rigid"])
@pytest.mark.parametrize("per_tick", [1, 3])
def test_the_compiled_tick_equals_the_python_tick_in_lockstep(scene_of, tier, per_tick):
    """The node's tick with and without the compiled call (core/network/tick.py), side by side over a run with
    breakpoints and held torques that change (a -0.0 among them): the states and every joint value, bit for bit;
    most ticks take the compiled call, the ticks at a breakpoint the old path."""
    scene = scene_of()
    layout = NetworkLayout(scene)
    old, new = NetworkStepper(scene, tier=tier), NetworkStepper(scene, tier=tier)
    encoder = layout.joint_encoder()
    new.use_joints(float(layout.arm[3]) if layout.arm else 0.0, encoder.layout)
    d = scene.driver
    other = next(i for i, p in enumerate(scene.pulleys) if p.role == "accessory")
    holds = {1: [(d, 0.0)], 20: [(d, 35.0)], 41: [(other, 3.0)], 60: [(d, -0.0)], 90: [(d, 80.0), (other, 0.5)]}
    xo, xn, k, compiled = old.initial(), new.initial(), 0, 0
    while k < 150:
        k1 = k + per_tick
        pending = [h for j in range(k + 1, k1 + 1) for h in holds.get(j, [])]  # arrived during this tick
        for i, value in pending:  # the node: staged, the steps, then held (the values the joints show)
            new.stage(i, value)
        stamp = 1_700_000_000_000_000_000 + k1 * 1_000_000 + 7  # the node's stamp: its tick's time [ns]
        xo, xn = old.advance(xo, k, k1), new.tick(xn, k, k1, stamp)
        for i, value in pending:
            old.hold(i, value)
            new.hold(i, value)
        k = k1
        assert np.array_equal(xo, xn), (k, tier)
        want = layout.joint_values(*old.pulley_state(k, xo))
        if new.fresh == k:
            compiled += 1
            got = new.y.tolist()
            assert bytes(new.message) == encoder.encode(stamp, want), k  # the message written in the same call
        else:
            got = layout.joint_values(*new.pulley_state(k, xn))
        assert all(type(v) is float for v in got)
        assert _joint_floats(got) == _joint_floats(want), (k, tier, got, want)
    assert compiled >= 150 // per_tick - 4
    assert np.ptp(xo) > 0.0


def three_ticks(scene, stepper):
    """Three ticks of ``stepper`` (a :class:`NetworkStepper` of ``scene``) as the node runs them: joints written,
    the driver held at 10 N m; the last state."""
    layout = NetworkLayout(scene)
    stepper.use_joints(float(layout.arm[3]) if layout.arm else 0.0, layout.joint_encoder().layout)
    stepper.hold(scene.driver, 10.0)
    x = stepper.initial()
    for k in range(3):
        x = stepper.tick(x, k, k + 1)
    return x


def test_the_compiled_tick_compiles_once_and_interpreted_gives_the_same_floats(tmp_path):
    """Every shipped network, both linear tiers: one signature of network_tick; NUMBA_DISABLE_JIT=1 writes the
    same joint values and states."""
    import os
    import subprocess
    import sys

    from belt_drive_ros.io.scenes import load_network, shipped_networks
    from belt_drive_ros.core.network.tick import network_tick, warm

    warm()  # the signature make install compiles is the one the node calls
    for name in shipped_networks():
        scene = load_network(name)
        for tier in ("flexible", "rigid"):
            try:
                stepper = NetworkStepper(scene, tier=tier)
            except Exception:  # noqa: BLE001 - a refused tier is fine here: only the signatures count
                continue
            three_ticks(scene, stepper)
    assert len(network_tick.signatures) == 1
    code = ("import sys, numpy as np\n"
            "from belt_drive_ros.io.scenes import load_network\n"
            "from belt_drive_ros.io.network_bag import NetworkLayout\n"
            "from belt_drive_ros.ros.network_stepper import NetworkStepper\n"
            "scene = load_network('fead_i4'); layout = NetworkLayout(scene); s = NetworkStepper(scene)\n"
            "s.use_joints(float(layout.arm[3]), layout.joint_encoder().layout); s.hold(scene.driver, 30.0)\n"
            "x = s.initial(); rows = []\n"
            "for k in range(40):\n"
            "    x = s.tick(x, k, k + 1, 10**9 * k + 3); assert s.fresh == k + 1\n"
            "    rows.append(np.concatenate([x, s.y, np.frombuffer(bytes(s.message), dtype=np.uint8)]))\n"
            "np.save(sys.argv[1], np.array(rows))\n")
    rows = {}
    for jit in ("0", "1"):
        path = tmp_path / f"tick_{jit}.npy"
        done = subprocess.run([sys.executable, "-c", code, str(path)], env=dict(os.environ, NUMBA_DISABLE_JIT=jit),
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        rows[jit] = np.load(path)
    assert rows["0"].shape[0] == 40 and np.array_equal(rows["0"], rows["1"])
    assert np.ptp(rows["0"][:, -1]) == 0.0 and np.ptp(rows["0"][:, 0]) > 0.0  # the arm's effort 0.0; the run moved
