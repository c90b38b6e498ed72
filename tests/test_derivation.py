"""Symbolic derivation of the equations of motion (sympy, test dependency only).

The runtime builds M, K, C and the state-space matrices A, B by hand
(``belt_drive_ros/model.py``). Here sympy derives them from the Lagrangian
written in ``docs/model.md`` (the paper's eq. 11, 15 and 17, plus a
Rayleigh dissipation function for belt span and bearing damping), with
Lagrange's equations of the second kind::

    d/dt dL/dq' - dL/dq + dD/dq' = Q,     L = T - V

and the two must agree for random parameter sets. The paper's as-printed
stiffness matrix (eq. 20) is then shown to be non-symmetric and to break
conservation of the energy the paper itself writes down (eq. 15 + eq. 17).

Tolerances
----------
* matrices: rtol 1e-12 -- both sides evaluate the same rational expressions
  in double precision, a handful of roundings each (~1e-15); 1e-12 leaves
  room for the different operation order, and is far below any real error
  (a wrong factor g = 0.4..1.6 shows up as O(1)).
* energy drift, correct K: 1e-12 relative over ~60 belt periods (the exact
  ZOH step is orthogonal-to-rounding; ~3000 steps of eps-level error).
* energy drift, paper's K: > 0.1 relative -- eleven orders of magnitude above
  rounding; the actual figure is O(|1 - g|) (0.66 at g = 0.4).
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from belt_drive_ros.core.integrators import make_integrator
from belt_drive_ros.core.model import FlexibleBeltModel, RigidBeltModel
from belt_drive_ros.core.params import BeltDriveParams

RTOL_MATRIX = 1e-12  # same rational expressions in float64 on both sides (see module docstring)
N_RANDOM = 20


def paper_as_printed_stiffness(params: BeltDriveParams) -> np.ndarray:
    """The stiffness matrix exactly as printed in the paper's eq. 20 (erratum 1).

    Row 1 carries ``g`` where ``g^2`` belongs and lacks ``g`` in the coupling
    term, so the matrix is not symmetric. Exists only so that these tests can show
    what the erratum does; never used by a simulation.
    """
    p = params
    g = p.gear_ratio
    return 2.0 * p.k * np.array([[p.r_2**2 * g, -p.r_2 * p.r_3], [-p.r_2 * p.r_3 * g, p.r_3**2]])


# --------------------------------------------------------------- symbols
SYMBOLS = sp.symbols("I_M I_1 I_2 I_3 r_M R_1 r_1 R_2 r_2 r_3 k c b_M b_1 b_2 b_3", positive=True)
(I_M, I_1, I_2, I_3, r_M, R_1, r_1, R_2, r_2, r_3, k, c, b_M, b_1, b_2, b_3) = SYMBOLS
PARAM_NAMES = [str(s) for s in SYMBOLS]
t = sp.symbols("t")
M_drive, M_load = sp.symbols("M_drive M_load")
g = (r_M / R_1) * (r_1 / R_2)  # gear train M -> 2 (model.md)
i_ratio = g * r_2 / r_3  # rigid-belt ratio M -> 3


def _lagrange(L, D, Q, q):
    """Left sides of d/dt dL/dq' - dL/dq + dD/dq' - Q = 0, one per coordinate."""
    qd = [qq.diff(t) for qq in q]
    return [sp.expand(L.diff(qdj).diff(t) - L.diff(qj) + D.diff(qdj) - Qj) for qj, qdj, Qj in zip(q, qd, Q)]


def _generalized_forces(virtual_work, variations):
    """Q_j = d(delta W)/d(delta q_j)."""
    return [virtual_work.diff(v) for v in variations]


def _second_order_matrices(eqs, q):
    """M, C, K and the input matrix F of M q'' + C q' + K q = F u, u = [M_drive, M_load]."""
    qd = [qq.diff(t) for qq in q]
    qdd = [qq.diff(t, 2) for qq in q]
    # Replace the functions of time by plain symbols so jacobians are algebraic.
    pos = sp.symbols(f"q0:{len(q)}")
    vel = sp.symbols(f"v0:{len(q)}")
    acc = sp.symbols(f"a0:{len(q)}")
    subs = {**dict(zip(qdd, acc)), **dict(zip(qd, vel)), **dict(zip(q, pos))}
    e = sp.Matrix([eq.subs(subs) for eq in eqs])
    u = sp.Matrix([M_drive, M_load])
    M = e.jacobian(acc)
    C = e.jacobian(vel)
    K = e.jacobian(pos)
    F = -e.jacobian(u)
    # The equations must be linear: nothing may be left over.
    rest = sp.simplify(e - M * sp.Matrix(acc) - C * sp.Matrix(vel) - K * sp.Matrix(pos) + F * u)
    assert rest == sp.zeros(len(q), 1)
    return M, C, K, F


def _state_space(M, C, K, F):
    n = M.shape[0]
    Minv = M.inv()
    A = sp.zeros(2 * n, 2 * n)
    A[0:n, n : 2 * n] = sp.eye(n)
    A[n:, 0:n] = -Minv * K
    A[n:, n:] = -Minv * C
    B = sp.zeros(2 * n, 2)
    B[n:, :] = Minv * F
    return A, B


@pytest.fixture(scope="module")
def flexible_symbolic():
    """Derive the flexible (2 DOF) model from T, V, D and the virtual work."""
    phi_M, phi_3 = sp.Function("phi_M")(t), sp.Function("phi_3")(t)
    wM, w3 = phi_M.diff(t), phi_3.diff(t)
    T = (
        sp.Rational(1, 2) * I_M * wM**2
        + sp.Rational(1, 2) * I_1 * (r_M / R_1 * wM) ** 2
        + sp.Rational(1, 2) * I_2 * (g * wM) ** 2
        + sp.Rational(1, 2) * I_3 * w3**2
    )  # paper eq. 17
    V = 2 * sp.Rational(1, 2) * k * (r_2 * g * phi_M - r_3 * phi_3) ** 2  # paper eq. 15, two spans
    D = 2 * sp.Rational(1, 2) * c * (r_2 * g * wM - r_3 * w3) ** 2 + sp.Rational(1, 2) * (
        b_M * wM**2 + b_1 * (r_M / R_1 * wM) ** 2 + b_2 * (g * wM) ** 2 + b_3 * w3**2
    )  # Rayleigh: span dampers + bearings
    dM, d3 = sp.symbols("delta_phi_M delta_phi_3")
    Q = _generalized_forces(M_drive * dM - M_load * d3, [dM, d3])  # drive on M, load opposes wheel 3
    assert Q == [M_drive, -M_load]
    eqs = _lagrange(T - V, D, Q, [phi_M, phi_3])
    M, C, K, F = _second_order_matrices(eqs, [phi_M, phi_3])
    A, B = _state_space(M, C, K, F)
    # Energies as functions of the state x = [phi_M, phi_3, w_M, w_3], for the energy checks.
    x = sp.symbols("x0:4")
    xs = {wM: x[2], w3: x[3], phi_M: x[0], phi_3: x[1]}
    energies = {"T": T.subs(xs), "V": V.subs(xs), "P_d": 2 * D.subs(xs)}
    lam = lambda expr: sp.lambdify(SYMBOLS, expr, modules="numpy")  # noqa: E731
    lam_x = lambda expr: sp.lambdify((SYMBOLS, x), expr, modules="numpy")  # noqa: E731
    return {
        "M": lam(M), "C": lam(C), "K": lam(K), "A": lam(A), "B": lam(B),
        "energies": {name: lam_x(e) for name, e in energies.items()},
        "K_sym": K,
    }


@pytest.fixture(scope="module")
def rigid_symbolic():
    """Derive the rigid (1 DOF) model: the same Lagrangian with phi_3 = i phi_M (V = 0)."""
    phi_M = sp.Function("phi_M")(t)
    wM = phi_M.diff(t)
    w3 = i_ratio * wM
    T = (
        sp.Rational(1, 2) * I_M * wM**2
        + sp.Rational(1, 2) * I_1 * (r_M / R_1 * wM) ** 2
        + sp.Rational(1, 2) * I_2 * (g * wM) ** 2
        + sp.Rational(1, 2) * I_3 * w3**2
    )  # paper eq. 11
    V = 2 * sp.Rational(1, 2) * k * (r_2 * g * phi_M - r_3 * i_ratio * phi_M) ** 2
    assert sp.simplify(V) == 0  # a rigid belt stores nothing
    D = 2 * sp.Rational(1, 2) * c * (r_2 * g * wM - r_3 * w3) ** 2 + sp.Rational(1, 2) * (
        b_M * wM**2 + b_1 * (r_M / R_1 * wM) ** 2 + b_2 * (g * wM) ** 2 + b_3 * w3**2
    )
    dM = sp.symbols("delta_phi_M")
    Q = _generalized_forces(M_drive * dM - M_load * i_ratio * dM, [dM])  # delta phi_3 = i delta phi_M
    eqs = _lagrange(T - V, D, Q, [phi_M])
    M, C, K, F = _second_order_matrices(eqs, [phi_M])
    A, B = _state_space(M, C, K, F)
    lam = lambda expr: sp.lambdify(SYMBOLS, expr, modules="numpy")  # noqa: E731
    return {"M": lam(M), "C": lam(C), "K": lam(K), "A": lam(A), "B": lam(B)}


def random_params(rng: np.random.Generator, n: int = N_RANDOM) -> list[BeltDriveParams]:
    """Parameter sets log-uniform over several decades; some with zero intermediate inertia or damping."""
    out = []
    for j in range(n):
        lu = lambda lo, hi: float(np.exp(rng.uniform(np.log(lo), np.log(hi))))  # noqa: E731
        values = {
            "I_M": lu(1e-3, 1.0), "I_1": lu(1e-4, 0.1), "I_2": lu(1e-4, 0.1), "I_3": lu(1e-3, 1.0),
            "r_M": lu(0.01, 0.2), "R_1": lu(0.01, 0.2), "r_1": lu(0.01, 0.2), "R_2": lu(0.01, 0.2),
            "r_2": lu(0.02, 0.2), "r_3": lu(0.02, 0.2),
            "k": lu(1e3, 1e7), "c": lu(1e-2, 1e2),
            "b_M": lu(1e-4, 1e-1), "b_1": lu(1e-4, 1e-1), "b_2": lu(1e-4, 1e-1), "b_3": lu(1e-4, 1e-1),
        }
        if j % 5 == 1:
            values["I_1"] = 0.0  # intermediate wheels may be massless
        if j % 5 == 2:
            values["I_2"] = 0.0
            values["c"] = 0.0
        out.append(BeltDriveParams(**values))
    return out


def _args(p: BeltDriveParams):
    return [getattr(p, name) for name in PARAM_NAMES]


def test_flexible_matrices_equal_lagrange_derivation(flexible_symbolic):
    for p in random_params(np.random.default_rng(20240601)):
        model = FlexibleBeltModel(p)
        a = _args(p)
        np.testing.assert_allclose(model.mass_matrix, flexible_symbolic["M"](*a), rtol=RTOL_MATRIX, atol=0)
        np.testing.assert_allclose(model.stiffness_matrix, flexible_symbolic["K"](*a), rtol=RTOL_MATRIX, atol=0)
        np.testing.assert_allclose(model.damping_matrix, flexible_symbolic["C"](*a), rtol=RTOL_MATRIX, atol=0)
        # the model's state is [phi_M, delta, omega_M, omega_3]; T maps it to Lagrange's [phi_M, phi_3, ...]
        T = model.lagrange_map
        np.testing.assert_array_equal(T @ T, np.eye(4))
        A_sym = flexible_symbolic["A"](*a)
        np.testing.assert_allclose(T @ model.A @ T, A_sym, rtol=RTOL_MATRIX, atol=RTOL_MATRIX * np.max(np.abs(A_sym)))
        np.testing.assert_allclose(T @ model.B, flexible_symbolic["B"](*a), rtol=RTOL_MATRIX, atol=0)


def test_rigid_matrices_equal_lagrange_derivation(rigid_symbolic):
    for p in random_params(np.random.default_rng(7)):
        model = RigidBeltModel(p)
        a = _args(p)
        m = float(np.squeeze(rigid_symbolic["M"](*a)))
        assert p.inertia_reduced == pytest.approx(m, rel=RTOL_MATRIX)  # paper eq. 13
        assert p.bearing_damping_reduced == pytest.approx(float(np.squeeze(rigid_symbolic["C"](*a))), rel=RTOL_MATRIX)
        assert float(np.squeeze(rigid_symbolic["K"](*a))) == 0.0  # the belt term cancels exactly
        np.testing.assert_allclose(model.A, rigid_symbolic["A"](*a), rtol=RTOL_MATRIX, atol=0)
        np.testing.assert_allclose(model.B, rigid_symbolic["B"](*a), rtol=RTOL_MATRIX, atol=0)


def test_energy_functions_equal_lagrangian_terms(flexible_symbolic):
    """kinetic/potential energy and dissipation power of the runtime equal T, V and 2 D."""
    rng = np.random.default_rng(99)
    for p in random_params(rng, 8):
        model = FlexibleBeltModel(p)
        a = _args(p)
        x = rng.normal(size=(5, 4)) * np.array([0.1, 0.1, 50.0, 50.0])
        e = flexible_symbolic["energies"]
        for row in x:  # row in Lagrange's coordinates; the model reads its own state T row
            assert model.kinetic_energy(model.lagrange_map @ row) == pytest.approx(e["T"](a, row), rel=1e-12)
            assert model.potential_energy(model.lagrange_map @ row) == pytest.approx(e["V"](a, row), rel=1e-12)
            assert model.dissipation_power(model.lagrange_map @ row) == pytest.approx(e["P_d"](a, row), rel=1e-12)



def test_symbolic_stiffness_matches_design_note(flexible_symbolic):
    """K = 2k [[r_2^2 g^2, -r_2 r_3 g], [-r_2 r_3 g, r_3^2]] exactly (model.md), i.e. erratum 1 fixed."""
    K = flexible_symbolic["K_sym"]
    expected = 2 * k * sp.Matrix([[r_2**2 * g**2, -r_2 * r_3 * g], [-r_2 * r_3 * g, r_3**2]])
    assert sp.simplify(K - expected) == sp.zeros(2, 2)


# ------------------------------------------------- the paper's erratum 1
#: Geometry of the shipped ``paper`` scene, written out so the test does not
#: move with the defaults: g = (0.04/0.06)(0.03/0.05) = 0.4, far from 1.
PAPER_GEOMETRY = dict(
    I_M=0.02, I_1=0.004, I_2=0.003, I_3=0.03, r_M=0.04, R_1=0.06, r_1=0.03, R_2=0.05, r_2=0.06, r_3=0.05, k=2.0e4
)
UNDAMPED = dict(c=0.0, b_M=0.0, b_1=0.0, b_2=0.0, b_3=0.0)


def test_paper_stiffness_is_not_symmetric_and_differs_from_derivation():
    p = BeltDriveParams(**PAPER_GEOMETRY)
    gg = p.gear_ratio
    assert abs(gg - 1.0) > 0.1  # the erratum is invisible at g = 1
    Kp = paper_as_printed_stiffness(p)
    K = FlexibleBeltModel(p).stiffness_matrix
    # Symmetric PSD where it must be, non-symmetric as printed:
    np.testing.assert_array_equal(K, K.T)
    assert np.min(np.linalg.eigvalsh(K)) >= -1e-9 * np.max(np.abs(K))
    asym = abs(Kp[0, 1] - Kp[1, 0])
    assert asym == pytest.approx(2 * p.k * p.r_2 * p.r_3 * abs(1 - gg), rel=1e-12)
    assert asym > 0.1 * np.max(np.abs(Kp))
    # Precisely: the printed first row is the derived first row divided by g; the second row is right.
    np.testing.assert_allclose(Kp[0], K[0] / gg, rtol=1e-12)
    np.testing.assert_allclose(Kp[1], K[1], rtol=1e-12)


def _free_energy_history(params, stiffness, n_periods=60, steps_per_period=50):
    """Undamped, unforced run with the exact method from a deflected belt; total energy T + V per step."""
    model = FlexibleBeltModel(params)
    mass = model.mass_matrix
    A = np.zeros((4, 4))
    A[0:2, 2:4] = np.eye(2)
    A[2:4, 0:2] = -np.linalg.solve(mass, stiffness)
    dt = 2 * np.pi / params.belt_natural_frequency / steps_per_period
    integ = make_integrator("exact", A, model.B, dt)
    n = n_periods * steps_per_period
    x0 = np.array([0.0, -1e-3, 0.0, 0.0])  # wheel 3 lags by 1 mrad, everything at rest
    Phi = integ.linear_step().Phi
    states = [x0]
    for _ in range(n):
        states.append(Phi @ states[-1])
    states = np.array(states)
    energy = model.total_energy(states @ model.lagrange_map.T)  # the paper's own energy: eq. 17 + eq. 15
    return energy


def test_paper_stiffness_breaks_energy_conservation():
    """Same run, two stiffness matrices: the derived K conserves T + V, the printed one does not.

    The printed K equals diag(1/g, 1) K, so M^-1 K_printed = diag(g I_f, I_3)^-1 K:
    it conserves the energy of a system whose drive side is g times heavier, not
    the paper's own T (eq. 17) + V (eq. 15). The physical energy therefore swings
    by O(|1 - g|) of itself (measured: 0.66 at g = 0.4).
    """
    p = BeltDriveParams(**PAPER_GEOMETRY, **UNDAMPED)
    correct = _free_energy_history(p, FlexibleBeltModel(p).stiffness_matrix)
    printed = _free_energy_history(p, paper_as_printed_stiffness(p))
    drift_correct = np.max(np.abs(correct - correct[0])) / correct[0]
    drift_printed = np.max(np.abs(printed - printed[0])) / printed[0]
    assert drift_correct < 1e-12  # rounding only
    assert drift_printed > 0.1  # eleven orders of magnitude above rounding: not an energy-conserving system
