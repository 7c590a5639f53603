"""The box utility (`planner.utility: box`): each side's band from the estimate's interval,
the width of every band a view's rays cross before the table or the bound part of the
object, by hand and on an estimate of rendered readings; and its division by the seconds a
view costs."""

import numpy as np
import pytest
from rendered_views import render

from lrnbv_drake.core.boxes import AlignedBox, OrientedBox
from lrnbv_drake.core.estimation.estimator import ShapeEstimator
from lrnbv_drake.core.estimation.params import EstimationParams
from lrnbv_drake.core.planning.box_gain import SideBands, box_gains
from lrnbv_drake.core.planning.config import PlannerParams
from lrnbv_drake.core.planning.lrnbv import LrNbvPolicy
from lrnbv_drake.core.planning.utility import Gains, sensor_rays
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.sensing.sensor import ZoneGeometry
from lrnbv_drake.station.parts import sensor_behaviour
from lrnbv_drake.station.scenario import load_scenario

DOWN = np.array([[0.0, 0.0, 1.0]])  # one ray along the sensor's optical axis


def _down_at(x: float, y: float, z: float) -> np.ndarray:
    return look_at([x, y, z], [x, y, 0.0], up=(1.0, 0.0, 0.0))


def test_a_ray_gains_the_width_of_each_band_it_crosses_before_the_bound_part_or_the_table():
    """A box 0.30 x 0.20 x 0.12 m at (0.5, 0.1) on a table at 0.02 m whose length may be
    0.26-0.34 m (each end moves 2 cm), width 0.19-0.21 (5 mm) and height 0.11-0.13 (2 cm at
    the top). Looking straight down: over the centre a ray crosses the top band and stops on
    the bound part (the box of the lower dimensions); at x = 0.5 + 0.15 it crosses the top
    band and then the +x end's band down to the table; beyond 0.17 nothing."""
    box = OrientedBox([0.5, 0.1, 0.08], [0.30, 0.20, 0.12])
    dut = SideBands.of(box, [0.26, 0.19, 0.11], [0.34, 0.21, 0.13], 0.02)
    np.testing.assert_allclose(dut.widths, [0.04, 0.04, 0.01, 0.01, 0.02])
    poses = np.array([_down_at(0.5, 0.1, 0.6), _down_at(0.65, 0.1, 0.6),
                      _down_at(0.68, 0.1, 0.6), _down_at(0.5, 0.1 + 0.1025, 0.6)])
    gains = box_gains(poses, dut, DOWN, max_range=1.0)
    np.testing.assert_allclose(gains, [0.02, 0.02 + 0.04, 0.0, 0.02 + 0.01])
    # A ray gains nothing beyond its range: the bands' top is 0.45 m down (0.6 - 0.15).
    np.testing.assert_allclose(box_gains(poses[1:2], dut, DOWN, max_range=0.44), [0.0])
    np.testing.assert_allclose(box_gains(poses[1:2], dut, DOWN, max_range=0.46), [0.06])
    # Turned a quarter turn, the same box's ends lie along y.
    turned = SideBands.of(OrientedBox([0.5, 0.1, 0.08], [0.30, 0.20, 0.12], np.pi / 2),
                          [0.26, 0.19, 0.11], [0.34, 0.21, 0.13], 0.02)
    np.testing.assert_allclose(box_gains(_down_at(0.5, 0.1 + 0.15, 0.6), turned, DOWN, 1.0),
                               [0.06])


def test_a_view_past_a_side_no_reading_bounds_beats_one_of_the_top():
    """The horizontal box rendered from the top and from its -x side only: the estimate's
    +x end is bounded by no reading of the table beyond it. A view from the +x side, which
    sees the table there, gains more than one just above the top."""
    frames, truth, model = render("{seed: 0}")
    c = truth.center
    seen = [(f, X) for f, X in frames if X[0, 3] < c[0] - 0.1 or
            np.hypot(*(X[:2, 3] - c[:2])) < 0.05]
    assert len(seen) >= 3
    scenario = load_scenario(data="{seed: 0}")
    estimator = ShapeEstimator(model, sensor_behaviour(scenario), 0.0,
                               tuple(scenario.cell.table_extent), EstimationParams())
    for frame, X_WS in seen:
        estimator.add(frame, X_WS)
        estimate = estimator.estimate(OrientedBox(c, truth.dims + 0.02, truth.yaw))
    bands = SideBands.of(estimate.box, estimate.dims_lower, estimate.dims_upper, 0.0)
    side = look_at(c + np.array([0.25, 0.0, 0.22]), c)
    top = _down_at(c[0], c[1], truth.dims[2] + 0.15)
    rays = sensor_rays(ZoneGeometry())
    gain_side, gain_top = box_gains(np.array([side, top]), bands, rays, max_range=1.0)
    assert gain_side > gain_top > 0


def test_the_box_utility_is_its_gains_over_the_seconds_a_view_costs():
    """Views with the same gains, 0.5 s and 2 s away, each frame 0.25 s: their box utilities
    are the weighted gains over 0.75 and 2.25 s, less 1 for a view in a visited cell."""
    params = PlannerParams(utility="box", box_exploration=0.5)
    workspace = AlignedBox(np.array([0.0, -0.5, 0.05]), np.array([0.8, 0.5, 0.9]))
    dut = LrNbvPolicy(params, ZoneGeometry(), workspace,
                      ik=lambda poses, q: (np.zeros((len(poses), 1, 6)),
                                           np.ones(len(poses), int)),
                      collision_free=lambda q: True,
                      travel_time=lambda q, Q: 5.0 * np.max(np.abs(Q - q), axis=1),
                      capture_seconds=0.25)
    gains = Gains(np.array([2.0, 2.0, 2.0]), np.ones(3), np.ones(3), np.array([0, 0, -1.0]),
                  box=np.array([0.04, 0.04, 0.04]))
    dut.utility.observe(Gains(np.array([4.0]), np.ones(1), np.ones(1), np.zeros(1),
                              box=np.array([0.08])))
    u = dut.utilities(gains, [np.full(6, 0.1), np.full(6, 0.4), np.full(6, 0.1)])
    # Gb / max Gb + 0.5 Ge / max Ge = 0.5 + 0.25, density and quality weigh 0; the third
    # view's cell was visited: it loses 1.
    np.testing.assert_allclose(u, 0.75 / np.array([0.75, 2.25, 0.75]) - [0, 0, 1])
    with pytest.raises(ValueError, match="capture_seconds"):
        LrNbvPolicy(params, ZoneGeometry(), workspace, ik=None, collision_free=None,
                    travel_time=lambda q, Q: 0.0)
