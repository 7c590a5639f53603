"""ToFSerialReader against a fake board on a pseudo-terminal, its LeafSystem, and the
`lrnbv sensor` commands. Every wait is bounded; nothing asserts on how long anything took."""

from __future__ import annotations

import binascii
import contextlib
import os
import select
import threading
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from lrnbv_drake.cli.main import main
from lrnbv_drake.core.calibration.sensor_model import fit_noise_model
from lrnbv_drake.core.sensing.sensor import NoiseModel, ToFFrame
from lrnbv_drake.core.sensing.tof_protocol import encode_frame
from lrnbv_drake.drivers.tof_serial import (
    SensorError,
    SensorTimeout,
    ToFSerialReader,
)
from lrnbv_drake.experiments.recording import (
    frames_to_arrays,
    load_recording,
    write_npz_atomically,
)
from lrnbv_drake.station.scenario import load_scenario
from lrnbv_drake.systems.tof_serial_receiver import ToFSerialReceiver

WAIT = 5.0  # upper bound of every wait; a passing run never comes near it


def _eventually(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {WAIT} s: {what}")
        time.sleep(0.005)


def _frame(sequence: int) -> ToFFrame:
    """A distinct, reproducible 8x8 frame per sequence number."""
    rng = np.random.default_rng(sequence)
    return ToFFrame(
        distance_mm=rng.integers(20, 4000, (8, 8)),
        status=np.where(rng.random((8, 8)) < 0.9, 5, 255),
        sigma_mm=rng.integers(0, 50, (8, 8)),
        sequence=sequence,
        timestamp_us=sequence * 66_667,
    )


def _assert_same(a: ToFFrame, b: ToFFrame) -> None:
    assert (a.sequence, a.timestamp_us) == (b.sequence, b.timestamp_us)
    for name in ("distance_mm", "status", "sigma_mm"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


class FakeBoard:
    """The board's end of a pseudo-terminal. The driver opens `path`, a symlink to the slave
    device, so that `unplug` + `plug` (a new pty, the link re-pointed) looks like a USB device
    that went away and came back under the same name."""

    def __init__(self, directory: Path) -> None:
        self.path = directory / "ttyTOF"
        self._master = self._slave = -1
        self.plug()

    def plug(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo or CR translation before the driver opens it
        os.set_blocking(self._master, False)
        link = self.path.with_name("ttyTOF.new")
        os.symlink(os.ttyname(self._slave), link)
        os.replace(link, self.path)

    def unplug(self) -> None:
        self.path.unlink()
        os.close(self._master)
        os.close(self._slave)
        self._master = self._slave = -1

    def close(self) -> None:
        if self._master >= 0:
            self.unplug()

    def write(self, data: bytes, stop: threading.Event | None = None) -> None:
        """Writes all of `data` unless `stop` is set first."""
        view = memoryview(data)
        deadline = time.monotonic() + WAIT
        while view and not (stop is not None and stop.is_set()):
            assert time.monotonic() < deadline, "the driver stopped reading"
            if select.select([], [self._master], [], 0.05)[1]:
                with contextlib.suppress(BlockingIOError):
                    view = view[os.write(self._master, view):]

    def read(self, n: int) -> bytes:
        """Reads what the driver sent, `n` bytes."""
        out = b""
        deadline = time.monotonic() + WAIT
        while len(out) < n and time.monotonic() < deadline:
            if select.select([self._master], [], [], 0.05)[0]:
                out += os.read(self._master, n - len(out))
        return out


@contextlib.contextmanager
def streaming(board: FakeBoard) -> Iterator[None]:
    """The board streaming frames 1, 2, 3, ... in a thread until the block ends."""
    stop = threading.Event()

    def run() -> None:
        sequence = 1
        while not stop.is_set():
            board.write(encode_frame(_frame(sequence)), stop)
            sequence += 1
            stop.wait(0.005)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(WAIT)


@pytest.fixture
def board(tmp_path: Path) -> Iterator[FakeBoard]:
    fake = FakeBoard(tmp_path)
    yield fake
    fake.close()


@pytest.fixture
def sensor(board: FakeBoard) -> Iterator[ToFSerialReader]:
    with ToFSerialReader(str(board.path), reconnect_interval=0.05, stale_after=0.3) as driver:
        # Opening flushes the input, so the board writes only once the port is open.
        _eventually(lambda: driver.connected, "the driver opens the pty")
        yield driver


# --- Driver ---------------------------------------------------------------------------------


def test_clean_frames_arrive_in_order(board: FakeBoard, sensor: ToFSerialReader) -> None:
    board.write(b"".join(encode_frame(_frame(s)) for s in (1, 2, 3)))
    _assert_same(sensor.wait_for_frame(2, timeout=WAIT), _frame(3))
    stats = sensor.stats
    assert (stats.frames, stats.gaps, stats.missed, stats.bad_crc, stats.garbage_bytes) == (
        3, 0, 0, 0, 0)


def test_garbage_cut_lines_and_bad_lines_are_dropped_and_counted(
    board: FakeBoard, sensor: ToFSerialReader
) -> None:
    banner, noise = b"vl53l8cx_tof_stream boot", b"\x00\xff~noise"
    cut = encode_frame(_frame(2))[:60]  # a reset mid-line: no CRC, ended by the next '$'
    good = encode_frame(_frame(4))
    bad_crc = good[:20] + (b"7" if good[20:21] != b"7" else b"8") + good[21:]
    body = encode_frame(_frame(5))[1:-7] + b",0"  # one field too many, under a valid CRC
    bad_fields = b"$%s*%04X\r\n" % (body, binascii.crc_hqx(body, 0xFFFF))
    board.write(banner + b"\r\n" + encode_frame(_frame(1)) + noise + cut
                + encode_frame(_frame(3)) + bad_crc + bad_fields + encode_frame(_frame(6)))

    _assert_same(sensor.wait_for_frame(5, timeout=WAIT), _frame(6))
    stats = sensor.stats
    assert (stats.frames, stats.bad_crc, stats.bad_fields, stats.truncated) == (3, 1, 1, 1)
    assert (stats.gaps, stats.missed, stats.restarts) == (2, 1 + 2, 0)  # 1, 3, 6 accepted
    assert stats.garbage_bytes == (len(banner) + len(noise) + len(cut) + len(bad_crc) - 2
                                   + len(bad_fields) - 2)
    assert stats.rejected == {"no_crc": 1, "bad_crc": 1, "bad_field_count": 1}
    assert sensor.messages() == [banner.decode(), "\x00\ufffd~noise"]


def test_sequence_gaps_and_board_restarts_are_counted(
    board: FakeBoard, sensor: ToFSerialReader
) -> None:
    board.write(b"".join(encode_frame(_frame(s)) for s in (1, 2, 5, 6, 10)))
    sensor.wait_for_frame(9, timeout=WAIT)
    board.write(b"".join(encode_frame(_frame(s)) for s in (1, 2)))  # the board reset
    _eventually(lambda: sensor.stats.frames == 7, "all seven frames parsed")
    stats = sensor.stats
    assert (stats.gaps, stats.missed, stats.restarts) == (2, 2 + 3, 1)
    assert sensor.latest().sequence == 2
    with pytest.raises(SensorTimeout, match=r"none newer than 10 .*restarted its count 1 time"):
        # Within the fixture's stale_after (0.3 s) even on a loaded machine.
        sensor.wait_for_frame(10, timeout=0.02)


def test_silence_makes_the_frame_stale_and_waits_time_out(
    board: FakeBoard, sensor: ToFSerialReader
) -> None:
    with pytest.raises(SensorTimeout, match=f"no frame from {board.path} in the [0-9.]+ s "
                                            f"since the driver started"):
        sensor.wait_for_frame(0, timeout=0.05)
    board.write(b"OK BOOT\r\n" + encode_frame(_frame(1)))
    sensor.wait_for_frame(0, timeout=WAIT)
    _eventually(lambda: sensor.latest() is None, "the frame goes stale")
    assert sensor.latest(allow_stale=True).sequence == 1
    with pytest.raises(SensorTimeout, match=f"no frame from {board.path} for [0-9]+\\.[0-9]{{2}}"
                                            f" s \\(last sequence 1\\).*'OK BOOT'"):
        sensor.wait_for_frame(1, timeout=0.05)


def test_the_port_vanishing_and_returning_reconnects(
    board: FakeBoard, sensor: ToFSerialReader
) -> None:
    board.write(encode_frame(_frame(1)))
    sensor.wait_for_frame(0, timeout=WAIT)
    board.unplug()
    _eventually(lambda: not sensor.connected, "the driver notices the pty is gone")
    with pytest.raises(SensorTimeout, match=f"{board.path}.*the port is not open"):
        sensor.wait_for_frame(1, timeout=0.05)
    with pytest.raises(SensorError, match="not connected"):
        sensor.send_command("INFO")

    board.plug()
    _eventually(lambda: sensor.connected, "the driver reopens the path")
    board.write(encode_frame(_frame(2)))
    _assert_same(sensor.wait_for_frame(1, timeout=WAIT), _frame(2))
    stats = sensor.stats
    assert (stats.reconnects, stats.frames, stats.gaps, stats.restarts) == (1, 2, 0, 0)


def test_a_missing_port_fails_at_once_and_says_why_once(tmp_path: Path, capsys) -> None:
    missing = tmp_path / "ttyACM9"
    codes: list[int] = []
    stream = threading.Thread(target=lambda: codes.append(
        main(["sensor", "stream", "--port", str(missing), "--timeout", "0.1"])), daemon=True)
    stream.start()
    stream.join(WAIT)  # it used to wait for the port for ever, "waiting: ..." every timeout
    assert main(["sensor", "record", "--port", str(missing), "--frames", "1", "--timeout",
                 "0.1", "--out", str(tmp_path / "r.npz")]) == 2
    assert codes == [2]
    assert capsys.readouterr().err.count(f"no serial port {missing}: ") == 2
    # The driver itself waits for a device to appear; its reason is given once, not nested
    # in pyserial's "could not open port ...: [Errno 2] ...".
    with ToFSerialReader(str(missing), reconnect_interval=0.05) as driver:
        def reason() -> str:
            try:
                driver.wait_for_frame(0, timeout=0.01)
            except SensorTimeout as e:
                return str(e)
            return ""

        _eventually(lambda: "cannot open" in reason(), "the driver tries to open the port")
        assert f"(cannot open {missing}: No such file or directory)" in reason()
        assert "could not open port" not in reason() and "Errno" not in reason()


def test_commands_reach_the_board_and_replies_come_back(
    board: FakeBoard, sensor: ToFSerialReader
) -> None:
    sensor.send_command("RES 64")
    assert board.read(8) == b"RES 64\r\n"
    board.write(b"OK RES 64\r\n")
    _eventually(lambda: sensor.messages() == ["OK RES 64"], "the reply is kept")
    with pytest.raises(ValueError, match="one ASCII line"):
        sensor.send_command("RES 64\nSTOP")


def test_loop_url_and_the_frame_queue() -> None:
    with ToFSerialReader("loop://", queue_size=2) as dut:
        _eventually(lambda: dut.connected, "loop:// opens")
        dut.write(b"".join(encode_frame(_frame(s)) for s in (1, 2, 3)))
        _eventually(lambda: dut.stats.frames == 3, "three frames looped back")
        assert [dut.next_frame(WAIT).sequence for _ in range(2)] == [2, 3]
        assert dut.stats.dropped == 1
        with pytest.raises(SensorTimeout):
            dut.next_frame(timeout=0.05)
    with pytest.raises(SensorError, match="queue_size"):
        ToFSerialReader("loop://").next_frame(0.05)


def test_system_copies_the_drivers_frame_to_tof_frame() -> None:
    with ToFSerialReader("loop://") as driver:
        dut = ToFSerialReceiver(driver, period=0.1)
        simulator = Simulator(dut)
        context = simulator.get_mutable_context()
        tof_frame = dut.GetOutputPort("tof_frame")
        assert dut.get_tof_frame_output_port() is tof_frame

        simulator.AdvanceTo(0.05)  # the t = 0 update finds no frame: the empty one stays
        assert tof_frame.Eval(context).sequence == 0
        assert not tof_frame.Eval(context).valid.any()

        _eventually(lambda: driver.connected, "loop:// opens")
        driver.write(encode_frame(_frame(7)))
        driver.wait_for_frame(0, timeout=WAIT)
        assert tof_frame.Eval(context).sequence == 0  # nothing changes between updates
        simulator.AdvanceTo(0.15)
        _assert_same(tof_frame.Eval(context), _frame(7))


def test_system_stops_on_a_frame_of_another_resolution() -> None:
    """A board left at `RES 16` must not feed 4x4 frames to a diagram built for 8x8."""
    four = ToFFrame(distance_mm=np.full((4, 4), 500), status=np.full((4, 4), 5),
                    sigma_mm=np.full((4, 4), 3), sequence=1, timestamp_us=0)
    with ToFSerialReader("loop://") as driver:
        dut = ToFSerialReceiver(driver, period=0.1, resolution=8)
        simulator = Simulator(dut)
        _eventually(lambda: driver.connected, "loop:// opens")
        driver.write(encode_frame(four))
        driver.wait_for_frame(0, timeout=WAIT)
        with pytest.raises(SensorError, match=r"loop:// streams 4x4 zones but the scenario's "
                                              r"sensor\.resolution is 8: send the board `RES 64`"):
            simulator.AdvanceTo(0.15)


# --- Commands -------------------------------------------------------------------------------


def test_record_writes_every_frame_in_order(board: FakeBoard, tmp_path: Path) -> None:
    out = tmp_path / "rec" / "flat.npz"
    with streaming(board):
        code = main(["sensor", "record", "--port", str(board.path), "--frames", "5",
                     "--out", str(out), "--timeout", str(WAIT)])
    assert code == 0
    assert not out.with_suffix(".tof").exists()
    rec = load_recording(out)
    assert rec["distance_mm"].shape == (5, 8, 8)
    np.testing.assert_array_equal(np.diff(rec["sequence"]), 1)
    for i, sequence in enumerate(rec["sequence"]):
        expected = frames_to_arrays([_frame(int(sequence))])
        for key, value in expected.items():
            np.testing.assert_array_equal(rec[key][i], value[0])


def test_a_journal_cut_by_a_crash_still_loads(tmp_path: Path, board: FakeBoard) -> None:
    journal = tmp_path / "flat.tof"
    journal.write_bytes(b"".join(encode_frame(_frame(s)) for s in (1, 2, 3))
                        + encode_frame(_frame(4))[:100])
    np.testing.assert_array_equal(load_recording(journal)["sequence"], [1, 2, 3])
    # ... and record refuses to append to it.
    assert main(["sensor", "record", "--port", str(board.path), "--frames", "1",
                 "--out", str(tmp_path / "flat.npz")]) == 2


def test_stream_shows_frames_and_stats(board: FakeBoard, capsys) -> None:
    with streaming(board):
        assert main(["sensor", "stream", "--port", str(board.path), "--frames", "3"]) == 0
    out = capsys.readouterr().out
    assert out.count("raw zone order") == 3
    assert "'.' no target" in out and "frames " in out


# --- Noise characterization -----------------------------------------------------------------


def test_fit_recovers_a_noise_free_model_exactly() -> None:
    # sigma = max(5, 0.02 d): knee at 250 mm, two points on each piece.
    fit = fit_noise_model(np.array([800.0, 100, 400, 200]), np.array([16.0, 5, 8, 5]))
    assert fit.sigma0_mm == pytest.approx(5.0, abs=1e-12)
    assert fit.k == pytest.approx(0.02, abs=1e-15)
    assert fit.rms_mm == pytest.approx(0.0, abs=1e-12) and not fit.warning


def test_fit_refuses_one_distance_and_warns_without_a_knee() -> None:
    with pytest.raises(ValueError, match="two or more distinct distances"):
        fit_noise_model(np.full(10, 500.0), np.full(10, 7.0))
    fit = fit_noise_model(np.array([100.0, 200, 300]), np.array([5.0, 5, 5]))
    assert fit.sigma0_mm == pytest.approx(5.0) and "do not straddle" in fit.warning


@pytest.mark.parametrize("known_distance", [False, True])
def test_characterize_recovers_sigma0_and_k(tmp_path: Path, known_distance: bool) -> None:
    truth = NoiseModel(sigma0_mm=6.0, k=0.012)  # knee at 500 mm
    rng = np.random.default_rng(11)
    distances = [150, 300, 450, 600, 800, 1000]
    files = []
    for d in distances:
        frames = []
        for seq in range(1, 151):
            reading = np.rint(d + truth.sigma_mm(d) * rng.standard_normal((8, 8)))
            status = np.full((8, 8), 5)
            status[0, 0] = 255  # a zone that never sees the target
            frames.append(ToFFrame(reading, status, np.full((8, 8), 9), sequence=seq))
        files.append(tmp_path / f"flat_{d}.npz")
        write_npz_atomically(files[-1], frames_to_arrays(frames))
    scenario = tmp_path / "cell.yaml"
    scenario.write_text("seed: 4\nsensor:\n  resolution: 8\n  sigma0_mm: 1.0\n")

    args = ["sensor", "characterize", "--frames", *map(str, files), "--out", str(scenario)]
    if known_distance:
        args += ["--distance-mm", *map(str, distances)]
    assert main(args) == 0
    loaded = load_scenario(filename=scenario)
    assert loaded.seed == 4 and loaded.sensor.resolution == 8
    assert loaded.sensor.sigma0_mm == pytest.approx(truth.sigma0_mm, rel=0.08)
    assert loaded.sensor.noise_k == pytest.approx(truth.k, rel=0.08)
