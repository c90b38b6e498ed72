"""The accuracy guard's batched pieces give each matrix's own floats: closed-loop maps of several gains in one
step, spectral radii of a stack, and a Lawson method's exponentials with their halves in one call."""

import numpy as np
import pytest

from belt_drive_ros.core import integrators
from belt_drive_ros.core.accuracy_probes import closed_loop_maps, closed_loop_maps_of
from belt_drive_ros.core.integrators import make_integrator
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.stability import spectral_radii, spectral_radius
from belt_drive_ros.io.scenes import load_scene


def _flexible(c_scale: float):
    p = load_scene("paper").params
    return make_model("flexible", p.replace(c=p.c * c_scale))


GAINS = [np.array([[-0.3, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, -0.05]]), np.zeros((2, 4)),
         np.array([[0.0, -2.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.7]])]  # fmt: skip


@pytest.mark.parametrize("method", ["lawson5", "etd2", "rk4", "trapezoidal", "exact", "symplectic_euler"])
def test_maps_of_several_gains_are_each_gains_own(method):
    m = _flexible(1.0 + 3e-12)
    integrator = make_integrator(method, m.A, m.B, 2e-3)
    together = closed_loop_maps_of(integrator, GAINS)
    for K, (M, G) in zip(GAINS, together):
        M1, G1 = closed_loop_maps(integrator, K)
        assert M.tobytes() == M1.tobytes() and G.tobytes() == G1.tobytes()
    assert not np.array_equal(together[0][0], together[2][0])  # the gains' maps differ: each read its own K


def test_spectral_radii_of_a_stack_are_each_maps_own():
    m = _flexible(1.0)
    integrator = make_integrator("rk4", m.A, m.B, 5e-3)
    maps = [M for M, _ in closed_loop_maps_of(integrator, GAINS)]
    real = np.diag([0.5, -0.9, 1.0 + 1e-9, 0.2])  # real eigenvalues only, stacked with complex ones
    radii = spectral_radii(np.stack(maps + [real]))
    assert radii == [spectral_radius(M) for M in maps + [real]]
    assert radii[-1] == 1.0  # the rigid-body Jordan block's 1 +/- sqrt(eps) snapped to 1


def test_lawson_exponentials_with_their_halves_are_the_same_floats():
    A = _flexible(1.0 + 7e-12).A
    taus = (1e-3, 1.5e-3, 4e-3)
    integrators._EXPM_AT.clear()
    with_halves = integrators._expm_at(A, taus, halves=True)
    half = integrators._expm_at(A, tuple(t / 2.0 for t in taus))  # kept by the first call
    assert with_halves.tobytes() == integrators._expm_at_of(A, taus).tobytes()
    assert half.tobytes() == integrators._expm_at_of(A, tuple(t / 2.0 for t in taus)).tobytes()
    B = _flexible(1.0 + 7e-12).B
    lawson5 = integrators.REGISTRY["lawson5"]  # (make_integrator would share one integrator and its scheme)
    integrators._EXPM_AT.clear()
    whole, halved = (lawson5(A, B, h).scheme for h in (5e-3, 2.5e-3))  # the half step's read from the first
    assert sum(1 for key in integrators._EXPM_AT if key[0] == integrators._key(A)) == 2  # one call kept both
    integrators._EXPM_AT.clear()
    for h, scheme in ((2.5e-3, halved), (5e-3, whole)):  # each alone, the half step first: nothing kept to read
        alone = lawson5(A, B, h).scheme
        assert alone.final.tobytes() == scheme.final.tobytes()
        assert all(a is b or a.tobytes() == b.tobytes() for a, b in zip(alone.stages, scheme.stages))
