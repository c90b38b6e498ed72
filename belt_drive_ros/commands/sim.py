"""``belt-drive sim``: run a scene offline, write CSV/MCAP and the paper's panels."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

EPILOG = """\
examples:
  belt-drive sim paper --plot paper.png --out paper.csv
  belt-drive sim truck_compressor --model flexible --method rk4 --dt 2e-4
  belt-drive sim my_scene.yaml --duration 10 --out run.mcap
  belt-drive sim paper --method RK45 --method-option rtol=1e-8

SCENE is a shipped scene name (belt-drive scenes lists them) or a YAML path.
CSV columns (SI units): time, phi_M, omega_M, phi_3, omega_3, drive_torque,
load_torque, belt_torque, relative_deflection; a slipping-model run adds
span_force_tight, span_force_slack [N], friction_use [1], slip [0/1],
slip_speed [m/s], elastic_deflection, slip_angle [rad] (docs/slip.md).
"""


def _start_time(text: str):
    """argparse type of --start-time (ns since the epoch, None for 'now')."""
    import argparse

    from ..io.recording import parse_start_time

    try:
        return parse_start_time(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(sub) -> None:
    from ..core.integrators import describe_methods  # the method registry (numpy only; scipy loads on use)

    p = sub.add_parser(
        "sim",
        help="simulate a scene offline (no ROS needed)",
        description="Simulate a scene offline and print a summary; optionally write CSV/MCAP and a PNG.",
        epilog=EPILOG + "\nintegrators (--method; default: the scene's):\n" + describe_methods() + "\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scene", help="shipped scene name or path to a scene YAML")
    p.add_argument(
        "--model", choices=("rigid", "flexible", "slipping", "auto"),
        help="belt model (default: the scene's, usually auto; auto goes on to slipping past the friction limit)",
    )
    p.add_argument("--method", help="integrator by name (list below; default: the scene's)")
    p.add_argument("--method-option", action="append", default=[], metavar="KEY=VALUE", help="integrator option, e.g. rtol=1e-8 (repeatable)")
    p.add_argument("--dt", type=float, help="integrator step [s] (output interval for adaptive methods)")
    p.add_argument("--duration", type=float, help="simulated time [s]")
    p.add_argument("--out", type=Path, help="write the run: .csv, or .mcap (ROS 2 bag); by extension, any case")
    p.add_argument("--plot", type=Path, help="PNG with the paper's panels, rigid and flexible overlaid")
    p.add_argument("--torque-bag", type=Path, help="drive the model with drive_torque recorded in this MCAP")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs (--out and --plot)")
    p.add_argument("--start-time", default=None, metavar="WHEN", type=_start_time,
                   help="time stamp of scene time 0 in an .mcap: 'now' (default, the wall time of the run, "
                        "as rosbag2 stamps it), seconds since the epoch (0: simulated time), or an ISO 8601 date")
    p.add_argument("--bag-folder", action="store_true",
                   help="write --out as a rosbag2 bag folder (OUT/OUT_0.mcap + metadata.yaml)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _options(pairs):
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise SystemExit(f"belt-drive: error: --method-option expects KEY=VALUE, got {pair!r}")
        try:
            out[key] = float(value) if key not in ("max_iter",) else int(value)
        except ValueError:
            raise SystemExit(f"belt-drive: error: --method-option {key}: not a number: {value!r}") from None
    return out


def run(args) -> int:
    from ..io.progress import ProgressBar
    from ..core.scene import load_scene
    from ..core.simulate import simulate

    scene = load_scene(args.scene)
    if args.method_option:
        scene = scene.with_overrides(method_options=_options(args.method_option))
    if args.torque_bag is not None:
        from ..io.torque_bag import scene_with_torque_bag  # issue 4: offline replay of a recorded profile

        scene = scene_with_torque_bag(scene, args.torque_bag)
    out_format = check_outputs(args)
    bar = ProgressBar(f"sim {scene.name}", force=False) if not args.quiet else None
    result = simulate(scene, model=args.model, method=args.method, dt=args.dt, duration=args.duration, progress=bar)
    print_summary(result)
    if args.out is not None:
        from ..io.atomic import atomic_output

        if out_format == "mcap" and args.bag_folder:
            from ..io.recording import write_result_mcap

            write_result_mcap(result, args.out, force=args.force, start_time_ns=args.start_time, bag_folder=True)
        elif out_format == "mcap":
            from ..io.recording import write_result_mcap

            with atomic_output(args.out, args.force, "wb", what="--out") as f:
                write_result_mcap(result, f, start_time_ns=args.start_time)
        else:
            with atomic_output(args.out, args.force, "w", what="--out") as f:
                result.to_csv(f)
        print(f"wrote {args.out}")
    if args.plot is not None:
        from ..io.atomic import atomic_output
        from ..io.plotting import plot_runs

        comp = _overlay_run(scene, result, args)
        runs = sorted([result, comp], key=lambda r: r.model != "rigid")
        with atomic_output(args.plot, args.force, "wb", what="--plot") as f:
            plot_runs(runs, f, title=f"scene '{scene.name}': rigid vs flexible belt")
        print(f"wrote {args.plot}")
    return 0


#: --out formats by extension (compared case-insensitively)
OUT_FORMATS = {".csv": "csv", ".mcap": "mcap"}


def check_outputs(args) -> str | None:
    """Refuse bad outputs before the run; return the --out format (``csv``/``mcap``) or None.

    The format follows the extension, case-insensitively (``run.MCAP`` is
    MCAP); an unknown one is an error. ``--force`` governs every output, the
    plot included; devices, FIFOs and directories are refused
    (:func:`belt_drive_ros.io.atomic.check_output`).
    """
    from ..io.atomic import OutputRefused, check_output

    out_format = None
    if args.out is not None:
        if args.bag_folder:
            out_format = "mcap"
            if args.out.exists() and not args.out.is_dir():
                raise OutputRefused(f"--out {args.out}: exists and is not a folder (--bag-folder writes a folder)")
        else:
            check_output(args.out, args.force, "--out")
            out_format = OUT_FORMATS.get(args.out.suffix.lower())
            if out_format is None:
                raise OutputRefused(
                    f"--out {args.out}: unknown format {args.out.suffix or '(no extension)'!r}; "
                    f"use .csv or .mcap (any case), or --bag-folder"
                )
    if args.plot is not None:
        check_output(args.plot, args.force, "--plot")
        if args.plot.suffix.lower() != ".png":
            raise OutputRefused(f"--plot {args.plot}: the plot is a PNG; give a .png path (got {args.plot.suffix or 'no extension'!r})")
        if args.out is not None and args.plot.resolve() == args.out.resolve():
            raise OutputRefused("--plot and --out name the same file")
    return out_format


def _overlay_run(scene, result, args):
    """The other model for the plot overlay, with the same method where that is stable.

    A step that is stable for the rigid model may not be for the flexible one
    (its belt mode); the overlay then falls back to ``etd2`` and says so
    (the legend names the method) rather than failing a valid run.
    """
    from ..core.model import make_model
    from ..core.simulate import simulate
    from ..core.stability import check_step

    other = "flexible" if result.model == "rigid" else "rigid"
    method = result.method
    model = make_model(other, scene.params)
    report = check_step(model.A, model.B, method, result.dt)
    if not report.stable:
        print(f"note: overlay {other} model uses etd2: {report.describe()}")
        method = "etd2"
    return simulate(scene, model=other, method=method, dt=result.dt, duration=args.duration)


def print_summary(result) -> None:
    """Short human summary of a run (rpm for people, SI otherwise)."""
    rpm = 60.0 / (2.0 * math.pi)
    o = result.outputs
    p = result.scene.params
    print(f"scene          {result.scene.name}: {result.scene.description}".rstrip())
    print(f"model          {result.model}" + (f"  ({result.choice.reason})" if result.choice else ""))
    print(f"integrator     {result.method}, dt={result.dt:g} s" + (" (vectorized open-loop path)" if result.vectorized else ""))
    if result.stability is not None:
        print(f"stability      {result.stability.describe()}")
    print(f"belt mode      {p.belt_natural_frequency / (2 * math.pi):.1f} Hz, damping ratio {p.belt_damping_ratio:.4f}")
    print(f"simulated      {result.time[-1] - result.time[0]:g} s in {result.wall_time * 1e3:.1f} ms ({result.realtime_factor:,.0f}x real time)")
    print(f"final speed    {o['omega_M'][-1]:.3f} rad/s ({o['omega_M'][-1] * rpm:.1f} rpm) at wheel M")
    print(f"load torque    {o['load_torque'][-1]:.3f} N m (final), belt torque {o['belt_torque'][-1]:.3f} N m")
    print(
        f"deflection     final {o['relative_deflection'][-1]:.5g} rad, peak {o['relative_deflection'].max():.5g} rad, "
        f"static M_L/(2 k r_3^2) {o['load_torque'][-1] / p.belt_torsional_stiffness:.5g} rad"
    )
    slip = float(o["slip"].mean())
    if result.model == "slipping":
        onsets = sum(1 for e in result.events if e[0] == "onset")
        print(
            f"belt           slips {100 * slip:.1f}% of the time ({onsets} slip phases, peak slip speed "
            f"{np.max(np.abs(o['slip_speed'])):.3g} m/s); wheel 3 lost {o['slip_angle'][-1]:.4g} rad to slip "
            f"(elastic deflection {o['elastic_deflection'][-1]:.4g} rad at the end)"
        )
    else:
        print(f"belt           {'slips or slackens ' + format(100 * slip, '.1f') + '% of the time (linear model outside validity)' if slip else 'no slip, no slack'}")
