"""Clamps at torque breakpoints: one array form for every plan (``StepPlanner._plan``: ``clamps = (cells, lo, hi)``,
``splits = {cell: cuts}``), the rule applied breakpoint by breakpoint, and the runs of clamped steps (one compiled
call, ``kernel.clamped_steps``) bit for bit as the same plan stepped one step at a time (one kernel call each).
The hard case: a torque recorded at the step rate beside a load that reads time (``bags/compressor_cycling``)."""

import math
from pathlib import Path

import numpy as np
import pytest

from belt_drive_ros.core import step_plan
from belt_drive_ros.core import stepper as S
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.sources import Sine, Table
from belt_drive_ros.core.step_plan import snap_tolerance, step_arrays
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.io.torque_bag import scene_with_torque_bag

ROOT = Path(__file__).resolve().parents[1]


def _scene():
    return scene_with_torque_bag(load_scene(str(ROOT / "bags" / "compressor_cycling.yaml")),
                                 ROOT / "bags" / "compressor_cycling_torque.mcap")


def _stepper(scene, model, method, dt, load=None, guard=None):
    plant = S.Plant(make_model(model, scene.params), scene.drive, load or scene.load)
    return S.Stepper(plant, method, dt, guard=guard), scene.initial_state.vector(model, scene.params.ratio)


def _one_by_one(st, x0, t0, t1):
    """(times, states) of the plan ``st.steps(t0, t1)`` stepped one step at a time (``_special_step``: one kernel call
    per step or piece, the step's own clamps), stopping after the step where the guard fires."""
    times, steps = st.steps(t0, t1)
    states = [np.asarray(x0, dtype=float)]
    for a, e, whole, lo, hi, cuts in steps:
        states.append(st._special_step(states[-1], a, e, whole, lo, hi, list(cuts)))
        if st.guard is not None and st.guard.value(states[-1]) > 0.0:
            break
    return times[: len(states)], np.array(states)


def _rule(st, t0, t1):
    """``({cell: [lo, hi]}, {cell: [cuts]})``: the plan's clamps and splits by the rule, one breakpoint at a time in
    Python (scalar ``left_of``)."""
    k0, k1 = st._snap(t0), st._snap(t1)
    start = st.grid_time(k0) if k0 is not None else t0
    end = st.grid_time(k1) if k1 is not None else t1
    first = k0 if k0 is not None else st._cell(t0)
    last = k1 - 1 if k1 is not None else st._cell(t1)
    tol0, tol1 = snap_tolerance(start, st.dt), snap_tolerance(end, st.dt)
    clamps, splits = {}, {}
    if last < first:  # t0 and t1 on one grid time: no step
        return clamps, splits

    def bound(c, side, value):
        entry = clamps.setdefault(c, [-math.inf, math.inf])
        entry[side] = max(entry[0], value) if side == 0 else min(entry[1], value)

    for b in np.asarray(st.breakpoints, dtype=float).tolist():
        if abs(b - start) <= max(tol0, snap_tolerance(b, st.dt)) or abs(b - t0) <= tol0:
            bound(first, 0, b)
        elif abs(b - end) <= max(tol1, snap_tolerance(b, st.dt)) or abs(b - t1) <= tol1:
            bound(last, 1, st.plant.left_of(b))
        elif start < b < end:
            k = st._snap(b)
            if k is not None:  # on a knot: the step ending there up to its left limit, the one starting there from it
                if first <= k - 1:
                    bound(k - 1, 1, st.plant.left_of(b))
                if k <= last:
                    bound(k, 0, b)
            else:
                splits.setdefault(min(max(st._cell(b), first), last), []).append(b)
    return clamps, splits


@pytest.fixture(params=["numpy", "loop"])
def path(request, monkeypatch):
    """Breakpoints classified with numpy (every plan) or one at a time in Python (every plan)."""
    monkeypatch.setattr(step_plan, "VECTOR_MIN", 0 if request.param == "numpy" else 10**9)
    return request.param


def _assert_plan_is_the_rule(st, t0, t1):
    plan = st._plan(t0, t1)
    clamps, splits = _rule(st, t0, t1)
    cells, lo, hi = plan["clamps"]
    assert cells.dtype == np.int64 and np.all(np.diff(cells) > 0)
    assert cells.tolist() == sorted(clamps)
    assert lo.tolist() == [clamps[c][0] for c in cells.tolist()]  # the same floats
    assert hi.tolist() == [clamps[c][1] for c in cells.tolist()]
    assert plan["splits"] == splits and st.split_steps == splits
    if not plan["empty"]:
        lo_all, hi_all, special = step_arrays(plan)
        n = plan["last"] - plan["first"] + 1
        assert lo_all.size == hi_all.size == special.size == n
        for c in range(plan["first"], plan["last"] + 1):
            step = st._step(plan, c)
            assert step[3:5] == tuple(clamps.get(c, (-math.inf, math.inf))) == (lo_all[c - plan["first"]], hi_all[c - plan["first"]])
            assert list(step[5]) == splits.get(c, [])
    return plan


@pytest.mark.parametrize("method", ["etd4", "exact", "rk4", "lawson5", "trapezoidal"])
@pytest.mark.parametrize("model", ["rigid", "flexible"])
def test_clamped_steps_are_the_steps_stepped_one_by_one(model, method):
    scene = _scene()
    st, x0 = _stepper(scene, model, method, scene.dt)
    plan = st._plan(0.0, 2.5)
    assert plan["clamps"][0].size > 2000 and not plan["splits"]  # every step clamped, in the arrays
    times, states = st.run(x0, 0.0, 2.5)
    ref_times, ref_states = _one_by_one(st, x0, 0.0, 2.5)
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)  # the same floats, not merely close
    progress = []
    _, with_progress = st.run(x0, 0.0, 2.5, progress.append)
    np.testing.assert_array_equal(with_progress, ref_states)
    assert len(progress) > 10 and progress[-1] == 1.0
    # an advance from and to times off the grid (partial steps at both ends, the rest in compiled runs)
    np.testing.assert_array_equal(st.advance(x0, 0.0123456, 2.3456789), _one_by_one(st, x0, 0.0123456, 2.3456789)[1][-1])
    times, states = st.run(x0, 0.0004321, 1.7654321)
    ref_times, ref_states = _one_by_one(st, x0, 0.0004321, 1.7654321)
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)


def test_the_plan_is_the_rule_breakpoint_by_breakpoint(path):
    """Every clamp and split of a plan as the rule gives it one breakpoint at a time: a recording at the step rate
    (a breakpoint on every knot), at a rate off the grid (splits), a few among many steps, ends on, off and at
    breakpoints."""
    scene = _scene()
    st, _ = _stepper(scene, "flexible", "etd4", scene.dt)
    bps = np.asarray(st.breakpoints)
    plan = _assert_plan_is_the_rule(st, 0.0, 3.0)
    assert plan["clamps"][0].size == 3000  # both sides of every interior knot and the last step's end
    for t0, t1 in ((0.0123456, 2.3456789), (float(bps[100]), float(bps[2000])), (0.0004321, 1.7654321),
                   (float(bps[5]) + 1e-12, float(bps[9]) - 1e-12), (0.5, 0.5), (0.5, 0.5 + 1e-13), (1.0, 1.0004)):
        _assert_plan_is_the_rule(st, t0, t1)
    off, _ = _stepper(scene, "flexible", "rk4", 3e-4, load=Sine(mean=5.0, amplitude=3.0, frequency=7.0))
    plan = _assert_plan_is_the_rule(off, 0.0, 1.5)
    assert len(plan["splits"]) == 1000 and plan["clamps"][0].size > 500  # samples inside steps (cuts), on knots
    _assert_plan_is_the_rule(off, 0.00011, 1.49)
    times = np.arange(30) * 0.05
    drive = Table(times=times, values=20.0 + 5.0 * np.cos(times), interpolation="previous")
    few = S.Stepper(S.Plant(make_model("flexible", scene.params), drive, Sine(mean=5.0, amplitude=3.0, frequency=7.0)),
                    "rk4", scene.dt)  # fmt: skip
    plan = _assert_plan_is_the_rule(few, 0.0, 1.5)
    assert plan["clamps"][0].size == 2 * 29  # both sides of 29 interior knots
    for t0, t1 in ((0.05, 1.45), (0.0499999, 1.4500001), (0.0004, 1.4996), (0.1, 0.1001)):
        _assert_plan_is_the_rule(few, t0, t1)
    # several breakpoints on one knot (within its snap tolerance) and at the ends: the latest lo, the earliest hi
    b = np.asarray(few.breakpoints)
    few.breakpoints = np.unique(np.r_[b, b[1:5] + 3e-13, b[5:9] - 2e-13, b[9:12] + 4e-13, 1e-13, 1.5 - 1e-13, 1.5])
    for t0, t1 in ((0.0, 1.5), (0.05, 1.45), (0.0499999, 1.4500001), (float(b[3]) + 2e-13, float(b[7]) - 1e-13)):
        plan = _assert_plan_is_the_rule(few, t0, t1)
    assert plan["clamps"][0].size == 8
    few.origin = 0.00025  # the table's times off the grid: cuts
    assert _assert_plan_is_the_rule(few, 0.0, 1.5)["splits"]


def test_a_recording_beside_a_time_free_load(path):
    """A recording at the step rate with a load that reads no time: every step clamped by the rule (each in the
    plan's arrays), the run the same floats as one step at a time."""
    from test_recorded_steps import _recorded

    from belt_drive_ros.core.sources import Constant

    scene = _scene()
    plant = S.Plant(make_model("flexible", scene.params), _recorded(), Constant(value=5.0))
    st = S.Stepper(plant, "etd4", 1e-3)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    for t0, t1 in ((0.0, 1.2), (0.00031, 1.19)):
        plan = _assert_plan_is_the_rule(st, t0, t1)
        assert plan["clamps"][0].size > 1000 and not plan["splits"]
        times, states = st.run(x0, t0, t1)
        ref_times, ref_states = _one_by_one(st, x0, t0, t1)
        np.testing.assert_array_equal(times, ref_times)
        np.testing.assert_array_equal(states, ref_states)


def test_a_recorded_drive_and_a_sine_load_on_and_off_the_grid(path):
    """A load of the time itself (a sine: never time-free) beside a recording at the step rate, and at a rate
    off the grid (split steps: Python as before, the clamped ones compiled); the same floats either way."""
    scene = _scene()
    load = Sine(mean=5.0, amplitude=3.0, frequency=7.0)
    for dt in (1e-3, 3e-4):
        st, x0 = _stepper(scene, "flexible", "rk4", dt, load=load)
        np.testing.assert_array_equal(st.run(x0, 0.0, 1.5)[1], _one_by_one(st, x0, 0.0, 1.5)[1])


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
    times, states = st.run(x0, 0.0, 3.0)
    assert 100 < times.size < 3000 and st.stopped is not None
    ref_times, ref_states = _one_by_one(st, x0, 0.0, 3.0)
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)
    j = st.stopped[0]
    assert st.stopped[1:] == (*st._step(st._plan(0.0, 3.0), j)[:5], [])  # the step it stopped in, as planned


def test_clamped_steps_add_no_compiled_specialisation():
    from belt_drive_ros.core import kernel

    scene = _scene()
    st, x0 = _stepper(scene, "flexible", "etd4", scene.dt)
    st.run(x0, 0.0, 0.5)
    st.advance(x0, 0.0001, 0.4999)
    assert all(len(getattr(kernel, name).signatures) == 1 for name in ("linear_steps", "clamped_steps"))


def test_a_few_breakpoints_among_many_steps(path):
    """Breakpoints on every 50th knot (a held table's switching times) among 1,500 steps, a sine load: the clamps
    and the groups' ends as sorted sets (memory of the breakpoints' size, not the run's), the same floats as one
    step at a time."""
    scene = _scene()
    times = np.arange(30) * 0.05
    drive = Table(times=times, values=20.0 + 5.0 * np.cos(times), interpolation="previous")
    plant = S.Plant(make_model("flexible", scene.params), drive, Sine(mean=5.0, amplitude=3.0, frequency=7.0))
    st = S.Stepper(plant, "rk4", scene.dt)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    plan = st._plan(0.0, 1.5)
    cells, _, _, ends = st._groups(plan)
    assert cells.size == 2 * 29 and ends.size < 100  # both sides of 29 interior knots, no array of the run's length
    assert ends[-1] == plan["last"] and np.all(np.diff(ends) > 0)
    np.testing.assert_array_equal(st.run(x0, 0.0, 1.5)[1], _one_by_one(st, x0, 0.0, 1.5)[1])
    np.testing.assert_array_equal(st.advance(x0, 0.0004, 1.4996), _one_by_one(st, x0, 0.0004, 1.4996)[1][-1])
