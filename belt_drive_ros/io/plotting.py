"""Plots people would rather look at than read (matplotlib, Agg backend)."""

from __future__ import annotations

import math

import numpy as np

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)


def plot_runs(runs, path, title: str | None = None) -> None:
    """The paper's panels (Figs. 3-4) for one or more :class:`SimResult` overlaid.

    Panels: drive torque [N m], drive shaft speed [rpm], load and belt torque
    at wheel 3 [N m], relative deflection ``i phi_M - phi_3`` [mrad] with its
    static value. Belt slip/slack intervals are shaded.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    styles = {"rigid": dict(color="tab:blue", lw=1.6), "flexible": dict(color="tab:red", lw=1.0),
              "slipping": dict(color="tab:green", lw=1.0)}
    for run in runs:
        st = styles.get(run.model, dict(lw=1.0))
        lab = f"{run.model} ({run.method}, dt={run.dt:g} s)"
        t = run.time
        axes[0].plot(t, run["drive_torque"], label=lab, **st)
        axes[1].plot(t, run["omega_M"] * RPM_PER_RAD_S, label=lab, **st)
        axes[2].plot(t, run["load_torque"], label=f"load torque, {run.model}", ls="--", **st)
        axes[2].plot(t, run["belt_torque"], label=f"belt torque, {run.model}", alpha=0.8, **st)
        axes[3].plot(t, 1e3 * run["relative_deflection"], label=lab, **st)
        if run.model == "slipping":  # the part lost to slip, beside the elastic part
            axes[3].plot(t, 1e3 * run["slip_angle"], label="of it: slip (s / r_3)", ls="--", **st)
        if np.any(run["slip"]):
            axes[3].fill_between(
                t, 0, 1, where=run["slip"], transform=axes[3].get_xaxis_transform(),
                color=st.get("color", "gray"), alpha=0.12, label=f"belt slips ({run.model})" if run.model == "slipping" else f"belt slips/slack ({run.model})",
            )
    last = runs[-1]
    static = 1e3 * last["load_torque"] / last.scene.params.belt_torsional_stiffness
    axes[3].plot(last.time, static, color="k", ls=":", lw=1.0, label="static M_L/(2 k r_3^2)")
    axes[0].set_ylabel("drive torque\n[N m]")
    axes[1].set_ylabel("drive shaft speed\n[rpm]")
    axes[2].set_ylabel("torque at wheel 3\n[N m]")
    axes[3].set_ylabel("relative deflection\ni*phi_M - phi_3 [mrad]")
    axes[3].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(title or f"scene '{last.scene.name}'")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=110, format="png")  # path or binary file (an atomic output)
    finally:
        plt.close(fig)
