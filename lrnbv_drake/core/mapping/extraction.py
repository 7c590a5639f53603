"""Object extraction from the occupied cells of the map: the paper's "Object Clustering and
Dynamic ROI" step (Algorithm 1, line 18).

No Drake here: `systems/object_clustering.py` wraps `extract_object` as a system.

Pipeline: crop to the workspace, drop the table (known height, or the dominant horizontal plane
found by RANSAC), cluster what remains with DBSCAN, reject clusters too small to be an object,
pick one cluster near the workspace centre, then box it. The box serves as the object estimate
(dimensions and IoU metrics), and inflated by a margin as the dynamic ROI and collision volume.

Cells, not points: the input is the centres of occupied cells of size `cell_size`, and a cell is
occupied when any part of it holds a surface hit. With `enclose_cells` (the default) the boxes
enclose the cells, i.e. each centre +- cell_size/2, so the box contains every measured surface, as
collision checking and container choice need. The price is a bias. For faces parallel to the grid,
sitting anywhere in their cells, length and width come out 0 to 2 cells too long (1 on average)
and the height, with a known table, 0 to 1 cell too tall. Faces oblique to the grid add staircase
cells: dense synthetic scans of boxes at random yaw gave +2.2 cells on average in length and
width, at most 2.9. Boxing the bare centres instead (`enclose_cells=False`) errs by under one cell
either way for grid-parallel faces (+0.9 on average, at most 1.7, at random yaw) but can cut into
the object.
"""

from __future__ import annotations

import dataclasses as dc
import enum
import itertools
import math
from typing import Literal

import numpy as np
from sklearn.cluster import DBSCAN

from lrnbv_drake.core.boxes import AlignedBox, OrientedBox

#: Label of points DBSCAN left as noise, or in a cluster smaller than `min_cluster_points`.
LABEL_NOISE = -1
#: Label of points removed as the table (or below it).
LABEL_TABLE = -2
#: Label of points outside the workspace, or not finite.
LABEL_OUTSIDE = -3


class ExtractionStatus(enum.Enum):
    """Outcome of `extract_object`; only FOUND fills the object fields."""

    FOUND = "found"
    NO_POINTS = "no_points"  # nothing (finite) inside the workspace
    ONLY_TABLE = "only_table"  # every point belongs to the table
    ONLY_NOISE = "only_noise"  # points above the table, but no cluster big enough
    NONE_NEAR_CENTER = "none_near_center"  # clusters, but none close enough to the centre


@dc.dataclass
class ExtractionParams:
    """Settings of `extract_object`; lengths in metres, defaults for 1 cm cells.

    Args:
        table_height: z of the table top. None: estimate it (see `use_ransac_fallback`) as the
            mean z of the table's cell centres, which is unbiased for the surface height.
        table_tolerance: points with z < table height + this are the table (1.5 cells): it
            absorbs the table cell and sensor noise, so an object must be taller than it.
        use_ransac_fallback: with table_height None, find the table as the dominant horizontal
            plane by RANSAC; if False, remove no table (the input is already segmented) and box
            the object from its lowest point.
        ransac_threshold: RANSAC inlier band, |z - plane| <= this; half a cell takes in one
            layer of cell centres, not the object's first layer above the table.
        ransac_iterations: RANSAC hypotheses (one sampled point each: the plane is horizontal).
        dbscan_eps: DBSCAN neighbourhood radius (2.5 cells: bridges one missing cell).
        dbscan_min_samples: DBSCAN core-point neighbour count, the point itself included.
        min_cluster_points: clusters with fewer points are noise.
        selection: "largest_near_center": the cluster with the most points among those whose xy
            centroid lies within `max_center_distance` of the workspace centre (ties to the
            nearer); "nearest_to_center": of those, the one whose centroid is nearest.
        workspace: crop the input to this box first; None keeps everything.
        workspace_center: (2,) xy the selection measures from; None: the workspace's centre.
        max_center_distance: xy distance from the centre beyond which a cluster is not a
            candidate; inf (the default) disables the gate.
        roi_margin: the ROI is the object's aligned box grown by this, clipped to the workspace.
        cell_size: edge of the occupancy cells the input points are centres of.
        enclose_cells: box the cells (centres +- cell_size/2) rather than the centres; see the
            module docstring for the bias either way.
        seed: RANSAC random seed.
    """

    table_height: float | None = 0.0
    table_tolerance: float = 0.015
    use_ransac_fallback: bool = True
    ransac_threshold: float = 0.005
    ransac_iterations: int = 100
    dbscan_eps: float = 0.025
    dbscan_min_samples: int = 4
    min_cluster_points: int = 10
    selection: Literal["largest_near_center", "nearest_to_center"] = "largest_near_center"
    workspace: AlignedBox | None = None
    workspace_center: np.ndarray | None = None
    max_center_distance: float = math.inf
    roi_margin: float = 0.05
    cell_size: float = 0.01
    enclose_cells: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        if self.selection not in ("largest_near_center", "nearest_to_center"):
            raise ValueError(f"unknown selection {self.selection!r}")
        if self.workspace_center is not None:
            self.workspace_center = np.asarray(self.workspace_center, dtype=np.float64)
            if self.workspace_center.shape != (2,):
                raise ValueError(
                    f"workspace_center must be xy (2,); got {self.workspace_center.shape}"
                )
        needs_center = self.selection == "nearest_to_center" or math.isfinite(
            self.max_center_distance
        )
        if needs_center and self.center_xy is None:
            raise ValueError(
                "selection by distance to the centre needs workspace_center or workspace"
            )
        if self.cell_size <= 0 or self.dbscan_eps <= 0:
            raise ValueError("cell_size and dbscan_eps must be positive")

    @property
    def center_xy(self) -> np.ndarray | None:
        """The xy the selection measures from, or None when neither centre nor workspace is set."""
        if self.workspace_center is not None:
            return self.workspace_center
        if self.workspace is not None:
            return self.workspace.center[:2]
        return None


@dc.dataclass
class ExtractionResult:
    """What `extract_object` found. The object fields are None unless status is FOUND.

    Args:
        status: outcome.
        reason: one readable line explaining the status.
        labels: (N,) int per input point: cluster index >= 0 (0 the largest), or LABEL_NOISE,
            LABEL_TABLE, LABEL_OUTSIDE.
        n_clusters: clusters with at least `min_cluster_points` points.
        table_height: the table height used (given or estimated); None when no table removed.
        object_label: the chosen cluster's label.
        object_points: (M, 3) the chosen cluster's points.
        aligned_box: axis-aligned box of the object, down to the table.
        oriented_box: yaw-oriented minimum-footprint box of the object, down to the table.
        dimensions: (3,) length >= width, height of `oriented_box`.
        roi: `aligned_box` grown by `roi_margin` and clipped to the workspace.
        center: (3,) centre of `oriented_box` (the paper's x_object).
        loose_points: (K, 3) the points above the table when they form no cluster of
            `min_cluster_points` (status ONLY_NOISE): where an object may stand, seen too
            little to be one yet.
    """

    status: ExtractionStatus
    reason: str
    labels: np.ndarray
    n_clusters: int = 0
    table_height: float | None = None
    object_label: int | None = None
    object_points: np.ndarray | None = None
    aligned_box: AlignedBox | None = None
    oriented_box: OrientedBox | None = None
    dimensions: np.ndarray | None = None
    roi: AlignedBox | None = None
    center: np.ndarray | None = None
    loose_points: np.ndarray | None = None

    @property
    def found(self) -> bool:
        """True when an object was extracted."""
        return self.status is ExtractionStatus.FOUND


def found_box(extraction: ExtractionResult | None) -> OrientedBox | None:
    """The object's cell box from an extraction, or None when it found no object."""
    return extraction.oriented_box if extraction is not None and extraction.found else None


def fit_table_height(
    points: np.ndarray, threshold: float, iterations: int, rng: np.random.Generator
) -> float:
    """Height of the dominant horizontal plane of `points` (at least one) by RANSAC.

    A horizontal plane is fixed by one point, so each hypothesis is the z of one sampled point;
    the one with most inliers wins (ties to the lower plane, the table being under the object),
    refined to the mean z of its inliers.
    """
    z = np.asarray(points, dtype=np.float64)[:, 2]
    candidates = z[rng.integers(0, len(z), size=iterations)]
    counts = (np.abs(z[None, :] - candidates[:, None]) <= threshold).sum(axis=1)
    best = candidates[counts == counts.max()].min()
    return float(z[np.abs(z - best) <= threshold].mean())


def extract_object(occupied_points: np.ndarray, params: ExtractionParams) -> ExtractionResult:
    """Finds the object among the occupied cell centres and boxes it.

    Never raises on the content of the scan (empty, all table, all noise): the status and
    reason say what was missing. Raises ValueError only for a malformed array.
    """
    pts = np.asarray(occupied_points, dtype=np.float64)
    if pts.size == 0:
        pts = pts.reshape(0, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"occupied_points must be (N, 3); got shape {np.shape(occupied_points)}")
    labels = np.full(len(pts), LABEL_OUTSIDE, dtype=np.int64)

    keep = np.all(np.isfinite(pts), axis=1)
    if params.workspace is not None:
        keep[keep] = params.workspace.contains(pts[keep])
    if not keep.any():
        where = "inside the workspace" if params.workspace is not None else "with finite values"
        return ExtractionResult(ExtractionStatus.NO_POINTS, f"no occupied points {where}", labels)
    labels[keep] = LABEL_TABLE

    table_height = params.table_height
    if table_height is None and params.use_ransac_fallback:
        rng = np.random.default_rng(params.seed)
        table_height = fit_table_height(
            pts[keep], params.ransac_threshold, params.ransac_iterations, rng
        )
    if table_height is not None:
        # Cell centres lie on the cut when the table height is a multiple of the cell: keep
        # them whatever the last bit of the sum (at 0.13 + 0.015 it dropped a whole layer).
        keep &= pts[:, 2] >= table_height + params.table_tolerance - 1e-9
    if not keep.any():
        return ExtractionResult(
            ExtractionStatus.ONLY_TABLE,
            f"all {np.count_nonzero(labels == LABEL_TABLE)} points lie below "
            f"z = {table_height + params.table_tolerance:.3f} (table plus tolerance)",
            labels,
            table_height=table_height,
        )

    labels[keep] = _clusters_by_size(pts[keep], params)
    n_clusters = int(labels.max()) + 1 if labels.max() >= 0 else 0
    if n_clusters == 0:
        return ExtractionResult(
            ExtractionStatus.ONLY_NOISE,
            f"{np.count_nonzero(keep)} points above the table form no cluster of at least "
            f"{params.min_cluster_points} points",
            labels,
            table_height=table_height,
            loose_points=pts[keep],
        )

    chosen = _select_cluster(pts, labels, n_clusters, params)
    if chosen is None:
        return ExtractionResult(
            ExtractionStatus.NONE_NEAR_CENTER,
            f"none of {n_clusters} clusters has its centroid within "
            f"{params.max_center_distance:.3f} m of the workspace centre",
            labels,
            n_clusters=n_clusters,
            table_height=table_height,
        )

    object_points = pts[labels == chosen]
    aligned, oriented = _boxes(object_points, table_height, params)
    roi = aligned.inflate(params.roi_margin)
    if params.workspace is not None:
        roi = roi.clip(params.workspace)  # never None: the object is inside the workspace
    return ExtractionResult(
        ExtractionStatus.FOUND,
        f"cluster {chosen} of {n_clusters} ({len(object_points)} points), "
        f"dimensions {np.array2string(oriented.dims, precision=3)} m",
        labels,
        n_clusters=n_clusters,
        table_height=table_height,
        object_label=chosen,
        object_points=object_points,
        aligned_box=aligned,
        oriented_box=oriented,
        dimensions=oriented.dims.copy(),
        roi=roi,
        center=oriented.center.copy(),
    )


def _clusters_by_size(points: np.ndarray, params: ExtractionParams) -> np.ndarray:
    """DBSCAN labels with clusters under `min_cluster_points` turned to noise and the rest
    renumbered by decreasing size (0 the largest; ties keep DBSCAN's order)."""
    raw = DBSCAN(eps=params.dbscan_eps, min_samples=params.dbscan_min_samples).fit_predict(points)
    ids, counts = np.unique(raw[raw >= 0], return_counts=True)
    big = counts >= params.min_cluster_points
    ids, counts = ids[big], counts[big]
    order = np.argsort(-counts, kind="stable")
    remap = np.full(raw.max() + 2, LABEL_NOISE, dtype=np.int64)  # index -1 maps noise to noise
    remap[ids[order]] = np.arange(len(ids))
    return remap[raw]


def _select_cluster(
    points: np.ndarray, labels: np.ndarray, n_clusters: int, params: ExtractionParams
) -> int | None:
    """The chosen cluster label per `params.selection`, or None if no cluster qualifies."""
    center = params.center_xy
    if center is None:  # no centre to measure from: the gate is off, take the largest
        return 0
    centroids = np.array([points[labels == k, :2].mean(axis=0) for k in range(n_clusters)])
    distances = np.linalg.norm(centroids - center, axis=1)
    candidates = np.flatnonzero(distances <= params.max_center_distance)
    if len(candidates) == 0:
        return None
    if params.selection == "nearest_to_center":
        return int(candidates[np.argmin(distances[candidates])])
    sizes = np.bincount(labels[labels >= 0], minlength=n_clusters)[candidates]
    best = candidates[sizes == sizes.max()]
    return int(best[np.argmin(distances[best])])


def _boxes(
    points: np.ndarray, table_height: float | None, params: ExtractionParams
) -> tuple[AlignedBox, OrientedBox]:
    """Aligned and oriented boxes of a cluster, standing on the table when its height is known."""
    if params.enclose_cells:
        offsets = np.array(list(itertools.product((-0.5, 0.5), repeat=3))) * params.cell_size
        points = (points[:, None, :] + offsets[None, :, :]).reshape(-1, 3)
    oriented = OrientedBox.from_points(points, floor_z=table_height)
    aligned = AlignedBox.from_points(points)
    if table_height is not None:
        aligned = AlignedBox([*aligned.lower[:2], table_height], aligned.upper)
    return aligned, oriented
