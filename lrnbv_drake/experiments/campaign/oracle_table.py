"""A campaign's planners against the oracle (`core.evaluation.oracle`): each one's poses and
cycle time over the oracle's on the same object and trial, for summary.md and the results
page, and the poses split in two: those its views took to bring the estimate within 5 mm
(over the oracle's), and those its stop took after that to confirm it."""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Sequence
from typing import Any

import numpy as np

from lrnbv_drake.core.evaluation.oracle import ORACLE
from lrnbv_drake.core.evaluation.stats import summarize
from lrnbv_drake.experiments.campaign.figures import planner_label
from lrnbv_drake.experiments.campaign.markdown import cell, table
from lrnbv_drake.experiments.campaign.plan import CampaignConfig


@dc.dataclass(frozen=True)
class OracleRatios:
    """A planner against the oracle, one value per trial both finished on where the oracle
    reached 5 mm.

    Args:
        poses: the planner's poses over the oracle's poses to 5 mm: all it took, within 5 mm
            or not, so one that stops short of 5 mm can score below 1.
        cycle: its cycle time over the oracle's.
        views: its poses to 5 mm over the oracle's, on the trials it reached 5 mm too: how
            far its views are from the oracle's.
        confirming: its poses after it reached 5 mm (on those trials): what its stop took.
        oracle_never: the oracle's trials that never reached 5 mm (no ratio).
        planner_never: the trials the oracle reached 5 mm on and the planner did not.
    """

    poses: np.ndarray
    cycle: np.ndarray
    views: np.ndarray
    confirming: np.ndarray
    oracle_never: int
    planner_never: int


def oracle_ratios(config: CampaignConfig, ok: Sequence[dict[str, Any]], planner: str,
                  obj: str | None = None) -> OracleRatios:
    """`planner` against the oracle on `obj`, or on every object (`OracleRatios`)."""
    never = config.scenario.max_poses + 1
    mine = [r for r in ok if obj in (None, r["object"])]
    oracle = {(r["object"], r["trial"]): r for r in mine if r["planner"] == ORACLE}
    reached = {k: o for k, o in oracle.items() if o["poses_to_5mm"] < never}
    pairs = [(r, reached[r["object"], r["trial"]]) for r in mine
             if r["planner"] == planner and (r["object"], r["trial"]) in reached]
    both = [(r, o) for r, o in pairs if r["poses_to_5mm"] < never]
    return OracleRatios(
        poses=np.array([r["n_poses"] / o["poses_to_5mm"] for r, o in pairs]),
        cycle=np.array([r["cycle_s"] / o["cycle_s"] for r, o in pairs]),
        views=np.array([r["poses_to_5mm"] / o["poses_to_5mm"] for r, o in both]),
        confirming=np.array([r["n_poses"] - r["poses_to_5mm"] for r, _ in both], float),
        oracle_never=len(oracle) - len(reached), planner_never=len(pairs) - len(both))


def _floored(config: CampaignConfig) -> list[str]:
    """The planners measured against the oracle: all but it; none without it."""
    if ORACLE not in config.planners:
        return []
    return [p for p in config.planners if p != ORACLE]


def oracle_section(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> list[str]:
    """Each planner's poses and cycle time as ratios to the oracle's on the same object and
    trial, and its poses split into its views' and its stop's (`oracle_ratios`), per object
    and over every object; none without the oracle."""
    others = _floored(config)
    if not others:
        return []
    objects = [*(o.label for o in config.objects), None]
    ratios = {(p, obj): oracle_ratios(config, ok, p, obj) for p in others for obj in objects}
    header = ["object", "oracle never within 5 mm"]
    split_header = ["object"]
    for p in others:
        header += [f"{planner_label(p)} poses / oracle's", f"{planner_label(p)} cycle / oracle's"]
        split_header += [f"{planner_label(p)} poses to 5 mm / oracle's",
                         f"{planner_label(p)} poses after 5 mm",
                         f"{planner_label(p)} never within 5 mm"]
    body, split = [], []
    for obj in objects:
        name = obj or "every object"
        body.append([name, str(ratios[others[0], obj].oracle_never)])
        split.append([name])
        for p in others:
            r = ratios[p, obj]
            body[-1] += [cell(summarize(r.poses)), cell(summarize(r.cycle))]
            split[-1] += [cell(summarize(r.views)), cell(summarize(r.confirming)),
                          str(r.planner_never)]
    return ["## Against the oracle", "",
            "The oracle knows the object (core/evaluation/oracle.py): its poses are those after "
            "which the estimate was within 5 mm in every dimension, its cycle time the time "
            "they took. Each cell: median [Q1, Q3] (n) of a planner's poses (cycle time) over "
            "the oracle's on the same object and trial, where the oracle got within 5 mm; a "
            "planner's poses are all it took, so one that stops short of 5 mm can score "
            "below 1.", "",
            *table(header, body), "",
            "The same trials, where the planner's estimate got within 5 mm too: the poses its "
            "views took to get there over the oracle's, and the poses its stop took after "
            "that (a box stop confirms the box over `planner.stop.stable_poses` more poses).",
            "", *table(split_header, split)]


def oracle_line(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> str:
    """Each other planner's poses over the oracle's (`oracle_ratios`) pooled over objects,
    and of those its views' and its stop's, on one line; empty without the oracle."""
    others = _floored(config)
    if not others:
        return ""
    ratios = {p: oracle_ratios(config, ok, p) for p in others}
    cells = [f"{planner_label(p)} {cell(summarize(r.poses))} (where it got within 5 mm too: "
             f"its poses to 5 mm over the oracle's {cell(summarize(r.views))}, then "
             f"{cell(summarize(r.confirming))} poses to its stop)"
             for p, r in ratios.items()]
    return ("Poses over the oracle's on the same object and trial, where it got within 5 mm "
            f"(it never did in {ratios[others[0]].oracle_never}): " + "; ".join(cells) + ".")
