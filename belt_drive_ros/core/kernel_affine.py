"""The compiled long-run path of :func:`~belt_drive_ros.core.model._affine` (numba): ``y = x M^T`` of many samples in
one pass, each output summed column by column from the left, ``((x_0 M_j0 + x_1 M_j1) + x_2 M_j2) + ...``: the same
floats as numpy's outer products summed in that order and as one sample's plain floats (no BLAS, no reordering, no
fused multiply-add). Compiled once, cached on disk, run without the GIL; ``NUMBA_DISABLE_JIT=1`` runs it as Python
with the same floats."""

from __future__ import annotations

import numpy as np
from numba import njit

_JIT = dict(cache=True, nogil=True)


@njit(**_JIT)
def affine_rows(M, x, out):
    """``out[j, i] = sum_k x[i, k] M[j, k]`` summed from ``k = 0`` up: ``M`` (O, n), ``x`` (N, n), ``out`` (O, N),
    float64, C-contiguous. Output row by output row, so each row is written in order."""
    rows, n = M.shape
    samples = x.shape[0]
    for j in range(rows):
        m = M[j, 0]
        for i in range(samples):
            out[j, i] = x[i, 0] * m
        for k in range(1, n):
            m = M[j, k]
            for i in range(samples):
                out[j, i] = out[j, i] + x[i, k] * m


def warm() -> None:
    """Compile (or load from the disk cache) :func:`affine_rows` with the one signature runs use."""
    affine_rows(np.zeros((2, 2)), np.zeros((1, 2)), np.empty((2, 1)))
