"""`lrnbv sensor ...`: watch, record and characterize the real VL53L8CX over serial, and
calibrate the sensor model from recordings.

- `stream`: a live view of the 8x8 distances in the terminal, in the board's raw zone order
  (the order to read while calibrating the flips, docs/sensor-model.md).
- `record`: saves N frames to an .npz. Each frame is appended to a journal of `$TOF` lines
  (`FILE.tof`, fsync'ed) before the next one is awaited, and the journal becomes the .npz at
  the end, so a crash or a pulled cable loses nothing already captured: the journal is
  CRC-checked line by line and `characterize` reads it as it is.
- `characterize`: fits the sensor model to calibration recordings and writes it into a
  scenario's `sensor:` section: the noise sigma = max(sigma0, k d) from a flat board at several
  distances (`sigma0_mm`, `noise_k`), the zone directions from a small target stepped across
  the field of view (`zone_directions`, a CSV beside the scenario), and the mixed-zone rule
  from a board edge swept across it (`target_order`, `merge_mm`, `merged_depth`, `min_share`).
- `simulate`: makes those recordings with a scenario's simulated device (`device:`), to
  calibrate from as from the real cell's (docs/sensor-calibration.md).
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import math
import sys
from pathlib import Path

from lrnbv_drake.cli.arg_types import spread_count
from lrnbv_drake.core.calibration.mixed_zone import MixedZoneFit
from lrnbv_drake.core.calibration.sensor_model import zone_errors_mm
from lrnbv_drake.core.sensing.sensor import STATUS_NO_TARGET, ToFFrame
from lrnbv_drake.drivers.tof_serial import SensorError, SerialStats
from lrnbv_drake.experiments.sensor_recording import (
    RECORDING_FILES,
    RecordingNoise,
    characterize,
    characterize_directions,
    characterize_mixed_zones,
    record,
    simulate_recordings,
    stream,
    write_sensor_to_scenario,
)
from lrnbv_drake.station.parts import sensor_params
from lrnbv_drake.station.scenario import load_scenario

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
                 f"mm, with the fixed offsets {zone_errors_mm(noise).mean():.2f} mm, device "
                 f"sigma {noise.reported_sigma_mm.mean():.2f} mm")
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


def _mixed_lines(fit: MixedZoneFit) -> list[str]:
    """What `characterize` prints of the mixed-zone fit."""
    lo, hi = fit.merge_bounds_mm
    merge = (f"merge_mm {fit.merge_mm:.0f} (the sweeps merged at {lo:.0f} mm, not at "
             f"{hi:.0f} mm)" if fit.merge_mm > 0 and math.isfinite(hi) else
             f"merge_mm {fit.merge_mm:.0f}")
    rms = ", ".join(f"{k} {v:.1f} mm" for k, v in fit.merged_rms_mm.items()
                    if math.isfinite(v))
    rules = ", ".join(f"{order}/{m:.0f}: {100 * a:.1f} %"
                      for (order, m), a in fit.candidates.items())
    return [f"mixed zones: target_order {fit.target_order}, {merge}, merged_depth "
            f"{fit.merged_depth}, min_share {fit.min_share:.3f}: predicts "
            f"{100 * fit.agreement:.1f} % of {fit.zones} mixed zones",
            f"  rules tried (order/merge_mm: agreement): {rules}",
            *([f"  merged depth rms: {rms}"] if rms else [])]


def _characterize(args: argparse.Namespace) -> int:
    if not (args.frames or args.target or args.edge):
        raise ValueError("give recordings: --frames (flat board), --target (small target) "
                         "and/or --edge (edge sweep)")
    params = sensor_params(load_scenario(filename=args.out if args.out.exists() else None))
    noise = directions = mixed = None
    if args.frames:
        noise = characterize(args.frames, args.distance_mm, args.min_frames,
                             lambda r: print(_recording_line(r)))
        print(f"sigma = max({noise.sigma0_mm:.2f} mm, {noise.k:.5f} d): knee "
              f"{noise.knee_mm:.0f} mm, rms residual {noise.rms_mm:.2f} mm over "
              f"{noise.n_points} zones")
        if noise.warning:
            print(f"warning: {noise.warning}", file=sys.stderr)
    if args.target:
        directions = characterize_directions(args.target, params.geometry)
        print(f"zone directions from {int(directions.hits.sum())} target sightings "
              f"({directions.hits.min()} to {directions.hits.max()} per zone)")
        if directions.stray.any():
            zones = [(int(r), int(c)) for r, c in zip(*directions.stray.nonzero(), strict=True)]
            print(f"warning: {int(directions.stray.sum())} target sightings apart from their "
                  f"zone's footprint left out, in zones (row, column) "
                  f"{', '.join(map(str, zones[:8]))}{' ...' if len(zones) > 8 else ''}: a "
                  f"reading at the target's depth from something else in the field of view",
                  file=sys.stderr)
        params = dc.replace(params, geometry=dc.replace(params.geometry,
                                                        centres_deg=directions.centres_deg))
    if args.edge:
        mixed = characterize_mixed_zones(args.edge, params)
        print("\n".join(_mixed_lines(mixed)))
        if mixed.warning:
            print(f"warning: {mixed.warning}", file=sys.stderr)
    fields = write_sensor_to_scenario(args.out, noise, directions, mixed,
                                      [*args.frames, *args.target, *args.edge])
    print(f"wrote sensor.{', sensor.'.join(fields)} to {args.out}")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    clash = [args.out / name for name in RECORDING_FILES.values() if (args.out / name).exists()]
    if clash and not args.overwrite:
        raise ValueError(f"--out {args.out} holds {', '.join(p.name for p in clash)}: choose "
                         f"another folder, or pass --overwrite to replace them")
    scenario = load_scenario(filename=args.scenario, data=args.scenario_text)
    simulate_recordings(scenario, args.out, on_recording=lambda kind, path, n: print(
        f"wrote {n} {kind} frames to {path}", flush=True))
    files = {kind: args.out / name for kind, name in RECORDING_FILES.items()}
    print(f"calibrate with: lrnbv sensor characterize --frames {files['flat']} --target "
          f"{files['target']} --edge {files['edge']} --out SCENARIO.yaml")
    return 0


def add_sensor_commands(subparsers: argparse._SubParsersAction) -> None:
    """Adds `sensor stream|record|characterize|simulate` to the `lrnbv` parser's
    subcommands."""
    sensor = subparsers.add_parser("sensor", help="the real VL53L8CX over serial, and "
                                                  "calibrating the sensor model",
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
                            help="fit the sensor model (noise, zone directions, mixed zones) "
                                 "to calibration recordings")
    p.add_argument("--frames", nargs="+", action="extend", default=[], metavar="FILE",
                   help="flat-board recordings (.npz, or a .tof journal): one per distance, "
                        "or holding each frame's distance (board_mm)")
    p.add_argument("--distance-mm", nargs="+", action="extend", type=float, metavar="D",
                   help="known perpendicular board distance of each --frames recording; the "
                        "fit then uses it for the zones on the board and reports the bias")
    p.add_argument("--target", nargs="+", action="extend", default=[], metavar="FILE",
                   help="small-target recordings (.npz with target_deg, target_mm per frame)")
    p.add_argument("--edge", nargs="+", action="extend", default=[], metavar="FILE",
                   help="edge-sweep recordings (.npz with edge_deg, near_mm, far_mm per "
                        "frame)")
    p.add_argument("--out", type=Path, required=True,
                   help="scenario YAML to write (merged into it if it exists; its sensor "
                        "section is the model refined, e.g. its zone flips)")
    p.add_argument("--min-frames", type=spread_count, default=10,
                   help="valid frames a zone needs to count in the noise fit (default 10, "
                        "at least 2: one frame has no spread)")

    p = commands.add_parser("simulate",
                            help="make the calibration recordings with the simulated device")
    p.add_argument("--scenario", help="scenario YAML file (its device: section and seed)")
    p.add_argument("--scenario-text", metavar="YAML",
                   help="scenario fields as YAML, over the file, e.g. "
                        "'{device: {profile: datasheet}}'")
    p.add_argument("--out", type=Path, required=True,
                   help=f"folder for {', '.join(RECORDING_FILES.values())}")
    p.add_argument("--overwrite", action="store_true", help="replace recordings in --out")


def run_sensor_command(args: argparse.Namespace) -> int:
    """Runs a command parsed by `add_sensor_commands`; returns the exit code."""
    try:
        if args.sensor_command == "stream":
            return _stream(args)
        if args.sensor_command == "record":
            return _record(args)
        if args.sensor_command == "simulate":
            return _simulate(args)
        return _characterize(args)
    except (ValueError, OSError, SensorError) as e:
        print(f"lrnbv sensor: error: {e}", file=sys.stderr)
        return 2

