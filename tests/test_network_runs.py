"""Belt networks' runs: the compiled loop, its tiers and methods, ``model: auto``, the kernel interpreted, and the
run's hostile arguments (the scene helpers are tests/test_network.py's)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from belt_drive_ros.core.errors import SceneError
from belt_drive_ros.core.network.model import NetworkModel, modes
from belt_drive_ros.core.network.simulate import simulate
from belt_drive_ros.core.network.scene import NetworkScene
from belt_drive_ros.io.scenes import load_network
from test_network import _paper_network_raw, _pulley, _raw_tensioned, _scene


# ---------------------------------------------------------------------- the compiled loop, tiers and auto
def test_paper_drive_as_a_network_equals_the_paper_model_to_1e12_of_peak():
    """The network's lag coordinates (l_i = rho_i theta_d - theta_i) are the paper's relative deflection for
    every pulley: the run keeps the stretch's digits (absolute pulley angles gave 2e-11 of the belt torque)."""
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.core.simulate import simulate as simulate_paper

    paper = load_scene("paper")
    g = paper.params.gear_ratio
    for method in ("etd2", "exact", "etd4"):
        today = simulate_paper(paper, model="flexible", method=method, dt=1e-3)
        net = simulate(load_network("paper_network"), model="flexible", method=method, dt=1e-3)
        for ours, theirs in ((net.speed[:, 1], today["omega_3"]), (net.speed[:, 0], g * today["omega_M"]),
                             (net.belt_torque[:, 1], today["belt_torque"])):
            assert np.max(np.abs(ours - theirs)) <= 1e-12 * np.max(np.abs(theirs))  # 9e-14 measured (etd2)


def _stiff(EA):
    data = _raw_tensioned()
    data["belt"].update(EA=EA, damping=EA * 2e-4)
    data["tensioner"]["damping"] = 0.5
    data["pulleys"][0]["torque"] = {"type": "ramp", "start_value": 0.0, "end_value": 6.0, "start_time": 0.0,
                                    "end_time": 0.2}
    data["pulleys"][2]["torque"] = {"type": "polynomial", "c0": 0.5, "c1": 0.01}
    data.update(duration=0.3, dt=1e-4, initial_speed=20.0, method="exact")
    return NetworkScene.from_mapping(data)


def test_rigid_tier_is_the_limit_of_a_stiff_belt():
    """Speeds and quasi-static span tensions of the rigid tier against the flexible tier with a belt 7500x stiffer."""
    scene = _stiff(9e8)
    rigid = simulate(scene, model="rigid")
    flexible = simulate(scene, model="flexible", method="exact")
    assert rigid.tier == "rigid" and flexible.tier == "flexible"
    half = len(rigid.time) // 2  # after the start-up transient of the stiff spans (the run starts unstretched)
    assert np.max(np.abs(rigid.speed[half:] - flexible.speed[half:])) <= 1e-6 * np.max(np.abs(flexible.speed))
    change = np.max(np.abs(flexible.tension[half:] - 300.0))
    assert change > 5.0  # the loads did change the tensions
    assert np.max(np.abs(rigid.tension[half:] - flexible.tension[half:])) <= 2e-3 * change
    soft = simulate(_stiff(1.2e5), model="flexible", method="exact")  # a real belt rings: the limit does not hold
    assert np.max(np.abs(rigid.tension[half:] - soft.tension[half:])) > 10 * np.max(np.abs(rigid.tension[half:] - flexible.tension[half:]))


def test_every_fixed_step_method_runs_the_network_and_converges_to_exact():
    from belt_drive_ros.core.integrators import REGISTRY

    scene = load_network("fead_i4")
    ref = simulate(scene, duration=0.05, dt=5e-6, method="etd4", model="flexible", check_accuracy=False)
    scale = np.max(np.abs(ref.tension - 300.0))
    fixed = [name for name, cls in REGISTRY.items() if cls.fixed_step]
    assert {"exact", "etd2", "etd4", "lawson5", "rk4", "trapezoidal"} <= set(fixed)
    for name in fixed:
        stride = 10 if (REGISTRY[name].order or 1) >= 2 else 1  # first-order explicit methods: inside their bound
        run = simulate(scene, duration=0.05, dt=5e-6 * stride, method=name, model="flexible")
        err = np.max(np.abs(run.tension - ref.tension[::stride])) / scale
        assert run.method == name and err < 3e-2, (name, err)
        if REGISTRY[name].order and REGISTRY[name].order >= 2:
            assert err < 5e-3, (name, err)  # trapezoidal 1.6e-3, the others below 1e-4
            est = float(run.accuracy.split("error ")[1].split(" N")[0])  # the guard's step-doubling estimate
            if err > 1e-6:  # above the reference's own error
                assert 0.3 <= est / (err * scale) <= 3.0, (name, est, err * scale)
            assert run.accuracy.startswith("accurate" if err < 1e-3 else "INACCURATE")
    with pytest.raises(SceneError, match="fixed-step method"):
        simulate(scene, duration=0.01, method="RK45", model="flexible")


def test_the_accuracy_guard_estimates_the_error_and_names_a_step():
    scene = load_network("fead_i4")
    coarse = simulate(scene, duration=0.3, dt=4e-3, method="etd2", model="flexible")
    assert coarse.accuracy.startswith("INACCURATE") and "dt <= " in coarse.accuracy
    ref = simulate(scene, duration=0.3, dt=1e-5, method="etd4", model="flexible", check_accuracy=False)
    est = float(coarse.accuracy.split("error ")[1].split(" N")[0])
    true = np.max(np.abs(coarse.tension - ref.tension[::400]))
    assert 0.3 * true <= est <= 3.0 * true  # Richardson's estimate within a factor 3 of the true error


@pytest.mark.parametrize("steps", [1, 2, 3])
def test_a_run_of_fewer_than_four_steps_is_checked_too(steps):
    """One to three steps (dt a large part of the duration): step doubling at 2 dt has nothing to compare, so the
    guard compares with dt / 2; such a run is far off and says so (before: no verdict at all, the run unchecked)."""
    scene = load_network("paper_network")
    run = simulate(scene, duration=0.5, dt=0.5 / steps, method="etd2", model="flexible")
    assert run.accuracy.startswith("INACCURATE") and "dt <= " in run.accuracy
    fine = simulate(scene, duration=0.5, dt=1e-3, method="etd2", model="flexible")
    assert fine.accuracy.startswith("accurate")


def test_auto_names_the_pulley(monkeypatch):
    import belt_drive_ros.core.network.simulate as network

    fead = simulate(load_network("fead_i4"), duration=0.05)
    assert fead.tier == "flexible" and fead.reason.startswith("flexible: crank's engine")
    quiet = simulate(NetworkScene.from_mapping({**_raw_tensioned(), "duration": 0.05, "dt": 1e-4, "initial_speed": 10.0}))
    assert quiet.tier == "rigid" and "nothing excites it" in quiet.reason
    raw = _paper_network_raw()
    raw["pulleys"][1]["mu"] = 0.02  # a greasy pulley 3: the run-up's torque passes its limit
    greasy = NetworkScene.from_mapping(raw)
    seen = []

    def slipping(model, duration, dt, method=None):
        seen.append((model.scene.name, duration, dt))
        return simulate(greasy, duration=duration, dt=dt, model="flexible")

    monkeypatch.setattr(network, "run_slipping", slipping)
    run = simulate(greasy, duration=0.5)
    onset = simulate(greasy, duration=0.5, model="flexible").capstan_onset(greasy)
    assert run.tier == "slipping" and seen == [(greasy.name, 0.5, 1e-3)]
    assert run.reason == f"slipping: pulley_3 reaches the capstan limit at t = {onset[1]:.6g} s (in the flexible tier's run)"


def test_stacked_profiles_evaluate_as_each_profile_alone():
    from numba.core.registry import CPUDispatcher

    from belt_drive_ros.core import kernel_profiles
    from belt_drive_ros.core.profile_data import stack
    from belt_drive_ros.core.sources import make_profile

    profiles = [make_profile(spec, "t") for spec in (
        {"type": "table", "times": [0.0, 0.5, 1.0], "values": [1.0, 3.0, 2.0]},
        {"type": "engine", "cylinders": 4, "strokes": 4, "mean_torque": 10.0, "harmonics": [3.0, 1.0]},
        {"type": "schedule", "periods": [[0.2, 0.4]], "active": {"type": "table", "times": [0.0, 1.0], "values": [0.0, 5.0]},
         "inactive": 2.0},
        {"type": "motor", "curve": [[0.0, 20.0], [50.0, 15.0], [100.0, 0.0]]},
    )]
    data, start = stack([p.data() for p in profiles])
    alone = {(t, p): profile.torque(t, 1.3, 40.0) for t in (0.1, 0.3, 0.7) for p, profile in enumerate(profiles)}
    # the stacked evaluation interpreted, its helpers too: called from Python, the compiled one (inlined in the
    # network loops) would compile again for Python's argument types in every fresh clone; the same floats
    with pytest.MonkeyPatch.context() as mp:
        for name, value in list(vars(kernel_profiles).items()):
            if isinstance(value, CPUDispatcher):
                mp.setattr(kernel_profiles, name, value.py_func)
        for (t, p), torque in alone.items():
            assert kernel_profiles.profile_torque_at(data.kinds, data.params, data.tx, data.ty, int(start[p]), t, 1.3, 40.0) == torque


def test_the_network_kernel_compiles_once_and_interpreted_gives_the_same_floats(tmp_path):
    import os
    import subprocess
    import sys

    from belt_drive_ros.core import kernel
    from belt_drive_ros.io.scenes import shipped_networks

    for name in shipped_networks():
        for method in ("exact", "etd2", "rk4", "trapezoidal"):
            for tier in ("flexible", "rigid"):
                try:
                    simulate(load_network(name), duration=0.01, dt=1e-4, method=method, model=tier, check_accuracy=False)
                except Exception:  # noqa: BLE001 - a refused step is fine here: only the signatures count
                    pass
    assert len(kernel.wheel_steps.signatures) == 1  # the linear drive's loop: one compiled signature for both
    code = ("import sys, numpy as np\n"
            "from belt_drive_ros.core.network.simulate import simulate\n"
            "from belt_drive_ros.io.scenes import load_network\n"
            "r = simulate(load_network('fead_i4'), duration=0.02, method=sys.argv[2], model='flexible', check_accuracy=False)\n"
            "np.save(sys.argv[1], np.column_stack([r.states, r.tension]))\n")
    for method in ("etd2", "trapezoidal"):
        states = {}
        for jit in ("0", "1"):
            path = tmp_path / f"{method}_{jit}.npy"
            done = subprocess.run([sys.executable, "-c", code, str(path), method], env=dict(os.environ, NUMBA_DISABLE_JIT=jit),
                                  capture_output=True, text=True, timeout=600)
            assert done.returncode == 0, done.stderr
            states[jit] = np.load(path)
        assert states["0"].shape[0] == 21 and np.array_equal(states["0"], states["1"])


def test_advancing_tick_by_tick_equals_the_whole_run_bit_for_bit():
    """The node's way (advance a few steps per tick, across the engine's ramp breakpoint at 0.1 s) is the run's way."""
    from belt_drive_ros.core.network.simulate import NetworkLoop, advance, model_of

    scene = load_network("fead_i4")
    whole = simulate(scene, duration=0.15, model="flexible", check_accuracy=False)
    loop = NetworkLoop(model_of(scene), "flexible", scene.method, scene.dt)
    x = loop.initial()
    states = [x]
    for k0 in range(0, 150, 7):
        k1 = min(k0 + 7, 150)
        out = np.empty((k1 - k0, x.size))
        advance(loop, x, out, k0, k1)
        x = out[-1]
        states.extend(out)
    model = model_of(scene)
    np.testing.assert_array_equal(model.to_absolute(np.array(states)), whole.states)
    loop.hold(scene.index("power_steering"), 1.5)  # its constant profile's own value: the same run
    x = loop.initial()
    out = np.empty((150, x.size))
    advance(loop, x, out, 0, 150)
    np.testing.assert_array_equal(model.to_absolute(out), whole.states[1:])
    loop.hold(scene.index("power_steering"), 4.0)
    advance(loop, loop.initial(), out, 0, 150)
    assert not np.array_equal(model.to_absolute(out), whole.states[1:])


def test_trapezoidal_runs_the_shipped_fead_at_its_step_and_converges_to_the_reference():
    """The implicit stage's fixed point on the crank's governed engine torque stalls at rounding (a 2-cycle one ulp of
    speed apart, times the governor's gain, is above the 1e-13 tolerance): it was refused at t = 0.214 s."""
    scene = load_network("fead_i4")
    ref = simulate(scene, dt=1e-5, method="etd4", model="flexible", check_accuracy=False)
    scale = np.max(np.abs(ref.tension - 300.0))
    for dt, stride in ((1e-3, 100), (1e-4, 10)):
        run = simulate(scene, dt=dt, method="trapezoidal", model="flexible")
        assert run.method == "trapezoidal" and run.time[-1] == pytest.approx(1.0)
        err = np.max(np.abs(run.tension - ref.tension[::stride]))
        est = float(run.accuracy.split("error ")[1].split(" N")[0])
        assert 0.3 <= est / err <= 3.0, (dt, est, err)  # the guard says how wrong the step is
        assert run.accuracy.startswith("accurate" if err < 1e-3 * scale else "INACCURATE"), (dt, run.accuracy, err / scale)
    assert err < 0.02 * scale  # 0.25 of the peak change at 1 ms, 0.009 at 0.1 ms: the step converges


def test_a_breakpoint_inside_a_step_splits_it_as_a_grid_holding_the_breakpoint_does():
    """The alternator's load steps at 12.5 ms, inside the 1 ms grid's step 12: the step is split there (each piece the
    method at its length), so the run equals one on a 0.5 ms grid (which holds 12.5 ms) at the common times; the
    exponential methods are exact for piecewise-constant torques. Unsplit, the step saw the jump at its end."""
    raw = _raw_tensioned()
    raw["pulleys"][2]["torque"] = {"type": "step", "initial": 2.0, "final": 6.0, "time": 0.0125}
    scene = NetworkScene.from_mapping({**raw, "duration": 0.05, "dt": 1e-3, "initial_speed": 10.0})
    for method in ("exact", "etd2"):
        coarse = simulate(scene, method=method, model="flexible", check_accuracy=False)
        fine = simulate(scene, dt=5e-4, method=method, model="flexible", check_accuracy=False)
        change = np.max(np.abs(fine.tension - 300.0))
        assert np.max(np.abs(coarse.tension - fine.tension[::2])) <= 1e-9 * change, method
        assert np.max(np.abs(coarse.speed - fine.speed[::2])) <= 1e-9 * np.max(np.abs(fine.speed)), method


def test_centrifugal_tension_moves_the_arm_mode_with_speed_as_its_closed_form():
    """At belt speed v the belt pulls on the arm with ``T_j - w``, ``w = m' v^2``. Without loads the spans share one
    tension ``T_0 + dT``; the stretch round the loop is the arm's, ``dT / K_b = G theta_a`` (``K_b = 1 / sum 1/k_j``,
    ``G = sum_j g_j``), and the arm balances ``G dT + (k_a + (T_0 + dT - w) D) theta_a = w G`` (``D = sum_j dg_j``):
    ``D dT^2 + (G^2 K_b + k_a + (T_0 - w) D) dT - w G^2 K_b = 0``. The modes are those of ``K_belt + (k_a + (T_0 +
    dT - w) D) e_a e_a^T`` against M: the Campbell lines move with speed (they were flat)."""
    raw = _raw_tensioned()
    raw["belt"]["mass_per_length"] = 0.12
    for p in raw["pulleys"]:
        if "torque" in p:
            p["torque"] = {"type": "constant", "value": 0.0}
    scene = NetworkScene.from_mapping({**raw, "duration": 0.1, "dt": 1e-4, "initial_speed": 10.0})
    model = NetworkModel.build(scene)
    T0, ka = 300.0, scene.tensioner.spring_rate
    G, D, Kb = float(np.sum(model.g)), float(np.sum(model.dg)), 1.0 / float(np.sum(1.0 / model.k))
    r = scene.pulleys[scene.driver].radius
    lowest = []
    for speed in (0.0, 300.0, 600.0):
        w = 0.12 * (speed * r) ** 2
        a, b, c = D, G * G * Kb + ka + (T0 - w) * D, -w * G * G * Kb
        dT = 2 * c / (-b - math.copysign(math.sqrt(b * b - 4 * a * c), b))  # the root near -c / b (no cancellation)
        K, _, T = model.operating_point(speed)
        np.testing.assert_allclose(T, T0 + dT, rtol=0, atol=1e-9 * T0)
        Kc = model.K_belt.copy()
        Kc[model.arm, model.arm] += (T0 + dT - w) * D  # K_belt holds the spring k_a already
        np.testing.assert_allclose(K, Kc, rtol=1e-12, atol=1e-9)
        Minv_half = np.diag(1.0 / np.sqrt(np.diag(model.M)))
        ev = np.linalg.eigvalsh(Minv_half @ Kc @ Minv_half)
        expected = np.sqrt(ev[ev > 1e-6 * ev.max()]) / (2 * math.pi)
        found = np.array([md.frequency for md in modes(model, speed)])
        np.testing.assert_allclose(found, expected, rtol=1e-9)
        lowest.append(found[0])
        if speed:
            assert 0.0 < dT < w  # a soft tensioner lets the span tension rise by most of w, not all of it
    assert lowest[0] < lowest[1] < lowest[2]  # the arm feels less tension: its (negative) geometric stiffness shrinks


def _two_pulleys():
    return [_pulley("a", (0.0, 0.0), 0.05, role="driver", torque=0.1), _pulley("b", (0.3, 0.0), 0.05, role="accessory", torque=0.1)]


@pytest.mark.parametrize("where, value, message", [
    ("kind", np.array(["network", "x"]), "kind: must be 'network'"),
    ("engine", {"strokes": np.array([2, 4])}, "engine.strokes: 2 or 4, got array"),
    ("engine", {"cylinders": 2.0}, "engine.cylinders: an integer 1..32, got 2.0"),
    ("EA", 1e300, "belt.EA: 1e\\+300 is outside the plausible range"),
])
def test_network_scene_hostile_values_are_one_scene_error(where, value, message):
    """Arrays where a word or a whole number belongs and huge floats: one SceneError naming the key (before:
    numpy's "truth value of an array is ambiguous" ValueError, and "an integer beyond 2^63" for the float 1e300)."""
    with pytest.raises(SceneError, match=message):
        _scene(_two_pulleys(), EA=value) if where == "EA" else _scene(_two_pulleys(), **{where: value})


def test_network_scene_takes_numpy_scalars_and_load_network_refuses_non_names():
    """numpy scalars are numbers (np.int64 cylinders, np.float32 radius); load_network of a non-name is one
    SceneError like load_scene's (before: "unknown network scene 'nan'" for float('nan'))."""
    pulleys = _two_pulleys()
    pulleys[1]["radius"] = np.float32(0.0625)
    scene = _scene(pulleys, engine={"cylinders": np.int64(4), "strokes": np.int64(2)})
    assert scene.pulleys[1].radius == 0.0625 and scene.engine.cylinders == 4
    for bad in (math.nan, None, ["fead_i4"]):
        with pytest.raises(SceneError, match="^scene: expected a name or a path, got "):
            load_network(bad)


@pytest.mark.parametrize("kwargs, message", [
    ({"duration": math.nan}, "duration: must be finite, got nan"),
    ({"duration": 10**400}, "duration: must be finite, got an integer beyond 2\\^63"),
    ({"duration": np.array([0.01])}, "duration: must be a number, got ndarray"),
    ({"duration": 1e9}, "duration: 1e\\+09 is outside the plausible range"),
    ({"dt": 0.0}, "dt: must be > 0, got 0.0"),
    ({"duration": 1e6, "dt": 1e-6}, "dt: 1e-06 s over 1e\\+06 s is more than 1e8 steps"),
    ({"model": ["flexible"]}, "model: must be one of"),
])
def test_network_simulate_refuses_bad_run_arguments_in_one_line(kwargs, message):
    """simulate(scene, duration=..., dt=...) checks them as the scene file's keys are checked (before: ValueError
    'cannot convert float NaN to integer', OverflowError, ZeroDivisionError, a 116 TiB MemoryError for 1e9 s)."""
    scene = _scene(_two_pulleys())
    with pytest.raises(SceneError, match=message):
        simulate(scene, **kwargs)
    with pytest.raises(SceneError, match="scene: expected a NetworkScene"):
        simulate(None, duration=0.01)



def test_the_rigid_tiers_arm_sits_where_its_tensions_hold_it():
    """The rigid tier's span tensions are the belt's static stretch with the arm at its equilibrium; the arm angle it
    reports is that equilibrium's too (before: the installed angle, where those tensions do not balance the spring).
    Against the flexible tier's run settled under the same constant torques."""
    data = _raw_tensioned()
    data.update(duration=3.0, dt=1e-4, initial_speed=50.0)
    data["belt"]["damping"] = 20.0
    data["tensioner"]["damping"] = 0.5
    scene = NetworkScene.from_mapping(data)
    rigid = simulate(scene, model="rigid", method="etd2")
    settled = simulate(scene, model="flexible", method="etd2")
    assert np.ptp(rigid.arm_angle) < 1e-12  # constant torques: one equilibrium
    installed = simulate(scene, duration=1e-3, model="flexible", method="etd2").arm_angle[0]
    assert abs(rigid.arm_angle[-1] - installed) > 1e-4  # the arm has moved from where it was installed
    assert rigid.arm_angle[-1] == pytest.approx(settled.arm_angle[-1], abs=1e-6)
    np.testing.assert_allclose(rigid.tension[-1], settled.tension[-1], rtol=1e-4)


def test_the_rigid_tiers_arm_follows_a_changing_load():
    """Under a load that changes (the crank's ramp), the rigid arm swings with the quasi-static tensions: at every
    sample its swing is the statics' ``a . Q`` (``a``: the arm's row of the stiffness' pseudo-inverse) of the torques
    the belt takes at the pulleys, read back from the tensions the run reports (not from the arm's own row)."""
    from belt_drive_ros.core.network.simulate import model_of

    scene = load_network("fead_i4")
    run = simulate(scene, model="rigid", method="etd2", duration=0.3)
    model = model_of(scene)
    m, n = model.M.shape[0], len(scene.pulleys)
    rhs = np.zeros((m, n))
    rhs[:n] = np.eye(n)
    a = np.linalg.lstsq(model.stiffness(), rhs, rcond=None)[0][model.arm]
    swing = np.asarray(run.states)[:, model.arm]
    assert np.ptp(swing) > 1e-3  # the arm moves
    np.testing.assert_allclose(swing, -(run.belt_torque @ a), rtol=0, atol=1e-12)
