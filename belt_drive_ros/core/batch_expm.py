"""Matrix exponentials of a stack of small matrices at once (numpy over the batch axis).

``scipy.linalg.expm`` accepts a stack (..., n, n) but computes each matrix
with its own calls (tens of us per 4x4 matrix); an ensemble of thousands of
variants needs a dozen exponentials per variant. This is the same algorithm,
scaling and squaring with the degree-13 Pade approximant (Higham 2005, "The
scaling and squaring method for the matrix exponential revisited", SIAM J.
Matrix Anal. Appl. 26(4), Algorithm 2.3), written with batched matmul and
solve::

    s = max(0, ceil(log2(||A||_1 / theta_13)))       per matrix
    r_13(X) = q(X)^{-1} p(X),  X = A / 2^s            (p(X) = V + U, q(X) = V - U)
    e^A = r_13(X)^(2^s)                                (s squarings)

It agrees with scipy's per-matrix result to rounding (scipy picks a lower
degree for small norms; tests/test_ensemble.py compares the two).
"""

from __future__ import annotations

import numpy as np

#: Pade coefficients b_0 .. b_13 of degree 13 (Higham 2005, Table 2.3 / eq. 2.5)
_B13 = (
    64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0, 129060195264000.0,
    10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0,
)  # fmt: skip
#: largest ||X||_1 for which r_13 is accurate to double precision (Higham 2005, Table 2.3)
_THETA_13 = 5.371920351148152


def expm_stack(A: np.ndarray) -> np.ndarray:
    """e^{A[k]} for each matrix of a stack ``A`` (..., n, n) of real or complex matrices."""
    A = np.asarray(A)
    if A.ndim == 2:
        return expm_stack(A[None])[0]
    shape = A.shape
    A = A.reshape((-1,) + shape[-2:])
    n = shape[-1]
    norm = np.max(np.sum(np.abs(A), axis=-2), axis=-1)  # ||A||_1 per matrix
    with np.errstate(divide="ignore"):
        s = np.maximum(0, np.ceil(np.log2(norm / _THETA_13))).astype(int)
    s[~np.isfinite(norm)] = 0
    X = A / np.ldexp(1.0, s)[:, None, None]
    b = _B13
    eye = np.eye(n, dtype=X.dtype)
    X2 = X @ X
    X4 = X2 @ X2
    X6 = X4 @ X2
    U = X @ (X6 @ (b[13] * X6 + b[11] * X4 + b[9] * X2) + b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * eye)
    V = X6 @ (b[12] * X6 + b[10] * X4 + b[8] * X2) + b[6] * X6 + b[4] * X4 + b[2] * X2 + b[0] * eye
    R = np.linalg.solve(V - U, V + U)
    for j in range(int(s.max(initial=0))):
        squared = R @ R
        R = np.where((j < s)[:, None, None], squared, R)
    return R.reshape(shape)
