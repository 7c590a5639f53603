"""The box stop rule (core/planning/stop.py) on constructed sequences of estimates."""

import types

import numpy as np
import pytest

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.planning.stop import BoxStop, BoxStopParams
from lrnbv_drake.core.sensor import ToFFrame


class Scripted:
    """A stand-in estimator whose fit after the n-th frame has the n-th scripted dims and,
    when asked for its interval, the n-th scripted readings width (1 mm unless given)."""

    def __init__(self, dims_mm, widths_mm=None):
        self.dims = [None if d is None else np.array(d) / 1000 for d in dims_mm]
        self.widths = [None if w is None else np.array(w) / 1000
                       for w in widths_mm or [(1, 1, 1)] * len(dims_mm)]
        self.added = 0
        self.starts = []

    def add(self, frame, X_WS):
        self.added += 1

    def estimate(self, start, interval=True):
        self.starts.append(start)
        d = self.dims[self.added - 1]
        width = self.widths[self.added - 1] if interval else None
        return None if d is None else types.SimpleNamespace(
            box=OrientedBox(np.zeros(3), d), readings_width=width)


def _acquisitions(n):
    return [(ToFFrame.empty(), np.eye(4))] * n


def _first_stop(dims_mm, params, widths_mm=None):
    dut = BoxStop(Scripted(dims_mm, widths_mm), params)
    for n in range(1, len(dims_mm) + 1):
        if dut.update(_acquisitions(n), None) is not None:
            return n
    return None


def test_it_stops_once_the_dimensions_held_still_over_k_poses_and_not_before():
    params = BoxStopParams(tolerance=0.005, stable_poses=2, min_poses=4)
    # mm: converging; poses 4, 5 and 6 within 5 mm of each other in every dimension.
    dims = [(250, 150, 110), (290, 190, 118), (310, 205, 121), (302, 201, 120),
            (300, 200, 120), (301, 202, 119), (300, 200, 120)]
    assert _first_stop(dims, params) == 6
    assert _first_stop(dims, BoxStopParams(0.005, 3, 4)) == 7  # three poses: one more
    assert _first_stop(dims, BoxStopParams(0.001, 2, 4)) is None  # 2 mm spread is too much


def test_it_waits_for_the_minimum_and_for_an_estimate():
    still = [(300, 200, 120)] * 6
    assert _first_stop(still, BoxStopParams(0.005, 2, 5)) == 5
    assert _first_stop([None, None, None, *still[:2]], BoxStopParams(0.005, 2, 1)) is None
    assert _first_stop([None, *still[:3]], BoxStopParams(0.005, 2, 1)) == 4


def test_a_still_box_with_a_side_the_readings_do_not_bound_does_not_stop():
    """Seed 0 of the horizontal box: the dimensions held still from pose 5 while no view had
    seen beyond the far end (a 118 mm wide length); it stops once a view bounds it."""
    still = [(297, 201, 120)] * 8
    widths = [(118, 4, 1)] * 6 + [(12, 3, 1)] * 2
    assert _first_stop(still, BoxStopParams(0.005, 2, 4), widths) == 7
    assert _first_stop(still, BoxStopParams(0.005, 2, 4, interval_width=0.2), widths) == 4
    assert _first_stop(still, BoxStopParams(0.005, 2, 4, interval_width=0.01), widths) is None
    # A refit that found no reading near the box hands back an older fit without a width.
    assert _first_stop(still, BoxStopParams(0.005, 2, 4), [None] * 8) is None


def test_each_acquisition_is_added_once_and_the_cell_box_starts_the_fit():
    estimator = Scripted([(300, 200, 120)] * 3)
    dut = BoxStop(estimator, BoxStopParams())
    start = OrientedBox(np.zeros(3), np.array([0.31, 0.21, 0.13]))
    dut.update(_acquisitions(2), start)
    dut.update(_acquisitions(3), start)
    assert estimator.added == 3 and estimator.starts == [start] * 3


def test_bad_thresholds_are_refused():
    with pytest.raises(ValueError, match="tolerance"):
        BoxStopParams(tolerance=0.0)
    with pytest.raises(ValueError, match="interval_width"):
        BoxStopParams(interval_width=0.0)
