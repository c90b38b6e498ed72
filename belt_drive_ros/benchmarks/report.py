"""``summary.md``: the headline tables of a benchmark run, regenerated from its CSV files.

``docs/performance.md`` explains the studies and quotes these numbers;
``docs/bench/summary.md`` is what the last ``make bench`` measured.
"""

from __future__ import annotations

import datetime
import math
import platform
from pathlib import Path

from ..core.fidelity import FREQUENCY_RATIO_THRESHOLD
from .common import get_scene, read_csv


def _fmt(v, spec=".3g"):
    return format(v, spec) if isinstance(v, float) else str(v)


def _table(header, rows) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return out + [""]


def realtime_lines(out: Path) -> list[str]:
    path = out / "realtime.csv"
    if not path.exists():
        return []
    rows = read_csv(path)
    lines = ["## x real time at each scene's own step (`Simulator.run`, min of 15)", ""]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    table = []
    for s in scenes:
        srows = {r["method"]: r for r in rows if r["scene"] == s}
        first = next(iter(srows.values()))
        loop = "open loop" if first["open_loop"] == 1.0 else "closed loop"
        cells = [s, f"{first['model']}, {loop}", f"{first['dt']:.3g}"]
        for m in methods:
            r = srows.get(m)
            cells.append("-" if r is None else ("unstable" if not isinstance(r.get("x_realtime"), float) else f"{r['x_realtime']:.0f}x"))
        whole = [r for r in srows.values() if isinstance(r.get("x_realtime_simulate"), float)]
        cells.append(f"{whole[0]['x_realtime_simulate']:.0f}x" if whole else "-")
        table.append(cells)
    lines += _table(["scene", "model", "dt [s]", *methods, "whole simulate() (default)"], table)
    return lines


def versus_lines(out: Path) -> list[str]:
    lines = []
    match = out / "versus_matched.csv"
    sweep = out / "versus_scipy.csv"
    if match.exists():
        rows = read_csv(match)
        lines += ["## Matched accuracy against `solve_ivp` RK45 (cheapest measured run reaching the error)", ""]
        table = []
        for r in rows:
            speed = f"{r['speedup']:.1f}x" if isinstance(r["speedup"], float) else "RK45 did not reach it"
            rk = f"{r['rk45_cpu_per_sim_s']:.3g} (rtol {r['rk45_rtol']:.2g})" if isinstance(r["rk45_cpu_per_sim_s"], float) else "-"
            table.append([r["scene"], f"{r['target_error']:g}", r["method"], r["setting"], f"{r['cpu_per_sim_s']:.3g}", rk, speed])
        lines += _table(["scene", "error <=", "method", "setting", "CPU s / sim s", "RK45 CPU s / sim s", "speed-up vs RK45"], table)
    if sweep.exists():
        rows = read_csv(sweep)
        lines += ["## What a user gets by default", ""]
        table = []
        for s in dict.fromkeys(r["scene"] for r in rows):
            d = [r for r in rows if r["scene"] == s and r.get("user_default") == 1.0]
            dt = get_scene(s).dt
            e = [r for r in rows if r["scene"] == s and r["method"] == get_scene(s).method and math.isclose(r["dt"], dt, rel_tol=1e-6)]
            for r in d + e[:1]:
                table.append([s, r["method"] + (" (solve_ivp defaults)" if r.get("user_default") == 1.0 else " (package default)"),
                              _fmt(r["rtol"]) if r["rtol"] != "" else f"dt={r['dt']:.3g}", f"{r['error']:.2e}",
                              f"{r['x_realtime']:.0f}x"])  # fmt: skip
        lines += _table(["scene", "method", "setting", "error", "x real time"], table)
    return lines


def workprecision_lines(out: Path) -> list[str]:
    path = out / "workprecision.csv"
    if not path.exists():
        return []
    from .workprecision import row_label

    rows = read_csv(path)
    lines = ["## Work-precision: default method and Pareto front", ""]
    table = []
    for s in dict.fromkeys(r["scene"] for r in rows):
        srows = [r for r in rows if r["scene"] == s and r["status"] == "ok"]
        default = [r for r in srows if r["default"] == 1.0]
        front = sorted((r for r in srows if r["pareto"] == 1.0), key=lambda r: r["cpu_per_sim_s"])
        members = ", ".join(dict.fromkeys(row_label(r) for r in front))
        skipped = sum(1 for r in rows if r["scene"] == s and r["status"] != "ok")
        d = default[0] if default else None
        table.append([s, srows[0]["model"], f"{d['error']:.2e}" if d else "-", f"{d['x_realtime']:.0f}x" if d else "-",
                      "yes" if d and d["pareto"] == 1.0 else "no", members, skipped])  # fmt: skip
    lines += _table(["scene", "model", "default error", "default x real time", "default on front", "front (fast -> accurate)", "points not run/failed"], table)
    linear = [r for r in rows if r["scene"].endswith("open_loop") and r["method"] == "exact" and r["status"] == "ok"]
    if linear:
        lines += [f"Exact method on the open-loop scene: largest error over all steps {max(r['error'] for r in linear):.1e} (rounding level).", ""]
    return lines


def stability_lines(out: Path) -> list[str]:
    path = out / "stability_map.csv"
    if not path.exists():
        return []
    rows = read_csv(path)
    lines = ["## Stability boundary h*omega_n: measured vs predicted by the guard", ""]
    table = []
    for m in dict.fromkeys(r["method"] for r in rows if r["study"] == "plane"):
        pairs = {}
        for r in rows:
            if r["study"] == "plane" and r["method"] == m and r["kind"] != "grid":
                pairs.setdefault(r["zeta"], {})[r["kind"]] = r["h_omega_n"]
        z0 = pairs.get(0.0, {})
        devs = [abs(v["measured boundary"] / v["predicted boundary"] - 1) for v in pairs.values()
                if isinstance(v.get("predicted boundary"), float) and math.isfinite(v["predicted boundary"]) and v["predicted boundary"] > 0
                and math.isfinite(v["measured boundary"])]  # fmt: skip
        table.append([m, _fmt(z0.get("predicted boundary", "-"), ".4g"), _fmt(z0.get("measured boundary", "-"), ".4g"),
                      f"{max(devs):.2%}" if devs else "no boundary (stable at every step)"])  # fmt: skip
    lines += _table(["method", "predicted (zeta=0)", "measured (zeta=0)", "max deviation over zeta > 0 values"], table)
    slip = {}
    for r in rows:
        if r["study"] == "slipping" and r["kind"] != "grid":
            slip.setdefault(r["method"], {})[r["kind"]] = r["dt"]
    if slip:
        lines += ["Slipping scene (`truck_compressor` on the slipping model): step [s] from which a run fails, "
                  "measured vs predicted (inf: none)", ""]  # fmt: skip
        table = [[m, _fmt(v.get("measured boundary", "-")), _fmt(v.get("guard (stick mode)", "-")),
                  _fmt(v.get("slip mode", v.get("regularised, linearized", "-")))] for m, v in slip.items()]  # fmt: skip
        lines += _table(["variant", "measured", "guard (stick mode)", "slip mode / regularised linearized"], table)
    return lines


def fidelity_lines(out: Path) -> list[str]:
    path = out / "fidelity.csv"
    if not path.exists():
        return []
    from .fidelity_chart import ratio_at_error, threshold_error

    rows = read_csv(path)
    e_belt = threshold_error(rows, "e_belt")
    e_speed = threshold_error(rows, "e_speed")
    e_speed3 = threshold_error(rows, "e_speed3")
    lines = [
        "## Fidelity: rigid-model error at the auto threshold",
        "",
        f"At f_exc/f_n = {FREQUENCY_RATIO_THRESHOLD:g} (truck belt): belt torque {e_belt:.2%}, load pulley speed "
        f"{e_speed3:.2%}, drive shaft speed {e_speed:.3%} of the flexible model's fluctuation.",
        "",
    ]
    table = []
    for target in (0.01, 0.02, 0.05, 0.1):
        ratio = ratio_at_error(rows, target)
        table.append([f"{target:.0%}", f"{ratio:.3g}" if math.isfinite(ratio) else "-"])
    lines += _table(["rigid belt-torque error", "reached at f/f_n (interpolated)"], table)
    return lines


def write_summary(out: Path, quick: bool = False, blas: str = "", timings: dict | None = None) -> Path:
    out = Path(out)
    lines = [
        "# Benchmark summary (generated by `belt-drive bench all`; do not edit)",
        "",
        f"{datetime.date.today().isoformat()}, Python {platform.python_version()}, {platform.machine()}, "
        f"{blas}{', QUICK configuration' if quick else ''}.",
        "Definitions and discussion: docs/performance.md.",
        "",
    ]
    if timings:
        lines += ["Study run times: " + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ".", ""]
    for part in (realtime_lines, versus_lines, workprecision_lines, stability_lines, fidelity_lines):
        lines += part(out)
    from ..io.atomic import write_output

    return write_output(out / "summary.md", "\n".join(lines), force=True)
