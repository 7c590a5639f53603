"""Recordings on disk: the one atomic write every output goes through, the one layout frames
take as arrays (a sensor recording's .npz, an episode's frames.npz), and the real cell's
journal of acquisitions.

An atomic write leaves either the old file or the new one, never half of either, even when
the process or the machine dies in the middle: the bytes go to a temporary file in the same
folder, are flushed to the disk, renamed over the target, and the folder itself is synced so
the rename survives a power cut.
"""

from __future__ import annotations

import io
import json
import logging
import os
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from lrnbv_drake.core.acquisition import Acquisition
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.core.sensing.tof_protocol import FrameAssembler
from lrnbv_drake.experiments.report import json_default

_log = logging.getLogger(__name__)


class RecordingError(ValueError):
    """A recording on disk that cannot be read back."""


def _fsync_dir(folder: Path) -> None:
    """Makes a rename in `folder` durable (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # Windows cannot open a folder; its rename is durable on its own
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomically(path: str | Path, data: bytes | str) -> None:
    """Replaces `path` by `data` (str as UTF-8) so that readers and crashes see the old
    content or the new one, never a mix; an error leaves the old file and no temporary one."""
    path = Path(path)
    payload = data.encode() if isinstance(data, str) else data
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp")
    # Not mkstemp: its 0600 would make the file private; this gets the umask's usual mode.
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def write_npz_atomically(path: str | Path, arrays: Mapping[str, np.ndarray]) -> None:
    """An uncompressed .npz of `arrays`, written by `write_atomically`."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    write_atomically(path, buffer.getvalue())


def frames_to_arrays(frames: Sequence[ToFFrame]) -> dict[str, np.ndarray]:
    """Stacks frames (raw zone order) into distance_mm, status, sigma_mm (frames, res, res)
    and int64 sequence and timestamp_us: signed, so differences of either never wrap."""
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
        "timestamp_us": np.array([f.timestamp_us for f in frames], np.int64),
    }


def frames_from_arrays(arrays: Mapping[str, np.ndarray]) -> list[ToFFrame]:
    """The frames `frames_to_arrays` stacked, back one by one."""
    return [ToFFrame(distance_mm=arrays["distance_mm"][i], status=arrays["status"][i],
                     sigma_mm=arrays["sigma_mm"][i], sequence=int(arrays["sequence"][i]),
                     timestamp_us=int(arrays["timestamp_us"][i]))
            for i in range(len(arrays["distance_mm"]))]


def load_recording(path: str | Path) -> dict[str, np.ndarray]:
    """Loads a recording: an .npz (timestamps as int64, also from older files that stored
    uint64), or a `$TOF` journal, e.g. left by a crash (a cut-off last line fails its CRC and
    is skipped)."""
    path = Path(path)
    if path.suffix == ".npz":
        with np.load(path) as data:
            arrays = {key: data[key] for key in data.files}
        if "timestamp_us" in arrays:
            arrays["timestamp_us"] = arrays["timestamp_us"].astype(np.int64)
        return arrays
    assembler = FrameAssembler()
    frames = assembler.feed(path.read_bytes()) + assembler.flush()
    if not frames:
        raise ValueError(f"{path}: no valid $TOF line")
    return frames_to_arrays(frames)


def save_frames(path: str | Path, acquisitions: Sequence[Acquisition]) -> None:
    """An episode's frames.npz: its frames (`frames_to_arrays`) with each one's sensor pose
    `X_WS` (n, 4, 4), joints `q` (n, 6) and diagram `time` (n,); empty arrays for none."""
    if acquisitions:
        arrays = frames_to_arrays([a.frame for a in acquisitions])
    else:
        empty = ToFFrame.empty()
        arrays = {key: value[:0] for key, value in frames_to_arrays([empty]).items()}
    arrays.update(X_WS=np.array([a.X_WS for a in acquisitions], float).reshape(-1, 4, 4),
                  q=np.array([a.q for a in acquisitions], float).reshape(-1, 6),
                  time=np.array([a.time for a in acquisitions], float))
    write_npz_atomically(path, arrays)


def acquisition_to_json(a: Acquisition) -> str:
    """One journal line (no newline)."""
    f = a.frame
    return json.dumps({
        "index": a.index, "time": a.time, "q": a.q, "X_WS": a.X_WS,
        "frame": {"sequence": f.sequence, "timestamp_us": f.timestamp_us,
                  "distance_mm": f.distance_mm, "status": f.status, "sigma_mm": f.sigma_mm},
        "info": a.info,
    }, default=json_default)


def acquisition_from_json(line: str) -> Acquisition:
    d = json.loads(line)
    f = d["frame"]
    frame = ToFFrame(distance_mm=np.array(f["distance_mm"]), status=np.array(f["status"]),
                     sigma_mm=np.array(f["sigma_mm"]), sequence=f["sequence"],
                     timestamp_us=f["timestamp_us"])
    return Acquisition(index=d["index"], time=d["time"], q=np.array(d["q"], float),
                       X_WS=np.array(d["X_WS"], float), frame=frame, info=d["info"])


class AcquisitionJournal:
    """`acquisitions.jsonl`: an append-only file with one acquisition per line, each fsynced
    before `append` returns, so a crash loses at most the line being written."""

    def __init__(self, path: Path) -> None:
        self.path = path

    @property
    def torn_path(self) -> Path:
        """Where `append` moves a torn line's bytes (`<journal>.torn`)."""
        return self.path.with_name(self.path.name + ".torn")

    def append(self, acquisition: Acquisition) -> None:
        """Appends one line and fsyncs it. A torn line left at the end (a crash or a full disk
        mid-write, which `load` drops) is first moved to `torn_path`: written after it, this
        line would join it, and `load` would drop both or fail on every later resume."""
        line = (acquisition_to_json(acquisition) + "\n").encode()
        with self.path.open("ab+") as f:
            end = f.seek(0, os.SEEK_END)
            f.seek(max(end - 1, 0))
            if end and f.read(1) != b"\n":
                f.seek(0)
                data = f.read()
                start = data.rfind(b"\n") + 1
                with self.torn_path.open("ab") as torn:
                    torn.write(data[start:] + b"\n")
                    torn.flush()
                    os.fsync(torn.fileno())
                f.truncate(start)
                _log.warning("%s: moved a torn last line to %s", self.path, self.torn_path)
            f.write(line)
            f.flush()
            os.fsync(f.fileno())

    def load(self) -> list[Acquisition]:
        """The recorded acquisitions; a torn last line (a crash mid-write) is dropped."""
        if not self.path.exists():
            return []
        lines = self.path.read_text().splitlines()
        acquisitions = []
        for i, line in enumerate(lines):
            try:
                acquisitions.append(acquisition_from_json(line))
            except (json.JSONDecodeError, KeyError, ValueError) as e:
                if i == len(lines) - 1:
                    _log.warning("%s: dropping a torn last line (%s)", self.path, e)
                    break
                raise RecordingError(f"{self.path}, line {i + 1}: not an acquisition ({e})") \
                    from e
        return acquisitions
