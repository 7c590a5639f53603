"""The numeric core of the simulated VL53L8CX: zone reduction, noise, status, zone order."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from lrnbv_drake.core.sensing.sensor import (
    STATUS_NO_TARGET,
    STATUS_VALID,
    NoiseModel,
    SensorModelParams,
    ToFFrame,
    ZoneGeometry,
    cluster_depths,
    frame_rng,
    zone_readings,
)

RES, K = 8, 8
NOISELESS = SensorModelParams(noise=NoiseModel(sigma0_mm=0.0, k=0.0))
FLIPS = list(itertools.product([False, True], repeat=3))  # (flip_x, flip_y, transpose)


def _scene(depth_m: float) -> np.ndarray:
    """Every sub-sample of every zone at `depth_m`."""
    return np.full((RES, RES, K, K), depth_m)


def test_noise_model_hand_values() -> None:
    noise = NoiseModel(sigma0_mm=5.0, k=0.015)
    # max(5, 0.015 * d): the floor below 333 mm, 1.5 % above.
    np.testing.assert_allclose(noise.sigma_mm([200.0, 500.0, 1000.0]), [5.0, 7.5, 15.0])
    with pytest.raises(ValueError):
        NoiseModel(sigma0_mm=-1.0)


def test_flat_wall_without_noise_is_exact() -> None:
    frame = zone_readings(_scene(0.5), NOISELESS, frame_rng(0, 1))
    np.testing.assert_array_equal(frame.distance_mm, 500)
    np.testing.assert_array_equal(frame.status, STATUS_VALID)
    np.testing.assert_array_equal(frame.sigma_mm, 0)


def test_flat_wall_with_noise_stays_within_sigma() -> None:
    params = SensorModelParams()
    frame = zone_readings(_scene(0.5), params, frame_rng(0, 1), sequence=1, timestamp_us=42)
    # sigma(500 mm) = max(5, 7.5) = 7.5 mm, reported rounded.
    np.testing.assert_array_equal(frame.sigma_mm, 8)
    np.testing.assert_array_equal(frame.status, STATUS_VALID)
    assert np.all(np.abs(frame.distance_mm.astype(float) - 500) <= 4 * 7.5)
    # Mean of 64 readings: standard error 7.5 / 8 ~ 0.94 mm.
    assert abs(frame.distance_mm.mean() - 500) < 4.0
    assert np.unique(frame.distance_mm).size > 1  # the noise is there
    assert (frame.sequence, frame.timestamp_us) == (1, 42)


def test_noise_has_the_model_sigma() -> None:
    params = SensorModelParams()
    readings = np.stack(
        [zone_readings(_scene(1.0), params, frame_rng(7, n)).distance_mm for n in range(200)]
    ).astype(float)
    # sigma(1000 mm) = 15 mm; 12 800 readings pin the sample std to about +-1 %.
    assert readings.std() == pytest.approx(15.0, rel=0.05)
    assert readings.mean() == pytest.approx(1000.0, abs=1.0)


def test_edge_across_a_zone_reports_the_nearer_surface() -> None:
    sub = _scene(0.5)
    sub[2, 3, :, :4] = 0.30  # left half of zone (2, 3) on a box face at 0.30 m
    frame = zone_readings(sub, NOISELESS, frame_rng(0, 1))
    assert frame.distance_mm[2, 3] == 300  # the nearer surface, not the 400 mm average
    others = np.ones((RES, RES), bool)
    others[2, 3] = False
    np.testing.assert_array_equal(frame.distance_mm[others], 500)

    noisy = zone_readings(sub, SensorModelParams(), frame_rng(0, 1))
    assert abs(int(noisy.distance_mm[2, 3]) - 300) <= 4 * 5  # sigma(300 mm) = 5 mm
    assert noisy.sigma_mm[2, 3] == 5


@pytest.mark.parametrize(
    ("near_samples", "expected_mm"),
    [
        (8, 500),  # one sub-column: 12.5 % < 25 %, the dominant wall wins
        (15, 500),  # just under the share
        (16, 200),  # exactly 25 %: reported
    ],
)
def test_near_sliver_needs_the_minimum_share(near_samples: int, expected_mm: int) -> None:
    sub = _scene(0.5)
    sub[4, 4].reshape(-1)[:near_samples] = 0.2
    frame = zone_readings(sub, NOISELESS, frame_rng(0, 1))
    assert frame.distance_mm[4, 4] == expected_mm
    assert frame.status[4, 4] == STATUS_VALID


def test_cluster_gap_joins_close_depths_and_splits_far_ones() -> None:
    joined = _scene(0.5)
    joined[0, 0, :, 4:] = 0.52  # 20 mm apart: one surface, median between the two halves
    split = _scene(0.5)
    split[0, 0, :, 4:] = 0.53  # 30 mm apart: the nearer half is reported
    assert cluster_depths(joined, NOISELESS)[0, 0] == pytest.approx(0.51)
    assert cluster_depths(split, NOISELESS)[0, 0] == pytest.approx(0.50)


def test_oblique_plane_stays_one_cluster_at_range() -> None:
    # A plane 60 degrees from normal at 1.5 m: neighbouring sub-columns differ by
    # 1.5 m * tan(60) * 0.70 deg ~ 32 mm, more than the 25 mm gap, but the incidence term
    # (70 degrees) widens the gap to ~50 mm, so the zone is one cluster, not eight slivers.
    pitch = np.deg2rad(45 / 8 / K)
    step = 1.5 * np.tan(np.deg2rad(60)) * pitch
    ramp = 1.5 + step * (np.arange(K) - (K - 1) / 2)
    sub = np.broadcast_to(ramp, (RES, RES, K, K)).copy()
    depth = cluster_depths(sub, NOISELESS)
    np.testing.assert_allclose(depth, 1.5)

    no_widening = SensorModelParams(max_incidence_deg=0.0, noise=NoiseModel(0.0, 0.0))
    assert np.all(np.isnan(cluster_depths(sub, no_widening)))


@pytest.mark.parametrize("depth_m", [np.inf, np.nan, 0.0, -1.0, 4.5, 0.01])
def test_nothing_in_range_is_no_target(depth_m: float) -> None:
    frame = zone_readings(_scene(depth_m), SensorModelParams(), frame_rng(0, 1))
    np.testing.assert_array_equal(frame.status, STATUS_NO_TARGET)
    np.testing.assert_array_equal(frame.distance_mm, 0)
    np.testing.assert_array_equal(frame.sigma_mm, 0)
    assert not frame.valid.any()


def test_range_limits_are_inclusive() -> None:
    sub = _scene(0.5)
    sub[0, 0] = 0.020
    sub[0, 1] = 4.000
    sub[0, 2] = 0.0199
    sub[0, 3] = 4.0001
    frame = zone_readings(sub, NOISELESS, frame_rng(0, 1))
    np.testing.assert_array_equal(frame.status[0, :4], [5, 5, 255, 255])
    np.testing.assert_array_equal(frame.distance_mm[0, :4], [20, 4000, 0, 0])


def test_mostly_no_return_is_no_target() -> None:
    sub = np.full((RES, RES, K, K), np.inf)
    sub[..., 0, :3] = 0.5  # 3 of 64 samples hit: far below the share
    frame = zone_readings(sub, NOISELESS, frame_rng(0, 1))
    np.testing.assert_array_equal(frame.status, STATUS_NO_TARGET)


def test_reduction_ignores_sample_order() -> None:
    rng = np.random.default_rng(3)
    sub = rng.choice([0.3, 0.31, 0.45, 0.8, np.inf], size=(RES, RES, K, K))
    flat = sub.reshape(RES, RES, K * K)
    shuffled = rng.permuted(flat, axis=-1).reshape(sub.shape)
    np.testing.assert_array_equal(
        cluster_depths(sub, NOISELESS), cluster_depths(shuffled, NOISELESS)
    )


def test_same_seed_and_sequence_give_the_same_frame() -> None:
    params = SensorModelParams()
    a = zone_readings(_scene(0.7), params, frame_rng(3, 11), sequence=11)
    np.random.default_rng(99).standard_normal(1000)  # unrelated draws change nothing
    b = zone_readings(_scene(0.7), params, frame_rng(3, 11), sequence=11)
    c = zone_readings(_scene(0.7), params, frame_rng(3, 12), sequence=12)
    d = zone_readings(_scene(0.7), params, frame_rng(4, 11), sequence=11)
    np.testing.assert_array_equal(a.distance_mm, b.distance_mm)
    assert not np.array_equal(a.distance_mm, c.distance_mm)
    assert not np.array_equal(a.distance_mm, d.distance_mm)


@pytest.mark.parametrize(("flip_x", "flip_y", "transpose"), FLIPS)
def test_raw_order_round_trips(flip_x: bool, flip_y: bool, transpose: bool) -> None:
    geometry = ZoneGeometry(flip_x=flip_x, flip_y=flip_y, transpose=transpose)
    row_major = np.arange(RES * RES).reshape(RES, RES)
    np.testing.assert_array_equal(geometry.to_row_major(geometry.to_raw(row_major)), row_major)

    # A scene whose every zone has its own depth comes out in raw order.
    depth_mm = 300 + 10 * row_major
    sub = np.broadcast_to(depth_mm[..., None, None] / 1000.0, (RES, RES, K, K))
    params = SensorModelParams(geometry=geometry, noise=NoiseModel(0.0, 0.0))
    frame = zone_readings(sub, params, frame_rng(0, 1))
    np.testing.assert_array_equal(frame.distance_mm, geometry.to_raw(depth_mm))
    np.testing.assert_array_equal(geometry.to_row_major(frame.distance_mm), depth_mm)


def test_flipped_board_reports_zone_zero_at_the_flipped_corner() -> None:
    sub = _scene(0.5)
    sub[0, 0] = 0.3  # row-major zone (0, 0): -x, -y corner
    params = SensorModelParams(geometry=ZoneGeometry(flip_x=True), noise=NoiseModel(0.0, 0.0))
    frame = zone_readings(sub, params, frame_rng(0, 1))
    assert frame.distance_mm[0, RES - 1] == 300  # raw column 7 runs towards -x
    assert frame.distance_mm[0, 0] == 500


def test_wall_frame_points_are_perpendicular() -> None:
    geometry = ZoneGeometry()
    frame = ToFFrame(
        distance_mm=np.full((RES, RES), 500),
        status=np.full((RES, RES), STATUS_VALID),
        sigma_mm=np.zeros((RES, RES)),
    )
    points, valid = geometry.points(frame)
    assert valid.all()
    pts = points.reshape(RES, RES, 3)
    np.testing.assert_allclose(pts[..., 2], 0.5)  # z = d in every zone
    # Column 7's centre is 22.5 - 5.625 / 2 = 19.6875 degrees right of the axis; row 0's is
    # the same angle up (-y).
    np.testing.assert_allclose(pts[:, 7, 0], 0.5 * np.tan(np.deg2rad(19.6875)))
    np.testing.assert_allclose(pts[0, :, 1], -0.5 * np.tan(np.deg2rad(19.6875)))
    np.testing.assert_allclose(pts[:, 4, 0], 0.5 * np.tan(np.deg2rad(5.625 / 2)))


def test_rejects_a_grid_of_the_wrong_shape() -> None:
    with pytest.raises(ValueError, match="expected"):
        zone_readings(np.full((RES, RES, 4, 4), 0.5), SensorModelParams(), frame_rng(0, 1))


def test_rejects_inconsistent_parameters() -> None:
    with pytest.raises(ValueError):
        SensorModelParams(min_share=0.0)
    with pytest.raises(ValueError):
        SensorModelParams(min_range_mm=5000)
    with pytest.raises(ValueError):
        SensorModelParams(subsamples=0)
