"""``belt-drive demo``: the main job of ``make demo``.

1. Live: an engine torque source drives the belt-drive node over ROS 2 for a
   few seconds of real time (one process, two nodes, one events executor, a
   private ROS domain on loopback), then a summary: achieved tick rate and
   period error, final speed, load torque, peak belt deflection, the model
   chosen and why.
2. Offline: the paper scene (rigid and flexible), ``out/paper.csv`` and
   ``out/paper.png``.
3. Offline: the shipped serpentine FEAD (``fead_i4``): what each pulley,
   span and the tensioner arm did, and ``out/fead_i4.mcap`` (every topic the
   network node publishes, for Foxglove).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)


def register(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="the main job: engine source -> belt node live over ROS 2, then the paper scene offline (CSV + PNG)",
        description=(
            "Run an engine torque source and the belt-drive node together over ROS 2 for a few seconds of real "
            "time and print a summary; then simulate the 'paper' scene offline and write out/paper.csv and "
            "out/paper.png."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out-dir", type=Path, default=Path("out"), help="where to write (default: out/)")
    p.add_argument("--scene", default="truck_compressor", help="scene of the live run; its drive must be an engine (default truck_compressor)")
    p.add_argument("--duration", type=float, default=4.0, help="live run length [s of real time] (default 4)")
    p.add_argument("--executor", choices=("auto", "events", "single"), default="auto", help="rclpy executor (default auto: events)")
    p.add_argument("--no-live", action="store_true", help="skip the ROS part")
    p.add_argument("--no-offline", action="store_true", help="skip the offline paper scene")
    p.add_argument("--no-network", action="store_true", help="skip the serpentine FEAD (fead_i4)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core.errors import ParameterError
    from ..io.atomic import OutputRefused

    if args.no_live and args.no_offline and args.no_network:
        raise ParameterError("--no-live --no-offline --no-network", "all three parts skipped: nothing to run")
    if not args.no_live and not 0 < args.duration < float("inf"):  # refused before any node starts
        raise ParameterError("--duration", f"must be finite and > 0 s, got {args.duration!r}")
    if args.out_dir.exists() and not args.out_dir.is_dir():
        raise OutputRefused(f"--out-dir {args.out_dir}: exists and is not a folder")
    if not args.no_live:
        from ..core.errors import SceneError
        from ..io.scenes import load_scene

        drive = load_scene(args.scene).drive.kind  # (refused before any node starts, not after their start-up logs)
        if drive != "engine":  # (and before the output folder is made: a refused run leaves nothing behind)
            raise SceneError(f"--scene {args.scene[:80]}: the live run drives the belt by the scene's engine; its drive "
                             f"is a {drive!r} profile (an engine scene: truck_compressor)")
    if not (args.no_offline and args.no_network):  # (made before the live run: a folder that cannot be is refused now)
        try:
            args.out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputRefused(f"--out-dir {args.out_dir}: cannot make the folder: {exc.strerror or exc}") from None
    if not args.no_live:
        signum = live_run(args.scene, args.duration, args.executor).get("interrupted", 0)
        if signum:  # Ctrl-C or SIGTERM: the live summary is printed; the rest of the demo is not run
            import signal
            import sys

            print(f"belt-drive: demo: interrupted by {signal.Signals(signum).name} during the live run; the offline "
                  "parts were not run", file=sys.stderr)
            return 128 + int(signum)
    code = 0
    if not args.no_offline:
        from .sim import register as register_sim, run as run_sim

        print("\n== offline: the paper scene, rigid and flexible ==")
        # sim's own parser: its every option at its default (a Namespace written here missed the ones added later)
        parser = argparse.ArgumentParser(prog="belt-drive")
        register_sim(parser.add_subparsers(dest="command"))
        ns = parser.parse_args(["sim", "paper", "--out", str(args.out_dir / "paper.csv"),
                                "--plot", str(args.out_dir / "paper.png"), "--force"])
        code = run_sim(ns)
    if not args.no_network and code == 0:
        from .network_sim import demo_network

        print("\n== offline: the serpentine FEAD fead_i4 (belt network), what each pulley did ==")
        demo_network("fead_i4", args.out_dir / "fead_i4.mcap")
    return code


def belt_statement(summary: dict, tick_s: float) -> str:
    """What the belt did in the run, as the model computed it (one line)."""
    slip, slack = summary["slip_ticks"], summary["slack_ticks"]
    if summary["model"] == "slipping":
        if not summary["slip_events"]:
            return "stuck to its pulleys throughout (slipping model: the force stayed within the capstan limit)"
        return (
            f"slid on its pulley in {slip} ticks ({slip * tick_s:.3g} s) at the capstan limit, sticking otherwise: "
            f"{summary['slip_events']} stick/slip events located (slipping model); wheel 3 lost "
            f"{summary['slip_angle']:.4g} rad to slip"
        )
    if slip or slack:
        return (
            f"passes the capstan limit in {slip} ticks, slack in {slack} (the {summary['model']} model cannot "
            "show slip there; model 'slipping' or 'auto' can)"
        )
    return "no slip, no slack"


def live_run(scene_name: str = "truck_compressor", duration: float = 4.0, executor: str = "auto") -> dict:
    """Engine source -> belt node for ``duration`` s of real time; print and return the summary figures
    (``interrupted``: the signal that ended the run early, 0 when it ran its ``duration``)."""
    import time

    from ..ros import environment as ros_env

    ros_env.configure_environment(loopback=True)  # the demo keeps to this machine
    ros_env.limit_blas_threads()
    from ..ros.executors import executor_name, ros_session, spin_nodes

    domain = ros_env.process_domain_id()
    with ros_session(["belt-drive-demo"], domain_id=domain) as context:
        nodes = _live_nodes(scene_name, context)
        node = nodes[0]
        s = node.settings
        clock: dict = {}

        def started(ex) -> None:
            print(
                f"== live: engine source -> belt node over ROS 2, scene '{s.scene.name}', {duration:g} s of real "
                f"time ({executor_name(ex)} executor, ROS domain {domain}, loopback only) =="
            )
            clock.update(wall=time.perf_counter(), cpu=time.process_time(), ticks=node.counters["ticks"])

        def stopped(signum) -> None:
            clock.update(wall=time.perf_counter() - clock["wall"], cpu=time.process_time() - clock["cpu"])
            clock["summary"] = {**_summary(node, nodes[2].seen, clock), "interrupted": int(signum or 0)}

        spin_nodes(nodes, context, executor=executor, started=started, stopped=stopped, duration=duration)
    return clock["summary"]


def _live_nodes(scene_name: str, context) -> list:
    """[belt node, engine source, monitor] on ``context``; the monitor's ``seen`` collects outputs."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from ..core.errors import SceneError
    from ..ros.executors import destroy
    from ..ros.node import BeltDriveNode
    from ..ros.source_node import TorqueSourceNode

    nodes: list = []
    try:
        node = BeltDriveNode(
            scene=scene_name, context=context, parameter_overrides=[Parameter("input_timeout", value=0.5)]
        )
        nodes.append(node)
        s = node.settings
        if s.scene.drive.kind != "engine":
            raise SceneError(f"demo: scene '{s.scene.name}' has a {s.scene.drive.kind!r} drive, not an engine")
        nodes.append(TorqueSourceNode(
            s.scene.drive, context=context, rate_hz=s.step_rate_hz, initial_speed=s.scene.initial_state.omega_M
        ))
        monitor = Node("demo_monitor", context=context)
        monitor.seen = {"joints": [], "deflections": []}
        monitor.create_subscription(
            JointState, "joint_states",
            lambda m: monitor.seen["joints"].append((m.velocity[0], m.effort[0], -m.effort[3])), 100,
        )
        monitor.create_subscription(Float64, "relative_deflection", lambda m: monitor.seen["deflections"].append(m.data), 100)
        nodes.append(monitor)
    except BaseException:
        destroy(None, nodes)
        raise
    return nodes


def _summary(node, seen: dict, clock: dict) -> dict:
    """Print and return the live run's figures."""
    import numpy as np

    s = node.settings
    wall, cpu = clock["wall"], clock["cpu"]
    status = {st.name.split(": ")[-1]: st for st in node.diagnostic_status()}
    sim_values = {kv.key: kv.value for kv in status["simulation"].values}
    ticks = node.counters["ticks"] - clock["ticks"]
    last = node.last
    joints, deflections = seen["joints"], seen["deflections"]
    data = np.array(joints) if joints else np.zeros((0, 3))
    tail = data[-max(1, int(0.25 * len(data))):] if len(data) else data
    p = s.params
    summary = {
        "achieved_rate_hz": ticks / wall,
        "set_rate_hz": s.step_rate_hz,
        "period_error_ms": tuple(float(sim_values[f"period_error_ms_{q}"]) for q in ("p50", "p99", "max")),
        "overruns": node.counters["overruns"],
        "cpu_percent": 100.0 * cpu / wall,
        "final_speed": last.get("omega_M", math.nan),
        "load_torque": last.get("load_torque", math.nan),
        "mean_load_torque": float(tail[:, 2].mean()) if len(tail) else math.nan,
        "mean_drive_torque": float(tail[:, 1].mean()) if len(tail) else math.nan,
        "peak_deflection": float(np.max(np.abs(deflections))) if deflections else math.nan,
        "model": s.model.name,
        "model_reason": s.model_reason,
        "received": node.counters["received"],
        "published": node.counters["published"],
        "slip_ticks": node.counters["slip_ticks"],
        "slack_ticks": node.counters["slack_ticks"],
        "slip_events": node.counters.get("slip_events", 0),
        "slip_angle": float(last.get("slip_angle", 0.0)),
        "outputs_seen": len(joints),
    }
    w = summary["final_speed"]
    lo, p99, mx = summary["period_error_ms"]
    print(f"  node rate        {summary['achieved_rate_hz']:.1f} Hz achieved (set {s.step_rate_hz:g} Hz); "
          f"tick period error p50/p99/max {lo:.3f}/{p99:.3f}/{mx:.3f} ms; overruns {summary['overruns']}")
    print(f"  process CPU      {summary['cpu_percent']:.0f} % of one core (node + source + this monitor)")
    print(f"  model            {s.model_reason}")
    print(f"  integrator       {s.method}, dt={s.dt:g} s ({s.substeps} substep(s) per tick); {s.stability.describe()}")
    print(f"  drive torque     {summary['mean_drive_torque']:.2f} N m mean over the last quarter "
          f"(engine: {s.scene.drive.pulses_per_revolution:g} firing pulses per revolution, governor)")
    print(f"  final speed      {w:.2f} rad/s ({w * RPM_PER_RAD_S:.0f} rpm) at wheel M")
    print(f"  load torque      {summary['load_torque']:.2f} N m at wheel 3 (final), "
          f"{summary['mean_load_torque']:.2f} N m mean over the last quarter")
    print(f"  peak deflection  {summary['peak_deflection']:.5g} rad (i*phi_M - phi_3); static value at the final load "
          f"{summary['load_torque'] / p.belt_torsional_stiffness:.3g} rad; belt mode "
          f"{p.belt_natural_frequency / (2 * math.pi):.1f} Hz")
    print("  belt             " + belt_statement(summary, s.tick_ns / 1e9))
    print(f"  messages         {summary['received']} drive_torque received by the node, {summary['published']} output "
          f"sets published, {summary['outputs_seen']} joint_states seen by the monitor")
    return summary
