"""Summary statistics and Mann-Whitney U comparisons of a benchmark campaign's episodes.

The paper ("Results") compares LR-NBV with NBV and HEU by the Mann-Whitney U test over five
reconstructions per object, so this module gives, per group of episodes, the median and the
quartiles (robust for five skewed samples), and the two-sided U test between two planners.

No Drake here: rows are plain mappings (a results.csv row), metric values floats with NaN for
"not measured" (a failed episode, a report without metrics). NaN values are left out of every
statistic, and each result carries how many values it used.
"""

from __future__ import annotations

import dataclasses as dc
import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
from scipy import stats

#: Significance level of the paper's comparisons.
ALPHA = 0.05
#: With ties, the p-value is exact (all splits of the pooled sample enumerated) up to this many
#: splits; beyond it, the normal approximation with tie correction is good enough.
MAX_EXACT_SPLITS = 9999


@dc.dataclass(frozen=True)
class Summary:
    """Median and quartiles (numpy's linear interpolation) of the finite values of a sample."""

    n: int
    median: float
    q1: float
    q3: float

    @property
    def iqr(self) -> float:
        """Interquartile range, Q3 - Q1."""
        return self.q3 - self.q1


def finite(values: Iterable[float]) -> np.ndarray:
    """The finite values, as floats: NaN marks a value that was not measured."""
    array = np.asarray(list(values), dtype=np.float64)
    return array[np.isfinite(array)]


def summarize(values: Iterable[float]) -> Summary:
    """Median and quartiles of the finite `values`; NaN statistics (n = 0) for none."""
    sample = finite(values)
    if len(sample) == 0:
        return Summary(0, math.nan, math.nan, math.nan)
    q1, median, q3 = np.percentile(sample, [25, 50, 75])
    return Summary(len(sample), float(median), float(q1), float(q3))


@dc.dataclass(frozen=True)
class MannWhitney:
    """A two-sided Mann-Whitney U test of sample a against sample b.

    Args:
        n_a, n_b: finite values used from each sample.
        u: U statistic of sample a (pairs where a's value is larger, ties counting half), so
            0 means every a is below every b and n_a * n_b every a above; NaN when not tested.
        p: two-sided p-value; NaN when not tested.
        method: how p was computed ("exact", "exact, ties", "normal approximation"), or "n/a".
        note: why the test is n/a, or what limits it; empty when nothing does.
    """

    n_a: int
    n_b: int
    u: float
    p: float
    method: str
    note: str = ""

    @property
    def tested(self) -> bool:
        """Whether there was a test at all (both samples had values)."""
        return math.isfinite(self.p)

    @property
    def significant(self) -> bool:
        """p < ALPHA."""
        return self.tested and self.p < ALPHA


def min_two_sided_p(n_a: int, n_b: int) -> float:
    """The smallest two-sided p-value the exact U test can give without ties: both extreme
    orderings out of the C(n_a + n_b, n_a) equally likely ones."""
    return min(1.0, 2.0 / math.comb(n_a + n_b, n_a))


def mann_whitney(a: Iterable[float], b: Iterable[float]) -> MannWhitney:
    """Two-sided Mann-Whitney U test of `a` against `b` (`scipy.stats.mannwhitneyu`).

    The p-value is exact when it can be: without ties scipy's exact distribution for small
    samples; with ties (frequent here: HEU always takes 13 poses) the exact permutation
    distribution of the tied ranks, which the normal approximation misjudges at n = 5. Two-sided
    p is twice the smaller one-sided p, capped at 1 (scipy's convention). Samples with all
    values equal give p = 1: nothing tells them apart. An empty sample is n/a.
    """
    x, y = finite(a), finite(b)
    if len(x) == 0 or len(y) == 0:
        empty = " and ".join(name for name, s in (("a", x), ("b", y)) if len(s) == 0)
        return MannWhitney(len(x), len(y), math.nan, math.nan, "n/a",
                           f"no values in {empty}")
    pooled = np.concatenate([x, y])
    ties = len(np.unique(pooled)) < len(pooled)
    splits = math.comb(len(pooled), len(x))
    p_value = None
    if ties and splits <= MAX_EXACT_SPLITS and min(len(x), len(y)) >= 2:
        # n_resamples >= the number of distinct splits makes scipy enumerate them all.
        method, label = stats.PermutationMethod(n_resamples=MAX_EXACT_SPLITS), "exact, ties"
    elif ties and min(len(x), len(y)) == 1:
        # scipy's permutation test wants two values per sample; with one, the splits are
        # which pooled value it is, few enough to enumerate here.
        method, label = "asymptotic", "exact, ties"
        p_value = _one_value_p(x, y)
    elif ties or min(len(x), len(y)) > 8:
        method, label = "asymptotic", "normal approximation"
    else:
        method, label = "exact", "exact"
    result = stats.mannwhitneyu(x, y, alternative="two-sided", method=method)
    notes = []
    if np.all(pooled == pooled[0]):
        notes.append("all values equal")
    smallest = min_two_sided_p(len(x), len(y))
    if smallest >= ALPHA:
        notes.append(f"n = {len(x)} and {len(y)} cannot reach p < {ALPHA:g} "
                     f"(smallest p {smallest:.2g})")
    return MannWhitney(len(x), len(y), float(result.statistic),
                       float(result.pvalue if p_value is None else p_value), label,
                       "; ".join(notes))


def _one_value_p(x: np.ndarray, y: np.ndarray) -> float:
    """The exact two-sided p of the U test when one sample holds one value: each pooled value
    in turn is that sample's, all equally likely; twice the smaller tail, capped at 1, as
    scipy's permutation test gives it for larger samples."""
    pooled = np.concatenate([x, y])
    single = 0 if len(x) == 1 else len(x)

    def u_of_a(k: int) -> float:
        others = np.delete(pooled, k)
        u = float(np.sum(others < pooled[k]) + 0.5 * np.sum(others == pooled[k]))
        return u if len(x) == 1 else len(others) - u  # U of a + U of b = n_a n_b

    us = np.array([u_of_a(k) for k in range(len(pooled))])
    observed = u_of_a(single)
    return min(1.0, 2.0 * min(np.mean(us <= observed), np.mean(us >= observed)))


Row = Mapping[str, object]


def _values(rows: Iterable[Row], metric: str) -> list[float]:
    """Each row's `metric` as a float, NaN where it has none (None, or an empty csv field)."""
    return [math.nan if row.get(metric) in (None, "") else float(row[metric]) for row in rows]


def group_summaries(
    rows: Sequence[Row], metrics: Sequence[str], by: tuple[str, ...] = ("object", "planner")
) -> dict[tuple[object, ...], dict[str, Summary]]:
    """{group key (the rows' `by` values): {metric: Summary}}, groups in order of appearance."""
    groups: dict[tuple[object, ...], list[Row]] = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in by), []).append(row)
    return {key: {m: summarize(_values(members, m)) for m in metrics}
            for key, members in groups.items()}


@dc.dataclass(frozen=True)
class Comparison:
    """One cell of the comparison table: `reference` against `other` on `metric` for `object`."""

    object: str
    metric: str
    reference: str
    other: str
    test: MannWhitney


def compare_planners(
    rows: Sequence[Row], metrics: Sequence[str], reference: str, others: Sequence[str],
    objects: Sequence[str],
) -> list[Comparison]:
    """The U test of `reference` against each of `others` on every metric, per object."""
    table = []
    for obj in objects:
        of_object = [r for r in rows if r["object"] == obj]
        ref_rows = [r for r in of_object if r["planner"] == reference]
        for other in others:
            other_rows = [r for r in of_object if r["planner"] == other]
            table.extend(
                Comparison(obj, m, reference, other,
                           mann_whitney(_values(ref_rows, m), _values(other_rows, m)))
                for m in metrics)
    return table


@dc.dataclass(frozen=True)
class PairedChange:
    """One metric of one planner's episodes before and after a change, pair by pair: the same
    (object, trial), so the same seed and placement, and only the change between them.

    Args:
        n: pairs with a value on both sides.
        before, after: median and quartiles of each side's values over those pairs.
        before_mean, after_mean: their means (a share for a yes/no metric).
        before_p95, after_p95: their 95th percentiles.
        lower, higher: pairs whose value fell, rose, by more than the tolerance.
        p: two-sided Wilcoxon signed-rank p of the differences; NaN where none differs.
    """

    planner: str
    metric: str
    n: int
    before: Summary
    after: Summary
    before_mean: float
    after_mean: float
    before_p95: float
    after_p95: float
    lower: int
    higher: int
    p: float


def paired_changes(before: Sequence[Row], after: Sequence[Row], metrics: Sequence[str],
                   tolerance: Mapping[str, float] | None = None) -> list[PairedChange]:
    """Each planner's `metrics` compared pair by pair between two campaigns' rows (results.csv
    rows, matched on planner, object and trial; a pair missing either value is left out).
    Why paired: a change to the estimator moves each episode by less than episodes differ
    from each other, which a test of the pooled samples cannot see. `tolerance` (per metric,
    default 0) is the move that counts as lower or higher."""
    def key(row: Row) -> tuple[str, str, str]:
        return str(row["planner"]), str(row["object"]), str(row["trial"])

    def p95(v: np.ndarray) -> float:
        return float(np.percentile(v, 95)) if len(v) else math.nan

    def mean(v: np.ndarray) -> float:
        return float(np.mean(v)) if len(v) else math.nan

    tolerance = tolerance or {}
    later = {key(row): row for row in after}
    out = []
    for planner in dict.fromkeys(str(row["planner"]) for row in before):
        pairs = [(row, later[key(row)]) for row in before
                 if row["planner"] == planner and key(row) in later]
        for metric in metrics:
            x = np.array(_values((a for a, _ in pairs), metric))
            y = np.array(_values((b for _, b in pairs), metric))
            both = np.isfinite(x) & np.isfinite(y)
            x, y = x[both], y[both]
            step = tolerance.get(metric, 0.0)
            p = float(stats.wilcoxon(x, y).pvalue) if np.any(x != y) else math.nan
            out.append(PairedChange(
                planner, metric, len(x), summarize(x), summarize(y), mean(x), mean(y),
                p95(x), p95(y), int(np.sum(y < x - step)), int(np.sum(y > x + step)), p))
    return out
