"""Every shipped scene's default method and step earn their place, on the model ``auto`` actually runs.

References: DOP853 at rtol 1e-13 restarted at every torque breakpoint
(:func:`belt_drive_ros.benchmarks.common.dop853_reference`) for a scene that
stays linear; for one that goes on to the slipping tier, the event-located
DOP853 reference of the hybrid model
(:func:`belt_drive_ros.benchmarks.slip_runs.reference`, rtol 1e-13) against
the slipping engine's run (``bench workprecision``'s slipping panel).
Metric: max error of the drive speed and of the belt torque relative to
their peaks. Tolerance: 1e-4, what the README promises for the defaults.
The accuracy guard must say so too: a shipped scene does not warn on its
own default (bsg_start's and e_motor_start's smooth starts were rated as
unit steps: 1.3e-4 and 4.5e-5), and its estimate is no smaller than
measured by more than a small factor.
"""

from __future__ import annotations

import pytest

from belt_drive_ros.benchmarks import slip_runs
from belt_drive_ros.benchmarks.common import dop853_reference, run_errors
from belt_drive_ros.core.fidelity import choose_model
from belt_drive_ros.core.model import make_model
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.scene import shipped_scenes
from belt_drive_ros.core.simulate import Simulator, simulate

DEFAULT_TOLERANCE = 1e-4
#: the guard's estimate may fall below the measured error by at most this factor (an estimate, not a bound)
UNDER_RATING = 2.0


def _auto_model(scene) -> str:
    if scene.model != "auto":
        return scene.model
    return choose_model(scene).model


@pytest.mark.parametrize("name", shipped_scenes())
def test_default_method_and_step_reach_1e_4_of_the_peak(name):
    scene = load_scene(name)
    kind = _auto_model(scene)
    if kind == "slipping":
        case = slip_runs.case_from_scene(scene)
        run = slip_runs.run(case, "hybrid", scene.method, scene.dt, repeats=1)
        assert run.status == "ok", run.status
        errors = slip_runs.errors(slip_runs.reference(case, scene.dt), run)
    else:
        model = make_model(kind, scene.params)
        sim = Simulator(model, scene.drive, scene.load, scene.method, scene.dt, scene.method_options)
        times, states = sim.run(scene.duration, scene.initial_state.vector(kind, scene.params.ratio))
        errors = run_errors(dop853_reference(scene, kind), times, states)
    assert errors["e_speed"] <= DEFAULT_TOLERANCE and errors["e_belt"] <= DEFAULT_TOLERANCE, (kind, scene.method, scene.dt, errors)
    result = simulate(scene)
    assert result.model == kind
    report = result.accuracy
    assert report is not None and report.accurate, report.describe()  # no warning on its own default
    measured = max(errors["e_speed"], errors["e_belt"])
    assert report.error * UNDER_RATING >= measured, (report.describe(), errors)


def test_the_slipping_run_is_rated_where_its_modes_alone_pass():
    """truck_compressor at etd4, 1 ms: each mode alone passes, the run is 2.4e-4 off; the guard must see it."""
    scene = load_scene("truck_compressor").with_overrides(dt=1e-3)
    case = slip_runs.case_from_scene(scene)
    run = slip_runs.run(case, "hybrid", "etd4", 1e-3, repeats=1)
    measured = slip_runs.errors(slip_runs.reference(case, 1e-3), run)["error"]
    assert measured > DEFAULT_TOLERANCE
    report = simulate(scene).accuracy
    assert not report.accurate and report.error * UNDER_RATING >= measured, report.describe()
    assert report.suggestion is not None and report.suggestion <= 5e-4, report.describe()
