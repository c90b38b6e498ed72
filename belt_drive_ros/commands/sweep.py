"""``belt-drive sweep``: run a campaign (grid, tolerance Monte Carlo, profiles, fleet) on a Dask cluster."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

EPILOG = """\
examples:
  belt-drive sweep paper_tolerances.yaml                      # a local Dask cluster, one worker per CPU
  belt-drive sweep paper_tolerances.yaml --workers 2 --csv --plots
  belt-drive sweep fleet.yaml --scheduler tcp://10.0.0.5:8786 # an existing dask.distributed scheduler
  belt-drive sweep paper_tolerances.yaml --out runs/tol       # interrupted? the same command resumes
  belt-drive sweep paper_tolerances.yaml --check              # validate, estimate, run a few variants here

Results go to OUT (default: CAMPAIGN's name beside it, '.campaign'):
results.parquet (pandas.read_parquet), results.csv with --csv, parts/ as
batches finish, summary.txt, and with --plots histograms.png,
metrics_vs_parameters.png, fleet_worst.png. Exit 0 when every run ran (and,
for a fleet with goldens, every recording passed), 1 otherwise, 2 for a bad
campaign file or a campaign too large for the machine (the one error line
says what it would cost), 130 / 143 when interrupted by SIGINT / SIGTERM
(the batches finished so far are kept: the same command resumes). The file
format and the metrics: docs/campaigns.md.
"""
#: variants --check runs in this process
CHECK_VARIANTS = 8


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
    p.add_argument("--quiet", action="store_true", help="no estimate or progress line")
    p.add_argument("--check", action="store_true", help=f"validate the file, print the estimate and run up to "
                   f"{CHECK_VARIANTS} variants (first, last, and spread between) in this process, without a cluster")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..campaign import limits
    from ..campaign.execute import check_out_folder, run_campaign
    from ..campaign.report import plot, summary
    from ..campaign.spec import Campaign, CampaignError
    from ..io.atomic import write_output

    if args.batch_size is not None and args.batch_size < 1:
        raise CampaignError(f"--batch-size: must be >= 1, got {args.batch_size}")
    if args.workers is not None and args.workers < 1:
        raise CampaignError(f"--workers: must be >= 1, got {args.workers}")
    campaign = Campaign.load(args.campaign)
    workers = limits.check(campaign, args.workers, local=not args.scheduler)
    if args.check:
        return check(campaign, workers)
    if not args.quiet:
        print(f"belt-drive: sweep {campaign.name}: {limits.estimate(campaign, workers)}", file=sys.stderr)
    out = args.out or args.campaign.with_suffix(".campaign")
    check_out_folder(campaign, Path(out), csv=args.csv, plots=args.plots)  # (run_campaign checks all but the charts)
    done = run_campaign(
        campaign, out, scheduler=args.scheduler, workers=args.workers, csv=args.csv,
        progress=False if args.quiet else None, force=args.force, batch_size=args.batch_size,
    )  # fmt: skip
    if done.interrupted:
        how = f"interrupted by {signal.Signals(done.signum).name}" if done.signum else "interrupted"
        print(f"belt-drive: {how}: {len(done.table)} of {campaign.size} runs kept in {out}; "
              "run the same command again to resume", file=sys.stderr)
        return 128 + done.signum if done.signum else 1
    text = summary(done.table, campaign, done.wall, done.workers)
    write_output(Path(out) / "summary.txt", text + "\n", force=True, what="campaign output")
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


def check(campaign, workers: int) -> int:
    """``--check``: the estimate, then up to :data:`CHECK_VARIANTS` variants run here as a worker runs them and
    their rows written as a part is; exit 0 if they ran, 1 if one failed (its error printed)."""
    import tempfile

    import numpy as np

    from ..campaign import limits
    from ..campaign.execute import portable_of, run_batch, write_part

    table = campaign.variants()
    picks = sorted(set(np.linspace(0, len(table) - 1, min(CHECK_VARIANTS, len(table))).round().astype(int).tolist()))
    with tempfile.TemporaryDirectory(prefix="belt_drive_check_") as tmp:
        recordings = Path(tmp) / "recordings" if campaign.fleet_folder is not None else None
        if recordings is not None:
            recordings.mkdir()
        rows = run_batch(portable_of(campaign), table.iloc[picks], str(recordings) if recordings else None)
        write_part(Path(tmp) / "part-00000.parquet", rows)  # the rows' columns must be typed as a part needs
    failed = rows[rows["error"] != ""]
    print(f"campaign {campaign.name}: {limits.estimate(campaign, workers)}")
    print(f"checked {len(rows)} of {len(table)} variants here: {len(rows) - len(failed)} ran, {len(failed)} failed")
    if len(failed):
        first = failed.iloc[0]
        print(f"belt-drive: error: variant {int(first['variant'])}: {first['error']}", file=sys.stderr)
        return 1
    return 0
