"""Energy balance: E(t) - E(0) = input work - dissipated energy.

Tolerances (one per quantity, with the reason)
----------------------------------------------
* free undamped belt, exact method: |E - E0| / E0 <= 4e-12 over 200 belt
  periods. The ZOH step is exact up to rounding of expm (~1e-16 per step);
  8000 steps accumulate ~1e-12 (measured: 1.8e-12 with the batched Pade of core/batch_expm.py).
* power identity dE/dt = P_in - P_d at random states: rtol 1e-12 (a few
  float64 roundings of the same quadratic forms; a wrong factor is O(1)).
* work / dissipation on the output grid: the simulator integrates the powers
  with the trapezoid rule, whose error is, by Euler-Maclaurin,
  ``W_trap - W = (dt^2/12) (P'(t) - P'(0)) + O(dt^4)``. With the exact method
  (exact states for constant torques) the balance residual must *be* that
  leading term: we require ``|residual - leading term| <= 1e-2 * max|leading
  term|``; the next term is ~(omega_n dt)^2/10 ~ 4e-4 of it at omega_n dt =
  2 pi/100. P' is taken by second-order differences of P on the grid
  (relative error O((omega_n dt)^2), same size as the next term).
"""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.core.model import FlexibleBeltModel, RigidBeltModel
from belt_drive_ros.core.params import BeltDriveParams
from belt_drive_ros.core.scene import InitialState, Scene
from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.core.sources import Constant

#: paper-scene geometry written out (g = 0.4), so the tests do not move with the defaults.
GEOMETRY = dict(
    I_M=0.02, I_1=0.004, I_2=0.003, I_3=0.03, r_M=0.04, R_1=0.06, r_1=0.03, R_2=0.05, r_2=0.06, r_3=0.05, k=2.0e4
)
UNDAMPED = dict(c=0.0, b_M=0.0, b_1=0.0, b_2=0.0, b_3=0.0)
DAMPED = dict(c=3.0, b_M=2e-3, b_1=1e-3, b_2=1e-3, b_3=3e-3)

RTOL_FREE_ENERGY = 4e-12  # exact ZOH: rounding only (module docstring): ~1 ulp per step over the 8000 steps
RTOL_POWER_IDENTITY = 1e-12  # same quadratic forms in float64
RTOL_EULER_MACLAURIN = 1e-2  # next E-M term ~(omega_n dt)^2/10 of the leading one


def _scene(params, drive=0.0, load=0.0, periods=20, steps_per_period=100, **init):
    period = 2 * np.pi / params.belt_natural_frequency
    return Scene(
        params=params,
        drive=Constant(drive),
        load=Constant(load),
        duration=periods * period,
        dt=period / steps_per_period,
        model="flexible",
        method="exact",
        initial_state=InitialState(**init),
    )


def _total(result):
    return result.energy["kinetic"] + result.energy["potential"]


def test_undamped_free_belt_conserves_energy():
    p = BeltDriveParams(**GEOMETRY, **UNDAMPED)
    result = simulate(_scene(p, periods=200, steps_per_period=40, relative_deflection=1e-3))
    E = _total(result)
    assert E[0] > 0
    drift = np.max(np.abs(E - E[0])) / E[0]
    assert drift < RTOL_FREE_ENERGY
    # The energy really sloshes between belt and wheels (not a trivial rest state):
    assert np.max(result.energy["kinetic"]) > 0.9 * E[0]
    assert np.max(result.energy["potential"]) > 0.9 * E[0]


@pytest.mark.parametrize("model_cls", [FlexibleBeltModel, RigidBeltModel])
def test_power_identity_at_random_states(model_cls):
    """dE/dt along x' = A x + B u equals input power minus dissipation power, at every state."""
    rng = np.random.default_rng(3)
    p = BeltDriveParams(**GEOMETRY, **DAMPED)
    model = model_cls(p)
    n = model.n_states
    h = n // 2
    for _ in range(20):
        x = rng.normal(size=n) * np.r_[np.full(h, 0.01), np.full(h, 30.0)]
        u = rng.normal(size=2) * 10.0
        xdot = model.A @ x + model.B @ u
        if model_cls is FlexibleBeltModel:
            q = model.lagrange_map @ x  # [phi_M, phi_3, omega_M, omega_3]
            dE = xdot[2:] @ model.mass_matrix @ x[2:] + x[2:] @ model.stiffness_matrix @ q[:2]
        else:
            dE = p.inertia_reduced * x[1] * xdot[1]
        expected = model.input_power(x, u) - model.dissipation_power(x)
        scale = abs(model.input_power(x, u)) + abs(model.dissipation_power(x))
        assert abs(dE - expected) <= RTOL_POWER_IDENTITY * scale


def _euler_maclaurin_leading(power, dt):
    """(dt^2/12) (P'(t) - P'(0)): the trapezoid rule's leading error on the grid."""
    dP = np.gradient(power, dt, edge_order=2)
    return (dt**2 / 12.0) * (dP - dP[0])


def test_constant_torque_undamped_energy_equals_input_work():
    p = BeltDriveParams(**GEOMETRY, **UNDAMPED)
    scene = _scene(p, drive=3.0, load=2.0, omega_M=10.0, relative_deflection=1e-3)
    result = simulate(scene)
    model = FlexibleBeltModel(p)
    W = result.energy["input_work"]
    assert np.all(result.energy["dissipated"] == 0.0)
    residual = _total(result) - _total(result)[0] - W
    leading = -_euler_maclaurin_leading(model.input_power(result.states, result.inputs), scene.dt)
    assert np.max(np.abs(W)) > 100.0  # J: the torques do real work (speed rises several-fold)
    assert np.max(np.abs(residual)) < 1e-6 * np.max(np.abs(W))
    np.testing.assert_allclose(residual, leading, rtol=0, atol=RTOL_EULER_MACLAURIN * np.max(np.abs(leading)))


def test_damped_energy_lost_equals_energy_dissipated():
    p = BeltDriveParams(**GEOMETRY, **DAMPED)
    scene = _scene(p, periods=40, omega_M=20.0, relative_deflection=2e-3)
    result = simulate(scene)
    model = FlexibleBeltModel(p)
    E = _total(result)
    D = result.energy["dissipated"]
    assert np.all(result.energy["input_work"] == 0.0)
    assert E[-1] < 0.5 * E[0]  # more than half the energy is gone: a real test of the balance
    residual = (E[0] - E) - D  # = D_exact - D_trapezoid
    leading = -_euler_maclaurin_leading(model.dissipation_power(result.states), scene.dt)
    np.testing.assert_allclose(residual, leading, rtol=0, atol=RTOL_EULER_MACLAURIN * np.max(np.abs(leading)))
    assert np.max(np.abs(residual)) < 1e-5 * E[0]


def test_damped_forced_energy_balance():
    """E(t) - E(0) = W(t) - D(t) with constant torques and all dampers."""
    p = BeltDriveParams(**GEOMETRY, **DAMPED)
    scene = _scene(p, drive=4.0, load=1.5, periods=40, omega_M=5.0, relative_deflection=-1e-3)
    result = simulate(scene)
    model = FlexibleBeltModel(p)
    E = _total(result)
    W, D = result.energy["input_work"], result.energy["dissipated"]
    assert np.max(D) > 0.01 * np.max(np.abs(W))
    residual = (E - E[0]) - (W - D)
    net_power = model.input_power(result.states, result.inputs) - model.dissipation_power(result.states)
    leading = -_euler_maclaurin_leading(net_power, scene.dt)
    np.testing.assert_allclose(residual, leading, rtol=0, atol=RTOL_EULER_MACLAURIN * np.max(np.abs(leading)))


def test_rigid_energy_balance():
    """Rigid model: 1/2 I_red w^2 changes by the work of (M_drive - i M_load) minus bearing losses."""
    p = BeltDriveParams(**GEOMETRY, **DAMPED)
    scene = Scene(
        params=p, drive=Constant(2.0), load=Constant(1.0), duration=2.0, dt=1e-3, model="rigid", method="exact",
        initial_state=InitialState(omega_M=30.0),
    )
    result = simulate(scene)
    model = RigidBeltModel(p)
    E = _total(result)
    residual = (E - E[0]) - (result.energy["input_work"] - result.energy["dissipated"])
    net_power = model.input_power(result.states, result.inputs) - model.dissipation_power(result.states)
    leading = -_euler_maclaurin_leading(net_power, scene.dt)
    # The rigid motion is smooth (time constant I_red/b_red ~ 10 s): residual at rounding level,
    # bounded by the same leading term plus rounding of the cumulative sums (~1e-13 of |W|).
    assert np.max(np.abs(residual - leading)) <= 1e-2 * np.max(np.abs(leading)) + 1e-12 * np.max(np.abs(result.energy["input_work"]))
