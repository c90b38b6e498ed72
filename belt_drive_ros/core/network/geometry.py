"""Geometry of a belt network: tangent spans, wrap angles, belt length (SI units; ``docs/serpentine.md``, "Geometry").

Pulleys ``P_0 .. P_{n-1}`` in the order the belt travels, counter-clockwise; signed radius ``rho = side r`` (+1 inner
face, -1 backside). Span ``j`` from ``P_j`` to ``P_{j+1}``, ``d = c_{j+1} - c_j``, ``dr = rho_{j+1} - rho_j``::

    L = sqrt(|d|^2 - dr^2),   angle(e) = angle(d) - asin(dr / |d|),   tangent points c - rho n(e), n(e) = (-e_y, e_x)

A simple loop turns once: ``sum_i side_i beta_i = 2 pi``; belt length ``sum_j L_j + sum_i r_i beta_i``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import SceneError

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class Layout:
    """Computed geometry of a loop of n circles (span j leaves pulley j): unit span ``directions`` ``e_j`` (n, 2),
    span ``lengths`` ``L_j`` [m], tangent points of span j on ``P_j`` (``leave``) and ``P_{j+1}`` (``arrive``) [m],
    ``wraps`` ``beta_i`` [rad] (between span i-1 arriving and span i leaving), ``belt_length`` [m]."""

    directions: np.ndarray
    lengths: np.ndarray
    leave: np.ndarray
    arrive: np.ndarray
    wraps: np.ndarray
    belt_length: float


def _left(e: np.ndarray) -> np.ndarray:
    return np.array([-e[1], e[0]])


def tangent(c0, rho0, c1, rho1) -> tuple[np.ndarray, float] | None:
    """Direction ``e`` and length ``L`` of the span from circle (c0, rho0) to (c1, rho1); None if it does not exist."""
    d = np.asarray(c1, dtype=float) - np.asarray(c0, dtype=float)
    D = math.hypot(d[0], d[1])
    dr = rho1 - rho0
    if D <= abs(dr):
        return None
    L = math.sqrt(D * D - dr * dr)
    psi = math.atan2(d[1], d[0]) - math.asin(dr / D)
    return np.array([math.cos(psi), math.sin(psi)]), L


def layout(names, centres, radii, sides) -> Layout:
    """Geometry of the loop, or :class:`SceneError` naming the pulley (overlap, crossing, wrap <= 0, not a simple loop)."""
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    r = np.asarray(radii, dtype=float)
    s = np.asarray(sides, dtype=float)
    n = len(names)
    if n < 2:
        raise SceneError(f"pulleys: a belt network needs at least 2 pulleys, got {n}")
    rho = s * r
    for i in range(n):  # overlapping circles: no belt runs between them
        for k in range(i + 1, n):
            gap = math.hypot(*(c[k] - c[i])) - r[i] - r[k]
            if gap <= 0.0:
                raise SceneError(f"pulleys.{names[k]}: overlaps pulley {names[i]} "
                                 f"(centres {math.hypot(*(c[k] - c[i])):.4g} m apart, radii {r[i]:.4g} + {r[k]:.4g} m)")
    e = np.zeros((n, 2))
    L = np.zeros(n)
    for j in range(n):
        k = (j + 1) % n
        found = tangent(c[j], rho[j], c[k], rho[k])
        if found is None:  # (cannot happen without an overlap; kept as the formula's own guard)
            raise SceneError(f"pulleys.{names[k]}: no tangent span from {names[j]} (circles too close)")
        e[j], L[j] = found
    leave = np.array([c[j] - rho[j] * _left(e[j]) for j in range(n)])
    arrive = np.array([c[(j + 1) % n] - rho[(j + 1) % n] * _left(e[j]) for j in range(n)])
    ang = np.arctan2(e[:, 1], e[:, 0])
    wraps = np.array([(s[i] * (ang[i] - ang[i - 1])) % TWO_PI for i in range(n)])
    for i in range(n):
        if wraps[i] <= 1e-9:
            raise SceneError(f"pulleys.{names[i]}: wrap angle {wraps[i]:.3g} rad <= 0 (the belt runs straight past it)")
    total = float(np.sum(s * wraps))
    if abs(total - TWO_PI) > 1e-6:
        # the belt would have to turn the other way round one pulley: the one wrapped more than half a turn
        # against the sense of the others is on the wrong side of the belt (its side or position is wrong)
        wrong = [i for i in range(n) if wraps[i] > math.pi and abs(total - s[i] * TWO_PI - TWO_PI) < 1e-6]
        if wrong:
            i = max(wrong, key=lambda q: wraps[q])
            raise SceneError(f"pulleys.{names[i]}: wrap angle <= 0: the belt passes on its other side "
                             f"(side {'inner' if s[i] > 0 else 'backside'} or its position is wrong)")
        raise SceneError(f"pulleys: not a simple loop (the belt turns {total / TWO_PI:.3g} times, 1 expected; "
                         "list the pulleys in the order the belt travels, counter-clockwise)")
    for j in range(n):  # a span must not cut another pulley nor cross another span
        k = (j + 1) % n
        a, b = leave[j], arrive[j]
        for q in range(n):
            if q in (j, k):
                continue
            t = np.clip(np.dot(c[q] - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
            if math.hypot(*(a + t * (b - a) - c[q])) < r[q] * (1.0 - 1e-9):
                raise SceneError(f"pulleys.{names[q]}: the span {names[j]} -> {names[k]} crosses it")
        for m in range(j + 2, n):
            if (m + 1) % n == j:
                continue
            if _segments_cross(a, b, leave[m], arrive[m]):
                raise SceneError(f"pulleys.{names[k]}: not a simple loop: the span {names[j]} -> {names[k]} crosses "
                                 f"the span {names[m]} -> {names[(m + 1) % n]}")
    _adjacent_spans_clear(names, leave, arrive)
    length = float(np.sum(L) + np.sum(r * wraps))
    return Layout(e, L, leave, arrive, wraps, length)


def _adjacent_spans_clear(names, leave, arrive) -> None:
    """Refuse a belt whose two spans at a pulley cross (an alpha loop round it): the turn count adds the wraps, so a
    pulley passed on the wrong side (-2 pi) and another wrong the other way (+2 pi) summed to one turn, and a belt
    looped round both (wraps of 309 and 264 deg) ran. (Arcs need no check of their own: a span that crosses another
    pulley's arc cuts its circle, and circles do not overlap, both refused above.)"""
    n = len(names)
    for i in range(n):
        j = (i - 1) % n
        if j != i and _segments_cross(leave[j], arrive[j], leave[i], arrive[i]):
            raise SceneError(f"pulleys.{names[i]}: the spans {names[j]} -> {names[i]} and {names[i]} -> "
                             f"{names[(i + 1) % n]} cross: not a simple loop (a pulley on the wrong side of the "
                             "belt, or listed out of order)")


def _segments_cross(a, b, p, q) -> bool:
    """Whether the open segments a-b and p-q cross (properly)."""
    def orient(u, v, w):
        return (v[0] - u[0]) * (w[1] - u[1]) - (v[1] - u[1]) * (w[0] - u[0])
    o1, o2, o3, o4 = orient(a, b, p), orient(a, b, q), orient(p, q, a), orient(p, q, b)
    return o1 * o2 < 0.0 and o3 * o4 < 0.0
