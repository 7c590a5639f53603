"""The VL53L8CX as data: the frame both the simulated and the real sensor produce, and the zone
geometry that turns a frame into points.

No Drake here: the simulated sensor (`systems/tof_sensor.py`) and the serial driver
(`hardware/tof_serial.py`) both fill `ToFFrame`, and everything downstream reads only it.

Conventions (docs/sensor-model.md gives the sources):
- The sensor frame `tof` has z along the optical axis, x right and y down (Drake's camera
  convention).
- A frame's arrays are in the device's *raw* zone order, exactly as the ULD driver returns them.
  `ZoneGeometry` holds the flips that map a real board's raw order to the row-major
  (row = +y, column = +x) order used here; a simulated sensor with default flips emits row-major.
- Distances are perpendicular (z-depth), as the device reports them, not radial.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np

#: Target statuses the device marks as a valid range (UM3109: "5 & 9 means ranging OK").
VALID_STATUSES: tuple[int, ...] = (5, 9)
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
    """

    resolution: int = 8
    fov_deg: float = 45.0
    flip_x: bool = False
    flip_y: bool = False
    transpose: bool = False

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
        t = np.tan(self.zone_centres_rad())
        tx, ty = np.meshgrid(t, t, indexing="xy")
        return np.stack([tx, ty, np.ones_like(tx)], axis=-1)

    def sub_directions(self, k: int) -> np.ndarray:
        """(res, res, k, k, 3) (tan ax, tan ay, 1) of k x k sub-rays evenly spaced in angle over
        each zone's footprint, row-major. k = 1 gives the zone centres."""
        edges = self.zone_edges_rad()
        step = (edges[1] - edges[0]) / k
        offsets = (np.arange(k) + 0.5) * step
        ang = (edges[:-1, None] + offsets[None, :]).reshape(-1)  # (res*k,)
        t = np.tan(ang)
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
