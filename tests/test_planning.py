"""LR-NBV planner core: gains on hand-worked maps, the tree, caching and termination."""

import numpy as np
import pytest

from lrnbv_drake.core.acquisition import Acquisition
from lrnbv_drake.core.boxes import AlignedBox
from lrnbv_drake.core.mapping.extraction import ExtractionResult, ExtractionStatus
from lrnbv_drake.core.planning.config import GainParams, PlannerParams, UtilityWeights
from lrnbv_drake.core.planning.lrnbv import LrNbvPolicy, _Cached, cache_capacity
from lrnbv_drake.core.planning.policy import CANDIDATE_RANK, Observation
from lrnbv_drake.core.planning.rrt import ViewTree
from lrnbv_drake.core.planning.utility import (
    Gains,
    UtilityFunction,
    VisitedGrid,
    evaluate_gains,
    make_snapshot,
)
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry

RES = 0.01
CELL = RES**3


class GridMap:
    """A map stand-in: every cell unknown except those set by hand (index -> state)."""

    resolution = RES

    def __init__(self, states=None, default=-1):
        self.states = states or {}
        self.default = default

    def classify_block(self, lower, shape):
        keys = np.indices(shape).reshape(3, -1).T + lower
        return np.array([self.states.get(tuple(k), self.default) for k in keys.tolist()],
                        dtype=np.int8).reshape(shape)


# One ray along world +x from (0, 0.005, 0.005): a sensor at the origin whose optical axis
# (the single ray [0, 0, 1] in the sensor frame) points along +x.
RAY = np.array([[0.0, 0.0, 1.0]])
POSE = look_at([0.0, 0.005, 0.005], [1.0, 0.005, 0.005])
# The ROI spans cells x = 10..14 of the ray's row (y from -0.01 to 0.02, one z layer).
ROI = AlignedBox(np.array([0.10, -0.01, 0.0]), np.array([0.15, 0.02, 0.01]))


def _gains(grid, object_points=None, radius=0.0, visited=None):
    object_points = np.zeros((0, 3)) if object_points is None else object_points
    snapshot = make_snapshot(grid, ROI, object_points, np.array([1.0, 0.005, 0.005]), radius)
    return evaluate_gains(POSE[None], snapshot, RAY, visited or VisitedGrid(),
                          GainParams(max_range=1.0, density_radius=radius))


def test_a_ray_through_k_unknown_cells_of_the_roi():
    g = _gains(GridMap())
    assert g.exploration[0] == pytest.approx(5 * CELL)  # cells x = 10..14
    assert g.density[0] == pytest.approx(5.0)  # five valid samples, no object: 5 * 1/(1+0)
    assert g.quality[0] == pytest.approx(1 / (1 + 1.0))
    assert g.visited[0] == 0.0


def test_a_ray_blocked_by_an_object_cell():
    # Cell x = 12 is occupied (the object's surface): cells 10 and 11 are unknown and valid,
    # 12 is valid (seen) but known, 13 and 14 are hidden behind it.
    grid = GridMap({(12, 0, 0): 1})
    surface = np.array([[0.125, 0.005, 0.005]])
    g = _gains(grid, surface, radius=0.0)
    assert g.exploration[0] == pytest.approx(2 * CELL)
    # rho = 1 at the surface cell itself (r_d = 0 counts the cell's own point): 1 + 1 + 1/2.
    assert g.density[0] == pytest.approx(2.5)


def test_a_ray_clipping_the_corner_of_an_object_cell_is_stopped_there():
    """Rays past the corner of one occupied cell, aimed 10 um apart: each counts the unknown
    cells of the samples before it first enters the cell (the slab test on the cell's box),
    also where it crosses the cell between two samples, a cell apart."""
    grid = GridMap({(20, 20, 0): 1})
    roi = AlignedBox(np.array([0.1, 0.1, 0.0]), np.array([0.4, 0.4, 0.01]))
    snapshot = make_snapshot(grid, roi, np.zeros((0, 3)), np.array([0.3, 0.3, 0.005]), 0.0)
    o = np.array([0.0, 0.0037, 0.005])
    between_samples = 0
    for dx in np.linspace(-0.003, 0.003, 601):
        X = look_at(o, o + 10 * (np.array([0.21 + dx, 0.2 - dx, 0.005]) - o))
        d = X[:3, 2]
        g = evaluate_gains(X[None], snapshot, RAY, VisitedGrid(), GainParams(max_range=1.0))
        with np.errstate(divide="ignore"):
            slabs = np.sort((np.array([[0.20, 0.20, 0.0], [0.21, 0.21, 0.01]]) - o) / d, axis=0)
        enter, leave = slabs[0].max(), slabs[1].min()
        if abs(leave - enter) < 1e-9:
            continue  # grazes an edge or a corner: either answer is right
        t_occ = enter if enter < leave else np.inf
        t0 = max((roi.lower[:2] - o[:2]) / d[:2])
        samples = t0 + 0.5 * RES + RES * np.arange(60)
        inside = roi.contains(o + samples[:, None] * d)
        expected = np.sum(inside & (samples < t_occ)) * CELL
        assert g.exploration[0] == pytest.approx(expected, abs=1e-12), dx
        hits = np.floor((o + samples[:, None] * d) / RES + 1e-12) == (20, 20, 0)
        between_samples += bool(np.isfinite(t_occ) and not np.all(hits, axis=1).any())
    assert between_samples > 0  # the case the samples alone would see through


def test_density_counts_object_points_within_the_radius():
    # Everything free; object points in the row beside the ray at x = 11 and 12, one cell
    # (1 cm) from the ray's cells 11 and 12. With r_d = 1 cm each of those ray cells has one
    # neighbour: Gd = 3 * 1 + 2 * 1/2.
    grid = GridMap(default=0)
    points = np.array([[0.115, -0.005, 0.005], [0.125, -0.005, 0.005]])
    g = _gains(grid, points, radius=0.01)
    assert g.exploration[0] == 0.0
    assert g.density[0] == pytest.approx(4.0)
    # A smaller radius reaches no neighbour.
    assert _gains(grid, points, radius=0.009).density[0] == pytest.approx(5.0)


def test_a_visited_cell_costs_one():
    visited = VisitedGrid(0.18)
    visited.visit(np.array([0.1, 0.1, 0.1]))
    np.testing.assert_array_equal(
        visited.visited(np.array([[0.17, 0.0, 0.0], [0.19, 0.0, 0.0], [-0.01, 0.1, 0.1]])),
        [True, False, False])
    visited.visit(np.array([0.05, 0.05, 0.05]))  # same cell: still one
    assert len(visited) == 1
    g = _gains(GridMap(), visited=visited)  # the pose at the origin is in the visited cell
    assert g.visited[0] == -1.0


def test_utility_weights_and_normalisation_worked_by_hand():
    w = UtilityWeights(exploration=500, density=0.05, quality=0.08, visited=500)
    a = Gains(*(np.array([v]) for v in (2e-6, 10.0, 0.5, 0.0)))
    b = Gains(*(np.array([v]) for v in (4e-6, 5.0, 0.25, -1.0)))
    raw = UtilityFunction(w, normalize=False)
    assert raw(a)[0] == pytest.approx(500 * 2e-6 + 0.05 * 10 + 0.08 * 0.5)
    dut = UtilityFunction(w, normalize=True)
    dut.observe(Gains.concatenate([a, b]))  # maxima: Ge 4e-6, Gd 10, Gq 0.5
    assert dut(a)[0] == pytest.approx(500 * 0.5 + 0.05 * 1.0 + 0.08 * 1.0)
    assert dut(b)[0] == pytest.approx(500 * 1.0 + 0.05 * 0.5 + 0.08 * 0.5 - 500)


def test_cache_capacity_decreases_linearly():
    assert [cache_capacity(50, i, 300) for i in (0, 1, 150, 299, 300)] == [50, 50, 25, 1, 0]


def test_best_branch_maximises_the_summed_utility():
    #   0 -- 1 -- 2 -- 3        utilities: 1: 5, 2: -1, 3: 1  -> branch [1, 2, 3] sums to 5
    #         \-- 4             4: 0.5                       -> branch [1, 4] sums to 5.5
    #   0 -- 5                  5: 5.2                       -> branch [5] sums to 5.2
    tree = ViewTree(poses=[np.eye(4)] * 6, parents=[-1, 0, 1, 2, 1, 0], gains=[None] * 6,
                    configs=[None] * 6)
    utilities = np.array([5.0, -1.0, 1.0, 0.5, 5.2])
    assert sorted(map(tuple, tree.branches())) == [(1, 2, 3), (1, 4), (5,)]
    assert tree.best_branch(utilities) == [1, 4]


def _policy(**kwargs):
    params = PlannerParams(samples_per_iteration=10, **{"travel_discount": 0.0, **kwargs})
    workspace = AlignedBox(np.array([0.0, -0.5, 0.2]), np.array([0.8, 0.5, 0.7]))
    return LrNbvPolicy(params, ZoneGeometry(), workspace,
                       ik=lambda poses, q: (np.zeros((len(poses), 1, 6)), np.ones(len(poses), int)),
                       collision_free=lambda q: True, seed=1)


def _observation(grid, extraction=None, n=1):
    return Observation(time=0.0, q=np.zeros(6), X_WS=look_at([0.2, 0.0, 0.5], [0.5, 0, 0]),
                       occupancy=grid, extraction=extraction, n_acquisitions=n)


def test_first_iteration_proposes_the_best_node_and_caches_off_branch_nodes():
    dut = _policy()
    proposal = dut.propose(_observation(GridMap()))
    assert not proposal.done
    tree = dut.last_tree
    utilities = dut.utility(tree.candidate_gains())
    branch = tree.best_branch(utilities)
    best = max(branch, key=lambda i: utilities[i - 1])
    np.testing.assert_array_equal(proposal.candidates[0], tree.poses[best])
    off_branch = [i for i in range(1, len(tree.poses))
                  if i not in branch and utilities[i - 1] > dut.params.cache_threshold]
    assert len(dut.cache) == len(off_branch) > 0
    cached_positions = {tuple(c.X_WS[:3, 3]) for c in dut.cache}
    assert not cached_positions & {tuple(tree.poses[i][:3, 3]) for i in branch}
    # The visited cell of the current pose was marked.
    assert dut.visited.visited(np.array([[0.2, 0.0, 0.5]]))[0]


class PositionGains:
    """evaluate_gains stand-in: Ge from the sensor position only, other gains zero."""

    def __init__(self, exploration):
        self.exploration = exploration

    def __call__(self, poses, snapshot, rays, visited, params):
        p = np.asarray(poses).reshape(-1, 4, 4)[:, :3, 3]
        zeros = np.zeros(len(p))
        return Gains(np.array([self.exploration(x) for x in p]), zeros, zeros.copy(),
                     zeros.copy())


def _with_cache(monkeypatch, exploration, cached_positions):
    import lrnbv_drake.core.planning.lrnbv as mut

    monkeypatch.setattr(mut, "evaluate_gains", PositionGains(exploration))
    dut = _policy()
    dut.params.tree.max_edge = 0.05  # the random tree stays within 0.5 m of the start
    dut.workspace = AlignedBox(np.array([0.0, -0.5, 0.2]), np.array([1.2, 0.5, 0.7]))
    dut.cache = [_Cached(look_at(p, [0.5, 0.0, 0.0]), None, np.zeros(6))
                 for p in cached_positions]
    dut.iteration = 1
    return dut


def test_terminates_when_no_new_view_beats_the_worst_cached(monkeypatch):
    # Only the two cached positions see much (Ge = 1); anywhere else Ge = 0.1, including the
    # samples drawn around the cached nodes. Best new utility 500 * 0.1 < worst cached 500.
    cached = [np.array([0.95, 0.3, 0.5]), np.array([0.95, -0.3, 0.5])]

    def exploration(x):
        return 1.0 if min(np.linalg.norm(x - c) for c in cached) < 1e-6 else 0.1

    dut = _with_cache(monkeypatch, exploration, cached)
    proposal = dut.propose(_observation(GridMap(), n=2))
    assert proposal.done
    assert "line 24" in proposal.reason
    assert proposal.info["used_cached_tree"]  # line 10 was tried first
    assert proposal.info["utility"] == pytest.approx(50.0)
    assert proposal.info["worst_cached_utility"] == pytest.approx(500.0)


def test_expands_around_cached_nodes_when_the_new_tree_is_worse(monkeypatch):
    # Far from the start (x > 0.85) views see much; a mediocre cached node near the start sets
    # the worst cached utility. The random tree cannot get there, the cached tree can.
    cached = [np.array([0.95, 0.0, 0.5]), np.array([0.3, 0.3, 0.5])]

    def exploration(x):
        return 1.0 if x[0] > 0.85 else (0.05 if x[0] < 0.35 and x[1] > 0.25 else 0.1)

    dut = _with_cache(monkeypatch, exploration, cached)
    proposal = dut.propose(_observation(GridMap(), n=2))
    assert not proposal.done
    assert proposal.info["used_cached_tree"]
    assert proposal.info["best_cached_utility"] == pytest.approx(500.0)
    assert proposal.info["worst_cached_utility"] == pytest.approx(25.0)
    assert proposal.candidates[0][0, 3] > 0.85  # the chosen view is near the best cached node
    assert proposal.info["utility"] == pytest.approx(500.0)
    # The line-7 tree was expanded, not replaced: its 10 views plus one sample around the only
    # cached node that beats its best (the mediocre one does not).
    assert dut.last_tree.size == dut.params.samples_per_iteration + 1


def test_no_cached_expansion_when_the_new_tree_is_good_enough(monkeypatch):
    cached = [np.array([0.95, 0.0, 0.5])]
    dut = _with_cache(monkeypatch, lambda x: 0.2 if x[0] < 0.8 else 0.1, cached)
    proposal = dut.propose(_observation(GridMap(), n=2))
    assert not proposal.done
    assert not proposal.info["used_cached_tree"]
    assert proposal.info["utility"] > proposal.info["worst_cached_utility"]


def test_cache_is_trimmed_to_m_i_best_after_reevaluation(monkeypatch):
    positions = [np.array([0.1 * k, 0.0, 0.5]) for k in range(1, 8)]
    dut = _with_cache(monkeypatch, lambda x: x[0], positions)
    # Three proposals accepted: this update closes iteration 2 and keeps
    # m_2 = ceil(6 * (1 - 2/3)) = 2, the two best by Ge (x = 0.7, 0.6).
    dut.params.num_cached_nodes, dut.params.num_iterations, dut.iteration = 6, 3, 3
    dut.update_cache(None)
    assert [round(c.X_WS[0, 3], 3) for c in dut.cache] == [0.7, 0.6]


def test_the_first_update_keeps_m_0(monkeypatch):
    """Iteration 0 proposes, its view is accepted, and the next call's update closes it with
    m_0 = 6 (not m_1 = 4) of the seven cached nodes."""
    positions = [np.array([0.1 * k, 0.0, 0.5]) for k in range(1, 8)]
    dut = _with_cache(monkeypatch, lambda x: x[0], positions)
    dut.params.num_cached_nodes, dut.params.num_iterations, dut.iteration = 6, 3, 0
    dut.accepted(0, None)
    dut.update_cache(None)
    assert len(dut.cache) == 6


def test_the_executed_view_is_not_left_in_the_cache(monkeypatch):
    """When line 11 grows the tree from cached nodes, its new best branch can run through a
    node line 8 cached; that node is on the branch, so it leaves the cache (here x* itself,
    near the best cached position: a hand-found seed where it stayed before)."""
    far = np.array([0.95, 0.0, 0.5])

    def exploration(x):
        if np.linalg.norm(x - np.array([0.3, 0.45, 0.6])) < 1e-9:
            return 0.1
        return 1.0 if np.linalg.norm(x - far) < 0.12 else (
            0.6 + 0.35 * np.sin(25 * x[1]) * np.cos(17 * x[2]))

    import lrnbv_drake.core.planning.lrnbv as mut

    monkeypatch.setattr(mut, "evaluate_gains", PositionGains(exploration))
    params = PlannerParams(samples_per_iteration=20)
    params.tree.max_edge = 0.08
    dut = LrNbvPolicy(params, ZoneGeometry(),
                      AlignedBox(np.array([0.0, -0.5, 0.2]), np.array([1.2, 0.5, 0.7])),
                      ik=lambda P, q: (np.zeros((len(P), 1, 6)), np.ones(len(P), int)),
                      collision_free=lambda q: True, seed=36, variant="nbv")
    dut.cache = [_Cached(look_at(c, [0.5, 0, 0]), None, np.zeros(6))
                 for c in (far, np.array([0.3, 0.45, 0.6]))]
    dut.iteration = 1
    proposal = dut.propose(_observation(GridMap(), n=2))
    assert proposal.info["used_cached_tree"]
    branch = {tuple(p) for p in proposal.debug["tree_positions"][proposal.debug["best_branch"]]}
    assert not branch & {tuple(c.X_WS[:3, 3]) for c in dut.cache}


def test_reevaluation_drops_nodes_no_longer_above_tau(monkeypatch):
    # Ge = x, normalised by its maximum 0.7: U = 500 x / 0.7. tau = 500 * 0.45 / 0.7 keeps
    # x > 0.45.
    positions = [np.array([0.1 * k, 0.0, 0.5]) for k in range(1, 8)]
    dut = _with_cache(monkeypatch, lambda x: x[0], positions)
    dut.params.cache_threshold = 500 * 0.45 / 0.7
    dut.update_cache(None)
    assert [round(c.X_WS[0, 3], 3) for c in dut.cache] == [0.7, 0.6, 0.5]


def test_done_when_nothing_above_tau_is_left(monkeypatch):
    # Every view, cached or new, sees nothing (all gains 0, visited 0): U = 0 <= tau = 0.
    cached = [np.array([0.5, 0.3, 0.5])]
    dut = _with_cache(monkeypatch, lambda x: 0.0, cached)
    proposal = dut.propose(_observation(GridMap(), n=2))
    assert dut.cache == []
    assert proposal.done
    assert "no cached node is left above tau" in proposal.reason


def test_restore_puts_the_policy_where_the_run_was():
    """An initial capture and three planned ones, as the loop makes them; a new policy
    restored from them has the run's iteration count and visited cells, and does not mark
    where the arm happens to be when it goes on."""
    run = _policy()
    X = look_at([0.2, 0.0, 0.5], [0.5, 0, 0])
    recorded = [Acquisition(index=0, time=0.0, q=np.zeros(6), X_WS=X, frame=ToFFrame.empty())]
    for k in range(1, 4):
        observation = Observation(time=float(k), q=np.zeros(6), X_WS=X, occupancy=GridMap(),
                                  n_acquisitions=k)
        proposal = run.propose(observation)
        assert not proposal.done
        run.accepted(0, observation)
        X = proposal.candidates[0]
        recorded.append(Acquisition(index=k, time=float(k), q=np.zeros(6), X_WS=X,
                                    frame=ToFFrame.empty(),
                                    info={**proposal.info, CANDIDATE_RANK: 0}))
    restored = _policy()
    restored.restore(recorded)
    assert restored.iteration == run.iteration == 3
    positions = np.array([a.X_WS[:3, 3] for a in recorded])
    assert restored.visited.visited(positions).all()
    # The run marks its last position on its next proposal; the restored policy already has.
    run.propose(Observation(time=4.0, q=np.zeros(6), X_WS=X, occupancy=GridMap(),
                            n_acquisitions=4))
    assert len(restored.visited) == len(run.visited)
    elsewhere = look_at([0.7, 0.4, 0.3], [0.5, 0, 0])
    assert not restored.visited.visited(elsewhere[None, :3, 3])[0]
    restored.propose(Observation(time=5.0, q=np.zeros(6), X_WS=elsewhere, occupancy=GridMap(),
                                 n_acquisitions=4))
    assert not restored.visited.visited(elsewhere[None, :3, 3])[0]


def test_the_travel_discount_scales_positive_utilities_by_exp_minus_lambda_t(monkeypatch):
    """Two cached views with the same gains: without the discount they tie; with lambda = 0.5
    the one 2 s away keeps exp(-1) of its utility against exp(-0.25) for the one 0.5 s away,
    and a negative utility is left as it is."""
    near, far = np.full(6, 0.1), np.full(6, 0.4)
    dut = _with_cache(monkeypatch, lambda x: 1.0, [np.array([0.6, 0.2, 0.5]),
                                                   np.array([0.6, -0.2, 0.5])])
    dut.params.travel_discount = 0.5
    dut.travel_time = lambda q, Q: 5.0 * np.max(np.abs(Q - q), axis=1)  # 0.5 s and 2 s
    gains = Gains(np.array([1.0, 1.0, 0.5]), np.zeros(3), np.zeros(3),
                  np.array([0.0, 0.0, -1.0]))  # the third: visited, U < 0
    dut.utility.observe(gains)
    u = dut.utilities(gains, [near, far, far])
    u_plain = dut.utility(gains)
    np.testing.assert_allclose(u[:2], u_plain[:2] * np.exp([-0.25, -1.0]))
    assert u_plain[2] < 0 and u[2] == u_plain[2]
    with pytest.raises(ValueError, match="travel_time"):
        _policy(travel_discount=0.1)


def _loose(points):
    return ExtractionResult(ExtractionStatus.ONLY_NOISE, "no cluster", np.zeros(len(points)),
                            loose_points=np.asarray(points, float))


def test_the_search_looks_where_cells_too_few_for_a_cluster_stand():
    """From HOME the vertical box shows a few cells of its top: the search goes there, down
    to the table, and not to the table's lowest 8 cm."""
    dut = _policy()
    top = [[0.47, -0.04, 0.245], [0.52, 0.03, 0.255], [0.50, 0.0, 0.25]]
    roi, points, center = dut.roi(_loose(top))
    np.testing.assert_allclose(roi.lower, [0.42, -0.09, 0.0])
    np.testing.assert_allclose(roi.upper, [0.57, 0.08, 0.305])
    np.testing.assert_allclose(center, roi.center)
    assert len(points) == 0
    region = (dut.params.search_lower, dut.params.search_upper)
    # Too few cells, cells outside the search region's footprint, or the lead turned off.
    for extraction, kwargs in ((_loose(top[:2]), {}),
                               (_loose(np.add(top, [0.0, 0.4, 0.0])), {}),
                               (_loose(top), {"lead_points": 0}),
                               (None, {})):
        roi, _, _ = _policy(**kwargs).roi(extraction)
        np.testing.assert_allclose([roi.lower, roi.upper], region)
