"""Commissioning a cell from the arm's own views of its bare table: the sensor's pose on its
bracket against the CAD mount, the table's height and tilt, and the board's zone order.

Each view is a few frames of the bare table from a pose the arm's kinematics and the CAD mount
give (`TableView.X_WC`). Through the sensor model (its sub-rays and reading rule,
`core.estimation.forward`), a plane z = h + sx (x - x0) + sy (y - y0) and the sensor at
X_WC X_CS predict every zone's reading; `fit_commissioning` finds the nine numbers (the mount
X_CS, h, sx, sy) by robust least squares on the readings in model sigmas, and their standard
errors from the Jacobian scaled by the fit's own residual spread.

One view of a plane fixes only the plane in the sensor's frame (three numbers), so the mount is
found from how that plane moves as the arm turns the sensor: views at two heights or more, and
tilted in more than one direction. A view set that cannot tell a number apart is refused by
name (its standard error above the tolerance).

The zone order: a board whose grid is turned reads like a sensor turned on its bracket by the
same quarter turns, and a mirrored one like no rigid sensor at all. Each of the eight orders
is fitted from the CAD mount; the order kept is the best fit whose mount is within
`MOUNT_TURN_DEG` of the CAD (a bolted bracket is off by degrees, not a quarter turn).
"""

from __future__ import annotations

import dataclasses as dc
import itertools
from collections.abc import Sequence
from typing import Protocol

import numpy as np
import scipy.optimize
from scipy.spatial.transform import Rotation

from lrnbv_drake.core.estimation.forward import ReadingRule, zone_losses
from lrnbv_drake.core.planning.policy import (
    FRAME_OF_VIEW,
    Observation,
    Proposal,
    Recorded,
    ViewpointPolicy,
)
from lrnbv_drake.core.robot.poses import look_at, offset_transform
from lrnbv_drake.core.sensing.sensor import SensorModelParams, ToFFrame
from lrnbv_drake.core.sensing.tof_device import DeviceBehaviour
from lrnbv_drake.core.sensing.zone_order import ZONE_ROTATIONS, restore_zones

#: The fitted numbers, in the units of `CommissioningFit.values`.
PARAMETERS = ("mount x (mm)", "mount y (mm)", "mount z (mm)", "mount roll (deg)",
              "mount pitch (deg)", "mount yaw (deg)", "table height (mm)",
              "table slope along x (deg)", "table slope along y (deg)")
#: The largest turn of the sensor on its bracket away from the CAD mount, degrees.
MOUNT_TURN_DEG = 15.0
#: A zone the model says sees nothing, in model sigmas (as the estimator's `no_return`).
_NO_RETURN = 5.0
#: The robust loss's scale, model sigmas: residuals beyond it count linearly.
_LOSS_SCALE = 3.0
#: How far inside the table's edge every sub-ray of a fitted zone must land, metres.
EDGE_MARGIN = 0.05


class CommissioningError(ValueError):
    """Views that cannot determine the mount, the table or the zone order."""


@dc.dataclass(frozen=True)
class TableView:
    """Frames of the bare table from one arm pose.

    Attributes:
        X_WC: (4, 4) pose of the CAD mount's sensor frame `tof` in the world, from the arm's
            joint positions.
        frames: the board's frames at rest there, in its own zone order.
    """

    X_WC: np.ndarray
    frames: tuple[ToFFrame, ...]


@dc.dataclass(frozen=True)
class CommissioningFit:
    """The commissioned values (`PARAMETERS`, in that order) and what they rest on.

    Attributes:
        values: (9,) mount x, y, z (mm), roll, pitch, yaw (deg, Drake's roll-pitch-yaw: the
            sensor in the CAD tof frame), table height at `at_xy` (mm above the world's z = 0)
            and its slopes along x and y (deg).
        sigma: (9,) their standard errors.
        at_xy: (2,) where the table height is given, metres.
        zone_order: (rotate, flip) of the board (`core.sensing.zone_order`).
        rms: residual rms of the kept fit, model sigmas.
        orders: each order tried: (rotate, flip, rms, turn of its mount from the CAD, deg).
        readings: readings fitted.
    """

    values: np.ndarray
    sigma: np.ndarray
    at_xy: np.ndarray
    zone_order: tuple[int, str]
    rms: float
    orders: tuple[tuple[int, str, float, float], ...]
    readings: int

    @property
    def mount_xyz_mm(self) -> np.ndarray:
        return self.values[:3]

    @property
    def mount_rpy_deg(self) -> np.ndarray:
        return self.values[3:6]

    @property
    def table_height_m(self) -> float:
        return float(self.values[6]) / 1000


def table_view_poses(center_xy: np.ndarray, table_height: float) -> list[np.ndarray]:
    """X_WS of the views commissioning plans around `center_xy` on the table: straight down
    from three heights, and rings tilted 40 and 60 degrees from vertical looking at the centre
    from every side, the sensor turned a quarter turn about its axis on every other view.
    Tilts far apart separate the mount's offset along its axis from the table's height
    (module docstring); heights and sides vary so that the render's sampling errors average
    out."""
    c = np.array([*center_xy, table_height], float)
    quarter = np.eye(4)
    quarter[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
    up = np.array([0.0, 0.0, 1.0])
    poses = [look_at(c + h * up, c, up=(1.0, 0.0, 0.0)) for h in (0.22, 0.30, 0.40)]
    for tilt, height, sides in ((40.0, 0.25, 4), (60.0, 0.15, 8)):
        for azimuth in np.arange(sides) * 2 * np.pi / sides:
            side = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
            poses.append(look_at(c + height * (up + np.tan(np.deg2rad(tilt)) * side), c))
    return [X @ quarter if i % 2 else X for i, X in enumerate(poses)]


#: The key of an acquisition's info that names the commissioning view it belongs to.
VIEW = "view"


class TableViews(ViewpointPolicy):
    """The acquisition loop's policy while commissioning: each of `poses` in turn, `frames`
    frames at each. A view the arm cannot reach is passed over (the loop moves to the first
    reachable candidate, and every view still to take is one); each acquisition's info
    names its view (`VIEW`)."""

    name = "commission"

    def __init__(self, poses: Sequence[np.ndarray], frames: int) -> None:
        if frames < 1:
            raise ValueError(f"frames per view must be >= 1; got {frames}")
        self._poses = [np.asarray(X, float) for X in poses]
        self._frames = frames
        self._next = 0  # the first view not yet taken

    def propose(self, observation: Observation) -> Proposal:
        if self._next >= len(self._poses):
            return Proposal(done=True, reason=f"took the {len(self._poses)} commissioning "
                                              f"views that the arm could reach")
        views = range(self._next, len(self._poses))
        return Proposal(candidates=[self._poses[k] for k in views], frames=self._frames,
                        candidate_info=[{VIEW: k} for k in views])

    def accepted(self, index: int, observation: Observation) -> None:
        self._next += index + 1

    def restore(self, acquisitions: Sequence[Recorded]) -> None:
        """Carries on after the last view recorded whole; a view cut short is taken again."""
        taken = [a for a in acquisitions if VIEW in a.info]
        if taken:
            last = taken[-1].info
            whole = last.get(FRAME_OF_VIEW, 0) == self._frames - 1
            self._next = last[VIEW] + 1 if whole else last[VIEW]


class Captured(Recorded, Protocol):
    """A recorded acquisition with its frame (`core.acquisition.Acquisition`)."""

    frame: ToFFrame


def views_of(acquisitions: Sequence[Captured], frames: int) -> list[TableView]:
    """The table views in acquisitions the `TableViews` policy led to: each visit to a view
    that recorded its `frames` frames (numbered 0 up, `FRAME_OF_VIEW`), one `TableView` from
    its first frame's sensor pose. A visit a stop cut short is left out: its frames were
    taken from a pose the retake does not share."""
    visits: list[list[Captured]] = []
    for a in acquisitions:
        if VIEW not in a.info:
            continue
        if (not visits or a.info.get(FRAME_OF_VIEW, 0) == 0
                or a.info[VIEW] != visits[-1][-1].info[VIEW]):
            visits.append([])
        visits[-1].append(a)
    return [TableView(np.asarray(v[0].X_WS, float), tuple(a.frame for a in v))
            for v in visits if len(v) == frames]


@dc.dataclass(frozen=True)
class _Readings:
    """One view's mean valid readings in the model's row-major order."""

    X_WC: np.ndarray
    directions: np.ndarray  # (n, m, 3) sub-rays in the sensor frame, t = perpendicular depth
    measured: np.ndarray  # (n,) metres
    sigma: np.ndarray  # (n,) metres, of the mean
    zones: np.ndarray  # (n,) each reading's zone, row-major


def _readings(view: TableView, model: SensorModelParams, order: tuple[int, str],
              table_height: float, extent: np.ndarray) -> _Readings:
    """The view's zones seen valid in every frame, averaged, in row-major order; only zones
    whose every sub-ray meets the table `EDGE_MARGIN` inside its edge from the CAD mount, so
    that no zone's reading steps across the edge while the fit moves the sensor."""
    k = model.subsamples
    X_WC = np.asarray(view.X_WC, float)
    directions = model.geometry.sub_directions(k).reshape(-1, k * k, 3)
    inner = np.asarray(extent, float) + EDGE_MARGIN * np.array([1, 1, -1, -1])
    on_table = np.isfinite(_plane_depths(X_WC[:3, 3], directions @ X_WC[:3, :3].T,
                                         np.array([table_height, 0.0, 0.0]), np.zeros(2),
                                         inner)).all(axis=1)
    valid = on_table & np.all([restore_zones(f.valid, *order) for f in view.frames],
                              axis=0).reshape(-1)
    depth = np.mean([restore_zones(f.distance_mm, *order).astype(float)
                     for f in view.frames], axis=0).reshape(-1)[valid] / 1000
    sigma = model.noise.sigma_mm(depth * 1000) / 1000 / np.sqrt(len(view.frames))
    return _Readings(X_WC, directions[valid], depth, sigma, np.flatnonzero(valid))


def _plane_depths(o: np.ndarray, d: np.ndarray, plane: np.ndarray, at_xy: np.ndarray,
                  extent: np.ndarray) -> np.ndarray:
    """(n, m) perpendicular depths of sub-rays (origin `o`, directions `d` (n, m, 3) world)
    to z = h + sx (x - x0) + sy (y - y0) within the table's `extent`; inf elsewhere."""
    h, sx, sy = plane
    den = d[..., 2] - sx * d[..., 0] - sy * d[..., 1]
    num = h + sx * (o[0] - at_xy[0]) + sy * (o[1] - at_xy[1]) - o[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / den
    x, y = o[0] + t * d[..., 0], o[1] + t * d[..., 1]
    inside = ((t > 0) & (x >= extent[0]) & (x <= extent[2]) & (y >= extent[1])
              & (y <= extent[3]))
    return np.where(inside, t, np.inf)


def _residuals(theta: np.ndarray, views: list[_Readings], rule: ReadingRule,
               at_xy: np.ndarray, extent: np.ndarray) -> np.ndarray:
    """Every reading's residual in its sigma, less its zone's offset (`_zone_offsets`)."""
    X_CS = offset_transform(theta[:3], theta[3:6])
    plane = np.array([theta[6] / 1000, *np.tan(np.deg2rad(theta[7:9]))])
    predicted = []
    for v in views:
        X_WS = v.X_WC @ X_CS
        depths = _plane_depths(X_WS[:3, 3], v.directions @ X_WS[:3, :3].T, plane, at_xy,
                               extent)
        predicted.append(zone_losses(depths, v.measured, v.sigma, *rule.args(), 1.0,
                                     _NO_RETURN)[0])
    predicted = np.concatenate(predicted)
    measured, sigma, zones = (np.concatenate([getattr(v, name) for v in views])
                              for name in ("measured", "sigma", "zones"))
    error = measured - predicted
    seen = ~np.isnan(error)
    error[seen] -= _zone_offsets(error[seen], zones[seen])
    return np.where(seen, error / sigma, _NO_RETURN)


def _zone_offsets(error: np.ndarray, zones: np.ndarray) -> np.ndarray:
    """Each error's zone's fixed offset: the mean of that zone's errors over the views, less
    the mean over the zones. A real board is off by a fixed offset per zone, the same in
    every view (3 mm rms against 0.7 mm of noise, ../shared/notes/vl53l8cx-behaviour.md 9);
    profiled out, it cannot pull the mount. Their mean is left in: an offset common to every
    zone reads exactly as the sensor moved along its axis, which the mount's z then takes."""
    total = np.bincount(zones, error)
    count = np.bincount(zones)
    means = total[count > 0] / count[count > 0]
    return total[zones] / count[zones] - means.mean()


def _fit_one(views: list[_Readings], rule: ReadingRule, at_xy: np.ndarray,
             extent: np.ndarray, table_height: float) -> scipy.optimize.OptimizeResult:
    start = np.zeros(9)
    start[6] = table_height * 1000
    return scipy.optimize.least_squares(
        _residuals, start, args=(views, rule, at_xy, extent), loss="soft_l1",
        f_scale=_LOSS_SCALE, diff_step=1e-4, x_scale=np.ones(9))


def fit_commissioning(views: list[TableView], model: SensorModelParams,
                      behaviour: DeviceBehaviour, extent: np.ndarray, at_xy: np.ndarray,
                      table_height: float = 0.0,
                      tolerance: tuple[float, float] = (1.0, 0.2)) -> CommissioningFit:
    """The mount, table and zone order that explain `views` best.

    Args:
        views: frames of the bare table, each with the CAD sensor pose it was taken from.
        model: the sensor model, its geometry in row-major order (no flips: the order is
            what is fitted).
        behaviour: the model's reading rule (`sensor:`).
        extent: the table top (x_min, y_min, x_max, y_max), metres.
        at_xy: where to give the table's height (the drop zone's centre).
        table_height: the height the scenario assumes, the fit's start.
        tolerance: the largest standard error accepted, (mm, deg): above it the views
            cannot tell that number apart and CommissioningError names it.
    """
    if not views:
        raise CommissioningError("no views of the table to fit")
    rule, at_xy, extent = ReadingRule.of(model, behaviour), np.asarray(at_xy), np.asarray(extent)
    orders, fits = [], {}
    for rotate, flip in itertools.product(ZONE_ROTATIONS, ("none", "rows")):
        readings = [_readings(v, model, (rotate, flip), table_height, extent) for v in views]
        result = _fit_one(readings, rule, at_xy, extent, table_height)
        rms = float(np.sqrt(np.mean(result.fun ** 2)))
        turn = float(np.rad2deg(Rotation.from_euler("xyz", result.x[3:6],
                                                    degrees=True).magnitude()))
        orders.append((rotate, flip, rms, turn))
        fits[(rotate, flip)] = result, readings
    plausible = [o for o in orders if o[3] <= MOUNT_TURN_DEG]
    if not plausible:
        raise CommissioningError(
            "no zone order fits the views with the sensor within "
            f"{MOUNT_TURN_DEG:g} deg of its CAD mount: is the table bare, and the sensor on "
            f"its bracket? (each order's rms in model sigmas and turn: {_orders_text(orders)})")
    best = min(plausible, key=lambda o: o[2])
    rivals = [o for o in plausible if o is not best and o[2] < 2 * best[2]]
    if rivals:
        raise CommissioningError(
            "the views cannot tell the zone order apart: "
            f"{_orders_text([best, *rivals])} fit about as well; add views tilted towards "
            "other sides")
    result, readings = fits[best[:2]]
    n, p = len(result.fun), 9
    # The zones' offsets (`_zone_offsets`) are numbers fitted too, all but their mean.
    offsets = len(np.unique(np.concatenate([v.zones for v in readings]))) - 1
    jtj = result.jac.T @ result.jac
    scale = float(np.sum(result.fun ** 2)) / max(n - p - offsets, 1)
    sigma = np.sqrt(np.maximum(np.diag(np.linalg.pinv(jtj) * scale), 0.0))
    if np.linalg.matrix_rank(jtj, tol=1e-9 * np.abs(jtj).max()) < p:
        sigma[:] = np.inf
    limits = np.array([tolerance[0]] * 3 + [tolerance[1]] * 3 + [tolerance[0]]
                      + [tolerance[1]] * 2)
    unknown = [f"{name} (standard error {s:.3g}, at most {lim:g})"
               for name, s, lim in zip(PARAMETERS, sigma, limits, strict=True) if not s <= lim]
    if unknown:
        raise CommissioningError(
            "the views cannot tell these apart: " + "; ".join(unknown)
            + ". Take views at two heights or more, tilted towards several sides")
    return CommissioningFit(result.x.copy(), sigma, at_xy, best[:2], best[2], tuple(orders), n)


def _orders_text(orders) -> str:
    return ", ".join(f"rotate {r} flip {f}: {rms:.2f}, {turn:.1f} deg"
                     for r, f, rms, turn in orders)
