"""The accuracy guard's closed-loop verdicts of several probe gains made together (``accuracy_probes.linear_verdicts``:
one stacked exponential, one stacked eigenvalue call, one step-response orbit for all gains) are each gain's
verdict made alone, to the last bit: the guard's figures and verdicts do not depend on how many gains a scene's
probes give or on which of them a cache already held.
"""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.core import accuracy as acc
from belt_drive_ros.core import accuracy_probes as probes
from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.io.scenes import load_scene


def _calls(name: str, monkeypatch) -> list:
    """Every ``linear_verdicts`` call of a simulate() of ``name`` with numbers no cache has seen."""
    calls, made = [], probes.linear_verdicts

    def record(integrator, A, B, rows, Ks, n_steps):
        calls.append((integrator, A, B, rows, list(Ks), n_steps))
        return made(integrator, A, B, rows, Ks, n_steps)

    monkeypatch.setattr(acc, "linear_verdicts", record)
    scene = load_scene(name)
    simulate(scene.with_params(scene.params.replace(c=scene.params.c * (1.0 + 9e-12))))
    monkeypatch.setattr(acc, "linear_verdicts", made)
    return calls


@pytest.mark.parametrize("name", ["paper", "bsg_start"])  # stick-mode gains (3), and the slip mode's (both directions)
def test_gains_together_are_each_gain_alone(name, monkeypatch):
    calls = _calls(name, monkeypatch)
    together_sizes = [len(c[4]) for c in calls]
    assert max(together_sizes) >= 3  # several gains were made in one call
    for integrator, A, B, rows, Ks, n_steps in calls:
        probes._LINEAR_CACHE.clear()
        probes._EIGENVALUES.clear()
        together = probes.linear_verdicts(integrator, A, B, rows, Ks, n_steps)
        for K, verdict in zip(Ks, together):
            probes._LINEAR_CACHE.clear()
            probes._EIGENVALUES.clear()
            (alone,) = probes.linear_verdicts(integrator, A, B, rows, (K,), n_steps)
            assert repr(alone) == repr(verdict)  # every float to the bit (repr round-trips)
        # some cached, some not: the same verdicts in the gains' order
        probes._LINEAR_CACHE.clear()
        probes.linear_verdicts(integrator, A, B, rows, Ks[-1:], n_steps)
        assert repr(probes.linear_verdicts(integrator, A, B, rows, Ks, n_steps)) == repr(together)


def test_stacked_eigenvalues_and_exponentials_are_each_matrix_alone():
    rng = np.random.default_rng(5)
    A = np.triu(rng.normal(size=(4, 4))) * 100.0  # real eigenvalues with K = 0, complex ones with the other gains
    B = rng.normal(size=(4, 2))
    Ks = [np.zeros((2, 4))] + [rng.normal(size=(2, 4)) * 50.0 for _ in range(3)]
    probes._EIGENVALUES.clear()
    stacked = probes._eigenvalues(A, B, Ks)
    E, F = probes.exact_maps(np.stack([A + B @ K for K in Ks]), B, 1e-3)
    for j, K in enumerate(Ks):
        alone = np.linalg.eigvals(A + B @ K)
        assert stacked[j].dtype == alone.dtype and stacked[j].tobytes() == alone.tobytes()
        E1, F1 = probes.exact_maps(A + B @ K, B, 1e-3)
        assert E1.tobytes() == np.ascontiguousarray(E[j]).tobytes() and F1.tobytes() == np.ascontiguousarray(F[j]).tobytes()
    assert stacked[0].dtype == np.float64 and any(np.iscomplexobj(s) for s in stacked[1:])
