"""The forward model of the readings: what the sensor model says each zone reads for a shape
standing on the known table plane.

A zone's footprint is sampled by the model's k x k sub-rays (`ZoneGeometry.sub_directions`);
each sub-ray's depth is its first hit on the shape or on the table top (only within the
table's footprint: past its edge a sub-ray sees nothing), and the zone's reading is the
device rule applied to those depths: the same numba functions the simulated device reduces
its samples with (`sensor.sorted_cluster_median` for the nearest surface holding a share of
the zone, `tof_device.sorted_target` for targets merged by signal). Under the merged rule
with every surface in one target, the reading is the signal-weighted mean depth, every
surface of one reflectance: sum(1 / d) / sum(1 / d^2).

The shape is solid parts minus hole parts (`PART_SIZE` numbers each): a box (centre x, y,
yaw, length, width, height, standing on the table) cut by the ellipsoid rx (x/a)^2 +
ry (y/b)^2 + rz (z/c)^2 <= 1 in the box's own frame (a, b, c its half sizes). All r = 0 is
the box; (1, 1, 0) an upright elliptic cylinder, (1, 1, 1) an ellipsoid, (0, 1, 1) a
cylinder lying along the box's length. A taper tau in [-1, 1] scales the cross-section
linearly with height about the part's axis, by s = 1 - tau h / H at height h of H (tau > 0:
narrowing upward, 1 a cone or pyramid) or s = 1 + tau (1 - h / H) (tau < 0: widening
upward, a bucket), so the box still bounds the part: its sides become |x| <= a s and
|y| <= b s, and an upright cylinder's quadric rx (x/a)^2 + ry (y/b)^2 <= s^2, still
linear and quadratic along a ray (a tapered part has rz = 0). Every part is convex, so a
sub-ray meets it in one interval, exactly and in a few dozen flops, and its first visible
point is the first entry into a solid, or exit from a hole inside one, that no hole
covers. A clip plane n . p <= offset cuts every solid part (the interval's inward moves).
"""

from __future__ import annotations

import dataclasses as dc
import math

import numba
import numpy as np

from lrnbv_drake.core.sensing.sensor import (
    SensorModelParams,
    ToFFrame,
    cluster_rule,
    sorted_cluster_median,
)
from lrnbv_drake.core.sensing.tof_device import MERGED_DEPTHS, DeviceBehaviour, sorted_target

#: Numbers per part: centre x, y, yaw, length, width, height, rx, ry, rz, taper.
PART_SIZE = 10
#: The clip plane that cuts nothing.
NO_CLIP = np.array([0.0, 0.0, 0.0, 1.0])


@dc.dataclass
class ZoneRays:
    """Valid zone readings in world coordinates: (n, 3) sensor origins, (n, m, 3) sub-ray
    directions scaled so that t is the perpendicular depth, (n,) measured depths and their
    model sigmas, metres; (n, 4, 3) `planes`, each zone's bundle as four planes through its
    origin that every sub-ray lies behind (`bundle_planes`)."""

    origins: np.ndarray
    directions: np.ndarray
    measured: np.ndarray
    sigma: np.ndarray
    planes: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.planes is None:
            self.planes = bundle_planes(self.directions)

    def __len__(self) -> int:
        return len(self.measured)

    def take(self, keep: np.ndarray) -> ZoneRays:
        return ZoneRays(self.origins[keep], self.directions[keep], self.measured[keep],
                        self.sigma[keep], self.planes[keep])

    @staticmethod
    def concatenate(parts: list[ZoneRays], m: int) -> ZoneRays:
        if not parts:
            return ZoneRays(np.zeros((0, 3)), np.zeros((0, m, 3)), np.zeros(0), np.zeros(0))
        return ZoneRays(*(np.concatenate([getattr(p, f.name) for p in parts])
                          for f in dc.fields(ZoneRays)))

    def crossing(self, x: np.ndarray, floor: float, rows: np.ndarray | None = None,
                 before: np.ndarray | None = None) -> np.ndarray:
        """(len(rows), m) whether each sub-ray of zones `rows` (all if None) passes through
        box x standing on z = floor (its rounding ignored); with `before` (n, m), only where
        it enters the box no farther than its depth `before[i, j]`."""
        rows = np.arange(len(self)) if rows is None else rows
        return crossing(self.origins, self.directions, self.planes, rows, x, floor, before)


def bundle_planes(directions: np.ndarray) -> np.ndarray:
    """(n, 4, 3) normals of four planes through each zone's origin with every one of its
    sub-rays `directions` (n, m, 3) on their non-positive side: the sides of the rectangle
    that bounds the sub-rays' gnomonic projection about their mean direction, aligned with
    the first row of a k x k grid. A box whose corners all lie beyond one plane meets none of
    the zone's sub-rays, which `crossing` and `shape_depths` then skip."""
    n, m = directions.shape[:2]
    if n == 0:
        return np.zeros((0, 4, 3))
    unit = directions / np.linalg.norm(directions, axis=2, keepdims=True)
    u = unit.mean(axis=1)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    k = max(math.isqrt(m), 1)
    row = unit[:, k - 1] - unit[:, 0] if k > 1 else np.zeros((n, 3))
    row -= np.sum(row * u, axis=1, keepdims=True) * u
    fallback = np.cross(u, np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    row = np.where(np.linalg.norm(row, axis=1, keepdims=True) > 1e-9, row, fallback)
    e1 = row / np.linalg.norm(row, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    along = np.einsum("nmj,nj->nm", unit, u)
    a = np.einsum("nmj,nj->nm", unit, e1) / along
    b = np.einsum("nmj,nj->nm", unit, e2) / along
    slack = 1e-9
    lo_a, hi_a = a.min(axis=1)[:, None] - slack, a.max(axis=1)[:, None] + slack
    lo_b, hi_b = b.min(axis=1)[:, None] - slack, b.max(axis=1)[:, None] + slack
    return np.stack([lo_a * u - e1, e1 - hi_a * u, lo_b * u - e2, e2 - hi_b * u], axis=1)


def zone_rays(frame: ToFFrame, X_WS: np.ndarray, model: SensorModelParams) -> ZoneRays:
    """The valid zones of one frame as world sub-rays with their readings."""
    geometry, k = model.geometry, model.subsamples
    valid = geometry.to_row_major(frame.valid).reshape(-1)
    depth = geometry.to_row_major(frame.distance_mm).reshape(-1).astype(float)[valid] / 1000
    d_S = geometry.sub_directions(k).reshape(-1, k * k, 3)[valid]
    X = np.asarray(X_WS, float)
    return ZoneRays(np.repeat(X[None, :3, 3], len(depth), axis=0), d_S @ X[:3, :3].T, depth,
                    model.noise.sigma_mm(depth * 1000) / 1000)


@dc.dataclass(frozen=True)
class ReadingRule:
    """The kernels' form of how the model picks a zone's reading among its sub-rays' depths
    (`sensor:`: the share and gap of the cluster rule, the target order and merging)."""

    min_count: int
    gap_m: float
    slope: float
    merge_m: float
    strongest: bool
    merged_mode: int

    @staticmethod
    def of(model: SensorModelParams, behaviour: DeviceBehaviour) -> ReadingRule:
        return ReadingRule(*cluster_rule(model, model.subsamples ** 2),
                           behaviour.merge_mm / 1000, behaviour.target_order == "strongest",
                           MERGED_DEPTHS.index(behaviour.merged_depth))

    def args(self) -> tuple:
        return (self.min_count, self.gap_m, self.slope, self.merge_m, self.strongest,
                self.merged_mode)


@numba.njit(cache=True, nogil=True)
def _interval(o, d, x, c, s, table, clip):
    """(t0, t1): where the ray o + t d is inside part x, whose yaw has cosine c and sine s
    (and the clip plane); t0 > t1 if nowhere."""
    px, py = o[0] - x[0], o[1] - x[1]
    half = (0.5 * x[3], 0.5 * x[4], 0.5 * x[5])
    p = (c * px + s * py, -s * px + c * py, o[2] - table - half[2])
    v = (c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2])
    # The cross-section's scale along the ray, g0 + g1 t (the module doc; 1 untapered).
    tau = x[9]
    g0 = 1.0 - max(-tau, 0.0) - tau * (p[2] / x[5] + 0.5)
    g1 = -tau * v[2] / x[5]
    t0, t1 = -np.inf, np.inf
    qa, qb, qc = -g1 * g1, -2.0 * g0 * g1, -g0 * g0
    for i in range(3):
        if i < 2 and tau != 0.0:
            for sign in (1.0, -1.0):  # sign (p_i + t v_i) <= half_i (g0 + g1 t)
                a, b = sign * v[i] - half[i] * g1, half[i] * g0 - sign * p[i]
                if a > 0.0:
                    t1 = min(t1, b / a)
                elif a < 0.0:
                    t0 = max(t0, b / a)
                elif b < 0.0:
                    return np.inf, -np.inf
        elif v[i] == 0.0:
            if abs(p[i]) > half[i]:
                return np.inf, -np.inf
        else:
            u, w = (-half[i] - p[i]) / v[i], (half[i] - p[i]) / v[i]
            t0, t1 = max(t0, min(u, w)), min(t1, max(u, w))
        r = x[6 + i] / (half[i] * half[i])
        qa += r * v[i] * v[i]
        qb += 2.0 * r * p[i] * v[i]
        qc += r * p[i] * p[i]
    if x[6] + x[7] + x[8] > 0.0:
        disc = qb * qb - 4.0 * qa * qc
        if qa > 0.0:
            if disc < 0.0:
                return np.inf, -np.inf
            root = math.sqrt(disc)
            t0, t1 = max(t0, (-qb - root) / (2.0 * qa)), min(t1, (-qb + root) / (2.0 * qa))
        elif qa < 0.0:
            # A tapered quadric: inside outside the roots, of which one piece lies within
            # the slabs (the other nappe is beyond the apex, outside them).
            if disc > 0.0:
                root = math.sqrt(disc)
                lo, hi = (-qb + root) / (2.0 * qa), (-qb - root) / (2.0 * qa)
                if min(t1, lo) - t0 >= t1 - max(t0, hi):
                    t1 = min(t1, lo)
                else:
                    t0 = max(t0, hi)
        elif qb != 0.0:
            if qb > 0.0:
                t1 = min(t1, -qc / qb)
            else:
                t0 = max(t0, -qc / qb)
        elif qc > 0.0:
            return np.inf, -np.inf
    nd = clip[0] * d[0] + clip[1] * d[1] + clip[2] * d[2]
    no = clip[0] * o[0] + clip[1] * o[1] + clip[2] * o[2]
    if nd == 0.0:
        if no > clip[3]:
            return np.inf, -np.inf
    elif nd > 0.0:
        t1 = min(t1, (clip[3] - no) / nd)
    else:
        t0 = max(t0, (clip[3] - no) / nd)
    return t0, t1


@numba.njit(cache=True, nogil=True)
def _visible(t0, t1, solid, floor):
    """The first point at t >= 0 inside a solid interval and in no hole's interior, or
    `floor` (the table's depth) where that is nearer."""
    best = floor
    for i in range(t0.shape[0]):
        if t0[i] > t1[i] or t1[i] < 0.0:
            continue
        t = max(t0[i], 0.0) if solid[i] else t1[i]
        if t >= best:
            continue
        ok = True
        for j in range(t0.shape[0]):
            if j != i and not solid[j] and t0[j] < t < t1[j] and t0[j] <= t1[j]:
                ok = False
                break
        if ok and not solid[i]:  # a hole's far end shows only where a solid holds it
            ok = False
            for j in range(t0.shape[0]):
                if solid[j] and t0[j] <= t <= t1[j]:
                    ok = True
                    break
        if ok:
            best = t
    return best


@numba.njit(cache=True, nogil=True)
def table_depths(origins, directions, table, extent):
    """(n, m) each sub-ray's depth to the table top z = table within its footprint `extent`
    (x_min, y_min, x_max, y_max); inf where it never gets there."""
    n, m = directions.shape[0], directions.shape[1]
    out = np.full((n, m), np.inf)
    for i in range(n):
        for j in range(m):
            dz = directions[i, j, 2]
            if dz < 0.0:
                t = (table - origins[i, 2]) / dz
                x = origins[i, 0] + t * directions[i, j, 0]
                y = origins[i, 1] + t * directions[i, j, 1]
                if extent[0] <= x <= extent[2] and extent[1] <= y <= extent[3]:
                    out[i, j] = t
    return out


@numba.njit(cache=True, nogil=True, parallel=True)
def shape_depths(origins, directions, planes, parts, solid, base, table, clip):
    """(n, m) each sub-ray's depth to the shape (`parts`, `solid` their kinds; the clip plane
    cuts the solids) or the table (`base`); a part a zone's bundle (`planes`) misses is not
    cast for its sub-rays. Zones are cast in parallel, each alone, so the result does not
    depend on the threads."""
    n, m, k = directions.shape[0], directions.shape[1], parts.shape[0]
    out = np.empty((n, m))
    cs, sn = np.cos(parts[:, 2]), np.sin(parts[:, 2])
    for i in numba.prange(n):
        t0, t1 = np.empty(k), np.empty(k)
        hit = np.empty(k, np.bool_)
        for p in range(k):
            hit[p] = not _misses(origins[i], planes[i], parts[p], cs[p], sn[p], table)
        for j in range(m):
            for p in range(k):
                if hit[p]:
                    t0[p], t1[p] = _interval(origins[i], directions[i, j], parts[p], cs[p],
                                             sn[p], table, clip if solid[p] else NO_CLIP)
                else:
                    t0[p], t1[p] = np.inf, -np.inf
            out[i, j] = _visible(t0, t1, solid, base[i, j])
    return out


@numba.njit(cache=True, nogil=True)
def _reading(depths, min_count, gap_m, slope, merge_m, strongest, merged_mode, work):
    """The model's reading of one zone from its sub-rays' depths (inf: no return); NaN where
    the rule reports nothing. `work`: (3 m + 4) scratch."""
    m = depths.shape[0]
    if merge_m > 0.0 and merged_mode == 0:
        lo, hi, s1, s2 = np.inf, -np.inf, 0.0, 0.0
        for j in range(m):
            d = depths[j]
            if math.isfinite(d) and d > 0.0:
                lo, hi = min(lo, d), max(hi, d)
                s1 += 1.0 / d
                s2 += 1.0 / (d * d)
        if s2 == 0.0:
            return np.nan
        if hi - lo < merge_m:  # one target: every surface merged
            return s1 / s2
    ordered, signal, ones = work[:m], work[m:2 * m], work[2 * m:3 * m]
    for j in range(m):
        ordered[j] = depths[j] if depths[j] > 0.0 else np.inf
    ordered.sort()
    for j in range(m):
        signal[j] = 1.0 / (ordered[j] * ordered[j]) if math.isfinite(ordered[j]) else 0.0
        ones[j] = 1.0
    if merge_m <= 0.0 and not strongest:
        return sorted_cluster_median(ordered, min_count, gap_m, slope)
    target = work[3 * m:3 * m + 4]
    sorted_target(ordered, signal, ones, np.zeros(m, np.bool_), m, gap_m, slope, merge_m,
                  strongest, merged_mode, 0.0, min_count, target)
    return target[0]


@numba.njit(cache=True, nogil=True)
def _loss(measured, sigma, predicted, scale, no_return):
    """Soft-L1 of the residual in sigmas, `no_return` sigmas where nothing is predicted."""
    r = no_return if math.isnan(predicted) else (measured - predicted) / sigma
    q = r / scale
    return 2.0 * scale * scale * (math.sqrt(1.0 + q * q) - 1.0)


@numba.njit(cache=True, nogil=True)
def zone_losses(depths, measured, sigma, min_count, gap_m, slope, merge_m, strongest,
                merged_mode, scale, no_return):
    """(n,) each zone's reading (`_reading`) and its loss."""
    work = np.empty(3 * depths.shape[1] + 4)
    predicted, out = np.empty(depths.shape[0]), np.empty(depths.shape[0])
    for i in range(depths.shape[0]):
        predicted[i] = _reading(depths[i], min_count, gap_m, slope, merge_m, strongest,
                                merged_mode, work)
        out[i] = _loss(measured[i], sigma[i], predicted[i], scale, no_return)
    return predicted, out


@numba.njit(cache=True, nogil=True)
def _misses(o, planes, x, c, s, floor):
    """Whether box x (yaw cosine c, sine s) standing on z = floor lies wholly beyond one of a
    zone's bundle `planes` (4, 3) through its origin o, so that none of its sub-rays meets
    it."""
    for i in range(4):
        beyond = True
        for corner in range(8):
            u = (0.5 if corner & 1 else -0.5) * x[3]
            v = (0.5 if corner & 2 else -0.5) * x[4]
            px = x[0] + c * u - s * v - o[0]
            py = x[1] + s * u + c * v - o[1]
            pz = floor + (x[5] if corner & 4 else 0.0) - o[2]
            if planes[i, 0] * px + planes[i, 1] * py + planes[i, 2] * pz <= 1e-9:
                beyond = False
                break
        if beyond:
            return True
    return False


@numba.njit(cache=True, nogil=True, parallel=True)
def crossing(origins, directions, planes, rows, x, floor, before=None):
    """(len(rows), m) whether each sub-ray of zones `rows` passes through box x standing on
    z = floor (its rounding ignored) and, with `before` (n, m) depths, enters it no farther
    than `before[i, j]` (a millimetre's millionth of slack); a zone whose bundle misses the
    box is not cast."""
    box = x.copy()
    box[6:] = 0.0
    c, s = math.cos(x[2]), math.sin(x[2])
    out = np.zeros((rows.shape[0], directions.shape[1]), np.bool_)
    for r in numba.prange(rows.shape[0]):
        i = rows[r]
        if _misses(origins[i], planes[i], box, c, s, floor):
            continue
        for j in range(directions.shape[1]):
            t0, t1 = _interval(origins[i], directions[i, j], box, c, s, floor, NO_CLIP)
            out[r, j] = t0 <= t1 and t1 > 0.0
            if before is not None:
                out[r, j] = out[r, j] and t0 <= before[i, j] + 1e-9
    return out


@numba.njit(cache=True, nogil=True, parallel=True)
def grid_costs(origins, directions, measured, sigma, zones, starts, subrays, parts, solid,
               k, xs, depths, base, table, min_count, gap_m, slope, merge_m, strongest,
               merged_mode, scale, no_return):
    """(len(xs), len(zones)) each zone's loss with part k at each candidate xs[n]: a grid of
    one coordinate in one call. Only the sub-rays `subrays[starts[z]:starts[z + 1]]` of zone
    z can change (they cross what the grid moves); the others keep `depths`. Zones are
    costed in parallel, each alone, so the result does not depend on the threads."""
    m, n_parts = directions.shape[1], parts.shape[0]
    out = np.empty((xs.shape[0], zones.shape[0]))
    fixed0 = np.empty((subrays.shape[0], n_parts))
    fixed1 = np.empty((subrays.shape[0], n_parts))
    merged = merge_m > 0.0 and merged_mode == 0
    cs, sn = np.cos(parts[:, 2]), np.sin(parts[:, 2])
    xc, xsn = np.cos(xs[:, 2]), np.sin(xs[:, 2])
    for z in numba.prange(zones.shape[0]):
        i = zones[z]
        work = np.empty(3 * m + 4)
        d = np.empty(m)
        t0, t1 = np.empty(n_parts), np.empty(n_parts)
        for a in range(starts[z], starts[z + 1]):
            for p in range(n_parts):
                if p != k:
                    fixed0[a, p], fixed1[a, p] = _interval(origins[i], directions[i, subrays[a]],
                                                           parts[p], cs[p], sn[p], table,
                                                           NO_CLIP)
        # The zone's unchanged sub-rays, summed once for the merged reading.
        lo, hi, s1, s2 = np.inf, -np.inf, 0.0, 0.0
        for j in range(m):
            d[j] = depths[i, j]
        for a in range(starts[z], starts[z + 1]):
            d[subrays[a]] = np.inf
        for j in range(m):
            if math.isfinite(d[j]):
                lo, hi = min(lo, d[j]), max(hi, d[j])
                s1 += 1.0 / d[j]
                s2 += 1.0 / (d[j] * d[j])
        for n in range(xs.shape[0]):
            c_lo, c_hi, c1, c2 = lo, hi, s1, s2
            for a in range(starts[z], starts[z + 1]):
                j = subrays[a]
                for p in range(n_parts):
                    t0[p], t1[p] = fixed0[a, p], fixed1[a, p]
                t0[k], t1[k] = _interval(origins[i], directions[i, j], xs[n], xc[n], xsn[n],
                                         table, NO_CLIP)
                d[j] = _visible(t0, t1, solid, base[i, j])
                if merged and math.isfinite(d[j]):
                    c_lo, c_hi = min(c_lo, d[j]), max(c_hi, d[j])
                    c1 += 1.0 / d[j]
                    c2 += 1.0 / (d[j] * d[j])
            if merged and c2 > 0.0 and c_hi - c_lo < merge_m:
                predicted = c1 / c2
            elif merged and c2 == 0.0:
                predicted = np.nan
            else:
                predicted = _reading(d, min_count, gap_m, slope, merge_m, strongest,
                                     merged_mode, work)
            out[n, z] = _loss(measured[i], sigma[i], predicted, scale, no_return)
    return out
