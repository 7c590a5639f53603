"""A campaign's results: a results.csv row per episode, summary.md (the figures over every
object, medians, quartiles and Mann-Whitney U tests against the reference planner) and the
figures.

Rows carry NaN where a report has no value (a failed episode, or a report without `metrics`),
and every statistic leaves those out.
"""

from __future__ import annotations

import csv
import dataclasses as dc
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lrnbv_drake.core.evaluation.metrics import coverage_auc
from lrnbv_drake.core.evaluation.oracle import ORACLE
from lrnbv_drake.core.evaluation.stats import (
    ALPHA,
    compare_planners,
    finite,
    group_summaries,
    mann_whitney,
    summarize,
)
from lrnbv_drake.experiments.campaign.figures import (
    planner_label,
    plot_campaign,
    plot_coverage_curves,
)
from lrnbv_drake.experiments.campaign.index_page import index_page
from lrnbv_drake.experiments.campaign.markdown import cell, first_line, fmt, table
from lrnbv_drake.experiments.campaign.oracle_table import oracle_section
from lrnbv_drake.experiments.campaign.plan import CampaignConfig

#: The planner the U tests compare the others against.
REFERENCE_PLANNER = "lrnbv"


@dc.dataclass(frozen=True)
class Metric:
    """A results.csv column summarised and tested, with its label in summary.md."""

    column: str
    label: str


METRICS: tuple[Metric, ...] = (
    Metric("est_L", "estimated L (m)"),
    Metric("est_W", "estimated W (m)"),
    Metric("est_H", "estimated H (m)"),
    Metric("abs_err_L", "abs. L error (m)"),
    Metric("abs_err_W", "abs. W error (m)"),
    Metric("abs_err_H", "abs. H error (m)"),
    Metric("worst_err", "worst-dimension error (m)"),
    Metric("iou", "IoU"),
    Metric("coverage_1cm", "coverage, 1 cm"),
    Metric("coverage_2cm", "coverage, 2 cm"),
    Metric("auc_1cm", "coverage AUC, 1 cm, over the most poses on the object"),
    Metric("n_poses", "poses"),
    Metric("n_useless_poses", "useless poses"),
    Metric("poses_to_5mm", "poses to 5 mm (max_poses + 1: never)"),
    Metric("poses_to_10mm", "poses to 10 mm (max_poses + 1: never)"),
    Metric("truth_in_interval", "share of L, W, H inside the interval"),
    Metric("fits", "container fits (1 yes, 0 no)"),
    Metric("right_size", "container right size (1 yes, 0 no)"),
    Metric("wasted_volume", "container volume wasted (share)"),
    Metric("cycle_s", "cycle time (s)"),
    Metric("wall_seconds", "wall time (s)"),
)

CSV_COLUMNS: tuple[str, ...] = (
    "planner", "object", "trial", "seed", "status", "n_poses", "n_useless_poses",
    "coverage_1cm", "coverage_2cm", "auc_1cm", "auc_2cm", "iou",
    "est_L", "est_W", "est_H", "true_L", "true_W", "true_H", "abs_err_L", "abs_err_W",
    "abs_err_H", "worst_err", "poses_to_5mm", "poses_to_10mm", "truth_in_interval",
    "misfit_flag", "container", "fits",
    "right_size", "wasted_volume", "cycle_s", "motion_s", "settle_s", "computation_s",
    "object_x", "object_y", "object_yaw_deg", "termination", "wall_seconds", "error",
)


def _num(value: Any) -> float:
    """A metric value as float, NaN for missing (None in the JSON)."""
    return math.nan if value is None else float(value)


def _count(value: Any) -> int | float:
    """A count as int, NaN for missing."""
    return math.nan if value is None else int(value)


def _curve(values: Sequence[Any]) -> np.ndarray:
    """A coverage curve from a report, NaN for a missing value."""
    return np.array([_num(v) for v in values])


def _three(values: Sequence[Any] | None) -> list[float]:
    return [_num(v) for v in values] if values else [math.nan] * 3


def episode_row(record: dict[str, Any], auc_budget: int | None = None) -> dict[str, Any]:
    """The results.csv row of an episode record; NaN where the report has no value (a failed
    episode, or a report without `metrics`). With `auc_budget` the AUC columns are the
    coverage curve's over that many poses (`metrics.coverage_auc`), not the report's own."""
    fields = record["campaign"]
    metrics = record.get("metrics") or {}
    coverage, auc = metrics.get("coverage") or {}, metrics.get("auc") or {}
    if auc_budget is not None and metrics.get("coverage_curve"):
        auc = {t: coverage_auc(_curve(curve), auc_budget)
               for t, curve in metrics["coverage_curve"].items()}
    x, y, yaw = fields["object_pose"]
    row = {
        "planner": fields["planner"], "object": fields["object"], "trial": fields["trial"],
        "seed": fields["seed"], "status": fields["status"],
        "n_poses": _count(metrics.get("n_poses", record.get("n_poses"))),
        "n_useless_poses": _count(metrics.get("n_useless_poses")),
        "coverage_1cm": _num(coverage.get("0.01")), "coverage_2cm": _num(coverage.get("0.02")),
        "auc_1cm": _num(auc.get("0.01")), "auc_2cm": _num(auc.get("0.02")),
        "iou": _num(metrics.get("iou")),
        "object_x": x, "object_y": y, "object_yaw_deg": yaw,
        "termination": record.get("termination", ""),
        "wall_seconds": _num((record.get("timing") or {}).get("wall_seconds")),
        "error": fields["error"],
    }
    row.update(_accuracy_and_packing(record, metrics))
    for prefix, key in (("est", "estimated_dims"), ("true", "true_dims"),
                        ("abs_err", "abs_dim_errors")):
        row.update(zip((f"{prefix}_{d}" for d in "LWH"), _three(metrics.get(key)), strict=True))
    errors = [row[f"abs_err_{d}"] for d in "LWH"]
    row["worst_err"] = math.nan if any(map(math.isnan, errors)) else max(errors)
    row["misfit_flag"] = _flag((record.get("estimated_box") or {}).get("misfit_flag"))
    return row


def _flag(value: Any) -> float:
    return math.nan if value is None else float(bool(value))


def _accuracy_and_packing(record: dict[str, Any], metrics: dict[str, Any]) -> dict[str, Any]:
    """The box-accuracy, container and cycle-time columns. A pose count to an accuracy the
    episode never reached is the scenario's `max_poses` + 1, the same for every planner of a
    campaign, so that the median and the U test rank it last and tied (the episode's own
    length + 1 ranked a short episode that never got there above a long one)."""
    def poses_to(key: str) -> float:
        if key not in metrics:
            return math.nan
        if metrics[key] is None:
            return float(yaml.safe_load(record["scenario"])["max_poses"] + 1)
        return float(metrics[key])

    inside = metrics.get("truth_in_interval")
    packing = metrics.get("packing") or {}
    cycle = record.get("cycle_time") or {}
    return {
        "poses_to_5mm": poses_to("poses_to_5mm"), "poses_to_10mm": poses_to("poses_to_10mm"),
        "truth_in_interval": float(np.mean(inside)) if inside else math.nan,
        "container": (record.get("container") or {}).get("name") or "",
        "fits": _flag(packing.get("fits")), "right_size": _flag(packing.get("right_size")),
        "wasted_volume": _num(packing.get("wasted_volume")),
        "cycle_s": _num(cycle.get("total_s")), "motion_s": _num(cycle.get("motion_s")),
        "settle_s": _num(cycle.get("settle_s")),
        "computation_s": _num(cycle.get("computation_s")),
    }


def coverage_curves(records: Iterable[dict[str, Any]]) -> dict[tuple[str, str], list[np.ndarray]]:
    """{(object, planner): coverage-after-each-pose curves at the primary threshold} of the
    finished episodes that report metrics."""
    curves: dict[tuple[str, str], list[np.ndarray]] = {}
    for record in records:
        metrics, fields = record.get("metrics"), record["campaign"]
        if fields["status"] != "ok" or not metrics:
            continue
        curve = metrics["coverage_curve"][f"{metrics['primary_threshold']:g}"]
        curves.setdefault((fields["object"], fields["planner"]), []).append(_curve(curve))
    return curves


def auc_budgets(records: Iterable[dict[str, Any]]) -> dict[str, int]:
    """{object: the most poses any finished episode took on it}: the common budget its
    episodes' AUCs are compared over. Each over its own length, an episode that stopped after
    two good poses scored high: LR-NBV's AUC against HEU's came out significant on all four
    paper objects, on one over a common budget (docs/metrics.md, section 4)."""
    budgets: dict[str, int] = {}
    for record in records:
        metrics, fields = record.get("metrics"), record["campaign"]
        if fields["status"] == "ok" and metrics and metrics.get("coverage_curve"):
            length = max(len(c) for c in metrics["coverage_curve"].values())
            budgets[fields["object"]] = max(budgets.get(fields["object"], 1), length)
    return budgets


def write_results_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """One line per episode; missing numbers are written `nan`."""
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def read_results_csv(folder: str | Path) -> list[dict[str, str]]:
    """The rows of a campaign folder's results.csv (`write_results_csv`).

    Raises:
        ValueError: no results.csv in `folder`, or one without the campaign's planner,
            object and trial columns.
    """
    path = Path(folder) / "results.csv"
    try:
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
            columns = set(rows[0]) if rows else set()
    except OSError as e:
        raise ValueError(f"{path}: cannot read it ({e.strerror}); expected a campaign's "
                         f"folder (`lrnbv benchmark --out` or out/results/NAME)") from e
    missing = {"planner", "object", "trial"} - columns
    if missing:
        raise ValueError(f"{path}: no episodes with {', '.join(sorted(missing))}; expected "
                         f"the results.csv `lrnbv benchmark` writes")
    return rows


def summary_markdown(config: CampaignConfig, rows: Sequence[dict[str, Any]],
                     records: Sequence[dict[str, Any]]) -> str:
    """summary.md: settings, failures, medians with quartiles, and the U tests."""
    planners, object_labels = config.planners, [o.label for o in config.objects]
    ok = [r for r in rows if r["status"] == "ok"]
    failed = [r for r in rows if r["status"] != "ok"]
    placement = ("the scenario's, (x, y, yaw) = "
                 f"({config.scenario.object.x}, {config.scenario.object.y}, "
                 f"{config.scenario.object.yaw_deg} deg)" if config.placement is None else
                 f"random per trial: x in {list(config.placement.x)} m, y in "
                 f"{list(config.placement.y)} m, yaw in {list(config.placement.yaw_deg)} deg")
    lines = [
        "# Benchmark campaign", "",
        f"- planners: {', '.join(planner_label(p) for p in planners)}",
        f"- objects: {', '.join(object_labels)}",
        f"- trials: {config.trials} per planner and object; base seed {config.seed}; every "
        "planner gets the same seed and placement on the same (object, trial) (paired)",
        f"- placement: {placement}",
        f"- episodes: {len(rows)}, finished {len(ok)}, failed {len(failed)}", "",
    ]
    if failed:
        lines += ["## Failed episodes", "",
                  "Their tracebacks are in episodes/<episode>.json; rerun the same command to "
                  "retry them. They are left out of every statistic below.", ""]
        lines += table(["episode", "error"], (
            [f["episode"], first_line(f["error"])] for f in (r["campaign"] for r in records)
            if f["status"] != "ok"))
    no_metrics = sorted({r["campaign"]["planner"] for r in records
                         if r["campaign"]["status"] == "ok" and not r.get("metrics")})
    lines += ["## Medians and quartiles", "",
              "Each cell: median [Q1, Q3] (n = finished episodes with a value), or the value "
              "when n = 1; the IQR is Q3 - Q1. n/a: no value, because every episode failed or "
              "the reports carry no `metrics`."]
    if no_metrics:
        lines += ["", f"The reports of {', '.join(planner_label(p) for p in no_metrics)} "
                  "carry no `metrics` (box, IoU, coverage, useless poses): those are n/a and "
                  "only poses and wall time are summarised."]
    lines.append("")
    lines += pooled_section(config, ok)
    lines += oracle_section(config, ok)
    summaries = group_summaries(ok, [m.column for m in METRICS])
    empty = summarize([])
    for obj in object_labels:
        lines += [f"### {obj}", ""]
        lines += table(["metric", *(planner_label(p) for p in planners)], (
            [m.label, *(cell(summaries.get((obj, p), {}).get(m.column, empty))
                        for p in planners)] for m in METRICS))
    return "\n".join(lines + _comparison_section(config, ok)) + "\n"


def _share(rows: Sequence[dict[str, Any]], column: str) -> str:
    values = finite(r[column] for r in rows)
    return "n/a" if len(values) == 0 else f"{np.mean(values):.2f} (n={len(values)})"


def pooled_section(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> list[str]:
    """The summary's section over every object: `pooled_table` and `pooled_tests`."""
    lines = ["## Over every object", "",
             "Each planner's finished episodes pooled over objects and trials. The worst error "
             "is an episode's largest of its L, W and H errors; the interval's share is over "
             "(episode, dimension) pairs; a share is a mean of 1 (yes) and 0 (no).", "",
             *pooled_table(config, ok)]
    tests = pooled_tests(config, ok)
    if tests:
        lines += [f"Two-sided U tests of {planner_label(REFERENCE_PLANNER)} against each other "
                  "planner, pooled (U as below).", "",
                  *table(["metric", "U", "p", "n"], tests)]
    return lines


def pooled_table(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> list[str]:
    """Each planner over every object and trial: the worst-dimension error's median, 95th
    percentile and maximum, the shares of the truth inside the interval, of misfits flagged
    and of containers that fit and are the right size, the poses."""
    body = []
    for planner in config.planners:
        rows = [r for r in ok if r["planner"] == planner]
        worst = finite(r["worst_err"] for r in rows)
        spread = (["n/a"] * 3 if len(worst) == 0 else
                  [f"{1000 * v:.1f}" for v in np.percentile(worst, [50, 95, 100])])
        body.append([planner_label(planner), *spread,
                     *(_share(rows, c) for c in ("truth_in_interval", "misfit_flag", "fits",
                                                 "right_size")),
                     cell(summarize(r["n_poses"] for r in rows))])
    return table(["planner", "worst error median (mm)", "p95 (mm)", "max (mm)",
                   "truth in interval", "misfit flagged", "fits", "right size", "poses"], body)


def pooled_tests(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> list[list[str]]:
    """The U test of the worst error and of the poses of the reference planner against each
    other planner, pooled over objects: rows of (metric, U, p with * where significant,
    n); none without a reference and another planner."""
    ref, others = REFERENCE_PLANNER, rivals(config)
    if ref not in config.planners:
        return []
    body = []
    for other in others:
        for column, label in (("worst_err", "worst error"), ("n_poses", "poses")):
            t = mann_whitney((r[column] for r in ok if r["planner"] == ref),
                             (r[column] for r in ok if r["planner"] == other))
            body.append([f"{label}, vs {planner_label(other)}", fmt(t.u),
                         fmt(t.p, snap=False) + (" *" if t.significant else ""),
                         f"{t.n_a} / {t.n_b}"])
    return body


def rivals(config: CampaignConfig) -> list[str]:
    """The planners the reference is tested against: not itself, nor the oracle (a floor to
    measure against, `oracle_section`, not a rival)."""
    return [p for p in config.planners if p not in (REFERENCE_PLANNER, ORACLE)]


def _comparison_section(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> list[str]:
    ref, others = REFERENCE_PLANNER, rivals(config)
    lines = ["## Mann-Whitney U tests", ""]
    if ref not in config.planners or not others:
        ran = ", ".join(planner_label(p) for p in config.planners)
        return [*lines, f"n/a: the tests compare {planner_label(ref)} against the other "
                f"planners, and this campaign ran {ran}.", ""]
    if config.trials < 2:
        return [*lines, "n/a: with one trial per planner and object (n = 1) there is no "
                "spread to test a difference against; run two or more trials (the paper "
                "ran five: --trials 5).", ""]
    lines += [
        f"Two-sided `scipy.stats.mannwhitneyu` of {planner_label(ref)} against each other "
        "planner, per object and metric, over the finished episodes. U is "
        f"{planner_label(ref)}'s statistic: 0 when all its values are below the other's, "
        f"n1 x n2 when all above. * marks p < {ALPHA:g}. p is exact without ties (n <= 8) and "
        "exact over the permutations of the tied ranks with ties (small samples); n/a when a "
        "planner has no value; notes flag equal samples and sample sizes too small to ever "
        f"reach p < {ALPHA:g}.", ""]
    object_labels = [o.label for o in config.objects]
    tests = {(c.object, c.metric, c.other): c.test for c in compare_planners(
        ok, [m.column for m in METRICS], ref, others, object_labels)}
    header = ["metric"]
    for other in others:
        header += [f"vs {planner_label(other)}: {h}" for h in ("U", "p", "method; note")]
    for obj in object_labels:
        body = []
        for metric in METRICS:
            line = [metric.label]
            for other in others:
                t = tests[obj, metric.column, other]
                line += [fmt(t.u), fmt(t.p, snap=False) + (" *" if t.significant else ""),
                         "; ".join(filter(None, (t.method, t.note)))]
            body.append(line)
        lines += [f"### {obj}", "", *table(header, body)]
    return lines


def write_outputs(config: CampaignConfig, records: Sequence[dict[str, Any]]) -> None:
    """results.csv, summary.md, figure.png, coverage_curves.png and index.html from the
    records."""
    out_dir = config.out_dir
    budgets = auc_budgets(records)
    rows = [episode_row(r, budgets.get(r["campaign"]["object"])) for r in records]
    write_results_csv(out_dir / "results.csv", rows)
    (out_dir / "summary.md").write_text(summary_markdown(config, rows, records))
    object_labels = [o.label for o in config.objects]
    ok = [r for r in rows if r["status"] == "ok"]
    plot_campaign(ok, object_labels, config.planners, out_dir / "figure.png")
    plot_coverage_curves(coverage_curves(records), object_labels, config.planners,
                         out_dir / "coverage_curves.png")
    (out_dir / "index.html").write_text(index_page(out_dir, records, rows))

