"""``model._affine`` (a model's outputs, wheel coordinates: ``x @ M.T``) checks its shapes on long runs too.

A long run (over 512 numbers, several rows) is one compiled pass (:mod:`~belt_drive_ros.core.kernel_affine`), which
has no bounds checks: samples with fewer states than ``M`` has columns were read past each row, and past the
array's end on the last one, returning numbers instead of the IndexError a short run raises.
"""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.core.model import _affine


@pytest.mark.parametrize("samples", [10, 600, 5000])
@pytest.mark.parametrize("columns", [0, 2, 3])
def test_samples_with_fewer_states_than_the_map_has_columns_raise_at_any_length(samples, columns):
    M = np.arange(12.0).reshape(3, 4)
    with pytest.raises(IndexError):
        _affine(M, np.ones((samples, columns)))


def test_a_map_without_columns_raises_at_any_length():
    for samples in (10, 600):
        with pytest.raises(IndexError):
            _affine(np.ones((3, 0)), np.ones((samples, 0)))


@pytest.mark.parametrize("samples", [10, 600])
def test_long_and_short_runs_agree_where_the_shapes_fit(samples):
    rng = np.random.default_rng(3)
    M, x = rng.standard_normal((3, 4)), rng.standard_normal((samples, 4))
    y = _affine(M, x)
    assert np.array_equal(y, np.stack([_affine(M, row) for row in x]))
