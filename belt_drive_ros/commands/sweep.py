"""``belt-drive sweep``: run a campaign (grid, tolerance Monte Carlo, profiles, fleet) on a Dask cluster."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

EPILOG = """\
examples:
  belt-drive sweep paper_tolerances.yaml                      # a local Dask cluster, one worker per CPU
  belt-drive sweep paper_tolerances.yaml --workers 2 --csv --plots
  belt-drive sweep fleet.yaml --scheduler tcp://10.0.0.5:8786 # an existing dask.distributed scheduler
  belt-drive sweep paper_tolerances.yaml --out runs/tol       # interrupted? the same command resumes

Results go to OUT (default: CAMPAIGN's name beside it, '.campaign'):
results.parquet (pandas.read_parquet), results.csv with --csv, parts/ as
batches finish, summary.txt, and with --plots histograms.png,
metrics_vs_parameters.png, fleet_worst.png. Exit 0 when every run ran (and,
for a fleet with goldens, every recording passed), 1 otherwise, 2 for a bad
campaign file. The file format and the metrics: docs/campaigns.md.
"""


def register(sub) -> None:
    p = sub.add_parser(
        "sweep",
        help="run a campaign: parameter grid, tolerance Monte Carlo, profiles or a fleet of recordings (Dask)",
        description="Run a campaign of many variants of one scene on a Dask cluster and tabulate the metrics.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("campaign", type=Path, help="campaign YAML file (docs/campaigns.md)")
    p.add_argument("--out", type=Path, help="output folder (default: CAMPAIGN without .yaml, plus '.campaign')")
    p.add_argument("--scheduler", metavar="ADDRESS", help="address of a running dask.distributed scheduler "
                   "(default: start a local cluster on 127.0.0.1 and stop it at the end)")
    p.add_argument("--workers", type=int, help="worker processes of the local cluster (default: one per CPU)")
    p.add_argument("--batch-size", type=int, help="variants per task (default: sized so a task computes >= 0.1 s)")
    p.add_argument("--csv", action="store_true", help="also write results.csv")
    p.add_argument("--plots", action="store_true", help="write the histograms, metric-vs-parameter and fleet charts")
    p.add_argument("--force", action="store_true", help="start afresh in an --out folder that holds another run")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..campaign.execute import run_campaign
    from ..campaign.report import plot, summary
    from ..campaign.spec import Campaign, CampaignError

    campaign = Campaign.load(args.campaign)
    if args.workers is not None and args.workers < 1:
        raise CampaignError(f"--workers: must be >= 1, got {args.workers}")
    if args.batch_size is not None and args.batch_size < 1:
        raise CampaignError(f"--batch-size: must be >= 1, got {args.batch_size}")
    out = args.out or args.campaign.with_suffix(".campaign")
    done = run_campaign(
        campaign, out, scheduler=args.scheduler, workers=args.workers, csv=args.csv,
        progress=False if args.quiet else None, force=args.force, batch_size=args.batch_size,
    )  # fmt: skip
    if done.interrupted:
        print(f"belt-drive: interrupted: {len(done.table)} of {len(campaign.variants())} runs in {out}; "
              "run the same command again to resume", file=sys.stderr)
        return 1
    text = summary(done.table, campaign, done.wall, done.workers)
    (Path(out) / "summary.txt").write_text(text + "\n")
    print(text)
    print(f"wrote {Path(out) / 'results.parquet'}" + (f" and {Path(out) / 'results.csv'}" if args.csv else ""))
    if args.plots:
        for path in plot(done.table, campaign, out):
            print(f"wrote {path}")
    table = done.table
    failed = bool((table["error"] != "").any())
    if "compare_passed" in table:
        failed |= not bool(table["compare_passed"].fillna(False).astype(bool).all())
    return 1 if failed else 0
