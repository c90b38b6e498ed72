"""What a first call of an edited scene (a sweep's variant) reuses and what it does not: a rigid model's plant by its
matrices (``accuracy_probes.rigid_plant``: the rigid survey and a rigid run), and the accuracy guard's window runs on
the slipping engine's guarded flexible stepper (``simulate._WindowRuns``): the same floats as the steppers built
afresh, also where the capstan check stops a window's run."""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.core import accuracy_probes
from belt_drive_ros.core.accuracy_probes import RigidSurvey, probe_scene, rigid_plant
from belt_drive_ros.core.accuracy_windows import window_errors
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.simulate import _slipping_engine, _WindowRuns, simulate
from belt_drive_ros.core.stepper import shared_plant
from belt_drive_ros.io.scenes import load_scene


def _variant(scene, **changes):
    return scene.with_params(scene.params.replace(**changes))


def test_a_rigid_plant_is_shared_by_its_matrices_only():
    scene = load_scene("e_motor_start")
    p = scene.params
    first = rigid_plant(make_model("rigid", p), scene.drive, scene.load)
    damped = make_model("rigid", p.replace(c=p.c * (1.0 + 1e-9)))  # the belt's damping: not in the rigid model
    assert damped is not first.model and np.array_equal(damped.C, first.model.C)
    assert rigid_plant(damped, scene.drive, scene.load) is first
    stiffer = make_model("rigid", p.replace(k=p.k * 1.5))  # the quasi-static deflection rows differ
    assert rigid_plant(stiffer, scene.drive, scene.load) is not first
    heavier = make_model("rigid", p.replace(I_3=p.I_3 * 1.5))
    assert rigid_plant(heavier, scene.drive, scene.load) is not first
    other = load_scene("paper")  # other torques: never shared
    assert rigid_plant(make_model("rigid", p), other.drive, other.load) is not first


@pytest.mark.parametrize("name", ["e_motor_start", "paper"])
def test_an_edited_scene_runs_the_same_on_a_shared_rigid_plant(name):
    scene = load_scene(name)
    simulate(scene)
    variant = _variant(scene, c=scene.params.c * (1.0 + 3e-12))
    shared = simulate(variant)
    survey = RigidSurvey.of_scene(variant)
    survey.speeds
    assert rigid_plant(survey.rigid, variant.drive, variant.load).model is not survey.rigid  # (the one shared)
    accuracy_probes._RIGID_PLANTS.clear()  # the variant's own plant, stepper and loop, as before the sharing
    own = simulate(variant)
    for a, b in ((shared.time, own.time), (shared.states, own.states), (shared.inputs, own.inputs)):
        assert a.tobytes() == b.tobytes()
    for key in own.outputs:
        assert np.asarray(shared.outputs[key]).tobytes() == np.asarray(own.outputs[key]).tobytes()
    for key in own.energy:
        assert shared.energy[key].tobytes() == own.energy[key].tobytes()
    assert repr(shared.accuracy) == repr(own.accuracy) and repr(shared.choice) == repr(own.choice)


@pytest.mark.parametrize("name", ["paper", "truck_compressor", "bsg_start"])
def test_window_runs_on_the_guarded_stepper_are_the_unguarded_ones(name):
    scene = load_scene(name).with_overrides(duration=1.0)
    survey = RigidSurvey.of_scene(scene)
    sim, x0, probes = _slipping_engine(scene, True, survey)
    runs, stops = _WindowRuns(sim), []
    guarded_run = sim.stepper.run

    def noted(*args):
        out = guarded_run(*args)
        stops.append(sim.stepper.stopped is not None)
        return out

    sim.stepper.run = noted
    try:
        mine = window_errors(sim.plant, scene.method, scene.dt, probes, scene.method_options, runs)
    finally:
        del sim.stepper.run
    plain = window_errors(sim.plant, scene.method, scene.dt, probes, scene.method_options)
    assert len(mine) == len(plain) == len(stops) > 0
    for (t_a, e_a, p_a), (t_b, e_b, p_b) in zip(mine, plain):
        assert t_a == t_b and e_a.tobytes() == e_b.tobytes() and p_a.tobytes() == p_b.tobytes()
    if name != "paper":  # these slip: the capstan check stops some window's guarded run, which is made again
        assert any(stops)
    else:
        assert not any(stops)
    assert probe_scene(sim.plant, scene.duration, x0, scene.dt, survey=survey) is probes
    assert shared_plant(sim.flexible, scene.drive, scene.load) is sim.plant


def test_a_shared_rigid_plant_stays_one_whose_steppers_are_kept():
    from belt_drive_ros.core.stepper import _PLANT_CACHE_SIZE, is_shared

    scene = load_scene("e_motor_start")
    p = scene.params
    plant = rigid_plant(make_model("rigid", p), scene.drive, scene.load)
    assert is_shared(plant)
    for j in range(_PLANT_CACHE_SIZE):  # a sweep's new flexible plants push it out of shared_plant's cache
        shared_plant(make_model("flexible", p.replace(c=p.c * (1.0 + (j + 1) * 1e-9))), scene.drive, scene.load)
    assert not is_shared(plant)
    again = rigid_plant(make_model("rigid", p.replace(c=p.c * 2.0)), scene.drive, scene.load)
    assert again is not plant and is_shared(again)
    assert rigid_plant(make_model("rigid", p), scene.drive, scene.load) is again


@pytest.mark.parametrize("name", ["e_motor_start", "bsg_start"])
def test_a_repeated_survey_stops_where_the_first_did(name):
    scene = load_scene(name)
    first = RigidSurvey.of_scene(scene)
    speeds, states = first.speeds, dict(first.states)
    plan = accuracy_probes._survey_plan(first.plant, scene.duration, scene.dt)
    assert accuracy_probes._survey_plan(first.plant, scene.duration, scene.dt) is plan  # (kept: made once)
    first.early[-1.0] = 0.0  # a survey's own copies: the plan does not change
    first.plain.append(-1.0)
    again = RigidSurvey.of_scene(scene)
    assert again.speeds == speeds and again.states == states
    assert again.early == {b: t for b, t in first.early.items() if b != -1.0} and -1.0 not in again.plain
    accuracy_probes._SURVEY_PLANS.clear()  # made afresh: the same stops and floats
    fresh = RigidSurvey.of_scene(scene)
    assert fresh.speeds == speeds and fresh.states == states and fresh.early == again.early
    assert fresh.plain == again.plain and fresh.t_probe.tobytes() == again.t_probe.tobytes()
    other = accuracy_probes._survey_plan(first.plant, scene.duration, 0.5 * scene.dt)  # another step: its own plan
    assert other is not plan


@pytest.mark.parametrize("kind", ["rigid", "flexible"])
def test_outputs_without_the_torque_rows_of_d_are_the_full_affine_map(kind):
    from belt_drive_ros.core.model import LINEAR_OUTPUTS, _affine, _plus_affine

    scene = load_scene("e_motor_start")
    run = simulate(scene, model=kind)
    model = make_model(kind, scene.params)
    full = _plus_affine(_affine(model.C, run.states), model.D, run.inputs)  # D's every row, as before
    outputs = model.outputs(run.states, run.inputs)
    for j, name in enumerate(LINEAR_OUTPUTS):
        expected = run.inputs[:, ("drive_torque", "load_torque").index(name)] if name.endswith("_torque") and \
            name != "belt_torque" else full[:, j]  # fmt: skip
        assert np.asarray(outputs[name]).tobytes() == np.ascontiguousarray(expected).tobytes(), name
    assert not model._D_of_outputs.flags.writeable and model.D[LINEAR_OUTPUTS.index("drive_torque"), 0] == 1.0


def test_a_bounded_cache_drops_the_entry_used_least_recently():
    """``built_once`` keeps what was just used: a hit moves its entry to the end, so a plant a call has just found
    is not the next one dropped (with the oldest-inserted dropped, a scene's plant found again was pushed out by the
    next new plant, and what was built from it, its steppers, was then not kept either)."""
    from belt_drive_ros.core.identity_cache import built_once

    cache, objects = {}, [object() for _ in range(4)]
    built = [built_once(cache, 3, (o,), object) for o in objects[:3]]
    assert built_once(cache, 3, (objects[0],), object) is built[0]  # a hit: now the most recent
    built_once(cache, 3, (objects[3],), object)  # a fourth: the least recently used (objects[1]'s) goes
    assert built_once(cache, 3, (objects[0],), object) is built[0]
    assert built_once(cache, 3, (objects[2],), object) is built[2]
    assert built_once(cache, 3, (objects[1],), object) is not built[1]


def test_a_plant_found_again_keeps_its_steppers_after_many_new_plants():
    """A scene's plant found again stays shared (its steppers kept) while other scenes' plants come and go: after
    more new plants than the cache holds, each followed by the scene's own plant found again, the scene's stepper is
    the one made first."""
    from belt_drive_ros.core import stepper as stepper_module

    scene = load_scene("paper")
    model = make_model("flexible", scene.params)
    plant = stepper_module.shared_plant(model, scene.drive, scene.load)
    first = stepper_module.shared_stepper(plant, "etd2", scene.dt)
    for k in range(2 * stepper_module._PLANT_CACHE_SIZE):
        other = make_model("flexible", scene.params.replace(c=scene.params.c * (1.0 + (k + 1) * 1e-6)))
        stepper_module.shared_plant(other, scene.drive, scene.load)
        assert stepper_module.shared_plant(model, scene.drive, scene.load) is plant
    assert stepper_module.is_shared(plant)
    assert stepper_module.shared_stepper(plant, "etd2", scene.dt) is first
