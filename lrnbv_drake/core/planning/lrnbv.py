"""LR-NBV (Algorithm 1) as a viewpoint policy, and the NBV baseline (the same without Gd, Gv).

One call of `propose` is one iteration of Algorithm 1's loop, split where the acquisition loop
does the robot's part (capture, map update, clustering: lines 16-18):

- lines 19-21 (for the previous iteration): re-evaluate the cached nodes against the new map,
  keep the best m_i, take the best and worst cached utilities;
- lines 7-9: grow a new tree from the current pose, cache off-branch nodes above tau, take the
  best node of the best branch;
- lines 10-14: if it is worse than the best cached node, grow a tree from samples around the
  most promising cached nodes and take its best node instead;
- lines 15/24: stop if the best node is not better than the worst cached one; else propose it.

docs/algorithm.md maps each line and equation to the code and gives every reading chosen where
the paper is ambiguous.
"""

from __future__ import annotations

import dataclasses as dc
import math
import time
from collections.abc import Sequence

import numpy as np

from lrnbv_drake.core.boxes import AlignedBox
from lrnbv_drake.core.planning.box_gain import SideBands
from lrnbv_drake.core.planning.config import PlannerParams, UtilityWeights
from lrnbv_drake.core.planning.policy import Observation, Proposal, Recorded, ViewpointPolicy
from lrnbv_drake.core.planning.rrt import Reach, ViewTree, expand_tree
from lrnbv_drake.core.planning.utility import (
    Gains,
    PlanningSnapshot,
    UtilityFunction,
    VisitedGrid,
    evaluate_gains,
    make_snapshot,
    sensor_rays,
)
from lrnbv_drake.core.sensing.sensor import ZoneGeometry


@dc.dataclass
class _Cached:
    """A cached node: its pose, raw gains (scored again whenever compared) and the joint
    configuration that reaches it."""

    X_WS: np.ndarray
    gains: Gains
    q: np.ndarray


def cache_capacity(m0: int, iteration: int, num_iterations: int) -> int:
    """m_i: the number of cached nodes kept after iteration i, falling linearly from m0."""
    return max(0, math.ceil(m0 * (1.0 - iteration / num_iterations)))


class LrNbvPolicy(ViewpointPolicy):
    """The LR-NBV planner (or, with `variant="nbv"`, the standard NBV baseline).

    Args:
        params: planner parameters.
        geometry: the sensor's zones, from which the gain rays are cast.
        workspace: box the sensor positions must lie in.
        ik: IK solutions of sensor poses (N, 4, 4) from joints q: `ik(poses, q)` gives
            (Q, n), pose i's n[i] solutions best first in Q[i, :n[i]] (`Reach.ik`).
        collision_free: whether a joint configuration is collision free.
        table_height: the ROI never extends below the table top.
        seed: seed of the tree sampling.
        variant: "lrnbv" or "nbv" (Gd and Gv weights set to zero).
        travel_time: seconds the arm takes from joints q to each of configurations Q (n, 6),
            `travel_time(q, Q)`; needed with `params.travel_discount` > 0.
        first_view: the first frame's sensor pose (4x4 X_WS, the drop zone's view), proposed
            before any frame is taken; None: the first frame is taken at the start pose.
        capture_seconds: what a pose costs besides the motion (settling, the frame, the map),
            which the box utility adds to the travel time it divides by.
        first_free: the index of the first collision-free configuration of Q (k, 6), -1 if
            none, in one call (`Reach.first_free`); None: `collision_free` on each in turn.
    """

    def __init__(self, params: PlannerParams, geometry: ZoneGeometry, workspace: AlignedBox,
                 ik, collision_free, table_height: float = 0.0, seed: int = 0,
                 variant: str = "lrnbv", travel_time=None,
                 first_view: np.ndarray | None = None, capture_seconds: float = 0.0,
                 first_free=None):
        if variant not in ("lrnbv", "nbv"):
            raise ValueError(f"unknown variant '{variant}': expected 'lrnbv' or 'nbv'")
        if params.travel_discount < 0 or (params.travel_discount > 0 and travel_time is None):
            raise ValueError(f"travel_discount {params.travel_discount} needs to be >= 0, and "
                             f"a travel_time function when > 0")
        if params.utility == "box" and (travel_time is None or not capture_seconds > 0):
            raise ValueError("utility 'box' needs a travel_time function and capture_seconds "
                             f"> 0; got capture_seconds {capture_seconds}")
        weights = params.weights
        if params.utility == "box":
            weights = UtilityWeights(exploration=params.box_exploration, density=0.0,
                                     quality=0.0, visited=0.0, box=1.0)
        elif variant == "nbv":
            weights = dc.replace(weights, density=0.0, visited=0.0)
        self.capture_seconds = capture_seconds
        self.name = variant
        self.params = params
        self.first_view = None if first_view is None else np.asarray(first_view, float)
        self.capture_initial = first_view is None
        self.utility = UtilityFunction(weights, params.gains.normalize)
        self.reads_estimate = weights.box != 0  # the box gain's bands
        self.rays = sensor_rays(geometry, params.gains.rays_per_zone)
        self.workspace = workspace
        self.ik = ik
        self.collision_free = collision_free
        self.first_free = first_free
        self.travel_time = travel_time
        self._q = np.zeros(6)  # where the arm is, for the travel discount
        self.table_height = table_height
        self.visited = VisitedGrid(params.visited_cell_size)
        self.rng = np.random.default_rng(seed)
        self.iteration = 0
        self.cache: list[_Cached] = []
        self._marked = 0
        self._first_view_proposed = False
        # The last iteration's tree (for inspection; Proposal.debug carries what is drawn).
        self.last_tree: ViewTree | None = None

    # -- the steps of `propose`, each tested alone --------------------------------------

    def utilities(self, gains: Gains, configs: Sequence[np.ndarray]) -> np.ndarray:
        """The views' utilities: the box utility over the seconds a view costs (the arm's
        travel to its configuration from where it is, and `capture_seconds`), less 1 where
        its position's cell was visited (Gv: a view again where one was taken bounds little
        more); positive ones discounted by exp(-lambda t) for the travel time t."""
        utilities = self.utility(gains)
        box = self.params.utility == "box"
        if (box or self.params.travel_discount > 0) and len(configs):
            t = self.travel_time(self._q, np.array(configs))
            if box:  # a visited cell's view loses 1, whatever its time
                utilities = utilities / (t + self.capture_seconds) + gains.visited
            if self.params.travel_discount > 0:
                utilities = np.where(utilities > 0,
                                     utilities * np.exp(-self.params.travel_discount * t),
                                     utilities)
        return utilities

    def bands(self, estimate) -> SideBands | None:
        """The side bands of `estimate` (a `BoxEstimate`) for the box gain; None for the
        paper's utility or an estimate without an interval."""
        if self.utility.weights.box == 0 or estimate is None or estimate.interval is None:
            return None
        return SideBands.of(estimate.box, estimate.dims_lower, estimate.dims_upper,
                            self.table_height)

    def _scorer(self, snapshot: PlanningSnapshot):
        def score(poses: np.ndarray) -> tuple[Gains, np.ndarray]:
            gains = evaluate_gains(poses, snapshot, self.rays, self.visited, self.params.gains)
            self.utility.observe(gains)
            return gains, self.utility(gains)
        return score

    def roi(self, extraction) -> tuple[AlignedBox, np.ndarray, np.ndarray]:
        """ROI, object points and x_object from the extraction, or where to search for it."""
        if extraction is not None and extraction.found:
            roi, points, center = extraction.roi, extraction.object_points, extraction.center
        else:
            roi = self._search_region(extraction)
            points, center = np.zeros((0, 3)), roi.center
        lower = roi.lower.copy()
        lower[2] = max(lower[2], self.table_height)  # nothing to explore under the table top
        return AlignedBox(lower, roi.upper), points, center

    def _search_region(self, extraction) -> AlignedBox:
        """The search region, or the box of the loose cells standing above the table inside
        it (a lead: `PlannerParams.lead_points`). Measured: from HOME the vertical box shows
        9 cells of its top, one short of a cluster, and the flange 3-8 of its hub; aimed at the
        table's lowest 8 cm, the next view saw the box's foot (its first estimate 17-62 mm
        short in height) and found the flange at pose 3-4."""
        p = self.params
        region = AlignedBox(np.asarray(p.search_lower, float), np.asarray(p.search_upper, float))
        loose = None if extraction is None else extraction.loose_points
        if p.lead_points <= 0 or loose is None:
            return region
        xy = loose[:, :2]
        inside = np.all((xy >= region.lower[:2]) & (xy <= region.upper[:2]), axis=1)
        if np.count_nonzero(inside) < p.lead_points:
            return region
        lead = loose[inside]
        lower = lead.min(axis=0) - p.lead_margin
        lower[2] = self.table_height
        return AlignedBox(lower, lead.max(axis=0) + p.lead_margin)

    def _random_positions(self, k: int) -> np.ndarray:
        """(k, 3) uniform positions in the workspace (the same draws as k draws of one)."""
        return self.rng.uniform(self.workspace.lower, self.workspace.upper, (k, 3))

    def _cached_sampler(self, promising: list[_Cached]):
        """Positions around the promising cached nodes, best first, in turn (ExpandRRTCached)."""
        spread = self.params.cached_sample_spread
        centers = np.array([node.X_WS[:3, 3] for node in promising])
        drawn = 0

        def sample(k: int) -> np.ndarray:
            nonlocal drawn
            around = centers[(drawn + np.arange(k)) % len(promising)]
            drawn += k
            return around + self.rng.normal(0.0, spread, (k, 3))
        return sample

    def _grow(self, tree: ViewTree | np.ndarray, n: int, sampler, snapshot: PlanningSnapshot,
              roi: AlignedBox, reach: Reach, steer: bool = True
              ) -> tuple[ViewTree, np.ndarray, list[int]]:
        """Grows the tree and scores it; the utilities are current until the next scoring."""
        tree = expand_tree(tree, n, sampler, self.workspace, roi, self._scorer(snapshot),
                           reach, self.params.tree, steer)
        utilities = self.utilities(tree.candidate_gains(), tree.configs[1:])
        return tree, utilities, tree.best_branch(utilities)

    def _cache_off_branch(self, tree: ViewTree, utilities: np.ndarray, branch: list[int],
                          cached: dict[int, _Cached]) -> None:
        """Lines 8 and 12: caches the tree's nodes off the best branch above tau, once each
        (`cached` maps the tree indices already cached to their entries and is updated)."""
        on_branch = set(branch)
        for i in range(1, len(tree.poses)):
            if i not in on_branch and i not in cached and \
                    utilities[i - 1] > self.params.cache_threshold:
                cached[i] = _Cached(tree.poses[i], tree.gains[i], tree.configs[i])
                self.cache.append(cached[i])

    def update_cache(self, snapshot: PlanningSnapshot) -> float:
        """Lines 19-21: re-evaluate the cache, drop the nodes no longer above tau, keep the best
        m_i; returns the seconds it took."""
        started = time.perf_counter()
        if self.cache:
            poses = np.array([c.X_WS for c in self.cache])
            gains = evaluate_gains(poses, snapshot, self.rays, self.visited, self.params.gains)
            self.utility.observe(gains)
            # This update closes the iteration before this call (`accepted` has counted it).
            keep = cache_capacity(self.params.num_cached_nodes, max(self.iteration - 1, 0),
                                  self.params.num_iterations)
            utilities = self.utilities(gains, [c.q for c in self.cache])
            order = np.argsort(-utilities, kind="stable")[:keep]
            self.cache = [_Cached(self.cache[i].X_WS, gains.take(i), self.cache[i].q)
                          for i in order if utilities[i] > self.params.cache_threshold]
        return time.perf_counter() - started

    # -- the policy -----------------------------------------------------------------------

    def propose(self, observation: Observation) -> Proposal:
        # Acquisitions since the last call make their positions visited (Gv).
        if observation.n_acquisitions > self._marked:
            self.visited.visit(observation.X_WS[:3, 3])
            self._marked = observation.n_acquisitions
        if self.iteration >= self.params.num_iterations:
            return Proposal(done=True, reason=f"reached {self.params.num_iterations} iterations")
        if self.first_view is not None and observation.n_acquisitions == 0:
            return self._propose_first_view()

        q = self._q = np.asarray(observation.q, float)
        reach = Reach(lambda poses: self.ik(poses, q), self.collision_free, self.first_free)
        roi, object_points, center = self.roi(observation.extraction)
        snapshot = make_snapshot(observation.occupancy, roi, object_points, center,
                                 self.params.gains.density_radius,
                                 self.bands(observation.estimate))
        reevaluation_s = self.update_cache(snapshot)
        cached_before = list(self.cache)
        cached_gains = Gains.concatenate([c.gains for c in cached_before])
        cached_configs = [c.q for c in cached_before]

        def cached_utilities() -> np.ndarray:
            # Scored now: the running maxima may have grown since the cache was updated.
            return self.utilities(cached_gains, cached_configs)

        def best_node(utilities: np.ndarray, branch: list[int]) -> tuple[int | None, float]:
            if not branch:
                return None, -np.inf
            best = max(branch, key=lambda i: utilities[i - 1])
            return best, float(utilities[best - 1])

        started = time.perf_counter()
        n = self.params.samples_per_iteration
        tree, utilities, branch = self._grow(observation.X_WS, n, self._random_positions,
                                             snapshot, roi, reach)
        cached_nodes: dict[int, _Cached] = {}
        self._cache_off_branch(tree, utilities, branch, cached_nodes)
        best, u_best = best_node(utilities, branch)
        used_cached_tree = False
        u_cached = cached_utilities() if cached_before else None
        if cached_before and u_best < u_cached.max():
            # Line 11: expand this tree from the cached nodes better than its best node.
            promising = [cached_before[i] for i in np.argsort(-u_cached, kind="stable")
                         if u_cached[i] > u_best][:n]
            size = tree.size
            tree, utilities, branch = self._grow(tree, len(promising),
                                                 self._cached_sampler(promising), snapshot,
                                                 roi, reach, steer=False)
            self._cache_off_branch(tree, utilities, branch, cached_nodes)
            used_cached_tree = tree.size > size
            best, u_best = best_node(utilities, branch)
            # The grown tree's best branch may run through nodes line 8 cached (x* among
            # them): on the branch, they are not off it.
            on_branch = {id(cached_nodes[i]) for i in branch if i in cached_nodes}
            self.cache = [c for c in self.cache if id(c) not in on_branch]
        expansion_s = time.perf_counter() - started
        self.last_tree = tree
        final_cached = cached_utilities() if cached_before else None
        best_cached = float(final_cached.max()) if cached_before else None
        worst_cached = float(final_cached.min()) if cached_before else None

        info = {
            "iteration": self.iteration,
            "utility": float(u_best),
            "best_cached_utility": best_cached,
            "worst_cached_utility": worst_cached,
            "n_tree_nodes": tree.size,
            "n_cached": len(self.cache),
            "used_cached_tree": used_cached_tree,
            "object_found": bool(observation.extraction is not None
                                 and observation.extraction.found),
            "roi": [roi.lower.tolist(), roi.upper.tolist()],
            "tree_expansion_s": expansion_s,
            "cache_reevaluation_s": reevaluation_s,
        }
        if best is None:
            return Proposal(done=True, reason="no reachable view found around the ROI",
                            info=info)
        if self.iteration > 0 and not cached_before and u_best <= self.params.cache_threshold:
            return Proposal(done=True, info=info, reason=(
                f"no cached node is left above tau = {self.params.cache_threshold:g} and the "
                f"best new view's utility {u_best:.4g} is not above it either"))
        if cached_before and u_best <= worst_cached:
            return Proposal(done=True, info=info, reason=(
                f"best utility {u_best:.4g} is not above the worst cached node's "
                f"{worst_cached:.4g} (Algorithm 1, line 24)"))
        g = tree.gains[best]
        info["gains"] = {"exploration": float(g.exploration[0]), "density": float(g.density[0]),
                         "quality": float(g.quality[0]), "visited": float(g.visited[0]),
                         "box": float(g.box[0])}
        # The best node first; then the rest of the tree by utility, in case the motion to the
        # best one fails.
        order = [best] + [int(i) + 1 for i in np.argsort(-utilities, kind="stable")
                          if int(i) + 1 != best]
        debug = {
            "tree_positions": np.array([X[:3, 3] for X in tree.poses]),
            "tree_parents": np.array(tree.parents),
            "best_branch": np.array(branch),
            "cached_positions": np.array([c.X_WS[:3, 3] for c in self.cache]).reshape(-1, 3),
            "roi": (roi.lower, roi.upper),
        }
        return Proposal(candidates=[tree.poses[i] for i in order], info=info, debug=debug,
                        candidate_info=[{"node_utility": float(utilities[i - 1])}
                                        for i in order])

    def _propose_first_view(self) -> Proposal:
        """The drop zone's view, once: if the arm cannot reach it, the episode ends saying
        so (a tree needs a frame to grow from)."""
        if self._first_view_proposed:
            at = np.round(self.first_view[:3, 3], 3).tolist()
            return Proposal(done=True, reason=(
                f"the drop zone's first view (sensor at {at} m, looking down) is out of the "
                "arm's reach: move cell.drop_zone, lower cell.max_item_height or set "
                "planner.first_view: home"))
        self._first_view_proposed = True
        return Proposal(candidates=[self.first_view], info={"first_view": "drop_zone"})

    def accepted(self, index: int, observation: Observation) -> None:
        # The drop zone's view is the first frame, as the start pose's is: no iteration.
        if self.first_view is None or observation.n_acquisitions > 0:
            self.iteration += 1

    def restore(self, acquisitions: Sequence[Recorded]) -> None:
        """The iteration count (one per acquisition a proposal led to) and the visited cells
        (every recorded position, the last included, which `propose` would mark on its next
        call; so it does not also mark wherever the arm is when the episode goes on).

        Not rebuilt: the view cache, the sampler's random state and the utility's running
        maxima, which came from maps that no longer exist; a restored LR-NBV therefore
        continues validly but not as the uninterrupted run would have.
        """
        super().restore(acquisitions)
        for a in acquisitions:
            self.visited.visit(a.X_WS[:3, 3])
        self._marked = len(acquisitions)
