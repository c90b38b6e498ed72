"""Invariants of the benchmark data (not timings), on quick configurations.

Tolerances, with the reason
---------------------------
* exact method on the open-loop linear scene: error <= 1e-10 relative to the
  signal peak at every step. The torques are piecewise constant and switch
  on every grid, so the ZOH step is exact; what is left is rounding summed
  over up to 2^15 reference steps (measured ~1e-11). A first-order error
  here would be >= 1e-3.
* measured RK4 (and symplectic Euler) stability boundary within 5 % of the
  guard's prediction (issue 5); measured ~0.2 %: the divergence criterion
  (energy x10 over the run) needs |R| - 1 ~ 0.3 % per step at 2.2 steps per
  period to trip.
* rigid-model error grows with f/f_n below resonance (strictly, point to
  point) and the simulated steady-state error matches the two models'
  frequency responses within 10 % (transient e^-6 left, input interpolation).
* error at the auto threshold f/f_n = 0.1: within [0.5 %, 2 %] (theory for
  the undamped belt mode: r^2 / (1 - r^2) = 1.01 %).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from belt_drive_ros.benchmarks import common, fidelity_chart, stability_map, versus_scipy, workprecision
from belt_drive_ros.core.fidelity import FREQUENCY_RATIO_THRESHOLD


@pytest.fixture(scope="module")
def wp_rows():
    config = workprecision.Config(
        scenes=("paper", common.LINEAR_SCENE),
        fixed_methods=("exact", "etd2", "etd4", "lawson5", "rk4", "euler"),
        adaptive_methods=("RK45",),
        step_exponents=(-2, 0, 2),
        rtols={"RK45": (1e-5,)},
        duration=0.5,
        repeats=1,
    )
    return workprecision.measure(config, quiet=True)


def test_exact_method_is_at_rounding_level_on_the_linear_scene(wp_rows):
    rows = [r for r in wp_rows if r["scene"] == common.LINEAR_SCENE and r["method"] == "exact"]
    assert len(rows) == 3 and all(r["status"] == "ok" for r in rows)
    assert max(r["error"] for r in rows) <= 1e-10
    # etd2 is exact for piecewise-linear torque: with the switches (on the grid) taken from their left
    # limit at a step's end it is at rounding level too (it was first order, > 1e-4, when the step ending
    # on a switch sampled the torque after the jump)
    etd2 = [r for r in wp_rows if r["scene"] == common.LINEAR_SCENE and r["method"] == "etd2"]
    assert etd2 and max(r["error"] for r in etd2) <= 1e-10


def test_linear_reference_agrees_with_an_independent_dop853():
    scene = common.linear_scene().with_overrides(duration=0.5)
    exact = common.exact_reference(scene, "flexible")
    dop = common.dop853_reference(scene, "flexible")
    times = scene.dt * np.arange(int(round(scene.duration / scene.dt)) + 1)
    e = common.run_errors(exact, times, dop.states(times))
    assert e["error"] <= 1e-10


def test_unstable_points_are_skipped_and_marked(wp_rows):
    euler = [r for r in wp_rows if r["method"] == "euler"]
    assert euler and all(r["status"] == "unstable (guard)" for r in euler)  # undamped-ish belt: never stable
    assert all("error" not in r and "pareto" not in r for r in euler)


def test_pareto_front_is_non_dominated_and_complete(wp_rows):
    for scene in ("paper", common.LINEAR_SCENE):
        ok = [r for r in wp_rows if r["scene"] == scene and r["status"] == "ok"]
        front = [r for r in ok if r["pareto"] == 1]
        assert front
        for f in front:  # nobody beats a front point in both
            assert not any(
                o["cpu_per_sim_s"] <= f["cpu_per_sim_s"] and o["error"] <= f["error"]
                and (o["cpu_per_sim_s"] < f["cpu_per_sim_s"] or o["error"] < f["error"])
                for o in ok
            )  # fmt: skip
        for r in ok:  # every other point is beaten by a front point
            if r["pareto"] == 0:
                assert any(f["cpu_per_sim_s"] <= r["cpu_per_sim_s"] and f["error"] <= r["error"] for f in front)


def test_default_is_marked_once_per_scene(wp_rows):
    for scene in ("paper", common.LINEAR_SCENE):
        defaults = [r for r in wp_rows if r["scene"] == scene and r["default"] == 1]
        assert len(defaults) == 1
        assert defaults[0]["method"] == common.get_scene(scene).method
        assert math.isclose(defaults[0]["dt"], common.get_scene(scene).dt)


def test_errors_fall_with_the_step_at_each_methods_order(wp_rows):
    # paper scene, closed loop and smooth after the 0.02 s soft start: etd2 order 2, rk4 order 4 (+/- 0.6)
    for method, order in (("etd2", 2), ("rk4", 4)):
        rows = sorted((r for r in wp_rows if r["scene"] == "paper" and r["method"] == method), key=lambda r: r["dt"])
        slope = math.log(rows[1]["error"] / rows[0]["error"]) / math.log(rows[1]["dt"] / rows[0]["dt"])
        assert abs(slope - order) < 0.6, (method, slope)


def test_pareto_mask_on_a_hand_made_set():
    cost = [1, 2, 3, 2, 1]
    error = [5, 4, 1, 6, 5]
    assert common.pareto_mask(cost, error).tolist() == [True, True, True, False, True]


def test_rk4_measured_stability_boundary_within_5_percent_of_prediction():
    config = replace(stability_map.QUICK, methods=("rk4", "symplectic_euler"), zetas=(0.0, 0.05, 0.2), slip_study=False)
    rows = stability_map.measure(config, quiet=True)
    for method in ("rk4", "symplectic_euler"):
        for zeta, measured, predicted in stability_map.boundaries(rows, method):
            assert abs(measured / predicted - 1.0) < 0.05, (method, zeta, measured, predicted)
    assert stability_map.boundaries(rows, "rk4")[0][2] == pytest.approx(2.0 * math.sqrt(2.0), rel=1e-6)
    # the grid agrees with the boundary: diverged exactly where h*omega_n exceeds it
    b = {z: m for z, m, _ in stability_map.boundaries(rows, "rk4")}
    for r in rows:
        if r["study"] == "plane" and r["method"] == "rk4" and r["kind"] == "grid":
            assert bool(r["diverged"]) == (r["h_omega_n"] > b[r["zeta"]])


def test_unconditionally_stable_methods_do_not_diverge_at_large_steps():
    params = stability_map._paper_params(0.0)
    for method in ("exact", "etd2", "trapezoidal"):
        assert stability_map.growth(params, method, 5.0 / params.belt_natural_frequency, periods=20) < 2.0
    assert stability_map.growth(params, "rk4", 3.0 / params.belt_natural_frequency, periods=20) > stability_map.FACTOR


@pytest.fixture(scope="module")
def fidelity_rows():
    return fidelity_chart.measure(fidelity_chart.QUICK, quiet=True)


def test_fidelity_error_grows_with_excitation_ratio(fidelity_rows):
    rows = sorted(fidelity_rows, key=lambda r: r["ratio"])
    below = [r for r in rows if r["ratio"] < 0.8]
    for key in ("e_belt", "e_speed", "e_speed3"):
        values = [r[key] for r in below]
        assert all(b > a for a, b in zip(values, values[1:])), key


def test_fidelity_simulation_matches_frequency_response(fidelity_rows):
    for r in fidelity_rows:
        for sim, theory in (("e_belt", "h_belt"), ("e_speed", "h_speed"), ("e_speed3", "h_speed3")):
            assert r[sim] == pytest.approx(r[theory], rel=0.1), (r["ratio"], sim)


def test_auto_switches_at_the_threshold_and_its_error_level(fidelity_rows):
    for r in fidelity_rows:
        assert r["auto"] == ("rigid" if r["ratio"] < FREQUENCY_RATIO_THRESHOLD else "flexible"), r["ratio"]
    err = fidelity_chart.threshold_error(fidelity_rows)
    assert 0.005 <= err <= 0.02


def test_matched_accuracy_picks_the_cheapest_run_reaching_each_target():
    rows = [
        dict(scene="s", method="etd2", dt=1e-3, rtol="", cpu_per_sim_s=1.0, error=1e-4),
        dict(scene="s", method="etd2", dt=5e-4, rtol="", cpu_per_sim_s=2.0, error=2e-5),
        dict(scene="s", method="solve_ivp RK45", dt=1e-3, rtol=1e-6, cpu_per_sim_s=5.0, error=5e-5),
        dict(scene="s", method="solve_ivp RK45", dt=1e-3, rtol=1e-8, cpu_per_sim_s=9.0, error=1e-6),
    ]
    match = {m["target_error"]: m for m in versus_scipy.matched(rows, targets=(1e-4, 1e-5, 1e-7))}
    assert match[1e-4]["speedup"] == pytest.approx(5.0)  # etd2 dt=1e-3 vs RK45 rtol 1e-6
    assert 1e-5 not in match or match[1e-5]["method"] != "etd2"  # etd2 never reached 1e-5
    assert 1e-7 not in match


# ------------------------------------------------------------ slipping scenes
# The slipping scene's variants (benchmarks/slip_runs.py) against closed forms and the event-located reference.
from belt_drive_ros.benchmarks import slip_runs  # noqa: E402

#: RK4's stability limit on the negative real axis: 1 + x + x^2/2 + x^3/6 + x^4/24 = 1 at x = -2.7853
RK4_REAL_AXIS = 2.785293563405282


def test_regularised_contact_is_no_stiffer_than_the_span_relaxation():
    """Linearized, the contact ``Q_max tanh(s'/v_eps)`` in series with the span relaxes the stretch at
    ``2k / (2c + d)``, d the contact's slope: at most ``k / c``, reached while the belt slides fast. RK4's
    largest stable step is therefore its real-axis limit over k / c at every v_eps (docs/model.md), the
    same as on the hybrid's slip mode, and not a step that shrinks with v_eps."""
    case = slip_runs.case_from_scene(common.get_scene(common.SLIP_SCENE)).with_duration(0.7)
    p = case.params
    expected = RK4_REAL_AXIS * p.c / p.k
    assert slip_runs.slip_mode_step(case, "rk4") == pytest.approx(expected, rel=1e-3)
    for v_eps in (1e-2, 1e-4):
        times, states = slip_runs.probe_states(case, v_eps, n=12)
        assert slip_runs.regularised_step(case, "rk4", v_eps, states, times) == pytest.approx(expected, rel=2e-2), v_eps
    assert slip_runs.slip_mode_step(case, "etd2") == math.inf  # exponential: the relaxation is integrated exactly


def test_event_location_keeps_etd2_second_order_through_the_engine():
    """Stick-slip case through the package's engine: etd2 with located events converges with order 2 against
    DOP853 with events; switching at the step end instead is > 10x worse at the finest step."""
    case = slip_runs.stick_slip_case()
    ref = slip_runs.reference(case, 2.5e-4)
    assert ref.events >= 8
    steps = (1e-3, 5e-4, 2.5e-4)
    located = [slip_runs.errors(ref, slip_runs.run(case, "hybrid", "etd2", dt, repeats=1))["error"] for dt in steps]
    order = np.log2(np.array(located[:-1]) / np.array(located[1:]))
    assert np.all(np.abs(order - 2.0) < 0.4), order
    sampled = slip_runs.errors(ref, slip_runs.run(case, "no_location", "etd2", steps[-1], repeats=1))["error"]
    assert sampled > 10 * located[-1]


def test_slipping_panel_marks_its_default_and_names_each_variant():
    config = workprecision.Config(
        scenes=(), fixed_methods=(), adaptive_methods=(), step_exponents=(0,), repeats=1,
        slip_scenes=(common.SLIP_SCENE,), slip_methods=("etd4",), slip_no_location=(), slip_regularised=("rk4",),
        slip_v_eps=(1e-3,), slip_duration=0.7,
    )  # fmt: skip
    rows = workprecision.measure(config, quiet=True)
    default = [r for r in rows if r["default"] == 1]
    scene = common.get_scene(common.SLIP_SCENE)
    assert len(default) == 1 and default[0]["method"] == scene.method and default[0]["family"] == "hybrid"
    assert default[0]["status"] == "ok" and default[0]["error"] < 1e-3 and default[0]["events"] > 0
    assert [workprecision.row_label(r) for r in rows] == ["etd4", "rk4 tanh v_eps=0.001"]
