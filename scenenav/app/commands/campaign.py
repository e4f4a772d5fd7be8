"""``scenenav campaign CAMPAIGN.yaml --out DIR``: many seeded flights as one command, on Dask."""

from __future__ import annotations

import argparse
import sys

DESCRIPTION = (
    "Expand a campaign file (base scenario, set, grid, random draws, repeat; docs/campaigns.md) into "
    "runs with stable ids, write DIR/plan.json, and fly every run that is not complete yet as a "
    "`scenenav run` on Dask: a local cluster of one-thread workers, one flight each (default: one per "
    "core), or an existing cluster (--scheduler; DIR must then be on a filesystem the workers share). "
    "A failed or timed-out run is recorded with its exit status and log tail and retried once; the "
    "campaign goes on. Ctrl-C stops the flights cleanly; the same command resumes. Writes "
    "DIR/runs/<id>/, DIR/results.parquet, DIR/results.csv and DIR/report.md (bootstrap intervals, "
    "plots).")


def _cmd(args: argparse.Namespace) -> int:
    from scenenav.app.campaign_run import run_campaign
    result = run_campaign(args.campaign, args.out, workers=args.workers, scheduler=args.scheduler,
                          extra_sets=tuple(args.set or ()), retry_failed=args.retry_failed,
                          max_runs=args.max_runs, max_repeat=args.repeat, progress=not args.quiet, report_dir=args.report_dir,
                          command="scenenav " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["campaign"] else None)
    print(f"results: {result.out_dir / 'results.parquet'}, {result.out_dir / 'report.md'}")
    return 1 if result.failed else 0


def register(sub) -> None:
    """Add ``campaign`` to the ``scenenav`` sub-commands."""
    c = sub.add_parser("campaign", help="fly a campaign of many runs on Dask and write one results table",
                       description=DESCRIPTION)
    c.add_argument("campaign", help="campaign YAML (see docs/campaigns.md and campaigns/)")
    c.add_argument("--out", required=True, metavar="DIR",
                   help="campaign folder; an existing one of the same campaign is resumed")
    c.add_argument("--workers", type=int, metavar="N",
                   help="local workers, one flight each (default: one per core)")
    c.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://HOST:8786, instead of a local cluster")
    c.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="one more override for every run (changes the run ids: a different campaign)")
    c.add_argument("--max-runs", type=int, metavar="N",
                   help="plan only the first N runs (a reduced campaign; the full one reuses them)")
    c.add_argument("--repeat", type=int, metavar="N",
                   help="fly only the first N repetitions of each point (a reduced campaign; same run ids)")
    c.add_argument("--retry-failed", action="store_true",
                   help="fly again the runs an earlier invocation recorded as failed")
    c.add_argument("--report-dir", metavar="DIR2", help="also write report.md and its plots to DIR2")
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    c.set_defaults(func=_cmd)
