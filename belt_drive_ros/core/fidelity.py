"""Model no more than a scene needs: the ``auto`` choice between rigid and flexible.

The flexible model differs from the rigid one by the belt mode at
``f_n = omega_n / (2 pi)``. A harmonic excitation at ``f`` drives the belt
deflection with the dynamic amplification ``1 / |1 - (f/f_n)^2|`` over its
quasi-static value, which the rigid model reports; at ``f/f_n = 0.1`` the
rigid model's belt torque is off by ~1 %, at 0.2 by ~4 %, at 0.5 by 33 %.
Step changes (a torque switched on or off) excite the belt's free vibration
at every frequency. Hence:

* **flexible** when any excitation frequency reaches
  ``FREQUENCY_RATIO_THRESHOLD * f_n`` or a torque changes stepwise;
* **rigid** otherwise; the quasi-static relative deflection
  ``T_b / (2 k r_3^2)`` is still reported.

Excitation frequencies depend on speed (engine firing, compressor strokes),
so the operating speeds are first estimated with a cheap rigid run.
``docs/performance.md`` (fidelity chart) shows the rigid model's measured
error against these ratios and where the threshold sits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .model import RigidBeltModel
from .stepper import Plant, Stepper

#: rigid is chosen while max(f_excitation) / f_n stays below this [-].
FREQUENCY_RATIO_THRESHOLD = 0.1


@dataclass(frozen=True)
class ModelChoice:
    """Outcome of :func:`choose_model`.

    Attributes
    ----------
    model : "rigid" or "flexible".
    reason : one sentence a person can check.
    belt_frequency : f_n [Hz].
    excitations : ((frequency [Hz], label), ...) at the estimated operating speeds.
    max_ratio : max excitation frequency / f_n [-] (inf for a step change).
    output_rate : rate [Hz] outputs are consumed at.
    """

    model: str
    reason: str
    belt_frequency: float
    excitations: tuple
    max_ratio: float
    output_rate: float


def _operating_speeds(scene) -> tuple[float, float]:
    """Largest |omega_M| and |omega_3| [rad/s] of a cheap rigid run of ``scene``."""
    model = RigidBeltModel(scene.params)
    dt = min(scene.duration / 500.0, 5e-3)
    stepper = Stepper(Plant(model, scene.drive, scene.load), "exact", dt)
    _, states = stepper.run(scene.initial_state.vector("rigid", scene.params.ratio), 0.0, scene.duration)
    w = float(np.max(np.abs(states[:, 1])))
    return w, w * scene.params.ratio


def choose_model(scene, threshold: float = FREQUENCY_RATIO_THRESHOLD) -> ModelChoice:
    """Rigid or flexible for ``scene``, with the reason (see the module docstring)."""
    f_n = scene.params.belt_natural_frequency / (2.0 * math.pi)
    w_M, w_3 = _operating_speeds(scene)
    excitations = list(scene.drive.excitation_frequencies(w_M)) + list(scene.load.excitation_frequencies(w_3))
    excitations = tuple(sorted(((float(f), label) for f, label in excitations), reverse=True))
    f_max, label = excitations[0] if excitations else (0.0, "none")
    ratio = f_max / f_n
    nyquist = 0.5 * scene.output_rate
    if math.isinf(f_max):
        model = "flexible"
        reason = f"flexible: {label} excites the belt mode ({f_n:.1f} Hz) at every frequency"
        finite = [(f, lab) for f, lab in excitations if math.isfinite(f)]
        if finite:
            reason += f"; also {finite[0][1]} at {finite[0][0]:.1f} Hz ({finite[0][0] / f_n:.2f} of it)"
    elif ratio >= threshold:
        model = "flexible"
        reason = (
            f"flexible: {label} at {f_max:.1f} Hz is {ratio:.2f} of the belt mode ({f_n:.1f} Hz), >= {threshold:g}: "
            + (
                f"the belt resonance amplifies it by {1 / (1 - ratio**2):.2f}x"
                if ratio < 1.0
                else "at or above resonance the belt dynamics dominate"
            )
        )
    else:
        model = "rigid"
        reason = (
            f"rigid: highest excitation {f_max:.3g} Hz ({label}) is {ratio:.3f} of the belt mode "
            f"({f_n:.1f} Hz), < {threshold:g}: the belt stays quasi-static "
            f"(amplification {1 / (1 - ratio**2):.4f}); quasi-static deflection reported"
        )
        if f_n > nyquist:
            reason += f"; the belt mode is also above the output Nyquist frequency ({nyquist:.0f} Hz)"
    return ModelChoice(model, reason, f_n, excitations, ratio, scene.output_rate)
