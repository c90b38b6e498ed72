"""A campaign's summary text and pictures.

* per metric a histogram with its limit drawn (``limits``: slack force 0 N, friction use 1);
* each metric against each varied parameter (scatter);
* for fleets, the worst recordings with their worst signal (text and a bar chart).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .metrics import METRICS

#: the charts :func:`plot` may write into the output folder (``sweep --plots``); the fleet's only with goldens
HISTOGRAMS, SCATTER, FLEET_WORST = "histograms.png", "metrics_vs_parameters.png", "fleet_worst.png"

#: columns of the result table that are not varied inputs
RESULT_COLUMNS = {
    "variant", "model", "ran", "single_reason", "error", "seconds", "compare_passed", "worst_signal",
    "worst_rel_error", "worst_errors", "recording", "profile", *METRICS,
}  # fmt: skip


#: units of the columns of a result table that are neither metrics nor parameters (SI)
COLUMN_UNITS = {
    "initial_state.phi_M": "rad", "initial_state.omega_M": "rad/s", "initial_state.relative_deflection": "rad",
    "initial_state.relative_speed": "rad/s", "seconds": "s", "worst_rel_error": "1",
}  # fmt: skip


def column_units(columns) -> dict[str, str]:
    """Column -> unit of the columns of a result or variant table whose unit is known: the metrics, ``params.NAME``
    (:data:`~belt_drive_ros.core.params.FIELD_DOCS`), ``dt``, ``duration``, ``output_rate``, the initial state and the
    fleet's relative error. Stored with the table (``pandas.read_parquet(...).attrs["units"]``); a profile's fields
    (``drive.FIELD``) have the unit its profile gives them (docs/model.md)."""
    from ..core.params import FIELD_DOCS
    from ..core.scene import RANGES

    out = {}
    for name in columns:
        if name in METRICS:
            out[name] = METRICS[name][0]
        elif name.startswith("params.") and name[len("params."):] in FIELD_DOCS:
            out[name] = FIELD_DOCS[name[len("params."):]][0]
        elif name in ("dt", "duration", "output_rate"):
            out[name] = RANGES[name][2]
        elif name in COLUMN_UNITS:
            out[name] = COLUMN_UNITS[name]
    return out


def varied_columns(table) -> list[str]:
    """The table's varied numeric inputs (key paths)."""
    from pandas.api.types import is_numeric_dtype

    return [c for c in table.columns if c not in RESULT_COLUMNS and is_numeric_dtype(table[c])]


def summary(table, campaign, wall: float | None = None, workers: int | None = None, worst: int = 10) -> str:
    """Plain-text summary: counts (ensemble, single with reasons, failed), metric ranges, limit violations, fleet verdicts."""
    n = len(table)
    lines = [f"campaign {campaign.name}: {n} runs" + (f" in {wall:.2f} s on {workers} worker(s)" if wall is not None else "")]
    ran = table["ran"].value_counts().to_dict() if n else {}
    lines.append(f"  ensemble: {ran.get('ensemble', 0)}   single: {ran.get('single', 0)}   not built: {ran.get('none', 0)}")
    if n and campaign.fleet_folder is None:  # (said where it is read: a row is no verdict on its step)
        lines.append("  accuracy: no verdict per variant in the table (the ensemble runs no accuracy guard: "
                     "docs/campaigns.md); `belt-drive sim` on a variant's scene rates its method and step")
    if ran.get("single", 0):
        reasons = table.loc[table["ran"] == "single", "single_reason"].value_counts()
        for reason, count in reasons.items():
            lines.append(f"    single, {count}: {reason}")
    failed = table[table["error"] != ""]
    lines.append(f"  failed: {len(failed)}")
    for _, row in failed.head(worst).iterrows():
        lines.append(f"    variant {int(row['variant'])}: {row['error']}")
    if len(failed) > worst:
        lines.append(f"    ... {len(failed) - worst} more (column 'error' of the table)")
    if "warning" in table:
        warned = table[table["warning"] != ""]
        if len(warned):
            lines.append(f"  recordings cut off (run on their complete chunks): {len(warned)}")
            for _, row in warned.head(worst).iterrows():
                lines.append(f"    variant {int(row['variant'])}: {row['warning']}")
            if len(warned) > worst:
                lines.append(f"    ... {len(warned) - worst} more (column 'warning' of the table)")
    if "model" in table and n:
        models = table.loc[table["model"] != "", "model"].value_counts().to_dict()
        lines.append("  models: " + ", ".join(f"{k} {v}" for k, v in models.items()))
    lines.append(f"  {'metric':<20s}{'unit':>7s}{'min':>13s}{'median':>13s}{'max':>13s}  limit")
    for name in campaign.metrics:
        values = table[name].to_numpy(dtype=float)
        finite = values[~np.isnan(values)]  # (a failed run's NaN left out; an infinite use, a lifted belt, counts)
        unit = METRICS[name][0]
        limit = campaign.limits.get(name)
        stats = (np.min(finite), np.median(finite), np.max(finite)) if finite.size else (math.nan,) * 3
        beyond = ""
        # a run that ran without a value (slip_time, accumulated_slip of a linear run past the capstan limit: slip not
        # modelled) is no pass: counted apart (it was left out, '0 beyond' where every such run was unknown)
        unknown = int(np.sum(np.isnan(values) & (table["error"] == "").to_numpy()))
        if limit is not None and (finite.size or unknown):
            count = int(np.sum(finite < limit)) if name.startswith("min_") else int(np.sum(finite > limit))
            beyond = f"{limit:g}: {count} beyond" + (f", {unknown} without a value (NaN)" if unknown else "")
            if name == "peak_friction_use" and limit >= 1.0 and "model" in table:
                # a run on the slipping model that reached the capstan limit slipped, its use held at 1 (never beyond
                # a limit of 1: '1: 0 beyond' for a campaign whose every run slipped)
                held = int(np.sum((table["model"] == "slipping").to_numpy() & (values >= 1.0)))
                beyond += f", {held} slipped (the slipping model's use stops at 1)" if held else ""
        lines.append(f"  {name:<20s}{unit:>7s}" + "".join(f"{v:13.5g}" for v in stats) + f"  {beyond}")
    if "compare_passed" in table:
        compared = table[table["compare_passed"].notna()]
        bad = compared[~compared["compare_passed"].astype(bool)]
        missed = n - len(compared)  # (a recording whose run failed is never compared: it was left out of the count)
        lines.append(f"  fleet compare: {len(compared) - len(bad)} of {n} recordings pass"
                     + (f" ({missed} not compared: the run failed)" if missed else ""))
        lines += ["  worst recordings (worst signal, worst relative error):"]
        for _, row in worst_recordings(table, worst).iterrows():
            verdict = "pass" if row["compare_passed"] else "FAIL"
            lines.append(f"    {row['recording']:<32s} {verdict}  {row['worst_signal']:<36s} {row['worst_rel_error']:.3g}")
    return "\n".join(lines)


def worst_recordings(table, count: int = 10):
    """The fleet's recordings by worst relative error, failures first."""
    rows = table[table["compare_passed"].notna()].copy()
    rows["_fail"] = ~rows["compare_passed"].astype(bool)
    return rows.sort_values(["_fail", "worst_rel_error"], ascending=[False, False]).head(count)


def _save(fig, path: Path, dpi: int) -> None:
    """``fig`` as the PNG ``path``, whole or not at all (:func:`~belt_drive_ros.io.atomic.atomic_output`)."""
    from ..io.atomic import atomic_output

    with atomic_output(path, force=True, what="campaign chart") as f:
        fig.savefig(f, format="png", dpi=dpi)


def plot(table, campaign, out_dir) -> list[Path]:
    """Write the pictures into ``out_dir`` (PNG); return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    metrics = [m for m in campaign.metrics if np.isfinite(table[m].to_numpy(dtype=float)).any()]
    if metrics:
        cols = min(3, len(metrics))
        rows = math.ceil(len(metrics) / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
        for ax, name in zip(axes.flat, metrics):
            values = table[name].to_numpy(dtype=float)
            ax.hist(values[np.isfinite(values)], bins=40, color="tab:blue", alpha=0.8)
            limit = campaign.limits.get(name)
            if limit is not None:
                ax.axvline(limit, color="tab:red", lw=2, label=f"limit {limit:g}")
                ax.legend(fontsize=8)
            ax.set_xlabel(f"{name} [{METRICS[name][0]}]")
            ax.set_ylabel("runs")
        for ax in list(axes.flat)[len(metrics):]:
            ax.axis("off")
        fig.suptitle(f"{campaign.name}: {len(table)} runs")
        fig.tight_layout()
        path = out_dir / HISTOGRAMS
        _save(fig, path, dpi=100)
        plt.close(fig)
        written.append(path)
    varied = varied_columns(table)
    if varied and metrics:
        fig, axes = plt.subplots(len(metrics), len(varied), figsize=(3.4 * len(varied), 2.6 * len(metrics)), squeeze=False)
        for i, name in enumerate(metrics):
            for j, key in enumerate(varied):
                ax = axes[i, j]
                ax.plot(table[key].to_numpy(dtype=float), table[name].to_numpy(dtype=float), ".", ms=2, alpha=0.5)
                limit = campaign.limits.get(name)
                if limit is not None:
                    ax.axhline(limit, color="tab:red", lw=1)
                ax.xaxis.set_major_locator(MaxNLocator(4))  # (five ticks of 16000 ran into one another)
                if i == len(metrics) - 1:
                    unit = column_units([key]).get(key)
                    ax.set_xlabel(f"{key} [{unit}]" if unit else key)
                if j == 0:
                    ax.set_ylabel(f"{name}\n[{METRICS[name][0]}]", fontsize=8)
        fig.tight_layout()
        path = out_dir / SCATTER
        _save(fig, path, dpi=90)
        plt.close(fig)
        written.append(path)
    if "compare_passed" in table and table["compare_passed"].notna().any():
        worst = worst_recordings(table, 15)
        fig, ax = plt.subplots(figsize=(8, 0.35 * len(worst) + 1.2))
        colors = ["tab:red" if not p else "tab:green" for p in worst["compare_passed"]]
        labels = [f"{r} ({s})" for r, s in zip(worst["recording"], worst["worst_signal"])]
        # on the log axis an error 0 (a run equal to its golden, the usual verdict) or inf (no golden) has no bar:
        # drawn at the axis' ends, each bar labelled with its value (all 0 drew an empty chart scaled 1 to 10)
        errors = worst["worst_rel_error"].to_numpy(dtype=float)
        seen = errors[np.isfinite(errors) & (errors > 0)]
        low = min(float(np.min(seen)) / 10, 1e-17) if seen.size else 1e-17
        high = max(float(np.max(seen)) * 10, 1.0) if seen.size else 1.0
        shown = np.where(np.isinf(errors), high, np.where(errors > 0, errors, low))
        ax.set_xscale("log")
        ax.barh(range(len(worst)), shown - low / 2, left=low / 2, color=colors)
        for y, (x, e) in enumerate(zip(shown, errors)):
            ax.text(x, y, " 0" if e == 0 else f" {e:.3g}", va="center", fontsize=7)
        ax.set_xlim(low / 2, high * 100)
        ax.set_yticks(range(len(worst)), labels, fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel("worst relative error against the golden (red: fails the tube)")
        fig.tight_layout()
        path = out_dir / FLEET_WORST
        _save(fig, path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written
