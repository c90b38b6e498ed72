"""``model: auto`` sees the start: torques applied at t = 0 onto a belt not deflected for them are a step.

Reference: the flexible model run with ``exact`` (exact for constant torques).
A constant drive switched on at t = 0 onto an unloaded belt makes the belt
ring about its quasi-static torque with an amplitude of that torque, so its
peak is up to twice the rigid model's; started at the quasi-static
deflection there is nothing to ring and the rigid model is right.
"""

from __future__ import annotations

import numpy as np

from belt_drive_ros.core import sources as S
from belt_drive_ros.core.fidelity import choose_model, start_mismatch
from belt_drive_ros.core.scene import InitialState
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import simulate


def _scene(relative_deflection=0.0):
    base = load_scene("paper")
    return base.with_overrides(
        drive=S.Constant(6.0), load=S.Constant(1.0), duration=1.0,
        initial_state=InitialState(relative_deflection=relative_deflection),
    )  # fmt: skip


def _peak_belt_torque(scene, model):
    return float(np.max(np.abs(simulate(scene, model=model, method="exact", dt=1e-3)["belt_torque"])))


def test_constant_drive_from_rest_is_a_step_and_auto_picks_flexible():
    scene = _scene()
    rigid, flexible = _peak_belt_torque(scene, "rigid"), _peak_belt_torque(scene, "flexible")
    assert flexible > 1.5 * rigid  # what the rigid model would miss (the issue: 10.6 against 20.3 N m)
    choice = choose_model(scene, check_slip=False)
    assert choice.model == "flexible", choice.reason
    assert "the start" in choice.reason and "stated deflection" in choice.reason


def test_start_at_the_quasi_static_deflection_is_rigid_and_matches_flexible():
    scene = _scene()
    needed, carried = start_mismatch(scene)
    assert carried == 0.0 and needed > 1.0  # wheel 3's load plus the torque that accelerates it
    matched = _scene(relative_deflection=needed / scene.params.belt_torsional_stiffness)
    needed2, carried2 = start_mismatch(matched)
    assert abs(needed2 - carried2) <= 1e-12 * needed
    choice = choose_model(matched, check_slip=False)
    assert choice.model == "rigid", choice.reason
    rigid, flexible = _peak_belt_torque(matched, "rigid"), _peak_belt_torque(matched, "flexible")
    assert abs(flexible - rigid) <= 1e-3 * flexible, (rigid, flexible)
