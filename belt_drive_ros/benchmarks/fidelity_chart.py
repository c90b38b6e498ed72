"""Fidelity: how wrong the rigid model is, against excitation frequency and belt stiffness.

Both models are driven by the same harmonic drive torque ``A sin(2 pi f t)``
(open loop, no load torque), from rest. After the belt's free vibration has
decayed (``8 / (zeta omega_n)`` s, e^-8 of it left) the error of the rigid
model against the flexible one is measured over at least 5 excitation
periods, relative to the flexible model's fluctuation::

    e_y = max |y_rigid - y_flexible| / max |y_flexible - mean(y_flexible)|

for y = drive shaft speed omega_M, load pulley speed omega_3 and belt torque
at wheel 3 (what the load receives). In steady state this is
``|H_rigid(j w) - H_flex(j w)| / |H_flex(j w)|`` of the two models' frequency
responses, drawn as lines over the simulated points (a check of both).

Both runs use ``etd2`` at 200 steps per period of the faster of f and f_n
(the belt mode is integrated exactly; the common input interpolation error
cancels in the difference).

The ``auto`` choice (:func:`belt_drive_ros.core.fidelity.choose_model`) is asked for
every point: where it switches, and the error level at its threshold
``FREQUENCY_RATIO_THRESHOLD``, are in the chart and the CSV.

Linear against slipping (third panel, ``slip_fidelity.csv``)
------------------------------------------------------------
The flexible (linear) model against the slipping one on ``truck_compressor``
(engine drive with a tenth of its firing ripple, F_0 = 300 N, mu = 0.3) with
a load ``L (1 + 0.3 sin(2 pi 8 t))`` whose mean ``L`` is swept through the
belt's capacity ``r_3 Q_max``: error of the flexible model's wheel-3 speed,
max over 1 s relative to the speed's maximum, against the peak force the
flexible run asks of the belt (``auto`` goes on to slipping beyond 1). Both
runs with the scene's default method and step.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.fidelity import FREQUENCY_RATIO_THRESHOLD, choose_model, limit_exceedance
from ..core.model import LINEAR_OUTPUTS, FlexibleBeltModel, RigidBeltModel
from ..core.scene import Scene
from ..io.scenes import load_scene
from ..core.simulate import simulate
from ..core.sources import Constant, Sine
from .common import log, pyplot, save_figure, write_csv

AMPLITUDE = 10.0  # N m (the models are linear: errors do not depend on it)
COLUMNS = ("study", "params", "k", "f_n", "zeta", "f_exc", "ratio", "auto", "e_speed", "e_speed3", "e_belt",
           "h_speed", "h_speed3", "h_belt")  # fmt: skip
SLIP_COLUMNS = ("load_ratio", "peak_force_ratio", "flexible_error", "slip_fraction", "events")


@dataclass(frozen=True)
class Config:
    ratios: tuple = tuple(np.round(np.logspace(-2, math.log10(2.0), 27), 5))
    stiffness_factors: tuple = (0.25, 1.0, 4.0)  # times the truck_compressor belt's k
    with_paper_params: bool = True
    stiffnesses: tuple = tuple(np.logspace(4, 8, 25))  # N/m, at the truck's firing frequency
    settle_e_folds: float = 8.0
    periods: int = 5
    load_ratios: tuple = (0.3, 0.5, 0.7, 0.8, 0.9, 1.0, 1.1, 1.25, 1.5, 2.0)  # slip study: mean load / r_3 Q_max


FULL = Config()
QUICK = Config(
    ratios=(0.02, 0.05, 0.1, 0.2, 0.4, 0.7),
    stiffness_factors=(1.0,),
    with_paper_params=False,
    stiffnesses=(),
    settle_e_folds=6.0,
    periods=3,
    load_ratios=(0.3, 0.7),
)


def truck_firing_frequency() -> float:
    """First firing order of the truck scene at its governor set speed [Hz]."""
    scene = load_scene("truck_compressor")
    return scene.drive.excitation_frequencies(scene.drive.speed_setpoint)[0][0]


def frequency_response(params, f: float) -> dict[str, float]:
    """|H_rigid - H_flex| / |H_flex| at f [Hz] for omega_M, omega_3 and the belt torque (drive input)."""
    s = 2j * math.pi * f
    flex, rigid = FlexibleBeltModel(params), RigidBeltModel(params)
    xf = np.linalg.solve(s * np.eye(4) - flex.A, flex.B[:, 0])  # per N m of drive torque
    xr = np.linalg.solve(s * np.eye(2) - rigid.A, rigid.B[:, 0])
    i = params.ratio
    belt_f = flex.C[LINEAR_OUTPUTS.index("belt_torque")] @ xf  # 2 k r_3^2 theta + 2 c r_3^2 theta'
    accel_r = s * xr[1]
    belt_r = params.I_3 * i * accel_r + params.b_3 * i * xr[1]  # wheel 3's equation, no load
    return {
        "h_speed": abs(xr[1] - xf[2]) / abs(xf[2]),
        "h_speed3": abs(i * xr[1] - xf[3]) / abs(xf[3]),
        "h_belt": abs(belt_r - belt_f) / abs(belt_f),
    }


def _fluct_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b - np.mean(b))))


def compare(params, f: float, config: Config) -> dict:
    """Simulated rigid-vs-flexible errors (module docstring) and the auto choice for drive frequency f [Hz]."""
    f_n = params.belt_natural_frequency / (2.0 * math.pi)
    decay = params.belt_damping_ratio * params.belt_natural_frequency
    settle = config.settle_e_folds / decay
    window = max(config.periods / f, 0.1)
    dt = 1.0 / (200.0 * max(f, f_n))
    n = int(math.ceil((settle + window) / dt))
    scene = Scene(
        name="fidelity", params=params, drive=Sine(mean=0.0, amplitude=AMPLITUDE, frequency=f), load=Constant(0.0),
        duration=n * dt, dt=dt, method="etd2", output_rate=1.0 / dt,
    )  # fmt: skip
    runs = {m: simulate(scene, model=m) for m in ("rigid", "flexible")}
    sel = runs["flexible"].time >= settle
    r, fl = runs["rigid"], runs["flexible"]
    out = {
        "e_speed": _fluct_error(r["omega_M"][sel], fl["omega_M"][sel]),
        "e_speed3": _fluct_error(r["omega_3"][sel], fl["omega_3"][sel]),
        "e_belt": _fluct_error(r["belt_torque"][sel], fl["belt_torque"][sel]),
        "auto": choose_model(scene.with_overrides(duration=min(scene.duration, 2.0 / f + 10 * dt)), check_slip=False).model,
    }
    out.update(frequency_response(params, f))
    return out


def measure(config: Config = FULL, quiet: bool = False) -> list[dict]:
    rows = []
    truck = load_scene("truck_compressor").params
    sets = [(f"truck k x{fac:g}", truck.replace(k=truck.k * fac)) for fac in config.stiffness_factors]
    if config.with_paper_params:
        sets.append(("paper", load_scene("paper").params))
    for label, params in sets:
        f_n = params.belt_natural_frequency / (2.0 * math.pi)
        for ratio in config.ratios:
            res = compare(params, ratio * f_n, config)
            rows.append(dict(res, study="frequency", params=label, k=params.k, f_n=f_n, zeta=params.belt_damping_ratio,
                             f_exc=ratio * f_n, ratio=ratio))  # fmt: skip
            log(f"[fidelity] {label:12s} f/f_n={ratio:<7g} e_speed={res['e_speed']:.2e} e_belt={res['e_belt']:.2e} "
                f"(analytic {res['h_belt']:.2e}) auto={res['auto']}", quiet)  # fmt: skip
    f_fire = truck_firing_frequency()
    for k in config.stiffnesses:
        params = truck.replace(k=float(k))
        f_n = params.belt_natural_frequency / (2.0 * math.pi)
        res = compare(params, f_fire, config)
        rows.append(dict(res, study="stiffness", params="truck", k=float(k), f_n=f_n, zeta=params.belt_damping_ratio,
                         f_exc=f_fire, ratio=f_fire / f_n))  # fmt: skip
        log(f"[fidelity] truck k={k:.3g} N/m f/f_n={f_fire / f_n:.3g} e_belt={res['e_belt']:.2e} auto={res['auto']}", quiet)
    return rows


def slip_fidelity(config: Config = FULL, quiet: bool = False) -> list[dict]:
    """Flexible-model error against the slipping model as the load passes the capacity (module docstring)."""
    base = load_scene("truck_compressor")
    params = base.params.replace(F_0=300.0, mu=0.3)
    capacity = params.r_3 * params.friction_limit(0.0)
    drive = dataclasses.replace(base.drive, harmonics=tuple(0.1 * a for a in base.drive.harmonics))  # smoother engine
    rows = []
    for ratio in config.load_ratios:
        mean = ratio * capacity
        scene = base.with_overrides(params=params, drive=drive, load=Sine(mean=mean, amplitude=0.3 * mean, frequency=8.0), duration=1.0)
        flex = simulate(scene, model="flexible")
        slip = simulate(scene, model="slipping")
        w_f, w_s = flex.outputs["omega_3"], slip.outputs["omega_3"]
        peak, _ = limit_exceedance(params, flex.time, flex.outputs)
        rows.append(dict(load_ratio=ratio, peak_force_ratio=peak,
                         flexible_error=float(np.max(np.abs(w_f - w_s)) / np.max(np.abs(w_s))),
                         slip_fraction=float(np.mean(slip.outputs["slip"])), events=len(slip.events)))  # fmt: skip
        r = rows[-1]
        log(f"[fidelity] slipping: load {ratio:.2f} x capacity: peak force {peak:.2f} x Q_max, flexible error "
            f"{r['flexible_error']:.3g}, slides {100 * r['slip_fraction']:.1f} % of the time", quiet)  # fmt: skip
    return rows


def threshold_error(rows: list[dict], key: str = "e_belt", threshold: float = FREQUENCY_RATIO_THRESHOLD) -> float:
    """Rigid-model error at the auto threshold (log-log interpolation on the reference stiffness)."""
    sel = sorted((r["ratio"], r[key]) for r in rows if r["study"] == "frequency" and r["params"] == "truck k x1")
    if not sel:
        sel = sorted((r["ratio"], r[key]) for r in rows if r["study"] == "frequency")
    x, y = np.log([p[0] for p in sel]), np.log([p[1] for p in sel])
    return float(np.exp(np.interp(math.log(threshold), x, y)))


def ratio_at_error(rows: list[dict], target: float, key: str = "e_belt") -> float:
    """f/f_n at which the rigid model's error first reaches ``target`` (log-log interpolation, reference stiffness)."""
    sel = sorted((r["ratio"], r[key]) for r in rows if r["study"] == "frequency" and r["params"] == "truck k x1")
    for (x0, e0), (x1, e1) in zip(sel, sel[1:]):
        if e0 <= target < e1:
            w = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return float(math.exp(math.log(x0) + w * (math.log(x1) - math.log(x0))))
    return math.nan


def plot(rows: list[dict], path: Path, slip_rows: list[dict] = ()) -> Path:
    plt = pyplot()
    has_k = any(r["study"] == "stiffness" for r in rows)
    n = 1 + int(has_k) + int(bool(slip_rows))
    fig, axes = plt.subplots(1, n, figsize=(6 * n, 4.6), squeeze=False)
    if slip_rows:
        _plot_slip(axes[0, -1], slip_rows)
    ax = axes[0, 0]
    labels = list(dict.fromkeys(r["params"] for r in rows if r["study"] == "frequency"))
    colors = dict(zip(labels, ("tab:blue", "tab:red", "tab:green", "tab:purple")))
    for label in labels:
        sel = sorted((r for r in rows if r["study"] == "frequency" and r["params"] == label), key=lambda r: r["ratio"])
        x = [r["ratio"] for r in sel]
        c = colors[label]
        ax.plot(x, [r["e_belt"] for r in sel], "o", color=c, ms=4, label=f"belt torque, {label}")
        ax.plot(x, [r["h_belt"] for r in sel], "-", color=c, lw=0.8)
        ax.plot(x, [r["e_speed"] for r in sel], "s", color=c, ms=3, mfc="none", label=f"drive speed, {label}")
        ax.plot(x, [r["h_speed"] for r in sel], ":", color=c, lw=0.8)
    thr = FREQUENCY_RATIO_THRESHOLD
    err_thr = threshold_error(rows)
    ax.axvline(thr, color="k", ls="--", lw=1)
    ax.axvspan(1e-3, thr, color="tab:blue", alpha=0.06)  # where auto picks rigid
    ax.text(thr * 0.93, 0.02, f"auto: rigid  |  flexible\nthreshold f/f_n = {thr:g}\nbelt torque error there: {err_thr:.1%}",
            transform=ax.get_xaxis_transform(), ha="center", fontsize=7, va="bottom")  # fmt: skip
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(min(r["ratio"] for r in rows if r["study"] == "frequency") * 0.8, None)
    ax.set_xlabel("excitation frequency / belt natural frequency  f / f_n")
    ax.set_ylabel("rigid-model error / flexible fluctuation")
    ax.set_title("rigid vs flexible, harmonic drive torque (markers: simulated, lines: frequency response)", fontsize=8)
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=6, loc="upper left")
    if has_k:
        ax = axes[0, 1]
        sel = sorted((r for r in rows if r["study"] == "stiffness"), key=lambda r: r["k"])
        k = [r["k"] for r in sel]
        ax.plot(k, [r["e_belt"] for r in sel], "o-", color="tab:red", ms=4, label="belt torque at wheel 3")
        ax.plot(k, [r["e_speed3"] for r in sel], "^-", color="tab:orange", ms=4, label="load pulley speed omega_3")
        ax.plot(k, [r["e_speed"] for r in sel], "s-", color="tab:blue", ms=3, mfc="none", label="drive speed omega_M")
        switch = [r["k"] for r in sel if r["auto"] == "rigid"]
        if switch:
            ax.axvspan(min(switch), max(k) * 1.2, color="tab:blue", alpha=0.06)
            ax.axvline(min(switch), color="k", ls="--", lw=1)
            ax.text(min(switch), 0.02, " auto: rigid ->", transform=ax.get_xaxis_transform(), fontsize=7)
        truck = load_scene("truck_compressor").params
        ax.axvline(truck.k, color="0.5", ls=":", lw=1)
        ax.text(truck.k, 0.9, " truck belt", transform=ax.get_xaxis_transform(), fontsize=7, color="0.4")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("belt span stiffness k [N/m]")
        ax.set_ylabel("rigid-model error / flexible fluctuation")
        ax.set_title(f"truck_compressor, drive at its firing frequency {sel[0]['f_exc']:.1f} Hz", fontsize=8)
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return Path(path)


def _plot_slip(ax, slip_rows: list[dict]) -> None:
    ratio = [r["peak_force_ratio"] for r in slip_rows]
    ax.semilogy(ratio, [max(r["flexible_error"], 1e-16) for r in slip_rows], "o-", color="tab:red", ms=4,
                label="wheel-3 speed (error 0 drawn at 1e-16)")  # fmt: skip
    ax.axvline(1.0, color="k", ls="--", lw=1)
    ax.axvspan(0.0, 1.0, color="tab:blue", alpha=0.06)
    ax.text(1.0, 0.02, " auto: slipping ->", transform=ax.get_xaxis_transform(), fontsize=7)
    ax.set_xlim(0.0, max(ratio) * 1.05)
    ax.set_xlabel("peak force the flexible run asks of the belt / capstan limit Q_max")
    ax.set_ylabel("flexible-model error / max speed")
    ax.set_title("flexible (linear) vs slipping, truck belt F_0 = 300 N, mu = 0.3, load swept", fontsize=8)
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7, loc="center right")


def run(out_dir: Path, quick: bool = False, quiet: bool = False) -> dict:
    config = QUICK if quick else FULL
    rows = measure(config, quiet=quiet)
    slip_rows = slip_fidelity(config, quiet=quiet)
    out_dir = Path(out_dir)
    csv_path = write_csv(out_dir / "fidelity.csv", rows, COLUMNS)
    slip_path = write_csv(out_dir / "slip_fidelity.csv", slip_rows, SLIP_COLUMNS)
    png_path = plot(rows, out_dir / "fidelity.png", slip_rows)
    return {"rows": rows, "slip_rows": slip_rows, "csv": [csv_path, slip_path], "png": png_path,
            "threshold_error": threshold_error(rows)}  # fmt: skip
