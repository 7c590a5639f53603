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
import sys
from pathlib import Path

from lrnbv_drake.core.sensor import STATUS_NO_TARGET, ToFFrame
from lrnbv_drake.drivers.tof_serial import SensorError, SerialStats
from lrnbv_drake.experiments.sensor_recording import (
    RecordingNoise,
    characterize,
    record,
    stream,
    write_noise_to_scenario,
)

DEFAULT_BAUD = 460800
#: Zone markers of the live view: valid, valid with a large pulse, any other status.
_MARKERS = {5: " ", 9: "*"}


# --- Printing --------------------------------------------------------------------------------


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


def _recording_line(r: RecordingNoise) -> str:
    """What `characterize` prints of one recording."""
    noise, n = r.noise, r.noise.mean_mm.size
    line = f"{r.source}: {r.zones} zones"
    if r.target_mm is not None:
        line += (f", {n} on the target at {r.target_mm:.0f} mm (bias "
                 f"{(noise.mean_mm - r.target_mm).mean():+.1f} mm)" if n else
                 f", none within reach of {r.target_mm:.0f} mm")
    if n:
        line += (f"; distance {noise.mean_mm.mean():.0f} mm, std {noise.std_mm.mean():.2f} "
                 f"mm, device sigma {noise.reported_sigma_mm.mean():.2f} mm")
    return line


# --- Commands --------------------------------------------------------------------------------


def _stream(args: argparse.Namespace) -> int:
    live = sys.stdout.isatty()

    def show(frame: ToFFrame, stats: SerialStats, rate_hz: float | None) -> None:
        text = render_frame(frame, stats, rate_hz)
        # Live: redraw in place, from the top left of a cleared screen.
        sys.stdout.write("\x1b[H\x1b[J" + text if live else text)
        sys.stdout.flush()

    run = stream(args.port, args.baud, args.frames, args.timeout, show,
                 lambda e: print(f"waiting: {e}", flush=True))
    if run.interrupted:
        print()
    print(format_stats(run.stats))
    return 130 if run.interrupted else 0


def _record(args: argparse.Namespace) -> int:
    if args.out.exists() and not args.overwrite:
        raise ValueError(f"--out {args.out} exists: choose another file, or pass --overwrite "
                         "to replace it")

    def progress(count: int, frame: ToFFrame) -> None:
        print(f"\rrecorded {count}/{args.frames} (sequence {frame.sequence})", end="",
              flush=True)

    run = record(args.port, args.baud, args.frames, args.out, args.timeout, progress)
    if run.timeout:
        print(f"\nlrnbv sensor record: {run.timeout}", file=sys.stderr)
    print()
    print(f"wrote {run.frames} of {args.frames} frames to {args.out}" if run.frames else
          "no frame recorded")
    print(format_stats(run.stats))
    return 1 if run.timeout else 130 if run.interrupted else 0


def _characterize(args: argparse.Namespace) -> int:
    fit = characterize(args.frames, args.distance_mm, args.min_frames,
                       lambda r: print(_recording_line(r)))
    print(f"sigma = max({fit.sigma0_mm:.2f} mm, {fit.k:.5f} d): knee {fit.knee_mm:.0f} mm, "
          f"rms residual {fit.rms_mm:.2f} mm over {fit.n_points} zones")
    if fit.warning:
        print(f"warning: {fit.warning}", file=sys.stderr)
    write_noise_to_scenario(args.out, fit, args.frames)
    print(f"wrote sensor.sigma0_mm and sensor.noise_k to {args.out}")
    return 0



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

    p = commands.add_parser("stream", help="live 8x8 view; Ctrl-C stops and prints stats "
                                           "(exit status 130)")
    serial_args(p)
    p.add_argument("--frames", type=int, default=0, help="stop after N frames (default: never)")

    p = commands.add_parser("record", help="save N frames to an .npz (journaled as they come)")
    serial_args(p)
    p.add_argument("--frames", type=int, required=True, help="frames to record")
    p.add_argument("--out", type=Path, required=True, help="output .npz")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")

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
            return _stream(args)
        if args.sensor_command == "record":
            return _record(args)
        return _characterize(args)
    except (ValueError, OSError, SensorError) as e:
        print(f"lrnbv sensor: error: {e}", file=sys.stderr)
        return 2

