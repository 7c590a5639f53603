"""The oracle: a planner that knows the true object, the floor the other planners are measured
against (simulation only).

A box is known once each of its five free sides (four walls and the top; the table is the
bottom) has been measured. From a fixed set of views aimed at the true box (`oracle_views`)
the oracle finds which sides each view measures (`side_cover`): a zone measures a side when
most of its sub-rays first meet the object within `tolerance` of that side's plane, so that
the zone's reading is that side's distance. It then visits the views of a greedy set cover
of the sides (`greedy_step`: the view measuring the most sides not yet measured, ties to the
nearer view), and after each frame compares the reported estimate with the truth: done when
every dimension is within `tolerance`. A cover that ends short of that starts another round
over the views not yet visited, asking each side for one more view, until no view is left
that measures a side.

Greedy set cover is within a factor ln(5) + 1 of the least cover of five sides, and it is the
cover the estimator needs, not only the map: the oracle's count is the poses after which the
product's own estimator is within `tolerance`, with views chosen knowing the object.
"""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Callable, Sequence

import numpy as np
import trimesh

from lrnbv_drake.core.boxes import AlignedBox, OrientedBox
from lrnbv_drake.core.estimation.estimator import BoxEstimate
from lrnbv_drake.core.evaluation.metrics import ROUNDING_SLACK
from lrnbv_drake.core.planning.policy import Observation, Proposal, Recorded, ViewpointPolicy
from lrnbv_drake.core.planning.utility import sensor_rays
from lrnbv_drake.core.robot.poses import look_at_batch
from lrnbv_drake.core.sensing.sensor import ZoneGeometry

#: IK of sensor poses (N, 4, 4) from joints q, as `LrNbvPolicy` takes it: (Q, n), pose i's
#: n[i] solutions best first in Q[i, :n[i]].
IK = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
#: Seconds the arm takes from joints q to each of configurations Q (n, 6).
TravelTime = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: The oracle's planner name (`OraclePolicy.name`), as campaigns and reports give it.
ORACLE = "oracle"
#: The box's free sides, in the order of `side_cover`'s columns (x, y: the box's own axes).
SIDES: tuple[str, ...] = ("+x", "-x", "+y", "-y", "top")


@dc.dataclass(frozen=True)
class OracleViews:
    """The oracle's candidate views: aimed at the true box's centre from every
    `azimuth_step_deg` around it, at each elevation and distance, and straight down from each
    distance."""

    #: Distances from the box's centre to the sensor, m.
    distances: tuple[float, ...] = (0.30, 0.45)
    #: Elevations of the sensor above the box centre's horizontal plane, degrees (below 90).
    elevations_deg: tuple[float, ...] = (30.0, 50.0, 70.0)
    #: Step between azimuths, degrees.
    azimuth_step_deg: float = 30.0
    #: Sub-rays per zone side when finding what a zone measures (k x k a zone).
    rays_per_zone: int = 3


def oracle_views(box: OrientedBox, views: OracleViews, workspace: AlignedBox) -> np.ndarray:
    """(N, 4, 4) X_WS of the candidate views `views` describes around `box` whose sensor lies
    in `workspace`."""
    az = np.deg2rad(np.arange(0.0, 360.0, views.azimuth_step_deg)) + box.yaw
    el = np.deg2rad(np.asarray(views.elevations_deg, float))
    d = np.asarray(views.distances, float)
    A, E, D = (g.ravel() for g in np.meshgrid(az, el, d, indexing="ij"))
    directions = np.column_stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)])
    eyes = box.center + D[:, None] * directions
    above = box.center + d[:, None] * np.array([0.0, 0.0, 1.0])
    X = np.concatenate([look_at_batch(eyes, box.center),
                        look_at_batch(above, box.center, up=(np.cos(box.yaw),
                                                             np.sin(box.yaw), 0.0))])
    return X[workspace.contains(X[:, :3, 3])]


def first_hits(mesh: trimesh.Trimesh, table_height: float, origins: np.ndarray,
               directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where rays (origins and unit directions, (n, 3)) first meet the object or the table:
    (points (n, 3), on_object (n,) bool); a ray that meets neither has NaN points."""
    t = np.full(len(origins), np.inf)
    down = directions[:, 2] < 0
    t[down] = (table_height - origins[down, 2]) / directions[down, 2]
    on_object = np.zeros(len(origins), bool)
    points, ray_index, _ = mesh.ray.intersects_location(origins, directions,
                                                        multiple_hits=False)
    if len(ray_index):
        t_mesh = np.einsum("ij,ij->i", points - origins[ray_index], directions[ray_index])
        nearer = t_mesh < t[ray_index]
        t[ray_index[nearer]] = t_mesh[nearer]
        on_object[ray_index[nearer]] = True
    with np.errstate(invalid="ignore"):
        hits = origins + np.where(np.isfinite(t), t, np.nan)[:, None] * directions
    return hits, on_object


def side_cover(X_WS: np.ndarray, rays_S: np.ndarray, mesh: trimesh.Trimesh,
               table_height: float, box: OrientedBox, tolerance: float) -> np.ndarray:
    """(N, 5) bool: which of `SIDES` of `box` each view X_WS (N, 4, 4) measures. `rays_S`
    (Z, K, 3): each zone's K unit sub-ray directions in the sensor frame; a zone measures a
    side when more than half its sub-rays first meet the object within `tolerance` of the
    side's plane, so that the zone's nearest-cluster reading is that side's distance."""
    Z, K = rays_S.shape[:2]
    N = len(X_WS)
    directions = np.einsum("nij,rj->nri", X_WS[:, :3, :3], rays_S.reshape(-1, 3))
    origins = np.broadcast_to(X_WS[:, None, :3, 3], directions.shape)
    hits, on_object = first_hits(mesh, table_height, origins.reshape(-1, 3),
                                 directions.reshape(-1, 3))
    c, s = np.cos(box.yaw), np.sin(box.yaw)
    rel = hits - box.center
    x, y = rel[:, 0] * c + rel[:, 1] * s, -rel[:, 0] * s + rel[:, 1] * c
    L, W, H = box.dims / 2
    band = tolerance + ROUNDING_SLACK
    with np.errstate(invalid="ignore"):
        near = np.column_stack([x >= L - band, x <= -L + band, y >= W - band, y <= -W + band,
                                rel[:, 2] >= H - band]) & on_object[:, None]
    per_zone = near.reshape(N, Z, K, len(SIDES)).sum(axis=2) > K / 2
    return per_zone.any(axis=1)


def greedy_step(covers: np.ndarray, needed: np.ndarray, cost: np.ndarray,
                open_views: np.ndarray) -> int | None:
    """The greedy set cover's next view among `open_views` (bool mask): the one measuring the
    most sides still `needed` (bool mask over the columns of `covers`), of those the least
    `cost`; None when no open view measures a needed side."""
    gain = np.where(open_views, (covers & needed).sum(axis=1), 0)
    if gain.max(initial=0) == 0:
        return None
    best = np.flatnonzero(gain == gain.max())
    return int(best[np.argmin(cost[best])])


def reachable(views: np.ndarray, ik: IK, collision_free: Callable[[np.ndarray], bool],
              q: np.ndarray) -> np.ndarray:
    """(N,) bool: which views (N, 4, 4) the arm reaches by an IK solution free of collision."""
    Q, n = ik(views, q)
    return np.array([any(collision_free(Q[i, j]) for j in range(n[i]))
                     for i in range(len(views))], bool)


def oracle_policy(mesh: trimesh.Trimesh, box: OrientedBox, table_height: float,
                  geometry: ZoneGeometry, workspace: AlignedBox, ik: IK,
                  collision_free: Callable[[np.ndarray], bool],
                  travel_time: TravelTime, q: np.ndarray,
                  views: OracleViews = OracleViews(), tolerance: float = 0.005
                  ) -> OraclePolicy:
    """The oracle of the object `mesh` (world frame) whose true box is `box`: the candidate
    views the arm reaches from joints q, and the sides each measures."""
    X = oracle_views(box, views, workspace)
    X = X[reachable(X, ik, collision_free, q)]
    rays = sensor_rays(geometry, views.rays_per_zone).reshape(geometry.resolution ** 2, -1, 3)
    covers = side_cover(X, rays, mesh, table_height, box, tolerance)
    return OraclePolicy(X, covers, box.dims, tolerance, ik, travel_time)


class OraclePolicy(ViewpointPolicy):
    """Visits greedy set covers of the true box's sides until the reported estimate is within
    `tolerance` of the truth in every dimension.

    Args:
        views: (N, 4, 4) candidate views (`oracle_views`).
        covers: (N, 5) which sides each measures (`side_cover`).
        true_dims: (L, W, H) of the true box, m.
        tolerance: the accuracy it stops at, m.
        ik: IK of the sensor poses (`IK`).
        travel_time: seconds from joints q to each of configurations Q (n, 6).
    """

    name = ORACLE
    capture_initial = False
    reads_estimate = True  # it stops once the estimate is within the tolerance

    def __init__(self, views: np.ndarray, covers: np.ndarray, true_dims: np.ndarray,
                 tolerance: float, ik: IK, travel_time: TravelTime):
        self.views, self.covers = np.asarray(views, float), np.asarray(covers, bool)
        self.true_dims, self.tolerance = np.asarray(true_dims, float), tolerance
        self.ik, self.travel_time = ik, travel_time
        self.open_views = np.ones(len(self.views), bool)
        self.needed = self.covers.any(axis=0)
        self._ranked: list[int] = []

    def _within(self, estimate: BoxEstimate | None) -> bool:
        return estimate is not None and bool(np.all(
            np.abs(estimate.box.dims - self.true_dims) <= self.tolerance + ROUNDING_SLACK))

    def _cost(self, q: np.ndarray) -> np.ndarray:
        """Seconds from q to each view's nearest IK solution (inf where it has none),
        whether or not that solution is free of collision: it only breaks ties between views
        that measure as many sides, and the loop plans the motion it makes."""
        Q, n = self.ik(self.views, q)
        cost = np.full(len(self.views), np.inf)
        cost[n > 0] = self.travel_time(q, Q[n > 0, 0])
        return cost

    def _visit(self, i: int) -> None:
        """Marks view i visited and its sides measured; when no open view measures a side
        still needed, a new round asks each side for one more view."""
        self.open_views[i] = False
        self.needed &= ~self.covers[i]
        if not (self.covers[self.open_views] & self.needed).any():
            self.needed = self.covers[self.open_views].any(axis=0)

    def propose(self, observation: Observation) -> Proposal:
        if self._within(observation.estimate):
            return Proposal(done=True, reason=f"every dimension within "
                            f"{self.tolerance * 1000:g} mm of the truth")
        # Every open view that measures a needed side, in the greedy's order of preference:
        # the loop moves to the first it can reach.
        cost, open_views, ranked = self._cost(observation.q), self.open_views.copy(), []
        while (i := greedy_step(self.covers, self.needed, cost, open_views)) is not None:
            ranked.append(i)
            open_views[i] = False
        if not ranked:
            return Proposal(done=True, reason="no view left that measures a side")
        self._ranked = ranked
        return Proposal(candidates=[self.views[i] for i in ranked],
                        candidate_info=[{"oracle_view": i, "sides": [
                            s for s, c in zip(SIDES, self.covers[i], strict=True) if c]}
                            for i in ranked])

    def accepted(self, index: int, observation: Observation) -> None:
        self._visit(self._ranked[index])

    def restore(self, acquisitions: Sequence[Recorded]) -> None:
        """Marks the logged `oracle_view` of each acquisition visited, in order."""
        for a in acquisitions:
            if "oracle_view" in a.info:
                self._visit(int(a.info["oracle_view"]))
