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

from ..core.fidelity import friction_use
from ..core.model import span_forces
from ..core.scene import SLIP_MODELS

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
    if "friction_use" in out:
        use = np.asarray(out["friction_use"], dtype=float)
    else:
        use = friction_use(belt, p.r_3, np.broadcast_to(p.friction_limit(omega), belt.shape))
    values = _finish(_reduce(belt, omega, np.asarray(out["span_force_slack"], dtype=float),
                             np.asarray(out["relative_deflection"], dtype=float), use))  # fmt: skip
    if result.model in SLIP_MODELS:
        sliding = np.asarray(out["slip"], dtype=bool)
        dt = np.diff(t)
        values["slip_time"] = np.sum(dt[sliding[1:] & sliding[:-1]])
        speed = np.abs(np.asarray(out["slip_speed"], dtype=float))
        values["accumulated_slip"] = np.sum(0.5 * (speed[1:] + speed[:-1]) * dt)
    return {name: float(values[name]) for name in METRICS}


def group_values(run) -> dict[str, np.ndarray]:
    """:func:`run_metrics` of every variant of a :class:`~belt_drive_ros.campaign.ensemble_run.GroupRun` at once:
    metric -> (V,) array, in the block's order.

    The same formulas as array reductions over the time axis of the (N+1, V)
    signals (so element v equals :func:`run_metrics` of that variant's single
    run bit for bit).
    """
    return summary_values(_finish(_window(run)))


#: how the linear-run metrics of windows of one run combine (:class:`~belt_drive_ros.campaign.ensemble_run.Reductions`)
WINDOW_KINDS = {
    "peak_belt_torque": "max", "min_slack_force": "min", "peak_friction_use": "max", "peak_deflection": "max",
    "final_speed": "last", "min_speed": "min",
}  # fmt: skip


def _window(run) -> dict:
    """The linear-run metrics of one window of a :class:`~belt_drive_ros.campaign.ensemble_run.GroupRun` (before :func:`_finish`).

    The peaks of |T_b|, |relative deflection| and the friction use from :meth:`GroupRun.peaks` (one compiled pass;
    the friction use's peak is its value at :func:`~belt_drive_ros.campaign.ensemble_run.peak_over_time`'s first
    peak, the float ``np.max`` gives: the same maximum, a NaN as the peak either way). ``min_slack_force`` from the
    window's peak |T_b| alone: F_slack = F_0 - (0.5 |T_b|) / r_3 (:func:`~belt_drive_ros.core.model.span_forces`)
    does not increase with |T_b| in floating point too (each rounded operation is monotone, r_3 > 0), so its minimum
    over the knots is its value at the largest |T_b|, the same float (NaN as ``np.min`` gives it: a NaN torque is the
    peak); no slack force at every knot.
    """
    peaks, omega = run.peaks(), run.output("omega_M")
    values = {
        "peak_belt_torque": peaks["belt"], "peak_friction_use": peaks["use"][0], "peak_deflection": peaks["deflection"],
        "final_speed": omega[-1], "min_speed": np.min(omega, axis=0),
    }  # fmt: skip
    values["min_slack_force"] = span_forces(run.param("F_0"), run.param("r_3"), run.param("capstan_ratio"), peaks["belt"])[1]
    return values


#: ``reduce`` of :func:`~belt_drive_ros.campaign.ensemble_run.run_groups` for the campaign metrics (then :func:`summary_values`)
GROUP_REDUCTION = (WINDOW_KINDS, _window)


def summary_values(values: dict) -> dict[str, np.ndarray]:
    """Every metric, metric -> (V,) float array, from reductions over whole runs (``GroupSummary.values`` of
    :data:`GROUP_REDUCTION`)."""
    if "slip_time" not in values:
        values = _finish(values)
    return {name: np.asarray(values[name], dtype=float) for name in METRICS}


def _reduce(belt, omega, slack_force, deflection, use) -> dict:
    """The metrics of a linear run, reduced over the time axis 0 (trailing axes: variants)."""
    return {
        "peak_belt_torque": np.max(np.abs(belt), axis=0),
        "min_slack_force": np.min(slack_force, axis=0),
        "peak_friction_use": np.max(use, axis=0),
        "peak_deflection": np.max(np.abs(deflection), axis=0),
        "final_speed": omega[-1],
        "min_speed": np.min(omega, axis=0),
    }


def _finish(values: dict) -> dict:
    """``values`` of :func:`_reduce` over the whole run with the slip metrics: 0 within the limit, NaN past it."""
    beyond = np.where(values["peak_friction_use"] <= 1.0, 0.0, math.nan)  # slip is not modelled by a linear run
    return dict(values, slip_time=beyond, accumulated_slip=beyond)
