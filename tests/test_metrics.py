"""Episode metrics: hand-worked IoUs and coverages, coverage against a brute-force reference,
useless poses and AUC on a hand-made curve, and the JSON export."""

import json
import math

import numpy as np
import pytest
import trimesh

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.evaluation.metrics import (
    box_metrics,
    coverage_auc,
    coverage_curve,
    episode_metrics,
    n_useless_poses,
    poses_to_accuracy,
    surface_coverage,
    true_box,
    useless_poses,
)

TRUE = OrientedBox(center=[0.4, -0.1, 0.06], dims=[0.30, 0.20, 0.12], yaw=0.3)


def scaled(box: OrientedBox, factors: tuple[float, float, float]) -> OrientedBox:
    """`box` with its dims multiplied per axis, standing on the same floor."""
    dims = box.dims * np.array(factors)
    center = box.center + np.array([0.0, 0.0, (dims[2] - box.dims[2]) / 2])
    return OrientedBox(center, dims, box.yaw)


# ---------------------------------------------------------------- boxes


def test_box_ten_percent_longer_gives_iou_one_over_1_1():
    metrics = box_metrics(scaled(TRUE, (1.1, 1.0, 1.0)), TRUE)
    assert metrics.found
    assert metrics.iou == pytest.approx(1 / 1.1)
    np.testing.assert_allclose(metrics.estimated_dims, [0.33, 0.20, 0.12])
    np.testing.assert_allclose(metrics.true_dims, [0.30, 0.20, 0.12])
    np.testing.assert_allclose(metrics.errors, [0.03, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(metrics.abs_errors, [0.03, 0.0, 0.0], atol=1e-12)


def test_box_errors_are_signed_and_height_uses_the_floor():
    # Half as wide, 1.5 times as tall (same floor): the estimate is 0.75 V, the intersection
    # 0.5 V, the union V + 0.75 V - 0.5 V = 1.25 V -> IoU 0.4.
    metrics = box_metrics(scaled(TRUE, (1.0, 0.5, 1.5)), TRUE)
    np.testing.assert_allclose(metrics.errors, [0.0, -0.10, 0.06], atol=1e-12)
    np.testing.assert_allclose(metrics.abs_errors, [0.0, 0.10, 0.06], atol=1e-12)
    assert metrics.iou == pytest.approx(0.4)


def test_box_shifted_along_its_length_by_half():
    shift = 0.15 * np.array([math.cos(TRUE.yaw), math.sin(TRUE.yaw), 0.0])
    metrics = box_metrics(OrientedBox(TRUE.center + shift, TRUE.dims, TRUE.yaw), TRUE)
    np.testing.assert_allclose(metrics.errors, 0.0, atol=1e-12)
    assert metrics.iou == pytest.approx(0.5 / 1.5)


def test_box_given_width_first_is_the_same_box():
    swapped = OrientedBox(TRUE.center, [0.20, 0.30, 0.12], TRUE.yaw + math.pi / 2)
    metrics = box_metrics(swapped, TRUE)
    np.testing.assert_allclose(metrics.estimated_dims, [0.30, 0.20, 0.12])
    assert metrics.iou == pytest.approx(1.0)


def test_missing_estimate_gives_nan_errors_and_zero_iou():
    metrics = box_metrics(None, TRUE)
    assert not metrics.found
    assert metrics.iou == 0.0
    assert np.all(np.isnan(metrics.estimated_dims))
    assert np.all(np.isnan(metrics.errors)) and np.all(np.isnan(metrics.abs_errors))
    np.testing.assert_allclose(metrics.true_dims, TRUE.dims)


def test_true_box_of_a_yawed_box_mesh_on_a_raised_table():
    table = 0.75
    mesh = trimesh.creation.box(extents=[0.30, 0.20, 0.12])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.4, [0, 0, 1]))
    mesh.apply_translation([0.5, 0.2, table + 0.06])
    box = true_box(mesh.vertices, table)
    np.testing.assert_allclose(box.dims, [0.30, 0.20, 0.12], atol=1e-9)
    np.testing.assert_allclose(box.center, [0.5, 0.2, table + 0.06], atol=1e-9)
    assert box.yaw == pytest.approx(0.4)


# ---------------------------------------------------------------- coverage

# The unit square z = 0, sampled at the centres of a 20 x 20 grid (every 0.05, first at 0.025),
# and 0.1 cells centred on z = 0 covering exactly its half x < 0.5.
GRID = (np.arange(20) + 0.5) / 20
SQUARE = np.array([[x, y, 0.0] for x in GRID for y in GRID])
HALF_CELLS = np.array(
    [[x, y, 0.0] for x in np.arange(0.05, 0.5, 0.1) for y in np.arange(0.05, 1, 0.1)]
)


def test_cells_over_half_the_square_cover_half_of_it():
    # Columns x > 0.5 lie x - 0.5 = 0.025, 0.075, ... from the cells' boxes: 1 cm takes none of
    # them, 3 cm the first column and 8 cm the first two.
    got = surface_coverage(SQUARE, HALF_CELLS, 0.1, thresholds=(0.0, 0.01, 0.03, 0.08))
    assert got == {0.0: 0.5, 0.01: 0.5, 0.03: 11 / 20, 0.08: 12 / 20}


def test_distance_is_to_the_cell_box_not_the_centre_ball():
    # A ball of radius threshold + half diagonal around the centres would take the x = 0.525
    # column at 1 cm (its nearest centre is sqrt(0.075^2 + 0.025^2) = 0.079 <= 0.0966 away);
    # the box distance, 0.025, does not.
    assert np.hypot(0.075, 0.025) <= 0.01 + math.sqrt(3) * 0.05
    assert surface_coverage(SQUARE, HALF_CELLS, 0.1, thresholds=(0.01,))[0.01] == 0.5


def test_distance_past_a_cube_corner_is_euclidean():
    # Cube of half-edge 0.01 at the origin; the sample lies 0.01 past its corner on each axis,
    # so 0.01 * sqrt(3) = 0.0173 from it (a per-axis test would say 0.01).
    sample = np.array([[0.02, 0.02, 0.02]])
    got = surface_coverage(sample, np.zeros((1, 3)), 0.02, thresholds=(0.017, 0.018))
    assert got == {0.017: 0.0, 0.018: 1.0}


def test_a_face_on_cell_boundaries_is_inside_its_cells():
    # The top of a 0.12 m box at z = 0.12 lies on the faces between cell layers; rounding must
    # not push it outside the cells it bounds, even at threshold 0.
    top = np.column_stack([SQUARE[:, :2] * 0.3, np.full(len(SQUARE), 0.12)])
    keys = np.unique(np.floor(top / 0.01), axis=0)
    assert surface_coverage(top, (keys + 0.5) * 0.01, 0.01, thresholds=(0.0,)) == {0.0: 1.0}


def test_no_cells_cover_nothing_and_cells_everywhere_cover_everything():
    assert surface_coverage(SQUARE, np.zeros((0, 3)), 0.1) == {0.01: 0.0, 0.02: 0.0}
    all_cells = np.array(
        [[x, y, 0.0] for x in np.arange(0.05, 1, 0.1) for y in np.arange(0.05, 1, 0.1)]
    )
    assert surface_coverage(SQUARE, all_cells, 0.1) == {0.01: 1.0, 0.02: 1.0}


def brute_force_coverage(samples, centers, cell_size, threshold):
    """Every sample against every cell: clamp the sample into the cube, measure to that point."""
    half = cell_size / 2
    nearest = np.clip(samples[:, None, :], centers[None] - half, centers[None] + half)
    distance = np.linalg.norm(samples[:, None, :] - nearest, axis=2).min(axis=1)
    return float(np.mean(distance <= threshold))


@pytest.mark.parametrize("cell_size", [0.0, 0.01, 0.025])
def test_coverage_matches_brute_force_on_random_data(cell_size):
    rng = np.random.default_rng(7)
    thresholds = (0.0, 0.005, 0.01, 0.02)
    for _ in range(5):
        samples = rng.uniform(0.0, 0.2, size=(400, 3))
        centers = rng.uniform(0.0, 0.2, size=(int(rng.integers(1, 150)), 3))
        got = surface_coverage(samples, centers, cell_size, thresholds)
        for t in thresholds:
            assert got[t] == brute_force_coverage(samples, centers, cell_size, t)


def test_coverage_grows_with_threshold_and_with_cells():
    rng = np.random.default_rng(3)
    samples = rng.uniform(0.0, 0.3, size=(500, 3))
    cells = rng.uniform(0.0, 0.3, size=(80, 3))
    thresholds = (0.0, 0.01, 0.02, 0.04)
    fewer = surface_coverage(samples, cells[:40], 0.01, thresholds)
    more = surface_coverage(samples, cells, 0.01, thresholds)
    assert list(more.values()) == sorted(more.values())
    assert all(fewer[t] <= more[t] for t in thresholds)
    assert more[0.04] > more[0.0]


def test_coverage_rejects_bad_input():
    with pytest.raises(ValueError):
        surface_coverage(np.zeros((0, 3)), HALF_CELLS, 0.1)
    with pytest.raises(ValueError):
        surface_coverage(SQUARE, HALF_CELLS, -0.1)
    with pytest.raises(ValueError):
        surface_coverage(SQUARE, HALF_CELLS, 0.1, thresholds=(-0.01,))
    with pytest.raises(ValueError):
        surface_coverage(SQUARE[:, :2], HALF_CELLS, 0.1)


# ---------------------------------------------------------------- curve, useless poses, AUC


def test_coverage_curve_is_the_coverage_after_each_pose():
    # Pose 0 sees the left half, pose 1 adds nothing, pose 2 loses the object, pose 3 sees all.
    all_cells = np.array(
        [[x, y, 0.0] for x in np.arange(0.05, 1, 0.1) for y in np.arange(0.05, 1, 0.1)]
    )
    poses = [HALF_CELLS, HALF_CELLS, np.zeros((0, 3)), all_cells]
    curves = coverage_curve(SQUARE, poses, 0.1, thresholds=(0.01, 0.03))
    np.testing.assert_array_equal(curves[0.01], [0.5, 0.5, 0.0, 1.0])
    np.testing.assert_array_equal(curves[0.03], [0.55, 0.55, 0.0, 1.0])
    assert useless_poses(curves[0.01]) == [1, 2]


def test_useless_poses_of_the_hand_made_curve():
    curve = np.array([0.1, 0.3, 0.3, 0.25, 0.5])
    assert useless_poses(curve) == [2, 3]
    assert n_useless_poses(curve) == 2


def test_first_pose_is_useless_only_if_it_covers_nothing():
    assert useless_poses([0.0, 0.2]) == [0]
    assert useless_poses([0.2, 0.2]) == [1]
    assert useless_poses([]) == []


def test_useless_poses_with_a_minimum_gain():
    assert useless_poses([0.1, 0.105, 0.3, 0.305], eps=0.01) == [1, 3]
    with pytest.raises(ValueError):
        useless_poses([0.1], eps=-0.01)


def test_auc_is_the_mean_coverage_over_the_poses():
    curve = [0.1, 0.3, 0.3, 0.25, 0.5]
    assert coverage_auc(curve) == pytest.approx(1.45 / 5)
    # A budget of 7 holds the final 0.5 for two more poses; a budget of 3 cuts the curve.
    assert coverage_auc(curve, budget=7) == pytest.approx(2.45 / 7)
    assert coverage_auc(curve, budget=3) == pytest.approx(0.7 / 3)
    assert coverage_auc([1.0]) == 1.0
    assert coverage_auc([]) == 0.0
    assert coverage_auc([], budget=4) == 0.0
    with pytest.raises(ValueError):
        coverage_auc(curve, budget=0)


# ---------------------------------------------------------------- episode


def plain_types_only(value) -> bool:
    if isinstance(value, dict):
        return all(isinstance(k, str) and plain_types_only(v) for k, v in value.items())
    if isinstance(value, list):
        return all(plain_types_only(v) for v in value)
    return value is None or type(value) in (bool, int, float, str)


def test_episode_metrics_gathers_everything():
    poses = [HALF_CELLS, HALF_CELLS, HALF_CELLS[:10]]
    metrics = episode_metrics(
        scaled(TRUE, (1.1, 1.0, 1.0)), TRUE, SQUARE, poses, 0.1, thresholds=(0.01, 0.03)
    )
    assert metrics.n_poses == 3
    assert metrics.useless == [1, 2]
    assert metrics.n_useless_poses == 2
    # The last pose keeps the first cell column, x < 0.1: 2 sample columns, 3 within 3 cm.
    assert metrics.coverage == {0.01: pytest.approx(0.1), 0.03: pytest.approx(0.15)}
    assert metrics.auc[0.01] == pytest.approx((0.5 + 0.5 + 0.1) / 3)
    assert metrics.box.iou == pytest.approx(1 / 1.1)

    record = json.loads(json.dumps(metrics.to_dict(), allow_nan=False))
    assert plain_types_only(metrics.to_dict())
    assert record["n_poses"] == 3 and record["n_useless_poses"] == 2
    assert record["useless_poses"] == [1, 2]
    assert record["coverage_curve"]["0.03"] == pytest.approx([0.55, 0.55, 0.15])
    assert record["iou"] == pytest.approx(1 / 1.1)
    assert record["box_found"] is True


def test_episode_without_estimate_or_poses_exports_nan_as_none():
    metrics = episode_metrics(None, TRUE, SQUARE, [], 0.1)
    assert metrics.n_poses == 0 and metrics.n_useless_poses == 0
    assert metrics.coverage == {0.01: 0.0, 0.02: 0.0}
    record = metrics.to_dict()
    assert plain_types_only(record)
    json.dumps(record, allow_nan=False)
    assert record["estimated_dims"] == [None, None, None]
    assert record["dim_errors"] == [None, None, None]
    assert record["iou"] == 0.0 and record["box_found"] is False
    assert record["coverage_curve"] == {"0.01": [], "0.02": []}


def test_episode_primary_threshold_must_be_reported():
    with pytest.raises(ValueError):
        episode_metrics(None, TRUE, SQUARE, [HALF_CELLS], 0.1, thresholds=(0.02,))


def test_poses_to_accuracy_is_the_first_pose_after_which_the_box_stays_within():
    mm = 0.001
    errors = np.array([[np.nan] * 3, [9, 1, 1], [4, 1, 1], [6, 0, 0], [2, -3, 1], [1, 1, -4]])
    assert poses_to_accuracy(errors * mm, 5 * mm) == 5  # pose 4 (6 mm) breaks the run
    assert poses_to_accuracy(errors * mm, 10 * mm) == 2  # NaN (no estimate) counts as outside
    assert poses_to_accuracy(errors[:4] * mm, 5 * mm) is None  # outside at the end
    assert poses_to_accuracy(np.zeros((0, 3)), 5 * mm) is None
    # An error of exactly the tolerance, as floats give it (0.30 m for 0.29 m) is within.
    assert 0.30 - 0.29 > 0.01
    assert poses_to_accuracy(np.array([[0.30 - 0.29, 0.0, 0.0]]), 0.01) == 1
