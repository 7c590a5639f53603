"""The real VL53L8CX over serial: record frames to an .npz, watch them live; the calibration
recordings (a flat board at several distances, a board edge swept across the field of view, a
small target stepped across it), made on the real cell or simulated on the calibration bench;
and the model fitted to them, written as a scenario's `sensor:` section
(docs/sensor-calibration.md).

`record` appends each frame to a journal of `$TOF` lines (`FILE.tof`, fsync'ed) before it
awaits the next one, and the journal becomes the .npz at the end, so a crash or a pulled cable
loses nothing already captured: `load_recording` reads a journal as it is. A device path that
does not exist fails at once (`check_port_exists`); one that goes away during a run is waited
for, as the driver reopens it. What to print is the caller's: these functions report through
callbacks and return how the run ended.
"""

from __future__ import annotations

import collections
import dataclasses as dc
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import yaml

from lrnbv_drake.core.calibration.mixed_zone import MixedZoneFit, edge_steps, fit_mixed_zone_rule
from lrnbv_drake.core.calibration.sensor_model import (
    NoiseFit,
    ZoneDirectionFit,
    ZoneNoise,
    fit_noise_model,
    fit_zone_directions,
    on_target,
    target_hits,
    target_raster,
    zone_errors_mm,
    zone_noise,
)
from lrnbv_drake.core.sensing.sensor import SensorModelParams, ToFFrame, ZoneGeometry
from lrnbv_drake.core.sensing.tof_protocol import encode_frame
from lrnbv_drake.drivers.tof_serial import (
    SensorTimeout,
    SerialStats,
    ToFSerialReader,
    check_port_exists,
)
from lrnbv_drake.experiments.recording import (
    frames_to_arrays,
    load_recording,
    write_atomically,
    write_npz_atomically,
)
from lrnbv_drake.station.calibration_bench import CalibrationBench
from lrnbv_drake.station.parts import zone_geometry
from lrnbv_drake.station.scenario import Scenario, load_scenario

#: Frames the live rate estimate averages over.
_RATE_WINDOW = 16


@dc.dataclass(frozen=True)
class SerialRun:
    """How a `record` or `stream` ended.

    Attributes:
        frames: frames recorded or shown.
        stats: the driver's counters at the end.
        interrupted: stopped by Ctrl-C.
        timeout: the wait that ended a recording, empty when none did.
    """

    frames: int
    stats: SerialStats
    interrupted: bool = False
    timeout: str = ""


def record(port: str, baud: int, n_frames: int, out: Path, timeout: float,
           on_frame: Callable[[int, ToFFrame], object] | None = None) -> SerialRun:
    """Records up to `n_frames` into `out` (.npz) through its journal; stops early, keeping
    what came, on a `timeout` without a frame or on Ctrl-C. `on_frame(count, frame)` follows
    the progress."""
    if out.suffix != ".npz":
        raise ValueError(f"--out {out}: expected a .npz file")
    if n_frames < 1:
        raise ValueError(f"--frames must be >= 1; got {n_frames}")
    check_port_exists(port)
    journal = out.with_suffix(".tof")
    if journal.exists():
        raise ValueError(f"{journal} exists, left by an interrupted recording: pass it to "
                         f"`lrnbv sensor characterize --frames` as it is, or move it away")
    out.parent.mkdir(parents=True, exist_ok=True)
    count, interrupted, timed_out = 0, False, ""
    with ToFSerialReader(port, baud, queue_size=1024) as sensor:
        try:
            with journal.open("ab") as f:
                while count < n_frames:
                    frame = sensor.next_frame(timeout)
                    f.write(encode_frame(frame))
                    f.flush()
                    os.fsync(f.fileno())
                    count += 1
                    if on_frame is not None:
                        on_frame(count, frame)
        except SensorTimeout as e:
            timed_out = str(e)
        except KeyboardInterrupt:
            interrupted = True
        stats = sensor.stats
    if count:
        write_npz_atomically(out, load_recording(journal))
    journal.unlink(missing_ok=True)
    return SerialRun(count, stats, interrupted, timed_out)


def stream(port: str, baud: int, n_frames: int, timeout: float,
           show: Callable[[ToFFrame, SerialStats, float | None], object],
           waiting: Callable[[SensorTimeout], object]) -> SerialRun:
    """Hands each new frame to `show(frame, stats, rate_hz)` until Ctrl-C or `n_frames`
    (0: no limit); `waiting(error)` hears of each `timeout` without one (a port that exists
    but sends nothing); a device path that does not exist fails at once."""
    check_port_exists(port)
    arrivals: collections.deque[float] = collections.deque(maxlen=_RATE_WINDOW)
    shown, last, interrupted = 0, 0, False
    with ToFSerialReader(port, baud) as sensor:
        try:
            while n_frames == 0 or shown < n_frames:
                try:
                    frame = sensor.wait_for_frame(last, timeout)
                except SensorTimeout as e:
                    waiting(e)
                    fresh = sensor.latest()
                    if fresh is not None and fresh.sequence < last:
                        last = 0  # the board restarted its count
                    continue
                last = frame.sequence
                shown += 1
                arrivals.append(time.monotonic())
                span = arrivals[-1] - arrivals[0]
                show(frame, sensor.stats, (len(arrivals) - 1) / span if span > 0 else None)
        except KeyboardInterrupt:
            interrupted = True
        return SerialRun(shown, sensor.stats, interrupted)


# --- Calibration recordings ------------------------------------------------------------------

#: What each kind of calibration recording holds beside the frames: the known geometry of each
#: frame (name: shape of one frame's value), in the sensor frame (docs/sensor-calibration.md).
GEOMETRY: dict[str, dict[str, tuple[int, ...]]] = {
    "flat": {"board_mm": ()},
    "edge": {"edge_deg": (), "near_mm": (), "far_mm": ()},
    "target": {"target_deg": (2,), "target_mm": ()},
}


def save_calibration_recording(path: Path, kind: str, frames: Sequence[ToFFrame],
                               geometry: dict[str, np.ndarray]) -> None:
    """A recording as `record` writes it, with each frame's known geometry (`GEOMETRY[kind]`)
    and `kind`, for `characterize_model`; what drives the arm on the real cell writes it."""
    arrays = frames_to_arrays(frames)
    arrays.update({name: np.asarray(value, float) for name, value in geometry.items()})
    arrays["kind"] = np.array(kind)
    _check_geometry(path, kind, arrays)
    write_npz_atomically(path, arrays)


def _check_geometry(path: str | Path, kind: str, arrays: dict[str, np.ndarray]) -> None:
    """Raises a ValueError naming the file and what a `kind` recording must hold."""
    expected = GEOMETRY[kind]
    n = arrays["distance_mm"].shape[0]
    want = ", ".join(f"{name} {(n, *shape)}" for name, shape in expected.items())
    for name, shape in expected.items():
        if name not in arrays or arrays[name].shape != (n, *shape):
            found = arrays[name].shape if name in arrays else "missing"
            raise ValueError(f"{path}: a {kind} recording of {n} frames needs the arrays "
                             f"{want}; {name} is {found}")
        if not np.all(np.isfinite(arrays[name])):
            raise ValueError(f"{path}: {name} has non-finite values")


def load_calibration_recording(path: str | Path, kind: str) -> dict[str, np.ndarray]:
    """A `kind` recording with its geometry checked (a ValueError names what is missing)."""
    arrays = load_recording(path)
    _check_geometry(path, kind, arrays)
    return arrays


def _row_major(path: str | Path, arrays: dict[str, np.ndarray], geometry: ZoneGeometry
               ) -> tuple[np.ndarray, np.ndarray]:
    """A recording's distances and statuses in row-major zone order, (n, res, res)."""
    res = arrays["distance_mm"].shape[-1]
    if res != geometry.resolution:
        raise ValueError(f"{path}: the recording has {res}x{res} zones; the scenario's sensor "
                         f"{geometry.resolution}x{geometry.resolution}")
    return tuple(np.array([geometry.to_row_major(a) for a in arrays[name]])
                 for name in ("distance_mm", "status"))


@dc.dataclass(frozen=True)
class CalibrationPlan:
    """The three recordings of the calibration, as an arm would make them on the real cell.

    Args:
        board_mm, flat_frames: flat board distances, and frames at each.
        edges_mm: (near, far) board distances of each edge sweep; separations on both sides of
            the merge distance tell whether and where surfaces merge, and a sweep whose
            surfaces are far apart but alike in signal (near 1000, far 1700) tells the target
            orders apart.
        edge_step_deg, edge_frames: edge positions step over +-`span_deg`; frames at each.
        target_mm, target_step_deg, target_frames: the small target's distance, the raster's
            step (`target_raster` over +-`span_deg`) and frames at each direction.
        span_deg: how far out either sequence steps.
    """

    board_mm: tuple[float, ...] = (100.0, 150.0, 200.0, 300.0, 450.0, 600.0, 800.0, 1000.0)
    flat_frames: int = 50
    edges_mm: tuple[tuple[float, float], ...] = ((850.0, 1000.0), (650.0, 1000.0),
                                                 (450.0, 1000.0), (1000.0, 1700.0))
    edge_step_deg: float = 0.75
    edge_frames: int = 2
    target_mm: float = 200.0
    target_step_deg: float = 1.25
    target_frames: int = 1
    span_deg: float = 27.5


#: File names `simulate_recordings` writes, by kind.
RECORDING_FILES = {"flat": "flat.npz", "edge": "edge.npz", "target": "target.npz"}


def simulate_recordings(scenario: Scenario, out_dir: Path,
                        plan: CalibrationPlan = CalibrationPlan(),
                        on_recording: Callable[[str, Path, int], object] | None = None
                        ) -> dict[str, Path]:
    """Records the plan's three sequences with the scenario's simulated device on the
    calibration bench (its noise seeded by `scenario.seed`) into `out_dir`;
    `on_recording(kind, path, frames)` hears of each file written."""
    bench = CalibrationBench(scenario)
    recordings: dict[str, tuple[list[ToFFrame], dict[str, list]]] = {}

    frames, board = [], []
    for d in plan.board_mm:
        frames += bench.flat(d, plan.flat_frames)
        board += [d] * plan.flat_frames
    recordings["flat"] = frames, {"board_mm": board}

    frames, geometry = [], {"edge_deg": [], "near_mm": [], "far_mm": []}
    for near, far in plan.edges_mm:
        for e in np.arange(-plan.span_deg, plan.span_deg + 1e-9, plan.edge_step_deg):
            frames += bench.edge(float(e), near, far, plan.edge_frames)
            for name, value in zip(geometry, (e, near, far), strict=True):
                geometry[name] += [value] * plan.edge_frames
    recordings["edge"] = frames, geometry

    frames, directions = [], []
    for direction in target_raster(plan.target_step_deg, plan.span_deg):
        frames += bench.target(tuple(direction), plan.target_mm, plan.target_frames)
        directions += [direction] * plan.target_frames
    recordings["target"] = frames, {"target_deg": directions,
                                    "target_mm": [plan.target_mm] * len(frames)}

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {}
    for kind, (frames, geometry) in recordings.items():
        paths[kind] = out_dir / RECORDING_FILES[kind]
        save_calibration_recording(paths[kind], kind, frames,
                                   {k: np.array(v) for k, v in geometry.items()})
        if on_recording is not None:
            on_recording(kind, paths[kind], len(frames))
    return paths


# --- Characterization ------------------------------------------------------------------------


@dc.dataclass(frozen=True)
class RecordingNoise:
    """What one recording adds to the noise fit.

    Attributes:
        source: the recording's file name.
        zones: zones that qualified (`zone_noise`).
        noise: the zones the fit uses: on the target when its distance is known, else all.
        target_mm: the known target distance, if given.
    """

    source: str
    zones: int
    noise: ZoneNoise
    target_mm: float | None = None

    @property
    def distances_mm(self) -> np.ndarray:
        """Each used zone's distance: the known target's, else the zone's mean reading."""
        if self.target_mm is None:
            return self.noise.mean_mm
        return np.full(self.noise.mean_mm.shape, float(self.target_mm))


def _flat_parts(name: str, distance_mm: float | None
                ) -> list[tuple[str, dict[str, np.ndarray], float | None]]:
    """A flat-board recording as (label, frames, known distance) parts: one per `board_mm`
    value where the file holds the distances, else the whole file at `distance_mm`."""
    arrays = load_recording(name)
    if "board_mm" not in arrays:
        # A file from `lrnbv sensor record` has no kind; an edge or a target recording does,
        # and its frames are not of a flat board.
        if "kind" in arrays and str(arrays["kind"]) != "flat":
            raise ValueError(f"{name}: a recording of kind '{arrays['kind']}', not of a flat board")
        return [(name, arrays, distance_mm)]
    if distance_mm is not None:
        raise ValueError(f"{name} holds its board distances (board_mm): leave --distance-mm "
                         f"out")
    _check_geometry(name, "flat", arrays)
    frames = ("distance_mm", "status", "sigma_mm")
    return [(f"{name} at {d:.0f} mm",
             {key: arrays[key][arrays["board_mm"] == d] for key in frames}, float(d))
            for d in np.unique(arrays["board_mm"])]


def characterize(files: Sequence[str], distances_mm: Sequence[float] | None, min_frames: int,
                 on_recording: Callable[[RecordingNoise], object] | None = None) -> NoiseFit:
    """Fits sigma = max(sigma0, k d) to flat-board recordings (each zone's spread and the
    zones' fixed offsets, `zone_errors_mm`): one per distance, or holding each frame's
    distance (`board_mm`); `on_recording` sees each distance's zones as read."""
    if distances_mm is not None and len(distances_mm) != len(files):
        raise ValueError(f"--distance-mm takes one distance per --frames file: got "
                         f"{len(distances_mm)} for {len(files)} files")
    used = []
    for i, name in enumerate(files):
        for label, arrays, target in _flat_parts(
                name, None if distances_mm is None else distances_mm[i]):
            noise = zone_noise(arrays, min_frames=min_frames)
            entry = RecordingNoise(label, noise.mean_mm.size,
                                   noise if target is None else on_target(noise, target),
                                   target)
            if on_recording is not None:
                on_recording(entry)
            used.append(entry)
    return fit_noise_model(np.concatenate([r.distances_mm for r in used]),
                           np.concatenate([zone_errors_mm(r.noise) for r in used]))


def characterize_directions(files: Sequence[str], geometry: ZoneGeometry) -> ZoneDirectionFit:
    """Zone centre directions from target recordings (`GEOMETRY["target"]`), in the raw zone
    order `geometry`'s flips say."""
    parts = [load_calibration_recording(name, "target") for name in files]
    distance, status = (np.concatenate(a) for a in
                        zip(*(_row_major(name, p, geometry)
                              for name, p in zip(files, parts, strict=True)), strict=True))
    target_deg = np.concatenate([p["target_deg"] for p in parts])
    target_mm = np.concatenate([p["target_mm"] for p in parts])
    return fit_zone_directions(target_hits(distance, status, target_mm), target_deg)


def characterize_mixed_zones(files: Sequence[str], params: SensorModelParams) -> MixedZoneFit:
    """The mixed-zone rule from edge-sweep recordings (`GEOMETRY["edge"]`) for the model
    `params` (its zone directions say which zones the edge crosses)."""
    parts = [load_calibration_recording(name, "edge") for name in files]
    distance, status = (np.concatenate(a) for a in
                        zip(*(_row_major(name, p, params.geometry)
                              for name, p in zip(files, parts, strict=True)), strict=True))
    edge, near, far = (np.concatenate([p[key] for p in parts])
                       for key in ("edge_deg", "near_mm", "far_mm"))
    return fit_mixed_zone_rule(edge_steps(distance, status, edge, near, far), params)


def zone_directions_csv(scenario_path: Path) -> Path:
    """Where `characterize` writes the zone directions of a scenario file: beside it."""
    return scenario_path.with_name(f"{scenario_path.stem}_zone_directions.csv").resolve()


def write_sensor_to_scenario(path: Path, noise: NoiseFit | None = None,
                             directions: ZoneDirectionFit | None = None,
                             mixed: MixedZoneFit | None = None,
                             sources: Sequence[str] = ()) -> list[str]:
    """Sets the `sensor:` fields the fits give in a scenario file, keeping its other fields
    (but not its comments: the file is rewritten through PyYAML); the zone directions go to a
    CSV beside it (`zone_directions_csv`), named by absolute path. Returns the fields set."""
    data = yaml.safe_load(path.read_text()) if path.exists() else None
    data = {} if data is None else data
    if not isinstance(data, dict) or not isinstance(data.setdefault("sensor", {}), dict):
        raise ValueError(f"{path}: not a scenario mapping with a 'sensor' mapping")
    fields: dict[str, object] = {}
    if noise is not None:
        fields.update(sigma0_mm=round(noise.sigma0_mm, 3), noise_k=round(noise.k, 6))
    csv = None
    if directions is not None:
        csv = zone_directions_csv(path)
        fields["zone_directions"] = str(csv)
    if mixed is not None:
        fields.update(target_order=mixed.target_order, merge_mm=round(mixed.merge_mm, 1),
                      merged_depth=mixed.merged_depth, min_share=round(mixed.min_share, 4))
    if not fields:
        raise ValueError("nothing to write: give flat-board, target or edge recordings")
    data["sensor"].update(fields)
    text = (f"# sensor.{', sensor.'.join(fields)} fitted by `lrnbv sensor characterize` from "
            f"{', '.join(sources)}\n" + yaml.safe_dump(data, sort_keys=False))
    path.parent.mkdir(parents=True, exist_ok=True)
    if csv is not None:
        rows = directions.centres_deg.reshape(-1, 2)
        write_atomically(csv, "# x_deg, y_deg per zone, row-major (lrnbv sensor characterize)\n"
                         + "".join(f"{x:.4f}, {y:.4f}\n" for x, y in rows))
    zone_geometry(load_scenario(data=text))  # refuse a file the simulator would not load
    write_atomically(path, text)
    return list(fields)
