"""OccupancyMap against OctoMap: pyoctomap 1.2.2 (liboctomap 1.10.0) as the oracle, OctoMap's
own reference numbers, and hand-worked cases."""

from __future__ import annotations

import copy
import math

import numba
import numpy as np
import pytest
from pyoctomap import OcTree

from lrnbv_drake.core.mapping import KEY_OFFSET, OccupancyMap, OccupancyUpdate, frame_scan, logodds
from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry

RES = 0.01
# Notes 4.6: reference scenarios are 8x8 zone clouds from this origin.
REF_ORIGIN = np.array([0.0012, 0.0031, 0.0047])
ZONE_DIRS = ZoneGeometry().directions().reshape(-1, 3)
HIT, MISS = logodds(0.7), logodds(0.4)
LMIN, LMAX = logodds(0.1192), logodds(0.971)


def octree(scans, res=RES, lazy_eval=True) -> OcTree:
    """pyoctomap tree after insertPointCloud of (origin, points, max_range) scans."""
    tree = OcTree(res)
    for origin, pts, max_range in scans:
        tree.insertPointCloud(np.asarray(pts, float), np.asarray(origin, float),
                              max_range=-1.0 if max_range is None else max_range,
                              lazy_eval=lazy_eval)
    return tree


def our_map(scans, bounds, res=RES) -> OccupancyMap:
    m = OccupancyMap(res, bounds=bounds)
    for origin, pts, max_range in scans:
        m.insert_scan(origin, pts, max_range)
    return m


def assert_same_as_octree(m: OccupancyMap, tree: OcTree, rng: np.random.Generator,
                          whole_tree_inside: bool = True) -> None:
    """Same known cells with identical float32 log-odds, and the same state at random points.

    `tree` must come from lazy insertions (no pruning), so that its leaves are single cells.
    """
    idx, values = m.known_cells()
    assert len(values) > 0
    theirs = np.full(len(values), np.nan, dtype=np.float32)
    for i, c in enumerate(m.cell_centers(idx)):
        node = tree.search(c)
        if node is not None:
            theirs[i] = node.getLogOdds()
    np.testing.assert_array_equal(theirs, values)
    if whole_tree_inside:
        n_theirs = tree.getNumLeafNodes()
    else:  # their leaves in the grid's key range
        lo, hi = m.bounds
        half = m.resolution / 2
        n_theirs = sum(1 for _ in tree.begin_leafs_bbx(lo + half, hi - half))
    assert n_theirs == len(values)
    # A sample of points anywhere in the grid, mostly in unknown cells.
    lo, hi = m.bounds
    pts = rng.uniform(lo, hi, size=(2000, 3))
    np.testing.assert_array_equal(m.classify(pts), tree.getLabels(pts))
    # A block of cells across the grid's lower corner, by slice, against the octree at its
    # cells' centres (outside the grid: unknown).
    lower, shape = m.index_offset - np.array([5, 3, 7]), (40, 35, 45)
    centers = (lower + np.indices(shape).reshape(3, -1).T + 0.5) * m.resolution
    inside = np.all((centers >= lo) & (centers < hi), axis=1)
    assert 0 < inside.sum() < len(inside)
    np.testing.assert_array_equal(m.classify_block(lower, shape).reshape(-1),
                                  np.where(inside, tree.getLabels(centers), -1))


# --- sensor model --------------------------------------------------------------------------------


def test_sensor_model_log_odds_are_octomaps():
    tree = OcTree(RES)
    ours = OccupancyUpdate().log_odds_array()
    theirs = [tree.getProbHitLog(), tree.getProbMissLog(), tree.getClampingThresMinLog(),
              tree.getClampingThresMaxLog(), tree.getOccupancyThresLog()]
    np.testing.assert_array_equal(ours, np.array(theirs, dtype=np.float32))
    np.testing.assert_allclose(ours, [0.8473, -0.4055, -2.0, 3.5110, 0.0], atol=1e-4)


def test_saturation_and_flips_notes_4_1():
    """5 hits -> 3.511 (4 hits 3.389); 5 misses -> -2; 9 misses flip a saturated occupied cell,
    3 hits a saturated free one."""
    m = OccupancyMap(RES, bounds=((-0.1, -0.1, -0.1), (0.2, 0.2, 0.2)))
    origin, target = np.array([0.005, 0.005, 0.005]), np.array([[0.105, 0.005, 0.005]])
    passed = np.array([[0.055, 0.005, 0.005]])  # a cell on the ray, freed by every insertion

    def insert(n):
        for _ in range(n):
            m.insert_scan(origin, target)

    insert(4)
    assert m.log_odds(target)[0] == pytest.approx(3.389, abs=1e-3)
    insert(1)
    assert m.log_odds(target)[0] == LMAX
    assert m.log_odds(passed)[0] == LMIN
    # Now miss the saturated occupied cell 8 times: still occupied; the 9th flips it.
    beyond = np.array([[0.205, 0.005, 0.005]])
    for _ in range(8):
        m.insert_scan(origin, beyond)
    assert m.classify(target)[0] == 1
    m.insert_scan(origin, beyond)
    assert m.classify(target)[0] == 0
    # The passed cell sits at -2: 2 hits leave it free, the 3rd makes it occupied.
    for _ in range(2):
        m.insert_scan(origin, passed)
    assert m.classify(passed)[0] == 0
    m.insert_scan(origin, passed)
    assert m.classify(passed)[0] == 1


def test_one_update_per_scan_and_occupied_wins():
    m = OccupancyMap(RES, bounds=((-0.1, -0.1, -0.1), (0.3, 0.1, 0.1)))
    origin = np.array([0.005, 0.005, 0.005])
    # Two rays along +x: the short one's endpoint is on the long one's path.
    m.insert_scan(origin, [[0.105, 0.005, 0.005], [0.205, 0.005, 0.005]])
    assert m.log_odds([[0.105, 0.005, 0.005]])[0] == HIT  # hit, not hit + miss
    assert m.log_odds([[0.055, 0.005, 0.005]])[0] == MISS  # one miss, not two
    assert m.log_odds([[0.205, 0.005, 0.005]])[0] == HIT
    assert m.counts() == (m.counts().unknown, 19, 2)


def test_scan_stamps_wrap_around():
    """The one-update-per-scan rule keeps holding after the 1-byte scan stamps restart: scans 1
    and 256 free a cell twice each (one miss per scan); the scans between stay clear of it."""
    origin = np.array([0.005, 0.005, 0.005])
    pair = (origin, [[0.105, 0.005, 0.005], [0.205, 0.005, 0.005]], None)
    elsewhere = (np.array([-0.1, -0.1, -0.1]), [[-0.2, -0.2, -0.1]], None)
    scans = [pair] + [elsewhere] * 254 + [pair]
    m = our_map(scans, ((-0.25, -0.25, -0.25), (0.25, 0.25, 0.25)))
    assert m.n_scans == 256
    assert m.log_odds([[0.055, 0.005, 0.005]])[0] == np.float32(MISS + MISS)  # 2 misses
    assert_same_as_octree(m, octree(scans), np.random.default_rng(14))


# --- agreement with pyoctomap --------------------------------------------------------------------


def test_reference_plane_at_half_metre():
    """Notes 4.6: 3908 cells, 64 occupied, 3844 free; three insertions keep the cells."""
    scan = (REF_ORIGIN, REF_ORIGIN + 0.5 * ZONE_DIRS, None)
    bounds = ((-0.3, -0.3, -0.1), (0.3, 0.3, 0.6))
    rng = np.random.default_rng(1)
    m = our_map([scan], bounds)
    assert m.counts()[1:] == (3844, 64)
    assert_same_as_octree(m, octree([scan]), rng)
    m3 = our_map([scan] * 3, bounds)
    assert m3.counts()[1:] == (3844, 64)
    assert_same_as_octree(m3, octree([scan] * 3), rng)


def test_reference_max_range():
    """Notes 4.6: plane at 2 m with maxrange 1 m -> 7860 free, 0 occupied."""
    scan = (REF_ORIGIN, REF_ORIGIN + 2.0 * ZONE_DIRS, 1.0)
    m = our_map([scan], ((-0.6, -0.6, -0.1), (0.6, 0.6, 1.1)))
    assert m.counts()[1:] == (7860, 0)
    assert_same_as_octree(m, octree([scan]), np.random.default_rng(2))


def test_tilted_plane():
    """A plane tilted 30 degrees about x, 0.5 m ahead on the axis, inserted twice."""
    n = np.array([0.0, math.sin(math.radians(30)), math.cos(math.radians(30))])
    t = (0.5 * n[2]) / (ZONE_DIRS @ n)
    scan = (REF_ORIGIN, REF_ORIGIN + t[:, None] * ZONE_DIRS, None)
    m = our_map([scan, scan], ((-0.4, -0.4, -0.1), (0.4, 0.4, 0.8)))
    assert_same_as_octree(m, octree([scan, scan]), np.random.default_rng(3))


def test_random_scans_with_max_range():
    rng = np.random.default_rng(4)
    scans = []
    for i in range(40):
        origin = rng.uniform(-0.3, 0.3, 3)
        pts = origin + rng.normal(scale=0.35, size=(64, 3))
        scans.append((origin, pts, None if i % 3 else 0.4))
    m = our_map(scans, ((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5)))
    assert_same_as_octree(m, octree(scans), rng)


def test_rays_through_cell_boundaries():
    """Origins and end points on cell borders and corners, axis-aligned and diagonal rays: the
    float voxel borders and the tie-break order decide these."""
    rng = np.random.default_rng(5)
    grid_pts = rng.integers(-30, 30, size=(64, 3)) * RES
    scans = [
        (np.zeros(3), grid_pts, None),  # origin on a corner, ends on corners
        (np.array([0.05, 0.0, 0.0]), grid_pts[:, [1, 2, 0]], None),
        (np.array([0.005, 0.005, 0.005]), [[0.3, 0.3, 0.3], [-0.2, 0.2, 0.0], [0.0, 0.0, 0.25],
                                           [0.105, -0.3, 0.005]], None),
        (np.array([0.0, 0.0, 0.0]), np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1], [-1, -1, -1]]) * 0.2,
         0.15),
    ]
    m = our_map(scans, ((-0.4, -0.4, -0.4), (0.4, 0.4, 0.4)))
    assert_same_as_octree(m, octree(scans), rng)


def test_rays_leaving_the_grid():
    """Inside the grid the map is OctoMap's map; free cells and end points outside are dropped;
    an origin outside the grid still frees the cells its rays cross inside."""
    rng = np.random.default_rng(6)
    bounds = ((-0.2, -0.2, -0.2), (0.2, 0.2, 0.2))
    scans = [
        (np.array([0.01, 0.02, 0.03]), rng.normal(scale=0.4, size=(64, 3)), None),
        (np.array([0.41, -0.03, 0.05]), rng.normal(scale=0.1, size=(64, 3)), None),  # outside
        (np.array([0.0, 0.1, -0.05]), rng.normal(scale=0.5, size=(64, 3)), 0.3),
    ]
    m = our_map(scans, bounds)
    tree = octree(scans)
    assert tree.getNumLeafNodes() > m.counts().free + m.counts().occupied
    assert_same_as_octree(m, tree, rng, whole_tree_inside=False)
    outside = np.array([[0.5, 0.0, 0.0], [0.0, -0.35, 0.0]])
    np.testing.assert_array_equal(m.classify(outside), [-1, -1])
    assert np.all(np.isnan(m.log_odds(outside)))


def test_keys_use_octomaps_resolution_factor():
    """OctoMap keys are floor(x * (1 / res)), which differs from floor(x / res) for some
    coordinates at some resolutions: at 0.07, x = 1.75 is cell 25, not 24."""
    res = 0.07
    pts = np.array([[1.75, 0.01, 0.01], [3.5, -0.02, 0.03], [0.02, 5.25, -0.01],
                    [0.03, 0.01, 1.75]])
    scan = (np.array([0.011, 0.012, 0.013]), pts, None)
    m = our_map([scan], ((-0.5, -0.5, -0.5), (5.5, 5.5, 2.0)), res=res)
    np.testing.assert_array_equal(m.cell_indices(pts[:1])[0] + m.index_offset, [[25, 0, 0]])
    assert_same_as_octree(m, octree([scan], res=res), np.random.default_rng(13))


def test_non_finite_points_are_skipped():
    m = OccupancyMap(RES, bounds=((-0.2, -0.2, -0.2), (0.2, 0.2, 0.2)))
    m.insert_scan(np.zeros(3) + 0.001, [[np.nan, 0, 0], [0.1, np.inf, 0], [0.1, 0.1, 0.1]])
    ref = OccupancyMap(RES, bounds=((-0.2, -0.2, -0.2), (0.2, 0.2, 0.2)))
    ref.insert_scan(np.zeros(3) + 0.001, [[0.1, 0.1, 0.1]])
    assert m.counts() == ref.counts()


@numba.njit(cache=True)
def _octomap_sphere_scan():
    """The points of OctoMap's unit test "InsertScan", with Vector3::rotate_IP's float casts:
    (2.01, 0.01, 0.01) yawed by 1 degree 360 times per row, pitched by 1 degree per row, each
    offset by the origin (0.01, 0.01, 0.02)."""
    f = np.float32
    out = np.empty((360 * 360, 3), dtype=np.float32)
    ox, oy, oz = f(0.01), f(0.01), f(0.02)
    x, y, z = f(2.01), f(0.01), f(0.01)
    one_deg = 1.0 * math.pi / 180.0
    n = 0
    for _ in range(360):
        for j in range(361):
            if j < 360:
                out[n, 0], out[n, 1], out[n, 2] = f(ox + x), f(oy + y), f(oz + z)
                n += 1
                roll, pitch, yaw = 0.0, 0.0, one_deg
            else:
                roll, pitch, yaw = 0.0, one_deg, 0.0
            xd, zd = np.float64(x), np.float64(z)
            x = f(zd * math.sin(pitch) + xd * math.cos(pitch))
            z = f(zd * math.cos(pitch) - xd * math.sin(pitch))
            xd, yd = np.float64(x), np.float64(y)
            x = f(xd * math.cos(yaw) - yd * math.sin(yaw))
            y = f(xd * math.sin(yaw) + yd * math.cos(yaw))
            yd, zd = np.float64(y), np.float64(z)
            y = f(yd * math.cos(roll) - zd * math.sin(roll))
            z = f(yd * math.sin(roll) + zd * math.cos(roll))
    return out


def test_octomap_insert_scan_unit_test():
    """OctoMap's unit test InsertScan (129 600 points, 0.05 m): same cells and log-odds as
    pyoctomap, and the pruned tree has OctoMap's expected 53959 nodes."""
    pts = _octomap_sphere_scan().astype(np.float64)
    origin = np.array([0.01, 0.01, 0.02], dtype=np.float32).astype(np.float64)
    scan = (origin, pts, None)
    m = our_map([scan], ((-2.1, -2.1, -2.1), (2.1, 2.1, 2.1)), res=0.05)
    assert_same_as_octree(m, octree([scan], res=0.05), np.random.default_rng(7))
    assert m.octree_size() == 53959


def test_octree_size_matches_pyoctomap_after_pruning():
    """Dense fans of rays make full 2x2x2 blocks of equal leaves, which OctoMap prunes."""
    rng = np.random.default_rng(8)
    geometry = ZoneGeometry()
    scans = []
    for _ in range(6):
        origin = np.array([0.0, 0.0, 0.0]) + rng.uniform(-0.02, 0.02, 3)
        dirs = geometry.sub_directions(6).reshape(-1, 3)
        scans.append((origin, origin + dirs * rng.uniform(0.2, 0.3), None))
    m = our_map(scans, ((-0.3, -0.3, -0.1), (0.3, 0.3, 0.4)))
    tree = octree(scans, lazy_eval=False)
    assert m.octree_size() == tree.size()
    assert m.octree_size() < m.counts().free + m.counts().occupied  # some pruning happened


# --- frames: ray and cone mode -------------------------------------------------------------------


def one_zone_frame(row: int, col: int, distance_mm: int, sequence: int = 1) -> ToFFrame:
    frame = ToFFrame.empty(8, sequence=sequence)
    frame.distance_mm[row, col] = distance_mm
    frame.status[row, col] = 5
    return frame


SMALL = ((-0.1, -0.1, -0.05), (0.1, 0.1, 0.4))


def test_ray_mode_single_zone_hand_worked():
    """Zone (3, 3) spans [-5.625, 0] degrees on both axes; its centre ray at -2.8125 degrees
    reaches x = y = 0.005 + 0.305 tan(-2.8125 deg) = -0.00998 at z = 0.305: cell (-1, -1, 30)."""
    X = np.eye(4)
    X[:3, 3] = [0.005, 0.005, 0.0]
    m = OccupancyMap(RES, bounds=SMALL)
    m.insert_frame(one_zone_frame(3, 3, 305), ZoneGeometry(), X, mode="ray")
    occupied = m.occupied_indices() + m.index_offset
    np.testing.assert_array_equal(occupied, [[-1, -1, 30]])
    idx, _ = m.known_cells()
    assert (idx + m.index_offset)[:, 2].max() == 30
    assert m.classify([[0.005, 0.005, 0.005]])[0] == 0  # the sensor's own cell is freed


def test_cone_mode_single_zone_hand_worked():
    """5x5 sub-rays at -5.0625, -3.9375, -2.8125, -1.6875, -0.5625 degrees end at
    0.005 + 0.305 tan(a) = -0.0220, -0.0160, -0.0100, -0.0040, +0.0020: cells -3, -2, -1, -1, 0
    on x and on y, so the surface is the 4 x 4 cells {-3..0}^2 at z = 30."""
    X = np.eye(4)
    X[:3, 3] = [0.005, 0.005, 0.0]
    m = OccupancyMap(RES, bounds=SMALL)
    m.insert_frame(one_zone_frame(3, 3, 305), ZoneGeometry(), X, mode="cone", cone_k=5)
    occupied = {tuple(c) for c in m.occupied_indices() + m.index_offset}
    assert occupied == {(x, y, 30) for x in range(-3, 1) for y in range(-3, 1)}
    idx, values = m.known_cells()
    cells = idx + m.index_offset
    free = cells[values < 0]
    assert free[:, 2].max() == 29 and free[:, 2].min() == 0
    # Every free cell lies in the zone's pyramid, tan(-5.625 deg) <= x/z, y/z <= 0, give or
    # take the cell the DDA crosses on the boundary.
    rel = m.cell_centers(idx[values < 0]) - [0.005, 0.005, 0.0]
    low = math.tan(math.radians(-5.625)) * rel[:, 2] - RES
    assert np.all(rel[:, :2] >= low[:, None]) and np.all(rel[:, :2] <= RES)


def test_cone_mode_is_one_octomap_scan_of_sub_ray_ends():
    rng = np.random.default_rng(9)
    frame = ToFFrame(distance_mm=rng.integers(150, 700, size=(8, 8)),
                     status=rng.choice([5, 9, 255, 6], size=(8, 8)),
                     sigma_mm=np.zeros((8, 8)), sequence=3)
    X = np.eye(4)
    c, s = math.cos(0.4), math.sin(0.4)
    X[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    X[:3, 3] = [0.013, -0.021, 0.002]
    geometry = ZoneGeometry(flip_x=True)
    m = OccupancyMap(RES, bounds=((-0.8, -0.8, -0.2), (0.8, 0.8, 0.9)))
    m.insert_frame(frame, geometry, X, mode="cone", cone_k=3, max_range=0.6)
    origin, pts = frame_scan(frame, geometry, X, mode="cone", cone_k=3)
    assert len(pts) == 9 * frame.valid.sum()
    assert_same_as_octree(m, octree([(origin, pts, 0.6)]), rng, whole_tree_inside=False)


def test_frame_scan_ray_mode_uses_zone_points():
    rng = np.random.default_rng(10)
    frame = ToFFrame(distance_mm=rng.integers(100, 900, size=(8, 8)),
                     status=rng.choice([5, 9, 255], size=(8, 8)), sigma_mm=np.zeros((8, 8)))
    geometry = ZoneGeometry(flip_y=True, transpose=True)
    X = np.eye(4)
    X[:3, 3] = [0.1, 0.2, 0.3]
    origin, pts = frame_scan(frame, geometry, X, mode="ray")
    p_S, valid = geometry.points(frame)
    np.testing.assert_allclose(pts, p_S[valid] + [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(origin, [0.1, 0.2, 0.3])


def test_no_target_zones_free_nothing_by_default():
    frame = ToFFrame.empty(8)
    X = np.eye(4)
    m = OccupancyMap(RES, bounds=SMALL)
    m.insert_frame(frame, ZoneGeometry(), X)
    assert m.counts().unknown == np.prod(m.shape)
    m.insert_frame(frame, ZoneGeometry(), X, max_range=0.2, free_no_target=True)
    counts = m.counts()
    assert counts.occupied == 0 and counts.free > 0
    idx, _ = m.known_cells()
    dist = np.linalg.norm(m.cell_centers(idx), axis=1)
    assert dist.max() <= 0.2 + RES * math.sqrt(3)
    with pytest.raises(ValueError, match="max_range"):
        m.insert_frame(frame, ZoneGeometry(), X, free_no_target=True)


# --- queries, copies, export ---------------------------------------------------------------------


def line_map() -> OccupancyMap:
    """Cells x = 0..49 (y = z = 0) free, x = 50 occupied."""
    m = OccupancyMap(RES, bounds=((-1.0, -0.2, -0.2), (1.0, 0.2, 0.2)))
    m.insert_scan([0.005, 0.005, 0.005], [[0.505, 0.005, 0.005]])
    return m


def test_first_occupied():
    m = line_map()
    origins = [[0.005, 0.005, 0.005], [0.005, 0.005, 0.005], [-0.2, 0.005, 0.005],
               [-0.2, 0.005, 0.005], [-3.0, 0.005, 0.005], [0.005, 0.1, 0.005],
               [0.505, 0.005, 0.005]]
    directions = [[1, 0, 0], [-1, 0, 0], [2, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0]]
    dist, cells = m.first_occupied(origins, directions, max_range=5.0)
    np.testing.assert_allclose(dist, [0.495, np.inf, 0.7, 0.7, 3.5, np.inf, 0.0], atol=1e-9)
    expected = np.array([50, 0, 0]) - m.index_offset
    for i in (0, 2, 3, 4, 6):
        np.testing.assert_array_equal(cells[i], expected)
    np.testing.assert_array_equal(cells[[1, 5]], -1)
    short, _ = m.first_occupied(origins[2:3], directions[2:3], max_range=0.6)
    assert short[0] == np.inf


def test_unknown_along_segments():
    empty = OccupancyMap(RES, bounds=((-1.0, -0.2, -0.2), (1.0, 0.2, 0.2)))
    o = [[0.005, 0.005, 0.005]] * 2
    e = [[0.305, 0.005, 0.005], [0.005, 0.005, 0.305]]
    n, length = empty.unknown_along_segments(o, e)
    np.testing.assert_array_equal(n, [31, 20])  # the z segment leaves the grid at z = 0.2
    np.testing.assert_allclose(length, [0.3, 0.195], atol=1e-12)
    box = ((0.095, -0.5, -0.5), (0.205, 0.5, 0.5))  # cells 9 and 20 in part, 10..19 whole
    n, length = empty.unknown_along_segments(o[:1], e[:1], box=box)
    assert n[0] == 12 and length[0] == pytest.approx(0.11, abs=1e-12)

    m = line_map()
    seg = ([[0.005, 0.005, 0.005]], [[0.995, 0.005, 0.005]])
    n, length = m.unknown_along_segments(*seg)
    assert n[0] == 0 and length[0] == 0.0  # free up to the occupied cell, then blocked
    n, length = m.unknown_along_segments(*seg, stop_at_occupied=False)
    assert n[0] == 49 and length[0] == pytest.approx(0.485, abs=1e-12)


def test_a_box_face_on_a_cell_face_counts_no_cell_beyond_it():
    """z cells 5..9 lie in the box [0, 0.1]; the walk's accumulated rounding gave cell 10 an
    overlap of 1e-17 m, counted one way along the segment and not the other."""
    empty = OccupancyMap(RES, bounds=((-0.3, -0.3, -0.3), (0.3, 0.3, 0.3)))
    box = ((0.0, 0.0, 0.0), (0.1, 0.1, 0.1))
    up, down = [0.055, 0.055, 0.055], [0.055, 0.055, 0.25]
    for o, e in ((up, down), (down, up)):
        n, length = empty.unknown_along_segments([o], [e], box=box)
        assert n[0] == 5 and length[0] == pytest.approx(0.045, abs=1e-12)


def test_queries_and_copies():
    m = line_map()
    np.testing.assert_array_equal(m.classify([[0.505, 0.005, 0.005], [0.255, 0.0, 0.0],
                                              [0.0, 0.1, 0.0], [5.0, 0.0, 0.0]]), [1, 0, -1, -1])
    lo = m.log_odds([[0.505, 0.005, 0.005], [0.0, 0.1, 0.0]])
    assert lo.dtype == np.float32 and lo[0] == HIT and np.isnan(lo[1])
    np.testing.assert_allclose(m.occupied_centers(), [[0.505, 0.005, 0.005]])
    assert m.counts() == (np.prod(m.shape) - 51, 50, 1)
    assert copy.deepcopy(m) is m and copy.copy(m) is m
    other = m.copy()
    other.insert_scan([0.005, 0.005, 0.005], [[-0.205, 0.005, 0.005]])
    assert m.counts().free == 50 and other.counts().free == 70
    assert m.n_scans == 1 and other.n_scans == 2


@pytest.mark.parametrize("suffix", [".ot", ".bt"])
def test_export_round_trip(tmp_path, suffix):
    rng = np.random.default_rng(11)
    scans = [(rng.uniform(-0.05, 0.05, 3), rng.normal(scale=0.2, size=(64, 3)), None)
             for _ in range(5)]
    scans += [scans[0]] * 5  # saturated cells, and prunable blocks of equal leaves
    m = our_map(scans, ((-0.6, -0.6, -0.6), (0.6, 0.6, 0.6)))
    before = m.known_cells()[1].copy()
    path = tmp_path / f"map{suffix}"
    m.export_octomap(path)
    np.testing.assert_array_equal(m.known_cells()[1], before)  # the map is untouched
    tree = OcTree(0.1).read(str(path)) if suffix == ".ot" else OcTree(str(path).encode())
    idx, values = m.known_cells()
    centers = m.cell_centers(idx)
    if suffix == ".ot":
        assert tree.size() == m.octree_size()
        theirs = np.array([tree.search(c).getLogOdds() for c in centers], dtype=np.float32)
        np.testing.assert_array_equal(theirs, values)
    labels = tree.getLabels(centers)
    np.testing.assert_array_equal(labels, (values >= 0).astype(int))
    lo, hi = m.bounds
    pts = rng.uniform(lo, hi, size=(2000, 3))
    np.testing.assert_array_equal(tree.getLabels(pts), m.classify(pts))


def test_cell_geometry_is_octomaps():
    m = OccupancyMap(0.05, bounds=((-0.12, -0.1, 0.0), (0.1, 0.1, 0.1)))
    np.testing.assert_array_equal(m.index_offset, [-3, -2, 0])
    np.testing.assert_allclose(m.bounds, [[-0.15, -0.1, 0.0], [0.1, 0.1, 0.1]])
    tree = OcTree(0.05)
    pts = np.random.default_rng(12).uniform(-0.15, 0.1, size=(500, 3))
    idx, inside = m.cell_indices(pts)
    keys = np.array([[k[0], k[1], k[2]] for k in map(tree.coordToKey, pts)])
    np.testing.assert_array_equal((idx + m.index_offset + KEY_OFFSET)[inside], keys[inside])
    centre = tree.keyToCoord(tree.coordToKey(np.array([0.0, 0.0, 0.0])))
    np.testing.assert_allclose(m.cell_centers([[3, 2, 0]]), [centre])
    np.testing.assert_allclose(centre, [0.025] * 3)
    with pytest.raises(ValueError, match="bounds"):
        OccupancyMap(0.01, bounds=((0, 0, 0), (0, 1, 1)))
