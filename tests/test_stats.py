"""Summary statistics and Mann-Whitney U tests, against hand-worked values and scipy."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from lrnbv_drake.core.evaluation.stats import (
    compare_planners,
    group_summaries,
    mann_whitney,
    min_two_sided_p,
    paired_changes,
    summarize,
)


def _enumerated_p(a, b):
    """U of a and its exact two-sided p computed without scipy's U test: U over every split of
    the pooled values into a and b (mid-ranks for ties), p twice the smaller tail (capped at 1),
    scipy's convention, the same as |U - mean| >= observed when the null is symmetric."""
    pooled = np.array(list(a) + list(b), float)
    ranks = stats.rankdata(pooled)
    n = len(a)

    def u(idx):
        return ranks[list(idx)].sum() - n * (n + 1) / 2

    observed = u(range(n))
    splits = np.array([u(c) for c in itertools.combinations(range(len(pooled)), n)])
    tails = np.mean(splits <= observed + 1e-12), np.mean(splits >= observed - 1e-12)
    return observed, min(1.0, 2 * min(tails))


def test_summary_hand_worked():
    s = summarize([4, 1, 3, 2])
    # Sorted 1 2 3 4: median (2 + 3) / 2; Q1 at position 0.75 -> 1.75; Q3 at 2.25 -> 3.25.
    assert (s.n, s.median, s.q1, s.q3, s.iqr) == (4, 2.5, 1.75, 3.25, 1.5)
    s = summarize([5, 6, 7, 8, 9])
    assert (s.median, s.q1, s.q3, s.iqr) == (7, 6, 8, 2)
    assert summarize([13] * 5).iqr == 0


def test_summary_drops_nan_and_empty_is_nan():
    assert summarize([1.0, math.nan, 3.0]) == summarize([1.0, 3.0])
    assert summarize([1.0, math.nan, 3.0]).n == 2
    empty = summarize([math.nan])
    assert empty.n == 0 and math.isnan(empty.median) and math.isnan(empty.iqr)


def test_summary_agrees_with_scipy():
    rng = np.random.default_rng(7)
    for n in (1, 2, 5, 11):
        x = rng.normal(size=n)
        s = summarize(x)
        assert s.median == pytest.approx(np.median(x))
        assert s.iqr == pytest.approx(stats.iqr(x))


def test_u_test_tiny_sample_by_hand():
    # Every value of a below every value of b: U = 0. Exact null: the 20 equally likely ways
    # to choose a's 3 ranks out of 6; only {1,2,3} and {4,5,6} are as extreme -> p = 2/20.
    t = mann_whitney([1, 2, 3], [4, 5, 6])
    assert (t.u, t.p, t.method) == (0.0, pytest.approx(0.1), "exact")
    assert not t.significant
    assert "cannot reach p < 0.05" in t.note
    reverse = mann_whitney([4, 5, 6], [1, 2, 3])
    assert (reverse.u, reverse.p) == (9.0, pytest.approx(0.1))
    ref = stats.mannwhitneyu([1, 2, 3], [4, 5, 6], alternative="two-sided")
    assert (t.u, t.p) == (pytest.approx(ref.statistic), pytest.approx(ref.pvalue))


def test_u_test_matches_scipy_without_ties():
    a = [0.91, 0.95, 0.88, 0.97, 0.93]
    b = [0.85, 0.90, 0.82, 0.87, 0.89]
    t = mann_whitney(a, b)
    ref = stats.mannwhitneyu(a, b, alternative="two-sided")
    assert t.u == ref.statistic and t.p == pytest.approx(ref.pvalue)
    # a beats b in 23 of the 25 pairs (0.88 < 0.89 and 0.88 < 0.90).
    assert t.u == 23
    assert t.p == pytest.approx(_enumerated_p(a, b)[1])
    assert t.significant and t.note == ""


def test_u_test_with_ties_is_exact():
    # Ranks of 1 2 2 2 3 3: 1, 3, 3, 3, 5.5, 5.5; a's rank sum 7, U = 7 - 3*4/2 = 1.
    t = mann_whitney([1, 2, 2], [2, 3, 3])
    assert t.u == 1.0 and t.method == "exact, ties"
    assert t.p == pytest.approx(_enumerated_p([1, 2, 2], [2, 3, 3])[1]) == pytest.approx(0.3)
    # Poses of a planner that stops early against HEU's constant 13: 2 of 252 splits.
    t = mann_whitney([5, 6, 5, 7, 6], [13] * 5)
    assert (t.u, t.p) == (0.0, pytest.approx(2 / 252))
    assert t.significant


def test_u_test_with_ties_and_one_value_is_exact_too():
    """scipy's permutation test wants two values a sample; with one, the p is still the exact
    one (the normal approximation gave 0.717 for the first pair)."""
    for a, b in (([1.0], [2, 2, 3, 0]), ([2, 2, 3, 0], [1.0]), ([13.0], [13, 13, 9, 13])):
        t = mann_whitney(a, b)
        assert t.method == "exact, ties"
        assert (t.u, t.p) == pytest.approx(_enumerated_p(a, b))
    assert mann_whitney([1.0], [2, 2, 3, 0]).p == pytest.approx(0.8)  # 2 x 2 of 5 splits


def test_u_test_equal_constant_samples_give_p_one():
    t = mann_whitney([13] * 5, [13] * 5)
    assert (t.u, t.p) == (12.5, 1.0)
    assert "all values equal" in t.note and not t.significant


def test_u_test_empty_sample_is_na_and_nan_is_dropped():
    t = mann_whitney([math.nan, math.nan], [1, 2])
    assert t.n_a == 0 and not t.tested and not t.significant
    assert math.isnan(t.u) and math.isnan(t.p) and t.method == "n/a"
    assert t.note == "no values in a"
    assert mann_whitney([1, 2, 3, math.nan], [4, 5, 6]) == mann_whitney([1, 2, 3], [4, 5, 6])


def test_large_samples_with_ties_use_the_normal_approximation():
    a = [1, 2, 2, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 6]
    b = [3, 4, 4, 5, 5, 5, 6, 6, 6, 7, 7, 8, 8, 9]
    t = mann_whitney(a, b)
    ref = stats.mannwhitneyu(a, b, alternative="two-sided", method="asymptotic")
    assert t.method == "normal approximation"
    assert (t.u, t.p) == (ref.statistic, pytest.approx(ref.pvalue))


def test_smallest_reachable_p():
    assert min_two_sided_p(3, 3) == pytest.approx(0.1)
    assert min_two_sided_p(5, 5) == pytest.approx(2 / 252)
    assert min_two_sided_p(1, 1) == 1.0


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 4), min_size=1, max_size=5),
       st.lists(st.integers(0, 4), min_size=1, max_size=5))
def test_u_test_properties(a, b):
    ab, ba = mann_whitney(a, b), mann_whitney(b, a)
    assert ab.u + ba.u == len(a) * len(b)
    assert ab.p == pytest.approx(ba.p)
    assert 0 < ab.p <= 1
    u, p = _enumerated_p(a, b)
    assert ab.u == u
    if ab.method.startswith("exact"):
        assert ab.p == pytest.approx(p)


ROWS = [
    {"object": "box", "planner": "lrnbv", "n_poses": 5.0},
    {"object": "box", "planner": "lrnbv", "n_poses": 7.0},
    {"object": "box", "planner": "lrnbv", "n_poses": 6.0},
    {"object": "box", "planner": "heu", "n_poses": 13.0},
    {"object": "box", "planner": "heu", "n_poses": 13.0},
    {"object": "box", "planner": "heu", "n_poses": None},
]


def test_group_summaries_and_comparisons():
    groups = group_summaries(ROWS, ["n_poses"])
    assert list(groups) == [("box", "lrnbv"), ("box", "heu")]
    assert groups["box", "lrnbv"]["n_poses"] == summarize([5, 6, 7])
    assert groups["box", "heu"]["n_poses"].n == 2  # the None is not measured
    (c,) = compare_planners(ROWS, ["n_poses"], "lrnbv", ["heu"], ["box"])
    assert (c.object, c.metric, c.reference, c.other) == ("box", "n_poses", "lrnbv", "heu")
    assert c.test == mann_whitney([5, 7, 6], [13, 13])
    assert c.test.u == 0


def test_paired_changes_match_episodes_by_planner_object_and_trial():
    """Five episodes before and after, the after rows shuffled and one of them missing a
    value: errors 1, 2, 3, 4 mm (the fifth left out) become 1, 1, 8, 2 mm; moves of -1, +5, -2
    mm, so with a 0.5 mm tolerance two fell and one rose; the median 2.5 -> 1.5 mm; the
    Wilcoxon p that of scipy on the four pairs."""
    before = [{"planner": "lrnbv", "object": o, "trial": "0", "worst_err": e}
              for o, e in zip("abcde", ("0.001", "0.002", "0.003", "0.004", "0.005"), strict=True)]
    before.append({"planner": "heu", "object": "a", "trial": "0", "worst_err": "0.001"})
    after = [{"planner": "lrnbv", "object": o, "trial": "0", "worst_err": e}
             for o, e in zip("dbace", ("0.002", "0.001", "0.001", "0.008", ""), strict=True)]
    after.append({"planner": "heu", "object": "a", "trial": "0", "worst_err": "0.001"})
    lrnbv, heu = paired_changes(before, after, ["worst_err"], {"worst_err": 0.0005})
    assert (lrnbv.planner, lrnbv.n, lrnbv.lower, lrnbv.higher) == ("lrnbv", 4, 2, 1)
    assert lrnbv.before.median == pytest.approx(0.0025)
    assert lrnbv.after.median == pytest.approx(0.0015)
    assert lrnbv.after_mean == pytest.approx(0.003)
    assert lrnbv.p == pytest.approx(stats.wilcoxon([0.001, 0.002, 0.003, 0.004],
                                                   [0.001, 0.001, 0.008, 0.002]).pvalue)
    assert (heu.n, heu.lower, heu.higher) == (1, 0, 0) and math.isnan(heu.p)

