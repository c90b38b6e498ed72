"""The one time-advance engine (``belt_drive_ros.core.stepper``) against closed forms.

Reference: the linear belt ``x' = A x + B u`` with piecewise-constant torques
is solved exactly piece by piece with the matrix exponential of the
augmented system (:func:`closed_form`); each piece's torque is read at the
piece's midpoint, so the reference does not depend on which side of a jump
a profile assigns the jump time to. Errors are per state component,
relative to that component's peak over the run. Tolerances: 1e-11 where a
method is exact for the torque (rounding over ~10^3 steps is ~1e-13), and
an observed convergence order within 0.3 of the method's order otherwise.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from belt_drive_ros.core import sources as S
from belt_drive_ros.core.errors import SimulationDivergedError
from belt_drive_ros.core.integrators import FIXED_STEP_METHODS, method_class
from belt_drive_ros.core.model import make_model
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import Simulator, simulate
from belt_drive_ros.core.stepper import Plant, Stepper
from belt_drive_ros.io.torque_bag import RecordedTorque

PARAMS = load_scene("paper").params
MODEL = make_model("flexible", PARAMS)
X0 = np.zeros(4)
#: methods exact (to rounding) for piecewise-constant torque on the linear belt
EXACT_FOR_HELD_TORQUE = ("exact", "etd2", "etd4")
ROUNDING = 1e-11


def closed_form(model, drive, load, x0, times) -> np.ndarray:
    """States at ``times`` of x' = A x + B u for time-only piecewise-constant torques (matrix exponential)."""
    A, B = model.A, model.B
    n = A.shape[0]
    jumps = {float(b) for b in (*drive.breakpoints(), *load.breakpoints()) if times[0] < b < times[-1]}
    knots = sorted({float(t) for t in times} | jumps)
    x = np.array(x0, dtype=float)
    at = {knots[0]: x}
    for a, b in zip(knots[:-1], knots[1:]):
        mid = 0.5 * (a + b)
        u = np.array([drive.torque(mid, 0.0, 0.0), load.torque(mid, 0.0, 0.0)], dtype=float)
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = A
        M[:n, n] = B @ u
        E = scipy.linalg.expm(M * (b - a))
        x = E[:n, :n] @ x + E[:n, n]
        at[b] = x
    return np.array([at[float(t)] for t in times])


def relative_error(states, reference) -> float:
    return float(np.max(np.abs(states - reference) / np.max(np.abs(reference), axis=0)))


def run_error(method, drive, load, dt, duration=1.0):
    stepper = Stepper(Plant(MODEL, drive, load), method, dt)
    times, states = stepper.run(X0, 0.0, duration)
    return relative_error(states, closed_form(MODEL, drive, load, X0, times))


#: (drive jump time, load jump time, dt): jumps on the binary grid, just off it, and decimal
#: jump times on a decimal grid whose float product lands an ulp below them (1500 * 6e-4 < 0.9)
CASES = {
    "on_grid": (0.25, 0.125, 2.0**-10),
    "off_grid": (0.25 + 1e-7, 0.125 + 3e-7, 2.0**-10),
    "ulp_below_decimal": (0.9, 0.3, 6e-4),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_jumps_anywhere_keep_each_methods_order(method, case):
    t_drive, t_load, dt = CASES[case]
    if case == "ulp_below_decimal":
        assert 1500 * dt < t_drive and round(t_drive / dt) == 1500  # the grid misses the jump by rounding
    drive, load = S.Step(0.0, 8.0, t_drive), S.Step(1.0, 3.0, t_load)
    coarse, fine = run_error(method, drive, load, dt), run_error(method, drive, load, dt / 2)
    if method in EXACT_FOR_HELD_TORQUE:
        assert max(coarse, fine) <= ROUNDING, (coarse, fine)
    elif fine > ROUNDING:
        order = math.log2(coarse / fine)
        assert order >= method_class(method).order - 0.3, (coarse, fine, order)
    # a jump on the grid costs nothing against the same jump moved off it
    if case == "on_grid":
        off = run_error(method, S.Step(0.0, 8.0, 0.25 + 1e-7), S.Step(1.0, 3.0, 0.125 + 3e-7), dt)
        assert coarse <= 1.1 * off + ROUNDING, (coarse, off)


def test_a_breakpoint_a_few_ulps_from_the_grid_counts_as_on_it():
    b = 0.25
    for near in (math.nextafter(b, math.inf), math.nextafter(math.nextafter(b, -math.inf), -math.inf)):
        drive = S.Step(0.0, 8.0, near)
        stepper = Stepper(Plant(MODEL, drive, S.Constant(2.0)), "etd2", 2.0**-10)
        times, states = stepper.run(X0, 0.0, 0.5)
        assert stepper.split_steps == {}  # no sliver sub-step of an ulp
        assert relative_error(states, closed_form(MODEL, drive, S.Constant(2.0), X0, times)) <= ROUNDING


def test_run_takes_the_left_limit_at_on_grid_jumps_of_a_table():
    drive, load = S.Step(0.0, 8.0, 0.9), S.Table((0.0, 0.3, 0.6), (1.0, 3.0, -1.0), interpolation="previous")
    for method in ("etd2", "etd4"):
        stepper = Stepper(Plant(MODEL, drive, load), method, 6e-4)
        times, states = stepper.run(X0, 0.0, 1.2)
        assert relative_error(states, closed_form(MODEL, drive, load, X0, times)) <= ROUNDING


def test_recorded_torque_with_a_sample_at_every_step_is_exact():
    """A torque bag replayed on its own grid (golden bags): every step ends on a jump of the hold."""
    dt = 1e-3
    times = np.arange(0, 500) * dt
    values = 5.0 + 3.0 * np.sin(times * 40.0)
    drive = RecordedTorque(times=tuple(times), values=tuple(values))
    load = S.Constant(2.0)
    for method in ("exact", "etd2", "etd4"):
        stepper = Stepper(Plant(MODEL, drive, load), method, dt)
        t, x = stepper.run(X0, 0.0, 0.5)
        assert relative_error(x, closed_form(MODEL, drive, load, X0, t)) <= ROUNDING, method


def test_run_ends_at_duration_exactly():
    drive, load = S.Step(0.0, 8.0, 0.2503), S.Constant(2.0)
    sim = Simulator(MODEL, drive, load, "exact", 11.9e-3)
    time, states = sim.run(5.0, X0)
    assert time[-1] == 5.0 and time.size == 422  # 420 whole steps of 11.9 ms, then 2 ms
    assert np.allclose(np.diff(time)[:-1], 11.9e-3) and math.isclose(time[-1] - time[-2], 5.0 - 420 * 11.9e-3)
    assert relative_error(states, closed_form(MODEL, drive, load, X0, time)) <= ROUNDING
    # a duration the step divides up to rounding: no sliver step at the end
    t2, _ = Simulator(MODEL, drive, load, "exact", 6e-4).run(0.9, X0)
    assert t2.size == 1501 and t2[-1] == 0.9
    # the whole simulate() call, an open-loop scene too
    result = simulate(load_scene("paper"), dt=11.9e-3, duration=0.5)
    assert result.time[-1] == 0.5
    on_grid = S.Step(0.0, 8.0, 0.21)  # 30 steps of 7 ms
    scene = load_scene("paper").with_overrides(drive=on_grid, load=load, model="flexible")
    open_loop = simulate(scene, method="etd2", dt=7e-3, duration=0.5)
    assert open_loop.time[-1] == 0.5


def test_advance_in_grid_ticks_is_bit_identical_to_one_run():
    """The node's tick: ticks on the grid (times from integer nanoseconds) reproduce the offline run bit for bit."""
    scene = load_scene("truck_compressor")
    model = make_model("flexible", scene.params)
    drive = S.Schedule(S.Constant(40.0), S.Constant(10.0), ((0.0123, 0.05),))
    for method, dt_ns, tick_ns in (("etd2", 500_000, 1_000_000), ("exact", 250_000, 1_000_000), ("lawson5", 1_000_000, 1_000_000)):
        dt = dt_ns / 1e9
        stepper = Stepper(Plant(model, drive, scene.load), method, dt)
        x0 = scene.initial_state.vector("flexible", scene.params.ratio)
        times, states = stepper.run(x0, 0.0, 0.08)
        x, ticks = x0, range(0, 80_000_001, tick_ns)
        every = tick_ns // dt_ns
        for j, (a, b) in enumerate(zip(ticks[:-1], ticks[1:])):
            x = stepper.advance(x, a / 1e9, b / 1e9)
            assert np.array_equal(x, states[(j + 1) * every]), (method, j)


def test_ticks_see_breakpoints_set_after_the_stepper_remembered_a_free_interval():
    """The tick's breakpoint check remembers the last breakpoint-free interval; a new breakpoint list (the node's
    torque changes) inside it must split the next tick as a new stepper does."""
    drive, load = S.Step(0.0, 8.0, 0.0105), S.Constant(1.0)
    stepper = Stepper(Plant(MODEL, drive, load), "exact", 1e-3)
    x = X0
    for k in range(5):  # the interval (-inf, 0.0105) remembered
        x = stepper.advance(x, k * 1e-3, (k + 1) * 1e-3)
    stepper.breakpoints = [0.0055]
    moved = Stepper(Plant(MODEL, drive, load), "exact", 1e-3)
    moved.breakpoints = [0.0055]
    after = stepper.advance(x, 0.005, 0.006)
    assert stepper.split_steps  # split at 0.0055, not taken as a whole step
    assert np.array_equal(after, moved.advance(x, 0.005, 0.006))


@pytest.mark.parametrize("assigned", ["list", "plant"])
def test_breakpoints_edited_in_place_never_reach_a_stale_step_plan(assigned):
    """``run`` keeps its step plans by the breakpoints object: editing that object in place must be refused (it is
    immutable), so the stepper never runs the plan of the old breakpoints; assigning new ones takes effect."""
    drive, load = S.Step(0.0, 8.0, 0.0105), S.Constant(1.0)
    stepper = Stepper(Plant(MODEL, drive, load), "exact", 1e-3)
    if assigned == "list":
        stepper.breakpoints = [0.0055]
    stepper.run(X0, 0.0, 0.02)  # the plan of these breakpoints kept
    try:
        stepper.breakpoints[0] = 0.0075  # (old code: the edit went through and the next run reused the plan)
    except (TypeError, ValueError):  # immutable: a tuple or a read-only array
        stepper.breakpoints = [0.0075]
    moved = Stepper(Plant(MODEL, drive, load), "exact", 1e-3)
    moved.breakpoints = [0.0075]
    time, states = stepper.run(X0, 0.0, 0.02)
    assert list(stepper.split_steps) == [7]
    assert np.array_equal(states, moved.run(X0, 0.0, 0.02)[1])


def test_advance_with_off_grid_ticks_against_closed_form():
    """Ticks of 1.5 ms on a 1 ms grid (partial steps), jumps at 0.1234567 s and at a tick time."""
    drive, load = S.Step(0.0, 8.0, 0.1234567), S.Step(2.0, -1.0, 0.0045)
    stepper = Stepper(Plant(MODEL, drive, load), "exact", 1e-3)
    ticks = [k * 1.5e-3 for k in range(201)]
    x, states = X0, [X0]
    for a, b in zip(ticks[:-1], ticks[1:]):
        x = stepper.advance(x, a, b)
        states.append(x)
    assert relative_error(np.array(states), closed_form(MODEL, drive, load, X0, ticks)) <= ROUNDING
    with pytest.raises(ValueError, match="before t0"):
        stepper.advance(x, 0.2, 0.1)
    assert np.array_equal(stepper.advance(x, 0.2, 0.2), x)


def test_divergence_raises_with_the_time():
    plant = Plant(MODEL, S.Constant(10.0), S.Constant(0.0))
    stepper = Stepper(plant, "euler", 0.02)
    with pytest.raises(SimulationDivergedError, match=r"diverged at t=.*method euler.*use method 'exact' or 'etd2'"):
        stepper.run(X0, 0.0, 200.0)
    # an exponential method is stable at any step: its advice is not another exponential method
    error = Stepper(plant, "exact", 0.02).diverged_error(1.0, X0)
    assert "check the torques and parameters" in str(error) and "use method" not in str(error)
    with pytest.raises(SimulationDivergedError, match=r"diverged at t="):
        stepper.advance(X0, 0.0, 200.0)
    stepper.loop = None  # the numpy path checks too
    with pytest.raises(SimulationDivergedError):
        stepper.run(X0, 0.0, 200.0)



def test_a_guarded_run_allocates_the_rows_it_reaches_and_stops_as_the_unguarded_run():
    """A guard may stop a run at its first steps (a slip onset): its state rows grow as it goes, so a 100 s run
    stopped near its start holds kilobytes, not the 100,000 rows of the whole run (3.2 MB); a stop after the
    rows grew is the unguarded run's states bit for bit, up to and including the crossing step."""
    import tracemalloc

    from belt_drive_ros.core.stage_scheme import Guard

    scene = load_scene("paper")
    p = scene.params
    i, k, c, r3 = p.ratio, p.k, p.c, p.r_3
    row = (2 * k * r3 * i, -2 * k * r3, 2 * c * r3 * i, -2 * c * r3)  # the belt's transmitted force Q [N]
    plant = Plant(MODEL, scene.drive, scene.load)
    x0 = scene.initial_state.vector("flexible", p.ratio)
    early = Stepper(plant, "etd2", 1e-3, guard=Guard(row, 60.0, True))
    early.run(x0, 0.0, 0.2)  # (its partial steps' integrators and loops built before the count)
    tracemalloc.start()
    try:
        t_e, _ = early.run(x0, 0.0, 100.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert early.stopped is not None and t_e.size < 256 and peak < 200_000
    times, states = Stepper(plant, "etd2", 1e-3).run(x0, 0.0, 2.0)
    q = np.abs(states @ np.array(row))
    late = 1.0001 * float(np.max(q[1:700]))
    j = int(np.argmax(q[1:] > late))  # the first step (j -> j+1) past it, beyond the first rows held
    assert j >= 699 and q[j + 1] > late
    guarded = Stepper(plant, "etd2", 1e-3, guard=Guard(row, late, True))
    t_g, s_g = guarded.run(x0, 0.0, 2.0)
    assert guarded.stopped[0] == j and np.array_equal(t_g, times[: j + 2]) and np.array_equal(s_g, states[: j + 2])

def test_left_of_gives_the_left_limit():
    cases = [
        (S.Step(1.0, 5.0, 0.3), 0.3),
        (S.Schedule(S.Constant(4.0), S.Constant(1.0), ((0.2, 0.4),)), 0.4),
        (S.Table((0.0, 0.5, 1.0), (1.0, 3.0, 2.0), interpolation="previous"), 0.5),
        (RecordedTorque(times=(0.0, 0.0005, 0.0010), values=(1.0, 2.0, 3.0)), 0.0005),
    ]
    for profile, b in cases:
        f = profile.scalar_torque()
        left, right = f(b - 1e-6, 0.0, 0.0), f(b, 0.0, 0.0)
        assert left != right
        assert f(profile.left_of(b), 0.0, 0.0) == left and profile.left_of(b) < b
        assert float(profile.torque(np.array([profile.left_of(b)]), 0.0, 0.0)[0]) == left


@pytest.mark.parametrize("compiled", [True, False])
def test_a_guard_stops_the_run_after_the_first_step_that_ends_past_it(compiled):
    """Guarded run = the unguarded run's states up to and including the first step whose end has g > 0.

    The guard here is |Q| > 60 N on the paper belt's transmitted force ``Q =
    2 k r_3 (i phi_M - phi_3) + 2 c r_3 (i omega_M - omega_3)`` (the form of the
    slipping belt's stick guard); the crossing step is found independently
    from the unguarded states. ``compiled`` False: the numpy step loop.
    """
    from belt_drive_ros.core.stage_scheme import Guard

    scene = load_scene("paper")
    p = scene.params
    i, k, c, r3 = p.ratio, p.k, p.c, p.r_3
    row = (2 * k * r3 * i, -2 * k * r3, 2 * c * r3 * i, -2 * c * r3)  # flexible x = [phi_M, phi_3, omega_M, omega_3]
    plant = Plant(MODEL, scene.drive, scene.load)
    free = Stepper(plant, "etd2", 1e-3)
    guarded = Stepper(plant, "etd2", 1e-3, guard=Guard(row, 60.0, True))
    if not compiled:
        free.loop = guarded.loop = None
    x0 = scene.initial_state.vector("flexible", p.ratio)
    times, states = free.run(x0, 0.0, 2.0)
    q = np.abs(states @ np.array(row))
    j = int(np.argmax(q[1:] > 60.0))  # first step (j -> j+1) that ends past the guard
    assert q[j + 1] > 60.0 and np.all(q[1 : j + 1] <= 60.0) and j > 10
    t_g, s_g = guarded.run(x0, 0.0, 2.0)
    assert guarded.stopped is not None and guarded.stopped[0] == j
    assert guarded.stopped[1:3] == (times[j], times[j + 1])
    assert np.array_equal(t_g, times[: j + 2]) and np.array_equal(s_g, states[: j + 2])
    # a guard that never fires: the whole run, bit for bit, not stopped
    never = Stepper(plant, "etd2", 1e-3, guard=Guard(row, 10.0 * q.max(), True))
    if not compiled:
        never.loop = None
    t_n, s_n = never.run(x0, 0.0, 2.0)
    assert never.stopped is None and np.array_equal(t_n, times) and np.array_equal(s_n, states)
