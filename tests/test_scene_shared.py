"""A scene read again shares its parameters and torques with the earlier read (core/scene.py ``_shared``): what the
core built from them by identity (models, plants, steppers) is reused, and the run is the same; values that differ in
any bit, and arrays, are never shared."""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.scene import Scene
from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.core.stepper import shared_plant
from belt_drive_ros.io.scenes import load_scene


def _mapping(**changes):
    base = load_scene("paper").to_dict()
    base.update(changes)
    return base


@pytest.mark.parametrize("name", ["paper", "e_motor_start", "bsg_start", "truck_compressor"])
def test_a_scene_read_again_holds_the_same_objects_and_reuses_what_was_built(name):
    first, again = load_scene(name), load_scene(name)
    assert first is not again
    assert first.params is again.params and first.drive is again.drive and first.load is again.load
    model = make_model("flexible", first.params)
    assert make_model("flexible", again.params) is model  # (built by identity: once)
    assert shared_plant(model, again.drive, again.load) is shared_plant(model, first.drive, first.load)


def test_the_run_of_a_scene_read_again_is_the_same():
    a = simulate(load_scene("e_motor_start"))
    b = simulate(load_scene("e_motor_start"))
    assert np.array_equal(a.states, b.states) and np.array_equal(a.time, b.time)
    assert repr(a.accuracy) == repr(b.accuracy) and repr(a.choice) == repr(b.choice)


def test_values_one_bit_apart_or_held_in_arrays_are_not_shared():
    base = Scene.from_mapping(_mapping())
    params = dict(base.params.to_dict())
    c_next = float(np.nextafter(params["c"], np.inf))
    other = Scene.from_mapping(_mapping(params={**params, "c": c_next}))
    assert other.params is not base.params and other.params.c == c_next
    assert other.drive is base.drive and other.load is base.load  # (the same torques)
    zero = Scene.from_mapping(_mapping(load={"type": "constant", "value": 0.0}))
    negative_zero = Scene.from_mapping(_mapping(load={"type": "constant", "value": -0.0}))
    assert zero.load is not negative_zero.load and np.signbit(negative_zero.load.value)
    curve = {"type": "motor", "stall_torque": 60.0, "no_load_speed": 300.0, "curve": [[0.0, 60.0], [300.0, 0.0]]}
    motor = Scene.from_mapping(_mapping(drive=curve))
    assert Scene.from_mapping(_mapping(drive=dict(curve))).drive is motor.drive
    moved = {**curve, "curve": [[0.0, 60.0], [300.0, float(np.nextafter(0.0, 1.0))]]}
    assert Scene.from_mapping(_mapping(drive=moved)).drive is not motor.drive
    table = {"type": "table", "times": [0.0, 1.0], "values": [2.0, 3.0]}  # (its arrays: never compared by value)
    assert Scene.from_mapping(_mapping(drive=table)).drive is not Scene.from_mapping(_mapping(drive=table)).drive


def test_the_value_key_tells_types_and_signed_zeros_apart():
    from belt_drive_ros.core.scene import _value_key

    assert _value_key((1,), 0) != _value_key((1.0,), 0) and _value_key(0.0, 0) != _value_key(-0.0, 0)
    assert _value_key(float("nan"), 0) is None and _value_key(np.zeros(2), 0) is None


def test_the_shared_objects_are_bounded():
    from belt_drive_ros.core import scene as scene_module

    base = Scene.from_mapping(_mapping())
    for j in range(scene_module.SHARED_SIZE + 5):
        Scene.from_mapping(_mapping(params={**base.params.to_dict(), "c": 20.0 + j}))
    assert len(scene_module._SHARED) <= scene_module.SHARED_SIZE
