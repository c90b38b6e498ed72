"""Every shipped scene's default method and step earn their place.

Reference: DOP853 at rtol 1e-13 restarted at every torque breakpoint
(:func:`belt_drive_ros.benchmarks.common.dop853_reference`), on the linear
model ``auto``'s frequency rule picks (a scene that goes on to the slipping
tier is checked on that linear model: the slipping model's accuracy is
``tests/test_slip*.py``'s). Metric: max error of the drive speed and of the
belt torque relative to their peaks (``run_errors``). Tolerance: 1e-4, what
the README promises for the defaults.
"""

from __future__ import annotations

import pytest

from belt_drive_ros.benchmarks.common import dop853_reference, run_errors
from belt_drive_ros.core.fidelity import choose_model
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.scene import shipped_scenes, load_scene
from belt_drive_ros.core.simulate import Simulator

DEFAULT_TOLERANCE = 1e-4


@pytest.mark.parametrize("name", shipped_scenes())
def test_default_method_and_step_reach_1e_4_of_the_peak(name):
    scene = load_scene(name)
    kind = scene.model if scene.model in ("rigid", "flexible") else choose_model(scene, check_slip=False).model
    model = make_model(kind, scene.params)
    sim = Simulator(model, scene.drive, scene.load, scene.method, scene.dt, scene.method_options)
    times, states = sim.run(scene.duration, scene.initial_state.vector(kind, scene.params.ratio))
    errors = run_errors(dop853_reference(scene, kind), times, states)
    assert errors["e_speed"] <= DEFAULT_TOLERANCE and errors["e_belt"] <= DEFAULT_TOLERANCE, (scene.method, scene.dt, errors)
