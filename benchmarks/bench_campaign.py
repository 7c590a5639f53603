"""Wall time of the paper's campaign: 4 objects x 5 trials x every available planner.

Runs `lrnbv benchmark` with `--jobs 2` (every planner of `experiments.episode.PLANNERS`) in a
fresh folder, since a resumed campaign skips its finished episodes and would time nothing, and
keeps the folder for a look at summary.md and the figures. Target: under 5 minutes on 2 cores.

    .venv/bin/python benchmarks/bench_campaign.py [--jobs 2] [--trials 5] [--out DIR]
"""

from __future__ import annotations

import argparse
import csv
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lrnbv_drake.cli.benchmark import add_benchmark_command, run_benchmark
from lrnbv_drake.core.evaluation.objects import PAPER_OBJECTS
from lrnbv_drake.experiments.episode import PLANNERS

TARGET_SECONDS = 300.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--out", help="campaign folder, which must not hold episodes yet "
                                      "(default: a new temporary folder)")
    args = parser.parse_args()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_campaign_"))
    if any((out / "episodes").glob("*.json")):
        parser.error(f"{out} already holds episodes, which a rerun would skip: use a new --out")

    argv = ["benchmark", "--planners", ",".join(PLANNERS), "--objects", "paper",
            "--trials", str(args.trials), "--jobs", str(args.jobs), "--out", str(out)]
    print("command: lrnbv " + shlex.join(argv), flush=True)
    cli = argparse.ArgumentParser(prog="lrnbv")
    add_benchmark_command(cli.add_subparsers(dest="command", required=True))
    started = time.perf_counter()
    status = run_benchmark(cli.parse_args(argv))
    wall = time.perf_counter() - started

    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    n = len(PAPER_OBJECTS) * args.trials * len(PLANNERS)
    failed = sum(r["status"] != "ok" for r in rows)
    busy = sum(float(r["wall_seconds"]) for r in rows if r["status"] == "ok")
    print(f"\n{n} episodes ({len(PAPER_OBJECTS)} objects x {args.trials} trials x "
          f"{', '.join(PLANNERS)}), {failed} failed, --jobs {args.jobs}")
    for planner in PLANNERS:
        times = [float(r["wall_seconds"]) for r in rows
                 if r["planner"] == planner and r["status"] == "ok"]
        if times:
            print(f"  {planner:6s} median episode {np.median(times):5.2f} s "
                  f"(max {max(times):.2f} s)")
    print(f"campaign wall time: {wall:.1f} s ({wall / 60:.2f} min), {wall / n:.2f} s per "
          f"episode; episodes' own wall time summed {busy:.1f} s")
    verdict = "meets" if wall < TARGET_SECONDS else "MISSES"
    print(f"{verdict} the target of {TARGET_SECONDS / 60:.0f} min; outputs in {out}")
    return status


if __name__ == "__main__":  # the spawned workers import this file again
    sys.exit(main())
