"""The compiled kernel keeps results and behaviour (no timing asserts).

* ``TorqueProfile.scalar_torque()`` equals ``torque()`` on scalars and on
  arrays bit for bit (one compiled dispatcher behind all three).
* The compiled time loop (``kernel.linear_steps``) equals the numpy reference
  ``step()`` loop to rounding: 1e-11 relative to each state's peak over 0.3 s.
  The two sum the same products in another order (the kernel applies
  ``W @ stage`` as one matrix); the closed-loop truck scene amplifies a 1-ulp
  difference of the initial speed to ~1e-12, so 1e-11 is rounding, while any
  slip in the maths is >= 1e-6.
* The kernel compiles once per installed version: its number of compiled
  signatures stays fixed whatever scenes run.
* ``NUMBA_DISABLE_JIT=1`` runs the same kernel interpreted, with the same floats.
* Divergence and solver failure still surface as the package's errors.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from belt_drive_ros.core import sources as S
from belt_drive_ros.core.errors import IntegratorError, SceneError, SimulationDivergedError
from belt_drive_ros.core.integrators import FIXED_STEP_METHODS, make_integrator
from belt_drive_ros.core.kernel_loop import KernelLoop
from belt_drive_ros.core.model import make_model
from belt_drive_ros.io.scenes import load_scene
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
    S.MotorCurve(curve=((10.0, 40.0), (300.0, -5.0)), soft_start_time=0.3),
    S.Table((0.3,), (2.0,)),
    S.Table((0.0, 0.2, 0.5, 0.9), (1.0, -2.0, 3.0, 0.5)),
    S.Polynomial(1.0, 0.1, 0.01),
    S.Compressor(c1=0.1, ramp_time=0.2),
    S.Schedule(S.Compressor(), S.Constant(2.0), ((0.2, 0.4),)),
    S.Schedule(S.Compressor(), S.Constant(2.0), ((0.2, 0.4), (0.6, 0.9))),
    # past what the 2- and 4-state loops read into scalars (kernel_profiles.profile_scalars): through the dispatcher there
    S.Engine(harmonics=(15.0, 5.0, 2.0, 1.0), speed_setpoint=70.0),
    S.MotorCurve(curve=((0.0, 60.0), (100.0, 55.0), (150.0, 60.0), (314.0, 28.0), (400.0, 0.0)), soft_start_time=0.4),
    S.Schedule(S.Compressor(harmonics=(3.0,)), S.Engine(), ((0.1, 0.2), (0.3, 0.4), (0.5, 0.8))),
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
        assert got == want
    ts, angles, speeds = (np.array(c) for c in zip(*points))
    assert np.array_equal(profile.torque(ts, angles, speeds), [f(*p) for p in points])


@pytest.mark.parametrize("points", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("kind", ["motor", "table"])
def test_a_few_points_from_scalars_equal_the_table_lookup(points, kind):
    """A motor curve or linear table of up to four points is read into scalars (``kernel_profiles._points_interp``); every
    sample over arrays equals the dispatcher's table lookup (``kernel_profiles._interp``) to the last bit: at each point,
    one ulp either side, beyond both ends, at NaN and infinities. Five points: the table lookup itself."""
    from belt_drive_ros.core import kernel_profiles

    rng = np.random.default_rng(points)
    for trial in range(20):
        xs, ys = np.sort(rng.uniform(-50.0, 400.0, points)), rng.uniform(-80.0, 80.0, points)
        if kind == "motor":
            if points < 2:
                continue
            profile = S.MotorCurve(curve=tuple(zip(xs.tolist(), ys.tolist())), soft_start_time=(0.0, 1.5)[trial % 2])
        else:
            xs = np.sort(rng.uniform(0.0, 3.0, points))
            profile = S.Table(tuple(xs.tolist()), tuple(ys.tolist()))
        d = profile.data()
        near = np.concatenate([xs, np.nextafter(xs, -np.inf), np.nextafter(xs, np.inf), [np.nan, np.inf, -np.inf, 0.0, -0.0]])
        wide = np.concatenate([near, rng.uniform(-100.0, 450.0, 200)])
        t = wide if kind == "table" else rng.uniform(-0.5, 3.5, wide.size)
        speed = wide if kind == "motor" else rng.uniform(-100.0, 450.0, wide.size)
        out = np.empty(wide.size)
        kernel_profiles.profile_torque_array(d.kinds, d.params, d.tx, d.ty, t, np.zeros(wide.size), speed, out)
        one = [kernel_profiles.profile_torque(d.kinds, d.params, d.tx, d.ty, float(a), 0.0, float(w)) for a, w in zip(t, speed)]
        assert out.tobytes() == np.array(one).tobytes()


def _sample_points():
    rng = np.random.default_rng(2)
    points = [(t, a, w) for t in (-0.1, 0.0, 0.2, 0.5, 0.7, 1.0, 1.3) for a, w in ((0.0, 0.0), (1.0, 150.0), (2.0, -400.0))]
    return points + [tuple(v) for v in rng.uniform((-0.2, -300, -500), (1.2, 300, 500), size=(300, 3))]


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.kind)
def test_profiles_that_skip_the_angle_do_not_read_it(profile):
    f = profile.scalar_torque()
    for t, a, w in _sample_points():
        if not profile.uses_angle:
            assert f(t, a, w) == f(t, 0.0, w)
    if profile.kind in ("engine", "compressor"):  # crank/compressor angle: these must keep it
        assert profile.uses_angle
        assert any(f(t, a, w) != f(t, 0.0, w) for t, a, w in _sample_points())


@pytest.mark.parametrize("scene_name", ["paper", "truck_compressor", "e_motor_start"])
@pytest.mark.parametrize("model_name", ["rigid", "flexible"])
@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_compiled_loop_equals_step_loop(scene_name, model_name, method):
    scene = load_scene(scene_name)
    dt = scene.dt / 8 if method == "euler" else scene.dt  # euler: small enough to stay bounded over 0.3 s
    sim = Simulator(make_model(model_name, scene.params), scene.drive, scene.load, method, dt, check_stability=False)
    x0 = scene.initial_state.vector(model_name, scene.params.ratio)
    _, fast = sim.run(0.3, x0)
    assert sim.stepper.loop is not None
    sim.stepper.loop = None  # whole steps through integrator.step (numpy)
    _, slow = sim.run(0.3, x0)
    scale = np.max(np.abs(slow), axis=0)
    assert np.max(np.abs(fast - slow) / scale) < 1e-11


def test_simulate_uses_the_compiled_loop_and_reports_progress():
    calls = []
    result = simulate(load_scene("paper"), dt=1e-3, duration=0.5, progress=calls.append)
    assert calls[-1] == 1.0 and calls == sorted(calls) and len(calls) >= 5  # every max(64, n//100) steps


def test_divergence_in_the_compiled_loop_raises_the_package_error():
    scene = load_scene("truck_compressor")  # engine harmonics: math.sin of an exploding angle
    with pytest.raises(SimulationDivergedError, match="diverged"):
        # rk4 (euler at 2 ms now chatters at the friction limit, its event steps' partial steps taken as etd4)
        simulate(scene, method="rk4", dt=2e-3, check_stability=False)


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


def test_kernel_loop_rejects_a_scheme_of_another_shape():
    scene = load_scene("paper")
    sim = Simulator(make_model("flexible", scene.params), scene.drive, scene.load, "etd2", 1e-3)
    plant = sim.plant
    with pytest.raises(ValueError, match="final map"):
        KernelLoop(sim.integrator.stage_scheme(), 1e-3, plant.wheel_map, plant.uses_angle, *plant.data, extra=(None,))


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


class _PythonOnly(S.TorqueProfile):
    """A profile without a data form (Python only)."""

    kind = "python_only"
    state_dependent = True

    def torque(self, t, angle=0.0, speed=0.0):
        return 1.0


@pytest.mark.parametrize("method", ["etd2", "trapezoidal", "RK45"])
@pytest.mark.parametrize("as_load", [False, True])
def test_a_python_only_profile_is_refused_in_one_line(method, as_load):
    """No data form: the linear stepper refuses it (the kernel steps compiled profiles only), whatever the method."""
    scene = load_scene("paper")
    drive, load = (scene.drive, _PythonOnly()) if as_load else (_PythonOnly(), scene.load)
    with pytest.raises(SceneError, match=r"^torque profile 'python_only' has no data form .*compiled profiles only$"):
        Simulator(make_model("flexible", scene.params), drive, load, method, 1e-3)
    with pytest.raises(SceneError, match="has no data form"):
        simulate(scene.with_overrides(drive=drive, load=load), model="flexible", method=method, duration=0.1)


def test_the_kernel_compiles_once_whatever_the_scene():
    """Profiles are data: running every shipped scene and every kind of profile adds no compiled specialisation."""
    from belt_drive_ros.core import kernel, kernel_profiles
    from belt_drive_ros.core.scene import shipped_scenes

    def counts():
        loops = ("clamped_steps", "linear_steps", "_steps", "_explicit", "_explicit_wide", "wheel_steps")
        profiles = ("profile_torque", "profile_torque_at", "profile_torque_array", "scalar_at_call")
        return {name: len(getattr(module, name).signatures) for module, names in ((kernel, loops), (kernel_profiles, profiles))
                for name in names}

    simulate(load_scene("paper"), duration=0.01)
    for profile in PROFILES:
        profile.torque(0.1, 1.0, 2.0), profile.torque(np.array([0.1, 0.2]), 1.0, 2.0)
    first = counts()
    # called from Python (a run's whole steps: clamped_steps): compiled (or loaded) once; the others, called from
    # compiled code (linear_steps: also from Python, for a partial or split step), at most once
    assert {first[n] for n in ("clamped_steps", "profile_torque", "profile_torque_array")} == {1} and max(first.values()) == 1
    for name in shipped_scenes():
        scene = load_scene(name)
        simulate(scene, duration=min(scene.duration, 0.05))
    for profile in PROFILES:
        profile.torque(0.3, 2.0, 5.0)
    assert max(counts().values()) == 1
    # the state loop, one compiled copy per literal ``wide`` (2 or 4 states; 5 or 6, the slipping belt's phases)
    assert len(kernel._state_loop.signatures) <= 2


def test_the_kernel_interpreted_gives_the_same_floats(tmp_path):
    """NUMBA_DISABLE_JIT=1 runs the kernels as Python: a short closed-loop slipping scene, both ways, bit for bit."""
    import os
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from belt_drive_ros.core.simulate import simulate\n"
        "from belt_drive_ros.io.scenes import load_scene\n"
        "r = simulate(load_scene('truck_compressor'), duration=0.05)\n"
        "np.save(sys.argv[1], r.states)\n"
    )
    states = {}
    for jit in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=jit)
        path = tmp_path / f"states_{jit}.npy"
        done = subprocess.run([sys.executable, "-c", code, str(path)], env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        states[jit] = np.load(path)
    assert states["0"].shape == states["1"].shape and len(states["0"]) > 10
    assert np.array_equal(states["0"], states["1"])


def _general_loop(loop, times, x, out):
    """The kernel's general loop (``kernel.wheel_steps``) interpreted on a :class:`KernelLoop`'s arrays.

    Its helpers run interpreted too (each compiled function of the kernel module and of the profiles' module it
    calls, ``kernel_profiles``, swapped for its Python function during the call): called from Python, a helper
    compiled again for Python's argument types, ~20 s of CPU in every fresh clone's suite. Interpreted and compiled
    give the same floats (``test_the_kernel_interpreted_gives_the_same_floats``). No compiled function gains a
    specialisation here (before, the profiles' helpers did: ``_row_scalars``, ``motor_line``, ``polynomial``, ...
    were compiled, once ``kernel_profiles`` was split from ``kernel``)."""
    from numba.core.registry import CPUDispatcher

    from belt_drive_ros.core import kernel, kernel_profiles

    modules = (kernel, kernel_profiles)
    compiled = {(m.__name__, name): value for m in modules for name, value in list(vars(m).items())
                if isinstance(value, CPUDispatcher)}
    before = {key: len(value.signatures) for key, value in compiled.items()}
    with pytest.MonkeyPatch.context() as mp:
        for (module, name), value in compiled.items():
            if name != "wheel_steps":
                mp.setattr(sys.modules[module], name, value.py_func)
        done = _wheel_steps_interpreted(kernel, loop, times, x, out)
    assert {key: len(value.signatures) for key, value in compiled.items()} == before
    return done


def _wheel_steps_interpreted(kernel, loop, times, x, out):
    ints, reals = loop.ints, loop.reals
    n, s, E, rows, cols = (int(v) for v in ints[:5])
    at = ints[kernel.HEADER : kernel.HEADER + len(kernel.SECTIONS) + 1]
    k0 = kernel.HEADER + len(kernel.SECTIONS) + 1
    nd = loop._dp.shape[0]
    part = dict(zip(kernel.SECTIONS, (reals[a:b] for a, b in zip(at[:-1], at[1:]))))
    return kernel.wheel_steps.py_func(
        times, x, out, -math.inf, math.inf, 1.0e5, part["W"].reshape((1, 4, n)), ints[k0 : k0 + s], part["offsets"],
        part["S"].reshape((s, rows, cols)), part["F"].reshape((1, n, cols)), int(ints[5]), float(part["tol"][0]),
        int(ints[6]), ints[7:9].copy(), np.zeros(2, dtype=np.int64), ints[k0 + s : k0 + s + nd], loop._dp, part["dx"], part["dy"],
        ints[k0 + s + nd :], loop._lp, part["lx"], part["ly"], part["extra"].reshape((E, 5)), part["guard"],
    )  # fmt: skip


@pytest.mark.parametrize("model_name", ["rigid", "flexible"])
@pytest.mark.parametrize("method", [m for m in FIXED_STEP_METHODS if m != "trapezoidal"])
@pytest.mark.parametrize("case", ["paper", "truck_compressor", "friction+guard"])
def test_the_scalar_state_loops_equal_the_general_loop_bit_for_bit(method, case, model_name):
    """A 2-state (rigid) or 4-state (flexible) plant with an explicit method steps with its state in scalars
    (``kernel._explicit``): the same sums in the same order as the general loop, so the same floats, to the last
    bit; the guard stops at the same step. ``friction+guard``: the slipping belt's extra input (drive-speed
    dependent) and a guard."""
    from belt_drive_ros.core.kernel_loop import FrictionForce
    from belt_drive_ros.core.stage_scheme import Guard

    scene = load_scene("paper" if case != "truck_compressor" else "truck_compressor")
    model = make_model(model_name, scene.params)
    sim = Simulator(model, scene.drive, scene.load, method, scene.dt, check_stability=False)
    plant, extra, guard, scheme = sim.plant, (), None, sim.integrator.scheme
    if case == "friction+guard":  # a third input column: a force on the drive wheel, as the slipping belt's
        extra = (FrictionForce(0.7, scene.params),)
        B = np.hstack([model.B, 1e-3 * model.B[:, :1]])
        scheme = make_integrator(method, model.A, B, scene.dt).scheme
    steps, n = 300, model.A.shape[0]
    times = scene.dt * np.arange(steps + 1, dtype=float)
    x0 = np.ascontiguousarray(scene.initial_state.vector(model_name, scene.params.ratio), dtype=float)
    x0[n // 2] += 1.0  # omega_M: moving from the first step
    if case == "friction+guard":  # a bound the run's |x_1| + 1e-4 omega_M^2 first passes in its second half
        free = np.zeros((steps, n))
        KernelLoop(scheme, scene.dt, plant.wheel_map, plant.uses_angle, *plant.data, extra)(times, x0.copy(), free)
        g = np.abs(free[:, 1]) + 1e-4 * free[:, n // 2] ** 2
        row, speed = np.eye(n)[1], np.eye(n)[n // 2]
        guard = Guard(row=tuple(row), bound=float(np.max(g[: steps // 2])), absolute=True, speed=tuple(speed), quad=1e-4)
    loop = KernelLoop(scheme, scene.dt, plant.wheel_map, plant.uses_angle, *plant.data, extra, guard)
    fast, slow = np.zeros((steps, n)), np.zeros((steps, n))
    done_fast = loop(times, x0.copy(), fast)
    done_slow = _general_loop(loop, times, x0.copy(), slow)
    assert done_fast == done_slow
    assert done_fast[0] > 10
    if case == "friction+guard":
        assert done_fast[1] == 2, "the guard stops this run (else the test would not cover it)"
    assert np.array_equal(fast, slow)


SLIP_PHASES = [("truck_compressor", ("slip", 1.0)), ("truck_compressor", ("slip", -1.0)), ("bsg_start", ("mass", 1.0)),
               ("bsg_start", ("mass", -1.0))]


@pytest.mark.parametrize("guarded", [False, True], ids=["free", "guard"])
@pytest.mark.parametrize("method", ["exact", "etd2", "etd4", "lawson5", "euler", "rk4"])
@pytest.mark.parametrize("scene_name, phase", SLIP_PHASES, ids=["slip6+", "slip6-", "mass5+", "mass5-"])
def test_the_slip_phases_scalar_state_loop_equals_the_general_loop_bit_for_bit(scene_name, phase, method, guarded):
    """The slipping belt's phases: a massless belt's slip mode (6 states, the slip force a constant state) and a
    belt with mass's (5 states, the slip force an input of the drive speed) step with their state in scalars too
    (``kernel._explicit_wide``): the general loop's floats to the last bit, its divergence test and guard."""
    from belt_drive_ros.core.slip_run import SlippingSimulator
    from belt_drive_ros.core.stage_scheme import Guard

    scene = load_scene(scene_name)
    dt = 5e-5  # (stable for every method here: euler's and rk4's bounds are below the scenes' own steps)
    st = SlippingSimulator(scene.params, scene.drive, scene.load, method, dt, check_stability=False).phase_stepper(phase)
    n = st.plant.model.A.shape[0]
    assert n == (6 if phase[0] == "slip" else 5) and st.loop is not None
    steps = 200
    times = dt * np.arange(steps + 1, dtype=float)
    x0 = np.zeros(n)
    x0[2:5] = (40.0, 38.0, 0.3) if n == 6 else (40.0, 38.0, 15.0)
    if n == 6:
        x0[5] = 0.8 * phase[1] * 2.0 * scene.params.F_0 * scene.params.r_3  # the slip force's torque (a state)
    guard = None
    if guarded:  # a bound the run's |x_0| + 1e-4 x_3^2 (x_0: the drive's angle, turning) first passes in its second half
        free = np.zeros((steps, n))
        st.plant.kernel_loop(st.integrator)(times, x0.copy(), free)
        g = np.abs(free[:, 0]) + 1e-4 * free[:, 3] ** 2
        row, speed = np.eye(n)[0], np.eye(n)[3]
        guard = Guard(row=tuple(row), bound=float(np.max(g[: steps // 2])), absolute=True, speed=tuple(speed), quad=1e-4)
    loop = st.plant.kernel_loop(st.integrator, guard)
    fast, slow = np.zeros((steps, n)), np.zeros((steps, n))
    done_fast = loop(times, x0.copy(), fast)
    done_slow = _general_loop(loop, times, x0.copy(), slow)
    assert done_fast == done_slow
    assert done_fast[0] > 10
    if guarded:
        assert done_fast[1] == 2, "the guard stops this run (else the test would not cover it)"
    assert np.ptp(slow[: done_slow[0]], axis=0).min() > 0.0 or n == 6  # every state moves (the 6th: Q' = 0)
    assert np.array_equal(fast, slow)


NESTED = S.Schedule(S.Schedule(S.Compressor(), S.Constant(1.0), ((0.3, 0.5),)), S.Table((0.0, 1.0), (2.0, 0.5)), ((0.2, 0.7),))


@pytest.mark.parametrize("model_name, method", [("flexible", "exact"), ("flexible", "etd4"), ("rigid", "etd2"), ("rigid", "etd4")])
@pytest.mark.parametrize("profile", PROFILES + [NESTED], ids=lambda p: p.kind)
def test_every_profile_kind_steps_alike_in_the_scalar_state_loops_and_the_general_loop(profile, method, model_name):
    """The 2- and 4-state loops evaluate a one-row formula profile (constant, step, ramp, sine, motor line,
    polynomial), an engine or compressor of up to three harmonics and a schedule of up to two periods of those from
    numbers read once per call, and every other kind (nested schedules too) from its data: each
    kind, on the drive and on the load, gives the general loop's floats to the last bit (across the profiles'
    breakpoints, no clamp)."""
    scene = load_scene("paper")
    model = make_model(model_name, scene.params)
    integrator = make_integrator(method, model.A, model.B, 5e-3)
    steps = 200  # 1 s: past every breakpoint of PROFILES
    times = 5e-3 * np.arange(steps + 1, dtype=float)
    i = scene.params.ratio
    x0 = np.array([0.0, 0.0, 20.0, 20.0 * i]) if model_name == "flexible" else np.array([0.0, 20.0])
    n = x0.size
    for drive, load in ((profile, scene.load), (scene.drive, profile)):
        loop = KernelLoop(integrator.scheme, 5e-3, model.wheel_map, (drive.uses_angle, load.uses_angle), drive.data(), load.data())
        fast, slow = np.zeros((steps, n)), np.zeros((steps, n))
        done_fast = loop(times, x0.copy(), fast)
        done_slow = _general_loop(loop, times, x0.copy(), slow)
        assert done_fast == done_slow and done_fast[0] > 10  # a polynomial drive runs away: both stop alike
        assert np.array_equal(fast, slow)


def test_a_guard_on_a_trapezoidal_stage_that_cannot_converge_says_so_not_unstable():
    """trapezoidal is A-stable: where its guard's maps fail (max_iter 2 sweeps cannot reach tol), the verdict is the
    iteration's, with what to change (before: "UNSTABLE ... growth/step inf"). The same scene at the default 50 sweeps
    then passes in the same process (the guard's verdict cache had no key for the options: it gave 50 the verdict of 2)."""
    from belt_drive_ros.core.errors import UnstableStepError

    scene = load_scene("paper").with_overrides(duration=0.5, method="trapezoidal", method_options={"max_iter": 2})
    with pytest.raises(UnstableStepError, match=r"trapezoidal at dt=0\.005 s on the closed loop: NOT CONVERGED \(the "
                       r"implicit stage's fixed-point iteration .* raise max_iter, loosen tol or reduce dt; estimated"):
        simulate(scene)
    assert simulate(scene.with_overrides(method_options={"max_iter": 50})).accuracy.stable
