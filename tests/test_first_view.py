"""The product's first view frames the drop zone: each corner of the zone read by the
sensor's zones, checked by casting the corner zones' own rays onto the table; and an object
at the zone's edge is found by the first frame."""

import math

import numpy as np
import pytest

from lrnbv_drake.core.boxes import AlignedBox
from lrnbv_drake.core.planning.config import PlannerParams
from lrnbv_drake.core.planning.first_view import drop_zone_view
from lrnbv_drake.core.planning.lrnbv import LrNbvPolicy
from lrnbv_drake.core.planning.policy import Observation
from lrnbv_drake.core.sensing.sensor import ZoneGeometry
from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.scenario import ScenarioError, load_scenario

ZONE = (0.40, -0.15, 0.60, 0.15)  # 0.20 x 0.30 m
TABLE = 0.02


def _table_hits(X_WS: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(n, 2) where rays of the sensor at X_WS along `directions` (sensor frame) meet the
    table plane."""
    d = directions @ X_WS[:3, :3].T
    t = (TABLE - X_WS[2, 3]) / d[:, 2]
    return (X_WS[:3, 3] + t[:, None] * d)[:, :2]


@pytest.mark.parametrize("min_height", [0.1, 0.6])
def test_the_corner_zones_rays_land_on_or_beyond_each_corner_of_the_zone(min_height):
    geometry = ZoneGeometry()
    dut = drop_zone_view(ZONE, TABLE, geometry, min_height)
    np.testing.assert_allclose(dut[:3, 2], [0, 0, -1], atol=1e-12)  # looking straight down
    np.testing.assert_allclose(dut[:2, 3], [0.50, 0.0], atol=1e-12)
    grid = geometry.directions()
    corner_rays = np.array([grid[0, 0], grid[0, -1], grid[-1, 0], grid[-1, -1]])
    hits = _table_hits(dut, corner_rays)
    lower, upper = hits.min(axis=0), hits.max(axis=0)
    # Every corner of the zone lies inside the square the corner zones' centres read.
    assert np.all(lower <= [ZONE[0] + 1e-9, ZONE[1] + 1e-9])
    assert np.all(upper >= [ZONE[2] - 1e-9, ZONE[3] - 1e-9])
    height = dut[2, 3] - TABLE
    if min_height < 0.3:
        # At the least height: the corner rays meet the zone's longer sides (y, +-0.15 m),
        # 0.15 / tan(45 / 2 - 45 / 16) above the table.
        assert height == pytest.approx(0.15 / math.tan(math.radians(22.5 - 45 / 16)))
        np.testing.assert_allclose([lower[1], upper[1]], [ZONE[1], ZONE[3]], atol=1e-9)
    else:
        assert height == pytest.approx(min_height)


def test_a_zone_turned_inside_out_is_refused_naming_it():
    with pytest.raises(ValueError, match=r"drop zone \[0.6, 0.0, 0.4, 0.1\]"):
        drop_zone_view((0.6, 0.0, 0.4, 0.1), 0.0, ZoneGeometry(), 0.4)
    with pytest.raises(ScenarioError, match=r"field 'cell.drop_zone'"):
        load_scenario(data="{cell: {drop_zone: [0.6, 0.0, 0.4, 0.1]}}")
    with pytest.raises(ScenarioError, match=r"field 'planner.first_view': expected one of"):
        load_scenario(data="{planner: {first_view: above}}")


def test_lrnbv_proposes_the_first_view_once_before_any_frame_and_counts_no_iteration():
    view = drop_zone_view(ZONE, TABLE, ZoneGeometry(), 0.45)
    workspace = AlignedBox(np.array([0.0, -0.5, 0.05]), np.array([0.8, 0.5, 0.9]))
    dut = LrNbvPolicy(PlannerParams(), ZoneGeometry(), workspace,
                      ik=lambda poses, q: (np.zeros((len(poses), 1, 6)),
                                           np.ones(len(poses), int)),
                      collision_free=lambda q: True, first_view=view)
    assert not dut.capture_initial
    start = Observation(time=0.0, q=np.zeros(6), X_WS=np.eye(4), n_acquisitions=0)
    proposal = dut.propose(start)
    assert not proposal.done and len(proposal.candidates) == 1
    np.testing.assert_array_equal(proposal.candidates[0], view)
    assert proposal.info == {"first_view": "drop_zone"}
    dut.accepted(0, start)
    assert dut.iteration == 0
    # Asked again before any frame, the view was out of reach: the episode ends, saying so.
    again = dut.propose(start)
    assert again.done and "out of the arm's reach" in again.reason
    assert "planner.first_view: home" in again.reason


@pytest.mark.parametrize("first_view, found", [("drop_zone", True), ("home", False)])
def test_an_object_at_the_zones_edge_is_found_by_the_drop_zone_views_first_frame(
        tmp_path, first_view, found):
    """The horizontal box (0.30 x 0.20 x 0.12 m) centred on the default drop zone's -y edge:
    HOME's frame, centred 0.13 m to +y, sees at most a sliver of its top; the drop zone's
    view, over the zone's centre, finds it."""
    scenario = load_scenario(data=(
        f"{{seed: 0, max_poses: 1, object: {{name: horizontal_box, x: 0.5, y: -0.12}}, "
        f"planner: {{first_view: {first_view}}}}}"))
    report = run_episode(scenario, "lrnbv", tmp_path).report
    assert report["n_poses"] == 1
    assert report["metrics"]["box_found"] is found
