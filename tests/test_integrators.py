"""Integrators: measured order, exactness of the ZOH step, the step loop against the step protocol, tableaus.

Scene for the orders: damped flexible belt (paper geometry, k = 2e4 N/m,
omega_n = 66 rad/s), drive = motor torque-speed line + 8 Hz sine, load =
polynomial in speed + compressor harmonic in wheel-3 angle, 0.3 s from
60 rad/s. Every torque is smooth in t, angle and speed along the run (speeds
stay positive), so each method shows its classical order.

Tolerances (one per quantity, with the reason)
----------------------------------------------
* measured order (log2 of the error ratio between the two finest steps):
  +/- 0.1 of the nominal order. The asymptotic constant is reached at
  omega_n h <= 0.05 (0.0031 for Euler, whose error constant grows like
  exp(omega_n^2 h t / 2) on an undamped-ish mode); 0.1 leaves room for the
  next error term and for 1e-13 reference error.
* reference: DOP853 at rtol 1e-13, atol 1e-12; its own error (checked
  against rtol 1e-12) is ~1e-12 relative, below the finest RK4 error (4e-8)
  by 4 orders.
* exact step vs scipy.signal.cont2discrete(zoh): 1e-13 relative to the
  matrix norms (two expm evaluations of the same block matrix).
* exact method vs DOP853 for piecewise-constant/constant torques: 1e-10
  relative, step-size independent (DOP853's own error ~1e-12; the ZOH error
  is rounding). A first-order method would be off by ~1e-4 here.
* the simulator's compiled loop and the linear one-step map (Phi, G_j) vs a
  bare step() loop: 1e-11 relative; they sum the same terms in different
  orders (measured ~2e-13 over 1000 steps).
* scipy adaptive methods vs the exact solution: global error <= 100 rtol,
  1000 rtol for BDF (rtol bounds the *local* error; the global one
  accumulates over the hundreds of steps of ~3 belt periods, most for the
  low-order multistep BDF, whose phase error on an oscillatory mode is
  largest -- measured 0.3..19 rtol for the others, 60..190 rtol for BDF),
  and it falls by > 100x when rtol falls 1000x (the option reaches the
  solver).
* step() derived from the StageScheme vs the textbook update formula written
  out in the test: 1e-13 relative (same products, other summation order).
* mode_growths (read off the one-step map) vs the closed-form |R(h lambda)|:
  1e-12 relative; 1e-6 for symplectic Euler, whose oscillator for a real
  lambda has a double root that eigvals resolves to ~sqrt(eps).
* exact_linear flag: Phi equals expm(A h) to 1e-12 relative at omega_n h = 3.3
  (rounding of two expm evaluations) exactly for the flagged methods; the
  others are off by O(1).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg
import scipy.signal

from belt_drive_ros.core.errors import IntegratorError, SceneError
from belt_drive_ros.core.integrators import (
    ADAPTIVE_METHODS,
    FIXED_STEP_METHODS,
    REGISTRY,
    ExplicitRungeKutta,
    FixedStepIntegrator,
    describe_methods,
    make_integrator,
)
from belt_drive_ros.core.model import FlexibleBeltModel, RigidBeltModel
from belt_drive_ros.core.params import BeltDriveParams
from belt_drive_ros.core.simulate import Plant, Simulator
from belt_drive_ros.core.sources import Compressor, Constant, MotorCurve, Polynomial, Ramp, Sine, Table, TorqueProfile

GEOMETRY = dict(I_M=0.02, I_1=0.004, I_2=0.003, I_3=0.03, r_M=0.04, R_1=0.06, r_1=0.03, R_2=0.05, r_2=0.06, r_3=0.05)
PARAMS = BeltDriveParams(**GEOMETRY, k=2.0e4, c=3.0, b_M=1e-3, b_1=5e-4, b_2=5e-4, b_3=1e-3)

ORDER_TOL = 0.1
RTOL_C2D = 1e-13
RTOL_EXACT_VS_DOP853 = 1e-10
RTOL_STEP_LOOP = 1e-11
ADAPTIVE_GLOBAL_FACTOR = 100.0
ADAPTIVE_GLOBAL_FACTOR_BDF = 1000.0  # multistep, largest phase error (module docstring)


class SumProfile(TorqueProfile):
    """Sum of profiles (test helper): e.g. a motor curve plus a sinusoidal disturbance."""

    kind = "test_sum"

    def __init__(self, *parts: TorqueProfile):
        self.parts = parts
        self.state_dependent = any(p.state_dependent for p in parts)

    def torque(self, t, angle, speed):
        return sum(p.torque(t, angle, speed) for p in self.parts)


DRIVE = SumProfile(MotorCurve(stall_torque=12.0, no_load_speed=160.0), Sine(mean=0.0, amplitude=3.0, frequency=8.0))
LOAD = SumProfile(Polynomial(c0=0.5, c1=0.02, c2=2e-4), Compressor(mean_torque=0.0, cylinders=2, harmonics=(1.0,)))
DURATION = 0.3
X0 = np.array([0.0, 0.0, 60.0, 60.0 * PARAMS.ratio])


def _dop853(model, plant, x0, t_span, rtol=1e-13, atol=1e-12):
    sol = scipy.integrate.solve_ivp(
        lambda t, x: model.A @ x + model.B @ plant.inputs(t, x), t_span, x0, method="DOP853", rtol=rtol, atol=atol
    )
    assert sol.success
    return sol.y[:, -1]


@pytest.fixture(scope="module")
def smooth_reference():
    model = FlexibleBeltModel(PARAMS)
    plant = Plant(model, DRIVE, LOAD)
    assert DRIVE.state_dependent  # closed loop: the torques read the state
    ref = _dop853(model, plant, X0, (0.0, DURATION))
    looser = _dop853(model, plant, X0, (0.0, DURATION), rtol=1e-12, atol=1e-11)
    T = model.lagrange_map  # errors on the wheel coordinates [phi_M, phi_3, omega_M, omega_3]
    scale = np.abs(T @ ref)
    assert np.max(np.abs(T @ (looser - ref)) / scale) < 1e-10  # the reference is converged
    return model, ref, scale


#: step counts over DURATION by nominal order (the registry's): the two finest give the measured order.
STEPS_BY_ORDER = {1: [200, 400, 800], 2: [200, 400, 800], 4: [50, 100, 200], 5: [25, 50, 100]}
#: ... except where the asymptotic range starts later (Euler's error constant grows like
#: exp(omega_n^2 h t / 2); RK4's next error term is large at omega_n h = 0.4).
STEPS = {"euler": [1600, 3200, 6400], "rk4": [100, 200, 400]}


def test_registry_lists_every_method_once_with_its_entry():
    assert {name for name, cls in REGISTRY.items() if issubclass(cls, FixedStepIntegrator)} == set(FIXED_STEP_METHODS)
    assert set(FIXED_STEP_METHODS) | set(ADAPTIVE_METHODS) == set(REGISTRY)
    for name, cls in REGISTRY.items():
        assert cls.name == name and cls.summary and "\n" not in cls.summary
        assert cls.fixed_step == (name in FIXED_STEP_METHODS)
        assert (cls.order is not None) == cls.fixed_step
    assert [n for n in FIXED_STEP_METHODS if REGISTRY[n].exact_linear] == ["exact", "etd2", "etd4", "lawson5"]
    help_text = describe_methods()
    assert all(f"  {name} " in help_text for name in REGISTRY)


@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_measured_order_state_dependent_torque(method, smooth_reference):
    model, ref, scale = smooth_reference
    T = model.lagrange_map
    nominal = REGISTRY[method].order
    steps = STEPS.get(method, STEPS_BY_ORDER[nominal])
    errors = []
    inputs = Plant(model, DRIVE, LOAD).inputs  # (the sum is Python only: the method's own step; the kernel
    for n in steps:  # equals it on compiled profiles, test_simulator_stepwise_equals_step_protocol_state_dependent)
        states = _manual_step_loop(make_integrator(method, model.A, model.B, DURATION / n), inputs, X0, n)
        errors.append(np.max(np.abs(T @ (states[-1] - ref)) / scale))  # wheel coordinates [phi_M, phi_3, ...]
    errors = np.array(errors)
    orders = np.log2(errors[:-1] / errors[1:])
    assert np.all(np.diff(errors) < 0), errors
    assert orders[-1] == pytest.approx(nominal, abs=ORDER_TOL), (errors, orders)
    assert model.__class__ is FlexibleBeltModel



@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_exact_linear_flag_is_true_of_the_one_step_map(method):
    """``exact_linear``: Phi is e^{Ah} to rounding at a step far beyond any explicit limit; otherwise it is not."""
    model = FlexibleBeltModel(PARAMS)
    dt = 0.05  # omega_n h = 3.3
    Phi = make_integrator(method, model.A, model.B, dt).linear_step().Phi
    expm = scipy.linalg.expm(model.A * dt)
    error = np.max(np.abs(Phi - expm)) / np.max(np.abs(expm))
    assert (error < 1e-12) == REGISTRY[method].exact_linear, error


# ------------------------------------------------------------------ exact ZOH
@pytest.mark.parametrize("dt", [1e-4, 3.7e-3, 0.05])
@pytest.mark.parametrize("model_cls", [FlexibleBeltModel, RigidBeltModel])
def test_exact_step_equals_cont2discrete(model_cls, dt):
    model = model_cls(PARAMS)
    n = model.A.shape[0]
    Phi_ref, Gamma_ref, *_ = scipy.signal.cont2discrete((model.A, model.B, np.eye(n), np.zeros((n, 2))), dt, method="zoh")
    step = make_integrator("exact", model.A, model.B, dt).linear_step()
    assert step.nodes == (0.0,)
    assert np.max(np.abs(step.Phi - Phi_ref)) <= RTOL_C2D * np.max(np.abs(Phi_ref))
    assert np.max(np.abs(step.gains[0] - Gamma_ref)) <= RTOL_C2D * np.max(np.abs(Gamma_ref))


def test_exact_method_is_exact_for_constant_torque():
    """Exact trajectory = DOP853 at tight tolerance, independent of the step (even far above 1/omega_n)."""
    model = FlexibleBeltModel(PARAMS)
    drive, load = Constant(5.0), Constant(2.0)
    plant = Plant(model, drive, load)
    ref = _dop853(model, plant, X0, (0.0, DURATION))
    for n in (3, 30, 3000):  # omega_n h = 6.6 ... 0.0066
        _, states = Simulator(model, drive, load, "exact", DURATION / n).run(DURATION, X0)
        assert np.max(np.abs(states[-1] - ref) / np.abs(ref)) < RTOL_EXACT_VS_DOP853


def test_exact_method_is_exact_for_piecewise_constant_torque():
    """Held torque (a ROS message per step): rounding-level error, any step dividing the hold period."""
    model = FlexibleBeltModel(PARAMS)
    hold = 2.0**-6  # s; binary fractions so the breakpoints fall exactly on the time grid
    times = hold * np.arange(20)
    rng = np.random.default_rng(4)
    drive = Table(times=tuple(times), values=tuple(rng.uniform(0.0, 10.0, times.size)), interpolation="previous")
    load = Table(times=tuple(times), values=tuple(rng.uniform(0.0, 4.0, times.size)), interpolation="previous")
    plant = Plant(model, drive, load)
    x = X0.copy()
    for t0 in times:  # reference: DOP853 restarted at every breakpoint
        x = _dop853(model, plant, x, (t0, t0 + hold))
    duration = hold * times.size
    errors = {}
    for dt in (hold, hold / 4, hold / 64):
        sim = Simulator(model, drive, load, "exact", dt)
        _, states = sim.run(duration, X0)
        errors[dt] = np.max(np.abs(states[-1] - x) / np.abs(x))
        assert errors[dt] < RTOL_EXACT_VS_DOP853, errors
    # Same torque, but sampled mid-hold by a first-order scheme would be off by O(1e-3): contrast.
    _, euler_states = Simulator(model, drive, load, "symplectic_euler", hold / 4).run(duration, X0)
    assert np.max(np.abs(euler_states[-1] - x) / np.abs(x)) > 1e3 * RTOL_EXACT_VS_DOP853


def test_exact_step_is_cached_per_step_size():
    model = FlexibleBeltModel(PARAMS)
    a = make_integrator("exact", model.A, model.B, 1e-3)
    b = make_integrator("exact", model.A.copy(), model.B.copy(), 1e-3)
    assert a.Phi is b.Phi  # one matrix exponential per (A, B, h)


# ------------------------------------------------------ step loop = step protocol
def _manual_step_loop(integrator, inputs, x0, n, t0=0.0):
    """x_{k+1} = integrator.step(t_k, x_k, inputs): the protocol a ROS node uses."""
    out = np.empty((n + 1, x0.size))
    out[0] = x = np.asarray(x0, dtype=float)
    for k in range(n):
        x = integrator.step(t0 + k * integrator.dt, x, inputs)
        out[k + 1] = x
    return out


@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
@pytest.mark.parametrize("model_cls", [FlexibleBeltModel, RigidBeltModel])
def test_open_loop_run_equals_step_protocol_and_linear_map(method, model_cls):
    """Open-loop torques: the simulator's run, a bare step() loop and the linear one-step map
    x+ = Phi x + sum_j G_j u(t + c_j h) agree."""
    model = model_cls(PARAMS)
    drive = Sine(mean=2.0, amplitude=3.0, frequency=8.0)
    load = Ramp(start_value=0.0, end_value=2.0, start_time=0.05, end_time=0.2)
    x0 = X0 if model.n_states == 4 else X0[[0, 2]]
    # No guard: Euler grows by 1.0018 per step here (x6 over the run); what is compared is the paths.
    sim = Simulator(model, drive, load, method, 1e-3, check_stability=False)
    _, run = sim.run(1.0, x0)
    integrator = make_integrator(method, model.A, model.B, 1e-3)
    plant = Plant(model, drive, load)
    bare = _manual_step_loop(integrator, plant.inputs, x0, 1000)
    step = integrator.linear_step()
    linear = np.empty_like(bare)
    linear[0] = x = np.array(x0, dtype=float)
    for k in range(1000):
        x = step.Phi @ x + sum(G @ plant.inputs((k + c) * 1e-3, x) for c, G in zip(step.nodes, step.gains))
        linear[k + 1] = x
    assert run.shape == bare.shape == (1001, model.n_states)
    scale = np.max(np.abs(bare), axis=0)
    assert np.max(np.abs(run - bare) / scale) < RTOL_STEP_LOOP
    assert np.max(np.abs(linear - bare) / scale) < RTOL_STEP_LOOP


@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_simulator_stepwise_equals_step_protocol_state_dependent(method):
    """State-dependent torques: whatever loop the simulator uses, it is integrator.step() to rounding (compiled
    profiles: the motor's speed, the compressor's speed and stroke angle; a Python-only sum is refused)."""
    model = FlexibleBeltModel(PARAMS)
    n = 300
    drive, load = MotorCurve(stall_torque=12.0, no_load_speed=160.0), Compressor(0.5, 0.02, 2, (1.0,))
    with pytest.raises(SceneError, match="no data form"):
        Simulator(model, DRIVE, LOAD, method, 1e-3, check_stability=False)
    sim = Simulator(model, drive, load, method, 1e-3, check_stability=False)
    _, states = sim.run(n * 1e-3, X0)
    bare = _manual_step_loop(make_integrator(method, model.A, model.B, 1e-3), Plant(model, drive, load).inputs, X0, n)
    assert np.max(np.abs(states - bare) / np.max(np.abs(bare), axis=0)) < RTOL_STEP_LOOP


# ------------------------------------------------------------------ tableaus
def _rk_classes():
    return [cls for cls in REGISTRY.values() if issubclass(cls, ExplicitRungeKutta)]


ORDER_CONDITIONS = {  # rooted trees up to order 4: (order, b-weighted expression, 1/gamma)
    1: [lambda A, b, c: b.sum() - 1.0],
    2: [lambda A, b, c: b @ c - 1 / 2],
    3: [lambda A, b, c: b @ c**2 - 1 / 3, lambda A, b, c: b @ (A @ c) - 1 / 6],
    4: [
        lambda A, b, c: b @ c**3 - 1 / 4,
        lambda A, b, c: (b * c) @ (A @ c) - 1 / 8,
        lambda A, b, c: b @ (A @ c**2) - 1 / 12,
        lambda A, b, c: b @ (A @ (A @ c)) - 1 / 24,
    ],
    5: [lambda A, b, c: b @ c**4 - 1 / 5],
}


@pytest.mark.parametrize("cls", _rk_classes(), ids=lambda c: c.name)
def test_runge_kutta_tableau_properties(cls):
    A, b, c = cls.A_tab, cls.B_tab, cls.C
    assert A.shape == (c.size, c.size) and b.shape == c.shape
    np.testing.assert_allclose(A.sum(axis=1), c, atol=1e-15)  # row sums = nodes
    assert b.sum() == pytest.approx(1.0, abs=1e-15)
    assert np.all(np.triu(A) == 0)  # explicit: strictly lower triangular
    for order in range(1, cls.order + 1):
        for cond in ORDER_CONDITIONS[order]:
            assert abs(cond(A, b, c)) < 1e-15, (cls.name, order)
    # ... and not one order more (the documented order is the true one).
    assert max(abs(cond(A, b, c)) for cond in ORDER_CONDITIONS[cls.order + 1]) > 1e-3


def test_rk4_amplification_is_its_stability_polynomial():
    cls = REGISTRY["rk4"]
    model = FlexibleBeltModel(PARAMS)
    it = cls(model.A, model.B, 0.01)
    for z in (0.3j, 1.7j, -0.5 + 2.0j, -2.0):
        R = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
        assert cls.mode_growths([z / 0.01], it.dt)[0] == pytest.approx(abs(R), rel=1e-13)


# --------------------------------------------- schemes against textbook steps
# Each method is written once, as its StageScheme; step() is derived from it. These are
# the methods' published update formulas written out independently (Cox & Matthews 2002
# for ETD2/ETD4, the Lawson transform of the DOPRI5 tableau, the trapezoidal rule, the
# velocity-first Euler), as references for the derived step. Tolerance 1e-13 relative
# per step: the same products summed in another order.
def _textbook_exact(it, t, x, u):
    Phi, Gamma, _ = _van_loan(it)
    return Phi @ x + Gamma @ u(t, x)


def _van_loan(it):
    n, m = it.B.shape
    M = np.zeros((n + 2 * m, n + 2 * m))
    M[:n, :n], M[:n, n : n + m], M[n : n + m, n + m :] = it.A, it.B, np.eye(m)
    E = scipy.linalg.expm(M * it.dt)
    return E[:n, :n], E[:n, n : n + m], E[:n, n + m :] / it.dt


def _textbook_etd2(it, t, x, u):
    Phi, G0, G1 = _van_loan(it)
    u0 = u(t, x)
    a = Phi @ x + G0 @ u0
    return a + G1 @ (u(t + it.dt, a) - u0)


def _phi_k(A, B, h):
    n, m = B.shape
    M = np.zeros((n + 3 * m, n + 3 * m))
    M[:n, :n], M[:n, n : n + m] = h * A, h * B
    M[n : n + m, n + m : n + 2 * m] = M[n + m : n + 2 * m, n + 2 * m :] = np.eye(m)
    E = scipy.linalg.expm(M)
    return E[:n, :n], E[:n, n : n + m], E[:n, n + m : n + 2 * m], E[:n, n + 2 * m :]


def _textbook_etd4(it, t, x, u):
    h = it.dt
    E, p1, p2, p3 = _phi_k(it.A, it.B, h)
    E2, P, _, _ = _phi_k(it.A, it.B, h / 2)
    u0 = u(t, x)
    a = E2 @ x + P @ u0
    ua = u(t + h / 2, a)
    b = E2 @ x + P @ ua
    ub = u(t + h / 2, b)
    c = E2 @ a + P @ (2.0 * ub - u0)
    uc = u(t + h, c)
    return E @ x + (p1 - 3 * p2 + 4 * p3) @ u0 + 2 * (p2 - 2 * p3) @ (ua + ub) + (4 * p3 - p2) @ uc


def _textbook_lawson5(it, t, x, u):
    h, C, A_tab, b = it.dt, it.C, it.A_tab, it.B_tab
    U = []
    for i in range(len(C)):  # X_i = e^{c_i h A} x + h sum_j a_ij e^{(c_i - c_j) h A} B U_j
        xi = scipy.linalg.expm(C[i] * h * it.A) @ x
        for j in range(i):
            xi = xi + h * A_tab[i][j] * scipy.linalg.expm((C[i] - C[j]) * h * it.A) @ it.B @ U[j]
        U.append(u(t + C[i] * h, xi))
    out = scipy.linalg.expm(h * it.A) @ x
    return out + sum(h * b[i] * scipy.linalg.expm((1 - C[i]) * h * it.A) @ it.B @ U[i] for i in range(len(C)))


def _textbook_symplectic_euler(it, t, x, u):
    n2 = x.size // 2
    w = x[n2:] + it.dt * (it.A @ x + it.B @ u(t, x))[n2:]
    return np.concatenate([x[:n2] + it.dt * it.A[:n2, n2:] @ w, w])  # q' = T omega (the kinematics block of A)


def _textbook_trapezoidal(it, t, x, u):
    n, h = x.size, it.dt
    lhs = np.eye(n) - 0.5 * h * it.A
    u0, u1 = u(t, x), u(t, x)
    for _ in range(100):
        x1 = np.linalg.solve(lhs, (np.eye(n) + 0.5 * h * it.A) @ x + 0.5 * h * it.B @ (u0 + u1))
        u1 = u(t + h, x1)
    return np.linalg.solve(lhs, (np.eye(n) + 0.5 * h * it.A) @ x + 0.5 * h * it.B @ (u0 + u1))


def _textbook_rk(it, t, x, u):
    k = []
    for i in range(len(it.C)):
        xi = x + it.dt * sum((it.A_tab[i, j] * k[j] for j in range(i)), np.zeros_like(x))
        k.append(it.A @ xi + it.B @ u(t + it.C[i] * it.dt, xi))
    return x + it.dt * sum(bi * ki for bi, ki in zip(it.B_tab, k))


TEXTBOOK = {
    "exact": _textbook_exact, "etd2": _textbook_etd2, "etd4": _textbook_etd4, "lawson5": _textbook_lawson5,
    "euler": _textbook_rk, "rk4": _textbook_rk, "symplectic_euler": _textbook_symplectic_euler,
    "trapezoidal": _textbook_trapezoidal,
}  # fmt: skip


def test_every_fixed_step_method_has_a_textbook_reference():
    assert set(TEXTBOOK) == set(FIXED_STEP_METHODS)


@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_step_from_the_scheme_equals_the_textbook_step(method):
    model = FlexibleBeltModel(PARAMS)
    plant = Plant(model, DRIVE, LOAD)
    it = make_integrator(method, model.A, model.B, 2e-3)
    x = X0 + np.array([0.01, -0.02, 0.5, -0.3])
    for t in (0.0, 0.0137, 0.2):
        got, want = it.step(t, x, plant.inputs), TEXTBOOK[method](it, t, x, plant.inputs)
        # trapezoidal: both sides iterate the implicit stage to 1e-13 of the torque, so they agree to ~1e-12
        assert np.max(np.abs(got - want) / np.abs(want)) < (1e-12 if method == "trapezoidal" else 1e-13), method


@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_amplification_is_the_closed_form(method):
    """mode_growths, read off the scheme, equals each method's known |R(h lambda)|."""
    cls = REGISTRY[method]
    h = 0.01
    lams = np.array([0.3j, 1.7j, -0.5 + 2.0j, -2.0, 0.0, 40.0j]) / h
    z = lams * h
    if cls.exact_linear:
        want = np.abs(np.exp(z))
    elif method == "trapezoidal":
        want = np.abs((1 + z / 2) / (1 - z / 2))
    elif method == "symplectic_euler":  # the oscillator's one-step matrix, written out
        want = [np.max(np.abs(np.linalg.eigvals(np.array(
            [[1.0 - h * h * abs(lam) ** 2, h * (1.0 + 2.0 * h * lam.real)], [-h * abs(lam) ** 2, 1.0 + 2.0 * h * lam.real]]
        )))) for lam in lams]  # fmt: skip
    else:  # explicit RK: R(z) = 1 + z b^T (I - z A)^{-1} 1
        s = len(cls.C)
        want = [abs(1.0 + zz * cls.B_tab @ np.linalg.solve(np.eye(s) - zz * cls.A_tab, np.ones(s))) for zz in z]
    got = cls.mode_growths(lams, h)
    rtol = 1e-6 if method == "symplectic_euler" else 1e-12  # a double root at real lambda: eigvals to sqrt(eps)
    np.testing.assert_allclose(got, want, rtol=rtol)


def test_lawson_scheme_and_growths_are_the_per_offset_exponentials_bit_for_bit():
    """lawson5's stage scheme takes every e^{c h A} of a step from one batched exponential, and its mode growths
    |e^{h lam}| from one exponential of the diagonal system: the same floats as an exponential per offset (the
    scheme written out here from the tableau) and as the growths read off the whole scheme's one-step map
    (the generic FixedStepIntegrator.mode_growths)."""
    from belt_drive_ros.core.batch_expm import expm_stack

    cls = REGISTRY["lawson5"]
    for model_cls in (RigidBeltModel, FlexibleBeltModel):
        model = model_cls(PARAMS)
        A, B = model.A, model.B
        for h in (1e-4, 0.005, 0.37):
            C, n = cls.C, A.shape[0]

            def E(c):
                return np.eye(n) if c == 0.0 else expm_stack(A * (c * h))  # one matrix per call

            stages = [np.concatenate([E(C[i])] + [h * cls.A_tab[i][j] * (E(C[i] - C[j]) @ B) for j in range(i)], axis=1)
                      for i in range(1, len(C))]  # fmt: skip
            final = np.concatenate([E(1.0)] + [h * cls.B_tab[i] * (E(1.0 - C[i]) @ B) for i in range(len(C))], axis=1)
            scheme = cls(A, B, h).stage_scheme()
            assert scheme.stages[0] is None
            for got, want in zip(scheme.stages[1:], stages, strict=True):
                assert got.tobytes() == want.tobytes()
            assert scheme.final.tobytes() == final.tobytes()
    lams = np.array([0.3j, 1.7j, -0.5 + 2.0j, -2.0, 0.0, 40.0j, -3.0e3 + 7.0e2j])
    for h in (1e-6, 0.01, 0.5, 3.0):
        for values in (lams, lams.real, FlexibleBeltModel(PARAMS).A.diagonal() + 0j):
            want = FixedStepIntegrator.mode_growths.__func__(cls, values, h)  # read off the whole scheme's map
            assert cls.mode_growths(values, h).tobytes() == want.tobytes()


def test_scipy_solvers_are_the_public_classes():
    """No private scipy API: each adaptive method is a class exported by scipy.integrate."""
    model = FlexibleBeltModel(PARAMS)
    for name in ADAPTIVE_METHODS:
        solver = make_integrator(name, model.A, model.B, 1e-3).solver_class
        assert solver is getattr(scipy.integrate, name) and name in scipy.integrate.__all__
        assert issubclass(solver, scipy.integrate.OdeSolver)


# ------------------------------------------------------------------ names, options
def test_unknown_method_error_lists_valid_names():
    model = FlexibleBeltModel(PARAMS)
    with pytest.raises(IntegratorError) as info:
        make_integrator("rk5", model.A, model.B, 1e-3)
    message = str(info.value)
    assert "rk5" in message
    for name in REGISTRY:
        assert name in message
    assert isinstance(info.value, ValueError)


def test_aliases_and_bad_options():
    model = FlexibleBeltModel(PARAMS)
    assert make_integrator("zoh", model.A, model.B, 1e-3).name == "exact"
    assert make_integrator("crank_nicolson", model.A, model.B, 1e-3).name == "trapezoidal"
    assert make_integrator("semi_implicit_euler", model.A, model.B, 1e-3).name == "symplectic_euler"
    for dt in (0.0, -1e-3, float("nan"), float("inf")):
        with pytest.raises(IntegratorError, match="dt"):
            make_integrator("rk4", model.A, model.B, dt)
    with pytest.raises(IntegratorError, match="tolerance_typo"):
        make_integrator("rk4", model.A, model.B, 1e-3, tolerance_typo=1.0)
    with pytest.raises(IntegratorError, match="rtol"):
        make_integrator("RK45", model.A, model.B, 1e-3, rtol=-1.0)


def test_trapezoidal_reports_non_convergent_fixed_point():
    """A torque far stiffer than the step can resolve: a clear error, not a NaN."""
    model = FlexibleBeltModel(PARAMS)
    stiff_load = Polynomial(c1=1.0e5)  # N m s/rad on a 0.03 kg m^2 wheel: h c1 / I_3 ~ 3e6
    sim = Simulator(model, Constant(1.0), stiff_load, "trapezoidal", 1e-3)
    with pytest.raises(IntegratorError, match="trapezoidal.*dt"):
        sim.run(0.01, X0)


# ------------------------------------------------------------------ scipy references
@pytest.fixture(scope="module")
def constant_torque_exact():
    model = FlexibleBeltModel(PARAMS)
    drive, load = Constant(5.0), Constant(2.0)
    _, exact = Simulator(model, drive, load, "exact", 1e-3).run(DURATION, X0)
    return model, drive, load, exact


def test_scipy_methods_with_held_torque_match_exact_zoh():
    """A ROS node holds the last torque message and calls step() with the same input callable.

    The held value changes between steps, so the solution is the exact ZOH one.
    An adaptive solver that keeps stepping past each output time with the old
    torque (t_bound = inf) and only interpolates afterwards integrates the wrong
    torque over part of every step.
    """
    model = FlexibleBeltModel(PARAMS)
    dt, n, rtol = 1e-3, 100, 1e-8
    torques = np.random.default_rng(0).uniform(0.0, 10.0, (n, 2))
    held = np.zeros(2)

    def inputs(t, x):  # the node's held message
        return held.copy()

    exact = make_integrator("exact", model.A, model.B, dt)
    errors = {}
    for method in ADAPTIVE_METHODS:
        adaptive = make_integrator(method, model.A, model.B, dt, rtol=rtol, atol=rtol * 1e-3)
        xe = xa = X0.copy()
        for k in range(n):
            held[:] = torques[k]
            xe = exact.step(k * dt, xe, inputs)
            xa = adaptive.step(k * dt, xa, inputs)
        T = model.lagrange_map  # on the wheel coordinates [phi_M, phi_3, omega_M, omega_3]
        errors[method] = float(np.max(np.abs(T @ (xa - xe)) / np.abs(T @ xe)))
    limits = {m: (ADAPTIVE_GLOBAL_FACTOR_BDF if m == "BDF" else ADAPTIVE_GLOBAL_FACTOR) * rtol for m in errors}
    assert all(errors[m] <= limits[m] for m in errors), errors


@pytest.mark.parametrize("method", ["DOP853", "LSODA", "BDF"])  # measured 1.37x, 1.63x, 1.75x over 1 s (6x over 3 s)
def test_simulator_continues_adaptive_solver_between_output_steps(method):
    """On the simulator's grid t_k = k dt the solver must continue, not restart, at every output step.

    The integrator continues only when the new t equals its last t_end = t_{k-1} + dt
    *exactly*; k dt and (k-1) dt + dt differ in the last bit at ~25 % of steps, each
    such step restarts the solver (new initial step selection). Budget: 1.2x the
    evaluations of one scipy solve_ivp over the same interval and tolerances.
    """
    model = FlexibleBeltModel(PARAMS)
    drive, load = Constant(5.0), Constant(2.0)
    options = dict(rtol=1e-8, atol=1e-11)
    sim = Simulator(model, drive, load, method, 1e-3, method_options=options)
    sim.run(1.0, X0)
    plant = Plant(model, drive, load)
    sol = scipy.integrate.solve_ivp(
        lambda t, x: model.A @ x + model.B @ plant.inputs(t, x), (0.0, 1.0), X0, method=method,
        t_eval=1e-3 * np.arange(1001), **options,
    )
    assert sim.integrator.n_rhs <= 1.2 * sol.nfev, (sim.integrator.n_rhs, sol.nfev)


@pytest.mark.parametrize("method", ADAPTIVE_METHODS)
def test_scipy_methods_reach_their_tolerance(method, constant_torque_exact):
    model, drive, load, exact = constant_torque_exact
    T = model.lagrange_map  # on the wheel coordinates [phi_M, phi_3, omega_M, omega_3]
    scale = np.max(np.abs(exact @ T.T), axis=0)
    errors = {}
    for rtol in (1e-6, 1e-9):
        sim = Simulator(model, drive, load, method, 1e-3, method_options=dict(rtol=rtol, atol=rtol * 1e-3))
        _, states = sim.run(DURATION, X0)
        assert not sim.integrator.fixed_step and sim.integrator.n_rhs > 0
        errors[rtol] = np.max(np.abs((states - exact) @ T.T) / scale)
        factor = ADAPTIVE_GLOBAL_FACTOR_BDF if method == "BDF" else ADAPTIVE_GLOBAL_FACTOR
        assert errors[rtol] <= factor * rtol, (method, rtol, errors[rtol])
    assert errors[1e-6] / errors[1e-9] > 100.0, errors


def test_a_fixed_step_integrator_is_shared_per_model_and_an_adaptive_one_never():
    """make_integrator builds a fixed-step method once per (method, dt, options, A, B) (read-only matrices);
    scipy's adaptive methods hold a solver's state, so every call gets its own."""
    A = np.array([[0.0, 1.0], [-4.0, -0.1]])
    B = np.array([[0.0, 0.0], [1.0, -1.0]])
    first = make_integrator("etd2", A, B, 1e-3)
    assert make_integrator("etd2", A.copy(), B.copy(), 1e-3) is first
    assert make_integrator("etd2", A, B, 2e-3) is not first
    assert make_integrator("trapezoidal", A, B, 1e-3, tol=1e-12) is not make_integrator("trapezoidal", A, B, 1e-3)
    other = A.copy()
    other[1, 0] = -5.0
    assert make_integrator("etd2", other, B, 1e-3) is not first
    assert make_integrator("RK45", A, B, 1e-3) is not make_integrator("RK45", A, B, 1e-3)
    stack = np.stack([A, other])  # an ensemble's stack of variants' matrices: not cached
    assert make_integrator("etd2", stack, B, 1e-3) is not make_integrator("etd2", stack, B, 1e-3)
