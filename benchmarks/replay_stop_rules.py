"""Recorded LR-NBV episodes replayed with this tree's estimator under the product's stop and
stop rules that would end them sooner: the estimates pose by pose (`lrnbv refit`'s), each
rule asked after each pose, and the box, its container and the cycle time up to the pose the
rule stops at (or the last recorded). The views before a stop do not depend on the stop rule
or the estimate, so an earlier stop on a recorded episode is the episode that rule would have
run; `box` against `recorded` is what a change of the estimator does to the same readings.

Rules: `box` is the product's (`planner.stop`, core/planning/stop.py). `stalled1`
(`stalled2`) also stops once the box held still over the last pose, at least `min_poses`
were taken, every dimension's interval is bounded (narrower than
`estimation.interval_reach`) and each is narrower than `interval_width` or narrowed by less
than `tolerance` over the last pose (each of the last two). Record 0026.

    .venv/bin/python benchmarks/replay_stop_rules.py [--max-estimate-seconds S] \
        [--rules box,stalled1,stalled2] out/results/family/runs/lrnbv__* > replay.jsonl
    .venv/bin/python benchmarks/replay_stop_rules.py --summary replay.jsonl

Beside another job, prefix `NUMBA_NUM_THREADS=1`: the kernels' threads spinning against
another process's made a replay about two hundred times slower here.
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import json
import math
from pathlib import Path

import numpy as np
import scipy.stats

from lrnbv_drake.core.evaluation.packing import packing_metrics
from lrnbv_drake.core.planning.stop import BoxStop
from lrnbv_drake.experiments.refit import load_episode
from lrnbv_drake.experiments.report import against_truth
from lrnbv_drake.station.parts import container_catalogue, episode_estimator, packing_decision


def stalled(k: int):
    def rule(track, p, reach):
        recent = BoxStop(dc.replace(p, stable_poses=max(k, p.stable_poses))).held_still(track)
        if recent is None:
            return False
        widths = [e.widths for e in recent]
        if np.all(widths[-1] <= p.interval_width) and recent[-1].chosen:
            return True
        if np.any(widths[-1] >= reach):
            return False
        return not any(np.any((b > p.interval_width) & (a - b >= p.tolerance))
                       for a, b in zip(widths[-k - 1:-1], widths[-k:], strict=True))
    return rule


def box(track, p, reach):
    return BoxStop(p).update(track) is not None


RULES = {"box": box, "stalled1": stalled(1), "stalled2": stalled(2)}


def replay(folder: str, rules: dict = RULES) -> dict:
    episode = load_episode(folder)
    report = json.loads((episode.folder / "report.json").read_text())
    scenario, true = episode.scenario, episode.true
    p, reach = scenario.planner.stop, scenario.estimation.interval_reach
    times = [pose["time"] for pose in report["poses"]]
    computing = [s["policy_s"] + s["motion_planning_s"] for s in report["timing"]["planning_steps"]]
    metrics, packing = report["metrics"], report["metrics"].get("packing", {})
    out = {"folder": folder, "recorded": {
        "poses": report["n_poses"], "worst": max(abs(v) for v in metrics["dim_errors_mm"]),
        "fits": packing.get("fits"), "right": packing.get("right_size"),
        "inside": all(metrics.get("truth_in_interval") or [False]),
        "cycle": report["cycle_time"]["total_s"]}}
    estimator, n = episode_estimator(scenario), len(episode.readings)
    for i in range(n):
        track = estimator.update(episode.readings[:i + 1], episode.cell_boxes[:i + 1])
        for name, rule in rules.items():
            if name in out or not (rule(track, p, reach) or i == n - 1):
                continue
            decision = packing_decision(scenario, track.latest)
            fit = packing_metrics(decision, true.dims, container_catalogue(scenario)) \
                if decision else {}
            truth = against_truth(track.latest, true)
            out[name] = {
                "poses": i + 1, "worst": max(abs(v) for v in truth["dim_errors_mm"]),
                "fits": fit.get("fits"), "right": fit.get("right_size"),
                "inside": all(truth["truth_in_interval"]),
                "cycle": times[i] + sum(computing[:i + 1])}
        if all(name in out for name in rules):
            break
    return out


def against_recorded(found: list[dict]) -> str:
    """The product's stop with this tree's estimator against the recorded episodes, paired."""
    now, then = (np.array([r[k]["worst"] for r in found]) for k in ("box", "recorded"))
    change = now - then
    p = scipy.stats.wilcoxon(now, then).pvalue if np.any(np.abs(change) > 0.02) else 1.0
    return (f"  box against recorded: {int(np.sum(np.abs(change) <= 0.02))} the same box, "
            f"{int(np.sum(change < -1))} better and {int(np.sum(change > 1))} worse by more "
            f"than 1 mm (Wilcoxon p = {p:.2f})")


def summary(path: str) -> None:
    rows = [json.loads(line) for line in open(path)]
    groups = sorted({r["folder"].split("/runs/")[0] for r in rows})
    for group in [*groups, "all"] if len(groups) > 1 else groups:
        found = [r for r in rows if group == "all" or r["folder"].startswith(group + "/runs/")]
        print(f"{group} ({len(found)} episodes)")
        print(against_recorded(found))
        for name in ("recorded", *(n for n in RULES if all(n in r for r in found))):
            v = {key: np.array([r[name][key] for r in found], float)
                 for key in ("poses", "worst", "fits", "right", "inside", "cycle")}
            print(f"  {name:9s} poses median {np.median(v['poses']):.1f} total "
                  f"{v['poses'].sum():.0f}; worst median {np.median(v['worst']):.1f} mm, p95 "
                  f"{np.percentile(v['worst'], 95):.1f}, max {v['worst'].max():.1f}; fits "
                  f"{v['fits'].mean():.2f}, right size {v['right'].mean():.2f}, truth inside "
                  f"{v['inside'].mean():.2f}; cycle median {np.median(v['cycle']):.1f} s, "
                  f"p95 {np.percentile(v['cycle'], 95):.0f}, max {v['cycle'].max():.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+")
    parser.add_argument("--summary", action="store_true", help="summarise a replay's lines")
    parser.add_argument("--max-estimate-seconds", type=float, default=math.inf,
                        help="skip the episodes whose estimates took longer (report.json)")
    parser.add_argument("--rules", default=",".join(RULES),
                        help="the rules replayed, comma-separated (an interval read by a rule "
                             "the others do not read is computed again: fewer rules, faster)")
    args = parser.parse_args()
    rules = args.rules.split(",")
    if not set(rules) <= set(RULES):
        parser.error(f"--rules: {args.rules!r}, expected names among {', '.join(RULES)}")
    if args.summary:
        summary(args.folders[0])
        return
    for folder in args.folders:
        report = json.loads((Path(folder) / "report.json").read_text())
        if sum(report["timing"]["box_estimate_s"]) <= args.max_estimate_seconds:
            print(json.dumps(replay(folder, {name: RULES[name] for name in rules})), flush=True)


if __name__ == "__main__":
    main()
