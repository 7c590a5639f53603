"""experiments.recording: the atomic write keeps the old file or the new one, never half of
either, and frames keep their int64 timestamps through an .npz and back."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.core.sensing.tof_protocol import encode_frame
from lrnbv_drake.experiments import recording
from lrnbv_drake.experiments.recording import (
    frames_to_arrays,
    load_recording,
    write_atomically,
    write_npz_atomically,
)

BIG_US = 2**31 + 12_345  # beyond int32: a board up for 36 minutes


def _frame(sequence: int, timestamp_us: int) -> ToFFrame:
    distance = np.arange(64, dtype=np.int16).reshape(8, 8) + sequence
    return ToFFrame(distance, np.full((8, 8), 5), np.full((8, 8), 3), sequence, timestamp_us)


def test_write_replaces_text_and_bytes(tmp_path: Path) -> None:
    path = tmp_path / "record.json"
    write_atomically(path, "old")
    write_atomically(path, b"\x00new\n")
    assert path.read_bytes() == b"\x00new\n"
    assert os.listdir(tmp_path) == ["record.json"]


@pytest.mark.parametrize("failing", ["replace", "write"])
def test_a_failed_write_keeps_the_old_file_and_no_temporary(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, failing: str) -> None:
    path = tmp_path / "record.json"
    path.write_text("old content")

    def fail(*args: object) -> None:
        raise OSError("disk pulled")

    if failing == "replace":
        monkeypatch.setattr(recording.os, "replace", fail)
    else:
        monkeypatch.setattr(recording.os, "fsync", fail)  # after the bytes, before the rename
    with pytest.raises(OSError, match="disk pulled"):
        write_atomically(path, "new content")
    assert path.read_text() == "old content"
    assert os.listdir(tmp_path) == ["record.json"]


def test_int64_timestamps_round_trip(tmp_path: Path) -> None:
    frames = [_frame(1, BIG_US), _frame(2, BIG_US + 66_000), _frame(3, 2**40)]
    arrays = frames_to_arrays(frames)
    assert arrays["timestamp_us"].dtype == np.int64 and arrays["sequence"].dtype == np.int64
    path = tmp_path / "rec.npz"
    write_npz_atomically(path, arrays)
    loaded = load_recording(path)
    assert loaded["timestamp_us"].dtype == np.int64
    np.testing.assert_array_equal(loaded["timestamp_us"], [BIG_US, BIG_US + 66_000, 2**40])
    for key, value in arrays.items():
        np.testing.assert_array_equal(loaded[key], value)
    # A journal gives the same arrays as the .npz made from it.
    journal = tmp_path / "rec.tof"
    journal.write_bytes(b"".join(encode_frame(f) for f in frames))
    from_journal = load_recording(journal)
    assert from_journal["timestamp_us"].dtype == np.int64
    for key, value in arrays.items():
        np.testing.assert_array_equal(from_journal[key], value)


def test_a_recording_with_uint64_timestamps_still_loads(tmp_path: Path) -> None:
    old = frames_to_arrays([_frame(1, BIG_US), _frame(2, BIG_US + 1)])
    old["timestamp_us"] = old["timestamp_us"].astype(np.uint64)  # what `record` used to write
    path = tmp_path / "old.npz"
    np.savez(path, **old)
    loaded = load_recording(path)
    assert loaded["timestamp_us"].dtype == np.int64
    np.testing.assert_array_equal(loaded["timestamp_us"], [BIG_US, BIG_US + 1])
    assert np.diff(loaded["timestamp_us"])[0] == 1
