"""The oracle (core/evaluation/oracle.py): which sides of a true box each view measures, by
casting the zones' rays on the mesh; the greedy set cover, counted by hand; the policy's stop
on the truth; and its ratios in a campaign's summary."""

import dataclasses as dc
from pathlib import Path

import numpy as np
import pytest
import trimesh

from lrnbv_drake.core.boxes import AlignedBox, OrientedBox
from lrnbv_drake.core.evaluation.oracle import (
    SIDES,
    OraclePolicy,
    OracleViews,
    first_hits,
    greedy_step,
    oracle_views,
    side_cover,
)
from lrnbv_drake.core.planning.policy import CANDIDATE_RANK, Observation
from lrnbv_drake.core.planning.utility import sensor_rays
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.sensing.sensor import ZoneGeometry
from lrnbv_drake.experiments.campaign.oracle_table import oracle_line, oracle_ratios
from lrnbv_drake.experiments.campaign.plan import CampaignConfig, CampaignObject
from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.scenario import load_scenario

CENTRE = np.array([0.5, 0.0, 0.06])


@pytest.fixture(scope="module")
def carton():
    """The horizontal box, 0.30 x 0.20 x 0.12 m, on the table at x = 0.5, and its true box."""
    mesh = trimesh.creation.box(extents=(0.30, 0.20, 0.12))
    mesh.apply_translation(CENTRE)
    return mesh, OrientedBox.from_points(mesh.vertices, floor_z=0.0)


def _view(azimuth_deg, elevation_deg, distance=0.45):
    a, e = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    return look_at(CENTRE + distance * np.array(
        [np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]), CENTRE)


def greedy_cover(covers, cost=None):
    """The views of one greedy set cover of every side some view measures, in order, each
    step `greedy_step` with a fixed cost (default the view's index)."""
    cost = np.arange(len(covers), dtype=float) if cost is None else cost
    needed, open_views, order = covers.any(axis=0), np.ones(len(covers), bool), []
    while (i := greedy_step(covers, needed, cost, open_views)) is not None:
        order.append(i)
        open_views[i], needed = False, needed & ~covers[i]
    return order


def _rays(k=3):
    return sensor_rays(ZoneGeometry(), k).reshape(64, k * k, 3)


def test_rays_meet_the_box_top_the_table_or_nothing():
    mesh = trimesh.creation.box(extents=(0.2, 0.2, 0.1))
    mesh.apply_translation((0.0, 0.0, 0.05))
    origins = np.array([[0.0, 0.0, 0.5], [0.5, 0.0, 0.5], [0.0, 0.0, 0.5]])
    directions = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    dut, on_object = first_hits(mesh, 0.0, origins, directions)
    np.testing.assert_allclose(dut[0], [0.0, 0.0, 0.1], atol=1e-12)  # the top, not the bottom
    np.testing.assert_allclose(dut[1], [0.5, 0.0, 0.0], atol=1e-12)  # beside it: the table
    assert np.isnan(dut[2]).all()  # upwards: nothing
    np.testing.assert_array_equal(on_object, [True, False, False])


def test_each_view_measures_the_sides_it_faces_and_two_diagonal_views_cover_the_box(carton):
    """Worked by hand: straight down, the rays spread outwards past walls that face
    outwards, so only the top is measured; from +x at 30 degrees up, the +x wall and the
    top; from the +x+y diagonal, both walls it faces and the top; from the -x-y diagonal,
    the other two and the top. The greedy takes the +x+y diagonal (three sides), then the
    -x-y one (the two left): two poses."""
    mesh, box = carton
    views = np.array([look_at(CENTRE + np.array([0.0, 0.0, 0.45]), CENTRE, up=(1.0, 0.0, 0.0)),
                      _view(0, 30), _view(45, 30), _view(225, 30)])
    dut = side_cover(views, _rays(), mesh, 0.0, box, 0.005)
    measured = [{s for s, c in zip(SIDES, row, strict=True) if c} for row in dut]
    assert measured == [{"top"}, {"+x", "top"}, {"+x", "+y", "top"}, {"-x", "-y", "top"}]
    assert greedy_cover(dut) == [2, 3]


@pytest.mark.parametrize("yaw_deg", [30.0, 90.0])
def test_a_turned_box_seen_from_views_turned_with_it_measures_the_same_sides(carton, yaw_deg):
    """The box's sides are in its own frame: turning the box and the views together about
    the box's vertical axis measures the same sides. At 90 degrees the true box's canonical
    yaw is -90 (a box is the same under a half turn), so its +x is the turned box's -x:
    the walls swap names, +x with -x and +y with -y."""
    mesh, box = carton
    views = np.array([_view(0, 30), _view(45, 30), _view(225, 30), _view(90, 50)])
    turn = trimesh.transformations.rotation_matrix(np.deg2rad(yaw_deg), [0, 0, 1], CENTRE)
    turned_mesh = mesh.copy().apply_transform(turn)
    turned_box = OrientedBox.from_points(turned_mesh.vertices, floor_z=0.0)
    dut = side_cover(turn @ views, _rays(), turned_mesh, 0.0, turned_box, 0.005)
    expected = side_cover(views, _rays(), mesh, 0.0, box, 0.005)
    if yaw_deg == 90.0:
        assert turned_box.yaw == pytest.approx(-np.pi / 2)
        expected = expected[:, [1, 0, 3, 2, 4]]
    np.testing.assert_array_equal(dut, expected)


def test_a_sliver_of_a_side_under_half_a_zone_does_not_measure_it(carton):
    """Straight down over the +x wall's edge from 0.2 m, the edge falls on a boundary
    between zones: the zones inside it see the top, the nearest 3.3 mm of each in its
    innermost column of sub-rays only, three of nine; a zone measures a side where most of
    its sub-rays land within 5 mm of it, so the top is measured and no wall is."""
    mesh, box = carton
    above_edge = look_at(np.array([0.65, 0.0, 0.32]), np.array([0.65, 0.0, 0.0]),
                         up=(1.0, 0.0, 0.0))
    dut = side_cover(above_edge[None], _rays(), mesh, 0.0, box, 0.005)[0]
    np.testing.assert_array_equal(dut, [False, False, False, False, True])


def test_greedy_steps_take_the_most_sides_then_the_cheapest_and_stop_when_none_is_needed():
    covers = np.array([[1, 0, 0, 0, 1], [1, 1, 0, 0, 0], [0, 1, 1, 0, 0], [0, 0, 0, 1, 0]],
                      bool)
    needed, open_views = np.ones(5, bool), np.ones(4, bool)
    cost = np.array([3.0, 1.0, 2.0, 0.5])
    assert greedy_step(covers, needed, cost, open_views) == 1  # 2 sides, cheaper than 0 and 2
    # Then views 0, 2 and 3 each measure one side still needed: the cheapest, 3.
    assert greedy_step(covers, needed & ~covers[1], cost, open_views) == 3
    assert greedy_step(covers, np.zeros(5, bool), cost, open_views) is None
    # A fixed cost (the index by default): 0 then 2 then 3 covers all five, three views.
    assert greedy_cover(covers) == [0, 2, 3]


def test_candidate_views_look_at_the_box_from_the_grid_and_stay_in_the_workspace(carton):
    _, box = carton
    views = OracleViews(distances=(0.3,), elevations_deg=(30.0, 60.0), azimuth_step_deg=90.0)
    everywhere = AlignedBox(np.full(3, -5.0), np.full(3, 5.0))
    dut = oracle_views(box, views, everywhere)
    assert len(dut) == 4 * 2 + 1
    for X in dut:
        to_centre = box.center - X[:3, 3]
        assert np.linalg.norm(to_centre) == pytest.approx(0.3)
        np.testing.assert_allclose(X[:3, 2], to_centre / 0.3, atol=1e-12)
    front = AlignedBox(np.array([0.6, -5.0, -5.0]), np.full(3, 5.0))  # x >= 0.6 only
    assert np.all(oracle_views(box, views, front)[:, 0, 3] >= 0.6)
    assert len(oracle_views(box, views, front)) == 2  # azimuth 0 at both elevations


class _Estimate:
    def __init__(self, dims):
        self.box = OrientedBox(CENTRE, np.asarray(dims, float))


def _policy(covers, true_dims=(0.3, 0.2, 0.12)):
    covers = np.asarray(covers, bool)
    views = np.array([np.eye(4)] * len(covers))
    views[:, 0, 3] = np.arange(len(covers))  # view i at x = i: the travel time

    def ik(poses, q):
        return poses[:, None, :3, 3].repeat(2, axis=2), np.ones(len(poses), int)

    return OraclePolicy(views, covers, np.asarray(true_dims), 0.005, ik,
                        travel_time=lambda q, Q: np.abs(Q[:, 0] - q[0]))


def _at(x, estimate=None):
    return Observation(time=0.0, q=np.array([x, 0, 0, 0, 0, 0.0]), X_WS=np.eye(4),
                       estimate=estimate)


def test_the_oracle_visits_a_cover_then_another_round_and_stops_on_the_truth():
    dut = _policy([[1, 1, 0, 0, 0], [0, 0, 1, 1, 1], [1, 1, 1, 1, 1], [0, 0, 0, 0, 1]])
    first = dut.propose(_at(0.0))
    # All five sides from view 2; then the views measuring two or three, the nearer first.
    assert [i["oracle_view"] for i in first.candidate_info] == [2, 1, 0, 3]
    dut.accepted(0, _at(0.0))
    # Covered: a new round asks each side once more of the views left (0, 1, 3).
    second = dut.propose(_at(2.0, _Estimate((0.31, 0.2, 0.12))))  # L 10 mm off: go on
    assert [i["oracle_view"] for i in second.candidate_info] == [1, 0, 3]
    dut.accepted(1, _at(2.0))  # the loop could not reach view 1 and went to view 0
    assert dut.propose(_at(0.0, _Estimate((0.304, 0.196, 0.12)))).done  # within 5 mm
    # With no estimate within 5 mm: view 1 (the three sides view 0 left), then view 3 (a
    # third round: the top once more), then nothing left.
    taken = []
    while (proposal := dut.propose(_at(0.0))).candidates:
        taken.append(proposal.candidate_info[0]["oracle_view"])
        dut.accepted(0, _at(0.0))
    assert taken == [1, 3]
    assert proposal.done and "no view left" in proposal.reason


def test_a_restored_oracle_proposes_what_the_one_it_replays_would():
    covers = [[1, 1, 0, 0, 0], [0, 0, 1, 1, 1], [1, 0, 1, 0, 1], [0, 1, 0, 1, 0]]
    played, acquisitions = _policy(covers), []

    class _Acq:
        def __init__(self, index, info):
            self.index, self.time, self.q, self.X_WS = index, 0.0, np.zeros(6), np.eye(4)
            self.info = info

    for n in range(2):
        proposal = played.propose(_at(0.0))
        played.accepted(1, _at(0.0))
        acquisitions.append(_Acq(n, {**proposal.candidate_info[1], CANDIDATE_RANK: 1}))
    dut = _policy(covers)
    dut.restore(acquisitions)
    assert dut.propose(_at(0.0)).candidate_info == played.propose(_at(0.0)).candidate_info


def test_ratios_to_the_oracle_pair_trials_and_leave_out_those_it_never_reached():
    config = CampaignConfig(Path("unused"), ("lrnbv", "oracle"),
                            (CampaignObject("a", "a"), CampaignObject("b", "b")), 2)
    never = config.scenario.max_poses + 1

    def row(planner, obj, trial, poses, to_5mm, cycle):
        return {"planner": planner, "object": obj, "trial": trial, "n_poses": poses,
                "poses_to_5mm": to_5mm, "cycle_s": cycle}

    rows = [row("oracle", "a", 0, 2, 2, 4.0), row("lrnbv", "a", 0, 6, 3, 12.0),
            row("oracle", "a", 1, 4, 4, 10.0), row("lrnbv", "a", 1, 6, never, 5.0),
            row("oracle", "b", 0, 9, never, 20.0), row("lrnbv", "b", 0, 5, 5, 8.0)]
    dut = oracle_ratios(config, rows, "lrnbv", "a")
    np.testing.assert_allclose(dut.poses, [3.0, 1.5])
    np.testing.assert_allclose(dut.cycle, [3.0, 0.5])
    # Only a's trial 0 has both within 5 mm: 3 poses to the oracle's 2, then 3 more.
    np.testing.assert_allclose(dut.views, [1.5])
    np.testing.assert_allclose(dut.confirming, [3.0])
    assert dut.oracle_never == 0 and dut.planner_never == 1
    dut = oracle_ratios(config, rows, "lrnbv")
    assert len(dut.poses) == 2 and dut.oracle_never == 1  # b: the oracle never got there
    line = oracle_line(config, rows)  # the results page's: median 2.25 of 3 and 1.5
    assert "LR-NBV 2.25 [" in line and "(n=2)" in line and "never did in 1" in line
    assert "over the oracle's 1.5 (n=1), then 3 (n=1) poses" in line
    assert oracle_line(dc.replace(config, planners=("lrnbv",)), rows) == ""


def test_the_oracle_ends_an_episode_when_the_estimate_is_within_5_mm(tmp_path):
    """End to end on the horizontal box: the episode ends at the pose whose estimate first
    has every dimension within 5 mm of the truth (the report's own poses-to-5 mm)."""
    scenario = load_scenario(data="{seed: 0, object: {name: horizontal_box}}")
    report = run_episode(scenario, "oracle", tmp_path).report
    assert report["termination"] == "every dimension within 5 mm of the truth"
    assert report["metrics"]["poses_to_5mm"] == report["n_poses"]
    assert all("oracle_view" in p["info"] for p in report["poses"])
