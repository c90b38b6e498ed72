"""``belt-drive sim``: run a scene offline, write CSV/MCAP and the paper's panels."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from ..core.scene import MODELS

EPILOG = """\
examples:
  belt-drive sim paper --plot paper.png --out paper.csv
  belt-drive sim truck_compressor --model flexible --method rk4 --dt 2e-4
  belt-drive sim my_scene.yaml --duration 10 --out run.mcap
  belt-drive sim paper --method RK45 --method-option rtol=1e-8
  belt-drive sim rec.mcap --out re.mcap     # re-simulate a recording; msg-tools compare rec.mcap re.mcap

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


def _positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text[:40]!r}")
    return value


def register(sub) -> None:
    from ..core.integrators import describe_methods  # the method registry (numpy only; scipy loads on use)

    p = sub.add_parser(
        "sim",
        help="simulate a scene offline (no ROS needed)",
        description="Simulate a scene offline and print a summary; optionally write CSV/MCAP and a PNG.",
        epilog=EPILOG + "\nintegrators (--method; default: the scene's):\n" + describe_methods() + "\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scene", help="shipped scene name, path to a scene YAML, or a recording (.mcap or bag folder) "
                                 "to re-simulate from its own scene record")
    p.add_argument(
        "--model", choices=MODELS,
        help="belt model (default: the scene's, usually auto; auto goes on to slipping past the friction limit)",
    )
    p.add_argument("--method", help="integrator by name (list below), or auto: the cheapest method and fewest substeps "
                                    "the accuracy guard rates within --tolerance (default: the scene's; a scene that "
                                    "names none: auto)")
    p.add_argument("--tolerance", type=float, metavar="REL",
                   help="relative error of drive speed and belt torque (to their peaks) the accuracy guard checks "
                        "and --method auto aims at (default: the scene's, 1e-4)")
    p.add_argument("--method-option", action="append", default=[], metavar="KEY=VALUE", help="integrator option, e.g. rtol=1e-8 (repeatable)")
    p.add_argument("--dt", type=float, help="integrator step [s] (output interval for adaptive methods)")
    p.add_argument("--duration", type=float, help="simulated time [s]")
    p.add_argument("--out", type=Path, help="write the run: .csv, or .mcap (ROS 2 bag); by extension, any case")
    p.add_argument("--plot", type=Path, help="PNG with the paper's panels, rigid and flexible overlaid")
    p.add_argument("--torque-bag", type=Path,
                   help="drive the model with the torque recorded in this MCAP: drive_torque_applied where the "
                        "file has it (a node recording: the torque the node applied), else drive_torque; with a "
                        "recording as the scene: the torque bag it was driven by, when that is not next to it")
    p.add_argument("--torque-topic", metavar="TOPIC",
                   help="the topic of --torque-bag to read (std_msgs/Float64), e.g. /truck2/drive_torque where the "
                        "bag holds several drives (default: as --torque-bag says)")
    p.add_argument("--force", action="store_true",
                   help="overwrite existing outputs (--out and --plot; never a file the run reads); a bag folder's "
                        "old bag is kept in a hidden .OUT.*.old beside it until the new one is whole (a run killed "
                        "outright leaves it there: the next run into OUT puts it back, or removes it once OUT's bag "
                        "is whole)")
    p.add_argument("--start-time", default=None, metavar="WHEN", type=_start_time,
                   help="time stamp of scene time 0 in an .mcap: 'now' (default, the wall time of the run, "
                        "as rosbag2 stamps it), seconds since the epoch (0: simulated time), or an ISO 8601 date")
    p.add_argument("--bag-folder", action="store_true",
                   help="write --out as a rosbag2 bag folder (OUT/OUT_0.mcap + metadata.yaml)")
    p.add_argument("--plot-every", type=_positive_int, default=1, metavar="N",
                   help="draw every Nth sample in --plot (a plot holds what it draws in memory; "
                        f"runs of more than {PLOT_SAMPLES:,} samples need it)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _refuse_idle_options(args) -> None:
    """An option that would change nothing of this command (its output not written) is a usage error, not ignored."""
    from ..core.errors import ParameterError

    mcap_out = args.out is not None and (args.bag_folder or args.out.suffix.lower() == ".mcap")
    if args.bag_folder and args.out is None:
        raise ParameterError("--bag-folder", "writes --out as a rosbag2 bag folder; give --out NAME")
    if args.plot_every != 1 and args.plot is None:
        raise ParameterError("--plot-every", "thins what --plot draws; give --plot FILE.png")
    if args.torque_topic is not None and args.torque_bag is None:
        raise ParameterError("--torque-topic", "names the topic of --torque-bag to read; give --torque-bag FILE")
    if args.torque_topic is not None and not args.torque_topic.strip("/"):
        raise ParameterError("--torque-topic", f"a topic name, got {args.torque_topic!r}")
    if args.start_time is not None and not mcap_out:
        raise ParameterError("--start-time", "stamps the messages of an MCAP output; --out is "
                             + ("not given" if args.out is None else f"{args.out.name}, not one"))


def _options(pairs):
    from ..core.errors import IntegratorError, short

    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise IntegratorError(f"--method-option expects KEY=VALUE, got {short(pair)}")
        if key in out:
            raise IntegratorError(f"--method-option {key[:80]}: given twice")
        try:
            out[key] = float(value) if key not in ("max_iter",) else int(value)
        except ValueError:
            what = "not a whole number" if key == "max_iter" else "not a number"
            raise IntegratorError(f"--method-option {short(key)}: {what}: {short(value)}") from None
    return out


#: runs with more samples than this stream (window by window, bounded memory); fewer: in memory (~300 B/sample)
STREAM_ABOVE = 250_000
#: most samples a plot takes (a plot holds every sample it draws in memory)
PLOT_SAMPLES = 250_000


def run(args) -> int:
    from ..io import is_recording  # a path check: mcap and msg_tools load only for a recording

    _refuse_idle_options(args)
    args.writer_options = {}
    if is_recording(args.scene) and args.torque_topic is not None:
        from ..core.errors import ParameterError

        raise ParameterError("--torque-topic", "a recording re-simulates from the torque topic its scene record names")
    if is_recording(args.scene):  # a recording re-simulated from its own scene record
        from ..io.network_bag import is_network_recording

        if is_network_recording(args.scene):  # a belt network node's recording (commands/network_sim.py)
            from .network_sim import resimulate

            return resimulate(args)
        scene = _resimulation(args)
    else:
        from ..io.scenes import is_network

        if is_network(args.scene):  # a belt network: its own run (commands/network_sim.py)
            from .network_sim import run_network

            return run_network(args)
        from ..io.scenes import load_either_scene

        scene = load_either_scene(args.scene)  # (an unknown name: the belt networks listed too)
    if args.method_option:
        scene = scene.with_overrides(method_options=_options(args.method_option))
    if args.torque_bag is not None and not is_recording(args.scene):  # (a recording's: read by _resimulation)
        from ..io.resimulate import torque_topic
        from ..io.torque_bag import torque_bag_scene  # offline replay of a recorded profile

        # a node recording: the torque it applied, unless a topic is named
        topic, note = (args.torque_topic, "") if args.torque_topic else torque_topic(args.torque_bag)
        if note:
            print(note)
        scene = torque_bag_scene(scene, args.torque_bag, topic=topic, duration=args.duration,
                                 streamed=lambda s: _samples(s.with_overrides(dt=args.dt, duration=args.duration)) > STREAM_ABOVE)
    scene = scene.with_overrides(model=args.model, method=args.method, dt=args.dt, duration=args.duration,
                                 tolerance=getattr(args, "tolerance", None))  # fmt: skip
    if args.torque_bag is not None and not is_recording(args.scene):  # what the drive holds where the bag is silent
        from ..io.torque_bag import silence_note, tail_note

        for note in (silence_note(scene.drive), tail_note(scene.drive, scene.duration)):
            if note:
                print(note)
    if args.start_time is not None:  # (mcap loads for an MCAP output only)
        from ..io.recording import check_stamp_span

        check_stamp_span(args.start_time, scene.duration)
    out_format = check_outputs(args, run_inputs(args, scene))
    if out_format == "mcap":
        from ..io.recording import output_rate_note

        note = output_rate_note(scene.dt, scene.output_rate)
        if note:
            print(note)
    if out_format != "mcap" or not args.bag_folder:
        return _run(scene, args, out_format)
    from ..io import holds_bag
    from ..io.atomic import OutputRefused
    from ..io.bag_folder import bag_folder_lock, settle_set_aside

    with bag_folder_lock(args.out):  # one run at a time into a bag folder: a second one is told who holds it
        for line in settle_set_aside(args.out):  # a bag a killed --force run set aside: back, or gone if replaced
            print(f"belt-drive: {line}", file=sys.stderr)
        if not args.force and holds_bag(args.out):  # refused before the run, not after it (the writer's rule)
            raise OutputRefused(f"--out {args.out} exists and holds a bag; pass --force to overwrite it")
        return _run(scene, args, out_format)


def _run(scene, args, out_format) -> int:
    """Run ``scene``, in memory or streamed by its length, into the outputs :func:`check_outputs` accepted."""
    from ..io.progress import ProgressBar

    samples = _samples(scene)
    check_plot_size(args, samples)
    bar = ProgressBar(f"sim {scene.name}", force=False) if not args.quiet else None
    if samples <= STREAM_ABOVE:
        return _run_in_memory(scene, args, out_format, bar)
    if not args.quiet:  # a long run: say up front what it will write and take
        from ..io.progress import estimate_run

        print(estimate_run(scene, out_format).describe(f"sim {scene.name}", args.out), file=sys.stderr, flush=True)
        bar = ProgressBar(f"sim {scene.name}", force=False)  # timed from here, not from before the trials
    return _run_streamed(scene, args, out_format, bar)


def _samples(scene) -> float:
    """Samples of a run of ``scene`` (the grid's knots)."""
    return scene.duration / scene.dt + 1.0


def _resimulation(args):
    """The scene of the recording ``args.scene``; ``args.writer_options`` make ``--out`` comparable with it
    (same start time, one sample per tick, the recorded inputs passed through)."""
    from ..io.recording import FLOAT_OUTPUTS, ROBOT_DESCRIPTION, SLIP_FLOAT_OUTPUTS, TF_TOPIC
    from ..io.resimulate import resimulation

    computed = (ROBOT_DESCRIPTION, "joint_states", TF_TOPIC) + tuple(n for n, _ in FLOAT_OUTPUTS + SLIP_FLOAT_OUTPUTS)
    resim = resimulation(args.scene, computed=computed, torque_bag=args.torque_bag)
    args.writer_options = {"namespace": resim.namespace, "drive_topic": resim.drive_topic,
                           "passthrough": resim.passthrough, "output_rate": resim.output_rate, "stamps": resim.stamps,
                           "topics": resim.topics}
    if args.start_time is None and resim.start_time_ns is not None:
        args.start_time = resim.start_time_ns  # the recording's time stamps, so the files line up
    drive = getattr(resim.scene.drive, "topic", "the scene's profile")
    print(f"re-simulating {args.scene} from its scene record (drive torque: {drive}; "
          f"{len(resim.passthrough)} more recorded topic(s) copied to --out as recorded)")
    return resim.scene


def check_plot_size(args, samples: float) -> None:
    """Refuse up front a plot of more than :data:`PLOT_SAMPLES` samples, offering ``--plot-every``."""
    from ..io.atomic import OutputRefused

    if args.plot is None or samples / args.plot_every <= PLOT_SAMPLES:
        return
    every = math.ceil(samples / PLOT_SAMPLES)
    raise OutputRefused(
        f"--plot: a plot holds every sample it draws in memory and this run has {samples:.3g} "
        f"(~{samples * 300 / 2**30:.2g} GiB with both models); pass --plot-every {every} (or more) to draw every "
        f"{_ordinal(every)} sample, or plot a shorter --duration (--out streams at full rate)"
    )


def _ordinal(n: int) -> str:
    """``n`` as an English ordinal: 2nd, 3rd, 11th, 21st."""
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def _write_plot(scene, runs, args) -> None:
    from ..io.atomic import atomic_output
    from ..io.plotting import plot_runs

    runs = sorted(runs, key=lambda r: r.model != "rigid")
    models = " vs ".join(dict.fromkeys(r.model for r in runs))
    with atomic_output(args.plot, args.force, "wb", what="--plot") as f:
        plot_runs(runs, f, title=f"scene '{scene.name}': {models} belt"
                  + (f" (every {_ordinal(args.plot_every)} sample)" if args.plot_every > 1 else ""))
    print(f"wrote {args.plot}")


def _run_in_memory(scene, args, out_format, bar) -> int:
    from ..core.simulate import simulate
    from ..io.atomic import atomic_output
    from ..io.run_writers import Decimator, RunSummary

    result = simulate(scene, progress=bar)
    print_summary(RunSummary().add(result))
    if args.out is not None:
        from ..io.recording import output_rate_note, write_result_mcap

        if out_format == "mcap" and result.dt != scene.dt:  # method auto took substeps: said for the step it ran
            note = output_rate_note(result.dt, float(args.writer_options.get("output_rate") or scene.output_rate))
            if note:
                print(note)

        if out_format == "mcap" and args.bag_folder:
            from ..io import holds_bag
            from ..io.bag_folder import bag_folder_kept, remove_bag_folder

            had_bag = holds_bag(args.out)
            try:
                with bag_folder_kept(args.out, args.force):  # (--force: the old bag back if this write fails)
                    write_result_mcap(result, args.out, force=args.force, start_time_ns=args.start_time, bag_folder=True,
                                      **args.writer_options)
            except BaseException:  # a failed or interrupted write leaves no partial bag behind
                if not had_bag:  # (an existing bag: refused untouched without --force, put back with it)
                    remove_bag_folder(args.out)
                raise
        elif out_format == "mcap":
            with atomic_output(args.out, args.force, "wb", what="--out") as f:
                write_result_mcap(result, f, start_time_ns=args.start_time, **args.writer_options)
        else:
            with atomic_output(args.out, args.force, "w", what="--out") as f:
                result.to_csv(f)
        print(f"wrote {args.out}")
    if args.plot is not None:
        from ..core.simulate import simulate as run_other

        other, method = _overlay_method(scene, result.model, result.method, result.dt)
        comp = run_other(scene, model=other, method=method, dt=result.dt)
        runs = []
        for run in (result, comp):
            keep = Decimator(args.plot_every)
            keep.add(run)
            runs.append(keep.result() if args.plot_every > 1 else run)
        _write_plot(scene, runs, args)
    return 0


def _run_streamed(scene, args, out_format, bar) -> int:
    """The run window by window (:func:`belt_drive_ros.core.stream.stream`): outputs written as it goes."""
    import contextlib

    from ..core.stream import Restart, stream
    from ..io.atomic import atomic_output, raise_if_interrupted
    from ..io.bag_folder import bag_folder_kept
    from ..io.run_writers import CsvWindows, Decimator, McapWindows, RunSummary

    summary = RunSummary()
    keep = Decimator(args.plot_every) if args.plot is not None else None
    with contextlib.ExitStack() as stack:
        sinks = []
        if args.out is not None and out_format == "mcap" and args.bag_folder:
            stack.enter_context(bag_folder_kept(args.out, args.force))  # (--force: the old bag back if interrupted)
            sinks.append(McapWindows(args.out, bag_folder=True, force=args.force, start_time_ns=args.start_time,
                                     **args.writer_options))
        elif args.out is not None:
            f = stack.enter_context(atomic_output(args.out, args.force, "wb" if out_format == "mcap" else "w", what="--out"))
            sinks.append(McapWindows(f, start_time_ns=args.start_time, **args.writer_options)
                         if out_format == "mcap" else CsvWindows(f))
        try:
            for window in stream(scene, progress=bar):
                if isinstance(window, Restart):
                    summary = RunSummary()
                    for sink in sinks + ([keep] if keep else []):
                        sink.restart()
                    continue
                summary.add(window)
                for sink in sinks + ([keep] if keep else []):
                    sink.add(window)
                raise_if_interrupted()  # (a signal whose exception some code swallowed stops the run here)
            for sink in sinks:
                sink.close()
        except BaseException:
            for sink in sinks:
                if hasattr(sink, "abort"):
                    sink.abort()
            raise
    print_summary(summary)
    if args.out is not None:
        print(f"wrote {args.out}")
    if keep is not None:
        other, method = _overlay_method(scene, summary.model, summary.method, summary.dt)
        comp = Decimator(args.plot_every)
        for window in stream(scene, model=other, method=method):
            comp.add(window)
            raise_if_interrupted()  # (a second run as long as the first: stopped here too, not at the plot's write)
        _write_plot(scene, [keep.result(), comp.result()], args)
    return 0


#: --out formats by extension (compared case-insensitively)
OUT_FORMATS = {".csv": "csv", ".mcap": "mcap"}


def run_inputs(args, scene) -> list:
    """The files a run reads: the scene file or recording, the torque bag (given, or the one a recording names)."""
    drive = getattr(scene, "drive", None)
    return [args.scene, args.torque_bag, getattr(drive, "_bag", None) or getattr(drive, "source", None) or None]


def check_outputs(args, inputs=()) -> str | None:
    """Refuse bad outputs before the run; return the --out format (``csv``/``mcap``) or None.

    The format follows the extension, case-insensitively (``run.MCAP`` is
    MCAP); an unknown one is an error. ``--force`` governs every output, the
    plot included; devices, FIFOs and directories are refused
    (:func:`belt_drive_ros.io.atomic.check_output`), and so is an output that would replace one of ``inputs``
    (:func:`belt_drive_ros.io.inputs.input_replaced`), --force or not.
    """
    from ..io.atomic import OutputRefused, check_output, check_writable_folder
    from ..io.inputs import input_replaced

    for option, path in (("--out", args.out), ("--plot", args.plot)):
        replaced = None if path is None else input_replaced(path, inputs, folder=path is args.out and args.bag_folder)
        if replaced is not None:
            raise OutputRefused(f"{option} {path}: would replace {replaced}, which this run reads; write elsewhere")
    out_format = None
    if args.out is not None:
        if args.bag_folder:
            out_format = "mcap"
            if args.out.exists() and not args.out.is_dir():
                raise OutputRefused(f"--out {args.out}: exists and is not a folder (--bag-folder writes a folder)")
            parent = args.out.absolute().parent
            if not parent.is_dir():  # (as for a file: the bag's own folder is made, never its parents)
                raise OutputRefused(f"--out {args.out}: folder {parent} does not exist")
            if not args.out.is_dir():  # (the bag's own folder and its lock file are made there)
                check_writable_folder(parent, f"--out {args.out}", args.out.name)
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


def _overlay_method(scene, model: str, method: str, dt: float) -> tuple[str, str]:
    """The other model for the plot overlay and its method: the run's where that is stable.

    A step that is stable for the rigid model may not be for the flexible one
    (its belt mode); the overlay then falls back to ``etd2`` and says so
    (the legend names the method) rather than failing a valid run.
    """
    from ..core.model import make_model
    from ..core.stability import check_step

    other = "flexible" if model == "rigid" else "rigid"
    report = check_step(make_model(other, scene.params).A, make_model(other, scene.params).B, method, dt)
    if not report.stable:
        print(f"note: overlay {other} model uses etd2: {report.describe()}")
        method = "etd2"
    return other, method


def print_summary(summary) -> None:
    """Short human summary of a run (:class:`~belt_drive_ros.io.run_writers.RunSummary`; rpm for people, SI otherwise)."""
    from ..core.integrators import method_class

    rpm = 60.0 / (2.0 * math.pi)
    o = summary.final
    scene = summary.scene
    p = scene.params
    print(f"scene          {scene.name}: {scene.description}".rstrip())
    print(f"model          {summary.model}" + (f"  ({summary.choice.reason})" if summary.choice else ""))
    print(f"integrator     {summary.method}, dt={summary.dt:g} s")
    choice = getattr(summary, "method_choice", None)
    if choice is not None:
        print(f"method choice  {choice.reason}")
    if summary.stability is not None:
        print(f"stability      {summary.stability.describe()}")
    if summary.accuracy is not None:
        print(f"accuracy       {summary.accuracy.describe()}")
        if not summary.accuracy.accurate:
            print(f"warning: {summary.accuracy.describe()}", file=sys.stderr)
    elif not (cls := method_class(summary.method)).fixed_step:  # no guard rates an adaptive method: said, not silent
        opts = {"rtol": cls.RTOL, "atol": cls.ATOL, **(scene.method_options or {})}
        print(f"accuracy       not rated: {summary.method} is adaptive (rtol {opts['rtol']:g}, atol {opts['atol']:g} "
              f"bound each step's local error, not the run's; the tolerance {scene.tolerance:g} is checked for "
              "fixed-step methods only)")
    if choice is not None and not choice.met and (summary.accuracy is None or summary.accuracy.accurate):
        # method auto found no candidate within the tolerance: said even where the run's own check rates it accurate
        print(f"warning: method auto: {choice.reason}", file=sys.stderr)
    init = scene.initial_state
    if summary.model == "rigid" and (init.relative_deflection or init.relative_speed):
        print(f"warning: the rigid model has no belt deflection: initial_state.relative_deflection "
              f"{init.relative_deflection:g} rad and relative_speed {init.relative_speed:g} rad/s are not used (wheel 3 "
              "starts at i phi_M, i omega_M; --model flexible starts from them)", file=sys.stderr)
    print(f"belt mode      {p.belt_natural_frequency / (2 * math.pi):.1f} Hz, damping ratio {p.belt_damping_ratio:.4f}")
    print(f"simulated      {summary.t_end - summary.t_start:g} s in {summary.wall_time * 1e3:.1f} ms ({summary.realtime_factor:,.0f}x real time)")
    print(f"final speed    {o['omega_M']:.3f} rad/s ({o['omega_M'] * rpm:.1f} rpm) at wheel M")
    print(f"load torque    {o['load_torque']:.3f} N m (final), belt torque {o['belt_torque']:.3f} N m")
    print(
        f"deflection     final {o['relative_deflection']:.5g} rad, peak {summary.peak_deflection:.5g} rad, "
        f"static M_L/(2 k r_3^2) {o['load_torque'] / p.belt_torsional_stiffness:.5g} rad"
    )
    slip = summary.slip_fraction
    if summary.model == "slipping":
        print(
            f"belt           slips {100 * slip:.1f}% of the time ({summary.onsets} slip phases, peak slip speed "
            f"{summary.peak_slip_speed:.3g} m/s); wheel 3 lost {o['slip_angle']:.4g} rad to slip "
            f"(elastic deflection {o['elastic_deflection']:.4g} rad at the end)"
        )
    else:
        print(f"belt           {'slips or slackens ' + format(100 * slip, '.1f') + '% of the time (linear model outside validity)' if slip else 'no slip, no slack'}")
