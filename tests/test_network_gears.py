"""A gear train in front of a network's driver (``gears:``), reduced onto the pulley as the paper's model does.

References written here from the paper's model (docs/model.md): ``g = (r_M / R_1)(r_1 / R_2)``,
``I_f = I_M + I_1 (r_M / R_1)^2 + I_2 g^2`` and ``b_f`` alike, on wheel 2 divided by ``g^2``; the drive
torque acts on M at M's speed. The paper's drive stated with its gear train runs as the paper's model
(flexible, with bearing damping on every wheel) to 1e-12 of the peak.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from belt_drive_ros.core.errors import SceneError
from belt_drive_ros.core.network.scene import NetworkScene
from belt_drive_ros.io.scenes import load_network
from belt_drive_ros.core.network.simulate import simulate

from test_network_slip import shipped


def _damped(b):
    """paper_network with bearing damping b = (b_M, b_1, b_2, b_3) on the wheels."""
    data = shipped("paper_network")
    driver, load = data["pulleys"]
    driver["damping"] = b[2]
    for wheel, value in zip(driver["gears"], b[:2]):
        wheel["damping"] = value
    load["damping"] = b[3]
    return data


def test_the_gear_train_reduces_to_the_papers_inertia_damping_and_ratio():
    from belt_drive_ros.io.scenes import load_scene

    p = load_scene("paper").params
    b = (0.05, 0.01, 0.002, 0.0)
    crank = NetworkScene.from_mapping(_damped(b)).pulleys[0]
    g = (p.r_M / p.R_1) * (p.r_1 / p.R_2)
    assert crank.gear == pytest.approx(g, rel=1e-15) and g == pytest.approx(p.gear_ratio, rel=1e-15)
    I_f = p.I_M + p.I_1 * (p.r_M / p.R_1) ** 2 + p.I_2 * g**2
    b_f = b[0] + b[1] * (p.r_M / p.R_1) ** 2 + b[2] * g**2
    assert crank.inertia == pytest.approx(I_f / g**2, rel=1e-14)
    assert crank.damping == pytest.approx(b_f / g**2, rel=1e-14)
    # the profile acts on the motor shaft: torque Q(omega_M) / g on the pulley at omega_M = omega_2 / g
    w2 = 30.0
    assert crank.load(10.0, 0.0, w2) == pytest.approx(12.0 * (1.0 - (w2 / g) / 160.0) / g, rel=1e-15)


def test_the_paper_drive_with_its_gear_train_and_bearing_damping_equals_the_paper_model():
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.core.simulate import simulate as simulate_paper

    paper = load_scene("paper")
    b = (0.05, 0.01, 0.002, 0.003)
    params = dataclasses.replace(paper.params, b_M=b[0], b_1=b[1], b_2=b[2], b_3=b[3])
    today = simulate_paper(dataclasses.replace(paper, params=params), model="flexible", method="exact", dt=1e-3)
    net = simulate(NetworkScene.from_mapping(_damped(b)), model="flexible", method="exact", dt=1e-3)
    g = paper.params.gear_ratio
    for ours, theirs in ((net.speed[:, 1], today["omega_3"]), (net.speed[:, 0], g * today["omega_M"]),
                         (net.belt_torque[:, 1], today["belt_torque"])):
        assert np.max(np.abs(ours - theirs)) <= 1e-12 * np.max(np.abs(theirs))
    rigid = simulate(NetworkScene.from_mapping(_damped(b)), model="rigid", method="exact", dt=1e-3)
    ref = simulate_paper(dataclasses.replace(paper, params=params), model="rigid", method="exact", dt=1e-3)
    assert np.max(np.abs(rigid.speed[:, 0] - g * ref["omega_M"])) <= 1e-9 * np.max(np.abs(g * ref["omega_M"]))


def test_a_held_drive_torque_acts_on_the_shaft():
    from belt_drive_ros.ros.network_stepper import NetworkStepper

    scene = load_network("paper_network")
    for tier in ("flexible", "rigid", "slipping"):
        stepper = NetworkStepper(scene, tier=tier)
        stepper.hold(0, 5.0)
        assert stepper.inputs(0.0, stepper.initial())[0] == 5.0 / scene.pulleys[0].gear


@pytest.mark.parametrize("change, message", [
    (lambda d: d["pulleys"][1].update(gears=[{"inertia": 0.01, "ratio": 0.5}]), "pulleys.pulley_3.gears: only the driver"),
    (lambda d: d["pulleys"][0]["gears"][1].update(ratio=0.0), r"pulleys.wheel_2.gears\[1\].ratio: must be > 0"),
    (lambda d: d["pulleys"][0]["gears"][0].update(efficiency=0.98), r"pulleys.wheel_2.gears\[0\].efficiency: unknown key"),
    (lambda d: d["pulleys"][0].update(gears=[]), "pulleys.wheel_2.gears: expected a list of 1 to 8 wheels"),
])
def test_a_bad_gear_train_is_a_one_line_error(change, message):
    data = shipped("paper_network")
    change(data)
    with pytest.raises(SceneError, match=message):
        NetworkScene.from_mapping(data)
