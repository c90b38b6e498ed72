"""Stability guard: predictions against runs, boundaries against theory, no NaN ever.

Undamped flexible belt (paper geometry, k = 2e4 N/m, omega_n = 66.1 rad/s):
a fixed-step method multiplies the belt mode by R(i h omega_n) per step. For
classical RK4, |R(iy)|^2 = 1 - y^6/72 + y^8/576: 0.72 at y = 2.7 (decays),
1.19 at y = 2.9 (grows), boundary y = 2 sqrt(2).

Tolerances (one per quantity, with the reason)
----------------------------------------------
* run growth: after 300 steps at y = 2.9 the belt amplitude must be > 1e10
  times the start (1.19^300 = 5e22); at y = 2.7 it must not exceed the start
  (1 + 1e-9 for rounding).
* max_stable_step: within 1e-6 relative of 2 sqrt(2)/omega_n (the bisection
  stops at 1e-9 relative; eig(A) is accurate to ~1e-15).
* symplectic Euler boundary 2/omega_n: 1e-6 relative, same reason.
* amplification vs the spectral radius of the method's one-step matrix Phi:
  rtol 1e-9 (eigenvalues of a 4x4 with simple eigenvalues; proportional
  bearing damping keeps the rigid-body eigenvalue simple and the modes
  decoupled).
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from belt_drive_ros.core.errors import SimulationDivergedError, UnstableStepError
from belt_drive_ros.core.integrators import FIXED_STEP_METHODS, make_integrator
from belt_drive_ros.core.model import FlexibleBeltModel
from belt_drive_ros.core.params import BeltDriveParams
from belt_drive_ros.core.scene import InitialState, Scene
from belt_drive_ros.core.simulate import Simulator, simulate
from belt_drive_ros.core.sources import Constant, Polynomial
from belt_drive_ros.core.stability import check_step, max_stable_step, require_stable

GEOMETRY = dict(I_M=0.02, I_1=0.004, I_2=0.003, I_3=0.03, r_M=0.04, R_1=0.06, r_1=0.03, R_2=0.05, r_2=0.06, r_3=0.05)
UNDAMPED = BeltDriveParams(**GEOMETRY, k=2.0e4, c=0.0, b_M=0.0, b_1=0.0, b_2=0.0, b_3=0.0)
#: Rayleigh-proportional damping C = alpha M + (c/k) K (bearing damping b_j = alpha I_j): the modes
#: decouple, so a method's growth per step is exactly max |R(h lambda)| over eig(A).
ALPHA = 0.5  # 1/s
PROPORTIONAL = BeltDriveParams(
    **GEOMETRY, k=2.0e4, c=3.0,
    b_M=ALPHA * GEOMETRY["I_M"], b_1=ALPHA * GEOMETRY["I_1"], b_2=ALPHA * GEOMETRY["I_2"], b_3=ALPHA * GEOMETRY["I_3"],
)
OMEGA_N = UNDAMPED.belt_natural_frequency

RTOL_BOUNDARY = 1e-6
RTOL_SPECTRAL = 1e-9


def _free_states(Phi, x0, n_steps):
    """x_0 .. x_n of x_{k+1} = Phi x_k: a fixed-step method's unforced run by its own one-step map."""
    states = [np.asarray(x0, dtype=float)]
    for _ in range(n_steps):
        states.append(Phi @ states[-1])
    return np.array(states)


def _belt_amplitude_after(method, h_omega, n_steps=300):
    """max |relative deflection| over the last 20 steps / initial, undamped free belt."""
    model = FlexibleBeltModel(UNDAMPED)
    dt = h_omega / OMEGA_N
    x0 = np.array([0.0, -1e-3, 0.0, 0.0])
    Phi = make_integrator(method, model.A, model.B, dt).linear_step().Phi
    with np.errstate(over="ignore", invalid="ignore"):
        states = _free_states(Phi, x0, n_steps)
        delta = np.abs(model.relative_deflection(states))
    return np.max(delta[-20:]) / delta[0], np.max(delta) / delta[0]


def test_rk4_stable_at_2_7_divergent_at_2_9_and_guard_predicts_both():
    model = FlexibleBeltModel(UNDAMPED)
    late, peak = _belt_amplitude_after("rk4", 2.7)
    assert peak <= 1.0 + 1e-9 and late < 1e-3  # RK4 damps the mode numerically at y = 2.7
    late, _ = _belt_amplitude_after("rk4", 2.9)
    assert late > 1e10
    ok = check_step(model.A, model.B, "rk4", 2.7 / OMEGA_N)
    bad = check_step(model.A, model.B, "rk4", 2.9 / OMEGA_N)
    assert ok.stable and not bad.stable
    assert ok.h_omega_n == pytest.approx(2.7, rel=1e-12) and bad.h_omega_n == pytest.approx(2.9, rel=1e-12)
    y = 2.9
    assert bad.growth == pytest.approx(math.sqrt(1 - y**6 / 72 + y**8 / 576), rel=1e-12)
    assert bad.limit == pytest.approx(2 * math.sqrt(2))
    assert "UNSTABLE" in bad.describe() and "rk4" in bad.describe()


def test_rk4_max_stable_step_is_2_sqrt2_over_omega_n():
    model = FlexibleBeltModel(UNDAMPED)
    h = max_stable_step(model.A, model.B, "rk4")
    assert h == pytest.approx(2 * math.sqrt(2) / OMEGA_N, rel=RTOL_BOUNDARY)


def test_symplectic_euler_boundary_is_2():
    model = FlexibleBeltModel(UNDAMPED)
    h = max_stable_step(model.A, model.B, "symplectic_euler")
    assert h * OMEGA_N == pytest.approx(2.0, rel=RTOL_BOUNDARY)
    assert check_step(model.A, model.B, "symplectic_euler", 1.99 / OMEGA_N).stable
    assert not check_step(model.A, model.B, "symplectic_euler", 2.01 / OMEGA_N).stable
    _, peak = _belt_amplitude_after("symplectic_euler", 1.99, n_steps=2000)
    assert peak < 30.0  # bounded (its modified energy is conserved; amplitude bounded by 1/sqrt(1-(y/2)^2))
    late, _ = _belt_amplitude_after("symplectic_euler", 2.01, n_steps=2000)
    assert late > 1e6


def test_euler_never_stable_on_undamped_belt():
    model = FlexibleBeltModel(UNDAMPED)
    for y in (1e-3, 0.1, 1.0):
        assert not check_step(model.A, model.B, "euler", y / OMEGA_N).stable
    late, _ = _belt_amplitude_after("euler", 0.1, n_steps=3000)  # |R|^2 = 1 + y^2: e^(3000 * 0.005)
    assert late > 1e5


def test_euler_max_stable_step_is_zero_and_guard_says_so():
    """|1 + i y| > 1 for every y > 0: no step, however small, is stable (stability.py docstring: 0.0)."""
    model = FlexibleBeltModel(UNDAMPED)
    assert not check_step(model.A, model.B, "euler", 1e-8).stable  # y = 6.6e-7: |R| - 1 = 2.2e-13 > 0
    assert max_stable_step(model.A, model.B, "euler") == 0.0
    with pytest.raises(UnstableStepError, match="no step is stable.*exact"):
        require_stable(model.A, model.B, "euler", 1e-4)


@pytest.mark.parametrize("method", ["exact", "etd2", "trapezoidal"])
def test_unconditionally_stable_methods(method):
    model = FlexibleBeltModel(UNDAMPED)
    assert max_stable_step(model.A, model.B, method) == math.inf
    assert check_step(model.A, model.B, method, 100.0 / OMEGA_N).stable
    late, peak = _belt_amplitude_after(method, 100.0)
    assert peak <= 1.0 + 1e-9


@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_amplification_equals_spectral_radius_of_step(method):
    """The guard's growth factor is the true per-step growth of the method's one-step map."""
    model = FlexibleBeltModel(PROPORTIONAL)
    omega = np.max(np.abs(np.linalg.eigvals(model.A)))
    for y in (0.3, 1.5, 2.5, 3.5):
        dt = y / omega
        report = check_step(model.A, model.B, method, dt)
        Phi = make_integrator(method, model.A, model.B, dt).linear_step().Phi
        rho = np.max(np.abs(np.linalg.eigvals(Phi)))
        assert report.growth == pytest.approx(rho, rel=RTOL_SPECTRAL), (method, y)


def test_symplectic_euler_guard_with_strong_bearing_damping():
    """Non-proportional damping (a heavily damped wheel 3): the guard must still not accept a growing step.

    SymplecticEuler.amplification treats every eigenvalue of A as an independent
    oscillator; the partitioned method does not commute with the eigenvectors of
    a non-proportionally damped A, so the prediction is only approximate there.
    Measured for b_3 = 1 N m s/rad: predicted boundary h omega = 1.641, true one
    (spectral radius of the one-step matrix) 1.572.
    """
    params = BeltDriveParams(**GEOMETRY, k=2.0e4, c=3.0, b_M=1e-3, b_1=0.0, b_2=0.0, b_3=1.0)
    model = FlexibleBeltModel(params)
    omega = np.max(np.abs(np.linalg.eigvals(model.A)))
    dt = 1.61 / omega
    rho = np.max(np.abs(np.linalg.eigvals(make_integrator("symplectic_euler", model.A, model.B, dt).linear_step().Phi)))
    assert rho > 1.001  # this step really is unstable ...
    assert not check_step(model.A, model.B, "symplectic_euler", dt).stable  # ... so the guard must say so


# ------------------------------------------------------------ the guard in simulate()
def _free_scene(**kw):
    return Scene(
        params=UNDAMPED, drive=Constant(0.0), load=Constant(0.0), duration=0.2, dt=1e-3, model="flexible",
        method="rk4", initial_state=InitialState(relative_deflection=1e-3), **kw,
    )


def test_guard_refuses_unstable_run_naming_a_stable_step_and_method():
    """The refusal names a step of the method and another method; both guards accept each (one notion of a good step)."""
    scene = _free_scene()
    with pytest.raises(UnstableStepError) as info:
        simulate(scene, dt=2.9 / OMEGA_N)
    message = str(info.value)
    assert "rk4" in message and "UNSTABLE" in message
    suggested = float(re.search(r"dt = ([0-9.eE+-]+) s is stable and accurate", message).group(1))
    method, other = re.search(r"so is (\w+) at dt = ([0-9.eE+-]+) s", message).groups()
    model = FlexibleBeltModel(UNDAMPED)
    assert suggested < 2 * math.sqrt(2) / OMEGA_N
    assert check_step(model.A, model.B, "rk4", suggested).stable
    # The suggestions work: the named step and the named method both run, and the accuracy guard accepts them.
    for result in (simulate(scene, dt=suggested), simulate(scene, dt=float(other), method=method)):
        assert np.all(np.isfinite(result.states)) and result.accuracy.ok, result.accuracy.describe()


def test_guard_accepts_stable_run_and_reports():
    result = simulate(_free_scene(), dt=2.7 / OMEGA_N)
    assert result.stability is not None and result.stability.stable
    assert result.stability.method == "rk4"


@pytest.mark.parametrize("closed_loop", [False, True], ids=["open-loop", "closed-loop"])
def test_forced_divergence_raises_with_time_never_nan(closed_loop):
    """check_stability=False, RK4 at h omega_n = 3.5 (|R| = 3.9 per step): an error naming the time."""
    dt = 3.5 / OMEGA_N
    scene = _free_scene()
    if closed_loop:  # a state-dependent (tiny) load
        scene = scene.with_overrides(load=Polynomial(c1=1e-9))
    with pytest.raises(SimulationDivergedError) as info, np.errstate(over="ignore", invalid="ignore"):
        simulate(scene, dt=dt, duration=300 * dt, check_stability=False)
    message = str(info.value)
    t_reported = float(re.search(r"diverged at t=([0-9.eE+-]+) s", message).group(1))
    assert 0.0 < t_reported < 300 * dt
    assert "rk4" in message and "exact" in message
    # The reported time is the first sample whose speed passes the 1e5 rad/s envelope.
    model = FlexibleBeltModel(UNDAMPED)
    Phi = make_integrator("rk4", model.A, model.B, dt).linear_step().Phi
    x0 = scene.initial_state.vector("flexible", UNDAMPED.ratio)
    with np.errstate(over="ignore", invalid="ignore"):
        states = _free_states(Phi, x0, 300)
        bad = ~np.all(np.isfinite(states), axis=1) | np.any(np.abs(states[:, 2:]) > 1e5, axis=1)
    first = int(np.argmax(bad))
    assert t_reported == pytest.approx(first * dt, rel=1e-5)


def test_simulation_diverged_error_is_an_arithmetic_error():
    assert issubclass(SimulationDivergedError, ArithmeticError)
    assert issubclass(UnstableStepError, ValueError)
