"""The metrics of one run, computed from its outputs (SI units).

With ``T_b`` the belt torque on wheel 3 [N m], ``Q = T_b / r_3`` the net
force the belt transmits [N], ``Q_max(omega_M)`` the capstan limit
(:meth:`~belt_drive_ros.core.params.BeltDriveParams.friction_limit`) and
``F_0`` the pre-tension:

=====================  ======  ==================================================================
metric                 unit    definition
=====================  ======  ==================================================================
peak_belt_torque       N m     max_t |T_b|
min_slack_force        N       min_t F_slack, F_slack = F_0 - |Q|/2 (< 0: the slack span would push)
peak_friction_use      1       max_t |Q| / Q_max(omega_M) (> 1: the belt slips; the slipping
                               model's own ``friction_use`` when the run is on it)
slip_time              s       time the belt slides (slipping model); 0 for a linear run within
                               the limit, NaN for a linear run past it (slip not modelled)
accumulated_slip       m       integral of |slip speed| dt (slipping model), as slip_time otherwise
peak_deflection        rad     max_t |relative_deflection| (at wheel 3)
final_speed            rad/s   omega_M at the end of the run
min_speed              rad/s   min_t omega_M
=====================  ======  ==================================================================

Integrals are trapezoidal on the run's knots; ``slip_time`` sums the
intervals whose both ends slide.
"""

from __future__ import annotations

import math

import numpy as np

#: metric -> (unit, one-line description)
METRICS: dict[str, tuple[str, str]] = {
    "peak_belt_torque": ("N m", "peak |belt torque| on wheel 3"),
    "min_slack_force": ("N", "minimum slack-span force"),
    "peak_friction_use": ("1", "peak transmitted force / capstan limit"),
    "slip_time": ("s", "time the belt slides"),
    "accumulated_slip": ("m", "distance the belt slides"),
    "peak_deflection": ("rad", "peak |relative deflection|"),
    "final_speed": ("rad/s", "speed of wheel M at the end"),
    "min_speed": ("rad/s", "minimum speed of wheel M"),
}
#: the limits drawn on the histograms by default
DEFAULT_LIMITS = {"min_slack_force": 0.0, "peak_friction_use": 1.0}


def run_metrics(result) -> dict[str, float]:
    """Every metric of :data:`METRICS` for one :class:`~belt_drive_ros.core.simulate.SimResult`."""
    out = result.outputs
    p = result.scene.params
    t = np.asarray(result.time, dtype=float)
    belt = np.asarray(out["belt_torque"], dtype=float)
    omega = np.asarray(out["omega_M"], dtype=float)
    q = np.abs(belt) / p.r_3
    if "friction_use" in out:
        use = np.asarray(out["friction_use"], dtype=float)
    else:
        qmax = np.broadcast_to(p.friction_limit(omega), q.shape)
        use = np.divide(q, qmax, out=np.full(q.shape, np.inf), where=qmax > 0)
    peak_use = float(np.max(use))
    if result.model == "slipping":
        sliding = np.asarray(out["slip"], dtype=bool)
        dt = np.diff(t)
        slip_time = float(np.sum(dt[sliding[1:] & sliding[:-1]]))
        speed = np.abs(np.asarray(out["slip_speed"], dtype=float))
        accumulated = float(np.sum(0.5 * (speed[1:] + speed[:-1]) * dt))
    else:
        slip_time = accumulated = 0.0 if peak_use <= 1.0 else math.nan
    return {
        "peak_belt_torque": float(np.max(np.abs(belt))),
        "min_slack_force": float(np.min(np.asarray(out["span_force_slack"], dtype=float))),
        "peak_friction_use": peak_use,
        "slip_time": slip_time,
        "accumulated_slip": accumulated,
        "peak_deflection": float(np.max(np.abs(np.asarray(out["relative_deflection"], dtype=float)))),
        "final_speed": float(omega[-1]),
        "min_speed": float(np.min(omega)),
    }
