"""The real VL53L8CX over serial: record frames to an .npz, watch them live, and fit the
simulator's noise model to recordings of a flat target into a scenario file.

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

from lrnbv_drake.core.sensor import ToFFrame
from lrnbv_drake.core.sensor_calibration import (
    NoiseFit,
    ZoneNoise,
    fit_noise_model,
    on_target,
    zone_noise,
)
from lrnbv_drake.core.tof_protocol import encode_frame
from lrnbv_drake.drivers.tof_serial import (
    SensorTimeout,
    SerialStats,
    ToFSerialReader,
    check_port_exists,
)
from lrnbv_drake.experiments.recording import (
    load_recording,
    write_atomically,
    write_npz_atomically,
)
from lrnbv_drake.station.scenario import load_scenario

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


# --- Noise characterization ------------------------------------------------------------------


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


def characterize(files: Sequence[str], distances_mm: Sequence[float] | None, min_frames: int,
                 on_recording: Callable[[RecordingNoise], object] | None = None) -> NoiseFit:
    """Fits sigma = max(sigma0, k d) to flat-target recordings (one per distance);
    `on_recording` sees each one's zones as it is read."""
    if distances_mm is not None and len(distances_mm) != len(files):
        raise ValueError(f"--distance-mm takes one distance per --frames file: got "
                         f"{len(distances_mm)} for {len(files)} files")
    used = []
    for i, name in enumerate(files):
        noise = zone_noise(load_recording(name), min_frames=min_frames)
        target = None if distances_mm is None else distances_mm[i]
        entry = RecordingNoise(name, noise.mean_mm.size,
                               noise if target is None else on_target(noise, target), target)
        if on_recording is not None:
            on_recording(entry)
        used.append(entry)
    return fit_noise_model(np.concatenate([r.distances_mm for r in used]),
                           np.concatenate([r.noise.std_mm for r in used]))


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
    write_atomically(path, text)
