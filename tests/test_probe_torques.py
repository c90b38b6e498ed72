"""The accuracy guard's probe torques in one evaluation per profile (``accuracy_probes._probe_torques``).

The speed slopes (central differences of each torque at every probe) and the rigid quasi-static belt torques at the
input weight's points are one torque call per profile; each sample is the profile's own at its point, and the belt
torque is ``RigidBeltModel.belt_torque``'s operations on 1-D arrays. So every figure must equal, bit for bit, the
same quantities computed apart: a torque call per quantity and profile, the rigid model's ``belt_torque`` on stacked
columns (what the guard computed before).
"""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.core.accuracy_probes import RigidSurvey, _probe_torques, _rigid_belt_torque, _weight_points
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.stepper import shared_plant
from belt_drive_ros.io.scenes import load_scene

SCENES = ["paper", "e_motor_start", "bsg_start", "truck_compressor"]


def _apart(plant, rigid, times, speeds, points):
    """The slopes and quasi-static belt torques of ``_probe_torques``, each by its own torque calls."""
    i = plant.model.params.ratio
    t = np.asarray(times, dtype=float)
    slopes = []
    with np.errstate(all="ignore"):
        for profile, w in ((plant.drive, np.asarray(speeds, dtype=float)), (plant.load, i * np.asarray(speeds, dtype=float))):
            d = 1e-6 * np.maximum(1.0, np.abs(w))
            up = profile.torque(t, np.zeros(t.size), w + d)
            down = profile.torque(t, np.zeros(t.size), w - d)
            slopes.append(((up - down) / (2.0 * d)).tolist())
        qt, qphi, qw = (np.array(c, dtype=float) for c in zip(*points))
        u = np.column_stack([plant.drive.torque(qt, qphi, qw), plant.load.torque(qt, i * qphi, i * qw)])
        qs = rigid.belt_torque(np.column_stack([qphi, qw]), u)
    return list(zip(*slopes)), qs.tolist()


def _bits(values) -> bytes:
    return np.asarray(values, dtype=float).tobytes()


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("kind", ["rigid", "flexible"])
def test_probe_torques_equal_the_torques_evaluated_apart(name, kind):
    scene = load_scene(name)
    survey = RigidSurvey.of_scene(scene)
    times, _, early, states = survey.probe_states()
    plant = shared_plant(make_model(kind, scene.params), scene.drive, scene.load)
    at = [(float(t), *states[float(t)]) for t in times]
    jumps = [(b, *states[t]) for b, t in early.items()]
    points = _weight_points(plant, scene.initial_state.vector(kind, scene.params.ratio), scene.dt, at, jumps)
    speeds = [w for _, _, w in at]
    slopes, qs = _probe_torques(plant, survey.rigid, times, speeds, points)
    want_slopes, want_qs = _apart(plant, survey.rigid, times, speeds, points)
    assert len(qs) == len(points) == 1 + 2 * len(at) + 2 * len(jumps)
    assert _bits(slopes) == _bits(want_slopes)
    assert _bits(qs) == _bits(want_qs)
    assert any(s != (0.0, 0.0) for s in slopes)  # the loads' speed slopes are there to compare


def test_rigid_belt_torque_is_the_models_on_every_sample_of_a_run():
    scene = load_scene("e_motor_start")
    rigid = make_model("rigid", scene.params)
    plant = shared_plant(rigid, scene.drive, scene.load)
    rng = np.random.default_rng(7)
    x = np.column_stack([rng.uniform(-50.0, 50.0, 2001), rng.uniform(-400.0, 400.0, 2001)])
    x[:3] = [[0.0, 0.0], [-0.0, 0.0], [0.0, -0.0]]  # signed zeros keep their signs through the same operations
    u = plant.input_array(rng.uniform(0.0, 4.0, 2001), x)
    want = rigid.belt_torque(x, u)
    got = _rigid_belt_torque(rigid, x[:, 0], x[:, 1], u[:, 0], u[:, 1])
    assert got.tobytes() == np.ascontiguousarray(want).tobytes()
