"""The accuracy guard's harmonic term: the error a periodic forcing builds up over the whole run.

The guard's other terms see a unit torque step over the run and the scene's
torques over short windows, not what a periodic torque does over hundreds
of periods on a lightly damped belt: near the belt mode the response grows
over ``~1 / (zeta omega_n)`` seconds, and so does the method's error. Two
mechanisms add up there: the method's quadrature of the forcing over a step
(etd2 takes it as linear in time, an error ``~(h omega)^2 / 12`` per step),
and, on a closed loop whose torques depend on speed, a shift ``delta`` of the
discrete belt mode, which moves the response near a resonance of quality
``Q = 1 / (2 zeta)`` by ``~delta Q / omega_n`` of itself.

Both are in the forced response of the linearized closed loop
``x' = A_cl x + B u``, ``A_cl = A + B K`` (:mod:`~belt_drive_ros.core.accuracy`),
to ``u = e^{j omega t}`` on one input, from rest, over the run. The method
maps ``x_{k+1} = M x_k + G(omega) e^{j omega t_k}`` with
``G(omega) = sum_i G_i e^{j omega c_i h}`` (``G_i`` the gain of stage ``i``,
node ``c_i``, read off the method's own stage scheme); the exact map is
``x_{k+1} = E x_k + F(omega) e^{j omega t_k}``, ``E = e^{h A_cl}``,
``F(omega) = int_0^h e^{(h - s) A_cl} B e^{j omega s} ds`` (:func:`exact_forcing_maps`).
The error of an output row is ``max_k |y_k - y*_k|`` (complex modulus: the
envelope of a cosine or sine forcing), its scale ``max_k |y*_k|``.

The harmonics: every excitation frequency the scene's torque profiles name
at the probed operating speeds (engine firing orders, compressor strokes, a
sine, a ramp or table's rate), each with an amplitude ``a`` [N m]: half the
profile's range over one period at that operating point. The error of output
``i`` relative to the run's peak ``P_i`` is

    e_i = err_i(omega) a / max(P_i, peak_i(omega) a)

(a resonance that builds up past the rigid estimate of the peak raises the
peak with it). The worst harmonic, output and probe counts.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from . import stage_scheme as _scheme
from .errors import IntegratorError
from .identity_cache import built_once

#: most distinct harmonics checked per input (lowest first after the largest amplitude ones)
MAX_HARMONICS = 8
#: harmonics closer than this (relative) in frequency count as one
FREQUENCY_MERGE = 0.02
#: samples of a profile over one period to read its amplitude
AMPLITUDE_SAMPLES = 32
#: a profile repeats over the next period within this fraction of its range: periodic (else not a harmonic)
PERIODIC_TOLERANCE = 0.05
#: samples of a response compared over the run (one by one up to half; beyond, in strides)
ORBIT_SAMPLES = 1200


def stage_gains(integrator, K: np.ndarray) -> tuple[np.ndarray, list]:
    """(M, [(c_i, G_i)]): the method's closed-loop step with the input applied at stage i only.

    On ``x' = A x + B (K x + v)``: ``x+ = M x + sum_i G_i v_i`` with ``v_i``
    the value of ``v`` the method samples at stage ``i`` (node ``c_i``).
    Read off :func:`~belt_drive_ros.core.stage_scheme.step` (the calls to the
    torque function come in stage order; the implicit stage's iterations all
    count as the last stage).
    """
    scheme, h = integrator.scheme, integrator.dt
    n, m = integrator.A.shape[0], K.shape[0]
    s = len(scheme.nodes)

    def run(x, V):  # V[i]: the value of v at stage i (columns as x's)
        calls = [0]

        def inputs(t, y):
            i = min(calls[0], s - 1)
            calls[0] += 1
            return K @ y + V[i]

        return _scheme.step(scheme, h, 0.0, x, inputs, integrator.name)

    if not scheme.implicit:  # one step of n + s m columns: M's, then each stage's gain (the sums run per column)
        X = np.zeros((n, n + s * m))
        X[:, :n] = np.eye(n)
        V = np.zeros((s, m, n + s * m))
        for i in range(s):
            V[i, :, n + i * m : n + (i + 1) * m] = np.eye(m)
        out = run(X, V)
        return out[:, :n], [(float(scheme.nodes[i]), out[:, n + i * m : n + (i + 1) * m]) for i in range(s)]
    M = np.column_stack([run(e, np.zeros((s, m))) for e in np.eye(n)])  # implicit: column by column (own iterations)
    at = np.arange(s)[:, None]
    return M, [(float(scheme.nodes[i]), np.column_stack([run(np.zeros(n), np.where(at == i, e, 0.0)) for e in np.eye(m)]))
               for i in range(s)]  # fmt: skip


def orbits(P: np.ndarray, X0: np.ndarray, count: int) -> np.ndarray:
    """``[P X0, P^2 X0, ..., P^count X0]`` for a stack of maps P (b, m, m): (b, m, count * c), by doubling.

    ``log2(count)`` batched products instead of ``count`` (the orbit of
    length 2 l is the one of length l followed by ``P^l`` times it, the last
    block only as long as needed), written into one array; sample k's columns
    are ``k c .. (k + 1) c - 1``. Real or complex.
    """
    c = X0.shape[-1]
    total = count * c
    S = np.empty(P.shape[:2] + (max(total, c),), dtype=np.result_type(P, X0))
    S[:, :, :c] = np.matmul(P, X0)
    Pl, filled = P, c
    while filled < total:
        k = min(filled, total - filled)
        S[:, :, filled : filled + k] = np.matmul(Pl, S[:, :, :k])
        filled += k
        if filled < total:
            Pl = np.matmul(Pl, Pl)
    return S[:, :, :total]


def sampled_orbits(P: np.ndarray, X0: np.ndarray, n_steps: int) -> tuple:
    """(:func:`orbits` at the sampled steps, head, stride, tail): k = 1 .. head (:data:`ORBIT_SAMPLES` / 2) one by
    one, then ``head + stride j`` for j = 1 .. tail with ``P^stride`` (exact; the samples between are skipped)."""
    head = min(n_steps, ORBIT_SAMPLES // 2)
    stride = max(1, math.ceil((n_steps - head) / (ORBIT_SAMPLES // 2)))
    tail = (n_steps - head) // stride if n_steps > head else 0
    orbit = orbits(P, X0, head)
    if tail > 0:
        orbit = np.concatenate([orbit, orbits(np.linalg.matrix_power(P, stride), orbit[:, :, -X0.shape[-1]:], tail)], axis=2)
    return orbit, head, stride, tail


def orbit_error(Ma: np.ndarray, Ea: np.ndarray, n: int, rows: np.ndarray, n_steps: int):
    """(err, peak), each (..., rows, inputs): the method's augmented map ``Ma`` against the exact ``Ea`` from rest.

    Both are ``[[M, G], [0, Z]]`` on ``[x; v]`` (``n`` states, ``m`` inputs
    ``v`` that start at 1, one per column), stepped ``n_steps`` times:
    ``err = max_k |C (x_k - x*_k)|``, ``peak = max_k |C x*_k|`` for each row
    ``C`` of ``rows``, at :func:`sampled_orbits`' steps. Leading axes of ``Ma``
    and ``Ea`` (several pairs, e.g. one per forcing frequency) are evaluated
    at once, each pair with the same operations as alone. Non-finite anywhere: err inf.
    """
    N = Ma.shape[-1]
    lead = Ma.shape[:-2]
    m = N - n
    P = np.stack([Ma, Ea]).reshape(-1, N, N)  # (2 b, N, N): the method's maps, then the exact ones
    X0 = np.broadcast_to(np.vstack([np.zeros((n, m)), np.eye(m)]).astype(Ma.dtype), (P.shape[0], N, m))
    with np.errstate(all="ignore"):
        orbit = sampled_orbits(P, X0, n_steps)[0]
        if not np.all(np.isfinite(orbit)):
            inf = np.full(lead + (rows.shape[0], m), np.inf)
            return inf, inf
        # (method/exact, ..., row, samples, inputs)
        y = np.matmul(rows, orbit[:, :n]).reshape((2,) + lead + (rows.shape[0], -1, m))
        # samples made the last, contiguous axis: numpy reduces a short last axis ~25x slower than a long one
        y = np.ascontiguousarray(np.swapaxes(y, -1, -2))
        return np.max(np.abs(y[0] - y[1]), axis=-1), np.max(np.abs(y[1]), axis=-1)


def harmonic_response_errors(integrator, A, B, rows, K, n_steps: int, omegas, channels) -> tuple[np.ndarray, np.ndarray]:
    """(err, peak), each (frequencies, rows): max_k |y_k - y*_k| and max_k |y*_k| for a unit
    ``e^{j omega t}`` on input ``channels[f]``, for every ``omega`` [rad/s] of ``omegas`` at once.

    From rest, ``x_{k+1} = M x_k + G z^k`` (``z = e^{j omega h}``) sums to
    ``x_k = sum_{i<k} M^{k-1-i} G z^i = (z I - M)^{-1} (z^k I - M^k) G``
    (multiply by ``z I - M``: the sum telescopes), so the output is
    ``y_k = z^k C P - (C M^k) P`` with ``P = (z I - M)^{-1} G``; the same for
    the exact map (E, F). The real orbits ``C M^k`` and ``C E^k`` at the
    sampled k (:func:`sampled_orbits`) are made once for every frequency.
    Where ``z I - M`` or ``z I - E`` is nearly singular (a forcing on an
    undamped mode; condition beyond :data:`FORCING_CONDITION_LIMIT`: the
    solve's rounding, ``cond eps``, relative to ``P``, stays below 1e-6 of it)
    the frequencies' augmented maps are stepped instead (:func:`orbit_error`).
    Non-finite: err inf (every frequency).
    """
    h = integrator.dt
    n, m = B.shape
    omegas = np.asarray(omegas, dtype=float)
    pick, channels = np.arange(omegas.size), np.asarray(channels, dtype=int)
    f = omegas.size
    M, gains = stage_gains(integrator, K)
    G = sum(Gi * np.exp(1j * omegas * c * h)[:, None, None] for c, Gi in gains)
    A_cl = A + B @ K
    E = scipy.linalg.expm(h * A_cl)
    z = np.exp(1j * omegas * h)
    I = np.eye(n)
    # j omega I - A_cl (the exact forcing map's solve) and the two resolvents z I - M, z I - E: one batched condition
    S = np.concatenate([1j * omegas[:, None, None] * I - A_cl, z[:, None, None] * I - M, z[:, None, None] * I - E])
    with np.errstate(all="ignore"):  # (a method's map that blew up: its resolvents are not solved)
        cond = np.linalg.cond(S) if np.all(np.isfinite(M)) else np.r_[np.linalg.cond(S[:f]), np.full(2 * f, np.inf)]
    F = exact_forcing_maps(A_cl, B, E, h, omegas, cond[:f] < FORCING_CONDITION_LIMIT)
    resolvents = [S[f : 2 * f], S[2 * f :]]
    if not np.all(cond[f:] < FORCING_CONDITION_LIMIT):  # step the augmented maps ([[M, G], [0, z I]] on [x; v])
        zm = z[:, None, None] * np.eye(m)
        Ma = np.zeros((f, n + m, n + m), dtype=complex)
        Ea = np.zeros_like(Ma)
        Ma[:, :n, :n], Ma[:, :n, n:], Ma[:, n:, n:] = M, G, zm
        Ea[:, :n, :n], Ea[:, :n, n:], Ea[:, n:, n:] = E, F, zm
        err, peak = orbit_error(Ma, Ea, n, rows, n_steps)
        return err[pick, :, channels], peak[pick, :, channels]
    r = rows.shape[0]
    with np.errstate(all="ignore"):
        P = np.stack([M.T, E.T])  # C M^k = ((M^T)^k C^T)^T
        CX, head, stride, tail = sampled_orbits(P, np.broadcast_to(rows.T.astype(float), (2, n, r)), n_steps)
        if not np.all(np.isfinite(CX)):
            inf = np.full((f, r), np.inf)
            return inf, inf
        # (method/exact, state, rows x samples): each row's samples contiguous (reduced over as orbit_error's)
        CX = CX.reshape(2, n, -1, r).transpose(0, 1, 3, 2).reshape(2, n, -1)
        # z^k at the sampled k (1 .. head, then head + stride j): running products (rounding ~k ulp)
        zk = np.cumprod(np.hstack([np.broadcast_to(z[:, None], (f, head)), np.broadcast_to(z[:, None] ** stride, (f, tail))]), axis=1)
        zr, zi = zk.real[:, None, :], zk.imag[:, None, :]
        y = []  # (real, imaginary) parts of y_k = z^k C P - (C M^k) P, each (frequencies, rows, samples)
        for R, Gm, CMk in ((resolvents[0], G, CX[0]), (resolvents[1], F, CX[1])):
            Pm = np.linalg.solve(R, Gm[pick, :, channels][:, :, None])[:, :, 0]  # (frequencies, n): the channel's column
            a = (Pm @ rows.T)[:, :, None]
            y.append((zr * a.real - zi * a.imag - (Pm.real @ CMk).reshape(f, r, -1),
                      zr * a.imag + zi * a.real - (Pm.imag @ CMk).reshape(f, r, -1)))  # fmt: skip
        (mr, mi), (er, ei) = y
        err = np.sqrt(np.max(np.square(mr - er) + np.square(mi - ei), axis=2))
        peak = np.sqrt(np.max(np.square(er) + np.square(ei), axis=2))
        if not (np.all(np.isfinite(err)) and np.all(np.isfinite(peak))):  # a non-finite sample reaches its maximum
            inf = np.full((f, r), np.inf)
            return inf, inf
        return err, peak


#: above this condition number of ``j omega I - A_cl`` (a forcing at an undamped mode) F comes from expm instead
FORCING_CONDITION_LIMIT = 1e10


def exact_forcing_maps(A_cl: np.ndarray, B: np.ndarray, E: np.ndarray, h: float, omegas, solvable=None) -> np.ndarray:
    """``F(omega) = int_0^h e^{(h - s) A_cl} B e^{j omega s} ds`` (frequencies, n, m) for every ``omega`` [rad/s] of
    ``omegas``, given ``E = e^{h A_cl}``.

    Since ``d/ds [e^{(h - s) A} e^{j omega s}] = e^{(h - s) A} (j omega I - A) e^{j omega s}``,
    ``F = (j omega I - A)^{-1} (e^{j omega h} I - E) B``: one linear solve
    per frequency (batched) instead of a matrix exponential of the system augmented
    with the oscillator. Where ``j omega I - A`` is (nearly) singular (the
    forcing on an undamped mode; ``solvable``: per frequency, conditioned below
    :data:`FORCING_CONDITION_LIMIT`, if known) the augmented exponential is used.
    """
    omegas = np.atleast_1d(np.asarray(omegas, dtype=float))
    n, m = B.shape
    I = np.eye(n)
    S = 1j * omegas[:, None, None] * I - A_cl
    rhs = (np.exp(1j * omegas * h)[:, None, None] * I - E) @ B
    F = np.empty((omegas.size, n, m), dtype=complex)
    solvable = np.linalg.cond(S) < FORCING_CONDITION_LIMIT if solvable is None else solvable
    if np.any(solvable):
        F[solvable] = np.linalg.solve(S[solvable], rhs[solvable])
    for k in np.flatnonzero(~solvable):
        aug = np.zeros((n + m, n + m), dtype=complex)
        aug[:n, :n], aug[:n, n:] = A_cl, B
        aug[n:, n:] = 1j * omegas[k] * np.eye(m)
        F[k] = scipy.linalg.expm(aug * h)[:n, n:]
    return F


def profile_harmonics(plant, probes) -> list[tuple[int, float, float]]:
    """``[(input 0 drive / 1 load, frequency [Hz], amplitude [N m])]`` the scene's torques excite at its operating points.

    ``probes``: ``(t [s], phi_M [rad], omega_M [rad/s])`` along the rigid
    estimate. Frequencies from each profile's ``excitation_frequencies`` at
    the wheel's speed (finite and > 0: steps are the step response's);
    amplitude half the profile's range over one period from that state, the
    wheel turning at its speed. Only what repeats over the next period
    counts (within :data:`PERIODIC_TOLERANCE` of the range): a ramp's or
    soft start's "frequency" is a single event, rated by the step response
    and the forcing windows. Close frequencies merge (largest amplitude
    kept); at most :data:`MAX_HARMONICS` per input, largest amplitude first.
    """
    i = plant.model.params.ratio
    sampled = []  # (input, candidates, their samples) of each input that names a frequency
    for channel, (profile, gear) in enumerate(((plant.drive, 1.0), (plant.load, i))):
        points = []  # (frequency, t, angle, speed) of every candidate: sampled all at once below
        for t, phi, omega in probes:
            speed = gear * omega
            try:
                freqs = profile.excitation_frequencies(abs(speed))
            except Exception:  # noqa: BLE001 - a profile that cannot say: none
                freqs = []
            points += [(float(f), t, gear * phi, speed) for f, _ in freqs if math.isfinite(float(f)) and float(f) > 0.0]
        if not points:
            continue
        f, t, angle, speed = (np.array(c, dtype=float)[:, None] for c in zip(*points))
        # two periods [s]: the floats of linspace(0, 2 / f, 2 AMPLITUDE_SAMPLES, endpoint=False, axis=1)
        offsets = np.arange(2 * AMPLITUDE_SAMPLES, dtype=float) * (2.0 / f / (2 * AMPLITUDE_SAMPLES))
        with np.errstate(all="ignore"):  # (every candidate's samples in one flat call, then a row each)
            values = np.asarray(profile.torque((t + offsets).ravel(), (angle + speed * offsets).ravel(),
                                               np.repeat(speed[:, 0], offsets.shape[1])), dtype=float).reshape(offsets.shape)
        sampled.append((channel, points, values))
    if not sampled:
        return []
    # every candidate's amplitude and repetition, both inputs' at once (the same operations per row)
    values = sampled[0][2] if len(sampled) == 1 else np.concatenate([v for _, _, v in sampled])
    with np.errstate(all="ignore"):
        first, second = values[:, :AMPLITUDE_SAMPLES], values[:, AMPLITUDE_SAMPLES:]
        amps = 0.5 * (np.max(first, axis=1) - np.min(first, axis=1))
        repeat = np.max(np.abs(second - first), axis=1)
    # not periodic here (a ramp, a soft start, a table): the step response and windows see it
    periodic = (np.all(np.isfinite(values), axis=1) & (amps > 0.0) & ~(repeat > PERIODIC_TOLERANCE * 2.0 * amps)).tolist()
    amps = amps.tolist()
    out, row = [], 0
    for channel, points, _ in sampled:
        found: list[tuple[float, float]] = []
        for k, point in enumerate(points):
            if not periodic[row + k]:
                continue
            a, fk = amps[row + k], point[0]
            for j, (f_old, a_old) in enumerate(found):
                if abs(fk - f_old) <= FREQUENCY_MERGE * max(fk, f_old):
                    found[j] = (f_old, max(a, a_old))
                    break
            else:
                found.append((fk, a))
        row += len(points)
        found.sort(key=lambda fa: -fa[1])
        out += [(channel, f_, a_) for f_, a_ in found[:MAX_HARMONICS]]
    return out


#: per integrator: its unit harmonic responses (err, peak) by closed loop, outputs, run length and frequencies
_RESPONSES: dict = {}


def harmonic_error(integrator, A, B, rows, K, n_steps: int, harmonics, peaks) -> float:
    """The harmonic term [-]: max over ``harmonics`` ``(input, f [Hz], a [N m])`` and output rows of
    ``err a / max(P, peak a)`` (module docstring); ``peaks`` (rows,): the run's estimated peak per output. The unit
    responses (:func:`harmonic_response_errors`), of the matrices and frequencies alone, are made once and kept."""
    if not harmonics:
        return 0.0
    peaks = np.asarray(peaks, dtype=float)
    channels = np.array([int(c) for c, _, _ in harmonics])
    amplitude = np.array([float(a) for _, _, a in harmonics])
    omegas = np.array([2.0 * math.pi * float(f) for _, f, _ in harmonics])
    key = tuple((np.shape(a), np.asarray(a).tobytes()) for a in (A, B, rows, K, omegas, channels)) + (int(n_steps),)
    try:
        responses = built_once(_RESPONSES, 64, (integrator,), lambda: harmonic_response_errors(
            integrator, A, B, rows, K, n_steps, omegas, channels), key)  # all at once
    except IntegratorError:  # the method's stage gains cannot be read
        return math.inf
    err, peak = responses[0] * amplitude[:, None], responses[1] * amplitude[:, None]  # (harmonics, rows)
    if not np.all(np.isfinite(err)):
        return math.inf
    scale = np.maximum(peaks[: err.shape[1]], peak)
    rel = np.where(scale > 0, err / np.where(scale > 0, scale, 1.0), 0.0)
    return float(np.max(rel))

