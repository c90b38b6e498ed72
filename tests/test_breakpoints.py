"""Torque breakpoints in closed-loop scenes (``Simulator.run`` through ``core.stepper``).

A one-step method that integrates across a jump or a kink of its torque is
locally first order: on ``paper`` a 12.5 ms ``lawson5`` step with the soft
start's end (0.02 s) inside it is 2000x less accurate than with the step split
at 0.02 s; a step that *ends* on a jump and samples the torque after it is
first order too. These tests check both against DOP853 references restarted
at every breakpoint (``tests/test_stepper.py`` checks open-loop jumps for
every method against the closed form).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from belt_drive_ros.core import sources as S
from belt_drive_ros.benchmarks.common import dop853_reference, run_errors
from belt_drive_ros.core.model import make_model
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import Simulator


def test_profiles_report_their_breakpoints():
    assert S.Step(0.0, 1.0, 0.3).breakpoints() == (0.3,)
    assert S.Step(1.0, 1.0, 0.3).breakpoints() == ()  # no jump
    assert S.Ramp(0.0, 5.0, 0.2, 0.7).breakpoints() == (0.2, 0.7)
    assert S.MotorCurve(soft_start_time=0.02).breakpoints() == (0.02,)
    assert S.MotorCurve().breakpoints() == () and S.Polynomial(1.0).breakpoints() == ()
    assert S.Engine(ramp_time=0.5).breakpoints() == (0.5,)
    assert S.Schedule(S.Compressor(ramp_time=0.1), S.Constant(2.0), ((0.2, 0.4),)).breakpoints() == (0.1, 0.2, 0.4)
    assert tuple(S.Table((0.0, 0.5, 1.0), (1.0, 3.0, 2.0)).breakpoints()) == (0.0, 0.5, 1.0)  # a float64 array


def test_exact_method_is_exact_again_with_a_jump_inside_a_step():
    """Open loop, piecewise-constant torque jumping off the grid: the split ``exact`` run is the exact solution."""
    scene = load_scene("paper").with_overrides(
        drive=S.Step(0.0, 8.0, 0.2503), load=S.Constant(2.0), duration=0.5, model="flexible"
    )
    model = make_model("flexible", scene.params)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    ref = dop853_reference(scene, "flexible")  # restarted at 0.2503 s
    sim = Simulator(model, scene.drive, scene.load, "exact", 1e-3)
    t, x = sim.run(0.5, x0)
    assert sim.stepper.split_steps == {250: [0.2503]}
    assert run_errors(ref, t, x)["error"] < 1e-9
    sim.stepper.breakpoints = []  # without the split: the jump is taken 0.7 ms late, a first-order error
    t, x = sim.run(0.5, x0)
    assert sim.stepper.split_steps == {} and run_errors(ref, t, x)["error"] > 1e-3


@functools.cache
def _paper_1s():
    """paper over 1 s and its DOP853 reference (computed once for both methods below)."""
    scene = load_scene("paper").with_overrides(duration=1.0)
    return scene, dop853_reference(scene, "flexible")


@pytest.mark.parametrize("method, split_error, unsplit_error", [("lawson5", 3e-6, 1e-4), ("etd4", 2e-4, 1e-3)])
def test_soft_start_end_inside_a_step(method, split_error, unsplit_error):
    """paper: the motor's soft start ends at 0.02 s, inside the second 12.5 ms step."""
    scene, ref = _paper_1s()
    model = make_model("flexible", scene.params)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    sim = Simulator(model, scene.drive, scene.load, method, 0.0125)
    t, x = sim.run(1.0, x0)
    assert sim.stepper.split_steps == {1: [0.02]}
    split = run_errors(ref, t, x)["error"]
    sim.stepper.breakpoints = []
    t, x = sim.run(1.0, x0)
    assert sim.stepper.split_steps == {}
    unsplit = run_errors(ref, t, x)["error"]
    assert split < split_error < unsplit_error < unsplit, (split, unsplit)


def test_breakpoints_on_the_grid_are_not_split():
    scene = load_scene("paper")
    model = make_model("flexible", scene.params)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    sim = Simulator(model, scene.drive, scene.load, "etd4", 0.005)  # 0.02 s = 4 steps, up to rounding
    sim.run(0.1, x0)
    assert sim.stepper.split_steps == {}
    off_grid = Simulator(model, S.Step(0.0, 5.0, 0.0123), S.Constant(1.0), "etd2", 0.005)
    _, states = off_grid.run(0.1, x0)
    assert off_grid.stepper.split_steps == {2: [0.0123]} and np.all(np.isfinite(states))


def test_load_switch_on_the_grid_keeps_fourth_order():
    """truck_compressor: the compressor's schedule switches at 0.5 s, on the binary grid of 2^-9 and 2^-10 s.

    Before the stepper sampled left limits, a step ending on the switch read the switched load:
    etd4 fell to first order there. Tolerance: an observed order within 0.3 of 4, and the same
    error (within 1.5x) as with the switch moved 1e-7 s off the grid.
    """
    base = load_scene("truck_compressor").with_overrides(duration=0.8, model="flexible")
    assert 0.5 in base.load.breakpoints()
    model = make_model("flexible", base.params)
    x0 = base.initial_state.vector("flexible", base.params.ratio)
    off = base.with_overrides(load=S.Schedule(base.load.active, base.load.inactive,
                                              tuple((a + 1e-7, b + 1e-7) for a, b in base.load.periods)))

    references = {}  # one DOP853 reference per scene (base is measured at two steps)

    def error(scene, dt):
        sim = Simulator(model, scene.drive, scene.load, "etd4", dt)
        t, x = sim.run(scene.duration, x0)
        if id(scene) not in references:
            references[id(scene)] = dop853_reference(scene, "flexible")
        return run_errors(references[id(scene)], t, x)["error"]

    coarse, fine = error(base, 2.0**-9), error(base, 2.0**-10)
    assert np.log2(coarse / fine) >= 3.7, (coarse, fine)
    assert fine <= 1.5 * error(off, 2.0**-10), fine


def test_a_table_of_a_few_points_nanoseconds_apart_does_not_set_the_surveys_step():
    """A valid table profile with points 1 ns apart: the survey took the table's spacing as its step over the whole
    run (5e9 steps: sim and the node hung at start, no message). A record's spacing sets the step only where the run
    at it takes about as many steps as the record has samples; otherwise the run's own step, clamped at them."""
    import numpy as np

    from belt_drive_ros.core.accuracy_probes import _survey_step, operating_run_step
    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.scenes import scene_from_mapping

    rdt = operating_run_step(5.0)
    few = [np.array([1e-9, 2e-9])]
    assert _survey_step(lambda: few, rdt, 5.0) == rdt
    recording = [np.arange(1, 5000) * 1e-3]  # a 1 kHz record over the run: its own steps
    assert _survey_step(lambda: recording, rdt, 5.0) == 1e-3
    scene = scene_from_mapping({"extends": "paper", "duration": 0.5, "method": "etd4", "dt": 1e-3,
                                "drive": {"type": "table", "times": [0.0, 1e-9, 2e-9], "values": [1.0, 2.0, 3.0],
                                          "interpolation": "previous"}})  # fmt: skip
    held = scene_from_mapping({"extends": "paper", "duration": 0.5, "method": "etd4", "dt": 1e-3,
                               "drive": {"type": "constant", "value": 3.0}})
    a, b = simulate(scene, model="flexible"), simulate(held, model="flexible")
    assert np.allclose(a.outputs["omega_M"][-1], b.outputs["omega_M"][-1], rtol=1e-6)
