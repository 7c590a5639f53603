"""Box geometry: hand-worked volumes and IoUs, a Monte-Carlo check of the oriented IoU, and the
minimum-area fit against shapely's own oriented envelope."""

import math

import numpy as np
import pytest
import shapely
import trimesh

from lrnbv_drake.core.boxes import AlignedBox, OrientedBox

UNIT = OrientedBox(center=[0.0, 0.0, 0.0], dims=[1.0, 1.0, 1.0], yaw=0.0)


def yaw_error(a: float, b: float) -> float:
    """Distance between two yaws modulo the half-turn symmetry of a box."""
    d = (a - b) % math.pi
    return min(d, math.pi - d)


def random_box(rng: np.random.Generator) -> OrientedBox:
    return OrientedBox(
        center=rng.uniform(-0.3, 0.3, 3),
        dims=rng.uniform(0.2, 1.0, 3),
        yaw=rng.uniform(-math.pi, math.pi),
    )


# ---------------------------------------------------------------- AlignedBox


def test_aligned_box_basic_quantities():
    box = AlignedBox([0.0, -1.0, 2.0], [2.0, 1.0, 5.0])
    np.testing.assert_allclose(box.center, [1.0, 0.0, 3.5])
    np.testing.assert_allclose(box.size, [2.0, 2.0, 3.0])
    assert box.volume == pytest.approx(12.0)
    corners = box.corners()
    assert corners.shape == (8, 3)
    assert len({tuple(c) for c in corners}) == 8
    np.testing.assert_allclose(corners.min(axis=0), box.lower)
    np.testing.assert_allclose(corners.max(axis=0), box.upper)


def test_aligned_box_rejects_inverted_bounds():
    with pytest.raises(ValueError):
        AlignedBox([0.0, 0.0, 1.0], [1.0, 1.0, 0.0])


def test_aligned_box_contains_boundary_and_tolerance():
    box = AlignedBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    pts = np.array([[0.5, 0.5, 0.5], [1.0, 1.0, 1.0], [1.05, 0.5, 0.5], [-0.2, 0.5, 0.5]])
    assert box.contains(pts).tolist() == [True, True, False, False]
    assert box.contains(pts, tol=0.1).tolist() == [True, True, True, False]
    assert box.contains(np.array([0.5, 0.5, 0.5])).tolist() == [True]


def test_aligned_box_inflate_grows_and_collapses():
    box = AlignedBox([0.0, 0.0, 0.0], [1.0, 2.0, 3.0])
    grown = box.inflate(0.5)
    np.testing.assert_allclose(grown.lower, [-0.5, -0.5, -0.5])
    np.testing.assert_allclose(grown.upper, [1.5, 2.5, 3.5])
    shrunk = box.inflate(-0.75)  # x collapses (1 - 1.5 < 0), y and z shrink
    np.testing.assert_allclose(shrunk.lower, [0.5, 0.75, 0.75])
    np.testing.assert_allclose(shrunk.upper, [0.5, 1.25, 2.25])
    per_axis = box.inflate(np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(per_axis.size, [1.0, 4.0, 3.0])


def test_aligned_box_clip():
    box = AlignedBox([0.0, 0.0, 0.0], [2.0, 2.0, 2.0])
    clipped = box.clip(AlignedBox([1.0, -1.0, 0.5], [3.0, 1.0, 1.5]))
    np.testing.assert_allclose(clipped.lower, [1.0, 0.0, 0.5])
    np.testing.assert_allclose(clipped.upper, [2.0, 1.0, 1.5])
    touching = box.clip(AlignedBox([2.0, 0.0, 0.0], [3.0, 1.0, 1.0]))
    assert touching is not None and touching.volume == 0.0
    assert box.clip(AlignedBox([2.5, 0.0, 0.0], [3.0, 1.0, 1.0])) is None


def test_aligned_box_intersection_and_iou_hand_worked():
    a = AlignedBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    b = AlignedBox([0.5, 0.0, 0.0], [1.5, 1.0, 1.0])
    assert a.intersection_volume(b) == pytest.approx(0.5)
    assert a.iou(b) == pytest.approx(1 / 3)
    assert a.iou(a) == pytest.approx(1.0)
    # Corner overlap: 0.5 x 0.5 x 0.5 = 1/8, union 2 - 1/8.
    c = AlignedBox([0.5, 0.5, 0.5], [1.5, 1.5, 1.5])
    assert a.iou(c) == pytest.approx((1 / 8) / (2 - 1 / 8))
    assert a.iou(AlignedBox([3.0, 0.0, 0.0], [4.0, 1.0, 1.0])) == 0.0
    flat = AlignedBox([0.0, 0.0, 0.0], [1.0, 1.0, 0.0])
    assert flat.iou(flat) == 0.0


# ---------------------------------------------------------------- OrientedBox: representation


def test_oriented_box_canonical_form():
    swapped = OrientedBox([0.0, 0.0, 0.0], [1.0, 2.0, 3.0], yaw=0.0)
    np.testing.assert_allclose(swapped.dims, [2.0, 1.0, 3.0])
    assert swapped.yaw == pytest.approx(-math.pi / 2)  # +pi/2 wraps to the closed end
    assert OrientedBox([0, 0, 0], [2, 1, 1], yaw=3 * math.pi / 4).yaw == pytest.approx(-math.pi / 4)
    assert OrientedBox([0, 0, 0], [2, 1, 1], yaw=-math.pi / 2).yaw == pytest.approx(-math.pi / 2)
    square = OrientedBox([0, 0, 0], [1, 1, 2], yaw=math.pi / 3)
    assert square.yaw == pytest.approx(math.pi / 3 - math.pi / 2)
    # Swapping and the half turn describe the same box.
    np.testing.assert_allclose(
        np.sort(swapped.corners(), axis=0),
        np.sort(OrientedBox([0, 0, 0], [2, 1, 3], yaw=math.pi / 2).corners(), axis=0),
        atol=1e-12,
    )
    with pytest.raises(ValueError):
        OrientedBox([0, 0, 0], [1, -1, 1])
    # A rounding step below -pi/2 stays in [-pi/2, pi/2): the float modulo rounds it up to +pi/2.
    below = OrientedBox([0, 0, 0], [2, 1, 1], yaw=math.nextafter(-math.pi / 2, -math.inf))
    assert -math.pi / 2 <= below.yaw < math.pi / 2


def test_oriented_box_corners_footprint_and_aligned():
    box = OrientedBox([1.0, 2.0, 0.5], [2.0, 1.0, 1.0], yaw=math.pi / 2)
    # Length along world y: x spans 1 +- 0.5, y spans 2 +- 1.
    aligned = box.aligned()
    np.testing.assert_allclose(aligned.lower, [0.5, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(aligned.upper, [1.5, 3.0, 1.0], atol=1e-12)
    assert box.footprint().area == pytest.approx(2.0)
    assert box.footprint().exterior.is_ccw
    corners = box.corners()
    np.testing.assert_allclose(corners[:4, 2], 0.0)
    np.testing.assert_allclose(corners[4:, 2], 1.0)
    assert box.contains(corners, tol=1e-12).all()


def test_oriented_box_aligned_is_tight_for_any_yaw():
    rng = np.random.default_rng(3)
    for _ in range(20):
        box = random_box(rng)
        reference = AlignedBox.from_points(box.corners())
        aligned = box.aligned()
        np.testing.assert_allclose(aligned.lower, reference.lower, atol=1e-12)
        np.testing.assert_allclose(aligned.upper, reference.upper, atol=1e-12)


def test_oriented_box_contains():
    box = OrientedBox([0.0, 0.0, 0.5], [2.0, 1.0, 1.0], yaw=math.pi / 4)
    d = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0])  # length axis
    n = np.array([-d[1], d[0], 0.0])  # width axis
    base = np.array([0.0, 0.0, 0.5])
    pts = np.array([base, base + 0.99 * d, base + 1.01 * d, base + 0.49 * n, base + 0.51 * n,
                    [0.0, 0.0, 1.01], [0.7, 0.0, 0.5]])  # fmt: skip
    # (0.7, 0, 0.5): along the length 0.495, across 0.495 -> inside the half-width 0.5.
    assert box.contains(pts).tolist() == [True, True, False, True, False, False, True]


# ---------------------------------------------------------------- OrientedBox: IoU


def test_iou_identical_is_one():
    assert UNIT.iou(UNIT) == pytest.approx(1.0)
    box = OrientedBox([0.3, -0.2, 1.0], [0.5, 0.2, 0.3], yaw=0.7)
    assert box.iou(box) == pytest.approx(1.0)
    half_turn = OrientedBox(box.center, box.dims, yaw=box.yaw + math.pi)
    assert box.iou(half_turn) == pytest.approx(1.0)


def test_iou_shift_by_half_is_one_third():
    for axis in range(3):
        shift = np.zeros(3)
        shift[axis] = 0.5
        moved = OrientedBox(shift, [1.0, 1.0, 1.0])
        assert UNIT.iou(moved) == pytest.approx(1 / 3)


def test_iou_45_degrees_hand_worked():
    # Unit square and its 45-degree turn about the centre overlap in a regular octagon of
    # inradius 1/2: area 8 * tan(pi/8) / 4 = 2 (sqrt 2 - 1). IoU = that / (2 - that) = 1/sqrt 2.
    rotated = OrientedBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], yaw=math.pi / 4)
    octagon = 2 * (math.sqrt(2) - 1)
    assert UNIT.footprint().intersection(rotated.footprint()).area == pytest.approx(octagon)
    assert UNIT.iou(rotated) == pytest.approx(1 / math.sqrt(2))
    # Also raised by half its height: the prism halves, the union is 2 - octagon/2.
    raised = OrientedBox([0.0, 0.0, 0.5], [1.0, 1.0, 1.0], yaw=math.pi / 4)
    expected = (math.sqrt(2) - 1) / (3 - math.sqrt(2))
    assert UNIT.iou(raised) == pytest.approx(expected)
    assert raised.iou(UNIT) == pytest.approx(expected)


def test_iou_of_boxes_sharing_edges_up_to_rounding_is_their_overlap():
    """An estimate with the truth's yaw and three of its footprint's edges (a case GEOS once
    intersected to a point, IoU 0): the overlap is the smaller box, 0.2712 / 0.2912 of the
    larger in W and 0.0859 / 0.0909 in H."""
    yaw = 1.3162901654449568
    true = OrientedBox([0.5, 0.0, 0.04295461829346069],
                       [0.29995075707129953, 0.2711787456213522, 0.08590923658692139], yaw)
    estimate = OrientedBox([0.4903221225377962, 0.002517675083597685, 0.045454618293460695],
                           [0.29995075707129953, 0.2911787456213522, 0.09090923658692139], yaw)
    assert estimate.iou(true) == pytest.approx(true.volume / estimate.volume, abs=1e-9)
    # And every box is its own corners' box, IoU 1 (27 of 5000 seeded boxes gave 0 before).
    rng = np.random.default_rng(0)
    for _ in range(5000):
        box = OrientedBox(rng.uniform(-0.1, 0.1, 3), rng.uniform(0.02, 0.3, 3),
                          rng.uniform(-4, 4))
        assert OrientedBox.from_points(box.corners()).iou(box) == pytest.approx(1.0, abs=1e-6)


def test_iou_disjoint_and_touching_are_zero():
    assert UNIT.iou(OrientedBox([3.0, 0.0, 0.0], [1.0, 1.0, 1.0], yaw=0.3)) == 0.0
    assert UNIT.iou(OrientedBox([0.0, 0.0, 2.0], [1.0, 1.0, 1.0])) == 0.0  # stacked apart
    assert UNIT.iou(OrientedBox([0.0, 0.0, 1.0], [1.0, 1.0, 1.0])) == 0.0  # face contact
    # Footprints overlap but z ranges do not.
    assert UNIT.iou(OrientedBox([0.2, 0.0, 1.5], [1.0, 1.0, 1.0], yaw=0.4)) == 0.0


def test_iou_matches_aligned_iou_at_zero_yaw():
    rng = np.random.default_rng(11)
    for _ in range(20):
        a = OrientedBox(rng.uniform(-0.3, 0.3, 3), rng.uniform(0.2, 1.0, 3))
        b = OrientedBox(rng.uniform(-0.3, 0.3, 3), rng.uniform(0.2, 1.0, 3))
        assert a.iou(b) == pytest.approx(a.aligned().iou(b.aligned()), abs=1e-12)


def test_iou_matches_monte_carlo():
    rng = np.random.default_rng(7)
    n_samples = 150_000
    for _ in range(6):
        a, b = random_box(rng), random_box(rng)
        b = OrientedBox(a.center + rng.uniform(-0.2, 0.2, 3), b.dims, b.yaw)  # make them overlap
        bounds = AlignedBox.from_points(np.vstack([a.corners(), b.corners()]))
        samples = rng.uniform(bounds.lower, bounds.upper, size=(n_samples, 3))
        in_a, in_b = a.contains(samples), b.contains(samples)
        estimate = np.count_nonzero(in_a & in_b) / np.count_nonzero(in_a | in_b)
        assert a.iou(b) > 0.05  # the draw must actually test an overlap
        assert a.iou(b) == pytest.approx(estimate, abs=0.01)


# ---------------------------------------------------------------- OrientedBox.from_points


def test_from_points_recovers_rotated_box_from_corners():
    rng = np.random.default_rng(5)
    for _ in range(50):
        truth = random_box(rng)
        fitted = OrientedBox.from_points(truth.corners())
        np.testing.assert_allclose(fitted.dims, truth.dims, atol=1e-9)
        np.testing.assert_allclose(fitted.center, truth.center, atol=1e-9)
        if truth.dims[0] - truth.dims[1] > 1e-6:  # a square has a quarter-turn symmetry too
            assert yaw_error(fitted.yaw, truth.yaw) < 1e-9
        assert fitted.iou(truth) == pytest.approx(1.0)


def test_from_points_known_case():
    # A 0.4 x 0.1 x 0.2 box turned by 30 degrees, its long side the one along +30 deg.
    truth = OrientedBox([0.5, -0.25, 0.1], [0.4, 0.1, 0.2], yaw=math.radians(30))
    fitted = OrientedBox.from_points(truth.corners())
    np.testing.assert_allclose(fitted.dims, [0.4, 0.1, 0.2], atol=1e-12)
    assert fitted.yaw == pytest.approx(math.radians(30))
    # The same shape described with width first (yaw -60 deg) comes back canonical.
    swapped = OrientedBox.from_points(
        OrientedBox([0.5, -0.25, 0.1], [0.1, 0.4, 0.2], yaw=math.radians(-60)).corners()
    )
    assert swapped.yaw == pytest.approx(math.radians(30))


def test_from_points_matches_shapely_oriented_envelope():
    rng = np.random.default_rng(9)
    for _ in range(30):
        pts = rng.normal(size=(int(rng.integers(3, 60)), 3)) * rng.uniform(0.1, 1.0, 3)
        fitted = OrientedBox.from_points(pts)
        envelope = shapely.oriented_envelope(shapely.MultiPoint(pts[:, :2]))
        assert fitted.dims[0] >= fitted.dims[1]
        assert -math.pi / 2 <= fitted.yaw < math.pi / 2
        assert fitted.footprint().area == pytest.approx(envelope.area, rel=1e-9)
        assert fitted.contains(pts, tol=1e-9).all()
        assert fitted.dims[2] == pytest.approx(np.ptp(pts[:, 2]))


def test_from_points_floor_and_degenerate_inputs():
    pts = np.array([[0.0, 0.0, 0.3], [1.0, 0.0, 0.5], [1.0, 0.5, 0.4], [0.0, 0.5, 0.5]])
    on_table = OrientedBox.from_points(pts, floor_z=0.1)
    assert on_table.dims[2] == pytest.approx(0.4)
    assert on_table.center[2] == pytest.approx(0.3)
    with pytest.raises(ValueError):
        OrientedBox.from_points(pts, floor_z=1.0)
    with pytest.raises(ValueError):
        OrientedBox.from_points(np.zeros((0, 3)))
    single = OrientedBox.from_points(np.array([[0.2, 0.3, 0.4]]))
    np.testing.assert_allclose(single.dims, 0.0)
    np.testing.assert_allclose(single.center, [0.2, 0.3, 0.4])
    line = OrientedBox.from_points(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 2.0, 0.0]]))
    np.testing.assert_allclose(line.dims, [2 * math.sqrt(2), 0.0, 0.0], atol=1e-12)
    assert line.yaw == pytest.approx(math.pi / 4)


def test_from_points_on_a_trimesh_ground_truth():
    transform = trimesh.transformations.rotation_matrix(math.radians(-70), [0, 0, 1])
    transform[:3, 3] = [0.1, 0.2, 0.04]
    mesh = trimesh.creation.box(extents=[0.08, 0.2, 0.08], transform=transform)
    fitted = OrientedBox.from_points(mesh.vertices)
    np.testing.assert_allclose(fitted.dims, [0.2, 0.08, 0.08], atol=1e-12)
    np.testing.assert_allclose(fitted.center, [0.1, 0.2, 0.04], atol=1e-12)
    assert yaw_error(fitted.yaw, math.radians(-70 + 90)) < 1e-9  # mesh y is the long side
    assert fitted.volume == pytest.approx(mesh.volume)


def test_footprint_iou_ignores_the_heights():
    # 2 x 1 footprints shifted by 1 along x: 1 m^2 in common of 3 (hand-worked).
    a = OrientedBox([0.0, 0.0, 0.5], [2.0, 1.0, 1.0], 0.0)
    b = OrientedBox([1.0, 0.0, 3.0], [2.0, 1.0, 0.2], 0.0)
    assert a.footprint_iou(b) == pytest.approx(1 / 3)
    assert a.iou(b) == 0.0  # their z ranges do not meet
