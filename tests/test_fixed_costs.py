"""The fixed work of a whole ``simulate()``: one rigid survey run shared by the model choice, the method choice
and the accuracy guard's probes, with the numbers the separate runs gave.

The survey (:class:`~belt_drive_ros.core.fidelity.RigidSurvey`) replaces two cheap rigid runs per call: the
frequency rule's operating-speed estimate and the guard's probe run. Its states at the probe stops must be
those of the probe run advanced from stop to stop (bit for bit: every verdict figure is computed from them);
its operating speeds those of a plain run on the survey grid, up to the rigid estimate's own step error (the
survey also stops at a breakpoint window's start, a partial step there).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

from belt_drive_ros.core import accuracy_probes, fidelity
from belt_drive_ros.core.accuracy_probes import RigidSurvey, operating_run_step
from belt_drive_ros.core.model import RigidBeltModel, make_model
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.core.stepper import Plant, Stepper


@pytest.mark.parametrize("name, overrides", [
    ("paper", {}), ("e_motor_start", {}), ("paper", {"method": "auto", "duration": 1.0}),
    ("e_motor_start", {"model": "flexible", "method": "auto", "duration": 2.0}),
])  # fmt: skip
def test_one_rigid_survey_and_one_probe_set_per_simulate(monkeypatch, name, overrides):
    runs, probe_sets = [], []
    run, probes = RigidSurvey._run, accuracy_probes._probes
    monkeypatch.setattr(RigidSurvey, "_run", lambda self: (runs.append(self), run(self))[1])
    monkeypatch.setattr(accuracy_probes, "_probes", lambda *a: (probe_sets.append(a[0].model.name), probes(*a))[1])
    result = simulate(load_scene(name).with_overrides(**overrides))
    assert result.accuracy is not None and result.accuracy.stable
    assert len(runs) == 1, "the model choice, the method choice and the guard read one rigid run"
    # the method choice's probes are the run's guard's (one per model checked)
    assert len(probe_sets) == len(set(probe_sets)) == 1


def _probe_run_states(scene, stops, rdt):
    """The guard's former probe run: the rigid model advanced from stop to stop (1000 steps per advance)."""
    x0 = scene.initial_state.vector("rigid", scene.params.ratio)
    stepper = Stepper(Plant(RigidBeltModel(scene.params), scene.drive, scene.load), "exact", rdt)
    states, x, t = {0.0: (float(x0[0]), float(x0[1]))}, np.array(x0, dtype=float), 0.0
    for t1 in stops:
        edges = np.append(np.arange(t, t1, 1000 * rdt), t1)
        for a, b in zip(edges[:-1], edges[1:]):
            x = stepper.advance(x, float(a), float(b))
        states[t1], t = (float(x[0]), float(x[1])), t1
    return states


@pytest.mark.parametrize("name", ["paper", "e_motor_start", "bsg_start", "truck_compressor"])
def test_survey_states_are_the_probe_runs_bit_for_bit(name):
    scene = load_scene(name)
    survey = RigidSurvey.of_scene(scene)
    t_probe, plain, early, states = survey.probe_states()
    stops = sorted(set(plain) | set(early.values()) | {float(t) for t in t_probe})
    assert len(stops) >= 5
    assert states == _probe_run_states(scene, stops, operating_run_step(scene.duration))


@pytest.mark.parametrize("name", ["paper", "e_motor_start", "bsg_start", "truck_compressor"])
def test_survey_speeds_are_those_of_a_plain_rigid_run(name):
    scene = load_scene(name)
    model = RigidBeltModel(scene.params)
    plant = Plant(model, scene.drive, scene.load)
    stepper = Stepper(plant, "exact", operating_run_step(scene.duration))
    time, states = stepper.run(scene.initial_state.vector("rigid", scene.params.ratio), 0.0, scene.duration)
    w = float(np.max(np.abs(states[:, 1])))
    peak = float(np.max(np.abs(model.belt_torque(states, plant.input_array(time, states)))))
    got = RigidSurvey.of_scene(scene).speeds
    # the survey also stops at a breakpoint window's start (a partial exact step) and samples its knot: the peak
    # belt torque is also read there (truck_compressor: 3e-4 higher, next to a schedule switch), the speeds move by
    # the estimate's own step error
    assert got[:2] == pytest.approx((w, w * scene.params.ratio), rel=1e-5)
    assert got[2] == pytest.approx(peak, rel=1e-3)
    assert fidelity.choose_model(scene, check_slip=False).model == fidelity.choose_model(
        scene, check_slip=False, speeds=(w, w * scene.params.ratio, peak)).model  # fmt: skip


def test_a_survey_that_diverges_probes_the_start_and_the_choice_raises():
    from belt_drive_ros.core import sources as S
    from belt_drive_ros.core.errors import SimulationDivergedError

    scene = load_scene("paper").with_overrides(drive=S.Constant(1e12), duration=1.0)
    survey = RigidSurvey.of_scene(scene)
    t_probe, plain, early, states = survey.probe_states()
    assert list(t_probe) == [0.0] and plain == [] and early == {} and list(states) == [0.0]
    with pytest.raises(SimulationDivergedError):
        survey.speeds


@pytest.mark.parametrize("given, expected", [(None, "1"), ("3", "3")])
def test_blas_runs_on_one_thread_unless_the_user_says(given, expected):
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    code = "import belt_drive_ros, os; print(os.environ['OPENBLAS_NUM_THREADS'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == expected


@pytest.mark.parametrize("name, overrides", [
    ("paper", {"method": "auto", "duration": 1.0}), ("e_motor_start", {"method": "auto"}),
    ("e_motor_start", {"model": "flexible", "method": "auto", "duration": 2.0}),
])  # fmt: skip
def test_method_auto_checks_its_choice_once_and_the_run_reports_that_check(monkeypatch, name, overrides):
    from belt_drive_ros.core import accuracy, method_choice
    from belt_drive_ros.core.model import make_model

    checks = []
    check = accuracy.check_accuracy
    for module in (accuracy, method_choice):  # the choice's checks and the run's guard (require_accurate)
        monkeypatch.setattr(module, "check_accuracy", lambda *a, **k: (checks.append((a[1], a[2])), check(*a, **k))[1])
    scene = load_scene(name).with_overrides(**overrides)
    result = simulate(scene)
    choice = result.method_choice
    assert choice.met and result.accuracy.ok
    assert len(checks) == len(set(checks)) == len(choice.tried), "each (method, step) rated once, the run's too"
    # the report is what the run's own guard would say (a fresh check, nothing shared)
    kind = result.model
    x0 = scene.initial_state.vector(kind, scene.params.ratio)
    fresh = check(Plant(make_model(kind, scene.params), scene.drive, scene.load), choice.method, choice.dt,
                  scene.duration, x0, scene.tolerance)  # fmt: skip
    assert result.accuracy == fresh


def test_a_run_within_the_capstan_limit_never_packs_the_hybrid_loop(monkeypatch):
    # paper stays within the limit: the slipping engine's first phase is the flexible model's own guarded loop,
    # and the event arrays (kernel_slip.pack) are built only from the step the stick check stops in
    from belt_drive_ros.core import kernel_slip, slip_run

    monkeypatch.setattr(slip_run, "_SHARED", {})  # (the phases an earlier test's truck run left: none, so it packs)
    packed = []
    pack = kernel_slip.pack
    monkeypatch.setattr(kernel_slip, "pack", lambda *a: (packed.append(a[1]), pack(*a))[1])
    result = simulate(load_scene("paper"))
    assert result.model == "flexible" and not result.events
    assert packed == []
    # a scene that slips packs it, once for the run and its rerun at 2 dt together (the rerun shares it)
    result = simulate(load_scene("truck_compressor").with_overrides(duration=0.8))
    assert result.model == "slipping" and result.events
    assert len(packed) == 1


def test_a_scene_that_slips_builds_its_phases_once_and_reruns_bit_for_bit(monkeypatch):
    # the slipping model, its phases' plants, their steppers (at dt and the rerun's 2 dt), the packed hybrid-loop
    # arrays and the event arrays are read-only: the run, its accuracy check's rerun and the next run of the same
    # scene share them (slip_run._shared_phases, SlippingSimulator._built); every guard still runs
    from belt_drive_ros.core import kernel_slip, slip_run

    scene = load_scene("truck_compressor").with_overrides(duration=0.8)
    first = simulate(scene)
    built, packed, steppers, loops = [], [], [], []
    monkeypatch.setattr(slip_run, "Plant", lambda *a, **k: (built.append(a[0]), Plant(*a, **k))[1])
    monkeypatch.setattr(slip_run, "Stepper", lambda *a, **k: (steppers.append(a[0]), Stepper(*a, **k))[1])
    pack = kernel_slip.pack
    monkeypatch.setattr(kernel_slip, "pack", lambda *a: (packed.append(a[1]), pack(*a))[1])
    pack_loops = slip_run.SlippingSimulator._pack
    monkeypatch.setattr(slip_run.SlippingSimulator, "_pack", lambda self, a: (loops.append(a), pack_loops(self, a))[1])
    again = simulate(scene)
    assert again.model == "slipping" and again.events == first.events and built == [] and packed == []
    assert steppers == [] and loops == [] and again.accuracy.slip_run_error == first.accuracy.slip_run_error
    assert np.array_equal(again.states, first.states) and again.accuracy == first.accuracy
    # another parameter set: its own phases
    simulate(scene.with_overrides(params=dataclasses.replace(scene.params, mu=0.45)))
    assert built and len(packed) == 1 and steppers and loops


def test_the_slipping_runs_error_from_its_outputs_is_the_one_from_its_states():
    # simulate hands slip_run_error the run's drive speed and belt torque from its outputs (computed once): the
    # same float as from the run's states
    from belt_drive_ros.core.accuracy import slip_run_error
    from belt_drive_ros.core.slip_run import SlippingSimulator

    scene = load_scene("truck_compressor").with_overrides(duration=0.8)
    sim = SlippingSimulator(scene.params, scene.drive, scene.load, "etd4", 1e-3, lazy=True)
    t, y, m, s = sim.run(scene.duration, scene.initial_state.vector("slipping", scene.params.ratio))
    out = sim.model.outputs(y, sim.input_array(t, y), m, s)
    args = (scene.params, scene.drive, scene.load, "etd4", 1e-3, t, y, m, s, [e.time for e in sim.events], None, sim._hybrid)
    error = slip_run_error(*args)
    assert error > 1e-6 and slip_run_error(*args, (out["omega_M"], out["belt_torque"])) == error


def test_the_slipping_runs_rerun_stops_at_its_last_grid_step_with_the_same_error(monkeypatch):
    # the rerun at 2 dt ends a window after the last event, off its grid: a partial step there (the Python
    # steppers) met no sample of the run, so the rerun stops at its last grid step; the same error as to the end
    from belt_drive_ros.core import accuracy
    from belt_drive_ros.core.slip_run import SlippingSimulator

    scene = load_scene("truck_compressor")
    sim = SlippingSimulator(scene.params, scene.drive, scene.load, "etd4", 1e-3, lazy=True)
    t, y, m, s = sim.run(scene.duration, scene.initial_state.vector("slipping", scene.params.ratio))
    events = [e.time for e in sim.events]
    args = (scene.params, scene.drive, scene.load, "etd4", 1e-3, t, y, m, s, events, None, sim._hybrid)
    partial = []
    steps, advance = SlippingSimulator._advance_steps, SlippingSimulator.advance
    monkeypatch.setattr(SlippingSimulator, "_advance_steps", lambda self, *a: (partial.append(a[1:3]), steps(self, *a))[1])
    error = accuracy.slip_run_error(*args)
    t1 = max(events) + accuracy.WINDOW_STEPS * 1e-3
    assert error > 1e-6 and partial == [] and t1 < t[-1]
    monkeypatch.setattr(SlippingSimulator, "advance", lambda self, state, t0, end, *a: advance(self, state, t0, t1, *a))
    assert accuracy.slip_run_error(*args) == error and len(partial) == 1  # to the end: one partial step more


def test_the_harmonic_terms_unit_responses_are_made_once_per_closed_loop(monkeypatch):
    # the harmonic term's responses to unit forcings depend on the matrices and frequencies alone: a scene run
    # again reuses them (the same report), a new step makes its own
    from belt_drive_ros.core import forced_response

    scene = load_scene("bsg_start")
    first = simulate(scene)
    calls = []
    responses = forced_response.harmonic_response_errors
    monkeypatch.setattr(forced_response, "harmonic_response_errors", lambda *a: (calls.append(a), responses(*a))[1])
    again = simulate(scene)
    assert calls == [] and again.accuracy == first.accuracy and first.accuracy.harmonic_error > 0
    forced_response._RESPONSES.clear()  # made afresh: the same figures
    assert simulate(scene).accuracy == first.accuracy and calls
    calls.clear()
    simulate(scene.with_overrides(dt=1e-4))
    assert calls


@pytest.mark.parametrize("name, method, guarded", [
    ("paper", "lawson5", False), ("e_motor_start", "etd2", False), ("truck_compressor", "etd4", False),
    ("truck_compressor", "etd4", True), ("bsg_start", "etd2", True),
])  # fmt: skip
def test_grouped_steps_between_breakpoints_are_the_clamped_steps_bit_for_bit(name, method, guarded):
    # a run with breakpoints on knots is one kernel call per group of steps between them; with a progress
    # callback the stepper takes each clamped step alone: the same states, the same stop of the guard
    from belt_drive_ros.core.slip_run import SlippingSimulator

    scene = load_scene(name)
    if guarded:  # the slipping engine's flexible stepper, whose guard (the stick check) stops at the first onset
        make = lambda: SlippingSimulator(scene.params, scene.drive, scene.load, method, scene.dt, lazy=True).stepper  # noqa: E731
        x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    else:
        model = make_model(result_model(name), scene.params)
        make = lambda: Stepper(Plant(model, scene.drive, scene.load), method, scene.dt)  # noqa: E731
        x0 = scene.initial_state.vector(model.name, scene.params.ratio)
    grouped, single = make(), make()
    assert len(grouped.breakpoints) and any(
        grouped._snap(float(b)) is not None for b in grouped.breakpoints if 0.0 < b < scene.duration
    ), "the scene has a breakpoint on a knot"
    t1, s1 = grouped.run(x0, 0.0, scene.duration)
    t2, s2 = single.run(x0, 0.0, scene.duration, progress=lambda f: None)
    assert np.array_equal(t1, t2) and np.array_equal(s1, s2)
    assert grouped.stopped == single.stopped
    if guarded:
        assert grouped.stopped is not None and len(t1) < round(scene.duration / scene.dt)


def result_model(name: str) -> str:
    return {"paper": "flexible", "e_motor_start": "rigid", "truck_compressor": "flexible"}[name]


@pytest.mark.parametrize("name", ["paper", "e_motor_start", "bsg_start"])
def test_forcing_windows_on_shared_steppers_equal_fresh_ones_bit_for_bit(monkeypatch, name):
    """The guard's window runs step on steppers shared across calls (one per plant, method and step): a verdict
    does not depend on the runs made before it (the same windows as on freshly built steppers)."""
    from belt_drive_ros.core import stepper as stepper_module
    from belt_drive_ros.core.accuracy import check_accuracy, probe_scene
    from belt_drive_ros.core.accuracy_windows import window_errors

    scene = load_scene(name)
    kind = "flexible"
    model = make_model(kind, scene.params)
    plant = stepper_module.shared_plant(model, scene.drive, scene.load)
    x0 = scene.initial_state.vector(kind, scene.params.ratio)
    probes = probe_scene(plant, scene.duration, x0, scene.dt)
    for method in ("etd2", "lawson5"):
        shared = [window_errors(plant, method, scene.dt, probes) for _ in range(2)]  # the second on used steppers
        stepper_module.shared_stepper(plant, method, scene.dt).run(x0, 0.0, 7.3 * scene.dt)  # a partial last step
        shared.append(window_errors(plant, method, scene.dt, probes))
        assert stepper_module.shared_stepper(plant, method, scene.dt) is stepper_module.shared_stepper(plant, method, scene.dt)
        monkeypatch.setattr(stepper_module, "shared_stepper", lambda p, m, dt, o=None: Stepper(p, m, dt, o))
        fresh = window_errors(plant, method, scene.dt, probes)
        monkeypatch.undo()
        for got in shared:
            assert len(got) == len(fresh) > 0
            for (t_a, e_a, p_a), (t_b, e_b, p_b) in zip(got, fresh):
                assert t_a == t_b and e_a.tobytes() == e_b.tobytes() and p_a.tobytes() == p_b.tobytes()
        report = check_accuracy(plant, method, scene.dt, scene.duration, x0, scene.tolerance, suggest=False, probes=probes)
        err, peak = np.max([e for _, e, _ in fresh], axis=0), np.max([p for _, _, p in fresh], axis=0)
        assert report.forcing_error == float(np.max(np.where(peak > 0, err / np.where(peak > 0, peak, 1.0), 0.0)))


def test_affine_of_a_long_run_is_the_per_sample_sum_bit_for_bit():
    """``model._affine`` sums a long run row-major over the samples: the same floats as the sample-by-sample form
    the node's tick uses (signed zeros, infinities and NaN included)."""
    from belt_drive_ros.core.model import _affine, _affine_sample

    rng = np.random.default_rng(7)
    for rows, cols, samples in ((12, 4, 1500), (12, 2, 700), (4, 4, 2000), (4, 2, 300), (1, 4, 900)):
        M = rng.standard_normal((rows, cols)) * rng.choice([0.0, 1.0, -1.0, 1e-3, 1e3], size=(rows, cols))
        x = rng.standard_normal((samples, cols)) * rng.choice([1.0, 1e-300, 1e300], size=(samples, cols))
        x[:5] = [-0.0, np.inf, -np.inf, np.nan, 0.0][:5][0]
        x[1, 0], x[2, -1], x[3, 0], x[4, :] = -0.0, np.inf, np.nan, -0.0
        with np.errstate(all="ignore"):
            whole = _affine(M, x)
            rows_of = tuple(zip(map(tuple, M.tolist()), ((0.0,) * 2,) * rows))
            each = np.array([_affine_sample(rows_of, list(map(float, s)), [0.0, 0.0]) for s in x])
            zero_u = _affine(np.zeros((rows, 2)), np.zeros((samples, 2)))
        assert whole.shape == (samples, rows)
        assert np.array_equal((whole + zero_u).view(np.int64), each.view(np.int64))
        stacked = x.reshape(samples // 100 if samples % 100 == 0 else 1, -1, cols)
        with np.errstate(all="ignore"):
            assert np.array_equal(_affine(M, stacked).reshape(-1, rows).view(np.int64), whole.view(np.int64))


def test_outputs_skip_the_zero_rows_of_d_bit_for_bit():
    """The outputs add one shared ``u_0 0 + u_1 0`` for the rows of D that are all +0.0 instead of a product per
    row: the same floats as ``y + _affine(D, u)``, signed zeros, infinities and NaN included (a -0.0 row: in full)."""
    from belt_drive_ros.core.model import _affine, _plus_affine

    rng = np.random.default_rng(11)
    for samples in (300, 1500):
        y = rng.standard_normal((samples, 12)) * rng.choice([0.0, -0.0, 1.0, np.inf, np.nan], size=(samples, 12),
                                                            p=[0.3, 0.3, 0.36, 0.02, 0.02])
        u = rng.standard_normal((samples, 2)) * rng.choice([0.0, -0.0, 1.0, -np.inf], size=(samples, 2))
        D = np.zeros((12, 2))
        D[8, 0], D[9, 1], D[10] = 1.0, 1.0, rng.standard_normal(2)
        for M in (D, np.where(np.arange(12)[:, None] == 3, -0.0, D)):
            with np.errstate(all="ignore"):
                assert np.array_equal(_plus_affine(y, M, u).view(np.int64), (y + _affine(M, u)).view(np.int64))


@pytest.mark.parametrize("name, duration", [("paper", 1.0), ("bsg_start", 0.1)])
def test_auto_flexible_result_is_the_same_whichever_path_runs_first(monkeypatch, name, duration):
    """``auto`` with the flexible tier runs the flexible phase alone first when the rigid survey puts the scene well
    within the capstan limit (``_may_slip`` False), else the slipping engine at once: the same result bit for bit
    either way, also when the guess is wrong (paper never slips; bsg_start slips at 25 ms)."""
    from belt_drive_ros.core import simulate as simulate_module

    scene = load_scene(name).with_overrides(duration=duration)
    results = []
    for guess in (False, True):
        monkeypatch.setattr(simulate_module, "_may_slip", lambda scene, survey, guess=guess: guess)
        results.append(simulate(scene))
    a, b = results
    assert a.model == b.model == ("flexible" if name == "paper" else "slipping")
    assert a.events == b.events and a.choice == b.choice and a.accuracy == b.accuracy
    for x, y in [(a.time, b.time), (a.states, b.states)] + [(a.outputs[k], b.outputs[k]) for k in a.outputs] + [
            (a.energy[k], b.energy[k]) for k in a.energy]:  # fmt: skip
        assert np.asarray(x).tobytes() == np.asarray(y).tobytes()


@pytest.mark.parametrize("name, overrides", [
    ("paper", {}), ("e_motor_start", {"duration": 1.0}), ("paper", {"model": "flexible", "method": "etd2", "duration": 1.0}),
])  # fmt: skip
def test_the_guard_reads_its_first_window_off_the_run(monkeypatch, name, overrides):
    """The first forcing window's run at the scene's step is the run's own first knots (the run is made inside the
    guard once it found the step stable): no run repeats them, and the report is the one a guard that runs that
    window itself gives, bit for bit."""
    from belt_drive_ros.core.accuracy import check_accuracy, probe_scene
    from belt_drive_ros.core.stepper import shared_plant

    scene = load_scene(name).with_overrides(**overrides)
    runs, run = [], Stepper.run
    monkeypatch.setattr(Stepper, "run", lambda self, x0, t0, t1, progress=None: (
        runs.append((self.dt, t0, t1)), run(self, x0, t0, t1, progress))[1])  # fmt: skip
    result = simulate(scene)
    monkeypatch.undo()
    from belt_drive_ros.core.accuracy_windows import window_span

    plant = shared_plant(make_model(result.model, scene.params), scene.drive, scene.load)
    x0 = scene.initial_state.vector(result.model, scene.params.ratio)
    probes = probe_scene(plant, scene.duration, x0, scene.dt)
    window = window_span(plant, probes, scene.dt)  # (a rigid run's are longer where a torque may repeat)
    assert (scene.dt / 2.0, 0.0, window) in runs  # the window's half-step run
    assert (scene.dt, 0.0, window) not in runs and (scene.dt, 0.0, scene.duration) in runs
    alone = check_accuracy(plant, scene.method, scene.dt, scene.duration, x0, scene.tolerance,
                           probes=probe_scene(plant, scene.duration, x0, scene.dt))  # fmt: skip
    assert repr(alone) == repr(result.accuracy)  # (etd2 at 5 ms: inaccurate, the same step named)


def test_profiles_never_periodic_at_a_steady_speed_get_no_harmonic_search(monkeypatch):
    """A motor, a polynomial load (and constants, steps, ramps) only rise, fall or hold at a steady speed: the
    harmonic search, which finds none for them, is not run (paper, e_motor_start); an engine's still is."""
    from belt_drive_ros.core.forced_response import profile_harmonics
    from belt_drive_ros.core.stepper import shared_plant

    calls = []
    monkeypatch.setattr(accuracy_probes, "profile_harmonics", lambda *a: (calls.append(a), profile_harmonics(*a))[1])
    for name in ("paper", "e_motor_start"):
        scene = load_scene(name).with_overrides(duration=1.0)
        assert simulate(scene).accuracy.harmonic_error == 0.0
        probe_times, _, _, states = RigidSurvey.of_scene(scene).probe_states()
        at = [(float(t), *states[float(t)]) for t in probe_times]
        for kind in ("rigid", "flexible"):  # what the search would have found
            assert profile_harmonics(shared_plant(make_model(kind, scene.params), scene.drive, scene.load), at) == []
    assert calls == []
    simulate(load_scene("bsg_start").with_overrides(duration=0.1))
    assert calls


@pytest.mark.parametrize("name", ["bsg_start", "truck_compressor"])
def test_phase_drift_of_all_windows_at_once_equals_each_window_alone_bit_for_bit(name):
    """The guard's angle-drift term is computed for all forcing windows in one pass (their rows one after the
    other): each window's error is the same floats as the window computed alone (no row spans two windows, the
    first-half and whole maxima are the window's own), and windows of one row carry none."""
    from belt_drive_ros.core.accuracy import probe_scene
    from belt_drive_ros.core.accuracy_windows import _phase_drifts
    from belt_drive_ros.core.stepper import shared_stepper

    scene = load_scene(name)
    model = make_model("flexible", scene.params)
    plant = stepper_module_shared_plant(model, scene)
    assert any(plant.uses_angle)  # the scenes' torques follow the crank angle
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    probes = probe_scene(plant, scene.duration, x0, scene.dt)
    coarse, fine = shared_stepper(plant, "etd2", scene.dt), shared_stepper(plant, "etd2", scene.dt / 2.0)
    rng = np.random.default_rng(3)
    windows = []
    for t0, x in probes.window_starts(plant, scene.dt):
        t1 = min(t0 + probes.span(scene.dt), probes.duration)
        tc, xc = coarse.run(x, t0, t1)
        tf, xf = fine.run(x, t0, t1)
        windows.append((xc, xf[::2], tf[::2], rng.standard_normal((tc.size, 2)) * (1.0 + tf[::2, None])))
    windows.insert(1, tuple(w[:1] for w in windows[0]))  # a window of one row
    assert len(windows) >= 3
    joined = [np.concatenate([w[k] for w in windows]) for k in range(4)]
    starts = np.cumsum([0] + [w[2].size for w in windows[:-1]])
    together = _phase_drifts(plant, starts, *joined, 4.0 / 3.0, scene.duration)
    assert 1 not in together and len(together) == len(windows) - 1
    assert any(e.max() > 0.0 for e in together.values())
    for j, w in enumerate(windows):
        alone = _phase_drifts(plant, np.array([0]), *w, 4.0 / 3.0, scene.duration)
        if j == 1:
            assert alone == {}
            continue
        assert together[j].tobytes() == alone[0].tobytes()


def stepper_module_shared_plant(model, scene):
    from belt_drive_ros.core.stepper import shared_plant

    return shared_plant(model, scene.drive, scene.load)
