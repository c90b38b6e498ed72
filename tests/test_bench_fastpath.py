"""The speed work behind the benchmarks keeps results and behaviour (no timing asserts).

* ``TorqueProfile.scalar_torque()`` equals ``torque()`` on scalars: 1e-13
  relative (same formulas, ``math`` for numpy; measured: bit-identical).
* The compiled float loop (``compile_scalar_loop``) equals the numpy
  ``step()`` loop to rounding: 1e-11 relative to each state's peak over 0.3 s.
  The two sum the same products in another order; the closed-loop truck
  scene amplifies a 1-ulp difference of the initial speed to ~1e-12, so
  1e-11 is rounding, while any slip in the maths is >= 1e-6.
* Divergence and solver failure still surface as the package's errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from belt_drive_ros.core import sources as S
from belt_drive_ros.core.errors import IntegratorError, SimulationDivergedError
from belt_drive_ros.core.formula import SCALAR_PRIMITIVES, render
from belt_drive_ros.core.integrators import FIXED_STEP_METHODS, compile_scalar_loop
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.scene import load_scene
from belt_drive_ros.core.simulate import Simulator, simulate

PROFILES = [
    S.Constant(3.0),
    S.Step(1.0, 2.0, 0.5),
    S.Ramp(0.0, 5.0, 0.2, 0.7),
    S.Sine(1.0, 2.0, 3.0, 0.4),
    S.Table((0.0, 0.5, 1.0), (1.0, 3.0, 2.0)),
    S.Table((0.0, 0.5, 1.0), (1.0, 3.0, 2.0), "previous"),
    S.Engine(),
    S.Engine(speed_setpoint=70.0, governor_gain=3.0, max_torque=50.0, ramp_time=0.3),
    S.MotorCurve(soft_start_time=0.5),
    S.MotorCurve(curve=((0.0, 60.0), (150.0, 60.0), (314.0, 28.0), (400.0, 0.0))),
    S.Polynomial(1.0, 0.1, 0.01),
    S.Compressor(c1=0.1, ramp_time=0.2),
    S.Schedule(S.Compressor(), S.Constant(2.0), ((0.2, 0.4),)),
    S.Schedule(S.Compressor(), S.Constant(2.0), ((0.2, 0.4), (0.6, 0.9))),
]


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.kind)
def test_scalar_torque_equals_torque(profile):
    f = profile.scalar_torque()
    rng = np.random.default_rng(1)
    points = [(t, a, w) for t in (0.0, 0.2, 0.5, 0.7, 1.0, 1.3) for a, w in ((0.0, 0.0), (1.0, 150.0), (2.0, 400.0))]
    points += [tuple(v) for v in rng.uniform((-0.2, -300, -500), (1.2, 300, 500), size=(300, 3))]
    for t, a, w in points:
        got, want = f(t, a, w), profile.torque(t, a, w)
        assert isinstance(got, float)
        assert got == pytest.approx(want, rel=1e-13, abs=1e-13)


def _sample_points():
    rng = np.random.default_rng(2)
    points = [(t, a, w) for t in (-0.1, 0.0, 0.2, 0.5, 0.7, 1.0, 1.3) for a, w in ((0.0, 0.0), (1.0, 150.0), (2.0, -400.0))]
    return points + [tuple(v) for v in rng.uniform((-0.2, -300, -500), (1.2, 300, 500), size=(300, 3))]


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.kind)
def test_inlined_source_is_bitwise_the_closure(profile):
    """The formula text as the loops inline it (other names, prefixed bindings) computes exactly the closure."""
    formula = profile.formula()
    assert formula is not None  # every shipped profile is written as one formula
    source, bindings = render(formula, "tt", "aa", "ww", prefix="d_")
    assert all(name.startswith("d_") for name in bindings)
    expression = compile(source, "<source>", "eval")
    f = profile.scalar_torque()
    for t, a, w in _sample_points():
        assert eval(expression, {**SCALAR_PRIMITIVES, **bindings}, {"tt": t, "aa": a, "ww": w}) == f(t, a, w)


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.kind)
def test_profiles_that_skip_the_angle_do_not_read_it(profile):
    f = profile.scalar_torque()
    for t, a, w in _sample_points():
        if not profile.uses_angle:
            assert f(t, a, w) == f(t, 0.0, w)
    if profile.kind in ("engine", "compressor"):  # crank/compressor angle: these must keep it
        assert profile.uses_angle
        assert any(f(t, a, w) != f(t, 0.0, w) for t, a, w in _sample_points())


@pytest.mark.parametrize("scene_name", ["paper", "e_motor_start"])
@pytest.mark.parametrize("method", ["etd4", "lawson5", "etd2", "rk4", "trapezoidal"])
def test_loop_with_inlined_torques_and_speed_only_stages_equals_the_call_loop(scene_name, method):
    """Inlining and skipping unused angles change no torque value: the states agree to rounding of W @ stage."""
    scene = load_scene(scene_name)
    model = make_model("flexible", scene.params)
    sim = Simulator(model, scene.drive, scene.load, method, scene.dt)
    plant = sim.plant
    assert plant.uses_angle == (False, False)  # motor curve and polynomial/compressor-free loads
    fast = sim.integrator.scalar_loop(plant.wheel_map, plant.uses_angle, plant.formulas)
    plain = sim.integrator.scalar_loop(plant.wheel_map)
    for name in ("drive(", "load("):  # every shipped profile has a formula: inlined, never called
        assert name not in fast.__source__ and name in plain.__source__
    assert scene_name != "paper" or "drive(" not in fast.__source__  # paper: linear motor line, inlined
    times = (scene.dt * np.arange(400)).tolist()
    x0 = tuple(scene.initial_state.vector("flexible", scene.params.ratio).tolist())
    a = np.array(fast(times, x0, plant.scalar_drive, plant.scalar_load, 1e5))
    b = np.array(plain(times, x0, plant.scalar_drive, plant.scalar_load, 1e5))
    assert a.shape == b.shape
    assert np.max(np.abs(a - b)) <= 1e-11 * np.max(np.abs(b))


@pytest.mark.parametrize("scene_name", ["paper", "truck_compressor", "e_motor_start"])
@pytest.mark.parametrize("model_name", ["rigid", "flexible"])
@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_compiled_loop_equals_step_loop(scene_name, model_name, method):
    scene = load_scene(scene_name)
    dt = scene.dt / 8 if method == "euler" else scene.dt  # euler: small enough to stay bounded over 0.3 s
    sim = Simulator(make_model(model_name, scene.params), scene.drive, scene.load, method, dt, check_stability=False)
    x0 = scene.initial_state.vector(model_name, scene.params.ratio)
    _, fast = sim.run(0.3, x0, vectorize=False)
    assert sim.stepper.loop is not None
    sim.stepper.loop = None  # whole steps through integrator.step (numpy)
    _, slow = sim.run(0.3, x0, vectorize=False)
    scale = np.max(np.abs(slow), axis=0)
    assert np.max(np.abs(fast - slow) / scale) < 1e-11


def test_simulate_uses_the_compiled_loop_and_reports_progress():
    calls = []
    result = simulate(load_scene("paper"), dt=1e-3, duration=0.5, progress=calls.append)
    assert not result.vectorized
    assert calls[-1] == 1.0 and calls == sorted(calls) and len(calls) >= 5  # every max(64, n//100) steps


def test_generated_source_is_inspectable_and_drops_zero_coefficients():
    scene = load_scene("paper")
    model = make_model("rigid", scene.params)
    sim = Simulator(model, scene.drive, scene.load, "exact", 1e-3)
    loop = sim.integrator.scalar_loop(sim.plant.wheel_map)
    assert "def loop(" in loop.__source__ and "drive(t, x0, x1)" in loop.__source__
    # rigid: the angle row of Phi is [1, h]; x0 appears with coefficient 1 and no torque term multiplied by 0
    assert "0.0 * " not in loop.__source__


def test_divergence_in_the_compiled_loop_raises_the_package_error():
    scene = load_scene("truck_compressor")  # engine harmonics: math.sin of an exploding angle
    with pytest.raises(SimulationDivergedError, match="diverged"):
        simulate(scene, method="euler", dt=2e-3, check_stability=False)


def test_trapezoidal_non_convergence_keeps_its_message():
    scene = load_scene("paper").with_overrides(load=S.Polynomial(c1=2000.0))  # stiff feedback: no fixed point
    with pytest.raises(IntegratorError, match="did not converge"):
        simulate(scene, model="flexible", method="trapezoidal", dt=1e-3, duration=0.05, check_stability=False)


def test_wheel_map_of_both_models():
    scene = load_scene("paper")
    i = scene.params.ratio
    sim = Simulator(make_model("rigid", scene.params), scene.drive, scene.load, "etd2", 1e-3)
    np.testing.assert_allclose(sim.plant.wheel_map, [[1, 0], [0, 1], [i, 0], [0, i]])
    sim = Simulator(make_model("flexible", scene.params), scene.drive, scene.load, "etd2", 1e-3)
    np.testing.assert_allclose(sim.plant.wheel_map, [[1, 0, 0, 0], [0, 0, 1, 0], [i, -1, 0, 0], [0, 0, 0, 1]])  # phi_3 = i phi_M - theta


def test_compile_rejects_a_plant_it_cannot_inline():
    scene = load_scene("paper")
    model = make_model("flexible", scene.params)
    sim = Simulator(model, scene.drive, scene.load, "etd2", 1e-3)
    with pytest.raises(IntegratorError):
        compile_scalar_loop(sim.integrator.stage_scheme(), np.eye(4)[:3], 1e-3)


def test_adaptive_solver_continues_across_output_steps():
    # the grid t0 + k dt and the sum t + dt differ by rounding: still one solver, not one restart per output
    scene = load_scene("paper").with_overrides(method_options={"rtol": 1e-6, "atol": 1e-9})
    model = make_model("flexible", scene.params)
    sim = Simulator(model, scene.drive, scene.load, "RK45", 1e-3, scene.method_options)
    sim.run(1.0, np.zeros(4))
    assert sim.integrator.n_rhs < 2000  # measured ~700; one restart per output would be >= 6000


def test_lsoda_through_the_registry_starts_from_rest():
    # rhs = 0 at t = 0 (soft start from rest): LSODA with t_bound = inf jumped to t = inf and returned NaN
    result = simulate(load_scene("paper"), method="LSODA", duration=0.5)
    assert np.all(np.isfinite(result.states)) and result.states[-1, 2] > 1.0


class _Exploding(S.TorqueProfile):
    """A profile without a formula (the loop calls it) that fails at t >= 0.0735 s: a traceback through the loop."""

    kind = "exploding"
    state_dependent = True

    def torque(self, t, angle=0.0, speed=0.0):
        if t >= 0.0735:
            raise RuntimeError("torque sensor failed")
        return 1.0


@pytest.mark.parametrize("method", ["etd2", "trapezoidal"])
def test_traceback_through_a_generated_loop_shows_its_source_lines(method):
    """Generated loops are in linecache: a traceback names the loop and prints the line that called the torque."""
    import traceback

    scene = load_scene("paper")
    sim = Simulator(make_model("flexible", scene.params), _Exploding(), scene.load, method, 1e-3)
    with pytest.raises(RuntimeError) as info:
        sim.run(0.1, np.zeros(4))
    frames = [f for f in traceback.extract_tb(info.value.__traceback__) if f.filename.startswith(f"<{method} scalar loop")]
    assert len(frames) == 1
    line = frames[0].line
    assert line.startswith("u") and "= drive(" in line  # the generated statement, e.g. u1_0 = drive(t1, ...)
    loop = sim.integrator.scalar_loop(sim.plant.wheel_map, sim.plant.uses_angle, sim.plant.formulas)
    assert line == loop.__source__.splitlines()[frames[0].lineno - 1].strip()
    assert "= drive(" in "".join(traceback.format_exception(info.value))


def test_traceback_through_a_formula_closure_shows_its_text():
    import traceback

    profile = S.Table((0.0, 1.0), (1.0, 2.0))
    f = profile.scalar_torque()
    with pytest.raises(TypeError) as info:
        f("not a time", 0.0, 0.0)
    text = "".join(traceback.format_exception(info.value))
    assert "return interp(t, times, values)" in text
