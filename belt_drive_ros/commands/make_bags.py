"""``belt-drive make-bags``: regenerate the reference recordings in ``bags/``."""

from __future__ import annotations

import argparse
from pathlib import Path

EPILOG = """\
examples:
  belt-drive make-bags --out bags --force        # what 'make bags' runs
  belt-drive make-bags --out /tmp/bags --only engine_idle
  belt-drive make-bags --list

For each case: NAME.yaml (scene), NAME_torque.mcap (/drive_torque at 1 kHz) and
NAME_golden.mcap (all outputs of the scene driven by that torque). Check a
fresh run against a golden file:
  belt-drive sim bags/engine_idle.yaml --torque-bag bags/engine_idle_torque.mcap --out fresh.mcap
  msg-tools compare fresh.mcap bags/engine_idle_golden.mcap
"""


def register(sub) -> None:
    p = sub.add_parser(
        "make-bags",
        help="regenerate the reference torque profiles and golden output bags",
        description="Write the reference scenes, torque-profile bags and golden output bags.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", type=Path, default=Path("bags"), help="folder (default: bags/)")
    p.add_argument("--force", action="store_true", help="replace existing files")
    p.add_argument("--only", nargs="+", metavar="NAME", help="make only these cases")
    p.add_argument("--list", action="store_true", help="list the cases and exit")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io.bags import REFERENCE_BAGS, make_bags
    from ..io.recording import BagReadError

    if args.list:
        for name, case in REFERENCE_BAGS.items():
            print(f"{name:20s} {case.description}")
        return 0
    if args.out.exists() and not args.out.is_dir():
        from ..io.atomic import OutputRefused

        raise OutputRefused(f"--out {args.out}: exists and is not a folder (make-bags writes NAME.yaml and bags into it)")
    try:
        make_bags(args.out, force=args.force, only=args.only)
    except ValueError as exc:
        raise BagReadError(str(exc)) from None
    return 0
