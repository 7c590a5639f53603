"""Reconstruction metrics of one episode, as the paper reports them ("Experimental Validation"):
bounding-box dimensions and IoU, number of poses, surface coverage and useless poses, plus the
coverage-versus-poses curve and its AUC (GenNBV style). docs/metrics.md gives the definitions and
why they were chosen.

No Drake here. Inputs are plain arrays: the estimate and ground truth as `OrientedBox`es, the
ground-truth surface as uniform samples (`objects.sample_surface`, spacing <= threshold / 2,
resting face left out), and the object's occupied cells as centres of cubes of edge `cell_size`
(e.g. `ExtractionResult.object_points`).

Coverage of one sample: the Euclidean distance from the sample to the nearest occupied cell, the
cell taken as its whole cube (0 inside it), is at most the threshold. An occupied cell says only
that some surface hit lies somewhere in the cube, so this is the distance to the nearest place
the measured surface can be.
"""

from __future__ import annotations

import dataclasses as dc
import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from lrnbv_drake.core.boxes import OrientedBox

#: Coverage thresholds reported, m: one and two map cells.
DEFAULT_THRESHOLDS: tuple[float, ...] = (0.01, 0.02)
#: The threshold the useless poses and the headline coverage use, m: one map cell.
PRIMARY_THRESHOLD = 0.01
#: Added to every threshold, m: a sample on a cell face (a box top at a multiple of the cell
#: size) comes out ~1e-17 m outside the cell by rounding, and 1 nm is physically nothing.
ROUNDING_SLACK = 1e-9


# ---------------------------------------------------------------- boxes


@dc.dataclass
class BoxMetrics:
    """Estimated against true box. Dims are (length, width, height) with length >= width, as
    `OrientedBox` keeps them.

    Args:
        found: whether there was an estimate; if not, the estimated dims and errors are NaN and
            the IoU is 0.
        estimated_dims: (3,) estimated L, W, H, m.
        true_dims: (3,) true L, W, H, m.
        errors: (3,) estimated - true, m (positive: the estimate is too big).
        abs_errors: (3,) |errors|, m.
        iou: exact 3-D IoU of the two yaw-oriented boxes, in [0, 1].
    """

    found: bool
    estimated_dims: np.ndarray
    true_dims: np.ndarray
    errors: np.ndarray
    abs_errors: np.ndarray
    iou: float

    def to_dict(self) -> dict[str, object]:
        """Plain JSON-able types, NaN as None."""
        return {
            "box_found": self.found,
            "estimated_dims": _json_list(self.estimated_dims),
            "true_dims": _json_list(self.true_dims),
            "dim_errors": _json_list(self.errors),
            "abs_dim_errors": _json_list(self.abs_errors),
            "iou": _json_float(self.iou),
        }


def true_box(mesh_vertices: np.ndarray, table_height: float) -> OrientedBox:
    """Ground-truth box: built like the estimate (minimum-footprint yaw box, down to the table)
    from the world-frame mesh vertices, so the IoU compares like with like."""
    return OrientedBox.from_points(mesh_vertices, floor_z=table_height)


def box_metrics(estimated: OrientedBox | None, true: OrientedBox) -> BoxMetrics:
    """Dimension errors and IoU of `estimated` (e.g. `ExtractionResult.oriented_box`, None when
    nothing was extracted) against `true`."""
    true_dims = true.dims.copy()
    if estimated is None:
        nan = np.full(3, np.nan)
        return BoxMetrics(False, nan, true_dims, nan.copy(), nan.copy(), 0.0)
    errors = estimated.dims - true_dims
    return BoxMetrics(
        True, estimated.dims.copy(), true_dims, errors, np.abs(errors), estimated.iou(true)
    )


def poses_to_accuracy(errors_after_each_pose: np.ndarray, tolerance: float) -> int | None:
    """The number of poses after which every dimension's |error| is within `tolerance` and
    stays so for every later pose; None if that never happens.

    Args:
        errors_after_each_pose: (n_poses, 3) estimate - truth after each pose (NaN: no
            estimate), e.g. the estimator re-run on each prefix of an episode. It measures a
            planner independently of when its stop rule ended the episode.
    """
    errors = np.abs(np.asarray(errors_after_each_pose, dtype=np.float64)).reshape(-1, 3)
    # NaN compares False; the slack keeps an error of exactly the tolerance (0.30 m estimated
    # for 0.29 m: 0.010000000000000009) within it.
    within = np.all(errors <= tolerance + ROUNDING_SLACK, axis=1)
    if len(within) == 0 or not within[-1]:
        return None
    outside = np.flatnonzero(~within)
    return int(outside[-1] + 2) if outside.size else 1


# ---------------------------------------------------------------- coverage


def _points(points: np.ndarray, name: str) -> np.ndarray:
    """(N, 3) finite float64 array, N may be 0."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.size == 0:
        return pts.reshape(0, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"{name} must be (N, 3); got shape {np.shape(points)}")
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"{name} must be finite")
    return pts


def _thresholds(thresholds: Sequence[float]) -> tuple[float, ...]:
    values = tuple(float(t) for t in thresholds)
    if not values or not all(math.isfinite(t) and t >= 0 for t in values):
        raise ValueError(f"thresholds must be one or more finite lengths >= 0; got {thresholds}")
    return values


class _SurfaceReference:
    """The ground-truth samples with their KD-tree, built once for a whole coverage curve."""

    def __init__(self, samples: np.ndarray, cell_size: float) -> None:
        self.samples = _points(samples, "surface_samples")
        if len(self.samples) == 0:
            raise ValueError("surface_samples is empty: coverage has no denominator")
        if not (math.isfinite(cell_size) and cell_size >= 0):
            raise ValueError(f"cell_size must be a finite length >= 0; got {cell_size}")
        self.half = cell_size / 2
        self.tree = cKDTree(self.samples)

    def cell_distances(self, centers: np.ndarray, max_distance: float) -> np.ndarray:
        """(M,) distance from each sample to the nearest cell cube, inf beyond `max_distance`.

        A cube is no farther than its centre minus the half diagonal, so the centres within
        `max_distance` + half diagonal hold every cube within `max_distance`; the KD-tree finds
        those pairs and the exact point-to-cube distance decides.
        """
        centers = _points(centers, "cell centres")
        distances = np.full(len(self.samples), np.inf)
        if len(centers) == 0:
            return distances
        reach = max_distance + math.sqrt(3) * self.half
        pairs = self.tree.sparse_distance_matrix(cKDTree(centers), reach, output_type="ndarray")
        outside = np.abs(self.samples[pairs["i"]] - centers[pairs["j"]]) - self.half
        to_cube = np.linalg.norm(np.maximum(outside, 0.0), axis=1)
        np.minimum.at(distances, pairs["i"], to_cube)
        return distances

    def coverage(self, centers: np.ndarray, thresholds: tuple[float, ...]) -> dict[float, float]:
        distances = self.cell_distances(centers, max(thresholds))
        return {t: float(np.mean(distances <= t + ROUNDING_SLACK)) for t in thresholds}


def surface_coverage(
    surface_samples: np.ndarray,
    object_cell_centers: np.ndarray,
    cell_size: float,
    thresholds: Sequence[float] = DEFAULT_THRESHOLDS,
) -> dict[float, float]:
    """Share of the surface samples within each threshold of an occupied object cell.

    The denominator is every sample, i.e. the whole sampled surface (the caller leaves out the
    face resting on the table), not only what some view could see. `cell_size` 0 makes the
    cells points, i.e. a plain point-to-point recall.

    Returns:
        {threshold: coverage in [0, 1]}.
    """
    reference = _SurfaceReference(surface_samples, cell_size)
    return reference.coverage(object_cell_centers, _thresholds(thresholds))


def coverage_curve(
    surface_samples: np.ndarray,
    cells_after_each_pose: Sequence[np.ndarray],
    cell_size: float,
    thresholds: Sequence[float] = DEFAULT_THRESHOLDS,
) -> dict[float, np.ndarray]:
    """Coverage after each pose: entry i is `surface_coverage` of the object cells once pose i
    was integrated (an empty (0, 3) array when no object was found then).

    Returns:
        {threshold: (n_poses,) coverage}.
    """
    values = _thresholds(thresholds)
    reference = _SurfaceReference(surface_samples, cell_size)
    per_pose = [reference.coverage(cells, values) for cells in cells_after_each_pose]
    return {t: np.array([c[t] for c in per_pose], dtype=np.float64) for t in values}


def useless_poses(curve: np.ndarray, eps: float = 0.0) -> list[int]:
    """Indices of the poses after which coverage did not rise by more than `eps` over the
    coverage before them (0 before the first pose): the paper's poses that "do not increase the
    reconstructed surface", including those that lower it."""
    values = np.asarray(curve, dtype=np.float64).reshape(-1)
    if not (math.isfinite(eps) and eps >= 0):
        raise ValueError(f"eps must be a finite share >= 0; got {eps}")
    before = np.concatenate([[0.0], values[:-1]])
    return np.flatnonzero(values - before <= eps).tolist()


def n_useless_poses(curve: np.ndarray, eps: float = 0.0) -> int:
    """Number of `useless_poses`."""
    return len(useless_poses(curve, eps))


def coverage_auc(curve: np.ndarray, budget: int | None = None) -> float:
    """Area under the coverage-versus-poses step curve divided by the number of poses: the mean
    coverage over the episode, 1 only if the first pose already saw everything.

    With `budget`, the curve is cut or extended to that many poses, holding the final coverage
    after the episode stopped, and divided by it, as GenNBV does with its fixed episode length:
    then a planner that stops early is neither rewarded nor punished for the poses it skipped.
    0 for an empty curve.
    """
    values = np.asarray(curve, dtype=np.float64).reshape(-1)
    if budget is not None:
        if budget < 1:
            raise ValueError(f"budget must be a positive number of poses; got {budget}")
        last = values[-1] if len(values) else 0.0
        values = np.concatenate([values[:budget], np.full(max(budget - len(values), 0), last)])
    return float(values.mean()) if len(values) else 0.0


# ---------------------------------------------------------------- episode


@dc.dataclass
class EpisodeMetrics:
    """The paper's metrics for one episode, with the coverage curve they are read from.

    Args:
        box: dimensions, their errors and the IoU of the final estimate.
        primary_threshold: the threshold `useless` is counted at, m.
        coverage: {threshold: coverage after the last pose}, 0 with no poses.
        coverage_curve: {threshold: (n_poses,) coverage after each pose}.
        auc: {threshold: `coverage_auc` of the curve}.
        useless: indices of the useless poses at `primary_threshold`.
    """

    box: BoxMetrics
    primary_threshold: float
    coverage: dict[float, float]
    coverage_curve: dict[float, np.ndarray]
    auc: dict[float, float]
    useless: list[int]

    @property
    def n_poses(self) -> int:
        """Poses taken."""
        return len(self.coverage_curve[self.primary_threshold])

    @property
    def n_useless_poses(self) -> int:
        """Poses that did not increase coverage at the primary threshold."""
        return len(self.useless)

    def to_dict(self) -> dict[str, object]:
        """Plain JSON-able types, NaN as None; per-threshold values keyed by the threshold in
        metres as text (`"0.01"`)."""
        return {
            **self.box.to_dict(),
            "n_poses": self.n_poses,
            "n_useless_poses": self.n_useless_poses,
            "useless_poses": [int(i) for i in self.useless],
            "primary_threshold": _json_float(self.primary_threshold),
            "coverage": {_key(t): _json_float(c) for t, c in self.coverage.items()},
            "coverage_curve": {_key(t): _json_list(c) for t, c in self.coverage_curve.items()},
            "auc": {_key(t): _json_float(a) for t, a in self.auc.items()},
        }


def episode_metrics(
    estimated: OrientedBox | None,
    true: OrientedBox,
    surface_samples: np.ndarray,
    cells_after_each_pose: Sequence[np.ndarray],
    cell_size: float,
    thresholds: Sequence[float] = DEFAULT_THRESHOLDS,
    primary_threshold: float = PRIMARY_THRESHOLD,
    eps: float = 0.0,
    auc_budget: int | None = None,
) -> EpisodeMetrics:
    """All metrics of one episode from its final box estimate and the object cells after each
    pose (the last entry being the final map)."""
    values = _thresholds(thresholds)
    if float(primary_threshold) not in values:
        raise ValueError(f"primary_threshold {primary_threshold} is not among {values}")
    curves = coverage_curve(surface_samples, cells_after_each_pose, cell_size, values)
    return EpisodeMetrics(
        box=box_metrics(estimated, true),
        primary_threshold=float(primary_threshold),
        coverage={t: float(c[-1]) if len(c) else 0.0 for t, c in curves.items()},
        coverage_curve=curves,
        auc={t: coverage_auc(c, auc_budget) for t, c in curves.items()},
        useless=useless_poses(curves[float(primary_threshold)], eps),
    )


def _json_float(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _json_list(values: np.ndarray) -> list[float | None]:
    return [_json_float(v) for v in np.asarray(values).reshape(-1).tolist()]


def _key(threshold: float) -> str:
    return f"{threshold:g}"
