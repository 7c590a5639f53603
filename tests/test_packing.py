"""The packing decision (core/evaluation/packing.py, and its margin in experiments/report.py) on
hand-worked cases."""

import dataclasses as dc

import numpy as np
import pytest

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation.estimator import BoxEstimate, confidence
from lrnbv_drake.core.evaluation.packing import (
    CatalogueError,
    Container,
    choose_container,
    load_catalogue,
    packing_metrics,
)
from lrnbv_drake.station.parts import container_catalogue, packing_decision
from lrnbv_drake.station.scenario import Scenario

FLAT = Container("flat", (0.40, 0.30, 0.10), 0.50)
TALL = Container("tall", (0.20, 0.20, 0.40), 0.60)
BIG = Container("big", (0.50, 0.40, 0.40), 1.00)
NONE = np.zeros(3)


def test_a_box_that_fits_only_stood_on_its_end_is_stood_on_its_end():
    # 0.35 x 0.12 x 0.25: `flat` is too low (0.10) and `tall` too narrow (0.20 < 0.25) in every
    # orientation; `upright` (0.30 x 0.13 x 0.36) holds it only with its length up and its
    # height along the container's length: (0.25, 0.12, 0.35).
    upright = Container("upright", (0.30, 0.13, 0.36), 0.40)
    decision = choose_container(np.array([0.35, 0.12, 0.25]), NONE, 0.0, [FLAT, TALL, upright])
    assert decision.container == upright
    assert decision.orientation == (2, 1, 0)
    np.testing.assert_allclose(decision.required[list(decision.orientation)],
                               [0.25, 0.12, 0.35])


def test_the_margin_pushes_the_box_into_the_next_size():
    dims = np.array([0.38, 0.28, 0.08])
    assert choose_container(dims, NONE, 0.01, [FLAT, BIG]).container == FLAT  # 0.39 x 0.29
    decision = choose_container(dims, np.array([0.015, 0.0, 0.0]), 0.01, [FLAT, BIG])
    assert decision.container == BIG  # 0.405 > 0.40
    np.testing.assert_allclose(decision.required, [0.405, 0.29, 0.09])


def test_nothing_fits_names_the_dimension_that_fails():
    decision = choose_container(np.array([0.20, 0.70, 0.10]), NONE, 0.005, [FLAT, TALL, BIG])
    assert decision.container is None and decision.orientation is None
    assert "width of 0.705 m exceeds every container" in decision.reason
    assert "0.500 m" in decision.reason
    wide = choose_container(np.array([0.45, 0.45, 0.45]), NONE, 0.0, [FLAT, TALL, BIG])
    assert wide.container is None and "in any orientation" in wide.reason


def test_ties_go_to_the_cheaper_then_the_smaller_and_no_costs_mean_the_smallest():
    a = Container("a", (0.30, 0.30, 0.30), 1.0)
    b = Container("b", (0.40, 0.40, 0.40), 1.0)
    c = Container("c", (0.50, 0.50, 0.50), 0.9)
    dims = np.array([0.2, 0.2, 0.2])
    assert choose_container(dims, NONE, 0.0, [a, b, c]).container == c  # the cheapest
    assert choose_container(dims, NONE, 0.0, [b, a]).container == a  # same cost: smaller
    free = [Container("x", (0.5, 0.5, 0.5)), Container("y", (0.3, 0.3, 0.3))]
    assert choose_container(dims, NONE, 0.0, free).container.name == "y"  # by volume
    partly = [Container("x", (0.5, 0.5, 0.5), 1.0), Container("y", (0.3, 0.3, 0.3))]
    with pytest.raises(ValueError, match="1 of 2 have one"):  # prices against guesses
        choose_container(dims, NONE, 0.0, partly)


@pytest.mark.parametrize("dims, margin, clearance", [
    ([0.2, np.nan, 0.1], NONE, 0.0), ([0.2, 0.1, 0.1], [0.0, -0.01, 0.0], 0.0),
    ([0.2, 0.1, 0.1], [0.0, np.inf, 0.0], 0.0), ([0.2, 0.1, 0.1], NONE, -0.05),
    ([0.2, 0.1, 0.1], NONE, np.nan),
])
def test_a_box_margin_or_clearance_that_is_not_a_size_is_refused(dims, margin, clearance):
    # A negative clearance would put a 0.12 m tall box into a 0.10 m tall container.
    with pytest.raises(ValueError, match="expected"):
        choose_container(np.array(dims), np.array(margin), clearance, [FLAT, TALL, BIG])


def test_fits_and_right_size_against_the_true_box():
    catalogue = [FLAT, BIG]
    generous = choose_container(np.array([0.38, 0.28, 0.08]), np.full(3, 0.03), 0.0,
                                catalogue)
    assert generous.container == BIG
    m = packing_metrics(generous, np.array([0.38, 0.28, 0.08]), catalogue)
    assert m["fits"] and not m["right_size"] and m["right_size_container"] == "flat"
    assert m["wasted_volume"] == pytest.approx(0.5 * 0.4 * 0.4 / (0.4 * 0.3 * 0.1) - 1)
    short = choose_container(np.array([0.36, 0.28, 0.08]), NONE, 0.0, catalogue)
    m = packing_metrics(short, np.array([0.42, 0.28, 0.08]), catalogue)  # underestimated
    assert not m["fits"] and not m["right_size"]


@pytest.mark.parametrize("text, words", [
    ("boxes: []", "expected 'containers:'"),
    ("containers: [{name: a, inner: [0.1, 0.2]}]", "containers[0] (a): 'inner'"),
    ("containers: [{name: a, inner: [0.1, 0.2, 0.3], cost: -1}]", "'cost' must be"),
    ("containers: [{name: a, inner: [1, 1, 1]}, {name: a, inner: [1, 1, 1]}]", "new non-empty"),
    ("containers: [{name: a, inner: [1, 1, 1], colour: red}]", "expected a mapping"),
    ("containers: [{name: a, inner: [300, 200, 100]}]", "divide by 1000"),
    ("containers: [{name: a, inner: [.inf, 0.2, 0.1]}]", "three positive lengths"),
    ("containers: [{name: a, inner: [true, true, true]}]", "three positive lengths"),
    ("containers: [{name: a, inner: [0.1, 0.2, 0.3], cost: .inf}]", "'cost' must be"),
    ("containers: [{name: a, inner: [0.1, 0.2, 0.3], cost: true}]", "'cost' must be"),
    ("containers: [{name: a, inner: [1, 1, 1]}]\ncontainers: [{name: b, inner: [1, 1, 1]}]",
     "'containers' is given twice"),
    ("containers: [{name: a, inner: [1, 1, 1]}]\ncontainerz: []", "unknown keys ['containerz']"),
    ("containers: [{name: a, inner: [1, 1, 1], cost: 1}, {name: b, inner: [1, 1, 1]}]",
     "no 'cost' for b"),
])
def test_a_bad_catalogue_is_refused_naming_the_entry(text, words):
    with pytest.raises(CatalogueError, match=r"my\.yaml") as error:
        load_catalogue(text, source="my.yaml")
    assert words in str(error.value)


def test_the_shipped_catalogue_holds_every_paper_object_in_a_sensible_box():
    catalogue = container_catalogue(Scenario())
    expected = {(0.30, 0.20, 0.12): "L 32x23x15", (0.12, 0.10, 0.25): "L-tall 20x20x30",
                (0.150, 0.085, 0.060): "S 20x15x10", (0.20, 0.20, 0.05): "M-flat 30.5x22x10"}
    for dims, name in expected.items():
        decision = choose_container(np.array(dims), np.full(3, 0.01), 0.005, catalogue)
        assert decision.container.name == name, (dims, decision.reason)


def test_the_margin_is_the_intervals_outer_half_and_a_wider_interval_takes_a_larger_box():
    """A box of 0.134 x 0.124 x 0.037 m whose interval reaches 0.151 x 0.141 x 0.040: the
    margin is their difference, 17, 17 and 3 mm; the same box with an interval reaching
    0.20 x 0.20 x 0.05 (what a misfit widens it to) needs a larger container, and the
    report says where the margin came from. The cell box, without an interval, takes
    `packing.fixed_margin`."""
    scenario = Scenario()
    box = OrientedBox(np.array([0.5, 0.0, 0.0185]), np.array([0.134, 0.124, 0.037]))
    narrow = BoxEstimate(box, None, confidence=confidence(2.71),
                         interval=lambda: (box.dims - 0.01, np.array([0.151, 0.141, 0.04]), True))
    wide = BoxEstimate(box, None, misfit_flag=True, confidence=confidence(2.71),
                       interval=lambda: (box.dims - 0.01, np.array([0.2, 0.2, 0.05]), True))
    decided = packing_decision(scenario, narrow)
    np.testing.assert_allclose(decided.margin, [0.017, 0.017, 0.003], atol=1e-12)
    widened = packing_decision(scenario, wide)
    assert np.prod(widened.container.inner) > np.prod(decided.container.inner)
    assert "widened by the readings' misfit" in widened.margin_from
    assert decided.margin_from == "the estimate's 90 % profile interval"
    # A rise of 3.84 (`estimation.interval_level`) is a 95 % interval, and says so.
    wider_level = dc.replace(narrow, confidence=confidence(3.84))
    assert packing_decision(scenario, wider_level).margin_from == (
        "the estimate's 95 % profile interval")
    cells = packing_decision(scenario, BoxEstimate.of_cells(box))
    np.testing.assert_allclose(cells.margin, [scenario.packing.fixed_margin] * 3)
    assert cells.margin_from == "packing.fixed_margin"
