"""Calibrating the sensor model from recordings a user can make on the real cell
(docs/sensor-calibration.md):

- noise: per-zone spread over static recordings of a flat board at several distances and the
  zones' fixed offsets from its plane, and the fit of the model's sigma = max(sigma0, k d);
- zone directions: a small target stepped across the field of view, each zone's centre the
  middle of the directions at which it reports the target.

The mixed-zone rule's fit is `core.calibration.mixed_zone`.

Numbers only, no files: `experiments.sensor_recording` loads the recordings and writes the fit.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
import scipy.sparse.csgraph
import scipy.spatial

from lrnbv_drake.core.sensing.sensor import (
    STATUS_VALID,
    VALID_STATUSES,
)
from lrnbv_drake.core.sensing.tof_device import (
    STATUS_MERGED,
    STATUS_NEW_TARGET,
    STATUS_NO_WRAP_CHECK,
)


@dc.dataclass(frozen=True)
class ZoneNoise:
    """Per-zone statistics of one static recording, for the zones that qualify.

    Attributes:
        mean_mm: mean valid distance of each zone.
        std_mm: standard deviation over frames (ddof 1).
        reported_sigma_mm: mean of the device's own sigma estimate.
        frames: valid frames per zone.
        grid: (n, 2) each zone's row and column in the recording's grid.
    """

    mean_mm: np.ndarray
    std_mm: np.ndarray
    reported_sigma_mm: np.ndarray
    frames: np.ndarray
    grid: np.ndarray


def zone_noise(recording: dict[str, np.ndarray], min_frames: int = 10,
               min_valid_fraction: float = 0.9) -> ZoneNoise:
    """Mean and spread of each zone over the frames of a recording of a static scene.

    A zone qualifies with at least `min_frames` valid frames and `min_valid_fraction` of all
    frames valid (a zone that flickers between surfaces or in and out of range measures
    something other than noise).
    """
    if min_frames < 2:
        raise ValueError(f"min_frames must be at least 2 (one frame has no spread), got "
                         f"{min_frames}")
    d = recording["distance_mm"].astype(np.float64)
    valid = np.isin(recording["status"], VALID_STATUSES) & (d > 0)
    n = valid.sum(axis=0)
    usable = (n >= min_frames) & (n >= min_valid_fraction * d.shape[0])
    count = np.maximum(n, 1)
    mean = np.where(valid, d, 0.0).sum(axis=0) / count
    var = np.where(valid, (d - mean) ** 2, 0.0).sum(axis=0) / np.maximum(n - 1, 1)
    sigma = np.where(valid, recording["sigma_mm"], 0.0).sum(axis=0) / count
    return ZoneNoise(mean[usable], np.sqrt(var[usable]), sigma[usable], n[usable],
                     np.argwhere(usable))


def on_target(noise: ZoneNoise, target_mm: float) -> ZoneNoise:
    """The zones whose mean lies within max(50 mm, 10 %) of a known target distance: the
    others see the floor or the surroundings, not the flat target."""
    keep = np.abs(noise.mean_mm - target_mm) <= max(50.0, 0.1 * target_mm)
    return ZoneNoise(*(getattr(noise, f.name)[keep] for f in dc.fields(noise)))


#: Fewest zones on a flat board that tell its plane (three numbers) from their offsets.
MIN_PLANE_ZONES = 6


def zone_errors_mm(noise: ZoneNoise) -> np.ndarray:
    """Each zone's error about a flat board: its spread over the frames and the zones' fixed
    offsets, the rms of their means' residuals from the plane fitted to them (linear in the
    zones' rows and columns, as a flat board's depth is for small tilts). A real device
    carries a fixed offset per zone, 3 mm rms against 0.7 mm of spread at 0.3 m (notes 9);
    the estimator sees one frame a pose, so to it the offset is noise as much as the spread
    is. The plane's three numbers and the means' own spread are taken out of the residuals'
    variance.

    Raises:
        ValueError: between one and `MIN_PLANE_ZONES` zones, which cannot tell the offsets
            from the plane (none give none).
    """
    n = noise.mean_mm.size
    if 0 < n < MIN_PLANE_ZONES:
        raise ValueError(f"a flat-board recording needs at least {MIN_PLANE_ZONES} zones on "
                         f"the board to tell their fixed offsets from its plane; got {n}")
    if n == 0:
        return np.zeros(0)
    a = np.c_[noise.grid, np.ones(n)]
    residual = noise.mean_mm - a @ np.linalg.lstsq(a, noise.mean_mm, rcond=None)[0]
    offset_var = np.mean(residual ** 2) * n / (n - 3) - np.mean(noise.std_mm ** 2 / noise.frames)
    return np.sqrt(noise.std_mm ** 2 + max(offset_var, 0.0))


@dc.dataclass(frozen=True)
class NoiseFit:
    """Least-squares fit of sigma = max(sigma0, k d) to per-zone (distance, std) points.

    Attributes:
        sigma0_mm, k: the fitted model.
        rms_mm: root-mean-square residual of the zone stds.
        n_points: zones used.
        distance_range_mm: nearest and farthest zone distance.
        warning: set when the data do not pin both parameters down.
    """

    sigma0_mm: float
    k: float
    rms_mm: float
    n_points: int
    distance_range_mm: tuple[float, float]
    warning: str = ""

    @property
    def knee_mm(self) -> float:
        """Distance where k d overtakes sigma0."""
        return self.sigma0_mm / self.k if self.k > 0 else np.inf


def fit_noise_model(distance_mm: np.ndarray, std_mm: np.ndarray) -> NoiseFit:
    """Exact least-squares fit of std = max(sigma0, k d) with sigma0, k >= 0.

    The model is flat below the knee d* = sigma0 / k and linear above, so every candidate
    optimum is one of: a split of the points sorted by distance into a flat and a linear part
    (mean and a line through the origin) that is self-consistent; the knee on a data point
    (sigma0 = k b, a one-parameter fit of k max(b, d)); or a bound (all flat with k = 0, all
    linear with sigma0 = 0). Evaluating them all and keeping the best gives the global optimum
    without a start point or an iterative solver.

    Raises:
        ValueError: fewer than two distinct distances, which cannot separate the two pieces.
    """
    order = np.argsort(distance_mm)
    d = np.asarray(distance_mm, np.float64)[order]
    s = np.asarray(std_mm, np.float64)[order]
    if d.size == 0 or np.unique(d).size < 2:
        raise ValueError("the noise fit needs zones at two or more distinct distances: record "
                         "a flat target at several distances (e.g. 150 to 1000 mm)")

    candidates = [(float(s.mean()), 0.0), (0.0, float(d @ s / (d @ d)))]
    for b in np.unique(d):
        m = np.maximum(b, d)
        k = float(m @ s / (m @ m))
        candidates.append((k * b, k))
    for j in range(1, d.size):
        if d[j - 1] == d[j]:
            continue
        sigma0 = float(s[:j].mean())
        k = float(d[j:] @ s[j:] / (d[j:] @ d[j:]))
        if k >= 0 and k * d[j - 1] <= sigma0 <= k * d[j]:
            candidates.append((sigma0, k))

    def cost(c: tuple[float, float]) -> float:
        return float(np.sum((np.maximum(c[0], c[1] * d) - s) ** 2))

    sigma0, k = min((c for c in candidates if c[0] >= 0 and c[1] >= 0), key=cost)
    d_range = (float(d[0]), float(d[-1]))
    fit = NoiseFit(sigma0, k, float(np.sqrt(cost((sigma0, k)) / d.size)), int(d.size), d_range)
    if not d_range[0] < fit.knee_mm < d_range[1]:
        fit = dc.replace(fit, warning=(
            f"the distances ({d_range[0]:.0f} to {d_range[1]:.0f} mm) do not straddle the "
            f"fitted knee ({fit.knee_mm:.0f} mm), so one parameter is only bounded: record "
            f"nearer and farther targets"))
    return fit


# --- Zone directions from a small target stepped across the field of view --------------------

#: Statuses that carry a range of the zone's own target (UM3109 Table 4): valid, valid on the
#: first frame (no wrap-around check yet), merged, valid on a newly acquired target. 12 (a
#: neighbour's target through the sharpener) and 13 (inconsistent) do not.
RANGING_STATUSES: tuple[int, ...] = (STATUS_VALID, STATUS_NO_WRAP_CHECK, STATUS_MERGED,
                                     STATUS_NEW_TARGET)
#: Golden ratio's fractional part: the row-to-row shift of the target raster, as a share of
#: the step, so that any few consecutive rows sample an axis at well-spread phases.
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def target_raster(step_deg: float, span_deg: float) -> np.ndarray:
    """(n, 2) target directions (x_deg, y_deg) for the zone-direction recording: a square
    grid of `step_deg` over +-`span_deg`, each row shifted in x and each column in y by a
    golden-ratio share of the step. A zone's footprint edges then fall between directions a
    small fraction of the step apart across the rows it spans, so its centre is found to far
    better than the step (`fit_zone_directions`) without a finer grid."""
    if step_deg <= 0 or span_deg <= 0:
        raise ValueError(f"target_raster needs step_deg > 0 and span_deg > 0; got {step_deg}, "
                         f"{span_deg}")
    grid = np.arange(-span_deg, span_deg + 1e-9, step_deg)
    i, j = np.meshgrid(np.arange(grid.size), np.arange(grid.size), indexing="xy")
    x = grid[i] + (j * _GOLDEN % 1.0) * step_deg
    y = grid[j] + (i * _GOLDEN % 1.0) * step_deg
    return np.stack([x.ravel(), y.ravel()], axis=-1)


def target_hits(distance_mm: np.ndarray, status: np.ndarray, target_mm: np.ndarray
                ) -> np.ndarray:
    """(n, res, res) whether each zone reports the target in each frame: a ranging status at
    a depth within max(25 mm, 10 %) of its known distance (anything else in range, e.g. a
    background, reports another depth)."""
    target = np.asarray(target_mm, float)[:, None, None]
    return (np.isin(status, RANGING_STATUSES) & (distance_mm > 0)
            & (np.abs(distance_mm - target) <= np.maximum(25.0, 0.1 * target)))


@dc.dataclass(frozen=True)
class ZoneDirectionFit:
    """Zone centre directions measured with a small target.

    Attributes:
        centres_deg: (res * res * 2,) (x_deg, y_deg) per zone, row-major
            (`ZoneGeometry.centres_deg`).
        hits: (res, res) frames in which each zone reported the target.
        stray: (res, res) of those, the ones left out: apart from the zone's footprint
            (`_footprint_hits`).
    """

    centres_deg: np.ndarray
    hits: np.ndarray
    stray: np.ndarray


def _footprint_hits(target: np.ndarray, hit: np.ndarray, link: float) -> np.ndarray:
    """`hit` without the sightings apart from the zone's footprint: the largest group of its
    hit directions, each within `link` of another. A zone sees the target over one connected
    patch of the raster; one reading at the target's depth from elsewhere (another object at
    that range, a multipath return) would otherwise move an edge of the footprint, and the
    centre with it, by several degrees without a word."""
    index = np.flatnonzero(hit)
    pairs = np.array(sorted(scipy.spatial.cKDTree(target[index]).query_pairs(link)),
                     dtype=int).reshape(-1, 2)
    graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                    shape=(len(index), len(index)))
    _, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
    keep = np.zeros_like(hit)
    keep[index[labels == np.argmax(np.bincount(labels))]] = True
    return keep


def _footprint_middle(along: np.ndarray, across: np.ndarray, hit: np.ndarray, axis: str,
                      zone: tuple[int, int]) -> float:
    """Middle of a zone's footprint along one axis: each of its two edges lies between the
    outermost target direction the zone saw and the nearest beyond it that it missed, among
    the directions well inside the footprint across (strictly between the outermost hits)."""
    seen = across[hit]
    band = (across > seen.min()) & (across < seen.max())
    if not np.any(band & hit):
        band = (across >= seen.min()) & (across <= seen.max())
    lo, hi = along[hit & band].min(), along[hit & band].max()
    below, above = along[band & ~hit & (along < lo)], along[band & ~hit & (along > hi)]
    if below.size == 0 or above.size == 0:
        side = "-" if below.size == 0 else "+"
        raise ValueError(f"zone {zone} saw the target up to the end of the recorded directions "
                         f"on the {side}{axis} side: step the target further out")
    return ((lo + below.max()) / 2 + (hi + above.min()) / 2) / 2


def fit_zone_directions(hits: np.ndarray, target_deg: np.ndarray) -> ZoneDirectionFit:
    """Each zone's centre direction from the directions at which it reported a small target.

    A zone reports the target wherever the target overlaps its footprint, a square around its
    centre; the middle of that region along x and along y is the centre whatever the
    footprint's and the target's size (`_footprint_middle`). Sightings apart from that
    region (`_footprint_hits`, linked within 1.5 raster steps) are left out and counted.

    Args:
        hits: (n, res, res) row-major, from `target_hits`.
        target_deg: (n, 2) the target's direction (x_deg, y_deg) in each frame.

    Raises:
        ValueError: a zone that never saw the target, or saw it at the edge of the recording.
    """
    hits = np.asarray(hits, bool)
    target = np.asarray(target_deg, float)
    if target.shape != (hits.shape[0], 2):
        raise ValueError(f"target_deg has shape {target.shape}; expected {(hits.shape[0], 2)}")
    res = hits.shape[1]
    centres = np.empty((res, res, 2))
    stray = np.zeros((res, res), int)
    # The raster's step: the median distance from a direction to its nearest other one.
    step = float(np.median(scipy.spatial.cKDTree(target).query(target, k=2)[0][:, 1])) \
        if len(target) > 1 else 0.0
    for r in range(res):
        for c in range(res):
            seen = hits[:, r, c]
            if not seen.any():
                raise ValueError(f"zone {(r, c)} (row-major) never reported the target: step "
                                 f"it over the whole field of view")
            hit = _footprint_hits(target, seen, 1.5 * step)
            stray[r, c] = int(seen.sum() - hit.sum())
            centres[r, c, 0] = _footprint_middle(target[:, 0], target[:, 1], hit, "x", (r, c))
            centres[r, c, 1] = _footprint_middle(target[:, 1], target[:, 0], hit, "y", (r, c))
    return ZoneDirectionFit(centres.reshape(-1), hits.sum(axis=0), stray)
