"""Regularised friction as a selectable model, its stability guard, and methods the slipping model refuses."""

from __future__ import annotations

from belt_drive_ros.cli import main


def _one_line_error(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and lines[0].startswith("belt-drive: error:")
    return lines[0]


def test_symplectic_euler_on_the_slipping_model_is_a_one_line_refusal(capsys):
    # the slip mode relaxes the span stretch by a first-order equation: no [coordinates, speeds] split
    code = main(["sim", "truck_compressor", "--model", "slipping", "--method", "symplectic_euler", "--duration", "0.05", "--quiet"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 2
    assert "symplectic_euler" in line and "etd2" in line and "internal error" not in line
    # the flexible model keeps the method (a meaningful run of the same scene)
    code = main(["sim", "truck_compressor", "--model", "flexible", "--method", "symplectic_euler", "--dt", "1e-4",
                 "--duration", "0.05", "--quiet"])  # fmt: skip
    assert code == 0, capsys.readouterr().err



def test_auto_with_symplectic_euler_runs_a_scene_within_the_limit_on_the_linear_model():
    # auto's single slipping pass cannot take a [coordinates, speeds] method: such a method keeps the
    # two-run path, so a scene that never reaches the capstan limit runs exactly as on its linear model
    from belt_drive_ros.core.scene import load_scene
    from belt_drive_ros.core.simulate import simulate
    import numpy as np

    scene = load_scene("paper")
    auto = simulate(scene, method="symplectic_euler", dt=1e-3)
    assert auto.choice.model == "flexible"
    linear = simulate(scene, model="flexible", method="symplectic_euler", dt=1e-3)
    assert np.array_equal(auto.states, linear.states)
    assert auto.outputs.keys() == linear.outputs.keys()
    assert all(np.array_equal(auto.outputs[k], linear.outputs[k]) for k in auto.outputs)


def test_auto_with_symplectic_euler_on_a_slipping_scene_is_a_one_line_refusal(capsys):
    # truck_compressor reaches the capstan limit at ~0.5 s: the slipping model is needed and refuses the method
    code = main(["sim", "truck_compressor", "--method", "symplectic_euler", "--duration", "1", "--quiet"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 2 and "symplectic_euler" in line and "slipping" in line


# ------------------------------------------------------------------ regularised friction as a model
import math  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from belt_drive_ros.core.errors import SceneError, UnstableStepError  # noqa: E402
from belt_drive_ros.core.params import BeltDriveParams  # noqa: E402
from belt_drive_ros.core.regularised import check_regularised, contact_gain  # noqa: E402
from belt_drive_ros.core.scene import Scene, load_scene  # noqa: E402
from belt_drive_ros.core.simulate import simulate  # noqa: E402
from belt_drive_ros.core.slip import SlippingBeltModel  # noqa: E402
from belt_drive_ros.core.slip_reference import reference_hybrid  # noqa: E402
from belt_drive_ros.core.sources import Constant, Sine  # noqa: E402
from belt_drive_ros.core.stepper import Plant  # noqa: E402


def _stick_slip(**changes) -> Scene:
    """Repeated stick-slip (the charts' stick_slip case): Q_max = 253 N, 30 N m drive, 15 +/- 10 N m at 8 Hz on wheel 3."""
    p = BeltDriveParams(mu=0.3, F_0=300.0)
    base = dict(params=p, drive=Constant(30.0), load=Sine(mean=15.0, amplitude=10.0, frequency=8.0), duration=0.3,
                model="regularised", method="etd2", dt=1e-4, v_eps=1e-3)  # fmt: skip
    return Scene(**{**base, **changes})


def test_regularised_approaches_the_event_located_hybrid_as_v_eps_shrinks():
    scene = _stick_slip()
    m = SlippingBeltModel(scene.params)
    plant = Plant(m, scene.drive, scene.load)
    time = np.arange(int(round(scene.duration / scene.dt)) + 1) * scene.dt
    ref = reference_hybrid(m, plant.scalar_drive, plant.scalar_load, time, scene.initial_state.vector("slipping", scene.params.ratio),
                           rtol=1e-12, atol=1e-12)  # fmt: skip
    assert len(ref.events) >= 4  # repeated stick-slip
    belt_ref = scene.params.r_3 * m.force(ref.states, ref.mode, ref.sigma)
    errors = []
    for v_eps in (1e-2, 1e-3, 1e-4):
        r = simulate(scene, model=None) if v_eps == scene.v_eps else simulate(Scene(**{**_fields(scene), "v_eps": v_eps}))
        assert r.model == "regularised"
        np.testing.assert_allclose(r.time, time, rtol=0, atol=1e-12)
        e_speed = np.max(np.abs(r["omega_M"] - ref.states[:, 2])) / np.max(np.abs(ref.states[:, 2]))
        e_belt = np.max(np.abs(r["belt_torque"] - belt_ref)) / np.max(np.abs(belt_ref))
        errors.append(max(e_speed, e_belt))
    # the modelling error of the regularisation falls with v_eps (about in proportion)
    assert errors[0] > 3.0 * errors[1] > 9.0 * errors[2], errors
    assert errors[2] < 1e-2, errors


def _fields(scene: Scene) -> dict:
    from dataclasses import fields

    return {f.name: getattr(scene, f.name) for f in fields(scene)}


def test_regularised_outputs_are_the_slipping_columns_and_energy_balances():
    rows = {}
    for dt in (1e-4, 5e-5):
        r = simulate(_stick_slip(dt=dt))
        e = r.energy
        residual = e["input_work"] - (e["kinetic"] - e["kinetic"][0]) - (e["potential"] - e["potential"][0]) - e["dissipated"] - e["friction"]
        rows[dt] = (float(np.max(np.abs(residual))), r)
    r = rows[5e-5][1]
    work = r.energy["input_work"][-1]
    # friction (integral of Q v_s) is most of the work here: leaving it out would miss by ~90 %
    assert r.energy["friction"][-1] > 0.5 * work > 0
    assert rows[5e-5][0] < 1e-3 * work and rows[5e-5][0] < rows[1e-4][0] / 3.0, {k: v[0] for k, v in rows.items()}
    o = r.outputs
    p = r.scene.params
    Q = o["belt_torque"] / p.r_3
    np.testing.assert_allclose(o["span_force_tight"] - o["span_force_slack"], Q, rtol=1e-12, atol=1e-9)
    assert np.all(np.abs(o["friction_use"]) <= 1.0)  # tanh never passes the limit (reaches it to rounding)
    np.testing.assert_array_equal(o["slip"], np.abs(o["slip_speed"]) > r.scene.v_eps)
    assert 0.05 < np.mean(o["slip"]) < 0.95 and len(r.events) >= 2  # it sticks and slides
    # accumulated slip is the integral of the slip speed (trapezoid, to its O(dt^2))
    s = np.concatenate([[0.0], np.cumsum(0.5 * (o["slip_speed"][1:] + o["slip_speed"][:-1]) * np.diff(r.time))])
    np.testing.assert_allclose(o["slip_distance"], s, rtol=0, atol=1e-3 * np.max(np.abs(s)))
    assert r.table().shape[1] == 9


def test_guard_refuses_an_unstable_step_with_the_span_relaxation_as_reason():
    scene = _stick_slip(method="rk4")
    report = check_regularised(scene.params, "rk4", 1e-3, scene.v_eps)
    assert not report.stable
    # the saturated contact (slope 0) relaxes the span at k / c: what limits the step
    assert report.slope == 0.0 and math.isclose(report.relaxation_rate, scene.params.k / scene.params.c, rel_tol=1e-12)
    h = report.max_stable_dt
    assert 0.0 < h < 1e-3
    with pytest.raises(UnstableStepError, match=r"2k/\(2c\+d\).*use dt <= "):
        simulate(scene, dt=1e-3)
    assert simulate(scene, dt=0.9 * h).stability.stable  # the named step runs
    with pytest.raises(Exception, match="diverged"):  # and the refusal is not idle: unguarded at 3x it diverges
        simulate(scene, dt=3.0 * h, check_stability=False)


def test_contact_slope_in_series_with_the_span_damper():
    """Linearized contact: the span stretch relaxes at 2k/(2c+d), slower for a stiffer (smaller v_eps) contact."""
    p = BeltDriveParams(mu=0.3, F_0=300.0)
    m = SlippingBeltModel(p)
    for d in (0.0, 1e3, 1e5, p.friction_limit(0.0) / 1e-4):
        K = contact_gain(m, d)
        J = m.A_reg + m.B_reg @ K
        # with the wheels held (omega rows removed) the stretch obeys theta_e' = -2k/(2c+d) theta_e
        assert math.isclose(J[1, 1], -2.0 * p.k / (2.0 * p.c + d), rel_tol=1e-12)
        # Q = d v_s and the span force balance 2 k r3 theta + 2 c (v_rel - v_s) = Q hold
        y = np.array([0.1, 1e-3, 50.0, 60.0, 0.0])
        v, Q = K[3] @ y, K[2] @ y
        assert math.isclose(Q, d * v, rel_tol=1e-12, abs_tol=1e-12)
        assert math.isclose(2 * p.k * p.r_3 * y[1] + 2 * p.c * (m.rel_row @ y - v), Q, rel_tol=1e-9, abs_tol=1e-9)


@pytest.mark.parametrize("bad, what", [(0.0, "> 0"), (-1e-3, "> 0"), (float("nan"), "> 0"), (5.0, "plausible range"),
                                       (1e-9, "plausible range"), ("fast", "> 0")])  # fmt: skip
def test_bad_v_eps_is_a_one_line_error(bad, what, tmp_path, capsys):
    with pytest.raises(SceneError, match=f"v_eps: .*{what}"):
        Scene.from_mapping({"extends": "truck_compressor", "model": "regularised", "v_eps": bad})
    if isinstance(bad, float) and math.isfinite(bad):
        code = main(["sim", "truck_compressor", "--model", "regularised", "--v-eps", repr(bad), "--duration", "0.01", "--quiet"])
        line = _one_line_error(capsys.readouterr().err)
        assert code == 2 and "v_eps" in line


def test_regularised_is_selectable_by_name_in_a_scene_and_on_the_cli(tmp_path, capsys):
    path = tmp_path / "reg.yaml"
    path.write_text("extends: truck_compressor\nmodel: regularised\nv_eps: 2.0e-3\ndt: 1.0e-4\nduration: 0.05\n")
    scene = load_scene(path)
    assert scene.model == "regularised" and scene.v_eps == 2e-3
    assert Scene.from_mapping(scene.to_dict()) == scene
    assert "v_eps" not in load_scene("truck_compressor").to_dict()  # shipped scenes print as before
    csv = tmp_path / "run.csv"
    code = main(["sim", str(path), "--out", str(csv), "--quiet"])
    out = capsys.readouterr().out
    assert code == 0 and "regularised" in out and "span relaxation" in out
    header = csv.read_text().splitlines()[0].split(",")
    assert {"span_force_tight", "span_force_slack", "friction_use", "slip", "slip_speed", "slip_angle"} <= set(header)


def test_node_refuses_the_regularised_model_with_a_reason():
    from belt_drive_ros.ros.parameter_schema import NodeConfigError, build_settings, default_values

    scene = load_scene("truck_compressor")
    values = {**default_values(scene), "drive_source": "scene", "model": "regularised"}
    with pytest.raises(NodeConfigError, match="regularised: offline only"):
        build_settings(values)
    assert build_settings({**values, "model": "slipping"}).model.name == "slipping"


def test_ensembles_and_campaign_metrics_take_the_regularised_model_one_run_at_a_time():
    from belt_drive_ros.campaign.metrics import run_metrics
    from belt_drive_ros.core.ensemble_run import simulate_many

    scenes = [_stick_slip(duration=0.1, params=BeltDriveParams(mu=0.3, F_0=f0)) for f0 in (280.0, 300.0, 320.0)]
    outcomes = sorted(simulate_many(scenes), key=lambda o: o.index)
    for o, scene in zip(outcomes, scenes):
        assert o.error is None and o.result.model == "regularised", o.error
        np.testing.assert_array_equal(o.result.states, simulate(scene).states)
        m = run_metrics(o.result)
        assert m["slip_time"] > 0.0 and m["accumulated_slip"] > 0.0
