"""Characterising the ToF sensor's noise from recordings of a flat target: per-zone spread
over a static recording, and the fit of the simulator's model sigma = max(sigma0, k d).

Numbers only, no files: `experiments.sensor_recording` loads the recordings and writes the fit.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np

from lrnbv_drake.core.sensor import VALID_STATUSES


@dc.dataclass(frozen=True)
class ZoneNoise:
    """Per-zone statistics of one static recording, for the zones that qualify.

    Attributes:
        mean_mm: mean valid distance of each zone.
        std_mm: standard deviation over frames (ddof 1).
        reported_sigma_mm: mean of the device's own sigma estimate.
        frames: valid frames per zone.
    """

    mean_mm: np.ndarray
    std_mm: np.ndarray
    reported_sigma_mm: np.ndarray
    frames: np.ndarray


def zone_noise(recording: dict[str, np.ndarray], min_frames: int = 10,
               min_valid_fraction: float = 0.9) -> ZoneNoise:
    """Mean and spread of each zone over the frames of a recording of a static scene.

    A zone qualifies with at least `min_frames` valid frames and `min_valid_fraction` of all
    frames valid (a zone that flickers between surfaces or in and out of range measures
    something other than noise).
    """
    d = recording["distance_mm"].astype(np.float64)
    valid = np.isin(recording["status"], VALID_STATUSES) & (d > 0)
    n = valid.sum(axis=0)
    usable = (n >= min_frames) & (n >= min_valid_fraction * d.shape[0])
    count = np.maximum(n, 1)
    mean = np.where(valid, d, 0.0).sum(axis=0) / count
    var = np.where(valid, (d - mean) ** 2, 0.0).sum(axis=0) / np.maximum(n - 1, 1)
    sigma = np.where(valid, recording["sigma_mm"], 0.0).sum(axis=0) / count
    return ZoneNoise(mean[usable], np.sqrt(var[usable]), sigma[usable], n[usable])


def on_target(noise: ZoneNoise, target_mm: float) -> ZoneNoise:
    """The zones whose mean lies within max(50 mm, 10 %) of a known target distance: the
    others see the floor or the surroundings, not the flat target."""
    keep = np.abs(noise.mean_mm - target_mm) <= max(50.0, 0.1 * target_mm)
    return ZoneNoise(*(getattr(noise, f.name)[keep] for f in dc.fields(noise)))


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
