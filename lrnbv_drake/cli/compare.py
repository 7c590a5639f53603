"""`lrnbv compare`: two campaigns' episodes compared pair by pair, the way a change to the
estimator or the planner is measured on the same seeds and placements."""

from __future__ import annotations

import argparse
import math
import sys

from lrnbv_drake.core.evaluation.stats import PairedChange, paired_changes
from lrnbv_drake.experiments.campaign.summary import read_results_csv

DESCRIPTION = """\
Compares two campaigns of the same manifest (`lrnbv benchmark` or `lrnbv results` folders,
each with its results.csv), run before and after a change: every (planner, object, trial)
episode of one against the same in the other, which had the same seed and placement. For
each planner and metric: the pairs, the median, mean and 95th percentile before and after, how many
pairs fell or rose (by more than a millimetre for an error, at all for the rest), and the
two-sided Wilcoxon signed-rank p of the differences. Errors are shown in mm."""

EPILOG = """\
examples:
  lrnbv compare out/results/family /tmp/after/out/results/family
  lrnbv compare out/before out/after --metrics worst_err,n_poses

exit status: 0 compared, 2 bad input (a folder without results.csv, no episode in both)."""

METRICS = ("worst_err", "truth_in_interval", "right_size", "fits", "n_poses")
#: An error move smaller than this is no move, metres.
ERROR_TOLERANCE = 0.001


def add_compare_command(subparsers: argparse._SubParsersAction) -> None:
    """Adds `compare` to the `lrnbv` parser's subcommands."""
    parser = subparsers.add_parser(
        "compare", help="compare two campaigns episode by episode (a change measured)",
        description=DESCRIPTION, epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", metavar="BEFORE", help="the campaign folder before the change")
    parser.add_argument("after", metavar="AFTER", help="the campaign folder after it")
    parser.add_argument("--metrics", default=",".join(METRICS),
                        help=f"results.csv columns, comma-separated (default: "
                             f"{','.join(METRICS)})")


def _is_error(metric: str) -> bool:
    """Whether `metric` is a length error in metres (shown in mm, moved by a tolerance)."""
    return "err" in metric


def _value(change: PairedChange, value: float) -> str:
    if not math.isfinite(value):
        return "n/a"
    return f"{value * 1000:.1f}" if _is_error(change.metric) else f"{value:.3g}"


def table(changes: list[PairedChange]) -> str:
    """The comparison as a markdown table."""
    lines = ["| planner | metric | pairs | median before -> after | mean before -> after "
             "| p95 before -> after | lower | higher | Wilcoxon p |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in changes:
        unit = " (mm)" if _is_error(c.metric) else ""
        p = "n/a (no pair moved)" if math.isnan(c.p) else f"{c.p:.3g}"
        lines.append(
            f"| {c.planner} | {c.metric}{unit} | {c.n} | {_value(c, c.before.median)} -> "
            f"{_value(c, c.after.median)} | {_value(c, c.before_mean)} -> "
            f"{_value(c, c.after_mean)} | {_value(c, c.before_p95)} -> "
            f"{_value(c, c.after_p95)} | {c.lower} | {c.higher} | {p} |")
    return "\n".join(lines)


def run_compare_command(args: argparse.Namespace) -> int:
    """Runs `lrnbv compare`; returns the exit code."""
    metrics = [m.strip() for m in args.metrics.split(",") if m.strip()]
    try:
        before, after = read_results_csv(args.before), read_results_csv(args.after)
        unknown = [m for m in metrics if m not in before[0] or m not in after[0]]
        if unknown:
            raise ValueError(f"--metrics: {', '.join(unknown)} not in both results.csv; "
                             f"expected columns such as {', '.join(METRICS)}")
    except ValueError as e:
        print(f"lrnbv compare: error: {e}", file=sys.stderr)
        return 2
    changes = paired_changes(before, after, metrics,
                             {m: ERROR_TOLERANCE for m in metrics if _is_error(m)})
    if not any(c.n for c in changes):
        print(f"lrnbv compare: error: no episode of {args.before} is in {args.after} with a "
              f"value; expected two campaigns of the same manifest", file=sys.stderr)
        return 2
    print(table(changes))
    return 0
