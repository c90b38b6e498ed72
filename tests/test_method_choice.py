"""Accurate by default: ``method: auto`` and the guard's harmonic term against an independent reference.

Reference: ``scipy.integrate.solve_ivp`` DOP853 at rtol 1e-12, written here
(restarted at every torque breakpoint, the torque read from the left inside
each piece), on the same model equations ``x' = A x + B u(t, x)``. Metric:
max error of drive speed and belt torque relative to their peaks (as the
guard's). The scenes name no method; the run must meet its tolerance, and no
run (chosen or stated) may say "accurate" with an error above twice it.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pytest
import scipy.integrate

from belt_drive_ros.benchmarks.auto_choice import varied_scene
from belt_drive_ros.core import sources as S
from belt_drive_ros.core.accuracy import check_accuracy
from belt_drive_ros.core.errors import SceneError
from belt_drive_ros.core.method_choice import CANDIDATES, choose_for_scene
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.scene import Scene
from belt_drive_ros.io.scenes import load_scene, scene_from_mapping
from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.core.stepper import Plant

TOL = 1e-4


def _reference_states(scene, kind, times):
    """DOP853 rtol 1e-12 through the breakpoints, evaluated at ``times``."""
    model = make_model(kind, scene.params)
    plant = Plant(model, scene.drive, scene.load)
    A, B = model.A, model.B
    x = scene.initial_state.vector(kind, scene.params.ratio)
    cuts = sorted({0.0, scene.duration} | {b for b in plant.breakpoints if 0.0 < b < scene.duration})
    out = np.empty((times.size, x.size))
    for a, b in zip(cuts[:-1], cuts[1:]):
        hi = plant.left_of(b)

        def rhs(t, y, lo=a, hi=hi):
            return A @ y + B @ plant.inputs(min(max(t, lo), hi), y)

        sol = scipy.integrate.solve_ivp(rhs, (a, b), x, method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
        assert sol.status == 0, sol.message
        sel = (times >= a) & (times <= b)
        out[sel] = sol.sol(times[sel]).T
        x = sol.y[:, -1]
    return out


def _error(result, kind):
    """max over drive speed and belt torque of max |run - reference| / max |reference|."""
    model = make_model(kind, result.scene.params)
    plant = Plant(model, result.scene.drive, result.scene.load)
    ref = _reference_states(result.scene, kind, result.time)
    ref_out = model.outputs(ref, plant.input_array(result.time, ref))
    errs = []
    for name in ("omega_M", "belt_torque"):
        r, y = np.asarray(ref_out[name]), np.asarray(result.outputs[name])
        errs.append(float(np.max(np.abs(y - r)) / np.max(np.abs(r))))
    return max(errs)


def _run(scene, **kw):
    return simulate(scene, **kw)


# ------------------------------------------------------------------ the harmonic term
def _resonant(c=0.5, duration=1.5):
    """The truck's belt, lightly damped, driven at its belt mode by a sine from rest (no step at t = 0)."""
    truck = load_scene("truck_compressor")
    p = replace(truck.params, c=c)
    f_n = p.belt_natural_frequency / (2.0 * math.pi)
    return truck.with_overrides(params=p, drive=S.Sine(mean=0.0, amplitude=10.0, frequency=f_n), load=S.Constant(0.0),
                                duration=duration, model="flexible", method="etd2", dt=1e-4)  # fmt: skip


@pytest.mark.parametrize("c", [0.5, 5.0])
def test_resonance_building_up_is_seen(c):
    """Forced at its mode the error grows with the response over the run: the windows saw 1/5 of it (4.4e-5 vs 2.1e-4)."""
    scene = _resonant(c)
    result = _run(scene)
    measured = _error(result, "flexible")
    report = result.accuracy
    assert measured > TOL  # the case matters: etd2 at 0.1 ms misses the tolerance here
    assert 0.5 * measured <= report.error <= 3.0 * measured, (report.describe(), measured)
    assert not report.accurate and report.harmonic_error >= 0.5 * measured
    auto = _run(scene.with_overrides(method="auto"))
    assert auto.method_choice is not None and auto.method != "etd2"
    assert _error(auto, "flexible") <= TOL, auto.method_choice.reason


def test_speed_dependent_load_with_exact():
    """Load 9.5 omega_3 at 2 ms, exact (holds the torque over the step): the estimate is the measured error's size."""
    truck = load_scene("truck_compressor")
    scene = truck.with_overrides(drive=S.Constant(50.0), load=S.Polynomial(0.0, 9.5), duration=1.0, model="flexible",
                                 method="exact", dt=2e-3)  # fmt: skip
    result = _run(scene)
    measured = _error(result, "flexible")
    assert measured > 0.1
    assert 0.5 * measured <= result.accuracy.error <= 2.0 * measured, (result.accuracy.describe(), measured)
    auto = _run(scene.with_overrides(method="auto"))
    assert _error(auto, "flexible") <= TOL, auto.method_choice.reason


@pytest.mark.parametrize("ratio", [0.3, 1.0, 2.5])
def test_auto_on_drives_below_at_and_above_the_belt_mode(ratio):
    """A sine drive at 0.3, 1 and 2.5 times the belt mode into a speed-dependent load; the scene names no method."""
    truck = load_scene("truck_compressor")
    p = replace(truck.params, c=2.0)
    f_n = p.belt_natural_frequency / (2.0 * math.pi)
    scene = truck.with_overrides(params=p, drive=S.Sine(mean=20.0, amplitude=15.0, frequency=ratio * f_n),
                                 load=S.Polynomial(0.0, 0.2), duration=1.0, model="flexible", method="auto",
                                 dt=5e-4)  # fmt: skip
    result = _run(scene)
    choice = result.method_choice
    assert choice is not None and choice.method in CANDIDATES and choice.met
    assert result.method == choice.method and result.dt == pytest.approx(choice.dt)
    assert choice.method in choice.reason and "tolerance" in choice.reason
    measured = _error(result, "flexible")
    assert measured <= TOL, (choice.reason, measured)
    assert result.accuracy.error >= 0.5 * measured  # the verdict on the chosen step is not optimistic


def test_choice_is_the_cheapest_the_guard_accepts():
    """Every cheaper candidate at the chosen step rates above a quarter of the tolerance (the choice's bar)."""
    scene = load_scene("paper").with_overrides(method="auto", model="flexible")
    choice = choose_for_scene(scene, "flexible")
    plant = Plant(make_model("flexible", scene.params), scene.drive, scene.load)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    for cheaper in CANDIDATES[: CANDIDATES.index(choice.method)]:
        report = check_accuracy(plant, cheaper, choice.dt, scene.duration, x0, scene.tolerance, suggest=False)
        assert not (report.ok and report.error <= 0.25 * scene.tolerance), report.describe()
    assert choice.error <= 0.25 * scene.tolerance


def test_substeps_when_no_method_meets_it_at_the_scene_dt():
    """A tolerance of 1e-9 at 5 ms on paper: none at 5 ms; the fewest substeps at which one is."""
    scene = load_scene("paper").with_overrides(method="auto", model="flexible", tolerance=1e-9, duration=1.0)
    choice = choose_for_scene(scene, "flexible")
    assert choice.substeps > 1 and choice.dt == pytest.approx(scene.dt / choice.substeps)
    assert "substeps" in choice.reason
    tried_at_dt = [e for m, h, e in choice.tried if h == scene.dt]
    assert tried_at_dt and min(tried_at_dt) > 0.25e-9


# ------------------------------------------------------------------ 20+ scenes that name no method
# the family: belt_drive_ros.benchmarks.auto_choice.varied_scene (sine drives 0.7-3.5 x the belt mode, engines with
# compressor loads by angle, sine loads, drives forced near their mode; truck and paper belts)
VARIED = 22


@pytest.mark.slow
@pytest.mark.parametrize("k", range(VARIED))
def test_default_run_meets_its_tolerance(k):
    scene = varied_scene(k)
    result = _run(scene)
    measured = _error(result, "flexible")
    assert result.method_choice is not None
    assert measured <= TOL, (result.method_choice.reason, measured)
    # the stated old default at the scene's dt: never "accurate" with an error above twice the tolerance
    stated = _run(scene.with_overrides(method="etd2"))
    if stated.accuracy.accurate:
        assert _error(stated, "flexible") <= 2.0 * TOL, stated.accuracy.describe()


# ------------------------------------------------------------------ scene key, CLI
def test_tolerance_key_is_validated_with_one_line():
    for bad in (0.0, -1e-4, 2.0, "1e-4", float("nan")):
        with pytest.raises(SceneError, match=r"^tolerance: ") as info:
            scene_from_mapping({"extends": "paper", "tolerance": bad})
        assert "\n" not in str(info.value)
    scene = scene_from_mapping({"extends": "paper", "tolerance": 1e-6})
    assert scene.tolerance == 1e-6 and Scene.from_mapping(scene.to_dict()) == scene


def test_a_scene_that_names_no_method_gets_auto():
    data = load_scene("paper").to_dict()
    del data["method"]
    scene = Scene.from_mapping(data)
    assert scene.method == "auto"
    result = simulate(scene, duration=0.5)
    assert result.method in CANDIDATES and result.method_choice is not None


def test_sim_cli_tolerance_and_choice(tmp_path, capsys):
    from belt_drive_ros.cli import main

    scene = tmp_path / "s.yaml"
    scene.write_text("extends: paper\nmethod: auto\nduration: 0.5\n", encoding="utf-8")
    assert main(["sim", str(scene), "--quiet", "--tolerance", "1e-6"]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("method choice"))
    assert re.search(r"tolerance 1e-06", line)
    assert main(["sim", str(scene), "--quiet", "--tolerance", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tolerance" in err[0]


def test_recording_metadata_says_how_the_method_was_chosen(tmp_path):
    from mcap.reader import make_reader

    from belt_drive_ros.cli import main

    scene, out = tmp_path / "s.yaml", tmp_path / "run.mcap"
    scene.write_text("extends: paper\nmethod: auto\nduration: 0.3\n", encoding="utf-8")
    assert main(["sim", str(scene), "--quiet", "--out", str(out)]) == 0
    with open(out, "rb") as f:
        record = next(m.metadata for m in make_reader(f).iter_metadata() if "method_choice" in m.metadata)
    assert record["method"] in CANDIDATES and record["method_choice"].startswith(record["method"])


def test_exact_forcing_map_equals_the_exponential_of_the_system_augmented_with_the_oscillator():
    """F(omega) = int_0^h e^{(h-s)A} B e^{j omega s} ds by the solve (j omega I - A)^{-1}(e^{j omega h} I - e^{hA}) B
    against Van Loan's augmented exponential, written here: damped random systems, and an undamped oscillator
    forced exactly at its frequency (the solve is singular there: the exponential is taken)."""
    import scipy.linalg

    from belt_drive_ros.core.forced_response import exact_forcing_maps

    def augmented(A, B, h, omega):
        n, m = B.shape
        aug = np.zeros((n + m, n + m), dtype=complex)
        aug[:n, :n], aug[:n, n:], aug[n:, n:] = A, B, 1j * omega * np.eye(m)
        return scipy.linalg.expm(aug * h)[:n, n:]

    rng = np.random.default_rng(7)
    for _ in range(20):
        n, m = 4, 2
        A = rng.normal(size=(n, n)) * 50.0
        A -= (np.max(np.linalg.eigvals(A).real) + rng.uniform(0.1, 20.0)) * np.eye(n)  # stable, damped
        B = rng.normal(size=(n, m))
        h, omega = rng.uniform(1e-4, 5e-3), rng.uniform(1.0, 3000.0)
        F = exact_forcing_maps(A, B, scipy.linalg.expm(h * A), h, omega)[0]
        ref = augmented(A, B, h, omega)
        assert np.max(np.abs(F - ref)) <= 1e-10 * np.max(np.abs(ref))
    w = 66.0
    A = np.array([[0.0, 1.0], [-w * w, 0.0]])  # undamped, eigenvalues +-j w
    B = np.array([[0.0], [1.0]])
    F = exact_forcing_maps(A, B, scipy.linalg.expm(1e-3 * A), 1e-3, w)[0]
    assert np.allclose(F, augmented(A, B, 1e-3, w), rtol=0, atol=1e-14)


def test_harmonic_response_in_closed_form_equals_the_stepped_orbit():
    """The harmonic term's response y_k = z^k C P - (C M^k) P (P = (z I - M)^{-1} G, forced_response) against the
    recurrence x_{k+1} = M x_k + G z^k stepped one step at a time, written here, for the method and the exact map:
    the paper drive's flexible closed loop with etd2 and lawson5, forcings below, near and above the belt mode;
    and a forcing exactly at an undamped mode (z I - M singular: the orbit is stepped there instead)."""
    import scipy.linalg

    from belt_drive_ros.core import forced_response as fr
    from belt_drive_ros.core.integrators import make_integrator

    def stepped(M, G, z, rows, n_steps):
        x, ys = np.zeros(G.shape[0], dtype=complex), []
        for k in range(n_steps):
            x = M @ x + G * z**k
            ys.append(rows @ x)
        return np.array(ys)

    scene = load_scene("paper")
    model = make_model("flexible", scene.params)
    A, B = model.A, model.B
    rows = np.vstack([model.C[1], model.C[6]])  # omega_M and a second output row
    K = np.zeros((2, A.shape[0]))
    K[0] = -0.5 * Plant(model, scene.drive, scene.load).wheel_map[1]  # a speed slope: a closed loop
    f_n = scene.params.belt_natural_frequency / (2.0 * math.pi)
    n_steps = 700  # past ORBIT_SAMPLES / 2: the strided part too
    for method in ("etd2", "lawson5"):
        integ = make_integrator(method, A, B, 1e-3)
        M, gains = fr.stage_gains(integ, K)
        A_cl = A + B @ K
        E = scipy.linalg.expm(1e-3 * A_cl)
        omegas = 2.0 * math.pi * np.array([0.3 * f_n, 0.97 * f_n, 2.5 * f_n])
        err, peak = fr.harmonic_response_errors(integ, A, B, rows, K, n_steps, omegas, [0, 1, 0])
        head, stride = 600, math.ceil((n_steps - 600) / 600)
        ks = list(range(head)) + [head - 1 + stride * j for j in range(1, (n_steps - head) // stride + 1)]
        for f, (omega, ch) in enumerate(zip(omegas, [0, 1, 0])):
            z = np.exp(1j * omega * 1e-3)
            G = sum(Gi[:, ch] * np.exp(1j * omega * c * 1e-3) for c, Gi in gains)
            F = fr.exact_forcing_maps(A_cl, B, E, 1e-3, omega)[0][:, ch]
            y, y_exact = stepped(M, G, z, rows, n_steps)[ks], stepped(E, F, z, rows, n_steps)[ks]
            ref_peak = np.max(np.abs(y_exact), axis=0)
            assert np.allclose(peak[f], ref_peak, rtol=1e-9, atol=0)
            assert np.allclose(err[f], np.max(np.abs(y - y_exact), axis=0), rtol=1e-6, atol=1e-12 * ref_peak)
    w = 66.0  # an undamped oscillator forced at its frequency, exact both ways: no error, a response that grows
    A = np.array([[0.0, 1.0], [-w * w, 0.0]])
    B = np.array([[0.0, 0.0], [1.0, 0.0]])
    integ = make_integrator("exact", A, B, 1e-3)
    err, peak = fr.harmonic_response_errors(integ, A, B, np.eye(2), np.zeros((2, 2)), 400, np.array([w]), [0])
    assert np.all(np.isfinite(err)) and np.all(peak > 0)
