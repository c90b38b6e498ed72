"""A torque recorded at the step rate beside a load that reads time: every step clamped at its own breakpoints,
planned by numpy and stepped in one compiled call (``Stepper._knot_clamps``, ``kernel.clamped_steps``), bit for bit
as planned and stepped one by one (the plan's Python loop, one kernel call per step: ``ABSORB_MIN`` out of reach)."""

from pathlib import Path

import numpy as np
import pytest

from belt_drive_ros.core import stepper as S
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.sources import Sine, Table
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.io.torque_bag import scene_with_torque_bag

ROOT = Path(__file__).resolve().parents[1]


def _scene():
    return scene_with_torque_bag(load_scene(str(ROOT / "bags" / "compressor_cycling.yaml")),
                                 ROOT / "bags" / "compressor_cycling_torque.mcap")


def _stepper(scene, model, method, dt, load=None, guard=None):
    plant = S.Plant(make_model(model, scene.params), scene.drive, load or scene.load)
    return S.Stepper(plant, method, dt, guard=guard), scene.initial_state.vector(model, scene.params.ratio)


def _both(call):
    """``call()`` planned as arrays (the default) and one step at a time (ABSORB_MIN out of reach)."""
    new = call()
    old_min, S.ABSORB_MIN = S.ABSORB_MIN, 10**12
    try:
        old = call()
    finally:
        S.ABSORB_MIN = old_min
    return new, old


@pytest.mark.parametrize("method", ["etd4", "exact", "rk4", "lawson5", "trapezoidal"])
@pytest.mark.parametrize("model", ["rigid", "flexible"])
def test_clamped_steps_are_the_steps_planned_one_by_one(model, method):
    scene = _scene()
    st, x0 = _stepper(scene, model, method, scene.dt)
    plan = st._plan(0.0, 2.5, absorb=True)
    assert plan["absorbed"].size == 0 and plan["knots"] is not None  # the schedule reads time: nothing absorbed
    assert plan["knots"][0].size > 2000 and len(plan["special"]) <= 4  # the knots' clamps as arrays
    (times, states), (ref_times, ref_states) = _both(lambda: st.run(x0, 0.0, 2.5))
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)  # the same floats, not merely close
    progress = []
    _, with_progress = st.run(x0, 0.0, 2.5, progress.append)
    np.testing.assert_array_equal(with_progress, ref_states)
    assert len(progress) > 10 and progress[-1] == 1.0
    # an advance from and to times off the grid (partial steps at both ends, the rest in compiled runs)
    new, old = _both(lambda: st.advance(x0, 0.0123456, 2.3456789))
    np.testing.assert_array_equal(new, old)
    (times, states), (ref_times, ref_states) = _both(lambda: st.run(x0, 0.0004321, 1.7654321))
    np.testing.assert_array_equal(states, ref_states)


def test_clamps_are_the_plans_loop_clamps():
    """The arrays hold, for every step, the bounds the plan's loop gives it (the merge of both sides' clamps)."""
    scene = _scene()
    st, _ = _stepper(scene, "flexible", "etd4", scene.dt)
    plan = st._plan(0.0, 3.0, absorb=True)
    cells, lo, hi, ends = st._clamps(plan)
    S.ABSORB_MIN, old_min = 10**12, S.ABSORB_MIN
    try:
        ref = st._plan(0.0, 3.0, absorb=True)
    finally:
        S.ABSORB_MIN = old_min
    assert ref["knots"] is None and len(ref["special"]) == cells.size
    assert cells.tolist() == sorted(ref["special"])
    assert lo.tolist() == [ref["special"][c][0] for c in cells.tolist()]
    assert hi.tolist() == [ref["special"][c][1] for c in cells.tolist()]
    for c in (0, 1, 500, 1250, 2999):  # a step's description (the guard's stop, _special_step) merges both as well
        assert st._step(plan, c)[:5] == st._step(ref, c)[:5], c
    assert ends[-1] == plan["last"] and np.all(np.diff(ends) > 0)


def test_a_recorded_drive_and_a_sine_load_on_and_off_the_grid():
    """A load of the time itself (a sine: never time-free) beside a recording at the step rate, and at a rate
    off the grid (split steps: Python as before, the clamped ones compiled); the same floats either way."""
    scene = _scene()
    load = Sine(mean=5.0, amplitude=3.0, frequency=7.0)
    for dt in (1e-3, 3e-4):
        st, x0 = _stepper(scene, "flexible", "rk4", dt, load=load)
        (_, states), (_, ref_states) = _both(lambda: st.run(x0, 0.0, 1.5))
        np.testing.assert_array_equal(states, ref_states)


def test_a_guarded_run_stops_where_the_steps_one_by_one_stop():
    """A guard (the slipping belt's mode switch test) fires inside the clamped steps: the same stop and states."""
    from belt_drive_ros.core.stage_scheme import Guard

    scene = _scene()
    model = make_model("flexible", scene.params)
    speed = np.zeros(model.A.shape[0])
    speed[1] = 1.0
    free, x0 = _stepper(scene, "flexible", "etd4", scene.dt)
    _, run = free.run(x0, 0.0, 3.0)
    bound = 0.5 * (run[:100, 1].max() + run[:, 1].max())  # the engine's speed: crossed after the first 100 steps
    guard = Guard(row=tuple(speed.tolist()), bound=float(bound), absolute=False)
    st, x0 = _stepper(scene, "flexible", "etd4", scene.dt, guard=guard)
    (times, states), (ref_times, ref_states) = _both(lambda: st.run(x0, 0.0, 3.0))
    assert 100 < times.size < 3000 and st.stopped is not None
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)
    stopped = st.stopped
    _both(lambda: st.run(x0, 0.0, 3.0))
    assert st.stopped == stopped


def test_clamped_steps_add_no_compiled_specialisation():
    from belt_drive_ros.core import kernel

    scene = _scene()
    st, x0 = _stepper(scene, "flexible", "etd4", scene.dt)
    st.run(x0, 0.0, 0.5)
    st.advance(x0, 0.0001, 0.4999)
    assert all(len(getattr(kernel, name).signatures) == 1 for name in ("linear_steps", "clamped_steps"))


def test_a_few_breakpoints_among_many_steps():
    """Breakpoints on every 50th knot (a held table's switching times) among 1,500 steps, a sine load: the clamps
    as sorted sets (memory of the breakpoints' size, not the run's), the same floats as one step at a time."""
    scene = _scene()
    times = np.arange(30) * 0.05
    drive = Table(times=times, values=20.0 + 5.0 * np.cos(times), interpolation="previous")
    plant = S.Plant(make_model("flexible", scene.params), drive, Sine(mean=5.0, amplitude=3.0, frequency=7.0))
    st = S.Stepper(plant, "rk4", scene.dt)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    plan = st._plan(0.0, 1.5, absorb=True)
    assert plan["knots"] is not None and plan["knots"][0].size == 2 * 29  # both sides of 29 interior knots...
    cells, _, _, ends = st._clamps(plan)
    assert cells.size < 100 and ends.size < 100  # ... no array of the run's length
    (_, states), (_, ref_states) = _both(lambda: st.run(x0, 0.0, 1.5))
    np.testing.assert_array_equal(states, ref_states)
    new, old = _both(lambda: st.advance(x0, 0.0004, 1.4996))
    np.testing.assert_array_equal(new, old)
