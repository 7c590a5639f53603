"""The object's box fitted to the raw zone readings through the sensor model: the estimate the
product reports (`extraction.estimator: model`).

Why not the occupied cells: a box around cell centres inherits 1 cm quantisation, mixed zones
that straddle an edge (their depth placed along the zone-centre ray, beyond the edge) and the
range noise of the extreme readings, so it comes out 1-3.5 cm too large and grows with every
pose. Here the box (centre x, y, yaw, length, width, height, standing on the table plane) is
instead the one whose predicted readings best explain every valid zone reading near it: each
zone's footprint is sampled by k x k sub-rays, cast against the box and the table plane, and
reduced by the sensor model's own rule (`sensor.cluster_median`: the nearest surface
cluster holding `min_share` of the zone). A zone that sees the table beside the box bounds the
box from outside (free space), one that sees the top bounds it from inside, and mixed zones say
where the edge is, all in one residual.

The objective is a robust (soft-L1) sum over zones of the reading's residual in units of the
model's sigma. Sub-ray sampling makes it piecewise constant in the box's sides, with flat
steps on which Nelder-Mead and Powell stalled 2.5 cm from the truth on noise-free data; so it
is minimised by a coordinate grid search over the four sides, the height and the yaw (each
side is seen by its own zones, which makes the cost nearly separable in them), from the cell
box or, warm-started, from the previous estimate. Each dimension's uncertainty is a profile
interval: how far each side can move out and in, the others held, before the cost rises by
`interval_cost` (2.71, the 90 % level of one degree of freedom for a cost that is a chi-square
near its minimum), summed over the dimension's two sides and widened by `interval_floor_m` for
what the model does not capture. It bounds what the readings allow, not a posterior.
"""

from __future__ import annotations

import dataclasses as dc
import math
from collections.abc import Sequence

import numba
import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.sensor import (
    SensorModelParams,
    ToFFrame,
    cluster_rule,
    sorted_cluster_median,
)
from lrnbv_drake.core.tof_device import MERGED_DEPTHS, DeviceBehaviour, sorted_target


@dc.dataclass(frozen=True)
class BoxFitParams:
    """Settings of the box fit; lengths in metres."""

    # Zones whose footprint passes within this of the starting box are fitted; the others see
    # only the table far from the object and say nothing about it.
    zone_margin: float = 0.06
    # Soft-L1 scale of the residuals, in sigmas: beyond it a zone counts linearly, not
    # quadratically (a zone the model cannot explain must not drag the box).
    loss_scale: float = 2.0
    # Residual (sigmas) of a zone for which the box predicts no sizeable surface at all.
    no_return_residual: float = 5.0
    # Coordinate search: finest step of the sides and height, of the yaw; the yaw's span;
    # and a cap on the sweeps (each side is searched within the fit's `span`).
    step_m: float = 0.0005
    yaw_step_deg: float = 0.2
    yaw_span_deg: float = 6.0  # for the 3 cm span of a cold start; in proportion when warm
    max_sweeps: int = 6
    # How far the device's share of a zone needed to report a surface may be from the model's
    # (until calibrated, it is a guess): each side of the footprint moves by this share of a
    # zone's footprint at the zones' median range, 5 mm at 0.35 m for 0.15, and the length
    # and width intervals widen by it on both sides. Fitting the share as a seventh
    # coordinate was tried: with a dozen views it trades off against the sides.
    share_tolerance: float = 0.15
    # Profile interval: cost rise that bounds a dimension, and what is added on either side.
    interval_cost: float = 2.71
    interval_floor_m: float = 0.002
    interval_max_m: float = 0.1
    # The table top's footprint in the world, (x_min, y_min, x_max, y_max), metres: a sub-ray
    # that passes beyond it sees nothing there. None: an endless table.
    table_extent: tuple[float, float, float, float] | None = None
    # How the model says a zone picks its reading (`sensor:`'s target order and merging,
    # `reduction_rule`); None: the nearest cluster holding min_share.
    behaviour: DeviceBehaviour | None = None

    def extent(self) -> np.ndarray:
        """`table_extent` as the kernels take it, +-inf for an endless table."""
        return (np.array([-np.inf, -np.inf, np.inf, np.inf]) if self.table_extent is None
                else np.asarray(self.table_extent, float))


@dc.dataclass(frozen=True)
class BoxFit:
    """A fitted box and how well the readings pin it down."""

    box: OrientedBox
    # (3,) lower and upper bounds of (length, width, height) at the profile level.
    dims_lower: np.ndarray
    dims_upper: np.ndarray
    cost: float
    n_zones: int
    n_evaluations: int
    # What the box bounds: "box" (the fitted solid box) or "height_map" (the bounding box of
    # the height map `height_map_fit` fits where the readings need more than a box).
    shape: str = "box"
    # (3,) the part of each interval the readings set: how far the dimension's sides move out
    # and in before the cost rises, without the widening for what the model does not capture.
    # A side no reading bounds makes it large (up to 2 x `interval_max_m` a side). None: not
    # computed.
    readings_width: np.ndarray | None = None

    @property
    def dims_halfwidth(self) -> np.ndarray:
        """(3,) half the interval of each dimension, metres."""
        return (self.dims_upper - self.dims_lower) / 2


@dc.dataclass
class ZoneRays:
    """Valid zone readings in world coordinates, ready to predict."""

    # (n, 3) sensor origins, (n, m, 3) sub-ray directions scaled so that t is the perpendicular
    # depth, (n,) measured depth and its model sigma, metres.
    origins: np.ndarray
    directions: np.ndarray
    measured: np.ndarray
    sigma: np.ndarray

    @staticmethod
    def empty(m: int) -> ZoneRays:
        return ZoneRays(np.zeros((0, 3)), np.zeros((0, m, 3)), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return len(self.measured)

    def take(self, keep: np.ndarray) -> ZoneRays:
        return ZoneRays(self.origins[keep], self.directions[keep], self.measured[keep],
                        self.sigma[keep])

    def extend(self, other: ZoneRays) -> ZoneRays:
        return ZoneRays(*(np.concatenate([a, b]) for a, b in
                          ((self.origins, other.origins), (self.directions, other.directions),
                           (self.measured, other.measured), (self.sigma, other.sigma))))


def zone_rays(frame: ToFFrame, X_WS: np.ndarray, model: SensorModelParams) -> ZoneRays:
    """The valid zones of one frame as world sub-rays with their readings."""
    geometry = model.geometry
    k = model.subsamples
    valid = geometry.to_row_major(frame.valid).reshape(-1)
    depth = geometry.to_row_major(frame.distance_mm).reshape(-1).astype(float) / 1000.0
    d_S = geometry.sub_directions(k).reshape(-1, k * k, 3)[valid]
    X = np.asarray(X_WS, float)
    d_W = d_S @ X[:3, :3].T
    n = int(valid.sum())
    measured = depth[valid]
    return ZoneRays(np.repeat(X[None, :3, 3], n, axis=0), d_W, measured,
                    model.noise.sigma_mm(measured * 1000.0) / 1000.0)


@numba.njit(cache=True)
def _box_frame_origin(origins, i, x, floor, c, s):
    """Zone i's sensor origin in the frame of box x (centred, axes along its sides) standing on
    z = floor, and the box's half sizes."""
    px, py = origins[i, 0] - x[0], origins[i, 1] - x[1]
    hz = abs(x[5]) / 2
    return (c * px + s * py, -s * px + c * py, origins[i, 2] - floor - hz,
            abs(x[3]) / 2, abs(x[4]) / 2, hz)


@numba.njit(cache=True)
def _rotate(directions, i, c, s, d0, d1):
    """Zone i's sub-ray directions along the box's x and y axes (z is the world's)."""
    for j in range(directions.shape[1]):
        dx, dy = directions[i, j, 0], directions[i, j, 1]
        d0[j], d1[j] = c * dx + s * dy, -s * dx + c * dy


@numba.njit(cache=True)
def _slab_axis(o, h, d, t_near, t_far):
    """[t_near, t_far] narrowed to where the ray o + t d lies within |p| <= h on one axis."""
    if d == 0.0:
        if abs(o) > h:
            return np.inf, -np.inf
        return t_near, t_far
    t1, t2 = (-h - o) / d, (h - o) / d
    return max(t_near, min(t1, t2)), min(t_far, max(t1, t2))


@numba.njit(cache=True)
def _first_hit(o0, o1, o2, h0, h1, h2, d0, d1, d2):
    """Depth t of the first point of the box |p_a| <= h_a on the ray o + t d (box frame): 0
    from inside, inf if the ray misses it (slab test)."""
    t_near, t_far = _slab_axis(o0, h0, d0, -np.inf, np.inf)
    t_near, t_far = _slab_axis(o1, h1, d1, t_near, t_far)
    t_near, t_far = _slab_axis(o2, h2, d2, t_near, t_far)
    return max(t_near, 0.0) if t_near <= t_far and t_far > 0.0 else np.inf


@numba.njit(cache=True)
def _table_depths(origins, directions, i, table, extent, out):
    """Each of zone i's sub-rays' depth to the table top z = table within its footprint
    `extent` (x_min, y_min, x_max, y_max); inf if it never gets there. Constant while a box
    is fitted, so computed once per zone and call."""
    for j in range(directions.shape[1]):
        out[j] = np.inf
        if directions[i, j, 2] < 0.0:
            t = (table - origins[i, 2]) / directions[i, j, 2]
            x = origins[i, 0] + t * directions[i, j, 0]
            y = origins[i, 1] + t * directions[i, j, 1]
            if t > 0.0 and extent[0] <= x <= extent[2] and extent[1] <= y <= extent[3]:
                out[j] = t


@numba.njit(cache=True)
def _zone_depths(origins, directions, i, x, floor, c, s, d0, d1, table_t, depths):
    """Zone i's sub-ray depths: the first hit on box x standing on z = floor, or the table
    (`table_t`) where nearer; `d0`, `d1` from `_rotate` at x's yaw."""
    o0, o1, o2, h0, h1, h2 = _box_frame_origin(origins, i, x, floor, c, s)
    for j in range(directions.shape[1]):
        t = _first_hit(o0, o1, o2, h0, h1, h2, d0[j], d1[j], directions[i, j, 2])
        depths[j] = table_t[j] if table_t[j] < t else t


@numba.njit(cache=True)
def _reduce_sorted(ordered, min_count, gap_m, slope, merge_m, strongest, merged_mode, signal,
                   ones, foreign, target):
    """The model's reading of one zone from its sorted sub-ray depths: the nearest cluster
    holding min_count (`sorted_cluster_median`) or, with `merge_m` > 0 or the strongest order,
    the target the model's rule reports (`tof_device.sorted_target`, as the device does, every
    surface of one reflectance, so a sample's signal is 1 / d^2). `signal`, `ones`,
    `foreign`, `target`: work buffers."""
    if merge_m <= 0.0 and not strongest:
        return sorted_cluster_median(ordered, min_count, gap_m, slope)
    for j in range(ordered.shape[0]):
        d = ordered[j]
        signal[j] = 1.0 / (d * d) if math.isfinite(d) else 0.0
    sorted_target(ordered, signal, ones, foreign, ordered.shape[0], gap_m, slope, merge_m,
                  strongest, merged_mode, 0.0, min_count, target)
    return target[0]


@numba.njit(cache=True)
def _predict_kernel(origins, directions, x, table, extent, min_count, gap_m, slope, merge_m,
                    strongest, merged_mode, out):
    """`predicted_depths` zone by zone: the box's sub-ray depths reduced by the model's
    rule."""
    m = directions.shape[1]
    d0, d1, table_t, depths = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    signal, ones, foreign, target = np.empty(m), np.ones(m), np.zeros(m, np.bool_), np.empty(4)
    c, s = math.cos(x[2]), math.sin(x[2])
    for i in range(origins.shape[0]):
        _rotate(directions, i, c, s, d0, d1)
        _table_depths(origins, directions, i, table, extent, table_t)
        _zone_depths(origins, directions, i, x, table, c, s, d0, d1, table_t, depths)
        depths.sort()
        out[i] = _reduce_sorted(depths, min_count, gap_m, slope, merge_m, strongest,
                                merged_mode, signal, ones, foreign, target)


@numba.njit(cache=True, error_model="numpy")
def _costs_kernel(origins, directions, measured, sigma, zones, xs, table, extent, min_count,
                  gap_m, slope, merge_m, strongest, merged_mode, loss_scale, loss_scale_sq,
                  no_return, order, out):
    """out[n, k]: the soft-L1 cost of zone zones[k]'s residual in model sigmas (`no_return`
    where no cluster is sizeable, inf for a flat box) for box xs[n], every candidate of a grid
    in one call. Zone by zone, so what only the zone fixes (the table depths, the
    rotated sub-rays while the yaw stays) is computed once; each zone's samples are sorted by
    insertion starting from `order[i]`, the order of its previous evaluation, which a small
    step of the box barely changes (a sort of nearly sorted samples is about linear)."""
    m = directions.shape[1]
    d0, d1, table_t, depths = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    ordered = np.empty(m)
    signal, ones, foreign, target = np.empty(m), np.ones(m), np.zeros(m, np.bool_), np.empty(4)
    for k in range(zones.shape[0]):
        i = zones[k]
        _table_depths(origins, directions, i, table, extent, table_t)
        yaw, c, s = np.nan, 1.0, 0.0
        for n in range(xs.shape[0]):
            x = xs[n]
            if x[3] <= 0.0 or x[4] <= 0.0 or x[5] <= 0.0:  # a flat box
                out[n, k] = np.inf
                continue
            if x[2] != yaw:
                yaw = x[2]
                c, s = math.cos(yaw), math.sin(yaw)
                _rotate(directions, i, c, s, d0, d1)
            _zone_depths(origins, directions, i, x, table, c, s, d0, d1, table_t, depths)
            for j in range(m):
                ordered[j] = depths[order[i, j]]
            for j in range(1, m):
                v, index = ordered[j], order[i, j]
                a = j - 1
                while a >= 0 and ordered[a] > v:
                    ordered[a + 1], order[i, a + 1] = ordered[a], order[i, a]
                    a -= 1
                ordered[a + 1], order[i, a + 1] = v, index
            r = (measured[i] - _reduce_sorted(ordered, min_count, gap_m, slope, merge_m,
                                              strongest, merged_mode, signal, ones, foreign,
                                              target)) / sigma[i]
            if math.isnan(r):
                r = no_return
            q = r / loss_scale
            out[n, k] = 2.0 * (math.sqrt(1.0 + q * q) - 1.0) * loss_scale_sq


@numba.njit(cache=True)
def _crosses_kernel(origins, directions, x, floor, out):
    """out[i]: a sub-ray of zone i passes through box x standing on z = floor."""
    c, s = math.cos(x[2]), math.sin(x[2])
    for i in range(origins.shape[0]):
        o0, o1, o2, h0, h1, h2 = _box_frame_origin(origins, i, x, floor, c, s)
        out[i] = False
        for j in range(directions.shape[1]):
            dx, dy = directions[i, j, 0], directions[i, j, 1]
            if _first_hit(o0, o1, o2, h0, h1, h2, c * dx + s * dy, -s * dx + c * dy,
                          directions[i, j, 2]) < np.inf:
                out[i] = True
                break


def reduction_rule(model: SensorModelParams, behaviour: DeviceBehaviour | None, m: int
                   ) -> tuple[int, float, float, float, bool, int]:
    """The kernels' arguments for the model's reading of a zone of m sub-rays: the cluster
    rule (`cluster_rule`), then the merge distance (m), strongest order and merged depth of
    `behaviour` (None, or merge_mm 0 with the closest order: the nearest cluster holding
    min_share)."""
    b = behaviour or DeviceBehaviour()
    return (*cluster_rule(model, m), b.merge_mm / 1000.0, b.target_order == "strongest",
            MERGED_DEPTHS.index(b.merged_depth))


def predicted_depths(rays: ZoneRays, x: np.ndarray, table_height: float,
                     model: SensorModelParams, params: BoxFitParams | None = None
                     ) -> np.ndarray:
    """(n,) the depth the model says each zone reports for box x = (cx, cy, yaw, L, W, H)
    standing on the table plane; NaN where no surface cluster is sizeable."""
    out = np.empty(len(rays))
    _predict_kernel(rays.origins, rays.directions, np.asarray(x, float), float(table_height),
                    (params or BoxFitParams()).extent(),
                    *reduction_rule(model, (params or BoxFitParams()).behaviour,
                                    rays.directions.shape[1]), out)
    return out


def _as_vector(box: OrientedBox) -> np.ndarray:
    return np.array([box.center[0], box.center[1], box.yaw, *box.dims])


def near_box(rays: ZoneRays, box: OrientedBox, table_height: float, margin: float
             ) -> np.ndarray:
    """(n,) zones with a sub-ray through `box` grown by `margin` (the zones that see it)."""
    x = _as_vector(box)
    x[3:5] += 2 * margin
    floor = table_height - margin
    x[5] = box.center[2] + box.dims[2] / 2 + margin - floor
    return _through(rays, x, floor)


def _through(rays: ZoneRays, x: np.ndarray, floor: float) -> np.ndarray:
    """(n,) zones with a sub-ray through box x standing on z = floor, whatever lies in front."""
    out = np.empty(len(rays), bool)
    _crosses_kernel(rays.origins, rays.directions, x, floor, out)
    return out


#: The least length, width and height a search starts from, metres (`_Edges`).
MIN_START_M = 0.01


class _Edges:
    """The box as its four side positions along and across the start box's axes, its height
    and its yaw, p = (a1, a2, b1, b2, h, yaw): each side is seen by its own zones, so the cost
    is nearly separable in these, which a coordinate search exploits."""

    def __init__(self, start: OrientedBox) -> None:
        self.c0 = np.asarray(start.center[:2], float)
        # A start flat in two dimensions (the cell centres of one column) would keep every
        # trial flat, and a flat box costs inf: a search that moves one side at a time never
        # leaves it. One cell is the least a start from the map can mean.
        dims = np.maximum(start.dims, MIN_START_M)
        half = dims / 2
        self.p0 = np.array([-half[0], half[0], -half[1], half[1], dims[2], start.yaw])

    def to_x(self, p: np.ndarray) -> np.ndarray:
        a1, a2, b1, b2, h, yaw = p
        u = np.array([math.cos(yaw), math.sin(yaw)])
        v = np.array([-u[1], u[0]])
        c = self.c0 + (a1 + a2) / 2 * u + (b1 + b2) / 2 * v
        return np.array([c[0], c[1], yaw, a2 - a1, b2 - b1, h])


class _SideSearch:
    """A coordinate grid search over `_Edges` coordinates that re-evaluates, for each side or
    the top, only the zones whose sub-rays cross the slab it sweeps: the others' predictions
    cannot change, so their cost is carried over (about a fifth of the zones a side). A grid's
    candidates are evaluated in one kernel call."""

    def __init__(self, rays: ZoneRays, edges: _Edges, table_height: float,
                 model: SensorModelParams, params: BoxFitParams) -> None:
        self.rays, self.edges, self.table = rays, edges, table_height
        self.params = params
        m = rays.directions.shape[1]
        self._rule = reduction_rule(model, params.behaviour, m)
        self._extent = params.extent()
        self._all = np.arange(len(rays))
        # Each zone's samples in the order its last evaluation sorted them (see _costs_kernel).
        self._order = np.tile(np.arange(m), (len(rays), 1))
        self.evaluations = 0

    def zone_costs(self, ps: Sequence[np.ndarray], zones: np.ndarray | None = None
                   ) -> np.ndarray:
        """(len(ps), len(zones)) each zone's cost (`_costs_kernel`) for each coordinate vector
        in `ps`; all zones by default."""
        self.evaluations += len(ps)
        zones = self._all if zones is None else zones
        xs = np.array([self.edges.to_x(p) for p in ps])
        out = np.empty((len(ps), len(zones)))
        r, params = self.rays, self.params
        _costs_kernel(r.origins, r.directions, r.measured, r.sigma, zones, xs, self.table,
                      self._extent, *self._rule, params.loss_scale, params.loss_scale ** 2,
                      params.no_return_residual, self._order, out)
        return out

    def cost(self, p: np.ndarray) -> float:
        return float(np.sum(self.zone_costs([p])[0]))

    def _swept(self, p: np.ndarray, index: int, grid: np.ndarray) -> np.ndarray | None:
        """Indices of the zones whose sub-rays cross the slab coordinate `index` sweeps over
        `grid`; None (all) for the yaw, which moves every side."""
        if index == 5:
            return None
        q = p.copy()
        lo, hi = float(grid.min()), float(grid.max())
        if index == 4:
            through = _through(self.rays, self.edges.to_x(np.r_[q[:4], hi - lo, q[5]]),
                               self.table + lo)
        else:
            q[index - index % 2], q[index - index % 2 + 1] = lo, hi
            through = _through(self.rays, self.edges.to_x(q), self.table)
        return np.flatnonzero(through)

    def run(self, p: np.ndarray, spans: np.ndarray, steps: np.ndarray, max_sweeps: int
            ) -> tuple[np.ndarray, float]:
        """Minimises one coordinate at a time over a grid, +-span in tenths (at least three
        `steps`) then +-1.5 of those in `steps`, sweeping until a sweep improves nothing. A
        grid does not stall on the flat steps of a sub-sampled objective, where simplex and
        line searches do."""
        p = p.copy()
        costs = self.zone_costs([p])[0]
        for _ in range(max_sweeps):
            improved = False
            for i in range(len(p)):
                coarse = max(spans[i] / 10, 3 * steps[i])
                for span, step in ((spans[i], coarse), (1.5 * coarse, steps[i])):
                    grid = p[i] + np.arange(-span, span + step / 2, step)
                    keep = self._swept(p, i, grid)
                    now = costs if keep is None else costs[keep]
                    best_j, best_sum = -1, float(np.sum(now)) - 1e-9
                    candidates = np.repeat(p[None], len(grid), axis=0)
                    candidates[:, i] = grid
                    trials = self.zone_costs(candidates, keep)
                    for j, trial in enumerate(trials):
                        total = float(np.sum(trial))
                        if total < best_sum:
                            best_j, best_sum = j, total
                    if best_j >= 0:
                        p[i] = grid[best_j]
                        if keep is None:
                            costs = trials[best_j]
                        else:
                            costs[keep] = trials[best_j]
                        improved = True
            if not improved:
                break
        return p, float(np.sum(costs))


def fit_box(rays: ZoneRays, start: OrientedBox, table_height: float,
            model: SensorModelParams, params: BoxFitParams | None = None,
            interval: bool = True, span: float = 0.03) -> BoxFit | None:
    """The box that best explains the zone readings `rays` near `start` (see the module doc),
    searched within about `span` of it; None when no reading sees the box's neighbourhood.
    Without `interval` the dimension bounds are NaN (they cost about 100 evaluations)."""
    params = params or BoxFitParams()
    rays = rays.take(near_box(rays, start, table_height, params.zone_margin + span))
    if len(rays) == 0:
        return None
    edges = _Edges(start)
    search = _SideSearch(rays, edges, table_height, model, params)
    spans = np.array([span] * 5 + [math.radians(params.yaw_span_deg) * span / 0.03])
    steps = np.array([params.step_m] * 5 + [math.radians(params.yaw_step_deg)])
    p, best = search.run(edges.p0, spans, steps, params.max_sweeps)
    if not math.isfinite(best):  # no box near the start explains any reading
        return None
    cost = search.cost
    # How far each side (and the top) can move out and in: the dimension's bounds add them.
    # A cost far above one per zone says the model explains the readings worse than its
    # sigma claims (a device that is not the model): the threshold grows with it, as a
    # least-squares interval scales with the reduced chi-square.
    rise = params.interval_cost * max(1.0, best / max(len(rays) - 6, 1))
    out, inward = np.full(5, np.nan), np.full(5, np.nan)
    for i in range(5 if interval else 0):
        outward_sign = -1 if i in (0, 2) else 1
        for sign, store in ((outward_sign, out), (-outward_sign, inward)):
            store[i] = profile_move(cost, p, i, sign, best, rise, params)
    share = (params.share_tolerance * float(np.median(rays.measured))
             * math.radians(model.geometry.zone_deg))
    widen = params.interval_floor_m + np.array([2 * share, 2 * share, 0.0])
    x = edges.to_x(p)
    lower = x[3:] - np.array([inward[0] + inward[1], inward[2] + inward[3], inward[4]]) - widen
    upper = x[3:] + np.array([out[0] + out[1], out[2] + out[3], out[4]]) + widen
    box = OrientedBox(np.array([x[0], x[1], table_height + abs(x[5]) / 2]),
                      np.abs(x[3:]), float(x[2]))
    moves = out + inward
    width = np.array([moves[0] + moves[1], moves[2] + moves[3], moves[4]])
    lower = np.maximum(lower, 0.0)
    if _swapped(box.yaw, x[2]):  # the canonical box's length is the search's width
        lower, upper, width = lower[[1, 0, 2]], upper[[1, 0, 2]], width[[1, 0, 2]]
    return BoxFit(box, lower, upper, best, len(rays), search.evaluations,
                  readings_width=None if not interval else width)


def _swapped(canonical_yaw: float, yaw: float) -> bool:
    """Whether a canonical box's length lies along the width of the box it was made from at
    `yaw`: told by the yaws, as a square's dims are equal either way."""
    return abs(math.cos(canonical_yaw - yaw)) < 0.5


def profile_move(cost, p: np.ndarray, index: int, sign: int, best: float, rise: float,
                 params: BoxFitParams, limit: float | None = None) -> float:
    """How far coordinate `index` moves in direction `sign`, the others held, before the cost
    rises by `rise` above the lowest cost met on the way (`best` at `p`; doubling from 1 mm,
    then bisection to 0.5 mm), at most `limit` (`interval_max_m`).

    From the lowest cost met, not from `best`: `p` is not always the minimum of `cost` along
    the move (the height map's clip is searched before its top is refitted), and from `best`
    a cost that falls before it rises never bounds the move (measured: flanges whose length
    came out 10 cm open, which put them in a container two sizes up)."""
    reach = params.interval_max_m if limit is None else max(0.0, min(limit, params.interval_max_m))
    lowest = best

    def rises(step: float) -> bool:
        nonlocal lowest
        q = p.copy()
        q[index] += sign * step
        c = cost(q)
        lowest = min(lowest, c)
        return c - lowest >= rise

    inside, step = 0.0, 0.001
    while step < reach and not rises(step):
        inside, step = step, 2 * step
    if step >= reach:
        if not rises(reach):
            return reach
        step = reach
    while step - inside > 0.0005:
        mid = (inside + step) / 2
        if rises(mid):
            step = mid
        else:
            inside = mid
    return (inside + step) / 2


#: Below this footprint IoU with the start it is given, `BoxEstimator` also fits from the
#: start. A cell box is 1-3 cm larger than the object: 0.6-0.8 against a right estimate.
STALE_IOU = 0.5


class BoxEstimator:
    """The fit kept up to date pose by pose: each `add` stores a frame's rays and `estimate`
    refits, starting from the previous estimate when there is one (a warm start), so a planner
    or a stop rule can ask after every pose."""

    def __init__(self, model: SensorModelParams, table_height: float,
                 params: BoxFitParams | None = None) -> None:
        self._model = model
        self._table_height = table_height
        self._params = params or BoxFitParams()
        self._rays = ZoneRays.empty(model.subsamples ** 2)
        self.last: BoxFit | None = None

    def add(self, frame: ToFFrame, X_WS: np.ndarray) -> None:
        """Stores the valid zones of one acquisition."""
        self._rays = self._rays.extend(zone_rays(frame, X_WS, self._model))

    def estimate(self, start: OrientedBox | None = None, interval: bool = True
                 ) -> BoxFit | None:
        """Refits from the last estimate (6 mm around it) and, before the first or when the last
        estimate and `start` (e.g. the cell box) disagree (footprint IoU below `STALE_IOU`),
        from `start` (3 cm around it), keeping the fit of lower cost per zone: an estimate of
        something else (a first cluster on noise) is not held there by the narrow search.
        `interval` as in `fit_box`."""
        fits = []
        if self.last is not None:
            fits.append(fit_box(self._rays, self.last.box, self._table_height, self._model,
                                self._params, interval, span=0.006))
        if start is not None and (self.last is None
                                  or self.last.box.footprint_iou(start) < STALE_IOU):
            fits.append(fit_box(self._rays, start, self._table_height, self._model,
                                self._params, interval, span=0.03))
        fits = [f for f in fits if f is not None]
        if fits:
            self.last = min(fits, key=lambda f: f.cost / f.n_zones)
        return self.last


def fit_episode(acquisitions: Sequence[tuple[ToFFrame, np.ndarray]], start: OrientedBox,
                table_height: float, model: SensorModelParams,
                params: BoxFitParams | None = None) -> BoxFit | None:
    """`fit_box` over every (frame, X_WS) of an episode, from `start`."""
    estimator = BoxEstimator(model, table_height, params)
    for frame, X_WS in acquisitions:
        estimator.add(frame, X_WS)
    return estimator.estimate(start)
