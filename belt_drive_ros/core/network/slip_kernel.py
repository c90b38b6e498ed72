"""The compiled loop of a belt network's slipping tier (stick or slip at every pulley, events located).

Every function is ``@njit(cache=True, nogil=True)`` over float64/int64 arrays and floats, valid Python under
``NUMBA_DISABLE_JIT=1`` with the same floats (every sum an explicit loop from the left, no BLAS call).

State ``x = [q (m), q' (m), s (n)]`` and mode ``sig`` (n,) as in :mod:`.slip`; in a mode ``x' = A x + B u +
c (T_0 - w)``, a step its exact flow ``x+ = Phi x + Gamma b`` (``u``, ``w`` held). Per step, every pulley's
switching function at its end (stick: ``|T_i - T_{i-1}| - tanh(mu_i beta_i / 2)(T_i + T_{i-1} - 2 w)``; slip:
``-sig_i s_i'``); where one turns positive the event is located on the flow (``docs/model.md``, "Slip at every
pulley of a network"): a step is ``2^L`` units (:data:`LEVELS`), each mode keeps its flows over ``dt / 2^i``
(:func:`step_chain`), a scan at :data:`N_SCAN` points brackets the first crossing, halving finds the last unit
inside; one unit later every pulley past or on its surface switches, the step running on in the new mode. Mode
matrices and flows are cached per mode in caller-owned arrays.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..kernel_profiles import profile_torque_at

_JIT = dict(cache=True, nogil=True)
#: small helpers of the step are inlined into it (no call, no reference counting of the arrays passed)
_INLINE = dict(cache=True, nogil=True, inline="always")

#: status codes of :func:`slip_steps`
OK, DIVERGED, CHATTER, EVENTS_FULL, ALL_SLIP, STUCK = 0, 1, 4, 5, 6, 7
#: most mode switches inside one grid step before the run is refused as chattering
MAX_SWITCHES = 64
#: points scanned (on the exact flow) for the first crossing in a step whose end lies past a switching surface
N_SCAN = 8
#: most Taylor terms of the scaled exponential (||A h|| <= 1/2: the remainder is below 1e-19)
N_TAYLOR = 18
#: a step is 2^LEVELS units: events are located to dt / 2^LEVELS (1e-13 s at dt = 0.1 ms)
LEVELS = 30
#: layout of ``par``: T_0 [N], m' [kg/m], dt [s], speed limit [rad/s], damped (1.0: span damping > 0), then per
#: pulley i at ``P_SHAFT + i`` the drive shaft's turn per pulley turn (1 / gear: 1.0 without a gear train)
P_T0, P_MASS, P_DT, P_LIMIT, P_DAMPED, P_SHAFT = 0, 1, 2, 3, 4, 5


# --------------------------------------------------------------------------- small linear algebra
@njit(**_JIT)
def _matmul(A, B, out):
    """``out = A B`` (square; each entry summed from the left, row by row so the inner loop runs along memory)."""
    N = A.shape[0]
    for i in range(N):
        for j in range(N):
            out[i, j] = 0.0
        for l in range(N):
            ail = A[i, l]
            for j in range(N):
                out[i, j] += ail * B[l, j]


@njit(**_JIT)
def _taylor(A, h, Phi, Gam, term, nxt):
    """``Phi = e^(A h)``, ``Gam = int_0^h e^(A s) ds`` by their Taylor series (``||A h||_inf <= 1/2``): terms
    until the next one is below 1e-18 of 1 (at most :data:`N_TAYLOR`)."""
    N = A.shape[0]
    for i in range(N):
        for l in range(N):
            term[i, l] = 1.0 if i == l else 0.0
            Phi[i, l] = term[i, l]
            Gam[i, l] = h * term[i, l]
    for k in range(1, N_TAYLOR + 1):
        _matmul(term, A, nxt)
        big = 0.0
        for i in range(N):
            for l in range(N):
                term[i, l] = nxt[i, l] * (h / k)
                Phi[i, l] += term[i, l]
                Gam[i, l] += h * term[i, l] / (k + 1)
                big = max(big, abs(term[i, l]))
        if big < 1e-18:
            break


@njit(**_JIT)
def step_chain(A, dt, Phs, Gas):
    """Per level ``i = 0 .. L``: ``Phs[i] = e^(A h_i)``, ``Gas[i] = int_0^h_i e^(A s) ds``, ``h_i = dt / 2^i``.

    The level ``j`` where ``||A h_j||_inf <= 1/2`` and every finer one by their Taylor series; the coarser
    ones by doubling, ``Gam(2h) = Gam(h) + Phi(h) Gam(h)``, ``Phi(2h) = Phi(h)^2`` (scaling and squaring;
    the finer levels are not squared up from tinier ones, which would lose their small parts to rounding).
    A flow over any whole number of units ``dt / 2^L`` is a product of levels (:func:`_moved`).
    """
    N = A.shape[0]
    L = Phs.shape[0] - 1
    norm = 0.0
    for i in range(N):
        row = 0.0
        for l in range(N):
            row += abs(A[i, l])
        norm = max(norm, row)
    norm *= dt
    j = 0
    while norm > 0.5 and j < L:
        norm *= 0.5
        j += 1
    term = np.empty((N, N))
    nxt = np.empty((N, N))
    for i in range(j, L + 1):
        _taylor(A, dt / 2.0**i, Phs[i], Gas[i], term, nxt)
    for i in range(j - 1, -1, -1):
        _matmul(Phs[i + 1], Gas[i + 1], Gas[i])
        for q in range(N):
            for l in range(N):
                Gas[i, q, l] += Gas[i + 1, q, l]
        _matmul(Phs[i + 1], Phs[i + 1], Phs[i])


@njit(**_INLINE)
def _flow(Phi, Gam, x, b, out):
    """``out = Phi x + Gam b``."""
    N = x.shape[0]
    for i in range(N):
        total = 0.0
        for l in range(N):
            total += Phi[i, l] * x[l]
        for l in range(N):
            total += Gam[i, l] * b[l]
        out[i] = total


@njit(**_INLINE)
def _moved(Phs, Gas, x, b, units, out, tmp):
    """``out`` = ``x`` moved along the mode's exact flow by ``units`` of ``dt / 2^L`` (one level per set bit)."""
    L = Phs.shape[0] - 1
    N = x.shape[0]
    for q in range(N):
        out[q] = x[q]
    for i in range(L + 1):
        bit = np.int64(1) << (L - i)
        if units & bit:
            _flow(Phs[i], Gas[i], out, b, tmp)
            for q in range(N):
                out[q] = tmp[q]


@njit(**_INLINE)
def _rate(A, x, b, out):
    """``out = A x + b`` (the mode's x')."""
    N = x.shape[0]
    for i in range(N):
        total = b[i]
        for l in range(N):
            total += A[i, l] * x[l]
        out[i] = total


# --------------------------------------------------------------------------- modes
@njit(**_JIT)
def mode_key(sig):
    """An integer naming the mode ``sig`` (base 3)."""
    key = 0
    for i in range(sig.shape[0] - 1, -1, -1):
        key = 3 * key + int(sig[i]) + 1
    return key


@njit(**_INLINE)
def _sliding(sig):
    """``(S, ns)``: the sliding pulleys' indices in ``S[:ns]``."""
    S = np.empty(sig.shape[0], dtype=np.int64)
    ns = 0
    for i in range(sig.shape[0]):
        if sig[i] != 0:
            S[ns] = i
            ns += 1
    return S, ns


@njit(**_INLINE)
def _capstan_column(i, prev, l, n, ei, ep, w):
    """Coefficient of ``s_l`` in ``ei w_i delta_i + ep w_prev delta_prev`` (``s_l``: +1 in span l-1, -1 in span l)."""
    col = 0.0
    if (l - 1) % n == i:
        col += ei * w[i]
    if l == i:
        col -= ei * w[i]
    if (l - 1) % n == prev:
        col += ep * w[prev]
    if l == prev:
        col -= ep * w[prev]
    return col


@njit(**_JIT)
def build_mode(sig, par, Minv, Karm, Cb, a, k, c, f, A, cvec, Gt, gt, Ls, ls, Hk):
    """The mode ``sig``'s matrices (see the module docstring and :mod:`.slip`).

    ``s_S'`` of the sliding pulleys S solves the capstan equalities
    ``(1 - sig_i f_i) T_i - (1 + sig_i f_i) T_{i-1} = -2 sig_i f_i w`` (damped spans; undamped: their
    time derivative with w held), tensions ``T = T_0 + Gt x + gt (T_0 - w)``, slip speeds
    ``s' = Ls x + ls (T_0 - w)``. ``Hk`` (n, n) receives ``E_S diag(k) D_S`` (projection of undamped slip).
    Returns the number of sliding pulleys, -1 if their equations are singular.
    """
    n, m = a.shape[0], a.shape[1]
    N = 2 * m + n
    damped = par[P_DAMPED] > 0.0
    S, ns = _sliding(sig)
    # stretch rows: P x = a q + D s (D[j, j+1] = 1, D[j, j] = -1), Pd x = a q'
    P = np.zeros((n, N))
    Pd = np.zeros((n, N))
    for j in range(n):
        for l in range(m):
            P[j, l] = a[j, l]
            Pd[j, m + l] = a[j, l]
        P[j, 2 * m + (j + 1) % n] += 1.0
        P[j, 2 * m + j] -= 1.0
    for i in range(n):
        ls[i] = 0.0
        for l in range(N):
            Ls[i, l] = 0.0
    if ns == n:  # the massless belt sliding on every pulley: sum_i (T_i - T_{i-1}) = 0 leaves no motion
        return -1
    if ns > 0:
        H = np.zeros((ns, ns))
        R = np.zeros((ns, N + 1))
        for r in range(ns):
            i = S[r]
            prev = (i - 1) % n
            ei, ep = 1.0 - sig[i] * f[i], -(1.0 + sig[i] * f[i])
            for q in range(ns):  # column of s_l: +1 in span l-1, -1 in span l
                l = S[q]
                H[r, q] = _capstan_column(i, prev, l, n, ei, ep, c if damped else k)
                Hk[r, q] = _capstan_column(i, prev, l, n, ei, ep, k)
            for l in range(N):
                if damped:
                    R[r, l] = -(ei * (k[i] * P[i, l] + c[i] * Pd[i, l]) + ep * (k[prev] * P[prev, l] + c[prev] * Pd[prev, l]))
                else:
                    R[r, l] = -(ei * k[i] * Pd[i, l] + ep * k[prev] * Pd[prev, l])
            R[r, N] = 2.0 * sig[i] * f[i] if damped else 0.0
        det = np.linalg.det(H)
        if not det != 0.0 or not math.isfinite(det):
            return -1
        for r in range(ns):
            for q in range(N + 1):
                if not math.isfinite(R[r, q]):
                    return -1
        X = np.linalg.solve(H, R)
        for r in range(ns):
            i = S[r]
            for l in range(N):
                Ls[i, l] = X[r, l]
            ls[i] = X[r, N]
    # tensions: T - T_0 = k (P x) + c (Pd x + D s')
    for j in range(n):
        nxt, cur = (j + 1) % n, j
        for l in range(N):
            Gt[j, l] = k[j] * P[j, l] + c[j] * (Pd[j, l] + Ls[nxt, l] - Ls[cur, l])
        gt[j] = c[j] * (ls[nxt] - ls[cur])
    # x' = A x + B u + cvec (T_0 - w)
    for i in range(N):
        cvec[i] = 0.0
        for l in range(N):
            A[i, l] = 0.0
    for l in range(m):
        A[l, m + l] = 1.0
        for col in range(m):
            A[m + l, col] = -Minv[l] * Karm[l, col]
            A[m + l, m + col] = -Minv[l] * Cb[l, col]
        for col in range(N):
            total = 0.0
            for j in range(n):
                total += a[j, l] * Gt[j, col]
            A[m + l, col] -= Minv[l] * total
        total = 0.0
        for j in range(n):
            total += a[j, l] * gt[j]
        cvec[m + l] = -Minv[l] * total
    for i in range(n):
        for l in range(N):
            A[2 * m + i, l] = Ls[i, l]
        cvec[2 * m + i] = ls[i]
    return ns


@njit(**_JIT)
def _slot(sig, ckey, cuse, par, Minv, Karm, Cb, a, k, c, f, cA, cc, cGt, cgt, cLs, cls, cHk, cPh, cGa, clock):
    """The cache slot of mode ``sig`` (built with its step exponentials when new; the least recently used is
    replaced); -1 if the mode's equations are singular."""
    key = mode_key(sig)
    K = ckey.shape[0]
    for s in range(K):
        if ckey[s] == key:
            cuse[s] = clock
            return s
    s = 0
    for j in range(1, K):
        if cuse[j] < cuse[s]:
            s = j
    ns = build_mode(sig, par, Minv, Karm, Cb, a, k, c, f, cA[s], cc[s], cGt[s], cgt[s], cLs[s], cls[s], cHk[s])
    if ns < 0:
        return -1
    step_chain(cA[s], par[P_DT], cPh[s], cGa[s])
    ckey[s] = key
    cuse[s] = clock
    return s


# --------------------------------------------------------------------------- inputs and guards
@njit(**_INLINE)
def _inputs(t, x, m, sgn, pk, pp, ptx, pty, start, Minv, driver, r, par, cvec, b, u):
    """Pulley torques ``u`` at (t, x) (pulley i's profile from row ``start[i]`` of the stacked data), and
    ``b = B u + cvec (T_0 - w)``; returns ``w = m' v^2``."""
    n = sgn.shape[0]
    N = b.shape[0]
    for i in range(n):
        if sgn[i] != 0.0:
            g = par[P_SHAFT + i]
            if g == 1.0:
                u[i] = sgn[i] * profile_torque_at(pk, pp, ptx, pty, start[i], t, x[i], x[m + i])
            else:
                u[i] = sgn[i] * profile_torque_at(pk, pp, ptx, pty, start[i], t, x[i] * g, x[m + i] * g)
        else:
            u[i] = 0.0
    v = r[driver] * x[m + driver]
    w = par[P_MASS] * v * v
    for i in range(N):
        b[i] = cvec[i] * (par[P_T0] - w)
    for i in range(n):
        b[m + i] += Minv[i] * u[i]
    return w


@njit(**_INLINE)
def _tensions(Gt, gt, x, T0w, T0, T):
    n, N = Gt.shape[0], Gt.shape[1]
    for j in range(n):
        total = T0
        for l in range(N):
            total += Gt[j, l] * x[l]
        T[j] = total + gt[j] * T0w


@njit(**_INLINE)
def _slip_speed(Ls, ls, x, T0w, i):
    total = 0.0
    for l in range(x.shape[0]):
        total += Ls[i, l] * x[l]
    return total + ls[i] * T0w


@njit(**_INLINE)
def guards(sig, x, xd, T0w, par, f, r, driver, m, Gt, gt, Ls, ls, T, Td, g, dg):
    """Switching functions ``g`` (n,) at state ``x`` (positive once the pulley's mode must end) and their
    rates ``dg`` along ``xd`` (skipped when ``xd`` is empty); tensions into ``T`` (``Td``: their rates)."""
    n = sig.shape[0]
    T0, mass = par[P_T0], par[P_MASS]
    _tensions(Gt, gt, x, T0w, T0, T)
    rates = xd.shape[0] > 0
    if rates:
        _tensions(Gt, gt, xd, 0.0, 0.0, Td)
    v = r[driver] * x[m + driver]
    dv = r[driver] * xd[m + driver] if rates else 0.0
    for i in range(n):
        if sig[i] == 0:
            p = (i - 1) % n
            D = T[i] - T[p]
            g[i] = abs(D) - f[i] * (T[i] + T[p] - 2.0 * mass * v * v)
            if rates:
                sd = 1.0 if D >= 0.0 else -1.0
                dg[i] = sd * (Td[i] - Td[p]) - f[i] * (Td[i] + Td[p] - 4.0 * mass * v * dv)
        else:
            g[i] = -sig[i] * _slip_speed(Ls, ls, x, T0w, i)
            if rates:
                dg[i] = -sig[i] * _slip_speed(Ls, ls, xd, 0.0, i)


@njit(**_INLINE)
def _add_friction_work(weight, sig, x, T0w, par, Gt, gt, Ls, ls, T, work):
    """``work_i += weight (T_i - T_{i-1}) s_i'`` for the sliding pulleys at state ``x``."""
    n = sig.shape[0]
    _tensions(Gt, gt, x, T0w, par[P_T0], T)
    for i in range(n):
        if sig[i] != 0:
            work[i] += weight * (T[i] - T[(i - 1) % n]) * _slip_speed(Ls, ls, x, T0w, i)


@njit(**_JIT)
def _project(sig, x, w, par, a, k, f, Hk, m):
    """Undamped spans: put the sliding pulleys' ``s`` where their capstan equalities hold exactly at ``w``."""
    n = sig.shape[0]
    S, ns = _sliding(sig)
    if ns == 0 or par[P_DAMPED] > 0.0:
        return
    H = Hk[:ns, :ns].copy()
    rhs = np.empty(ns)
    # stretch without the sliding pulleys' s
    delta = np.empty(n)
    for j in range(n):
        total = 0.0
        for l in range(m):
            total += a[j, l] * x[l]
        nxt = (j + 1) % n
        if sig[nxt] == 0:
            total += x[2 * m + nxt]
        if sig[j] == 0:
            total -= x[2 * m + j]
        delta[j] = total
    for r in range(ns):
        i = S[r]
        p = (i - 1) % n
        ei, ep = 1.0 - sig[i] * f[i], -(1.0 + sig[i] * f[i])
        rhs[r] = 2.0 * sig[i] * f[i] * (par[P_T0] - w) - (ei * k[i] * delta[i] + ep * k[p] * delta[p])
    s = np.linalg.solve(H, rhs)
    for r in range(ns):
        x[2 * m + S[r]] = s[r]


# --------------------------------------------------------------------------- the loop
@njit(**_JIT)
def slip_steps(k0, k1, t0, x, sig, out, out_sig, out_T, out_sdot, out_wf, out_win, events, n_events,
               par, Minv, Karm, Cb, a, k, c, f, r, sgn, driver, pk, pp, ptx, pty, start,
               ckey, cuse, cA, cc, cGt, cgt, cLs, cls, cHk, cPh, cGa, wf, win, fresh):  # fmt: skip
    """Grid steps ``k0 .. k1-1`` (times ``t0 + k dt``) from state ``x`` in mode ``sig`` (both updated in place).

    ``fresh`` (n,) bool, updated in place: the pulleys that switched at the last event and have not yet been seen
    inside their new mode (a step ending on an event passes it on to the next step): with ``x``, ``sig``, ``wf``
    and ``win`` it is the whole state a run continues from, so steps ``k0 .. k1-1`` taken in several calls equal
    one call bit for bit.

    Writes sample ``k + 1 - k0`` of: ``out`` (state), ``out_sig`` (mode), ``out_T`` (span tensions [N]),
    ``out_sdot`` (slip speeds [m/s]), ``out_wf`` / ``out_win`` (cumulative friction work and input work per pulley
    [J], running totals ``wf``, ``win``). ``events`` rows ``[time, pulley, old sig, new sig]`` from row ``n_events[0]``.
    Returns ``(status, k)``: :data:`OK` with ``k = k1``, else the status and the step that stopped.
    """
    n, m = a.shape[0], a.shape[1]
    N = x.shape[0]
    dt = par[P_DT]
    T0 = par[P_T0]
    L = cPh.shape[1] - 1
    U = np.int64(1) << L  # units per step
    b = np.empty(N)
    u = np.empty(n)
    x1 = np.empty(N)
    xm = np.empty(N)
    xc = np.empty(N)
    xt = np.empty(N)
    tmp = np.empty(N)
    d0 = np.empty(N)
    d1 = np.empty(N)
    T = np.empty(n)
    Td = np.empty(n)
    g = np.empty(n)
    dg = np.empty(n)
    g0 = np.empty(n)
    dg0 = np.empty(n)
    none = np.empty(0)
    none_b = np.zeros(N)
    newsig = sig.copy()
    clock = 0
    for step in range(k0, k1):
        if n_events[0] + (MAX_SWITCHES + 1) * n > events.shape[0]:  # room for a whole step's switches
            return EVENTS_FULL, step
        ta = t0 + step * dt
        pos = np.int64(0)  # position in the step [units]
        switches = 0
        while True:
            clock += 1
            s = _slot(sig, ckey, cuse, par, Minv, Karm, Cb, a, k, c, f, cA, cc, cGt, cgt, cLs, cls, cHk, cPh, cGa, clock)
            if s < 0:
                return ALL_SLIP, step
            Phs, Gas = cPh[s], cGa[s]
            a_t = ta + dt * (pos / U)
            w = _inputs(a_t, x, m, sgn, pk, pp, ptx, pty, start, Minv, driver, r, par, cc[s], b, u)
            T0w = T0 - w
            if pos == 0:
                _flow(Phs[0], Gas[0], x, b, x1)
            else:
                _moved(Phs, Gas, x, b, U - pos, x1, tmp)
            guards(sig, x1, none, T0w, par, f, r, driver, m, cGt[s], cgt[s], cLs[s], cls[s], T, Td, g, dg)
            fire = False
            for i in range(n):
                if g[i] > 0.0:
                    fire = True
            end = U
            if fire:
                # scan the exact flow at N_SCAN points for the first position past a surface, then halve down to
                # one unit: the last position inside (every pulley's switching function <= 0), one unit before it.
                # A pulley switched at this sub-step's start counts from the first scan point on (it was found
                # inside its new mode at the start).
                for i in range(N):
                    xc[i] = x[i]
                cur = pos
                chunk = U // N_SCAN
                hi = U
                while cur < U:
                    nxt = min(cur + chunk, U)
                    _moved(Phs, Gas, xc, b, nxt - cur, xt, tmp)
                    guards(sig, xt, none, T0w, par, f, r, driver, m, cGt[s], cgt[s], cLs[s], cls[s], T, Td, g, dg)
                    out_ = False
                    for i in range(n):
                        out_ = out_ or g[i] > 0.0
                    if out_:
                        hi = nxt
                        break
                    cur = nxt
                    for i in range(N):
                        xc[i] = xt[i]
                for lev in range(L + 1):
                    bit = np.int64(1) << (L - lev)
                    if cur + bit >= hi:
                        continue
                    _flow(Phs[lev], Gas[lev], xc, b, xt)
                    guards(sig, xt, none, T0w, par, f, r, driver, m, cGt[s], cgt[s], cLs[s], cls[s], T, Td, g, dg)
                    out_ = False
                    for i in range(n):
                        out_ = out_ or (g[i] > 0.0 and not (fresh[i] and cur + bit - pos < chunk))
                    if not out_:
                        cur += bit
                        for i in range(N):
                            xc[i] = xt[i]
                end = cur + 1 if cur + 1 <= hi else hi
            # the sub-step pos -> end: friction work by Simpson's rule, the torques' work
            if end == U and pos == 0:
                xe = x1
            else:
                _moved(Phs, Gas, x, b, end - pos, xt, tmp)
                xe = xt
            sliding = False
            for i in range(n):
                sliding = sliding or sig[i] != 0
            if sliding:
                _moved(Phs, Gas, x, b, (end - pos) // 2, xm, tmp)
                h = dt * ((end - pos) / U)
                _add_friction_work(h / 6.0, sig, x, T0w, par, cGt[s], cgt[s], cLs[s], cls[s], T, wf)
                _add_friction_work(4.0 * h / 6.0, sig, xm, T0w, par, cGt[s], cgt[s], cLs[s], cls[s], T, wf)
                _add_friction_work(h / 6.0, sig, xe, T0w, par, cGt[s], cgt[s], cLs[s], cls[s], T, wf)
            for i in range(n):
                win[i] += u[i] * (xe[i] - x[i])
            for i in range(N):
                x[i] = xe[i]
            pos = end
            if not fire:
                for i in range(n):
                    fresh[i] = False
                _project(sig, x, w, par, a, k, f, cHk[s], m)
                break
            a_t = ta + dt * (pos / U)
            # which pulleys switch: the one furthest past its surface and every one on it to rounding (switching
            # functions with w held, as along the flow that found the event; the new mode then holds w from here)
            v = r[driver] * x[m + driver]
            guards(sig, x, none, T0w, par, f, r, driver, m, cGt[s], cgt[s], cLs[s], cls[s], T, Td, g, dg)
            first = 0
            for i in range(n):
                if g[i] > g[first]:
                    first = i
            for i in range(n):
                newsig[i] = sig[i]
                p = (i - 1) % n
                if sig[i] == 0:
                    scale = abs(T[i] - T[p]) + f[i] * abs(T[i] + T[p])
                else:
                    scale = abs(v) + 1.0
                if i == first or g[i] > -1e-12 * scale:
                    if sig[i] == 0:
                        newsig[i] = 1 if T[i] - T[p] >= 0.0 else -1
                    else:
                        newsig[i] = 0
            # a re-stick holds if the stick mode's friction stays inside the limit (else it slides on)
            stuck = 0
            resticks = False
            for i in range(n):
                if sig[i] != 0 and newsig[i] == 0:
                    resticks = True
            if resticks:
                clock += 1
                s2 = _slot(newsig, ckey, cuse, par, Minv, Karm, Cb, a, k, c, f, cA, cc, cGt, cgt, cLs, cls, cHk, cPh, cGa, clock)
                if s2 < 0:
                    return ALL_SLIP, step
                _inputs(a_t, x, m, sgn, pk, pp, ptx, pty, start, Minv, driver, r, par, cc[s2], b, u)
                _rate(cA[s2], x, b, d0)
                _rate(cA[s2], d0, none_b, d1)  # x'' = A x' (inputs held)
                guards(newsig, x, d1, T0w, par, f, r, driver, m, cGt[s2], cgt[s2], cLs[s2], cls[s2], T, Td, g0, dg0)
                guards(newsig, x, d0, T0w, par, f, r, driver, m, cGt[s2], cgt[s2], cLs[s2], cls[s2], T, Td, g, dg)
                vd = r[driver] * d0[m + driver]
                for i in range(n):
                    if sig[i] != 0 and newsig[i] == 0:
                        p = (i - 1) % n
                        lim = f[i] * (T[i] + T[p] - 2.0 * w)
                        scale = (1.0 + f[i]) * (abs(Td[i]) + abs(Td[p])) + 4.0 * f[i] * par[P_MASS] * abs(v * vd)
                        if g[i] < -1e-9 * lim:
                            continue
                        if abs(dg[i]) > 1e-8 * scale:  # the friction needed to stick leaves the limit at once, or not
                            keep = dg[i] < 0.0
                        else:  # tangent (undamped spans: the rate is the slip mode's at s' = 0): the curvature decides
                            keep = dg0[i] + 4.0 * f[i] * par[P_MASS] * vd * vd <= 0.0
                        if not keep:  # the friction to stick would leave the limit at once: it slides on
                            newsig[i] = sig[i]
                            stuck = i
            changed = False
            for i in range(n):
                fresh[i] = newsig[i] != sig[i]
                if newsig[i] != sig[i]:
                    changed = True
                    e = n_events[0]
                    if e >= events.shape[0]:
                        return EVENTS_FULL, step
                    events[e, 0] = a_t
                    events[e, 1] = i
                    events[e, 2] = sig[i]
                    events[e, 3] = newsig[i]
                    n_events[0] = e + 1
                    sig[i] = newsig[i]
            if not changed and par[P_DAMPED] > 0.0:
                # a refused re-stick: the slip speed crossed zero, so the belt may slide on the other way (damped spans:
                # s' jumps, the state does not) if in that mode its slip speed has that direction
                newsig[stuck] = -sig[stuck]
                clock += 1
                s2 = _slot(newsig, ckey, cuse, par, Minv, Karm, Cb, a, k, c, f, cA, cc, cGt, cgt, cLs, cls, cHk, cPh, cGa, clock)
                if s2 < 0:
                    return ALL_SLIP, step
                if newsig[stuck] * _slip_speed(cLs[s2], cls[s2], x, T0w, stuck) > 0.0:
                    changed = True
                    e = n_events[0]
                    events[e, 0], events[e, 1], events[e, 2], events[e, 3] = a_t, stuck, sig[stuck], newsig[stuck]
                    n_events[0] = e + 1
                    sig[stuck] = newsig[stuck]
                    fresh[stuck] = True
                else:
                    newsig[stuck] = sig[stuck]
            if not changed:  # it can neither stick nor slide on either way (row written, not counted)
                e = n_events[0]
                events[e, 0], events[e, 1], events[e, 2], events[e, 3] = a_t, stuck, sig[stuck], sig[stuck]
                return STUCK, step
            if changed:
                clock += 1
                s = _slot(sig, ckey, cuse, par, Minv, Karm, Cb, a, k, c, f, cA, cc, cGt, cgt, cLs, cls, cHk, cPh, cGa, clock)
                if s < 0:
                    return ALL_SLIP, step
                _project(sig, x, w, par, a, k, f, cHk[s], m)
            switches += 1
            if switches > MAX_SWITCHES:
                return CHATTER, step
            if pos >= U:
                break
        # the sample at the end of the step
        total = 0.0
        for i in range(N):
            total += x[i]
        fast = False
        for i in range(m):
            if abs(x[m + i]) > par[P_LIMIT]:
                fast = True
        j = step + 1 - k0
        for i in range(N):
            out[j, i] = x[i]
        v = r[driver] * x[m + driver]
        T0w = T0 - par[P_MASS] * v * v
        _tensions(cGt[s], cgt[s], x, T0w, T0, T)
        for i in range(n):
            out_sig[j, i] = sig[i]
            out_T[j, i] = T[i]
            out_sdot[j, i] = _slip_speed(cLs[s], cls[s], x, T0w, i) if sig[i] != 0 else 0.0
            out_wf[j, i] = wf[i]
            out_win[j, i] = win[i]
        if not math.isfinite(total) or fast:
            return DIVERGED, step + 1
    return OK, k1
