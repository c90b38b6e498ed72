"""``belt-drive modes SCENE``: natural frequencies, damping and mode shapes of a belt network; the Campbell diagram."""

from __future__ import annotations

import math


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
    p.add_argument("--force", action="store_true", help="replace an existing PNG")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core.errors import SceneError
    from ..core.network.model import NetworkModel, modes
    from ..core.network.scene import load_network

    scene = load_network(args.scene)
    if args.speed is not None and not (math.isfinite(args.speed) and abs(args.speed) <= 1.0e4):
        raise SceneError(f"--speed: a finite driver speed within +-1e4 rad/s, got {args.speed!r}")
    if not 3 <= args.points <= 2000:
        raise SceneError(f"--points: 3 .. 2000, got {args.points}")
    if args.campbell:
        from ..io.atomic import check_output

        check_output(args.campbell, args.force, "Campbell plot")
    model = NetworkModel.build(scene)
    speed = scene.operating_speed if args.speed is None else args.speed
    names = [p.name for p in scene.pulleys] + (["tensioner_arm"] if scene.tensioner else [])
    print(f"# {scene.name}: modes at driver speed {speed:g} rad/s ({speed * 30 / math.pi:.0f} rpm)")
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
    return 0
