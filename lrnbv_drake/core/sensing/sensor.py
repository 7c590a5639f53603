"""The VL53L8CX as data: the frame both the simulated and the real sensor produce, and the zone
geometry that turns a frame into points.

No Drake here: the simulated sensor (`systems/tof_sensor.py`) and the serial driver
(`drivers/tof_serial.py`) both fill `ToFFrame`, and everything downstream reads only it.

Conventions (docs/sensor-model.md gives the sources):
- The sensor frame `tof` has z along the optical axis, x right and y down (Drake's camera
  convention).
- A frame's arrays are in the device's *raw* zone order, exactly as the ULD driver returns them.
  `ZoneGeometry` holds the flips that map a real board's raw order to the row-major
  (row = +y, column = +x) order used here; a simulated sensor with default flips emits row-major.
- Distances are perpendicular (z-depth), as the device reports them, not radial.

The second half is the simulated device's reduction: `zone_readings` turns a grid of
perpendicular depths sampled over each zone's footprint into the frame the device would report
(nearest sizeable surface cluster, range noise, status), so the simulator's only Drake-specific
part is producing that grid (`systems/tof_sensor.py` renders it).
"""

from __future__ import annotations

import dataclasses as dc
import math

import numba
import numpy as np

#: Target statuses the device marks as a valid range (UM3109: "5 & 9 means ranging OK").
VALID_STATUSES: tuple[int, ...] = (5, 9)
#: Status of a plainly valid range; the simulated sensor reports it for every valid zone.
STATUS_VALID = 5
#: Status the driver writes when no target is detected in a zone.
STATUS_NO_TARGET = 255
#: Ranging limits of the device, mm (DS14161: 2 to 400 cm per zone).
MIN_RANGE_MM = 20
MAX_RANGE_MM = 4000


@dc.dataclass
class ToFFrame:
    """One VL53L8CX frame, as the device reports it.

    Args:
        distance_mm: (res, res) int16 perpendicular distances in raw zone order. Meaningless
            where `status` is not valid: always gate on the status.
        status: (res, res) uint8 target status (5 and 9 valid, 255 no target).
        sigma_mm: (res, res) uint16 the device's range sigma estimate.
        sequence: frame counter.
        timestamp_us: capture time, microseconds (simulation time in the simulator, the MCU's
            clock on hardware).
    """

    distance_mm: np.ndarray
    status: np.ndarray
    sigma_mm: np.ndarray
    sequence: int = 0
    timestamp_us: int = 0

    def __post_init__(self) -> None:
        self.distance_mm = np.asarray(self.distance_mm, dtype=np.int16)
        self.status = np.asarray(self.status, dtype=np.uint8)
        self.sigma_mm = np.asarray(self.sigma_mm, dtype=np.uint16)
        shape = self.distance_mm.shape
        if len(shape) != 2 or shape[0] != shape[1]:
            raise ValueError(f"ToFFrame.distance_mm must be square (res, res); got {shape}")
        for name in ("status", "sigma_mm"):
            if getattr(self, name).shape != shape:
                raise ValueError(
                    f"ToFFrame.{name} has shape {getattr(self, name).shape}; expected {shape}"
                )

    @property
    def resolution(self) -> int:
        """Zones per side: 8 (or 4)."""
        return self.distance_mm.shape[0]

    @property
    def valid(self) -> np.ndarray:
        """(res, res) bool: zones whose status says the range is valid and nonzero."""
        return np.isin(self.status, VALID_STATUSES) & (self.distance_mm > 0)

    @staticmethod
    def empty(resolution: int = 8, sequence: int = 0, timestamp_us: int = 0) -> ToFFrame:
        """A frame with no target in any zone."""
        shape = (resolution, resolution)
        return ToFFrame(
            distance_mm=np.zeros(shape, np.int16),
            status=np.full(shape, STATUS_NO_TARGET, np.uint8),
            sigma_mm=np.zeros(shape, np.uint16),
            sequence=sequence,
            timestamp_us=timestamp_us,
        )


#: Roll steps about the optical axis, degrees, that map the square grid of zones onto itself
#: (`robot.sensor_roll_step_deg`; 0: no roll), and how they are named in an error.
ROLL_STEPS_DEG = (0.0, 90.0, 180.0)
ROLL_STEPS_TEXT = "0, 90 or 180 (the square grid's symmetries)"


@dc.dataclass
class ZoneGeometry:
    """Uniform zone model: `resolution` x `resolution` zones tiling a square field of view, each
    spanning fov/resolution degrees, with the raw-order flips of a particular board.

    Args:
        resolution: zones per side (8 for 8x8 mode).
        fov_deg: full square field of view, degrees (45 for the VL53L8CX).
        flip_x: raw column index runs towards -x.
        flip_y: raw row index runs towards -y.
        transpose: raw rows are columns.
        centres_deg: zone centre directions where they are not the uniform grid's: res * res
            (angle about y towards +x, angle about x towards +y) pairs, degrees, row-major,
            flattened; each zone still spans `zone_deg` around its centre. None: uniform.
    """

    resolution: int = 8
    fov_deg: float = 45.0
    flip_x: bool = False
    flip_y: bool = False
    transpose: bool = False
    centres_deg: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.centres_deg is not None:
            self.centres_deg = tuple(float(v) for v in np.ravel(self.centres_deg))
            if len(self.centres_deg) != 2 * self.resolution**2:
                raise ValueError(f"ZoneGeometry.centres_deg needs {2 * self.resolution**2} "
                                 f"angles (an (x, y) pair per zone); got "
                                 f"{len(self.centres_deg)}")

    @property
    def zone_deg(self) -> float:
        """Angular width of one zone, degrees (5.625 for 8x8 at 45 degrees)."""
        return self.fov_deg / self.resolution

    def zone_edges_rad(self) -> np.ndarray:
        """(res + 1,) zone boundary angles along either axis, radians, from -fov/2 to +fov/2."""
        half = np.deg2rad(self.fov_deg) / 2
        return np.linspace(-half, half, self.resolution + 1)

    def zone_centres_rad(self) -> np.ndarray:
        """(res,) zone centre angles along either axis, radians."""
        edges = self.zone_edges_rad()
        return (edges[:-1] + edges[1:]) / 2

    def to_row_major(self, raw: np.ndarray) -> np.ndarray:
        """Reorders a (res, res) array from the board's raw zone order to row-major (+y, +x)."""
        out = np.asarray(raw)
        if self.transpose:
            out = out.T
        if self.flip_y:
            out = out[::-1, :]
        if self.flip_x:
            out = out[:, ::-1]
        return out

    def to_raw(self, row_major: np.ndarray) -> np.ndarray:
        """Inverse of `to_row_major`: what the board would report for a row-major array."""
        out = np.asarray(row_major)
        if self.flip_x:
            out = out[:, ::-1]
        if self.flip_y:
            out = out[::-1, :]
        if self.transpose:
            out = out.T
        return out

    def directions(self) -> np.ndarray:
        """(res, res, 3) per-zone (tan ax, tan ay, 1) in row-major order, in the sensor frame.

        Multiplying by a perpendicular distance gives the zone-centre point.
        """
        if self.centres_deg is not None:
            t = np.tan(self.sub_angles_xy_rad(1)[:, :, 0, 0])
            return np.concatenate([t, np.ones((*t.shape[:2], 1))], axis=-1)
        t = np.tan(self.zone_centres_rad())
        tx, ty = np.meshgrid(t, t, indexing="xy")
        return np.stack([tx, ty, np.ones_like(tx)], axis=-1)

    def sub_angles_rad(self, k: int) -> np.ndarray:
        """(res*k,) angles along either axis of k sub-rays per zone, evenly spaced in angle and
        centred in their cells, zone by zone, on the uniform grid (`centres_deg` ignored).
        k = 1 gives the zone centres."""
        edges = self.zone_edges_rad()
        step = (edges[1] - edges[0]) / k
        return (edges[:-1, None] + (np.arange(k) + 0.5) * step).reshape(-1)

    def sub_angles_xy_rad(self, k: int) -> np.ndarray:
        """(res, res, k, k, 2) (angle x, angle y) of k x k sub-rays evenly spaced in angle over
        each zone's footprint, row-major zones, around `centres_deg` where given."""
        res = self.resolution
        if self.centres_deg is None:
            a = self.sub_angles_rad(k).reshape(res, k)
            ax = np.broadcast_to(a[None, :, None, :], (res, res, k, k))
            ay = np.broadcast_to(a[:, None, :, None], (res, res, k, k))
            return np.stack([ax, ay], axis=-1)
        centres = np.deg2rad(np.reshape(self.centres_deg, (res, res, 2)))
        offset = (np.arange(k) + 0.5 - k / 2) * np.deg2rad(self.zone_deg) / k
        ax = centres[:, :, None, None, 0] + offset[None, None, None, :]
        ay = centres[:, :, None, None, 1] + offset[None, None, :, None]
        return np.stack(np.broadcast_arrays(ax, ay), axis=-1)

    def max_angle_rad(self) -> float:
        """Half-width of the square that holds every zone's footprint, radians."""
        if self.centres_deg is None:
            return float(np.deg2rad(self.fov_deg) / 2)
        return float(np.deg2rad(np.max(np.abs(self.centres_deg)) + self.zone_deg / 2))

    def sub_directions(self, k: int) -> np.ndarray:
        """(res, res, k, k, 3) (tan ax, tan ay, 1) of k x k sub-rays evenly spaced in angle over
        each zone's footprint, row-major. k = 1 gives the zone centres."""
        if self.centres_deg is not None:
            t = np.tan(self.sub_angles_xy_rad(k))
            return np.concatenate([t, np.ones((*t.shape[:-1], 1))], axis=-1)
        t = np.tan(self.sub_angles_rad(k))
        tx, ty = np.meshgrid(t, t, indexing="xy")  # (res*k, res*k), [row, col]
        d = np.stack([tx, ty, np.ones_like(tx)], axis=-1)
        res = self.resolution
        return d.reshape(res, k, res, k, 3).transpose(0, 2, 1, 3, 4)

    def points(self, frame: ToFFrame) -> tuple[np.ndarray, np.ndarray]:
        """Converts a frame to zone-centre points in the sensor frame, metres.

        Returns:
            (points, valid): (res*res, 3) points in row-major zone order and the (res*res,) mask
            of zones with a valid range. Points of invalid zones are NaN.
        """
        if frame.resolution != self.resolution:
            raise ValueError(
                f"frame has {frame.resolution}x{frame.resolution} zones; the zone geometry "
                f"expects {self.resolution}x{self.resolution}"
            )
        d = self.to_row_major(frame.distance_mm).astype(np.float64) / 1000.0
        valid = self.to_row_major(frame.valid)
        pts = self.directions() * d[..., None]
        pts[~valid] = np.nan
        return pts.reshape(-1, 3), valid.reshape(-1)


# --- Simulated device ------------------------------------------------------------------------


@dc.dataclass(frozen=True)
class NoiseModel:
    """Range noise of one zone reading, sigma(d) = max(sigma0, k * d).

    The form and the defaults are an assumption (notes 1.5: sigma0 about 5-10 mm, k about
    1-2 %), to be fitted on the real board against a flat target at 0.1-1.0 m.

    Args:
        sigma0_mm: noise floor, mm.
        k: growth with distance (0.015 is 1.5 % of the distance).
    """

    sigma0_mm: float = 5.0
    k: float = 0.015

    def __post_init__(self) -> None:
        if self.sigma0_mm < 0 or self.k < 0:
            raise ValueError(f"NoiseModel needs sigma0_mm >= 0 and k >= 0; got {self}")

    def sigma_mm(self, distance_mm: np.ndarray | float) -> np.ndarray:
        """Standard deviation of a reading at `distance_mm`, mm."""
        return np.maximum(self.sigma0_mm, self.k * np.asarray(distance_mm, dtype=np.float64))


@dc.dataclass
class SensorModelParams:
    """What the simulated sensor reports for a given sampled scene (docs/sensor-model.md).

    Args:
        geometry: zone layout and the raw-order flips of the simulated board.
        subsamples: sub-samples per zone side; k x k samples, evenly spaced in angle, stand in
            for each zone's footprint (8 gives 8x8, about 0.7 degrees apart).
        min_share: smallest share of a zone's samples a surface cluster must hold to be
            reported; a nearer cluster with less is ignored, as a weak sliver would be on the
            device.
        cluster_gap_mm: depth samples (sorted) closer than this to the next one belong to the
            same surface cluster. 25 mm: a box or step taller than that stands out from the
            surface behind it, while a surface seen obliquely stays one cluster.
        max_incidence_deg: widens the gap with depth so that a plane seen up to this angle from
            its normal stays one cluster at any range (neighbouring samples on it differ by
            about d * tan(incidence) * sample pitch, which outgrows a fixed gap beyond ~0.7 m).
        min_range_mm: nearest valid reading (DS14161: 2 cm).
        max_range_mm: farthest valid reading (DS14161: 400 cm).
        noise: range noise model.
    """

    geometry: ZoneGeometry = dc.field(default_factory=ZoneGeometry)
    subsamples: int = 8
    min_share: float = 0.25
    cluster_gap_mm: float = 25.0
    max_incidence_deg: float = 70.0
    min_range_mm: int = MIN_RANGE_MM
    max_range_mm: int = MAX_RANGE_MM
    noise: NoiseModel = dc.field(default_factory=NoiseModel)

    def __post_init__(self) -> None:
        if self.subsamples < 1:
            raise ValueError(f"subsamples must be >= 1; got {self.subsamples}")
        if not 0 < self.min_share <= 1:
            raise ValueError(f"min_share must be in (0, 1]; got {self.min_share}")
        if self.cluster_gap_mm <= 0:
            raise ValueError(f"cluster_gap_mm must be > 0; got {self.cluster_gap_mm}")
        if not 0 <= self.max_incidence_deg < 90:
            raise ValueError(f"max_incidence_deg must be in [0, 90); got {self.max_incidence_deg}")
        if not 0 <= self.min_range_mm < self.max_range_mm:
            raise ValueError(
                f"need 0 <= min_range_mm < max_range_mm; got {self.min_range_mm}, "
                f"{self.max_range_mm}"
            )


def frame_rng(seed: int, sequence: int) -> np.random.Generator:
    """The noise stream of frame `sequence` of a sensor seeded with `seed`: the same pair gives
    the same frame whatever else has drawn random numbers."""
    return np.random.default_rng([seed, sequence])


def cluster_depths(sub_depth_m: np.ndarray, params: SensorModelParams) -> np.ndarray:
    """Noise-free depth each zone would report: the median of the nearest surface cluster that
    holds at least `min_share` of the zone's samples.

    Args:
        sub_depth_m: (res, res, k, k) perpendicular depths, metres, over each zone's footprint,
            row-major zones; inf, NaN or <= 0 where nothing returns. (res, res, n * k * k)
            takes n renders over the frame period together.
        params: sensor model.

    Returns:
        (res, res) depths, metres, row-major; NaN where no cluster holds enough of the zone.
    """
    res, k = params.geometry.resolution, params.subsamples
    sub = np.asarray(sub_depth_m, dtype=np.float64)
    if sub.shape[:2] != (res, res) or sub[0, 0].size % (k * k):
        raise ValueError(f"sub_depth_m has shape {sub.shape}; expected {(res, res, k, k)} "
                         f"(or (res, res, n * k * k): n renders over the frame)")
    return nearest_cluster_depth(sub.reshape(res * res, -1), params).reshape(res, res)


@numba.njit(cache=True)
def cluster_median(depths: np.ndarray, min_count: int, gap_m: float, slope: float) -> float:
    """The device rule on one zone's samples, sorted ascending in place (inf where nothing
    returns): the median of the nearest cluster of at least `min_count` samples, where a
    cluster breaks where the next sample is deeper by more than max(gap_m, slope * depth);
    NaN if no cluster is that big."""
    depths.sort()
    return sorted_cluster_median(depths, min_count, gap_m, slope)


@numba.njit(cache=True)
def sorted_cluster_median(depths: np.ndarray, min_count: int, gap_m: float, slope: float
                          ) -> float:
    """`cluster_median` of samples already sorted ascending: the box fit keeps each zone's
    samples nearly in order from one evaluation to the next, which sorts far faster itself."""
    m = depths.shape[0]
    start = 0
    while start < m and math.isfinite(depths[start]):
        end = start + 1
        while (end < m and math.isfinite(depths[end])
               and depths[end] - depths[end - 1] <= max(gap_m, slope * depths[end - 1])):
            end += 1
        n = end - start
        if n >= min_count:
            return 0.5 * (depths[start + (n - 1) // 2] + depths[start + n // 2])
        start = end
    return np.nan


@numba.njit(cache=True)
def _cluster_kernel(samples, min_count, gap_m, slope, out):
    buffer = np.empty(samples.shape[1])
    for i in range(samples.shape[0]):
        for j in range(samples.shape[1]):
            v = samples[i, j]
            buffer[j] = v if v > 0 else np.inf  # NaN and <= 0: no return
        out[i] = cluster_median(buffer, min_count, gap_m, slope)


def cluster_rule(params: SensorModelParams, n_samples: int) -> tuple[int, float, float]:
    """(min_count, gap_m, slope) of `cluster_median` for zones of `n_samples` sub-samples.
    The gap widens with depth so that a plane seen up to `max_incidence_deg` from its normal
    stays one cluster at any range."""
    pitch = np.deg2rad(params.geometry.zone_deg) / params.subsamples
    return (math.ceil(params.min_share * n_samples - 1e-9), params.cluster_gap_mm / 1000.0,
            math.tan(math.radians(params.max_incidence_deg)) * pitch)


def nearest_cluster_depth(samples_m: np.ndarray, params: SensorModelParams) -> np.ndarray:
    """`cluster_depths` for any number of zones: (n, k*k) depth samples, metres (inf, NaN or
    <= 0 where nothing returns), to (n,) reported depths, NaN where no cluster is sizeable.
    The box estimator predicts readings with the same `cluster_median`."""
    samples = np.ascontiguousarray(samples_m, dtype=np.float64)
    out = np.empty(samples.shape[0])
    _cluster_kernel(samples, *cluster_rule(params, samples.shape[1]), out)
    return out


def zone_readings(
    sub_depth_m: np.ndarray,
    params: SensorModelParams,
    rng: np.random.Generator,
    sequence: int = 0,
    timestamp_us: int = 0,
) -> ToFFrame:
    """The frame the device reports for a scene sampled over each zone's footprint.

    Per zone: the depth of the nearest sizeable surface cluster (`cluster_depths`), status 5
    when it lies within [min_range_mm, max_range_mm] and 255 otherwise (also where no cluster
    holds `min_share`); Gaussian noise of the noise model's sigma, drawn from `rng` for every
    zone in row-major order, added and rounded to whole mm (negative readings clamp to 0, as
    in the ULD); `sigma_mm` is the model's sigma (0 where no target).

    Args:
        sub_depth_m: (res, res, k, k) perpendicular depths, metres, row-major zones; inf, NaN
            or <= 0 where nothing returns.
        params: sensor model.
        rng: noise source; `frame_rng(seed, sequence)` for a reproducible sensor.
        sequence: frame counter to stamp.
        timestamp_us: capture time to stamp, microseconds.

    Returns:
        The frame in the geometry's raw zone order.
    """
    depth_mm = cluster_depths(sub_depth_m, params) * 1000.0
    noise = rng.standard_normal(depth_mm.shape)
    with np.errstate(invalid="ignore"):  # NaN where no cluster compares False
        valid = (depth_mm >= params.min_range_mm) & (depth_mm <= params.max_range_mm)
    sigma = params.noise.sigma_mm(np.where(valid, depth_mm, 0.0))
    reading = np.clip(np.rint(depth_mm + sigma * noise), 0, np.iinfo(np.int16).max)
    geometry = params.geometry
    return ToFFrame(
        distance_mm=geometry.to_raw(np.where(valid, reading, 0)),
        status=geometry.to_raw(np.where(valid, STATUS_VALID, STATUS_NO_TARGET)),
        sigma_mm=geometry.to_raw(np.where(valid, np.rint(sigma), 0)),
        sequence=sequence,
        timestamp_us=timestamp_us,
    )
