"""``/diagnostics`` of the belt-drive node: simulation, input and belt statuses.

:class:`NodeDiagnostics` publishes a ``diagnostic_msgs/DiagnosticArray``
once a second of wall time (and on demand). ``<node>`` in the status names
is the node's fully qualified name without its leading slash
(:func:`status_prefix`: ``belt_drive``, ``truck1/belt_drive`` in the
namespace ``/truck1``). Each status covers the window since the previous
publish:

* ``<node>: simulation``: ERROR if the state diverged in the window (the
  reason; the run restarted from its initial state), WARN for a gap in the
  ticks (:mod:`.gaps`: the last one; ``tick_gaps``, ``ticks_missed`` and
  ``last_gap`` count and describe them since the start), for overruns,
  a rate below 95 % on the system clock, or a failed recording; the values
  carry the model, method, step, stability, time base, tick statistics and
  counters.
* ``<node>: input``: WARN while ``input_timeout`` has expired or when
  messages were rejected (non-finite) or clamped in the window; counters, and
  ``publishers``: the drive_torque publishers its subscription is matched with.
* ``<node>: belt``: on a linear model, WARN when the belt went slack or
  slipped in the window (the linear model is outside its validity: the
  ``slipping`` model covers it); on the slipping model, OK with what the
  belt did (ticks and time sliding, stick/slip events, the last one,
  accumulated slip); span forces, friction use, slip state and speed.
"""

from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from .timing import stamp

__all__ = ["NodeDiagnostics", "status_prefix"]

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


def status_prefix(node) -> str:
    """What the names of ``node``'s statuses start with: its fully qualified name without the leading slash.

    ``belt_drive`` in the root namespace, ``truck1/belt_drive`` in ``/truck1``: drives in two namespaces report
    apart on the one ``/diagnostics`` (as diagnostic_updater's ``use_fqn``; with the bare node name, its default,
    both were ``belt_drive: simulation``, one entry in rqt_robot_monitor and the aggregator flipping between them).
    """
    return node.get_fully_qualified_name().lstrip("/")


def _kv(**items) -> list:
    return [KeyValue(key=k, value=str(v)) for k, v in items.items()]


class NodeDiagnostics:
    """Builds and publishes the node's statuses (see the module docstring).

    Parameters
    ----------
    node : BeltDriveNode
        Read: ``settings``, ``counters``, ``sim``, ``drive``, ``timing``,
        ``stats``, ``last`` and ``recorder``.
    """

    def __init__(self, node):
        self.node = node
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._seen = {}  # counters at the start of the window

    def _delta(self, key: str) -> int:
        now = self.node.counters[key]
        return now - self._seen.get(key, 0)

    def status(self) -> list[DiagnosticStatus]:
        """The node's health now (also starts a new window)."""
        node = self.node
        s = node.settings
        c = node.counters
        sim, drive, timing = node.sim, node.drive, node.timing
        w = node.stats.new_window()
        span = max(time.perf_counter() - w.wall, 1e-9)
        deltas = {k: self._delta(k) for k in ("divergences", "rejected_nonfinite", "clamped", "rejected_bound",
                                              "tick_gaps")}
        self._seen = dict(c)
        prefix = status_prefix(node)
        last = node.last
        p50, p99, pmax = node.stats.period_error_ms(timing.nominal_period())
        compute = timing.compute_us()  # the tick thread's compute time per tick [us] (None without it)
        rate = w.ticks / span
        realtime = timing.time_base() == "system"
        recorder = node.recorder
        level, message = OK, "running"
        if deltas["divergences"]:
            reason = sim.last_divergence[0] if sim.last_divergence else "diverged"
            level, message = ERROR, f"{deltas['divergences']} divergence(s), restarted from the initial state: {reason}"
        elif deltas["tick_gaps"]:
            level, message = WARN, f"{deltas['tick_gaps']} gap(s) in the ticks; last: {timing.gaps.last.describe()}"
        elif not sim.started:
            message = "waiting for the first tick" + (" (no /clock yet)" if timing.use_sim_time() else "")
        elif w.overruns > max(1, 0.01 * w.ticks):
            level, message = WARN, f"{w.overruns} of {w.ticks} ticks took longer than the period"
        elif realtime and w.ticks and rate < 0.95 * s.step_rate_hz and span > 0.5:
            level, message = WARN, f"achieved {rate:.1f} Hz < 95% of {s.step_rate_hz:g} Hz"
        elif recorder is not None and recorder.failed:
            level, message = WARN, f"simulating; {recorder.status}"
        if level == OK and s.accuracy is not None and not s.accuracy.accurate:  # runs, but said (and logged at the change)
            message += f" (step rated inaccurate: estimated error {s.accuracy.error:.2g} > {s.accuracy.tolerance:.2g})"
        simulation = DiagnosticStatus(
            level=level, name=f"{prefix}: simulation", message=message, hardware_id=s.scene.name,
            values=_kv(
                scene=s.scene.name,
                model=s.model.name,
                model_reason=s.model_reason,
                method=s.method,
                method_reason=s.method_reason,
                dt=f"{s.dt:.9g}",
                substeps=s.substeps,
                step_rate_hz=f"{s.step_rate_hz:g}",
                achieved_rate_hz=f"{rate:.2f}",
                stability=s.stability.describe(),
                accuracy=s.accuracy.describe() if s.accuracy is not None else "adaptive method (own error control)",
                time_base=timing.time_base(),
                sim_time=f"{last.get('time', 0.0):.6f}",
                ticks=c["ticks"],
                published=c["published"],
                overruns=c["overruns"],
                late_ticks=c["late_ticks"],
                period_error_ms_p50=f"{p50:.4f}",
                period_error_ms_p99=f"{p99:.4f}",
                period_error_ms_max=f"{pmax:.4f}",
                tick_lead_ms="-" if timing.lead_ns() is None else f"{timing.lead_ns() / 1e6:.3f}",
                tick_compute_us_p50="-" if compute is None else f"{compute[0]:.1f}",
                tick_compute_us_p99="-" if compute is None else f"{compute[1]:.1f}",
                restarts=c["restarts"],
                clock_jumps=c["clock_jumps"],
                tick_gaps=c["tick_gaps"],
                ticks_missed=c["ticks_missed"],
                last_gap=timing.gaps.last.describe() if timing.gaps.last is not None else "none",
                divergences=c["divergences"],
                last_divergence=sim.last_divergence[0] if sim.last_divergence else "none",
                recording="off" if recorder is None else recorder.status,
            ),
        )
        warn, message = drive.status(s)
        rejected = deltas["rejected_nonfinite"] + deltas["rejected_bound"]
        if not warn and s.drive_source == "topic" and (rejected or deltas["clamped"]):
            warn = True
            message = f"{rejected} message(s) rejected, {deltas['clamped']} clamped in the last window"
        age = (timing.now_ns() - drive.last_input_ns) / 1e9 if drive.last_input_ns is not None else math.nan
        inp = DiagnosticStatus(
            level=WARN if warn else OK, name=f"{prefix}: input", message=message, hardware_id=s.scene.name,
            values=_kv(
                drive_source=s.drive_source,
                drive_torque=f"{drive.applied.value:.6g}",
                received=c["received"],
                publishers=self.node._sub_torque.get_publisher_count(),
                rejected_nonfinite=c["rejected_nonfinite"],
                rejected_bound=c["rejected_bound"],
                clamped=c["clamped"],
                ignored=c["ignored"],
                timeouts=c["timeouts"],
                stale=drive.stale,
                last_input_age_s=f"{age:.3f}",
                input_timeout_s=f"{s.input_timeout_ns / 1e9:g}",
                timeout_behavior=s.timeout_behavior,
                torque_limit=f"{s.torque_limit:g}",
                torque_bound=f"{s.torque_bound:g}",
            ),
        )
        level, message = OK, "no slack, no slip"
        slipping = s.model.name == "slipping"
        if slipping:
            tick_s = s.tick_ns / 1e9
            events = sim.slip_events
            message = (
                f"slipping model: belt slides in {w.slip} of {max(w.ticks, 1)} ticks ({w.slip * tick_s:.3g} s), "
                f"sticks otherwise; {c['slip_events']} stick/slip event(s) located so far"
                + (f", last {events[-1][0]} at t = {events[-1][1]:.6g} s" if events else "")
                + f"; slip so far {last.get('slip_angle', 0.0):.4g} rad at wheel 3"
            )
        elif w.slack or w.slip:
            level = WARN
            message = (
                f"belt {'slack' if w.slack else 'slips'} in {max(w.slack, w.slip)} of {max(w.ticks, 1)} ticks: "
                "the linear model is outside its validity (model 'slipping' covers slip)"
            )
        belt = DiagnosticStatus(
            level=level, name=f"{prefix}: belt", message=message, hardware_id=s.scene.name,
            values=_kv(
                slack=last.get("slack", False),
                slip=last.get("slip", False),
                slack_ticks=c["slack_ticks"],
                slip_ticks=c["slip_ticks"],
                slip_state=("sliding" if last.get("slip", False) else "sticking") if slipping else "not modelled",
                slip_time_s=f"{c['slip_ticks'] * s.tick_ns / 1e9:.6g}",
                slip_events=c.get("slip_events", 0),
                last_slip_event=(f"{sim.slip_events[-1][0]} at t={sim.slip_events[-1][1]:.9g} s"
                                 if sim.slip_events else "none"),
                friction_use=f"{last.get('friction_use', math.nan):.6g}",
                slip_speed_mps=f"{last.get('slip_speed', 0.0):.6g}",
                slip_angle_rad=f"{last.get('slip_angle', 0.0):.6g}",
                span_force_tight_N=f"{last.get('span_force_tight', math.nan):.6g}",
                span_force_slack_N=f"{last.get('span_force_slack', math.nan):.6g}",
                belt_torque_Nm=f"{last.get('belt_torque', math.nan):.6g}",
                relative_deflection_rad=f"{last.get('relative_deflection', math.nan):.6g}",
                belt_mode_hz=f"{s.params.belt_natural_frequency / (2 * math.pi):.3f}",
            ),
        )
        return [simulation, inp, belt]

    def publish(self) -> None:
        """Publish ``/diagnostics`` now."""
        msg = DiagnosticArray()
        stamp(msg.header.stamp, self.node.timing.now_ns())
        msg.status = self.status()
        self._pub.publish(msg)
