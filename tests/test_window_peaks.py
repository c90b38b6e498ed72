"""The campaign's peaks of a window of variant knots in one compiled pass (``kernel_variants.window_peaks``) are the
floats of numpy's reductions of the outputs they replace, NaN, infinities and signed zeros included."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from belt_drive_ros.campaign.ensemble_run import GroupRun, peak_over_time, run_groups
from belt_drive_ros.campaign.metrics import GROUP_REDUCTION, run_metrics
from belt_drive_ros.core.ensemble import weighted_columns
from belt_drive_ros.core.fidelity import friction_use
from belt_drive_ros.core.kernel_variants import window_peaks
from belt_drive_ros.core.params import friction_limit_array
from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.io.scenes import load_scene


def _bits(a) -> np.ndarray:
    return np.asarray(a, dtype=float).view(np.int64)


def _reference(times, states, weights, limits):
    """What the campaign computed before: the outputs by ``weighted_columns``, then numpy's reductions."""
    K, _, V = states.shape
    with np.errstate(all="ignore"):
        belt, deflection, omega = (
            y if (y := weighted_columns(states, weights[j])) is not None else np.zeros((K, V)) for j in range(3)
        )
        q_max = friction_limit_array(limits[:, 1], limits[:, 3], limits[:, 2], limits[:, 4], omega)
        use = friction_use(belt, limits[:, 5], q_max)
        return (np.max(np.abs(belt), axis=0), np.max(np.abs(deflection), axis=0), np.max(use, axis=0),
                *peak_over_time(use, times))  # fmt: skip


@pytest.mark.parametrize("seed", range(6))
def test_the_same_floats_as_numpys_reductions(seed):
    rng = np.random.default_rng(seed)
    for trial in range(60):
        K, n, V = int(rng.integers(1, 70)), int(rng.choice([2, 4])), int(rng.integers(1, 40))
        states = rng.standard_normal((K, n, V)) * 10 ** rng.uniform(-3, 3)
        if trial % 3 == 0:  # diverged knots, zeros of either sign
            for _ in range(4):
                states[rng.integers(K), rng.integers(n), rng.integers(V)] = rng.choice([np.nan, np.inf, -np.inf, 0.0, -0.0])
        weights = rng.standard_normal((3, n, V))
        weights[:, rng.integers(n), :] = 0.0  # a column no variant weighs: skipped
        if trial % 2:  # the speed a state column taken as it is
            weights[2] = 0.0
            weights[2, 1] = 1.0
        if trial % 5 == 0:  # an output of no column: 0.0
            weights[1] = 0.0
        if trial % 7 == 0:  # a column some variants weigh 0.0: summed for all (0.0 times an infinity is NaN)
            weights[0, 0, : V // 2] = 0.0
        times = np.cumsum(rng.uniform(0.0, 1e-3, K))
        F_0 = rng.uniform(1.0, 500.0, V)
        F_0[: V // 2] *= trial % 9 != 0  # Q_max 0: a friction use of inf
        mass = rng.uniform(0.0, 0.5, V) * (trial % 4 != 0)  # a belt mass lifting the belt off at speed
        limits = np.ascontiguousarray(np.stack(
            [np.ones(V), F_0, mass, rng.uniform(0.0, 1.0, V), rng.uniform(0.5, 2.0, V), rng.uniform(0.01, 0.1, V)], axis=1))
        columns = np.array([[bool(np.any(w)) for w in weights[j]] for j in range(3)], dtype=np.int64)
        out = np.empty((4, V))
        window_peaks(times, states, np.ascontiguousarray(weights), columns, limits, out)
        belt, deflection, use, peak, at = _reference(times, states, weights, limits)
        for got, want in ((out[0], belt), (out[1], deflection), (out[2], use), (out[2], peak), (out[3], at)):
            assert np.array_equal(_bits(got), _bits(want)), (seed, trial, got, want)


def test_a_windowed_campaign_gives_the_single_runs_metrics():
    """Through ``run_groups``' windows (the capstan check and the metrics from ``GroupRun.peaks``): each variant's
    metrics are those of its single ``simulate`` run, bit for bit, and the block's peaks those of the numpy path."""
    base = dataclasses.replace(load_scene("paper"), duration=0.6)
    scenes = [dataclasses.replace(base, params=base.params.replace(k=base.params.k * (1 + 0.02 * i), F_0=base.params.F_0 * (1 - 0.03 * i)))
              for i in range(12)]  # fmt: skip
    blocks = [item for item in run_groups(scenes, reduce=GROUP_REDUCTION) if not hasattr(item, "index")]
    assert sum(len(b) for b in blocks) == 12
    from belt_drive_ros.campaign.metrics import summary_values

    for block in blocks:
        values = summary_values(block.values)
        for w, i in enumerate(block.indices):
            single = run_metrics(simulate(scenes[i], check_stability=False))
            for name, value in single.items():
                assert _bits(values[name][w]) == _bits(value), (i, name, values[name][w], value)
    # the block of a whole run: the compiled peaks equal the outputs' reductions
    run = next(item for item in run_groups(scenes) if isinstance(item, GroupRun))
    peaks = run.peaks()
    run._fixed["peaks"] = False  # (the numpy path, as for an output with a row of D)
    run._outputs.pop(" peaks")
    numpy_peaks = run.peaks()
    for name in ("belt", "deflection"):
        assert np.array_equal(_bits(peaks[name]), _bits(numpy_peaks[name]))
    assert all(np.array_equal(_bits(a), _bits(b)) for a, b in zip(peaks["use"], numpy_peaks["use"]))
