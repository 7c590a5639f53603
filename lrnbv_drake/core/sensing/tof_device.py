"""The simulated VL53L8CX as ST documents it: targets by signal, merged returns, sharpener
bleed, a non-uniform zone layout, the datasheet's accuracy, start-up statuses.

The `ideal` profile is the reduction in `core.sensing.sensor` (nearest surface cluster holding a
share of the zone, Gaussian noise, status 5): it stays the default and `device_readings` hands
it to `zone_readings` unchanged, so its frames are bit for bit what they were. The `datasheet`
profile follows ../shared/notes/vl53l8cx-behaviour.md (sections cited as "notes 2" etc.;
docs/sensor-model.md, section 8, says which value comes from where):

- every sample of a zone's footprint returns a signal rho * w / d^2 (reflectance, illumination
  fall-off, perpendicular depth in m); the zone's *signal* of a surface is the sum over its
  samples divided by the zone's own sample count, so a zone filled by one surface at d reads
  rho / d^2 (notes 1: the datasheet's maximum ranges make a 17 % target at 2.45 m the dark
  detection limit, 0.0283; at 5 klux 1.15 m, 0.129);
- samples group into surfaces by the same depth-gap rule as the ideal model; surfaces closer
  than `merge_mm` (ST: 600 mm) merge into one target, status 9, at a depth `merged_depth`
  chooses (nobody publishes where it lies, notes 2);
- one target per zone is reported, the nearest or the strongest (`target_order`, notes 2:
  ST's default is strongest);
- the sharpener lets a share `sharpener_bleed` of each 4-neighbour's samples into a zone;
  where they carry most of the reported target's signal the status is 12 (notes 2);
- noise follows the datasheet's accuracy (+-% of distance at 2.7 sigma by reflectance and
  ambient light, corners up to 4 points worse; notes 1), and the reported sigma misses the
  true one by a log-normal factor (notes 1: it "does not track" the spread);
- the first frame after ranging starts has status 6, a zone that just acquired a target 10.

Zone directions and integration over the frame period need the renderer and are applied where
the samples are made (`ZoneGeometry.centres_deg`, `systems/tof_sensor.py`).
"""

from __future__ import annotations

import dataclasses as dc
import math

import numba
import numpy as np

from lrnbv_drake.core.sensing.sensor import (
    STATUS_NO_TARGET,
    STATUS_VALID,
    SensorModelParams,
    ToFFrame,
    cluster_rule,
    zone_readings,
)

#: Statuses the datasheet device reports besides 5 and 255 (UM3109 Table 4).
STATUS_NO_WRAP_CHECK = 6
STATUS_MERGED = 9
STATUS_NEW_TARGET = 10
STATUS_BLURRED = 12

TARGET_ORDERS = ("closest", "strongest")
MERGED_DEPTHS = ("signal", "nearest", "farthest")
ACCURACY_LAWS = ("model", "datasheet")

#: Detection limit (zone signal rho / d^2, d in m) in the dark and at 5 klux: a 17 % target
#: filling the zone at the datasheet's maximum range (8x8 continuous, inner zones).
SIGNAL_LIMIT_DARK = 0.17 / 2.45**2
SIGNAL_LIMIT_5KLUX = 0.17 / 1.15**2
#: Datasheet accuracy, +-% of distance at 2.7 sigma, 8x8 continuous, 200-4000 mm, for
#: reflectances 17, 54 and 88 %, in the dark and at 5 klux (DS14161 Table 20).
_REFLECTANCES = np.array([0.17, 0.54, 0.88])
_ACCURACY_PCT_DARK = np.array([5.0, 5.0, 5.0])
_ACCURACY_PCT_5KLUX = np.array([8.0, 6.0, 5.0])
#: The same below 200 mm, in mm (the floor of the law).
_ACCURACY_MM_DARK = np.array([12.0, 12.0, 11.0])
_ACCURACY_MM_5KLUX = np.array([14.0, 13.0, 10.0])
#: Corner zones "may degrade by up to 4 %" against the centre four.
_CORNER_PCT = 4.0
_SIGMAS_PER_ACCURACY = 2.7


@dc.dataclass(frozen=True)
class DeviceBehaviour:
    """The datasheet knobs of the simulated device; the defaults are the ideal device.

    Args:
        target_order: "closest" or "strongest": which target a zone reports.
        merge_mm: surfaces closer than this in depth merge into one target (status 9);
            0 with the closest order keeps the ideal rule (the nearest surface holding
            `min_share`).
        merged_depth: where a merged target lies: "signal" (the signal-weighted mean depth),
            "nearest" or "farthest" of its surfaces.
        sharpener_bleed: share of each 4-neighbour zone's samples seen in a zone.
        illumination: weight samples by the emitter's fall-off (`illumination_weight`).
        accuracy: "model" (the sensor model's sigma law) or "datasheet" (`datasheet_sigma_mm`).
        ambient_klux: ambient light, klux (raises the detection limit and the noise).
        reported_sigma_spread: log-normal spread of the reported sigma around the true one.
        startup_statuses: status 6 on the first frame, 10 where a target was just acquired.
        reflectance: weigh each sample's signal by its surface's reflectance (the scene's
            `object.reflectance`, `cell.table_reflectance`); else every surface reflects
            alike, as the sensor model assumes.
        zone_offset_mm: rms of a fixed range offset per zone, the same in every frame (real
            frames: 3 mm at 0.3 m, notes 9), drawn from `zone_offset_seed`: one device unit.
    """

    target_order: str = "closest"
    merge_mm: float = 0.0
    merged_depth: str = "signal"
    sharpener_bleed: float = 0.0
    illumination: bool = False
    accuracy: str = "model"
    ambient_klux: float = 0.0
    reported_sigma_spread: float = 0.0
    startup_statuses: bool = False
    reflectance: bool = False
    zone_offset_mm: float = 0.0
    zone_offset_seed: int = 0

    def __post_init__(self) -> None:
        for name, allowed in (("target_order", TARGET_ORDERS), ("merged_depth", MERGED_DEPTHS),
                              ("accuracy", ACCURACY_LAWS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"DeviceBehaviour.{name} must be one of {allowed}; got "
                                 f"{getattr(self, name)!r}")
        for name in ("merge_mm", "sharpener_bleed", "ambient_klux", "reported_sigma_spread",
                     "zone_offset_mm", "zone_offset_seed"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"DeviceBehaviour.{name} must be >= 0; got "
                                 f"{getattr(self, name)}")
        if self.sharpener_bleed > 1:
            raise ValueError(f"DeviceBehaviour.sharpener_bleed must be <= 1; got "
                             f"{self.sharpener_bleed}")

    @property
    def ideal(self) -> bool:
        """Whether this is the ideal device (`core.sensing.sensor.zone_readings` reproduces it)."""
        return self == DeviceBehaviour()

    def signal_limit(self) -> float:
        """Weakest zone signal (rho / d^2) detected at this ambient light."""
        share = min(self.ambient_klux / 5.0, 1.0)
        return SIGNAL_LIMIT_DARK + share * (SIGNAL_LIMIT_5KLUX - SIGNAL_LIMIT_DARK)


@dc.dataclass(frozen=True)
class DeviceProfile:
    """A simulated device: its reduction and the two knobs that act where samples are made.

    Args:
        behaviour: the reduction's knobs; None: the sensor model's.
        zone_directions: "uniform", "st" (`st_zone_centres_deg`) or a CSV file; None: the
            sensor model's.
        integration_steps: renders a frame integrates over its period.
    """

    behaviour: DeviceBehaviour | None = None
    zone_directions: str | None = None
    integration_steps: int = 1


#: The profiles: the ideal device (the sensor model itself), the nearest-surface rule the model
#: assumed before real frames showed merging, and ST's defaults and documented behaviour,
#: where the bleed, the merged depth and the sigma spread are our guesses (no public figure;
#: docs/sensor-model.md, 8).
PROFILES = {
    "ideal": DeviceProfile(),
    "nearest": DeviceProfile(DeviceBehaviour()),
    "datasheet": DeviceProfile(
        DeviceBehaviour(target_order="strongest", merge_mm=600.0, merged_depth="signal",
                        sharpener_bleed=0.02, illumination=True, accuracy="datasheet",
                        reported_sigma_spread=0.5, startup_statuses=True, reflectance=True),
        zone_directions="st", integration_steps=3),
}


def st_zone_centres_deg(resolution: int = 8) -> np.ndarray:
    """(res * res * 2,) zone centres shaped like ST's per-zone table (notes 3): columns at
    3.0, 9.0, 14.8 and 19.8 deg either side on the middle rows, spreading outwards with the
    row's own angle to 23.0 deg at the corners (the table is not separable in x and y). Only
    8x8 has such a table; other resolutions get the uniform grid's centres."""
    if resolution != 8:
        half = 22.5 * (1 - 1 / resolution)
        base = np.linspace(-half, half, resolution)
    else:
        middle = np.array([3.0, 9.0, 14.8, 19.8])
        base = np.concatenate([-middle[::-1], middle])
    spread = 23.0 / base.max() - 1.0
    u = (base / base.max()) ** 2 if resolution == 8 else np.zeros(resolution)
    ax = base[None, :] * (1 + spread * u[:, None])  # [row, column]
    ay = base[:, None] * (1 + spread * u[None, :])
    return np.stack([ax, ay], axis=-1).reshape(-1)


def illumination_weight(angle_x_rad: np.ndarray, angle_y_rad: np.ndarray) -> np.ndarray:
    """Relative emitter power towards (angle_x, angle_y): exp(-(|a| / a0)^p) per axis, with
    a0 = 25.8 deg and p = 7.2 fitted to DS14161 2.3 (75 % of the peak at 21.7 deg, 10 % at
    29.0 deg, each side of a 43.4 and 57.9 deg field of illumination)."""
    a0, p = math.radians(25.8), 7.2
    return (np.exp(-(np.abs(angle_x_rad) / a0) ** p)
            * np.exp(-(np.abs(angle_y_rad) / a0) ** p))


def datasheet_sigma_mm(distance_mm: np.ndarray, reflectance: np.ndarray, ambient_klux: float,
                       corner: np.ndarray) -> np.ndarray:
    """1-sigma range noise from the datasheet's accuracy (notes 1): the +-% of distance (or
    the +-mm below 200 mm, whichever is larger), interpolated in reflectance and ambient light,
    plus up to 4 points at the corners (`corner` 0 at the centre four zones, 1 at a corner),
    divided by 2.7 (the datasheet's accuracy is 2.7 sigma)."""
    share = min(ambient_klux / 5.0, 1.0)
    rho = np.clip(reflectance, _REFLECTANCES[0], _REFLECTANCES[-1])
    pct = (np.interp(rho, _REFLECTANCES, _ACCURACY_PCT_DARK) * (1 - share)
           + np.interp(rho, _REFLECTANCES, _ACCURACY_PCT_5KLUX) * share) + _CORNER_PCT * corner
    floor = (np.interp(rho, _REFLECTANCES, _ACCURACY_MM_DARK) * (1 - share)
             + np.interp(rho, _REFLECTANCES, _ACCURACY_MM_5KLUX) * share)
    return np.maximum(floor, pct / 100.0 * np.asarray(distance_mm, float)) / _SIGMAS_PER_ACCURACY


def corner_share(resolution: int) -> np.ndarray:
    """(res, res) 0 at the centre four zones rising to 1 at the corners, by zone-centre
    distance from the centre four."""
    c = np.abs(np.arange(resolution) - (resolution - 1) / 2) - 0.5
    r = np.hypot(c[:, None], c[None, :])
    return r / r.max() if r.max() > 0 else r


def _with_neighbours(a: np.ndarray, fill: float) -> np.ndarray:
    """(res * res, 5 m): each zone's m samples of `a` (res, res, m), then those of its
    neighbours above, below, left and right (`fill` where it has no such neighbour)."""
    res, _, m = a.shape
    padded = np.full((res + 2, res + 2, m), fill)
    padded[1:-1, 1:-1] = a
    parts = [a] + [padded[1 + dr:res + 1 + dr, 1 + dc_:res + 1 + dc_]
                   for dr, dc_ in ((-1, 0), (1, 0), (0, -1), (0, 1))]
    return np.concatenate(parts, axis=-1).reshape(res * res, -1)


def bleed_samples(depth: np.ndarray, signal: np.ndarray, reflectance: np.ndarray,
                  bleed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each zone's samples followed by its 4-neighbours' at `bleed` times their signal.

    Args:
        depth, signal, reflectance: (res, res, m) per-zone samples (depth inf where nothing
            returns).

    Returns:
        (depth, signal, reflectance, foreign), each (res * res, 5 m), row-major zones: the
        zone's own m samples, then those of the neighbours above, below, left and right (zero
        signal where the zone has no such neighbour), `foreign` marking the neighbours'.
    """
    m = depth.shape[-1]
    foreign = np.zeros((depth.shape[0] ** 2, 5 * m), bool)
    foreign[:, m:] = True
    s = _with_neighbours(signal, 0.0)
    return (_with_neighbours(depth, np.inf), np.where(foreign, bleed * s, s),
            _with_neighbours(reflectance, 0.0), foreign)


# Not cached on disk, nor `_targets_kernel`: loaded from numba's cache beside the cached
# `sensor` kernels, they crashed the process (SIGSEGV; tests/test_numba_cache.py). Compiling
# them costs 1.5 s once per process that uses the datasheet device or a merging model.
@numba.njit
def sorted_target(depth, signal, reflectance, foreign, own_count, gap_m, slope, merge_m,
                  strongest, merged_mode, signal_limit, min_count, out):
    """One zone, its samples sorted by depth (inf, where nothing returns, last): groups them
    into surfaces by the depth-gap rule and surfaces into targets within `merge_m`, and
    writes the reported target's depth (m), status, signal-weighted reflectance and zone
    signal into `out` (depth NaN where no target is detected). With the closest order and no
    merging, a surface of fewer than `min_count` samples is not a target (the ideal rule's
    share, `cluster_rule`). The box fit predicts a merging device's zones with it too."""
    m = depth.shape[0]
    best_depth, best_status, best_rho, best_signal = np.nan, 255, 0.0, -1.0
    i = 0
    # the target being built: its signal sums and its surfaces' extreme centroids
    t_s, t_sd, t_srho, t_sf = 0.0, 0.0, 0.0, 0.0
    t_surfaces, t_near, t_far, t_last, t_n = 0, 0.0, 0.0, 0.0, 0
    centroid = 0.0
    share_rule = merge_m <= 0.0 and not strongest
    while True:
        # next surface, or flush at the end
        s_s, s_sd, s_srho, s_sf, s_n = 0.0, 0.0, 0.0, 0.0, 0
        at_end = i >= m or not math.isfinite(depth[i])
        if not at_end:
            j = i
            while True:
                s_s += signal[j]
                s_sd += signal[j] * depth[j]
                s_srho += signal[j] * reflectance[j]
                if foreign[j]:
                    s_sf += signal[j]
                s_n += 1
                j += 1
                if j >= m or not math.isfinite(depth[j]):
                    break
                if depth[j] - depth[j - 1] > max(gap_m, slope * depth[j - 1]):
                    break
            i = j
            if s_s <= 0.0:
                continue
            centroid = s_sd / s_s
            if t_surfaces > 0 and centroid - t_last < merge_m:
                t_s += s_s
                t_sd += s_sd
                t_srho += s_srho
                t_sf += s_sf
                t_n += s_n
                t_surfaces += 1
                t_far = centroid
                t_last = centroid
                continue
        if t_surfaces > 0:  # close the target being built
            zone_signal = t_s / own_count
            if zone_signal >= signal_limit and not (share_rule and t_n < min_count):
                better = (best_signal < 0.0) or (strongest and zone_signal > best_signal)
                if better:
                    if merged_mode == 0:
                        best_depth = t_sd / t_s
                    elif merged_mode == 1:
                        best_depth = t_near
                    else:
                        best_depth = t_far
                    if t_sf > 0.5 * t_s:
                        best_status = 12
                    elif t_surfaces > 1:
                        best_status = 9
                    else:
                        best_status = 5
                    best_rho = t_srho / t_s
                    best_signal = zone_signal
        if at_end:
            break
        t_s, t_sd, t_srho, t_sf = s_s, s_sd, s_srho, s_sf
        t_surfaces, t_near, t_far, t_last, t_n = 1, centroid, centroid, centroid, s_n
    out[0] = best_depth
    out[1] = best_status
    out[2] = best_rho
    out[3] = best_signal


@numba.njit
def _targets_kernel(depth, signal, reflectance, foreign, own_count, gap_m, slope, merge_m,
                    strongest, merged_mode, signal_limit, min_count, out):
    m = depth.shape[1]
    d, s, r, f = np.empty(m), np.empty(m), np.empty(m), np.empty(m, np.bool_)
    for z in range(depth.shape[0]):
        order = np.argsort(depth[z])
        for j in range(m):
            k = order[j]
            d[j], s[j], r[j], f[j] = depth[z, k], signal[z, k], reflectance[z, k], foreign[z, k]
        sorted_target(d, s, r, f, own_count, gap_m, slope, merge_m, strongest, merged_mode,
                      signal_limit, min_count, out[z])


def zone_targets(depth_m: np.ndarray, signal: np.ndarray, reflectance: np.ndarray,
                 foreign: np.ndarray, own_count: int, params: SensorModelParams,
                 behaviour: DeviceBehaviour) -> np.ndarray:
    """The target each zone reports, noise-free.

    Args:
        depth_m, signal, reflectance, foreign: (n, m) per-zone samples (depth inf where
            nothing returns), e.g. from `bleed_samples`.
        own_count: the zone's own samples, the signal's normaliser.
        params: the depth-gap rule that splits surfaces (`cluster_rule`).
        behaviour: order, merge distance and depth, detection limit.

    Returns:
        (n, 4): depth (m, NaN where nothing is detected), status, reflectance, zone signal.
    """
    min_count, gap_m, slope = cluster_rule(params, own_count)
    depth = np.ascontiguousarray(np.where(np.asarray(signal) > 0, depth_m, np.inf), float)
    out = np.empty((depth.shape[0], 4))
    _targets_kernel(depth, np.ascontiguousarray(signal, float),
                    np.ascontiguousarray(reflectance, float),
                    np.ascontiguousarray(foreign, bool), own_count, gap_m, slope,
                    behaviour.merge_mm / 1000.0, behaviour.target_order == "strongest",
                    MERGED_DEPTHS.index(behaviour.merged_depth), behaviour.signal_limit(),
                    min_count, out)
    return out


def zone_offsets_mm(behaviour: DeviceBehaviour, resolution: int) -> np.ndarray:
    """(res, res) the device unit's fixed range offset of each zone, row-major, mm."""
    rng = np.random.default_rng(behaviour.zone_offset_seed)
    return behaviour.zone_offset_mm * rng.standard_normal((resolution, resolution))


def device_readings(sub_depth_m: np.ndarray, params: SensorModelParams,
                    behaviour: DeviceBehaviour, rng: np.random.Generator, *,
                    reflectance: np.ndarray | None = None, weight: np.ndarray | None = None,
                    previous: ToFFrame | None = None, sequence: int = 0,
                    timestamp_us: int = 0) -> ToFFrame:
    """The frame the device reports for a scene sampled over each zone's footprint.

    Args:
        sub_depth_m: (res, res, m) or (res, res, k, k) perpendicular depths, metres, row-major
            zones; inf, NaN or <= 0 where nothing returns. m may exceed k * k: several renders
            over the frame period, concatenated.
        params: the sensor model the device starts from (geometry, gap rule, range, noise).
        behaviour: the datasheet knobs; the ideal device goes to `zone_readings` unchanged.
        rng: noise source (`frame_rng`).
        reflectance: like `sub_depth_m`, each sample's reflectance (0.5 if not given).
        weight: like `sub_depth_m`, each sample's illumination weight (1 if not given).
        previous: the frame before this one (None for the first after ranging starts).
        sequence, timestamp_us: to stamp.
    """
    if behaviour.ideal:
        return zone_readings(sub_depth_m, params, rng, sequence, timestamp_us)
    res = params.geometry.resolution
    depth = np.asarray(sub_depth_m, float).reshape(res, res, -1)
    m = depth.shape[-1]
    rho = (np.full(depth.shape, 0.5) if reflectance is None
           else np.asarray(reflectance, float).reshape(res, res, m))
    w = np.ones(depth.shape) if weight is None else np.asarray(weight, float).reshape(res, res, m)
    with np.errstate(divide="ignore", invalid="ignore"):
        returns = np.isfinite(depth) & (depth > 0)
        signal = np.where(returns, rho * w / np.where(returns, depth, 1.0) ** 2, 0.0)
    depth = np.where(returns, depth, np.inf)
    d, s, r, foreign = bleed_samples(depth, signal, rho, behaviour.sharpener_bleed)
    targets = zone_targets(d, s, r, foreign, m, params, behaviour).reshape(res, res, 4)
    depth_mm = targets[..., 0] * 1000.0
    noise = rng.standard_normal((res, res))
    with np.errstate(invalid="ignore"):
        valid = (depth_mm >= params.min_range_mm) & (depth_mm <= params.max_range_mm)
    depth_mm = np.where(valid, depth_mm, 0.0)
    if behaviour.accuracy == "datasheet":
        sigma = datasheet_sigma_mm(depth_mm, targets[..., 2], behaviour.ambient_klux,
                                   corner_share(res))
    else:
        sigma = params.noise.sigma_mm(depth_mm)
    reading = np.clip(np.rint(depth_mm + zone_offsets_mm(behaviour, res) + sigma * noise), 0,
                      np.iinfo(np.int16).max)
    reported = sigma * np.exp(behaviour.reported_sigma_spread * rng.standard_normal((res, res)))
    status = np.where(valid, targets[..., 1], STATUS_NO_TARGET).astype(np.uint8)
    if behaviour.startup_statuses:
        valid_now = valid & np.isin(status, (STATUS_VALID, STATUS_MERGED))
        if previous is None:
            status[valid_now] = STATUS_NO_WRAP_CHECK
        else:
            before = params.geometry.to_row_major(previous.status) != STATUS_NO_TARGET
            status[valid_now & ~before] = STATUS_NEW_TARGET
    geometry = params.geometry
    return ToFFrame(
        distance_mm=geometry.to_raw(np.where(valid, reading, 0)),
        status=geometry.to_raw(status),
        sigma_mm=geometry.to_raw(np.where(valid, np.rint(reported), 0)),
        sequence=sequence,
        timestamp_us=timestamp_us,
    )
