"""Object extraction on synthetic occupancy: the visible surfaces of a known box, sampled densely
and keyed into 1 cm cells the way an occupancy map keys its hits (cell = floor(p / res))."""

import dataclasses as dc
import math

import numpy as np
import pytest

from lrnbv_drake.core.boxes import AlignedBox, OrientedBox
from lrnbv_drake.core.mapping.extraction import (
    LABEL_NOISE,
    LABEL_OUTSIDE,
    LABEL_TABLE,
    ExtractionParams,
    ExtractionStatus,
    extract_object,
    fit_table_height,
)

RES = 0.01
WORKSPACE = AlignedBox([-0.3, -0.3, -0.05], [0.3, 0.3, 0.5])


def occupied_cells(points: np.ndarray, res: float = RES) -> np.ndarray:
    """Centres of the cells holding at least one point."""
    keys = np.unique(np.floor(points / res).astype(np.int64), axis=0)
    return (keys + 0.5) * res


def samples(lo: float, hi: float) -> np.ndarray:
    """Samples from lo to hi inclusive, a quarter cell apart at most (every crossed cell is hit)."""
    return np.linspace(lo, hi, max(2, math.ceil((hi - lo) / (RES / 4)) + 1))


def box_surface(box: OrientedBox, faces: tuple[str, ...] = ("top", "+x", "-y")) -> np.ndarray:
    """Dense points on the given faces of `box` (sides named by the box's own axes)."""
    length, width, height = box.dims
    bottom = box.center[2] - height / 2
    u, v = samples(-length / 2, length / 2), samples(-width / 2, width / 2)
    z = samples(bottom, bottom + height)
    patches = []
    if "top" in faces:
        uu, vv = np.meshgrid(u, v)
        patches.append(np.column_stack([uu.ravel(), vv.ravel(), np.full(uu.size, bottom + height)]))
    for sign, name in ((1, "+x"), (-1, "-x")):
        if name in faces:
            vv, zz = np.meshgrid(v, z)
            patches.append(
                np.column_stack([np.full(vv.size, sign * length / 2), vv.ravel(), zz.ravel()])
            )
    for sign, name in ((1, "+y"), (-1, "-y")):
        if name in faces:
            uu, zz = np.meshgrid(u, z)
            patches.append(
                np.column_stack([uu.ravel(), np.full(uu.size, sign * width / 2), zz.ravel()])
            )
    local = np.vstack(patches)
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    xy = local[:, :2] @ np.array([[c, s], [-s, c]]) + box.center[:2]
    return np.column_stack([xy, local[:, 2]])


def table_surface(height: float, half: float = 0.25) -> np.ndarray:
    """Dense points on a square of table around the origin."""
    xx, yy = np.meshgrid(samples(-half, half), samples(-half, half))
    return np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, height)])


def box_on_table(center_xy, dims, yaw=0.0, table_z=0.0) -> OrientedBox:
    return OrientedBox([*center_xy, table_z + dims[2] / 2], dims, yaw)


def scan(*boxes: OrientedBox, table_z: float | None = 0.0) -> np.ndarray:
    """Occupied cells of the boxes' visible faces plus the table around them."""
    parts = [box_surface(b) for b in boxes]
    if table_z is not None:
        table = table_surface(table_z)
        for b in boxes:  # the table under an object is hidden
            table = table[~b.contains(table, tol=-1e-9)]
        parts.append(table)
    return occupied_cells(np.vstack(parts))


def cell_span(lo: float, hi: float) -> tuple[float, float]:
    """Extent of the cells holding [lo, hi]: (of the cells, of their centres)."""
    n = math.floor(hi / RES) - math.floor(lo / RES)
    return (n + 1) * RES, n * RES


PARAMS = ExtractionParams(workspace=WORKSPACE)


# ---------------------------------------------------------------- one box on the table


@pytest.mark.parametrize("enclose", [True, False])
def test_grid_aligned_box_dimensions(enclose):
    # Faces off the cell boundaries, so the keyed cells are unambiguous.
    truth = box_on_table([0.0133, -0.0271], [0.12, 0.08, 0.063])
    result = extract_object(
        scan(truth), ExtractionParams(workspace=WORKSPACE, enclose_cells=enclose)
    )
    assert result.status is ExtractionStatus.FOUND
    pick = 0 if enclose else 1
    x = cell_span(0.0133 - 0.06, 0.0133 + 0.06)[pick]
    y = cell_span(-0.0271 - 0.04, -0.0271 + 0.04)[pick]
    top = (math.floor(0.063 / RES) + (1.0 if enclose else 0.5)) * RES
    np.testing.assert_allclose(result.dimensions, [x, y, top], atol=1e-9)
    assert np.all(np.abs(result.dimensions - truth.dims) <= RES + 1e-9)  # within one cell
    assert result.oriented_box.yaw == pytest.approx(0.0, abs=1e-9)
    assert result.oriented_box.center[2] - result.dimensions[2] / 2 == pytest.approx(0.0)
    np.testing.assert_allclose(result.center, result.oriented_box.center)
    np.testing.assert_allclose(result.aligned_box.lower[2], 0.0)
    np.testing.assert_allclose(result.aligned_box.size, result.dimensions, atol=1e-9)
    assert result.n_clusters == 1


@pytest.mark.parametrize("yaw", [0.3, -0.7, 1.2])
def test_rotated_box_is_enclosed_and_tight(yaw):
    truth = box_on_table([0.02, -0.01], [0.15, 0.07, 0.05], yaw)
    result = extract_object(scan(truth), PARAMS)
    assert result.status is ExtractionStatus.FOUND
    box = result.oriented_box
    # Enclosing the cells encloses every sampled surface point, the true corners among them.
    assert box.contains(truth.corners(), tol=1e-9).all()
    assert box.contains(result.object_points, tol=1e-9).all()
    # Minimum area: no larger than the truth-aligned rectangle round the cells. A cell holding a
    # face point reaches past the face by at most its width across the face, res (|cos| + |sin|).
    grow = 2 * RES * (abs(math.cos(yaw)) + abs(math.sin(yaw)))
    assert box.dims[0] * box.dims[1] <= (0.15 + grow) * (0.07 + grow) + 1e-12
    assert 0.05 < box.dims[2] <= 0.05 + RES
    assert math.degrees(abs(box.yaw - truth.yaw)) < 6.0
    assert box.iou(truth) == pytest.approx(truth.volume / box.volume)  # truth inside the box


def test_object_points_are_the_cells_above_the_table():
    truth = box_on_table([0.0, 0.0], [0.1, 0.06, 0.05])
    cells = scan(truth)
    result = extract_object(cells, PARAMS)
    expected = cells[(cells[:, 2] >= PARAMS.table_tolerance) & truth.contains(cells, tol=RES)]
    assert sorted(map(tuple, result.object_points)) == sorted(map(tuple, expected))
    assert np.all(result.labels[result.labels != 0] == LABEL_TABLE)
    assert result.table_height == 0.0


@pytest.mark.parametrize("table_height", [0.0, 0.12, 0.13, 0.14, 0.2])
def test_the_first_layer_above_the_tolerance_is_kept_at_any_table_height(table_height):
    """Cell centres fall exactly on the cut when the table is a multiple of the cell: the
    docstring keeps them, and at 0.13 m the float sum 0.13 + 0.015 dropped them."""
    k0 = round(table_height / RES)
    cells = np.array([((i + 0.5) * RES, (j + 0.5) * RES, (k + 0.5) * RES)
                      for i in range(6) for j in range(6) for k in range(k0, k0 + 5)])
    params = dc.replace(PARAMS, table_height=table_height, table_tolerance=0.015)
    result = extract_object(cells, params)
    assert len(np.unique(np.round(result.object_points[:, 2], 9))) == 4  # layers 2..5


def test_roi_is_the_aligned_box_inflated_and_clipped():
    truth = box_on_table([0.0, 0.0], [0.1, 0.06, 0.05])
    result = extract_object(scan(truth), PARAMS)
    np.testing.assert_allclose(result.roi.lower, result.aligned_box.lower - [0.05, 0.05, 0.05])
    np.testing.assert_allclose(result.roi.upper, result.aligned_box.upper + 0.05)
    tight = AlignedBox([-0.08, -0.3, -0.01], [0.3, 0.3, 0.5])
    clipped = extract_object(scan(truth), ExtractionParams(workspace=tight))
    np.testing.assert_allclose(clipped.roi.lower, [-0.08, result.roi.lower[1], -0.01])
    np.testing.assert_allclose(clipped.roi.upper, result.roi.upper)


# ---------------------------------------------------------------- several clusters


def two_objects() -> tuple[OrientedBox, OrientedBox, np.ndarray]:
    big = box_on_table([0.15, 0.0], [0.12, 0.1, 0.08])  # 15 cm from the centre
    small = box_on_table([-0.02, 0.03], [0.05, 0.04, 0.04])  # near the centre
    return big, small, scan(big, small)


def test_two_objects_give_two_clusters_and_the_largest_near_centre():
    big, small, cells = two_objects()
    both = extract_object(cells, ExtractionParams(workspace=WORKSPACE, max_center_distance=0.2))
    assert both.n_clusters == 2
    assert both.object_label == 0  # labels are ordered by size
    assert big.contains(both.object_points, tol=RES).all()
    assert both.oriented_box.iou(big) > 0.6
    near = extract_object(cells, ExtractionParams(workspace=WORKSPACE, max_center_distance=0.1))
    assert near.n_clusters == 2
    assert small.contains(near.object_points, tol=RES).all()
    nearest = extract_object(
        cells, ExtractionParams(workspace=WORKSPACE, selection="nearest_to_center")
    )
    np.testing.assert_allclose(nearest.dimensions, near.dimensions)
    assert np.count_nonzero(both.labels == 1) == len(near.object_points)


def test_workspace_center_overrides_the_workspace_middle():
    big, _, cells = two_objects()
    params = ExtractionParams(
        workspace=WORKSPACE, workspace_center=np.array([0.15, 0.0]), selection="nearest_to_center"
    )
    result = extract_object(cells, params)
    assert big.contains(result.object_points, tol=RES).all()


def test_no_cluster_near_the_centre():
    big = box_on_table([0.2, 0.0], [0.08, 0.06, 0.06])
    result = extract_object(
        scan(big), ExtractionParams(workspace=WORKSPACE, max_center_distance=0.1)
    )
    assert result.status is ExtractionStatus.NONE_NEAR_CENTER
    assert result.n_clusters == 1
    assert result.oriented_box is None and result.roi is None
    assert "0.100 m" in result.reason
    nearest = ExtractionParams(
        workspace=WORKSPACE, max_center_distance=0.1, selection="nearest_to_center"
    )
    assert extract_object(scan(big), nearest).status is ExtractionStatus.NONE_NEAR_CENTER


# ---------------------------------------------------------------- noise and failure modes


def scattered_noise(rng: np.random.Generator, n: int, away_from: OrientedBox | None = None):
    """Isolated noise cells above the table, at least 5 cm from `away_from` if given."""
    pts = rng.uniform([-0.28, -0.28, 0.03], [0.28, 0.28, 0.45], size=(n, 3))
    if away_from is not None:
        pts = pts[~away_from.contains(pts, tol=0.05)]
    return occupied_cells(pts)


def test_scattered_noise_only():
    noise = scattered_noise(np.random.default_rng(1), 40)
    result = extract_object(np.vstack([noise, occupied_cells(table_surface(0.0))]), PARAMS)
    assert result.status is ExtractionStatus.ONLY_NOISE
    assert result.n_clusters == 0
    assert np.count_nonzero(result.labels == LABEL_NOISE) == len(noise)
    assert result.oriented_box is None and result.dimensions is None
    # Where something may stand: every point above the table, as given.
    np.testing.assert_array_equal(result.loose_points, noise)


def test_noise_leaves_the_object_unchanged():
    truth = box_on_table([0.01, 0.0], [0.1, 0.07, 0.06], yaw=0.4)
    clean = extract_object(scan(truth), PARAMS)
    noise = scattered_noise(np.random.default_rng(2), 60, away_from=truth)
    noisy = extract_object(np.vstack([scan(truth), noise]), PARAMS)
    assert noisy.status is ExtractionStatus.FOUND and noisy.n_clusters == 1
    np.testing.assert_allclose(noisy.dimensions, clean.dimensions)
    assert noisy.oriented_box.yaw == pytest.approx(clean.oriented_box.yaw)
    assert np.count_nonzero(noisy.labels == LABEL_NOISE) == len(noise)


def test_small_clusters_are_noise():
    truth = box_on_table([0.0, 0.0], [0.1, 0.07, 0.06])
    blob = occupied_cells(
        np.array([[0.2, 0.2, 0.1]]) + RES * np.indices((2, 2, 2)).reshape(3, -1).T
    )
    result = extract_object(np.vstack([scan(truth), blob]), PARAMS)  # 8 cells < 10
    assert result.n_clusters == 1
    assert np.count_nonzero(result.labels == LABEL_NOISE) == 8
    kept = extract_object(
        np.vstack([scan(truth), blob]), ExtractionParams(workspace=WORKSPACE, min_cluster_points=8)
    )
    assert kept.n_clusters == 2


@pytest.mark.parametrize("points", [np.zeros((0, 3)), np.zeros(0), np.full((4, 3), np.nan)])
def test_no_points(points):
    result = extract_object(points, PARAMS)
    assert result.status is ExtractionStatus.NO_POINTS
    assert result.reason
    assert result.oriented_box is None and result.center is None
    assert len(result.labels) == len(np.reshape(points, (-1, 3)))


def test_points_outside_the_workspace_are_no_points():
    cells = scan(box_on_table([0.0, 0.0], [0.1, 0.07, 0.06])) + np.array([1.0, 0.0, 0.0])
    result = extract_object(cells, PARAMS)
    assert result.status is ExtractionStatus.NO_POINTS
    assert "workspace" in result.reason
    assert np.all(result.labels == LABEL_OUTSIDE)


def test_only_table():
    result = extract_object(occupied_cells(table_surface(0.0)), PARAMS)
    assert result.status is ExtractionStatus.ONLY_TABLE
    assert np.all(result.labels == LABEL_TABLE)
    assert result.dimensions is None


def test_malformed_input_raises():
    with pytest.raises(ValueError):
        extract_object(np.zeros((5, 2)), PARAMS)


def test_params_validation():
    with pytest.raises(ValueError):
        ExtractionParams(selection="biggest")
    with pytest.raises(ValueError):
        ExtractionParams(max_center_distance=0.1)  # no centre to measure from
    with pytest.raises(ValueError):
        ExtractionParams(workspace_center=np.zeros(3))
    assert ExtractionParams(workspace=WORKSPACE).center_xy.tolist() == [0.0, 0.0]


# ---------------------------------------------------------------- unknown table height


def test_fit_table_height_finds_the_dominant_plane():
    rng = np.random.default_rng(4)
    plane = np.column_stack([rng.uniform(-0.3, 0.3, (500, 2)), 0.31 + rng.normal(0, 0.001, 500)])
    clutter = rng.uniform([-0.1, -0.1, 0.33], [0.1, 0.1, 0.5], size=(300, 3))
    height = fit_table_height(np.vstack([plane, clutter]), 0.005, 50, np.random.default_rng(0))
    assert height == pytest.approx(plane[np.abs(plane[:, 2] - 0.31) <= 0.005, 2].mean(), abs=1e-6)


def test_ransac_finds_a_table_at_unknown_height():
    table_z = 0.137
    truth = box_on_table([0.01, -0.02], [0.11, 0.06, 0.07], table_z=table_z)
    cells = scan(truth, table_z=table_z)
    result = extract_object(cells, ExtractionParams(table_height=None, workspace=WORKSPACE, seed=3))
    assert result.status is ExtractionStatus.FOUND
    assert result.table_height == pytest.approx((math.floor(table_z / RES) + 0.5) * RES)
    assert abs(result.table_height - table_z) <= RES / 2
    assert np.all(np.abs(result.dimensions - truth.dims) <= RES + 1e-9)
    assert result.oriented_box.center[2] - result.dimensions[2] / 2 == pytest.approx(
        result.table_height
    )
    again = extract_object(cells, ExtractionParams(table_height=None, workspace=WORKSPACE, seed=3))
    assert again.table_height == result.table_height


def test_without_table_removal_the_box_starts_at_the_lowest_point():
    truth = box_on_table([0.0, 0.0], [0.1, 0.07, 0.06], table_z=0.2)
    cells = occupied_cells(box_surface(truth))
    params = ExtractionParams(table_height=None, use_ransac_fallback=False, workspace=WORKSPACE)
    result = extract_object(cells, params)
    assert result.status is ExtractionStatus.FOUND and result.table_height is None
    bottom = result.oriented_box.center[2] - result.dimensions[2] / 2
    assert bottom == pytest.approx(cells[:, 2].min() - RES / 2)
    assert result.aligned_box.lower[2] == pytest.approx(bottom)
