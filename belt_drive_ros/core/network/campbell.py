"""Campbell data of a belt network: natural frequencies against engine speed, firing orders, crossings.

At each driver speed the linear tier is linearised afresh (``NetworkModel.operating_point``: static tensions set
the arm's geometric stiffness, the profiles' speed slopes add damping). An engine order ``k`` excites at
``k * speed / (2 pi)`` [Hz]; where a mode's curve crosses an order line, that order drives it at resonance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .model import NetworkModel, modes


@dataclass(frozen=True)
class Crossing:
    """A mode (1-based, lowest first) meeting an engine order at crank speed [rad/s] and frequency [Hz]."""

    mode: int
    order: float
    speed: float
    frequency: float


@dataclass(frozen=True)
class Campbell:
    """speeds (S,) [rad/s] of the engine's pulley (the crank); frequencies (S, n_modes) [Hz]: the damped frequency of
    the j-th lowest oscillating mode at each speed (NaN where fewer modes oscillate); orders; crossings."""

    speeds: np.ndarray
    frequencies: np.ndarray
    orders: tuple
    crossings: tuple


def campbell(model: NetworkModel, points: int = 60) -> Campbell:
    """Frequencies over the scene's ``engine.speed_range`` (of the engine's pulley; each linearised at the
    driver's speed with the belt unstretched) and their crossings with the firing orders ``k * firing_order``
    (per crank revolution), k = 1, 2, 3."""
    scene = model.scene
    engine = scene.engine
    speeds = np.linspace(engine.speed_range[0], engine.speed_range[1], points)
    to_driver = scene.pulleys[scene.index(engine.pulley)].radius / scene.pulleys[scene.driver].radius
    per = [[md.frequency for md in modes(model, w * to_driver)] for w in speeds]
    count = max(len(p) for p in per)
    F = np.full((points, count), np.nan)
    for i, p in enumerate(per):
        F[i, : len(p)] = p
    orders = tuple(k * engine.firing_order for k in (1, 2, 3))
    found = []
    for order in orders:
        line = order * speeds / (2.0 * math.pi)
        for j in range(count):
            diff = F[:, j] - line
            for i in range(points - 1):
                a, b = diff[i], diff[i + 1]
                if np.isfinite(a) and np.isfinite(b) and a * b <= 0.0 and a != b:
                    s = a / (a - b)
                    w = speeds[i] + s * (speeds[i + 1] - speeds[i])
                    found.append(Crossing(j + 1, order, float(w), float(order * w / (2.0 * math.pi))))
    return Campbell(speeds, F, orders, tuple(sorted(found, key=lambda c: c.speed)))
