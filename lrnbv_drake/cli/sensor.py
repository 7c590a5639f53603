"""`lrnbv sensor ...`: watch, record and characterize the real VL53L8CX over serial.

- `stream`: a live view of the 8x8 distances in the terminal, in the board's raw zone order
  (the order to read while calibrating the flips, docs/sensor-model.md).
- `record`: saves N frames to an .npz. Each frame is appended to a journal of `$TOF` lines
  (`FILE.tof`, fsync'ed) before the next one is awaited, and the journal becomes the .npz at
  the end, so a crash or a pulled cable loses nothing already captured: the journal is
  CRC-checked line by line and `characterize` reads it as it is.
- `characterize`: fits the simulator's noise model sigma = max(sigma0, k d) to recordings of a
  flat target and writes `sensor.sigma0_mm` and `sensor.noise_k` into a scenario file.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses as dc
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

from lrnbv_drake.core.sensor import STATUS_NO_TARGET, VALID_STATUSES, ToFFrame
from lrnbv_drake.core.tof_protocol import FrameAssembler, encode_frame
from lrnbv_drake.drivers.tof_serial import SensorError, SensorTimeout, SerialStats, ToFSerialReader
from lrnbv_drake.station.scenario import load_scenario

DEFAULT_BAUD = 460800
#: Frames of the live view the rate estimate averages over.
_RATE_WINDOW = 16
#: Zone markers of the live view: valid, valid with a large pulse, any other status.
_MARKERS = {5: " ", 9: "*"}


# --- Recordings ------------------------------------------------------------------------------


def frames_to_arrays(frames: Sequence[ToFFrame]) -> dict[str, np.ndarray]:
    """Stacks frames into the arrays a recording .npz holds (raw zone order)."""
    if not frames:
        raise ValueError("no frames to save")
    shapes = {f.distance_mm.shape for f in frames}
    if len(shapes) > 1:
        raise ValueError(f"frames of several resolutions in one recording: {sorted(shapes)}")
    return {
        "distance_mm": np.stack([f.distance_mm for f in frames]),
        "status": np.stack([f.status for f in frames]),
        "sigma_mm": np.stack([f.sigma_mm for f in frames]),
        "sequence": np.array([f.sequence for f in frames], np.int64),
        "timestamp_us": np.array([f.timestamp_us for f in frames], np.uint64),
    }


def load_recording(path: str | Path) -> dict[str, np.ndarray]:
    """Loads a recording: an .npz from `record`, or its `$TOF` journal (e.g. left by a crash;
    a cut-off last line fails its CRC and is skipped)."""
    path = Path(path)
    if path.suffix == ".npz":
        with np.load(path) as data:
            return {key: data[key] for key in data.files}
    assembler = FrameAssembler()
    frames = assembler.feed(path.read_bytes()) + assembler.flush()
    if not frames:
        raise ValueError(f"{path}: no valid $TOF line")
    return frames_to_arrays(frames)


def save_npz_atomically(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Writes an .npz next to `path` and renames it over `path`: readers never see half."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def record(port: str, baud: int, n_frames: int, out: Path, timeout: float) -> int:
    """`lrnbv sensor record`; returns the exit code."""
    if out.suffix != ".npz":
        raise ValueError(f"--out {out}: expected a .npz file")
    if n_frames < 1:
        raise ValueError(f"--frames must be >= 1; got {n_frames}")
    journal = out.with_suffix(".tof")
    if journal.exists():
        raise ValueError(f"{journal} exists, left by an interrupted recording: pass it to "
                         f"`lrnbv sensor characterize --frames` as it is, or move it away")
    out.parent.mkdir(parents=True, exist_ok=True)
    count, code = 0, 0
    with ToFSerialReader(port, baud, queue_size=1024) as sensor:
        try:
            with journal.open("ab") as f:
                while count < n_frames:
                    frame = sensor.next_frame(timeout)
                    f.write(encode_frame(frame))
                    f.flush()
                    os.fsync(f.fileno())
                    count += 1
                    print(f"\rrecorded {count}/{n_frames} (sequence {frame.sequence})",
                          end="", flush=True)
        except SensorTimeout as e:
            print(f"\nlrnbv sensor record: {e}", file=sys.stderr)
            code = 1
        except KeyboardInterrupt:
            code = 130
        stats = sensor.stats
    print()
    if count:
        save_npz_atomically(out, load_recording(journal))
        journal.unlink()
        print(f"wrote {count} of {n_frames} frames to {out}")
    else:
        journal.unlink(missing_ok=True)
        print("no frame recorded")
    print(format_stats(stats))
    return code


# --- Live view -------------------------------------------------------------------------------


def format_stats(stats: SerialStats) -> str:
    """One line of driver counters."""
    return (f"frames {stats.frames}  gaps {stats.gaps} (missed {stats.missed})  "
            f"restarts {stats.restarts}  bad CRC {stats.bad_crc}  bad fields "
            f"{stats.bad_fields}  truncated {stats.truncated}  reconnects {stats.reconnects}  "
            f"garbage {stats.garbage_bytes} B")


def render_frame(frame: ToFFrame, stats: SerialStats, rate_hz: float | None) -> str:
    """The live view of one frame: distances (mm) in raw zone order with status markers."""
    rate = f"{rate_hz:5.1f} Hz" if rate_hz is not None else "   -- Hz"
    lines = [f"seq {frame.sequence:<10d} t_us {frame.timestamp_us:<12d} {rate}   "
             f"raw zone order, zone 0 top left"]
    for d_row, s_row in zip(frame.distance_mm, frame.status, strict=True):
        cells = []
        for d, s in zip(d_row.tolist(), s_row.tolist(), strict=True):
            cells.append("     ." if s == STATUS_NO_TARGET else f"{d:5d}{_MARKERS.get(s, '?')}")
        lines.append(" ".join(cells))
    lines.append("mm; ' ' status 5, '*' status 9 (valid), '?' other status, '.' no target")
    lines.append(format_stats(stats))
    return "\n".join(lines) + "\n"


def stream(port: str, baud: int, n_frames: int, timeout: float) -> int:
    """`lrnbv sensor stream`; runs until Ctrl-C or `n_frames` (0: no limit)."""
    live = sys.stdout.isatty()
    arrivals: collections.deque[float] = collections.deque(maxlen=_RATE_WINDOW)
    with ToFSerialReader(port, baud) as sensor:
        if live:
            sys.stdout.write("\x1b[2J")
        shown, last = 0, 0
        try:
            while n_frames == 0 or shown < n_frames:
                try:
                    frame = sensor.wait_for_frame(last, timeout)
                except SensorTimeout as e:
                    print(f"waiting: {e}", flush=True)
                    fresh = sensor.latest()
                    if fresh is not None and fresh.sequence < last:
                        last = 0  # the board restarted its count
                    continue
                last = frame.sequence
                shown += 1
                arrivals.append(time.monotonic())
                span = arrivals[-1] - arrivals[0]
                rate = (len(arrivals) - 1) / span if span > 0 else None
                text = render_frame(frame, sensor.stats, rate)
                sys.stdout.write("\x1b[H\x1b[J" + text if live else text)
                sys.stdout.flush()
        except KeyboardInterrupt:
            print()
        print(format_stats(sensor.stats))
    return 0


# --- Noise characterization ------------------------------------------------------------------


@dc.dataclass(frozen=True)
class ZoneNoise:
    """Per-zone statistics of one static recording, for the zones that qualify.

    Attributes:
        mean_mm: mean valid distance of each zone.
        std_mm: standard deviation over frames (ddof 1).
        reported_sigma_mm: mean of the device's own sigma estimate.
        frames: valid frames per zone.
    """

    mean_mm: np.ndarray
    std_mm: np.ndarray
    reported_sigma_mm: np.ndarray
    frames: np.ndarray


def zone_noise(recording: dict[str, np.ndarray], min_frames: int = 10,
               min_valid_fraction: float = 0.9) -> ZoneNoise:
    """Mean and spread of each zone over the frames of a recording of a static scene.

    A zone qualifies with at least `min_frames` valid frames and `min_valid_fraction` of all
    frames valid (a zone that flickers between surfaces or in and out of range measures
    something other than noise).
    """
    d = recording["distance_mm"].astype(np.float64)
    valid = np.isin(recording["status"], VALID_STATUSES) & (d > 0)
    n = valid.sum(axis=0)
    usable = (n >= min_frames) & (n >= min_valid_fraction * d.shape[0])
    count = np.maximum(n, 1)
    mean = np.where(valid, d, 0.0).sum(axis=0) / count
    var = np.where(valid, (d - mean) ** 2, 0.0).sum(axis=0) / np.maximum(n - 1, 1)
    sigma = np.where(valid, recording["sigma_mm"], 0.0).sum(axis=0) / count
    return ZoneNoise(mean[usable], np.sqrt(var[usable]), sigma[usable], n[usable])


@dc.dataclass(frozen=True)
class NoiseFit:
    """Least-squares fit of sigma = max(sigma0, k d) to per-zone (distance, std) points.

    Attributes:
        sigma0_mm, k: the fitted model.
        rms_mm: root-mean-square residual of the zone stds.
        n_points: zones used.
        distance_range_mm: nearest and farthest zone distance.
        warning: set when the data do not pin both parameters down.
    """

    sigma0_mm: float
    k: float
    rms_mm: float
    n_points: int
    distance_range_mm: tuple[float, float]
    warning: str = ""

    @property
    def knee_mm(self) -> float:
        """Distance where k d overtakes sigma0."""
        return self.sigma0_mm / self.k if self.k > 0 else np.inf


def fit_noise_model(distance_mm: np.ndarray, std_mm: np.ndarray) -> NoiseFit:
    """Exact least-squares fit of std = max(sigma0, k d) with sigma0, k >= 0.

    The model is flat below the knee d* = sigma0 / k and linear above, so every candidate
    optimum is one of: a split of the points sorted by distance into a flat and a linear part
    (mean and a line through the origin) that is self-consistent; the knee on a data point
    (sigma0 = k b, a one-parameter fit of k max(b, d)); or a bound (all flat with k = 0, all
    linear with sigma0 = 0). Evaluating them all and keeping the best gives the global optimum
    without a start point or an iterative solver.

    Raises:
        ValueError: fewer than two distinct distances, which cannot separate the two pieces.
    """
    order = np.argsort(distance_mm)
    d = np.asarray(distance_mm, np.float64)[order]
    s = np.asarray(std_mm, np.float64)[order]
    if d.size == 0 or np.unique(d).size < 2:
        raise ValueError("the noise fit needs zones at two or more distinct distances: record "
                         "a flat target at several distances (e.g. 150 to 1000 mm)")

    candidates = [(float(s.mean()), 0.0), (0.0, float(d @ s / (d @ d)))]
    for b in np.unique(d):
        m = np.maximum(b, d)
        k = float(m @ s / (m @ m))
        candidates.append((k * b, k))
    for j in range(1, d.size):
        if d[j - 1] == d[j]:
            continue
        sigma0 = float(s[:j].mean())
        k = float(d[j:] @ s[j:] / (d[j:] @ d[j:]))
        if k >= 0 and k * d[j - 1] <= sigma0 <= k * d[j]:
            candidates.append((sigma0, k))

    def cost(c: tuple[float, float]) -> float:
        return float(np.sum((np.maximum(c[0], c[1] * d) - s) ** 2))

    sigma0, k = min((c for c in candidates if c[0] >= 0 and c[1] >= 0), key=cost)
    d_range = (float(d[0]), float(d[-1]))
    fit = NoiseFit(sigma0, k, float(np.sqrt(cost((sigma0, k)) / d.size)), int(d.size), d_range)
    if not d_range[0] < fit.knee_mm < d_range[1]:
        fit = dc.replace(fit, warning=(
            f"the distances ({d_range[0]:.0f} to {d_range[1]:.0f} mm) do not straddle the "
            f"fitted knee ({fit.knee_mm:.0f} mm), so one parameter is only bounded: record "
            f"nearer and farther targets"))
    return fit


def write_noise_to_scenario(path: Path, fit: NoiseFit, sources: Sequence[str]) -> None:
    """Sets `sensor.sigma0_mm` and `sensor.noise_k` in a scenario file, keeping its other
    fields (but not its comments: the file is rewritten through PyYAML)."""
    data = yaml.safe_load(path.read_text()) if path.exists() else None
    data = {} if data is None else data
    if not isinstance(data, dict) or not isinstance(data.setdefault("sensor", {}), dict):
        raise ValueError(f"{path}: not a scenario mapping with a 'sensor' mapping")
    data["sensor"]["sigma0_mm"] = round(fit.sigma0_mm, 3)
    data["sensor"]["noise_k"] = round(fit.k, 6)
    text = (f"# sensor.sigma0_mm and sensor.noise_k fitted by `lrnbv sensor characterize` "
            f"from {', '.join(sources)}\n" + yaml.safe_dump(data, sort_keys=False))
    load_scenario(data=text)  # refuse to write a file the simulator would not load
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def characterize(files: Sequence[str], distances_mm: Sequence[float] | None, out: Path,
                 min_frames: int) -> int:
    """`lrnbv sensor characterize`; returns the exit code."""
    if distances_mm is not None and len(distances_mm) != len(files):
        raise ValueError(f"--distance-mm takes one distance per --frames file: got "
                         f"{len(distances_mm)} for {len(files)} files")
    all_d, all_s = [], []
    for i, name in enumerate(files):
        noise = zone_noise(load_recording(name), min_frames=min_frames)
        d = noise.mean_mm
        line = f"{name}: {d.size} zones"
        if distances_mm is not None:
            target = distances_mm[i]
            on_target = np.abs(d - target) <= max(50.0, 0.1 * target)
            noise = ZoneNoise(*(getattr(noise, f.name)[on_target] for f in dc.fields(noise)))
            d = np.full(noise.mean_mm.shape, float(target))
            line += (f", {d.size} on the target at {target:.0f} mm (bias "
                     f"{(noise.mean_mm - target).mean():+.1f} mm)" if d.size else
                     f", none within reach of {target:.0f} mm")
        if d.size:
            line += (f"; distance {noise.mean_mm.mean():.0f} mm, std {noise.std_mm.mean():.2f} "
                     f"mm, device sigma {noise.reported_sigma_mm.mean():.2f} mm")
        print(line)
        all_d.append(d)
        all_s.append(noise.std_mm)
    fit = fit_noise_model(np.concatenate(all_d), np.concatenate(all_s))
    print(f"sigma = max({fit.sigma0_mm:.2f} mm, {fit.k:.5f} d): knee {fit.knee_mm:.0f} mm, "
          f"rms residual {fit.rms_mm:.2f} mm over {fit.n_points} zones")
    if fit.warning:
        print(f"warning: {fit.warning}", file=sys.stderr)
    write_noise_to_scenario(out, fit, files)
    print(f"wrote sensor.sigma0_mm and sensor.noise_k to {out}")
    return 0


# --- Command line ----------------------------------------------------------------------------


def add_sensor_commands(subparsers: argparse._SubParsersAction) -> None:
    """Adds `sensor stream|record|characterize` to the `lrnbv` parser's subcommands."""
    sensor = subparsers.add_parser("sensor", help="the real VL53L8CX over serial",
                                   description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = sensor.add_subparsers(dest="sensor_command", required=True)

    def serial_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("--port", required=True,
                       help="serial device (/dev/ttyACM0, COM3) or a pyserial URL")
        p.add_argument("--baud", type=int, default=DEFAULT_BAUD,
                       help=f"line rate (default {DEFAULT_BAUD}; ignored over USB CDC)")
        p.add_argument("--timeout", type=float, default=5.0,
                       help="seconds without a frame before complaining (default 5)")

    p = commands.add_parser("stream", help="live 8x8 view; Ctrl-C stops and prints stats")
    serial_args(p)
    p.add_argument("--frames", type=int, default=0, help="stop after N frames (default: never)")

    p = commands.add_parser("record", help="save N frames to an .npz (journaled as they come)")
    serial_args(p)
    p.add_argument("--frames", type=int, required=True, help="frames to record")
    p.add_argument("--out", type=Path, required=True, help="output .npz")

    p = commands.add_parser("characterize",
                            help="fit sigma = max(sigma0, k d) from flat-target recordings")
    p.add_argument("--frames", nargs="+", required=True, metavar="FILE",
                   help="recordings (.npz, or a .tof journal), one per target distance")
    p.add_argument("--distance-mm", nargs="+", type=float, metavar="D",
                   help="known perpendicular target distance of each recording; the fit then "
                        "uses it for the zones on the target and reports the bias")
    p.add_argument("--out", type=Path, required=True,
                   help="scenario YAML to write (merged into it if it exists)")
    p.add_argument("--min-frames", type=int, default=10,
                   help="valid frames a zone needs to count (default 10)")


def run_sensor_command(args: argparse.Namespace) -> int:
    """Runs a command parsed by `add_sensor_commands`; returns the exit code."""
    try:
        if args.sensor_command == "stream":
            return stream(args.port, args.baud, args.frames, args.timeout)
        if args.sensor_command == "record":
            return record(args.port, args.baud, args.frames, args.out, args.timeout)
        return characterize(args.frames, args.distance_mm, args.out, args.min_frames)
    except (ValueError, OSError, SensorError) as e:
        print(f"lrnbv sensor: error: {e}", file=sys.stderr)
        return 2


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m lrnbv_drake.cli.sensor sensor ...`, the same as `lrnbv sensor`."""
    parser = argparse.ArgumentParser(prog="lrnbv")
    add_sensor_commands(parser.add_subparsers(dest="command", required=True))
    return run_sensor_command(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
