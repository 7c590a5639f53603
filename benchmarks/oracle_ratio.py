"""Each planner of one campaign against the oracle of another on the same objects and seeds:
poses and cycle time over the oracle's (`oracle_table.oracle_ratios`, summary.md's "Against
the oracle"), from the campaigns' episode records, so that an oracle campaign stopped before
its slowest episodes still counts the ones it finished.

    .venv/bin/lrnbv benchmark --planners oracle --objects family --trials 2 --out /tmp/oracle
    .venv/bin/python benchmarks/oracle_ratio.py /tmp/oracle out/results/family
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from lrnbv_drake.core.evaluation.oracle import ORACLE
from lrnbv_drake.core.evaluation.stats import summarize
from lrnbv_drake.experiments.campaign.markdown import cell
from lrnbv_drake.experiments.campaign.oracle_table import oracle_ratios
from lrnbv_drake.experiments.campaign.plan import CampaignConfig
from lrnbv_drake.experiments.campaign.run import CAMPAIGN_FILE
from lrnbv_drake.experiments.campaign.summary import episode_row
from lrnbv_drake.station.scenario import recorded_scenario


def finished_rows(folder: Path) -> list[dict]:
    """results.csv's rows of the episodes `folder` finished (`episodes/*.json`)."""
    rows = [episode_row(json.loads(path.read_text()))
            for path in sorted(folder.glob("episodes/*.json"))]
    return [row for row in rows if row["status"] == "ok"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("oracle", type=Path, help="the oracle's campaign folder")
    parser.add_argument("campaign", type=Path, help="the planners' campaign folder")
    args = parser.parse_args()
    rows = finished_rows(args.oracle) + finished_rows(args.campaign)
    planners = tuple(sorted({r["planner"] for r in rows}))
    # The ratios read the campaign's scenario (its pose cap), recorded in campaign.json.
    recorded = json.loads((args.campaign / CAMPAIGN_FILE).read_text())["scenario"]
    config = CampaignConfig(args.campaign, planners, (), 0, recorded_scenario(recorded))
    if not any(r["planner"] == ORACLE for r in rows):
        parser.error(f"{args.oracle}: no finished oracle episode in episodes/")
    for planner in (p for p in planners if p != ORACLE):
        r = oracle_ratios(config, rows, planner)
        print(f"{planner}: poses / oracle's {cell(summarize(r.poses))}; cycle / oracle's "
              f"{cell(summarize(r.cycle))}; poses to 5 mm / oracle's {cell(summarize(r.views))}"
              f"; poses after 5 mm {cell(summarize(r.confirming))}; the oracle never within "
              f"5 mm on {r.oracle_never}")


if __name__ == "__main__":
    main()
