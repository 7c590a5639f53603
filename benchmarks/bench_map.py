"""Map update speed: `OccupancyMap` against pyoctomap (lazy_eval=True) on the same scans.

Two workloads, both 8x8 VL53L8CX frames at 1 cm:
- one frame whose 64 zones see a stepped surface 0.2-0.8 m away, inserted into an empty map
  (a fresh map each time) and then 1000 times into the same map (cells saturate);
- an episode: an object (a 10 cm sphere on a floor) seen from 50 random poses 0.2-0.8 m away,
  every frame computed analytically; per-scan cost for both libraries in ray and cone mode,
  then the whole episode through `insert_frame` (frame-to-points conversion included).
Prints µs per scan and the ratio; the target is pyoctomap / ours >= 15 for ray-mode scans.

    .venv/bin/python benchmarks/bench_map.py
"""

from __future__ import annotations

import time

import numpy as np
from pyoctomap import OcTree

from lrnbv_drake.core.mapping import OccupancyMap, frame_scan
from lrnbv_drake.core.sensing.sensor import STATUS_NO_TARGET, STATUS_VALID, ToFFrame, ZoneGeometry

RESOLUTION = 0.01
BOUNDS = ((-0.9, -0.9, -0.05), (0.9, 0.9, 0.9))
CENTRE = np.array([0.0, 0.0, 0.1])
RADIUS = 0.1
N_FRAMES = 50
REPEATS = 7
TARGET_RATIO = 15.0


def look_at(eye: np.ndarray, target: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """4x4 X_WS with the sensor's +z towards `target`, rolled at random."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, rng.normal(size=3))
    x /= np.linalg.norm(x)
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    X[:3, 3] = eye
    return X


def render(X_WS: np.ndarray, geometry: ZoneGeometry, sequence: int) -> ToFFrame:
    """Perpendicular depth of each zone centre ray to the nearer of the sphere and the floor."""
    d_S = geometry.directions().reshape(-1, 3)
    d_W = d_S @ X_WS[:3, :3].T
    o = X_WS[:3, 3]
    t = np.full(len(d_W), np.inf)  # ray parameter along the unit-depth direction
    oc = o - CENTRE
    a = np.einsum("ij,ij->i", d_W, d_W)
    b = 2 * d_W @ oc
    disc = b * b - 4 * a * (oc @ oc - RADIUS**2)
    hit = disc >= 0
    t[hit] = (-b[hit] - np.sqrt(disc[hit])) / (2 * a[hit])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d_W[:, 2] < 0, -o[2] / d_W[:, 2], np.inf)
    t = np.where((t > 0) & (t < t_floor), t, t_floor)  # depth along the boresight = t
    valid = np.isfinite(t) & (t * 1000 < 4000)
    res = geometry.resolution
    return ToFFrame(
        distance_mm=np.where(valid, np.rint(t * 1000), 0).reshape(res, res),
        status=np.where(valid, STATUS_VALID, STATUS_NO_TARGET).reshape(res, res),
        sigma_mm=np.zeros((res, res)),
        sequence=sequence,
    )


def episode(seed: int = 0) -> tuple[list[ToFFrame], list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    geometry = ZoneGeometry()
    frames, poses = [], []
    for i in range(N_FRAMES):
        direction = rng.normal(size=3)
        direction[2] = abs(direction[2]) + 0.3
        direction /= np.linalg.norm(direction)
        eye = CENTRE + direction * (RADIUS + rng.uniform(0.2, 0.8))
        X = look_at(eye, CENTRE + rng.normal(scale=0.03, size=3), rng)
        poses.append(X)
        frames.append(render(X, geometry, i))
    return frames, poses


def best_of(run, repeats: int = REPEATS) -> float:
    """Best of `repeats` calls of `run()`, which returns its own timed seconds."""
    return min(run() for _ in range(repeats))


def report(label: str, t_ours: float, t_theirs: float) -> None:
    ratio = t_theirs / t_ours
    verdict = "meets" if ratio >= TARGET_RATIO else "MISSES"
    print(f"{label}: OccupancyMap {t_ours * 1e6:7.1f} µs   pyoctomap {t_theirs * 1e6:8.1f} µs   "
          f"ratio {ratio:5.1f}x ({verdict} the >= {TARGET_RATIO:.0f}x target)")


def single_frame() -> None:
    """One frame, 64 valid zones, rows at 0.2, 0.286, ..., 0.8 m."""
    geometry = ZoneGeometry()
    depth = np.repeat(np.linspace(200, 800, 8)[:, None], 8, axis=1)
    frame = ToFFrame(distance_mm=np.rint(depth), status=np.full((8, 8), STATUS_VALID),
                     sigma_mm=np.zeros((8, 8)))
    X = np.eye(4)
    X[:3, 3] = [0.0012, 0.0031, 0.0047]
    origin, pts = frame_scan(frame, geometry, X)
    bounds = ((-0.4, -0.4, -0.05), (0.4, 0.4, 0.85))

    def ours_empty():
        m = OccupancyMap(RESOLUTION, bounds=bounds)
        t0 = time.perf_counter()
        m.insert_scan(origin, pts)
        return time.perf_counter() - t0

    def theirs_empty():
        tree = OcTree(RESOLUTION)
        t0 = time.perf_counter()
        tree.insertPointCloud(pts, origin, lazy_eval=True)
        return time.perf_counter() - t0

    n_repeat = 1000
    m = OccupancyMap(RESOLUTION, bounds=bounds)
    tree = OcTree(RESOLUTION)

    def ours_again():
        t0 = time.perf_counter()
        for _ in range(n_repeat):
            m.insert_scan(origin, pts)
        return (time.perf_counter() - t0) / n_repeat

    def theirs_again():
        t0 = time.perf_counter()
        for _ in range(n_repeat):
            tree.insertPointCloud(pts, origin, lazy_eval=True)
        return (time.perf_counter() - t0) / n_repeat

    ours_empty()  # numba compile / cache load
    for name, a, b, repeats in (("into an empty map", ours_empty, theirs_empty, 50),
                                ("1000x into one map", ours_again, theirs_again, 3)):
        report(f"one frame, 64 zones at 0.2-0.8 m, {name}", best_of(a, repeats),
               best_of(b, repeats))


def main() -> None:
    single_frame()
    geometry = ZoneGeometry()
    frames, poses = episode()
    ray_scans = [frame_scan(f, geometry, X, "ray") for f, X in zip(frames, poses, strict=True)]
    cone_scans = [frame_scan(f, geometry, X, "cone") for f, X in zip(frames, poses, strict=True)]

    def ours(scans):
        def run():
            m = OccupancyMap(RESOLUTION, bounds=BOUNDS)  # allocation not timed
            t0 = time.perf_counter()
            for origin, pts in scans:
                m.insert_scan(origin, pts)
            return time.perf_counter() - t0
        return run

    def theirs(scans):
        def run():
            tree = OcTree(RESOLUTION)
            t0 = time.perf_counter()
            for origin, pts in scans:
                tree.insertPointCloud(pts, origin, lazy_eval=True)
            return time.perf_counter() - t0
        return run

    n_pts = np.mean([len(p) for _, p in ray_scans])
    print(f"episode: {N_FRAMES} frames around an object, {n_pts:.0f} valid zones per frame on "
          f"average, best of {REPEATS}")
    for name, scans in (("ray", ray_scans), ("cone k=5", cone_scans)):
        # Both start from an empty map on every repetition.
        report(f"  per scan [{name}]", best_of(ours(scans)) / len(scans),
               best_of(theirs(scans)) / len(scans))

    for mode in ("ray", "cone"):
        def episode_run(mode=mode):
            m = OccupancyMap(RESOLUTION, bounds=BOUNDS)
            t0 = time.perf_counter()
            for f, X in zip(frames, poses, strict=True):
                m.insert_frame(f, geometry, X, mode=mode)
            return time.perf_counter() - t0
        t = best_of(episode_run)
        print(f"  episode [{mode}]: {N_FRAMES} frames via insert_frame in {t * 1e3:6.2f} ms "
              f"({t / N_FRAMES * 1e6:.0f} µs/frame, frame conversion included)")


if __name__ == "__main__":
    main()
