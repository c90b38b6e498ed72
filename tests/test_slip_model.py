"""The slipping model as the third tier: model choice, bit-identity without slip, outputs everywhere they go.

Tolerances: bit-identity where the belt never slips (the stick phase is the
flexible model's own loop); the friction law exactly while slipping
(|Q| = Q_max(omega_M) to 1e-12 relative); the offline energy record to 1e-3
of the input work (trapezoidal quadrature on the output grid).
"""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from belt_drive_ros.core.model import make_model
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import SLIP_CSV_COLUMNS, simulate
from belt_drive_ros.core.slip import SlippingBeltModel
from belt_drive_ros.io.recording import SLIP_FLOAT_OUTPUTS, write_result_mcap


@pytest.fixture(scope="module")
def truck():
    # 0.5 ms: the energy record's trapezoidal quadrature on the output grid is O(dt^2) (test below)
    return simulate(load_scene("truck_compressor").with_overrides(duration=1.0, method="etd2", dt=5e-4))


def test_make_model_knows_slipping():
    p = load_scene("truck_compressor").params
    assert isinstance(make_model("slipping", p), SlippingBeltModel)
    with pytest.raises(ValueError, match="slipping"):
        make_model("sliding", p)


def test_auto_goes_on_to_slipping_and_says_why(truck):
    assert truck.model == "slipping"
    reason = truck.choice.reason
    assert reason.startswith("slipping: transmitted force reaches the capstan limit") and "at t = " in reason
    # one run on the slipping engine: the onset it names lies in the first step where the flexible run passes the limit
    onset = truck.choice.limit_time
    assert truck.events[0][:2] == ("onset", onset) and f"at t = {onset:.3g} s" in reason
    p = truck.scene.params
    flex = simulate(truck.scene, model="flexible")
    v = p.r_2 * p.gear_ratio * flex["omega_M"]
    q_max = 2.0 * (p.F_0 - p.belt_mass * v**2) * np.tanh(0.5 * p.mu / np.sin(0.5 * p.groove_angle) * p.wrap_angle)
    k = int(np.argmax(np.abs(flex["belt_torque"] / p.r_3) > q_max))
    assert k > 0 and flex.time[k - 1] < onset <= flex.time[k]
    # it slips where the flexible model went past the limit, and sticks again
    kinds = [e[0] for e in truck.events]
    assert kinds[:2] == ["onset", "restick"]
    o = truck.outputs
    assert 0.0 < np.mean(o["slip"]) < 0.5
    # while slipping the belt passes exactly the friction limit
    q = o["belt_torque"] / truck.scene.params.r_3
    slipping = o["slip"]
    qmax = truck.scene.params.friction_limit(o["omega_M"][slipping])
    np.testing.assert_allclose(np.abs(q[slipping]), qmax, rtol=1e-12)
    assert np.all(np.abs(o["friction_use"]) <= 1.0 + 1e-9)
    # the deflection splits into elastic + slip parts
    np.testing.assert_allclose(o["relative_deflection"], o["elastic_deflection"] + o["slip_angle"], rtol=1e-12, atol=1e-15)


def test_scene_within_the_limit_does_not_pay_for_slip():
    scene = load_scene("truck_compressor").with_overrides(duration=0.4)  # the compressor loads at 0.5 s
    auto = simulate(scene)
    flexible = simulate(scene, model="flexible")
    assert auto.model == "flexible"
    assert np.array_equal(auto.states, flexible.states)
    # explicitly slipping, never reaching the limit: the flexible model's states bit for bit
    slipping = simulate(scene, model="slipping")
    assert not slipping.events and not np.any(slipping.outputs["slip"])
    assert np.array_equal(slipping.outputs["omega_M"], flexible.outputs["omega_M"])
    assert np.array_equal(slipping.outputs["omega_3"], flexible.outputs["omega_3"])


def test_energy_record_balances(truck):
    e = truck.energy
    stored = e["kinetic"] + e["potential"] - e["kinetic"][0] - e["potential"][0]
    residual = e["input_work"] - stored - e["dissipated"] - e["friction"]
    assert e["friction"][-1] > 0.0
    assert np.max(np.abs(residual)) < 1e-3 * np.max(np.abs(e["input_work"]))


def test_csv_and_mcap_carry_the_slip_outputs(truck, tmp_path):
    path = tmp_path / "run.csv"
    truck.to_csv(path)
    with open(path) as f:
        header = next(csv.reader(f))
    assert set(SLIP_CSV_COLUMNS) <= set(header)
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    col = header.index("slip_speed")
    np.testing.assert_allclose(data[:, col], truck.outputs["slip_speed"], rtol=1e-11, atol=1e-12)
    bag = tmp_path / "run.mcap"
    write_result_mcap(truck, bag)
    with open(bag, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        got = {}
        for _s, ch, _m, msg in reader.iter_decoded_messages():
            got.setdefault(ch.topic, []).append(msg.data if hasattr(msg, "data") else None)
    stride = int(round(1.0 / (truck.scene.output_rate * truck.dt)))  # 1 kHz output of a 0.5 ms run
    for topic, signal in SLIP_FLOAT_OUTPUTS:
        values = np.array(got["/" + topic], dtype=float)
        np.testing.assert_array_equal(values, np.asarray(truck.outputs[signal], dtype=float)[::stride])


def test_bsg_start_slips_at_breakaway_then_sticks():
    run = simulate(load_scene("bsg_start"))
    assert run.model == "slipping"
    kinds = [e[0] for e in run.events]
    assert kinds[0] == "onset" and "restick" in kinds
    t_on = run.events[0][1]
    assert t_on < 0.06  # during the inverter ramp: breakaway torque beyond the belt's capacity
    o, p = run.outputs, run.scene.params
    # the BSG pulley runs ahead of the crank while slipping (positive slip speed), not after the last re-stick
    assert np.max(o["slip_speed"]) > 1.0
    last = max(e[1] for e in run.events)
    assert np.all(o["slip_speed"][run.time > last + 1e-9] == 0.0) or kinds[-1] == "onset"
    # belt torque at the crank pinned at r_3 Q_max(omega_M) while slipping
    s = o["slip"]
    np.testing.assert_allclose(o["belt_torque"][s], p.r_3 * p.friction_limit(o["omega_M"][s]), rtol=1e-12)


def test_choose_model_has_three_tiers_and_names_the_peak():
    """auto: the frequency rule picks the linear tier, its run's peak |Q| / Q_max decides on slipping."""
    from belt_drive_ros.core.fidelity import choose_model

    scene = load_scene("truck_compressor").with_overrides(duration=1.0)
    choice = choose_model(scene)
    assert (choice.model, choice.linear) == ("slipping", "flexible")
    # independent check of the peak: the flexible run's net force against the capstan law
    p = scene.params
    flex = simulate(scene, model="flexible")
    v = p.r_2 * p.gear_ratio * flex["omega_M"]
    q_max = 2.0 * (p.F_0 - p.belt_mass * v**2) * np.tanh(0.5 * p.mu / np.sin(0.5 * p.groove_angle) * p.wrap_angle)
    ratio = np.abs(flex["belt_torque"] / p.r_3) / q_max
    k = int(np.argmax(ratio))
    assert choice.limit_ratio == pytest.approx(ratio[k], rel=1e-12)
    assert choice.limit_time == flex.time[k]
    assert choice.reason.startswith(f"slipping: peak transmitted force {ratio[k]:.2f} x the capstan limit")
    assert f"at t = {flex.time[k]:.3g} s" in choice.reason and "flexible:" in choice.reason
    # within the limit (before the compressor loads at 0.5 s) the linear tier stays, with its margin
    calm = choose_model(scene.with_overrides(duration=0.4))
    assert calm.model == calm.linear == "flexible" and 0.0 < calm.limit_ratio < 1.0
    assert choose_model(scene, check_slip=False).model == "flexible"


def test_outputs_of_one_sample_equal_the_run_outputs_bit_for_bit(truck):
    """The node's one-sample outputs (plain floats) equal the offline array outputs at every sample, bit for bit."""
    m = SlippingBeltModel(truck.scene.params)
    modes = truck.outputs["slip"].astype(int)
    Q = truck.outputs["belt_torque"] / truck.scene.params.r_3
    sigmas = np.where(modes == 1, np.sign(Q), 0.0)
    full = m.outputs(truck.states, truck.inputs, modes, sigmas)
    assert np.any(modes == 1) and np.any(modes == 0)
    for k in range(0, truck.time.size, 7):
        one = m.outputs(truck.states[k], truck.inputs[k], modes[k], sigmas[k])
        for name, values in full.items():
            assert np.asarray(one[name]).tobytes() == np.asarray(values[k]).tobytes(), (name, k)


@pytest.mark.parametrize("belt_mass", [0.0, 0.05])
def test_a_slipping_run_past_the_speed_limit_is_refused_as_the_linear_models_are(belt_mass):
    """A drive torque no belt can hold: the motor runs away while the belt slips. Past 1e5 rad/s the run is refused
    with the divergence error the rigid and flexible models raise, whichever slip phase steps it (massless: the
    state [y, Q] of 6 entries, omega_M its third; with belt mass: y alone)."""
    from belt_drive_ros.core.errors import SimulationDivergedError
    from belt_drive_ros.core.sources import Constant

    paper = load_scene("paper")
    scene = paper.with_overrides(model="slipping", duration=3.0, drive=Constant(1.0e4), load=Constant(0.0),
                                 params=paper.params.replace(belt_mass=belt_mass))  # fmt: skip
    with pytest.raises(SimulationDivergedError, match=r"model slipping.*beyond 100000 rad/s"):
        simulate(scene)
    short = simulate(scene.with_overrides(duration=0.1))  # before the limit: a run, its speeds within it
    assert short.model == "slipping" and 1.0e3 < np.abs(short.states[:, 2]).max() <= 1.0e5


def test_auto_names_t0_as_the_onset_of_a_run_that_starts_slipping():
    # an initial deflection whose belt force is past the capstan limit: the run slips from its first sample and
    # its first event is a restick; the reason named that restick's time as where the limit was reached
    truck = load_scene("truck_compressor")
    start = dataclasses.replace(truck.initial_state, relative_deflection=0.05)
    scene = truck.with_overrides(duration=0.05, initial_state=start)
    run = simulate(scene)
    assert run.model == "slipping" and run.outputs["slip"][0]
    assert run.events[0][0] == "restick"
    assert run.choice.limit_time == 0.0 and "at t = 0 s" in run.choice.reason
