"""``belt-drive modes SCENE``: natural frequencies, damping and mode shapes of a belt network; the Campbell diagram."""

from __future__ import annotations

import math
import os
import sys


def register(sub) -> None:
    p = sub.add_parser(
        "modes", help="natural frequencies, damping and mode shapes of a belt network; --campbell plots them",
        description="Linearise a belt network (kind: network) at its operating point and print each vibration mode: "
                    "frequency, damping ratio and which pulleys and the tensioner arm move. --campbell draws the "
                    "frequencies against engine speed with the engine's firing orders and marks the crossings.")
    p.add_argument("scene", help="shipped network scene (e.g. fead_i4) or a YAML file with kind: network")
    p.add_argument("--speed", type=float, help="driver speed [rad/s] of the operating point (default: the scene's)")
    p.add_argument("--campbell", metavar="PNG", help="write the Campbell diagram to this PNG")
    p.add_argument("--points", type=int, default=60, help="engine speeds in the Campbell diagram (default 60)")
    p.add_argument("--runup", metavar="PNG", help="run the engine up through its speed range and chart the span "
                   "tensions and the tensioner arm against crank speed to this PNG")
    p.add_argument("--runup-time", type=float, default=4.0, metavar="S",
                   help="seconds the run-up takes from the bottom to the top of the engine's speed range (default 4)")
    p.add_argument("--force", action="store_true", help="replace an existing PNG")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core.errors import SceneError
    from ..core.network.model import NetworkModel, modes
    from ..io.scenes import load_network

    scene = load_network(args.scene)
    if args.speed is not None and not (math.isfinite(args.speed) and abs(args.speed) <= 1.0e4):
        raise SceneError(f"--speed: a finite driver speed within +-1e4 rad/s, got {args.speed!r}")
    if not 3 <= args.points <= 2000:
        raise SceneError(f"--points: 3 .. 2000, got {args.points}")
    from ..io.atomic import OutputRefused, check_output
    from ..io.inputs import input_replaced

    for option, path, what in (("--campbell", args.campbell, "Campbell plot"), ("--runup", args.runup, "run-up chart")):
        if path:
            if input_replaced(path, [args.scene]) is not None:
                raise OutputRefused(f"{option} {path}: would replace the scene file {args.scene}, which this run reads; "
                                    "write elsewhere")
            check_output(path, args.force, what)
            if not path.lower().endswith(".png"):
                raise OutputRefused(f"{option} {path}: the chart is a PNG; give a .png path")
    if args.campbell and args.runup and os.path.abspath(args.campbell) == os.path.abspath(args.runup):
        raise OutputRefused("--campbell and --runup name the same file")
    if args.runup and not (math.isfinite(args.runup_time) and 0.1 <= args.runup_time <= 600.0):
        raise SceneError(f"--runup-time: 0.1 .. 600 s, got {args.runup_time!r}")
    if args.runup:
        from .network_sim import check_samples

        check_samples("--runup-time", args.runup_time, scene.dt)  # (as sim's: a run holds every sample in memory)
    model = NetworkModel.build(scene)
    speed = scene.operating_speed if args.speed is None else args.speed
    names = [p.name for p in scene.pulleys] + (["tensioner_arm"] if scene.tensioner else [])
    print(f"# {scene.name}: modes at driver speed {speed:g} rad/s ({speed * 30 / math.pi:.0f} rpm)")
    from ..core.network.model import operating_limits

    for problem in operating_limits(model, speed):  # the linearisation holds only while the belt holds
        print(f"warning: at this operating point {problem}: the modes below assume a belt that neither slackens nor "
              "slips there", file=sys.stderr)
    print(f"{'mode':>4s} {'f [Hz]':>9s} {'f_n [Hz]':>9s} {'zeta':>7s}  moves (belt-direction amplitude, largest = 1)")
    for k, md in enumerate(modes(model, speed), start=1):
        movers = sorted(range(len(names)), key=lambda i: -abs(md.shape[i]))
        text = ", ".join(f"{names[i]} {md.shape[i]:+.2f}" for i in movers if abs(md.shape[i]) >= 0.3)
        print(f"{k:4d} {md.frequency:9.2f} {md.natural:9.2f} {md.damping_ratio:7.3f}  {text}")
    if args.campbell:
        from ..core.network.campbell import campbell
        from ..io.atomic import atomic_output
        from ..io.network_plot import plot_campbell

        data = campbell(model, points=args.points)
        for c in data.crossings:
            print(f"crossing: mode {c.mode} with order {c.order:g} at {c.speed * 30 / math.pi:.0f} rpm, {c.frequency:.1f} Hz")
        with atomic_output(args.campbell, args.force, what="Campbell plot") as fh:
            plot_campbell(data, fh, f"{scene.name}: Campbell diagram")
        print(f"wrote {args.campbell}")
    if args.runup:
        runup(args, scene, model)
    return 0


def runup_scene(label: str, scene, model, seconds: float):
    """The scene with the crank run up: from the bottom of the engine's speed range, its drive replaced by the
    engine's firing pulsations on a constant mean torque that takes the belt to the top of the range in about
    ``seconds``: ``T = J_eff (w_hi - w_lo) / seconds + (the accessories' loads at the crank, mean over the range)``,
    ``J_eff = sum_i J_i (r_d / r_i)^2`` (the belt turning every pulley without stretch)."""
    import numpy as np

    from ..io.inputs import parse_yaml
    from ..core.network.scene import NetworkScene
    from ..io.network_bag import scene_text

    lo, hi = scene.engine.speed_range
    d = scene.driver
    ratio = model.speeds_at(1.0)  # omega_i per unit crank speed: r_d / r_i
    j_eff = sum(p.inertia * ratio[i] ** 2 for i, p in enumerate(scene.pulleys))
    loads = sum(model.operating_loads(w) for w in np.linspace(lo, hi, 9)) / 9.0  # mean over the range
    reflected = -sum(loads[i] * ratio[i] for i in range(len(scene.pulleys)) if i != d)
    data = dict(parse_yaml(scene_text(label), label))
    pulleys = [dict(p) for p in data["pulleys"]]
    old = pulleys[d].get("torque") or {}
    pulleys[d]["torque"] = {"type": "engine", "cylinders": scene.engine.cylinders, "strokes": scene.engine.strokes,
                            "mean_torque": j_eff * (hi - lo) / seconds + reflected,
                            "harmonics": list(old.get("harmonics", [])) if old.get("type") == "engine" else []}
    data.update(pulleys=pulleys, initial_speed=lo, duration=seconds, name=f"{scene.name}_runup")
    return NetworkScene.from_mapping(data, name=f"{scene.name}_runup")


def runup(args, scene, model) -> None:
    """``--runup``: the run-up's span tensions and arm angle against crank speed (summary printed, chart written)."""
    import numpy as np

    from ..core.network.simulate import simulate
    from ..io.atomic import atomic_output
    from ..io.network_plot import plot_runup

    ramp = runup_scene(args.scene, scene, model, args.runup_time)
    run = simulate(ramp, model="flexible")
    rpm = run.speed[:, ramp.driver] * 30.0 / math.pi
    print(f"# run-up {rpm[0]:.0f} -> {rpm[-1]:.0f} rpm in {ramp.duration:g} s (crank mean torque "
          f"{ramp.pulleys[ramp.driver].torque.mean_torque:.1f} N m, {scene.engine.cylinders} cylinders)")
    for j, span in enumerate(ramp.span_names()):
        k = int(np.argmax(run.tension[:, j]))
        print(f"span {span:30s} {run.tension[:, j].min():8.1f} .. {run.tension[:, j].max():8.1f} N "
              f"(max at {rpm[k]:.0f} rpm){'  SLACK' if run.slack[:, j].any() else ''}")
    if run.arm_angle is not None:
        a = np.degrees(run.arm_angle)
        print(f"tensioner arm {a.min():.3f} .. {a.max():.3f} deg (swing {np.ptp(a):.3f} deg, widest near "
              f"{rpm[int(np.argmax(np.abs(a - a.mean())))]:.0f} rpm)")
    onset = run.capstan_onset(ramp)
    if onset:
        print(f"capstan limit: {onset[0]} reaches it first at {rpm[int(round(onset[1] / ramp.dt))]:.0f} rpm")
    with atomic_output(args.runup, args.force, what="run-up chart") as fh:
        plot_runup(ramp, run, fh)
    print(f"wrote {args.runup}")
