"""Matrix exponentials of a stack of small matrices at once (numpy over the batch axis; ``scipy.linalg.expm`` takes
tens of us per 4x4 matrix, an ensemble needs a dozen per variant). Scaling and squaring with Pade approximants
(Higham 2005, SIAM J. Matrix Anal. Appl. 26(4), Alg. 2.3) and the scaling of Al-Mohy and Higham 2009 (ibid. 31(3),
Alg. 3.1 without its backward-error correction), batched matmul and solve::

    s = max(0, ceil(log2(eta / theta_13))),  eta = min(max(d6, d8), max(d8, d10)),  d_p = ||A^p||_1^(1/p)
    r_13(X) = q(X)^{-1} p(X),  X = A / 2^s    (p = V + U, q = V - U);      e^A = r_13(X)^(2^s)

It agrees with scipy's per-matrix result to rounding (tests/test_ensemble.py).
"""

from __future__ import annotations

import numpy as np

#: Pade coefficients of degrees 3, 5, 7, 9, 13 (Higham 2005, eq. 2.5) and the norm bounds theta_m (Table 2.3:
#: theta_13 the largest ||X||_1 for which r_13 is accurate to double precision)
_B = {
    3: (120.0, 60.0, 12.0, 1.0),
    5: (30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0),
    7: (17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0),
    9: (17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0, 2162160.0, 110880.0, 3960.0, 90.0, 1.0),
    13: (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0, 129060195264000.0,
         10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0),
}  # fmt: skip
_THETA_13 = 5.371920351148152
_THETA = {3: 1.495585217958292e-2, 5: 2.539398330063230e-1, 7: 9.504178996162932e-1, 9: 2.097847961257068, 13: _THETA_13}


def _pade(m: int, X: dict, eye: np.ndarray):
    """(U, V) of the degree-m Pade approximant r_m = (V - U)^-1 (V + U) from the even powers X[2k] and X[1]."""
    b = _B[m]
    if m == 13:
        X1, X2, X4, X6 = X[1], X[2], X[4], X[6]
        U = X1 @ (X6 @ (b[13] * X6 + b[11] * X4 + b[9] * X2) + b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * eye)
        V = X6 @ (b[12] * X6 + b[10] * X4 + b[8] * X2) + b[6] * X6 + b[4] * X4 + b[2] * X2 + b[0] * eye
        return U, V
    odd = b[1] * eye + sum(b[k + 1] * X[k] for k in range(2, m, 2))
    V = b[0] * eye + sum(b[k] * X[k] for k in range(2, m, 2))
    return X[1] @ odd, V


def expm_stack(A: np.ndarray) -> np.ndarray:
    """e^{A[k]} for each matrix of a stack ``A`` (..., n, n), real or complex (or one (n, n) matrix): the lowest
    degree m = 3, 5 whose theta_m bounds max(d4, d6), else 7, 9 bounding max(d6, d8), else 13 with the scaling s.

    Each matrix's result depends on that matrix alone, bit for bit (numpy's stacked ``matmul`` and ``solve`` call
    BLAS/LAPACK matrix by matrix, the rest is elementwise): a single run and an ensemble get the same floats.
    """
    A = np.asarray(A)
    if A.ndim == 2:
        return expm_stack(A[None])[0]
    shape = A.shape
    A = A.reshape((-1,) + shape[-2:])
    n = shape[-1]
    eye = np.eye(n, dtype=A.dtype)
    P = {1: A, 2: A @ A}
    P[4] = P[2] @ P[2]
    P[6] = P[4] @ P[2]
    P[8] = P[4] @ P[4]
    P[10] = P[8] @ P[2]

    def d(p):  # ||A^p||_1^(1/p)
        return np.abs(P[p]).sum(axis=-2).max(axis=-1) ** (1.0 / p)

    d4, d6, d8, d10 = d(4), d(6), d(8), d(10)
    eta1, eta3 = np.maximum(d4, d6), np.maximum(d6, d8)
    eta5 = np.minimum(eta3, np.maximum(d8, d10))
    m = np.full(A.shape[0], 13)
    for degree, eta in ((9, eta3), (7, eta3), (5, eta1), (3, eta1)):
        m = np.where(eta <= _THETA[degree], degree, m)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.ceil(np.log2(eta5 / _THETA_13))
    s = np.where((m == 13) & np.isfinite(s), np.maximum(s, 0), 0).astype(int)
    R = np.empty_like(A, dtype=np.result_type(A, float))
    degrees = np.unique(m)
    for degree in degrees:
        every = len(degrees) == 1
        idx = slice(None) if every else np.flatnonzero(m == degree)
        if degree == 13 and np.any(s[idx]):
            scale = np.ldexp(1.0, -s[idx])[:, None, None]  # a power of two: X = A / 2^s exactly
            X = {p: P[p][idx] * scale**p for p in (1, 2, 4, 6, 8)}
        else:
            X = {p: P[p][idx] for p in (1, 2, 4, 6, 8)} if not every else P
        U, V = _pade(int(degree), X, eye)
        R[idx] = np.linalg.solve(V - U, V + U)
    for j in range(int(s.max(initial=0))):
        squared = j < s
        if squared.all():
            R = R @ R
        else:
            R[squared] = R[squared] @ R[squared]
    return R.reshape(shape)
