"""``belt-drive bench``: regenerate the benchmark charts and tables (``make bench``)."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from ..benchmarks.campaign import SAMPLES as CAMPAIGN_SAMPLES
from ..benchmarks.campaign import SCALING_SAMPLES as CAMPAIGN_SCALING_SAMPLES

STUDIES = ("workprecision", "stability", "fidelity", "versus", "slip")

EPILOG = f"""\
studies:
  workprecision  error vs CPU time, every integrator on every scene (Pareto front, default marked),
                 truck_compressor on the slipping model among them (regularised friction beside)
  stability      where fixed-step methods diverge: measured vs the stability guard's prediction,
                 and on the slipping scene per method and friction law
  fidelity       rigid vs flexible model error vs excitation frequency and belt stiffness;
                 linear vs slipping model as the load passes the capstan limit
  versus         default method vs scipy solve_ivp RK45 at matched accuracy; x real time per scene; whole
                 warm simulate() per shipped scene and paper vs the user's whole RK45 call at error 1e-6 (first)
  slip           a harder stick-slip case: event-driven hybrid vs step-end switching vs regularised
  node           the ROS node's real-time figures (needs the ROS extra)
  node-tick      the node's tick compute in-process on cold caches: the compiled common tick beside the
                 general path (Stepper.advance + model outputs), paper and slipping truck_compressor (not in 'all')
  soak           the node recording for --seconds (default 60): RSS growth per minute,
                 output rate per 10 s window, messages lost (not part of 'all')
  hostile        the hostile-input table: ~1,800 scene files, command lines, damaged MCAP files,
                 campaign files, bag folders and node inputs, each a clean error, ok, data lost,
                 silent wrong, crash or hang (hostile.csv, hostile.md; not part of 'all';
                 --only CATEGORY... for some of them)
  kernel         the compiled time loop: ns per step (kernel vs plain CPython vs C -O2), methods vs exact,
                 whole warm simulate() x real time, start-up CPU of 'belt-drive sim paper --quiet' (not in 'all')
  network        belt networks: fead_i4 whole warm simulate() x real time beside the Python step loop it
                 replaced, ns per step per method, the paper's drive as a network vs the paper model (not in 'all')
  replay         a 1-hour 1 kHz torque bag replayed offline to MCAP (--minutes; default 60): wall time
                 split into reading, simulation and writing, CPU, peak memory (not in 'all')
  slip-kernel    the slipping belt's compiled hybrid loop: truck_compressor whole warm simulate() x real
                 time, its run, accuracy rerun, node tick (not in 'all')
  campaign       {CAMPAIGN_SAMPLES:,}-variant Monte Carlo of paper (--samples) on Dask vs a loop of single runs,
                 1 vs 2 workers ({CAMPAIGN_SCALING_SAMPLES:,} variants), a fleet of 100 recordings replayed and
                 compared (needs the campaign extra; not in 'all')
  network_slip   a belt network's slipping tier: x real time on fead_i4 sticking and slipping, the paper's
                 drive slipping; the node's tick (advance, sample) slipping beside flexible (not in 'all')
  compile        the numba kernels built from an empty cache (the tree's own cache untouched): each
                 function's build, every kernel in one process, warm(jobs=2) as 'make install' runs it
                 (a few minutes per tree; --quick: the torque dispatcher only; not in 'all')
  all            all of the above, then docs/bench/summary.md

examples:
  belt-drive bench all --out docs/bench          # what 'make bench' runs (a few minutes)
  belt-drive bench stability --out /tmp/b --quick
  belt-drive bench node --duration 30 --floor    # the node's figures beside its model-free floor
  belt-drive bench soak --seconds 600            # 10 minutes of the recording node
  belt-drive bench hostile --out /tmp/hostile    # the hostile-input table (minutes)
  belt-drive bench hostile --only campaign bagdir --out /tmp/hostile
  belt-drive bench kernel --out /tmp/k           # the compiled kernel's figures (a minute)
  belt-drive bench kernel --quick --baseline ../old   # ... whole simulate() beside another checkout (git worktree add ../old REV)
  belt-drive bench replay --minutes 60           # the 1-hour torque bag replayed to MCAP
  belt-drive bench replay --baseline ../old      # ... beside another checkout, in one run
  belt-drive bench compile --baseline ../old --out /tmp/c  # build times of both trees' kernels

Each study writes a CSV and a PNG into --out. CPU time is process time, the
minimum of repeats; BLAS runs single-threaded (OPENBLAS_NUM_THREADS=1) so that
CPU time is not inflated by idle BLAS threads. Definitions:
docs/performance.md and belt_drive_ros/benchmarks/common.py.
"""


def register(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmarks: work-precision, stability map, fidelity, vs scipy, node",
        description="Run the benchmark studies and write their CSV tables and PNG charts.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("study", choices=(*STUDIES, "node", "soak", "hostile", "campaign", "kernel", "network", "network_slip",
                                     "slip-kernel", "replay", "node-tick", "compile", "all"), help="which study to run")  # fmt: skip
    p.add_argument("--out", type=Path, help="output folder (default: docs/bench in the current folder; node prints its figures "
                   "and writes its tables only with --out; node-tick and replay print their figures and write nothing)")
    p.add_argument("--quick", action="store_true", help="small sweeps and short runs (seconds; for tests)")
    p.add_argument("--quiet", action="store_true", help="no per-run log lines")
    p.add_argument("--seconds", type=float, default=60.0, help="soak: measured seconds (default 60)")
    p.add_argument("--duration", type=float, default=30.0, help="node: measured seconds (default 30)")
    p.add_argument("--minutes", type=float, default=60.0, help="replay: minutes of 1 kHz torque bag (default 60)")
    p.add_argument("--baseline", metavar="DIR", help="replay, kernel, node-tick, compile: a checkout of another commit (its numba "
                   "cache warm; compile: its kernels built from an empty cache) measured beside this tree in the same run")
    p.add_argument("--samples", type=int, default=None,
                   help="campaign: variants of the Monte Carlo (default 100,000; --quick 2,000)")
    p.add_argument("--floor", action="store_true",
                   help="node: then measure the same process without the model (rclpy + DDS only) for comparison")
    p.add_argument("--only", nargs="+", metavar="CATEGORY",
                   help="hostile: only these categories (scene, cli, mcap, campaign, bagdir, sweep, node, setparameters, "
                   "fifo, truncated)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                   help="node: a node parameter (repeatable), e.g. -p model:=slipping")
    p.add_argument("--scene", help="node: the scene the node runs (default: -p scene:=X, else paper); the floor "
                   "publishes that scene's joint_states")
    p.set_defaults(func=run)


def _single_threaded_blas() -> str:
    """Pin BLAS to one thread before numpy loads; say what happened."""
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    if "numpy" in sys.modules:
        return "numpy was already imported: BLAS threads as configured by the environment"
    return f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}"


def _run_node(out: Path, quick: bool, extra: list[str] | None = None) -> int:
    import importlib

    try:  # written with the ROS node; imported lazily (rclpy only inside it)
        node = importlib.import_module("belt_drive_ros.benchmarks.node")
    except ModuleNotFoundError as exc:
        if exc.name != "belt_drive_ros.benchmarks.node":
            raise
        print("belt-drive bench: node benchmark not available (belt_drive_ros/benchmarks/node.py missing); skipped")
        return 0
    return int(node.main((["--out", str(out)] if out is not None else []) + (["--quick"] if quick else []) + list(extra or []))
               or 0)


def _checked_baseline(study: str, baseline: str | None) -> Path | None:
    """``--baseline DIR`` as a checkout's root, or a one-line :class:`InputError`: the option applies to
    ``replay``, ``kernel`` and ``node-tick`` only, and ``DIR`` must hold ``belt_drive_ros/__init__.py`` (else the child
    processes would import this tree's package and print this tree against itself)."""
    if baseline is None:
        return None
    from ..core.errors import InputError

    if study not in ("replay", "kernel", "node-tick", "compile"):
        raise InputError(f"--baseline applies to 'bench replay', 'bench kernel', 'bench node-tick' and 'bench compile', "
                         f"not 'bench {study}'")
    root = Path(baseline)
    if not (root / "belt_drive_ros" / "__init__.py").is_file():
        raise InputError(f"--baseline {baseline}: not a checkout of belt_drive_ros (no belt_drive_ros/__init__.py in it)")
    return root


#: largest value of each numeric option (a day of measuring, of 1 kHz bag; 10 million campaign variants)
OPTION_LIMITS = {"seconds": 86400.0, "duration": 86400.0, "minutes": 1440.0, "samples": 1.0e7}


def _check_options(args) -> None:
    """One :class:`InputError` line for a numeric option outside ``(0, limit]`` (nan, inf, <= 0 included) or an
    --out that is not a folder, before anything is measured."""
    from ..core.errors import InputError

    for name, top in OPTION_LIMITS.items():
        value = getattr(args, name)
        if value is not None and not 0 < value <= top:
            raise InputError(f"--{name}: must be > 0 and at most {top:g}, got {value!r}")
    if args.only:  # (hostile's own parser printed its usage block)
        from ..benchmarks.hostile import CATEGORIES

        unknown = [name for name in args.only if name not in CATEGORIES]
        if args.study != "hostile" or unknown:
            raise InputError(f"--only: categories of 'bench hostile' ({', '.join(CATEGORIES)}), got "
                             f"{(unknown or args.only)[0][:60]!r}" + ("" if args.study == "hostile" else f" for 'bench {args.study}'"))
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        raise InputError(f"--out {args.out}: exists and is not a folder")


def _check_node_options(args) -> None:
    """``bench node``'s -p (NAME:=VALUE) and its scene, checked before the node's child process starts (its exit
    was an internal error, exit 1)."""
    from ..core.errors import InputError
    from ..io.scenes import is_network, load_network, load_scene

    scenes = [args.scene] if args.scene is not None else []
    for param in args.param:
        name, sep, value = param.partition(":=")
        if not sep or not name.strip():
            raise InputError(f"-p {param[:80]!r}: a node parameter is NAME:=VALUE")
        scenes += [value.strip()] if name.strip() == "scene" else []
    for scene in scenes:
        (load_network if is_network(scene) else load_scene)(scene)


def run(args) -> int:
    args.baseline = _checked_baseline(args.study, args.baseline)
    _check_options(args)
    blas = _single_threaded_blas()
    if args.study == "node":  # (figures printed; node.csv and node.md only into a folder asked for)
        _check_node_options(args)
        extra = ["--duration", repr(args.duration)] + (["--floor"] if args.floor else [])
        extra += ["--scene", args.scene] if args.scene else []
        return _run_node(args.out, args.quick, extra + [a for param in args.param for a in ("-p", param)])
    if args.study == "node-tick":
        from ..benchmarks import node_tick

        return node_tick.main(quick=args.quick, baseline=args.baseline)
    if args.study == "replay":
        from ..benchmarks import replay

        return replay.main(args.minutes if not args.quick else 1.0, baseline=args.baseline)
    out: Path = args.out if args.out is not None else Path("docs/bench")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        from ..io.atomic import OutputRefused

        raise OutputRefused(f"--out {out}: cannot make the folder: {exc.strerror or exc}") from None
    print(f"bench {args.study}: writing into {out.resolve()}", flush=True)
    if args.study == "soak":
        from ..benchmarks import soak

        return soak.main(["--seconds", repr(args.seconds), "--out", str(out)]
                         + (["--warmup", "1", "--window", "1"] if args.quick else []))
    if args.study == "hostile":
        from ..benchmarks import hostile

        return hostile.main(["--out", str(out)] + (["--quick"] if args.quick else []) + (["--only", *args.only] if args.only else []))
    if args.study == "compile":
        from ..benchmarks import compile_time

        result = compile_time.run(out, quick=args.quick, baseline=args.baseline)
        print(f"bench compile: {result['csv']}")
        return 0
    if args.study == "kernel":
        from ..benchmarks import kernel

        result = kernel.run(out, quick=args.quick, quiet=args.quiet, baseline=args.baseline)
        print(f"bench kernel: {result['csv']}")
        return 0
    if args.study == "network_slip":
        from ..benchmarks import network_slip

        result = network_slip.run(out, quick=args.quick, quiet=args.quiet)
        print(f"bench network_slip: {result['csv']}")
        return 0
    if args.study == "network":
        from ..benchmarks import network

        result = network.run(out, quick=args.quick, quiet=args.quiet)
        print(f"bench network: {result['csv']}")
        return 0
    if args.study == "slip-kernel":
        from ..benchmarks import slip_kernel

        print(f"bench slip-kernel: {slip_kernel.run(out, quick=args.quick, quiet=args.quiet)['csv']}")
        return 0
    if args.study == "campaign":
        from ..benchmarks import campaign

        print("bench campaign: figures measured side by side in this run")
        result = campaign.run(out, quick=args.quick, quiet=args.quiet, samples=args.samples)
        print(f"bench campaign: {result['csv']}")
        return 0

    from ..benchmarks import fidelity_chart, report, slip_chart, stability_map, versus_scipy, workprecision

    modules = {
        "workprecision": workprecision,
        "stability": stability_map,
        "fidelity": fidelity_chart,
        "versus": versus_scipy,
        "slip": slip_chart,
    }
    todo = STUDIES if args.study == "all" else (args.study,)
    results, timings = {}, {}
    for name in todo:
        start = time.perf_counter()
        results[name] = modules[name].run(out, quick=args.quick, quiet=args.quiet)
        timings[name] = time.perf_counter() - start
        files = results[name]["csv"] if isinstance(results[name]["csv"], list) else [results[name]["csv"]]
        print(f"bench {name}: {', '.join(str(f) for f in [*files, results[name]['png']])} ({timings[name]:.0f} s)")
    status = 0
    if args.study == "all":
        try:
            status = _run_node(out, args.quick)
        except Exception as exc:  # the offline studies and their summary stand without the node
            print(f"belt-drive bench: node benchmark failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            status = 1
        path = report.write_summary(out, quick=args.quick, blas=blas, timings=timings)
        print(f"bench summary: {path}")
    return status
