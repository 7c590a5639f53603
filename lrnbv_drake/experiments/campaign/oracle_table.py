"""A campaign's planners against the oracle (`core.evaluation.oracle`): each one's poses and
cycle time over the oracle's on the same object and trial, for summary.md and the results
page."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lrnbv_drake.core.evaluation.oracle import ORACLE
from lrnbv_drake.core.evaluation.stats import summarize
from lrnbv_drake.experiments.campaign.figures import planner_label
from lrnbv_drake.experiments.campaign.markdown import cell, table
from lrnbv_drake.experiments.campaign.plan import CampaignConfig


def oracle_ratios(config: CampaignConfig, ok: Sequence[dict[str, Any]], planner: str,
                  obj: str | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """`planner`'s poses over the oracle's poses to 5 mm and its cycle time over the
    oracle's, one of each per trial both finished on (on `obj`, or every object) where the
    oracle reached 5 mm; and the number of the oracle's trials (there) it never did. The
    planner's poses are all it took, within 5 mm or not: one that stops short of 5 mm can
    score below 1."""
    never = config.scenario.max_poses + 1
    mine = [r for r in ok if obj in (None, r["object"])]
    oracle = {(r["object"], r["trial"]): r for r in mine if r["planner"] == ORACLE}
    reached = {k: o for k, o in oracle.items() if o["poses_to_5mm"] < never}
    pairs = [(r, reached[r["object"], r["trial"]]) for r in mine
             if r["planner"] == planner and (r["object"], r["trial"]) in reached]
    return (np.array([r["n_poses"] / o["poses_to_5mm"] for r, o in pairs]),
            np.array([r["cycle_s"] / o["cycle_s"] for r, o in pairs]),
            len(oracle) - len(reached))


def _floored(config: CampaignConfig) -> list[str]:
    """The planners measured against the oracle: all but it; none without it."""
    if ORACLE not in config.planners:
        return []
    return [p for p in config.planners if p != ORACLE]


def oracle_section(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> list[str]:
    """Each planner's poses and cycle time as ratios to the oracle's on the same object and
    trial (`oracle_ratios`), per object and over every object; none without the oracle."""
    others = _floored(config)
    if not others:
        return []
    header = ["object", "oracle never within 5 mm"]
    for p in others:
        header += [f"{planner_label(p)} poses / oracle's", f"{planner_label(p)} cycle / oracle's"]
    body = []
    for obj in [*(o.label for o in config.objects), None]:
        line = [obj or "every object", str(oracle_ratios(config, ok, others[0], obj)[2])]
        for p in others:
            poses, cycle, _ = oracle_ratios(config, ok, p, obj)
            line += [cell(summarize(poses)), cell(summarize(cycle))]
        body.append(line)
    return ["## Against the oracle", "",
            "The oracle knows the object (core/evaluation/oracle.py): its poses are those after "
            "which the estimate was within 5 mm in every dimension, its cycle time the time "
            "they took. Each cell: median [Q1, Q3] (n) of a planner's poses (cycle time) over "
            "the oracle's on the same object and trial, where the oracle got within 5 mm; a "
            "planner's poses are all it took, so one that stops short of 5 mm can score "
            "below 1.", "",
            *table(header, body)]


def oracle_line(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> str:
    """Each other planner's poses over the oracle's (`oracle_ratios`) pooled over objects, on
    one line; empty without the oracle."""
    others = _floored(config)
    if not others:
        return ""
    cells = [f"{planner_label(p)} {cell(summarize(oracle_ratios(config, ok, p)[0]))}"
             for p in others]
    return ("Poses over the oracle's on the same object and trial, where it got within 5 mm "
            f"(it never did in {oracle_ratios(config, ok, others[0])[2]}): "
            + "; ".join(cells) + ".")
