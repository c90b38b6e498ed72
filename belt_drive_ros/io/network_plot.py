"""A belt network for people: its Campbell diagram as a PNG (matplotlib, Agg backend), its geometry as text."""

from __future__ import annotations

import math

import numpy as np


def plot_campbell(data, path, title: str) -> None:
    """Mode frequencies [Hz] against engine speed [rpm], the firing-order lines, crossings marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rpm = data.speeds * 60.0 / (2.0 * math.pi)
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for j in range(data.frequencies.shape[1]):
        ax.plot(rpm, data.frequencies[:, j], lw=1.8, label=f"mode {j + 1}")
    shown = data.frequencies[:, : min(5, data.frequencies.shape[1])]  # the lowest modes: where orders reach
    top = max(float(np.nanmax(shown, initial=0.0)) * 1.25, 1.0)
    for order in data.orders:
        line = order * data.speeds / (2.0 * math.pi)
        ax.plot(rpm, line, "k--", lw=0.8)
        end = min(len(rpm) - 1, int(np.searchsorted(line, top * 0.95)))  # the label where the line leaves the plot
        ax.annotate(f"order {order:g}", (rpm[end], min(line[end], top * 0.95)), ha="right", va="bottom", fontsize=8)
    for c in data.crossings:
        ax.plot(c.speed * 60.0 / (2.0 * math.pi), c.frequency, "ro", ms=6)
    ax.set_ylim(0.0, top)
    ax.set_xlabel("engine speed [rpm]")
    ax.set_ylabel("frequency [Hz]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def _tensions(ax, x, scene, run, rows: slice, legend: str, lw: float) -> None:
    """Span tensions [N] against ``x`` (samples ``rows`` of the run), with the slack threshold ``m' v^2`` dashed."""
    for j, span in enumerate(scene.span_names()):
        ax.plot(x, run.tension[rows, j], lw=lw, label=span)
    m = scene.belt.mass_per_length
    if m:
        v = run.speed[rows, scene.driver] * scene.pulleys[scene.driver].radius
        ax.plot(x, m * v * v, "k--", lw=0.8, label="slack below (m' v^2)")
    ax.set_ylabel("span tension [N]")
    ax.legend(fontsize=7, ncol=3, loc=legend)


def _finish(fig, axes, x, run, rows: slice, lw: float, xlabel: str, title: str, path) -> None:
    """The arm's panel (last, when there is an arm), labels, grid, and the PNG written."""
    import matplotlib.pyplot as plt

    if run.arm_angle is not None:
        axes[-1].plot(x, np.degrees(run.arm_angle[rows]), "C3", lw=lw)
        axes[-1].set_ylabel("tensioner arm [deg]")
    axes[-1].set_xlabel(xlabel)
    axes[0].set_title(title)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def plot_network_run(scene, run, path) -> None:
    """Three panels over time: pulley speeds [rpm], span tensions [N] (slack threshold dashed), arm angle [deg]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 3 if run.arm_angle is not None else 2
    fig, axes = plt.subplots(panels, 1, figsize=(9, 2.8 * panels), sharex=True)
    for i, p in enumerate(scene.pulleys):
        axes[0].plot(run.time, run.speed[:, i] * 30.0 / math.pi, lw=1.0, label=p.name)
    axes[0].set_ylabel("pulley speed [rpm]")
    axes[0].legend(fontsize=7, ncol=4, loc="lower right")
    _tensions(axes[1], run.time, scene, run, slice(None), "upper right", 1.0)
    _finish(fig, axes, run.time, run, slice(None), 1.0, "time [s]", f"{scene.name}: belt network, linear tier", path)


def plot_runup(scene, run, path, points: int = 4000) -> None:
    """A run-up against crank speed [rpm]: span tensions [N] with the slack threshold, the tensioner arm [deg]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    every = max(1, len(run.time) // points)
    rpm = run.speed[::every, scene.driver] * 30.0 / math.pi
    panels = 2 if run.arm_angle is not None else 1
    fig, axes = plt.subplots(panels, 1, figsize=(9, 3.2 * panels), sharex=True, squeeze=False)
    axes = axes[:, 0]
    rows = slice(None, None, every)
    _tensions(axes[0], rpm, scene, run, rows, "upper left", 0.8)
    _finish(fig, axes, rpm, run, rows, 0.8, "crank speed [rpm]",
            f"{scene.name}: engine run-up in {scene.duration:g} s, belt network, linear tier", path)


def describe(scene) -> str:
    """A network scene's computed geometry as text: spans, wraps, belt length, tensioner (``belt-drive scenes NAME``)."""
    g, n = scene.geometry, len(scene.pulleys)
    lines = [f"# {scene.name}: belt network ({n} pulleys){' -- ' + scene.description if scene.description else ''}",
             f"{'pulley':14s} {'role':10s} {'side':9s} {'x [m]':>8s} {'y [m]':>8s} {'r [m]':>7s} {'wrap [deg]':>10s}"]
    for i, p in enumerate(scene.pulleys):
        lines.append(f"{p.name:14s} {p.role:10s} {'inner' if p.side > 0 else 'backside':9s} "
                     f"{p.centre[0]:8.4f} {p.centre[1]:8.4f} {p.radius:7.4f} {math.degrees(g.wraps[i]):10.2f}")
    lines.append(f"{'span':28s} {'length [m]':>10s} {'k = EA/L [N/m]':>15s}")
    for j, s in enumerate(scene.span_names()):
        lines.append(f"{s:28s} {g.lengths[j]:10.4f} {scene.belt.EA / g.lengths[j]:15.4g}")
    lines.append(f"belt length {g.belt_length:.4f} m; installed tension {scene.belt.installed_tension:.4g} N")
    if scene.tensioner:
        from ..core.network.model import arm as arm_of

        t = scene.tensioner
        _, _, arm, ang = arm_of(scene.pulleys, t)
        ang = math.degrees(ang)
        lines.append(f"tensioner arm {t.pulley}: pivot ({t.pivot[0]:.4f}, {t.pivot[1]:.4f}) m, length {arm:.4f} m, "
                     f"installed at {ang:.2f} deg, spring preload {abs(t.preload):.4g} N m ({t.spring_rate:.4g} N m/rad)")
    return "\n".join(lines) + "\n"
