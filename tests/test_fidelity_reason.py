"""The ``auto`` model choice's reason is formatted when first read, and is the same text either way.

A campaign reads only each variant's model, so its choices never format a reason; ``simulate``'s report, the sim
command's model line, the node and the stream read it and get the sentence the rule gives."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import pytest

from belt_drive_ros.core import fidelity
from belt_drive_ros.core.fidelity import choose_model
from belt_drive_ros.io.scenes import load_scene


@pytest.fixture
def formatted(monkeypatch):
    """The names of the reasons formatted (the frequency rule's ``_linear_reason``, the capstan limit's
    ``_slipping_reason``), in order."""
    calls, call = [], fidelity._Deferred.__call__

    def counted(deferred):
        if deferred.text is None:
            calls.append(deferred.function.__name__)
        return call(deferred)

    monkeypatch.setattr(fidelity._Deferred, "__call__", counted)
    return calls


def test_a_campaign_formats_no_reason(formatted):
    from belt_drive_ros.campaign.ensemble_run import simulate_many

    base = dataclasses.replace(load_scene("paper"), model="auto", duration=0.5)
    scenes = [dataclasses.replace(base, params=base.params.replace(k=base.params.k * (1 + 0.01 * i))) for i in range(10)]
    outcomes = sorted(simulate_many(scenes), key=lambda o: o.index)
    assert all(o.ensemble and o.result.choice.model == "flexible" for o in outcomes)
    assert formatted == []
    # read: the rule's sentence, the one a single run gives
    assert outcomes[3].result.choice.reason == choose_model(scenes[3]).reason
    assert outcomes[3].result.choice.reason.startswith("flexible: motor soft start (1/ramp time) at 50.0 Hz")
    assert formatted == ["_linear_reason", "_linear_reason"]


def test_the_reason_is_formatted_once_and_kept_by_copies(formatted):
    scene = load_scene("e_motor_start")
    choice = choose_model(scene)
    twin, kept = copy.copy(choice), pickle.loads(pickle.dumps(choice))
    assert formatted == []
    text = choice.reason
    assert text.startswith("rigid: highest excitation") and "quasi-static deflection reported" in text
    assert choice.reason is text and twin.reason == text and formatted == ["_linear_reason"]
    assert kept.reason == text  # (pickled before it was read: formatted from the pickled numbers)
    assert formatted == ["_linear_reason", "_linear_reason"]
    # dataclasses.replace reads it; a reason given as text is that text
    assert dataclasses.replace(choice, limit_ratio=0.5).reason == text
    said = dataclasses.replace(choice, model="slipping", reason="slipping: said so")
    assert said.reason == "slipping: said so" and said.model == "slipping" and choice.reason == text
    with pytest.raises(dataclasses.FrozenInstanceError):
        choice.reason = "another"  # type: ignore[misc]


def test_the_slipping_reason_quotes_the_linear_one(formatted):
    scene = load_scene("paper")
    scene = dataclasses.replace(scene, params=scene.params.replace(F_0=scene.params.F_0 * 0.3))
    linear = choose_model(scene, check_slip=False)
    choice = choose_model(scene, linear=linear, limit=(1.5, 0.25))
    assert (choice.model, choice.linear, choice.limit_ratio, choice.limit_time) == ("slipping", "flexible", 1.5, 0.25)
    assert formatted == []
    q_max = scene.params.friction_limit(0.0)
    assert choice.reason == (f"slipping: peak transmitted force 1.50 x the capstan limit (Q_max = {q_max:.0f} N at rest) "
                             f"at t = 0.25 s in the flexible run ({linear.reason})")  # fmt: skip
    assert sorted(formatted) == ["_linear_reason", "_slipping_reason"]
    assert choice == choose_model(scene, linear=linear, limit=(1.5, 0.25))  # equal choices: their texts compared


def _speed_limited(width: float):
    """e_motor_start with its motor cut from 60 to 0 N m between 100 and 100 + ``width`` rad/s (a speed limiter),
    its soft start 0.3 s over 2 s."""
    from belt_drive_ros.core.scene import Scene
    from belt_drive_ros.io.scenes import load_scene

    data = load_scene("e_motor_start").to_dict()
    data.update(name=f"speed_limited_{width:g}", duration=2.0, model="auto", method="etd4", dt=2e-4)
    data["drive"] = {"type": "motor", "curve": [[0.0, 60.0], [100.0, 60.0], [100.0 + width, 0.0], [400.0, 0.0]],
                     "soft_start_time": 0.3}
    return Scene.from_mapping(data)


def test_a_torque_that_cuts_off_with_the_speed_is_an_excitation_the_rule_sees():
    """A motor curve that falls from 60 to 0 N m within 5 rad/s: as the speed passes it the belt torque drops in
    milliseconds and rings (the flexible run differs from the rigid one by 7 % of the peak), but the profile's own
    excitation is only its soft start (3.3 Hz against a 162 Hz belt): auto chose rigid, rated accurate. The rigid
    run's fastest belt-torque change over its swing (72 Hz, 0.44 of the belt mode) now counts; the shipped
    e_motor_start (1 Hz) stays rigid, and a cut spread over 20 rad/s (13.5 Hz) too."""
    import numpy as np

    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.scenes import load_scene

    steep = _speed_limited(5.0)
    result = simulate(steep)
    assert result.model == "flexible" and "fastest belt-torque change" in result.choice.reason
    rigid = simulate(steep, model="rigid")
    peak = np.max(np.abs(result.outputs["belt_torque"]))
    assert np.max(np.abs(result.outputs["belt_torque"] - rigid.outputs["belt_torque"])) > 0.03 * peak  # it mattered
    assert simulate(load_scene("e_motor_start")).model == "rigid"
    assert simulate(_speed_limited(20.0)).model == "rigid"


def test_a_choice_read_off_an_inaccurate_run_says_so():
    """model auto at rk4, 3 ms on the truck's belt (c = 2 N s/m, a load step at 0.2 s): the run is 0.42 off, and its
    choice 'flexible' (no slip) was given as settled, where an accurate run passes the capstan limit at 0.21 s. The
    reason now says it was read off a run rated inaccurate; an accurate run's reason does not."""
    from belt_drive_ros.core.scene import Scene
    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.scenes import load_scene

    truck = load_scene("truck_compressor").to_dict()
    data = {**truck, "model": "auto", "method": "rk4", "dt": 0.003, "duration": 0.5,
            "params": {**truck["params"], "c": 2.0, "F_0": 431.66},
            "drive": {**truck["drive"], "harmonics": [0.0]},
            "load": {"type": "step", "initial": 2.0, "final": 20.0, "time": 0.2}}
    result = simulate(Scene.from_mapping(data))
    assert not result.accuracy.accurate
    assert "read off a run rated INACCURATE" in result.choice.reason
    accurate = simulate(Scene.from_mapping({**data, "method": "etd4", "dt": 0.0005}))
    assert accurate.accuracy.accurate and "INACCURATE" not in accurate.choice.reason
    assert accurate.model == "slipping"  # what the inaccurate run's choice missed
