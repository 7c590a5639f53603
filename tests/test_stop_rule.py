"""The box stop rule (core/planning/stop.py) on constructed tracks of estimates."""

import numpy as np
import pytest

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation.estimator import BoxEstimate
from lrnbv_drake.core.estimation.track import EstimateTrack
from lrnbv_drake.core.planning.config import StopParams
from lrnbv_drake.core.planning.stop import BoxStop


def _estimate(dims_mm, width_mm=(1, 1, 1), chosen=True):
    """An estimate of dims (mm) whose interval is `width_mm` wide (None: the cell box) and
    whose class the criterion keeps (`chosen`)."""
    if dims_mm is None:
        return None
    dims = np.array(dims_mm) / 1000
    if width_mm is None:
        return BoxEstimate.of_cells(OrientedBox(np.zeros(3), dims))
    half = np.array(width_mm) / 2000
    return BoxEstimate(OrientedBox(np.zeros(3), dims), None,
                       interval=lambda: (dims - half, dims + half, chosen))


def _first_stop(dims_mm, params, widths_mm=None, chosen=None):
    """The number of poses after which `BoxStop` first stops, or None."""
    dut = BoxStop(params)
    widths = widths_mm or [(1, 1, 1)] * len(dims_mm)
    chosen = chosen or [True] * len(dims_mm)
    estimates = [_estimate(d, w, c) for d, w, c in zip(dims_mm, widths, chosen, strict=True)]
    for n in range(1, len(estimates) + 1):
        if dut.update(EstimateTrack(tuple(estimates[:n]))) is not None:
            return n
    return None


def test_it_stops_once_the_dimensions_held_still_over_k_poses_and_not_before():
    params = StopParams(tolerance=0.005, stable_poses=2, min_poses=4)
    # mm: converging; poses 4, 5 and 6 within 5 mm of each other in every dimension.
    dims = [(250, 150, 110), (290, 190, 118), (310, 205, 121), (302, 201, 120),
            (300, 200, 120), (301, 202, 119), (300, 200, 120)]
    assert _first_stop(dims, params) == 6
    assert _first_stop(dims, StopParams(tolerance=0.005, stable_poses=3, min_poses=4)) == 7
    assert _first_stop(dims, StopParams(tolerance=0.001, stable_poses=2, min_poses=4)) is None


def test_it_waits_for_the_minimum_and_for_an_estimate():
    still = [(300, 200, 120)] * 6
    assert _first_stop(still, StopParams(stable_poses=2, min_poses=5)) == 5
    assert _first_stop([None, None, None, *still[:2]],
                       StopParams(stable_poses=2, min_poses=1)) is None
    assert _first_stop([None, *still[:3]], StopParams(stable_poses=2, min_poses=1)) == 4


def test_a_still_box_with_a_side_no_reading_bounds_does_not_stop():
    """The dimensions hold still from the first pose while one side is open (a 118 mm wide
    interval on the length): the rule stops once a view bounds it, at its width."""
    still = [(297, 201, 120)] * 8
    widths = [(118, 4, 1)] * 6 + [(12, 3, 1)] * 2
    assert _first_stop(still, StopParams(), widths) == 7
    assert _first_stop(still, StopParams(interval_width=0.2), widths) == 4
    assert _first_stop(still, StopParams(interval_width=0.01), widths) is None
    # The cell box has no interval: it never says the box is known.
    assert _first_stop(still, StopParams(), [None] * 8) is None


def test_a_still_narrow_box_of_a_class_the_criterion_would_change_does_not_stop():
    """The box holds still with a narrow interval from the fourth pose, but until the sixth
    the interval finds a class of a part the criterion would choose over the fit's: the rule
    stops at the sixth."""
    still = [(297, 201, 120)] * 8
    assert _first_stop(still, StopParams(), chosen=[False] * 5 + [True] * 3) == 6
    assert _first_stop(still, StopParams(), chosen=[False] * 8) is None


def test_bad_thresholds_are_refused():
    with pytest.raises(ValueError, match="tolerance"):
        BoxStop(StopParams(tolerance=0.0))
    with pytest.raises(ValueError, match="interval_width"):
        BoxStop(StopParams(interval_width=0.0))


def test_the_interval_is_read_only_once_the_box_has_held_still():
    """An estimate's interval (a profile of every side and class) is computed only for the
    last estimate of a run that held still, not for every estimate the rule looks at."""
    read = []
    dims = [(250, 150, 110), (290, 190, 118), (310, 205, 121), (300, 200, 120),
            (300, 200, 120), (300, 200, 120)]
    estimates = []
    for i, d in enumerate(dims):
        box = OrientedBox(np.zeros(3), np.array(d) / 1000)
        estimates.append(BoxEstimate(box, None, interval=lambda i=i, box=box: (
            read.append(i) or (box.dims - 0.0005, box.dims + 0.0005, True))))
    dut = BoxStop(StopParams(tolerance=0.005, stable_poses=2, min_poses=1))
    stops = [dut.update(EstimateTrack(tuple(estimates[:n]))) for n in range(1, 7)]
    assert [s is not None for s in stops] == [False] * 5 + [True]
    assert read == [5]
