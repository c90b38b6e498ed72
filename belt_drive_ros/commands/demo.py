"""``belt-drive demo``: the main job of ``make demo``."""

from __future__ import annotations

from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("demo", help="the main job: run the paper scene, write out/paper.csv and out/paper.png",
                       description="Simulate the 'paper' scene (rigid and flexible), print a summary, write CSV and PNG.")
    p.add_argument("--out-dir", type=Path, default=Path("out"), help="where to write (default: out/)")
    p.set_defaults(func=run)


def run(args) -> int:
    from .sim import run as run_sim

    args.out_dir.mkdir(parents=True, exist_ok=True)
    ns = type("Args", (), dict(
        scene="paper", model=None, method=None, method_option=[], dt=None, duration=None,
        out=args.out_dir / "paper.csv", plot=args.out_dir / "paper.png", torque_bag=None, force=True, quiet=False,
    ))()
    return run_sim(ns)
