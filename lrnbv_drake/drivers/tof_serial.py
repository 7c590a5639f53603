"""The real VL53L8CX: a serial driver that reads `$TOF` lines (core/sensing/tof_protocol.py) in a
background thread. The `ToFSerialReceiver` system puts its frames on the diagram's `tof_frame`
port.

The driver never blocks its callers on I/O: a thread owns the port, parses lines as they arrive
and keeps the newest frame (and optionally a queue of every frame). The thread survives the
board going away: it closes the port, retries opening it every `reconnect_interval` and resumes
when the device comes back (a USB re-plug, a board reset). Anything `serial.serial_for_url`
opens works, so tests use `loop://` or a pseudo-terminal instead of a board.
"""

from __future__ import annotations

import collections
import dataclasses as dc
import logging
import os
import threading
import time
from types import TracebackType

import serial
from serial.tools import list_ports

from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.core.sensing.tof_protocol import (
    FieldCountError,
    FieldValueError,
    FrameAssembler,
    LineTooLongError,
    MissingCrcError,
    UnsupportedResolutionError,
    UnsupportedVersionError,
    ValueRangeError,
)

_log = logging.getLogger(__name__)

#: Rejections whose CRC passed but whose content is wrong: the board formats badly.
_BAD_FIELD_REASONS = (
    FieldCountError.reason,
    FieldValueError.reason,
    UnsupportedVersionError.reason,
    UnsupportedResolutionError.reason,
    ValueRangeError.reason,
)
#: Rejections of lines that never reached their CRC: cut short by a reset or a lost byte run.
_TRUNCATED_REASONS = (MissingCrcError.reason, LineTooLongError.reason)


class SensorError(RuntimeError):
    """The serial sensor cannot do what was asked (not connected, write failed)."""


class SensorTimeout(SensorError, TimeoutError):
    """No suitable frame arrived in time; the message names the port and the silence."""


def describe_error(error: BaseException) -> str:
    """The reason of an I/O error, once: pyserial nests the OS error in its own message
    ("could not open port X: [Errno 2] No such file or directory: 'X'")."""
    errno = getattr(error, "errno", None)
    return os.strerror(errno) if isinstance(errno, int) else str(error)


def check_port_exists(port: str) -> None:
    """Raises SensorError at once for a device path (/dev/...) that does not exist, naming the
    serial ports that do: the driver itself waits for a missing device to appear (a board
    being plugged in), which at the start of a command is a mistyped or unplugged port."""
    if not port.startswith("/") or os.path.exists(port):
        return  # a URL (loop://, socket://) or a Windows name (COM3) is pyserial's to open
    ports = sorted(p.device for p in list_ports.comports())
    raise SensorError(f"no serial port {port}: " + (
        f"the ports here are {', '.join(ports)}" if ports else
        "no serial port is connected (is the board plugged in?)"))


def check_resolution(frame: ToFFrame, expected: int, port: str) -> None:
    """Raises SensorError when the board on `port` streams another zone layout than the
    scenario's `sensor.resolution`: the map, the planner and the estimator assume the
    scenario's (a board left at `RES 16` from a terminal, or another board)."""
    if frame.resolution != expected:
        got = frame.resolution
        raise SensorError(
            f"the sensor on {port} streams {got}x{got} zones but the scenario's "
            f"sensor.resolution is {expected}: send the board `RES {expected * expected}` "
            f"(docs/serial-protocol.md, section 5) or set the scenario to {got}")


@dc.dataclass
class SerialStats:
    """What the driver has seen since it started.

    Attributes:
        frames: frames accepted.
        bad_crc: lines dropped because the CRC was malformed or did not match.
        bad_fields: lines whose CRC passed but whose fields were wrong (count, integers,
            version, resolution, ranges).
        truncated: candidate lines that ended before their CRC or ran too long.
        gaps: times the sequence jumped forward by more than one.
        missed: frames those jumps skipped (lost on the wire or during an outage).
        restarts: times the sequence did not increase, i.e. the board restarted its count.
        reconnects: times the port was reopened after being lost.
        dropped: frames pushed out of a full `next_frame` queue before being read.
        garbage_bytes: bytes outside accepted frames (CR and LF not counted).
        rejected: every rejected candidate line by `FrameError.reason`.
    """

    frames: int = 0
    bad_crc: int = 0
    bad_fields: int = 0
    truncated: int = 0
    gaps: int = 0
    missed: int = 0
    restarts: int = 0
    reconnects: int = 0
    dropped: int = 0
    garbage_bytes: int = 0
    rejected: dict[str, int] = dc.field(default_factory=dict)


class ToFSerialReader:
    """Reads `$TOF` frames from a serial port in a daemon thread.

    Use it as a context manager, or call `start()` and `close()`:

        with ToFSerialReader("/dev/ttyACM0") as sensor:
            frame = sensor.wait_for_frame(0, timeout=2.0)

    Sequence numbers are the board's own (it starts at 1 and counts up); a sequence that does
    not increase means the board restarted, and after that the new count is the reference.
    """

    def __init__(
        self,
        port: str,
        baud: int = 460800,
        *,
        timeout: float = 0.05,
        reconnect_interval: float = 0.5,
        stale_after: float = 0.5,
        queue_size: int = 0,
    ) -> None:
        """
        Args:
            port: a device path (`/dev/ttyACM0`, `COM3`) or any `serial_for_url` URL.
            baud: line rate; ignored by native USB CDC boards.
            timeout: longest a single read blocks, seconds; bounds how fast `close()` returns.
            reconnect_interval: wait between attempts to reopen a lost port, seconds.
            stale_after: a frame older than this is stale (`latest()` returns None) and is
                the default wait of `wait_for_frame`, seconds. 0.5 s is 7 frames at 15 Hz;
                raise it for rates below 4 Hz.
            queue_size: keep up to this many unread frames for `next_frame` (0: no queue).
        """
        for name, value in (("timeout", timeout), ("reconnect_interval", reconnect_interval),
                            ("stale_after", stale_after)):
            if not value > 0:
                raise ValueError(f"{name} must be > 0; got {value}")
        if queue_size < 0:
            raise ValueError(f"queue_size must be >= 0; got {queue_size}")
        self._port_name = port
        self._baud = baud
        self._read_timeout = timeout
        self._reconnect_interval = reconnect_interval
        self._stale_after = stale_after
        self._queue_size = queue_size

        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._serial: serial.SerialBase | None = None
        self._assembler = FrameAssembler()
        self._counts = SerialStats()
        self._queue: collections.deque[ToFFrame] = collections.deque()
        self._latest: ToFFrame | None = None
        self._latest_time = 0.0
        self._started_time = 0.0
        self._last_error = ""

    @property
    def port(self) -> str:
        """The port or URL this driver reads."""
        return self._port_name

    @property
    def connected(self) -> bool:
        """Whether the port is open right now."""
        with self._cond:
            return self._serial is not None

    @property
    def stats(self) -> SerialStats:
        """A snapshot of the counters."""
        with self._cond:
            rejected = self._assembler.rejected
            return dc.replace(
                self._counts,
                bad_crc=rejected["bad_crc"],
                bad_fields=sum(rejected[r] for r in _BAD_FIELD_REASONS),
                truncated=sum(rejected[r] for r in _TRUNCATED_REASONS),
                garbage_bytes=self._assembler.garbage_bytes,
                rejected=dict(rejected),
            )

    def messages(self) -> list[str]:
        """The last few non-frame lines from the board: banners, `OK`/`ERR` replies."""
        with self._cond:
            return list(self._assembler.text_lines)

    def start(self) -> ToFSerialReader:
        """Starts the reader thread; it opens the port (and keeps reopening it) by itself."""
        if self._thread is not None:
            raise SensorError(f"the driver for {self._port_name} is already started")
        self._started_time = time.monotonic()
        self._thread = threading.Thread(
            target=self._run, name=f"tof-serial {self._port_name}", daemon=True
        )
        self._thread.start()
        return self

    def close(self) -> None:
        """Stops the reader thread and closes the port."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self._read_timeout + self._reconnect_interval + 2.0)
            if self._thread.is_alive():
                _log.warning("the reader thread of %s did not stop", self._port_name)

    def __enter__(self) -> ToFSerialReader:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def latest(self, allow_stale: bool = False) -> ToFFrame | None:
        """The newest frame; None before the first one, or when it is older than
        `stale_after` unless `allow_stale`."""
        with self._cond:
            if self._latest is None:
                return None
            if not allow_stale and time.monotonic() - self._latest_time > self._stale_after:
                return None
            return self._latest

    def wait_for_frame(
        self, newer_than_sequence: int = 0, timeout: float | None = None
    ) -> ToFFrame:
        """Waits for the newest frame to have a sequence above `newer_than_sequence`.

        Pass the sequence of a frame already used to get the next one, or that plus n to
        skip n frames (e.g. the frames still exposed during a motion). After a board restart
        the sequence falls back; take the reference from `latest()` again.

        Args:
            newer_than_sequence: 0 accepts any frame (the board counts from 1).
            timeout: seconds; default `stale_after`.

        Raises:
            SensorTimeout: naming the port, how long it has been silent, or why the frames
                that did arrive were not new enough.
        """
        timeout = self._stale_after if timeout is None else timeout
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                frame = self._latest
                if frame is not None and frame.sequence > newer_than_sequence:
                    return frame
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise SensorTimeout(self._explain_timeout(newer_than_sequence, timeout))
                self._cond.wait(remaining)

    def next_frame(self, timeout: float | None = None) -> ToFFrame:
        """Pops the oldest unread frame, so that a recorder sees every frame in order even
        when it is slower than the board for a while. Needs `queue_size > 0`.

        Raises:
            SensorTimeout: no frame within `timeout` seconds (default `stale_after`).
        """
        if self._queue_size == 0:
            raise SensorError("next_frame needs a driver made with queue_size > 0")
        timeout = self._stale_after if timeout is None else timeout
        deadline = time.monotonic() + timeout
        with self._cond:
            while not self._queue:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise SensorTimeout(self._describe_silence() + f"; waited {timeout:.2f} s")
                self._cond.wait(remaining)
            return self._queue.popleft()

    def write(self, data: bytes) -> None:
        """Writes raw bytes to the board (with `loop://` they come straight back).

        Raises:
            SensorError: the port is not open or the write failed.
        """
        with self._cond:
            port = self._serial
        if port is None:
            raise SensorError(f"{self._port_name} is not connected"
                              + (f" ({self._last_error})" if self._last_error else ""))
        try:
            port.write(data)
            port.flush()
        except (serial.SerialException, OSError) as e:
            raise SensorError(f"writing to {self._port_name} failed: {e}") from e

    def send_command(self, command: str) -> None:
        """Sends one command line (`RES 64`, `FREQ 15`, `INFO`, ...; docs/serial-protocol.md).
        The board answers with an `OK ...` or `ERR ...` line, which `messages()` shows."""
        if not command.isascii() or "\r" in command or "\n" in command or "$" in command:
            raise ValueError(f"a command is one ASCII line without '$'; got {command!r}")
        self.write(command.encode() + b"\r\n")

    # --- Reader thread ---------------------------------------------------------------------

    def _run(self) -> None:
        opened_before = False
        while not self._stop.is_set():
            try:
                port = serial.serial_for_url(
                    self._port_name, baudrate=self._baud, timeout=self._read_timeout
                )
            except (serial.SerialException, OSError, ValueError) as e:
                self._note_error(f"cannot open {self._port_name}: {describe_error(e)}")
                self._stop.wait(self._reconnect_interval)
                continue
            with self._cond:
                if opened_before:
                    self._counts.reconnects += 1
                    _log.info("reopened %s", self._port_name)
                self._serial = port
                self._last_error = ""
            opened_before = True
            try:
                while not self._stop.is_set():
                    data = port.read(max(1, port.in_waiting))
                    if data:
                        self._feed(data)
            except (serial.SerialException, OSError) as e:
                self._note_error(f"lost {self._port_name}: {e}")
            finally:
                with self._cond:
                    self._serial = None
                    self._deliver(self._assembler.flush())
                port.close()
            self._stop.wait(self._reconnect_interval)

    def _note_error(self, message: str) -> None:
        with self._cond:
            if message != self._last_error:
                _log.warning("%s", message)
            self._last_error = message

    def _feed(self, data: bytes) -> None:
        with self._cond:
            self._deliver(self._assembler.feed(data))

    def _deliver(self, frames: list[ToFFrame]) -> None:
        """Counts and publishes frames; call with the lock held."""
        if not frames:
            return
        now = time.monotonic()
        counts = self._counts
        for frame in frames:
            if self._latest is not None:
                step = frame.sequence - self._latest.sequence
                if step > 1:
                    counts.gaps += 1
                    counts.missed += step - 1
                elif step < 1:
                    counts.restarts += 1
            counts.frames += 1
            self._latest, self._latest_time = frame, now
            if self._queue_size:
                if len(self._queue) == self._queue_size:
                    self._queue.popleft()
                    counts.dropped += 1
                self._queue.append(frame)
        self._cond.notify_all()

    # --- Diagnostics -----------------------------------------------------------------------

    def _describe_silence(self) -> str:
        """Why no frame came; call with the lock held."""
        now = time.monotonic()
        if self._latest is None:
            text = (f"no frame from {self._port_name} in the {now - self._started_time:.2f} s "
                    f"since the driver started")
        else:
            text = (f"no frame from {self._port_name} for {now - self._latest_time:.2f} s "
                    f"(last sequence {self._latest.sequence})")
        if self._serial is None:
            text += "; the port is not open" + (f" ({self._last_error})"
                                                 if self._last_error else "")
        if self._assembler.last_rejection:
            text += f"; last rejected line: {self._assembler.last_rejection}"
        if self._assembler.text_lines:
            text += f"; last text from the board: {self._assembler.text_lines[-1][:80]!r}"
        return text

    def _explain_timeout(self, newer_than_sequence: int, timeout: float) -> str:
        """Call with the lock held."""
        silence = time.monotonic() - self._latest_time
        if self._latest is None or silence > self._stale_after or self._serial is None:
            return self._describe_silence() + f"; waited {timeout:.2f} s"
        text = (f"frames from {self._port_name} are arriving (latest sequence "
                f"{self._latest.sequence}, {silence:.2f} s ago) but none newer than "
                f"{newer_than_sequence} came within {timeout:.2f} s")
        if self._counts.restarts:
            text += (f"; the board restarted its count {self._counts.restarts} time(s): take "
                     f"the reference sequence from latest() again")
        return text
