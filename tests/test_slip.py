"""The slipping belt (core/slip.py) against closed forms and an independent event-located reference.

Tolerances, per quantity:
* friction limit: the capstan law itself, to 1e-12 relative;
* event times: 1e-9 s against scipy DOP853 with events at rtol = atol = 1e-12;
  the force at the located onset: 1e-9 relative to Q_max;
* closed-form slip phase (c = 0, constant torques): speeds and the re-stick
  time to 1e-10 relative (exact method: exact flow, rounding only);
* energy balance: 1e-10 of the input work for the exact method with c = b = 0
  (every term has a closed form); 1e-6 with damping (losses by Simpson's rule);
* F_0 -> large: the flexible model's states to 1e-9 relative;
* fixed-step methods against DOP853: observed order of etd2 within 0.15 of 2
  with event location, and 50x larger error at the finest step without it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.integrate
import scipy.optimize

from belt_drive_ros.core.errors import ParameterError
from belt_drive_ros.core.model import FlexibleBeltModel
from belt_drive_ros.core.params import BeltDriveParams
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import Simulator
from belt_drive_ros.benchmarks.slip_reference import HybridStepper, RegularisedFriction, reference_hybrid
from belt_drive_ros.core.slip import SLIP, STICK, SlippingBeltModel


def _const(value):
    return lambda t, a, w: value


# ------------------------------------------------------------ the limit
@pytest.mark.parametrize("groove, mass, omega", [(math.pi, 0.0, 0.0), (math.radians(40), 0.0, 0.0), (math.radians(40), 0.12, 150.0)])
def test_friction_limit_satisfies_the_capstan_law(groove, mass, omega):
    p = BeltDriveParams(groove_angle=groove, belt_mass=mass, mu=0.35, wrap_angle=2.6, F_0=600.0)
    q = p.friction_limit(omega)
    mu_eff = 0.35 / math.sin(groove / 2)
    fc = mass * (p.r_2 * p.gear_ratio * omega) ** 2
    tight, slack = p.F_0 + q / 2, p.F_0 - q / 2
    assert (tight - fc) == pytest.approx((slack - fc) * math.exp(mu_eff * 2.6), rel=1e-12)
    assert p.mu_effective == pytest.approx(mu_eff, rel=1e-15)
    if groove == math.pi:
        assert p.mu_effective == p.mu  # flat belt: no groove factor, bit for bit


def test_groove_and_mass_are_validated_and_default_to_flat_massless():
    p = BeltDriveParams()
    assert p.groove_angle == math.pi and p.belt_mass == 0.0 and p.capstan_ratio == math.exp(p.mu * p.wrap_angle)
    for bad in (0.0, -0.1, 3.5):
        with pytest.raises(ParameterError, match="^groove_angle:"):
            BeltDriveParams(groove_angle=bad)
    with pytest.raises(ParameterError, match="^belt_mass:"):
        BeltDriveParams(belt_mass=-0.1)
    assert p.friction_limit(1e6) == p.friction_limit(0.0)  # massless: no speed dependence
    assert BeltDriveParams(belt_mass=0.1).friction_limit(1e6) == 0.0  # F_c > F_0: the belt lifts off


# ------------------------------------------------------------ onset
def test_onset_when_belt_torque_reaches_r3_qmax_located_between_grid_times():
    """Wheel 3 held (huge inertia), drive torque ramped slowly: slip starts at T_b = r_3 Q_max."""
    p = BeltDriveParams(I_3=1.0e6, c=500.0, mu=0.3, F_0=300.0)  # c: the ramp's start rings down by the onset
    m = SlippingBeltModel(p)
    qmax = m.limit(0.0)
    rate = 40.0  # N m/s at wheel M
    drive = lambda t, a, w: rate * t  # noqa: E731
    load = _const(0.0)
    dt = 1e-3
    time = np.arange(0.0, 0.8 + dt / 2, dt)
    run = HybridStepper(m, drive, load, "etd2").run(time, np.zeros(5))  # etd2: exact for a ramp
    onset = [e for e in run.events if e.kind == "onset"][0]
    # quasi-static estimate: the drive torque carried by the belt, M = g r_2 Q, lagging by
    # b_f / K (the steady ramp response of the drive side on the belt spring K = 2 k (r_2 g)^2)
    K = 2.0 * p.k * (p.r_2 * p.gear_ratio) ** 2
    t_qs = p.gear_ratio * p.r_2 * qmax / rate + p.bearing_damping_drive_side / K
    assert onset.time == pytest.approx(t_qs, rel=1e-3)
    # the force at the located event is the limit, and the event is not on the grid
    assert abs(p.r_3 * (m.q_row @ onset.state)) == pytest.approx(p.r_3 * qmax, rel=1e-9)
    assert abs(onset.time / dt - round(onset.time / dt)) > 1e-3
    ref = reference_hybrid(m, drive, load, time[time <= 0.75], np.zeros(5), rtol=1e-12, atol=1e-12)
    assert ref.events[0].kind == "onset"
    assert onset.time == pytest.approx(ref.events[0].time, abs=1e-9)
    # the grid samples before the event stick, those after slip
    k = int(onset.time / dt)
    assert run.mode[k] == STICK and run.mode[k + 1] == SLIP


def test_onset_in_the_compiled_engine_when_belt_torque_reaches_r3_qmax():
    """The same onset through the package's engine (SlippingSimulator: the compiled hybrid loop, the torques as
    data): at the quasi-static estimate, the force at the located event on the limit, off the grid, and at the
    DOP853 reference's time."""
    from belt_drive_ros.core.slip_run import SlippingSimulator
    from belt_drive_ros.core.sources import Constant, Ramp

    p = BeltDriveParams(I_3=1.0e6, c=500.0, mu=0.3, F_0=300.0)
    m = SlippingBeltModel(p)
    qmax, rate, dt = m.limit(0.0), 40.0, 1e-3
    sim = SlippingSimulator(p, Ramp(0.0, rate * 0.8, 0.0, 0.8), Constant(0.0), "etd2", dt, check_stability=False)
    time, states, modes, _ = sim.run(0.8, np.zeros(5))
    assert sim._compiled() is not None
    onset = [e for e in sim.events if e.kind == "onset"][0]
    K = 2.0 * p.k * (p.r_2 * p.gear_ratio) ** 2
    assert onset.time == pytest.approx(p.gear_ratio * p.r_2 * qmax / rate + p.bearing_damping_drive_side / K, rel=1e-3)
    assert abs(p.r_3 * (m.q_row @ onset.state)) == pytest.approx(p.r_3 * qmax, rel=1e-9)
    assert abs(onset.time / dt - round(onset.time / dt)) > 1e-3
    ref = reference_hybrid(m, lambda t, a, w: rate * t, _const(0.0), time[time <= 0.75], np.zeros(5), rtol=1e-12, atol=1e-12)
    assert onset.time == pytest.approx(ref.events[0].time, abs=1e-9)
    k = int(onset.time / dt)
    assert modes[k] == STICK and modes[k + 1] == SLIP


# ------------------------------------------------------ closed-form slip
@pytest.mark.parametrize("damped", [False, True])
def test_slip_phase_with_c0_and_constant_torques_matches_closed_forms(damped):
    b = dict(b_M=0.4, b_1=0.0, b_2=0.0, b_3=0.02) if damped else dict(b_M=0.0, b_1=0.0, b_2=0.0, b_3=0.0)
    p = BeltDriveParams(c=0.0, mu=0.3, F_0=300.0, **b)
    m = SlippingBeltModel(p)
    qmax, g, r2, r3 = m.limit(0.0), p.gear_ratio, p.r_2, p.r_3
    If, I3, bf, b3 = p.inertia_drive_side, p.I_3, p.bearing_damping_drive_side, p.b_3
    Md, Ml, w0 = 5.0, 2.0, 60.0
    y0 = np.array([0.0, qmax / (2 * p.k * r3), w0, 0.0, 0.0])  # drive spinning, wheel 3 at rest: slipping
    aM, a3 = Md - g * r2 * qmax, r3 * qmax - Ml  # net torques while slipping

    def speeds(t):
        if not damped:
            return w0 + aM / If * t, a3 / I3 * t
        wM_inf, w3_inf = aM / bf, a3 / b3
        return wM_inf + (w0 - wM_inf) * np.exp(-bf * t / If), w3_inf * (1 - np.exp(-b3 * t / I3))

    def slip_speed(t):
        wM, w3 = speeds(t)
        return r2 * g * wM - r3 * w3

    t_stick = scipy.optimize.brentq(slip_speed, 0.0, 5.0, xtol=1e-15) if damped else -slip_speed(0.0) / (r2 * g * aM / If - r3 * a3 / I3)
    dt = 1e-3
    time = np.arange(0.0, 2 * t_stick, dt)
    run = HybridStepper(m, _const(Md), _const(Ml), "exact").run(time, y0, mode0=SLIP, sigma0=1.0)
    assert [e.kind for e in run.events][:1] == ["restick"]
    assert run.events[0].time == pytest.approx(t_stick, rel=1e-10)
    before = time < t_stick
    wM, w3 = speeds(time[before])
    assert np.allclose(run.states[before, 2], wM, rtol=1e-10, atol=0)
    assert np.allclose(run.states[before, 3], w3, rtol=1e-10, atol=1e-10)
    out = m.outputs(run.states, np.tile([Md, Ml], (time.size, 1)), run.mode, run.sigma)
    assert np.allclose(out["slip_speed"][before], slip_speed(time[before]), rtol=1e-10, atol=1e-10)
    assert np.all(out["friction_use"][before] == 1.0) and np.all(out["slip"][before])
    # accumulated slip: the integral of the slip speed up to the re-stick, then held
    s_end = scipy.integrate.quad(slip_speed, 0.0, t_stick, epsabs=1e-14, epsrel=1e-13)[0]
    assert run.events[0].state[4] == pytest.approx(s_end, rel=1e-9)
    assert out["slip_angle"][-1] == pytest.approx(s_end / r3, rel=1e-9)
    assert out["relative_deflection"][-1] == pytest.approx(out["elastic_deflection"][-1] + s_end / r3, rel=1e-12)


# ------------------------------------------------------------- energy
def _stick_slip_case(c, b):
    p = BeltDriveParams(c=c, b_M=b, b_1=0.0, b_2=0.0, b_3=b / 10, mu=0.3, F_0=300.0)
    return p, SlippingBeltModel(p)


def test_energy_balance_over_repeated_stick_slip_exact_method_to_rounding():
    """c = b = 0, torques constant over each step (a square-wave load on a binary grid).

    W_in = sum_k (M_d dphi_M - M_L dphi_3) over the steps = dT + dV + Q_max sum |ds|:
    every term in closed form, so the balance holds to rounding.
    """
    p, m = _stick_slip_case(0.0, 0.0)
    Md = 30.0
    load = lambda t, a, w: 15.0 + 10.0 * (1.0 if math.floor(t * 16) % 2 == 1 else -1.0)  # noqa: E731
    time = np.arange(0, 615) / 2048.0  # exact binary times: the load switches on the grid
    run = HybridStepper(m, _const(Md), load, "exact").run(time, np.zeros(5))
    kinds = [e.kind for e in run.events]
    assert kinds.count("onset") >= 2 and kinds.count("restick") >= 2  # repeated stick-slip
    ys = run.states
    ml = np.array([load(t, 0, 0) for t in time[:-1]])
    work = float(np.sum(Md * np.diff(ys[:, 0]) - ml * np.diff(m.phi_3(ys))))
    stored = (m.kinetic_energy(ys[-1]) + m.potential_energy(ys[-1])) - (m.kinetic_energy(ys[0]) + m.potential_energy(ys[0]))
    friction, start = 0.0, None  # Q_max |ds| per slip phase (s is monotone in a phase: sigma s' >= 0)
    for e in run.events:
        if e.kind == "onset":
            start, sig = e.state[4], e.sigma
        else:
            friction += m.limit(0.0) * sig * (e.state[4] - start)
            start = None
    if start is not None:
        friction += m.limit(0.0) * sig * (ys[-1, 4] - start)
    assert friction > 0.05 * abs(work)
    assert work == pytest.approx(stored + friction, rel=1e-10)


def test_energy_balance_with_damping():
    p, m = _stick_slip_case(20.0, 0.05)
    load = lambda t, a, w: 15.0 + 10.0 * math.sin(2 * math.pi * 8 * t)  # noqa: E731
    drive = _const(30.0)
    time = np.linspace(0.0, 0.3, 30001)  # fine grid: the power integrals by Simpson's rule
    run = HybridStepper(m, drive, load, "etd4").run(time, np.zeros(5))
    assert len(run.events) >= 6
    u = np.column_stack([np.full(time.size, 30.0), [load(t, 0, 0) for t in time]])
    p_in = m.input_power(run.states, u)
    parts = m.force_parts(run.states, run.mode, run.sigma)
    p_d = m.damping_power(run.states, run.mode, run.sigma, parts)
    p_f = m.friction_power(run.states, run.mode, run.sigma, parts)
    assert np.all(p_f >= -1e-9) and np.all(p_d >= 0.0)
    work = scipy.integrate.simpson(p_in, x=time)
    losses = scipy.integrate.simpson(p_d + p_f, x=time)
    friction = scipy.integrate.simpson(p_f, x=time)
    stored = m.kinetic_energy(run.states[-1]) + m.potential_energy(run.states[-1])
    assert friction > 0.05 * work
    assert work == pytest.approx(stored + losses, rel=1e-6)


# ------------------------------------------------- the flexible limit
def test_large_preload_reproduces_the_flexible_model():
    scene = load_scene("truck_compressor")
    p = scene.params.replace(F_0=1.0e9)
    flex = FlexibleBeltModel(p)
    sim = Simulator(flex, scene.drive, scene.load, "etd2", scene.dt)
    x0 = scene.initial_state.vector("flexible", p.ratio)
    time, xs = sim.run(1.0, x0)
    m = SlippingBeltModel(p)
    run = HybridStepper(m, scene.drive.scalar_torque(), scene.load.scalar_torque(), "etd2").run(
        time, m.state_from_flexible(x0), breakpoints=sim.plant.breakpoints
    )
    assert not run.events and np.all(run.mode == STICK)
    assert np.allclose(m.phi_3(run.states), flex.outputs(xs, sim.plant.input_array(time, xs))["phi_3"], rtol=1e-9, atol=1e-9)
    assert np.allclose(run.states[:, 2:4], xs[:, 2:4], rtol=1e-9, atol=1e-9)
    assert np.allclose(run.states[:, 1], flex.relative_deflection(xs), rtol=1e-7, atol=1e-12)


# ----------------------------------------------- against DOP853, order
def _pulsating_scene():
    p = BeltDriveParams(mu=0.3, F_0=300.0)
    drive = lambda t, a, w: 20.0 + 40.0 * math.sin(2 * math.pi * 8 * t) - 0.2 * w  # noqa: E731
    load = lambda t, a, w: 10.0 + 0.01 * w  # noqa: E731
    return SlippingBeltModel(p), drive, load


def _errors(method, locate, ns, ref, m, drive, load, T=0.05):
    out = []
    for n in ns:
        time = np.linspace(0.0, T, n + 1)
        run = HybridStepper(m, drive, load, method, locate=locate).run(time, np.zeros(5))
        out.append(np.max(np.abs(run.states[:: n // 10, 2:4] - ref.states[:, 2:4])))
    return np.array(out)


def test_against_dop853_with_events_error_and_order():
    m, drive, load = _pulsating_scene()
    ref = reference_hybrid(m, drive, load, np.linspace(0.0, 0.05, 11), np.zeros(5), rtol=1e-13, atol=1e-13)
    assert [e.kind for e in ref.events] == ["onset", "restick"]  # stick - slip - stick
    run = HybridStepper(m, drive, load, "etd4").run(np.linspace(0.0, 0.05, 201), np.zeros(5))
    assert [e.kind for e in run.events] == ["onset", "restick"]
    for mine, theirs in zip(run.events, ref.events):
        assert mine.time == pytest.approx(theirs.time, abs=1e-9)
    ns = (100, 200, 400, 800)
    located = _errors("etd2", True, ns, ref, m, drive, load)
    order = np.log2(located[:-1] / located[1:])
    assert np.all(np.abs(order - 2.0) < 0.15), order
    sampled = _errors("etd2", False, ns[-1:], ref, m, drive, load)
    assert sampled[0] > 50 * located[-1]
    exact = _errors("exact", True, ns, ref, m, drive, load)  # torque sampled at the step start: order 1
    assert np.all(np.abs(np.log2(exact[:-1] / exact[1:]) - 1.0) < 0.1)
    assert _errors("etd4", True, (200,), ref, m, drive, load)[0] < 1e-7


# ------------------------------------------------------- regularised
def test_regularised_friction_approaches_coulomb_as_v_eps_shrinks():
    m, drive, load = _pulsating_scene()
    time = np.linspace(0.0, 0.05, 11)
    ref = reference_hybrid(m, drive, load, time, np.zeros(5), rtol=1e-12, atol=1e-12)
    errs = []
    for v_eps in (1e-2, 1e-3, 1e-4):
        states = RegularisedFriction(m, v_eps).run(np.linspace(0.0, 0.05, 501), np.zeros(5), drive, load, "Radau")
        errs.append(np.max(np.abs(states[::50, 2:4] - ref.states[:, 2:4])))
    assert errs[0] > errs[1] > errs[2] and errs[2] < 0.05 * errs[0]


@pytest.mark.parametrize("scene", ["truck_compressor", "bsg_start"])
@pytest.mark.parametrize("mode", [STICK, SLIP])
def test_compiled_modal_etd4_step_equals_the_matrix_etd4_step(scene, mode):
    """The compiled event step's etd4 step on the modal flow (partial steps of any length) is the integrator's
    ETDRK4 step, to rounding. The scene's torques depend on time, angle and speed (truck_compressor: the engine's
    firing harmonics, the compressor's schedule), the belt-mass friction force is the slip mode's third input."""
    from belt_drive_ros.core import kernel_slip
    from belt_drive_ros.core.integrators import make_integrator
    from belt_drive_ros.core.slip_run import SlippingSimulator

    s = load_scene(scene)
    sim = SlippingSimulator(s.params, s.drive, s.load, "etd4", s.dt, check_stability=False)
    m, arrays = sim.model, sim.hybrid._kernel
    Z, R, c, mats, guards, uses = arrays[:6]
    A, B = (m.A_stick, m.B_stick) if mode == STICK else (m.A_slip, m.B_slip)
    sigma = 0.0 if mode == STICK else 1.0

    def u(t, y):
        values = sim.inputs(t, y).tolist() + [sigma * m.limit(float(y[2]))]
        return np.array(values[: B.shape[1]])

    rng = np.random.default_rng(3)
    for h in (1e-5, 3e-4, 1e-3, 2e-3):
        y = np.array([1.0, 1e-3, 70.0, 80.0, 1e-3]) + rng.normal(size=5) * np.array([1.0, 1e-3, 5.0, 5.0, 1e-3])
        u0 = np.zeros(3)
        u0[: B.shape[1]] = u(0.6, y)
        modal = np.empty(5)
        work = np.full(kernel_slip.FLOW_WORK, np.nan), np.full(kernel_slip.FLOW_WORK, complex(np.nan, np.nan))
        kernel_slip._flow(mode, sigma, 0.6, y, h, math.inf, u0, Z, R, c, uses, *[kernel_slip.DISPATCHED] * 2,
                          *arrays[6:], modal, *work)
        matrix = make_integrator("etd4", A, B, h).step(0.6, y, u)
        np.testing.assert_allclose(modal, matrix, rtol=1e-13, atol=1e-13 * np.max(np.abs(matrix)))


@pytest.mark.parametrize("method", ["etd2", "etd4", "rk4"])
def test_slip_phases_of_a_belt_with_mass_in_the_loop_equal_the_hybrid_stepper(method):
    """bsg_start (belt mass, c > 0): the compiled loop with Q = sigma Q_max(omega_M) as an extra input gives the
    hybrid stepper's run (the method's flow step by step, events located in each step) to rounding, events alike."""
    from belt_drive_ros.core.slip_run import SlippingSimulator

    scene = load_scene("bsg_start").with_overrides(duration=0.5)
    dt = 2e-4 if method != "rk4" else 2e-5  # rk4: explicit, the slip mode's -k/c = -2.5e4 1/s needs h < 1.1e-4 s
    sim = SlippingSimulator(scene.params, scene.drive, scene.load, method, dt, check_stability=False)
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    time, states, modes, _ = sim.run(scene.duration, y0)
    assert sim.phase_stepper(("mass", 1.0)).loop is not None
    assert np.any(modes == SLIP) and sum(e.kind == "onset" for e in sim.events) >= 2
    # etd2/etd4: the hybrid stepper's every grid step by the compiled event step (the torques as data), against the
    # simulator's phases in the linear loop; rk4: the reference takes an event step's partial steps by rk4 in Python,
    # the simulator's compiled event step by etd4 (both fourth order): the elastic deflection differs by ~4e-9 of its
    # range there, the events are located by the same compiled location
    hs = HybridStepper(sim.model, sim.plant.scalar_drive, sim.plant.scalar_load, method,
                       data=(*sim.plant.data, sim.plant.uses_angle))  # fmt: skip
    assert (hs._kernel is not None) == (method != "rk4") and (hs._located is not None) == (method == "rk4")
    ref = hs.run(time, y0, breakpoints=sim.breakpoints)
    assert [e.kind for e in ref.events] == [e.kind for e in sim.events]
    np.testing.assert_allclose([e.time for e in sim.events], [e.time for e in ref.events], rtol=0.0, atol=1e-12)
    scale = np.max(np.abs(ref.states), axis=0)
    error = np.max(np.abs(states - ref.states) / scale, axis=0)  # per coordinate, relative to its range
    assert np.all(error < (1e-10 if method != "rk4" else 1e-8)), error
    np.testing.assert_array_equal(modes, ref.mode)


def test_span_forces_name_the_stretched_span_tight_in_every_model_when_the_load_overruns():
    """The tight span is the one the belt torque stretches, whichever way it acts: with the load driving the belt
    (T_b < 0) the slipping model used to report F_0 + Q/2 with Q signed, so its 'tight' span was the slacker one
    while the rigid and flexible models' was the tighter (F_0 +- |Q|/2). Every model: F_tight >= F_0 >= F_slack and
    F_tight - F_slack = |T_b| / r_3; the slipping model that never slips equals the flexible one."""
    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.scenes import scene_from_mapping

    scene = scene_from_mapping({"extends": "paper", "duration": 1.0, "method": "etd4", "dt": 1e-3,
                                "params": {"b_M": 0.05, "c": 5.0},
                                "drive": {"type": "constant", "value": 0.0},
                                "load": {"type": "constant", "value": -1.0}})  # fmt: skip
    runs = {m: simulate(scene, model=m).outputs for m in ("rigid", "flexible", "slipping")}
    F_0, r_3 = scene.params.F_0, scene.params.r_3
    for model, out in runs.items():
        tb = np.asarray(out["belt_torque"])
        assert tb[-1] < -0.5, model  # the load overruns: the belt brakes it
        assert np.all(out["span_force_tight"] >= F_0) and np.all(out["span_force_slack"] <= F_0), model
        assert np.allclose(out["span_force_tight"] - out["span_force_slack"], np.abs(tb) / r_3, rtol=1e-12, atol=1e-9)
    assert not np.any(runs["slipping"]["slip"])
    for key in ("span_force_tight", "span_force_slack"):
        assert np.allclose(runs["slipping"][key], runs["flexible"][key], rtol=0, atol=1e-9), key
