"""The Campbell diagram of a belt network as a PNG (matplotlib, Agg backend)."""

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
