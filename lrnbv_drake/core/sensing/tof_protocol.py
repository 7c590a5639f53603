"""The `$TOF` line protocol between the sensor board and the PC (docs/serial-protocol.md).

One ASCII line per frame, in the driver's raw zone order:

    $TOF,<ver>,<seq>,<t_us>,<res>,<res distances>,<res statuses>,<res sigmas>*<CRC16>\\r\\n

Plain text so that a terminal shows it and a boot banner or debug print cannot be mistaken for
a frame; a CRC-16/CCITT-FALSE over the bytes between `$` and `*` so that a corrupted or spliced
line is dropped rather than mapped. No pyserial and no Drake here: the firmware's host test, the
serial driver and the recorder all share this module.
"""

from __future__ import annotations

import binascii
import collections
import re
from typing import ClassVar

import numpy as np

from lrnbv_drake.core.sensing.sensor import ToFFrame

#: The only version this parser accepts.
PROTOCOL_VERSION = 1
#: `res` field (zone count) -> zones per side.
RESOLUTIONS: dict[int, int] = {16: 4, 64: 8}
#: Header fields after the `TOF` tag: ver, seq, t_us, res.
HEADER_FIELDS = 5
#: Field ranges: seq is the MCU's u32 counter; t_us may come from a u32 or u64 clock.
SEQUENCE_MAX = 2**32 - 1
TIMESTAMP_MAX = 2**64 - 1
DISTANCE_RANGE = (-(2**15), 2**15 - 1)  # int16
STATUS_RANGE = (0, 255)  # uint8
SIGMA_RANGE = (0, 2**16 - 1)  # uint16
#: Longest valid line without its terminator: every field at its widest (1134 bytes). Longer
#: candidate lines cannot be frames and are dropped without being parsed.
MAX_LINE_BYTES = (
    len(f"$TOF,{PROTOCOL_VERSION},{SEQUENCE_MAX},{TIMESTAMP_MAX},64")
    + 64 * len(",-32768")
    + 64 * len(",255")
    + 64 * len(",65535")
    + len("*FFFF")
)

_PREFIX = b"$TOF,"
_CRC_TEXT = re.compile(rb"[0-9A-F]{4}")
_INTEGER = re.compile(rb"-?[0-9]{1,20}")
_DELIMITERS = re.compile(rb"[\r\n$]")


class FrameError(ValueError):
    """A line that is not a valid frame; `reason` is a short key for counting rejections."""

    reason: ClassVar[str] = "malformed"


class MissingPrefixError(FrameError):
    """The line does not start with `$TOF,` (a banner, a reply, noise)."""

    reason = "no_prefix"


class MissingCrcError(FrameError):
    """No `*` before the CRC: usually a line cut short."""

    reason = "no_crc"


class CrcError(FrameError):
    """The CRC field is not 4 upper-case hex digits, or does not match the body."""

    reason = "bad_crc"


class FieldCountError(FrameError):
    """The CRC checks but the line does not hold 5 + 3 res fields."""

    reason = "bad_field_count"


class FieldValueError(FrameError):
    """A field is not a plain decimal integer."""

    reason = "bad_field"


class UnsupportedVersionError(FrameError):
    """A protocol version this parser does not know."""

    reason = "bad_version"


class UnsupportedResolutionError(FrameError):
    """A `res` other than 16 or 64."""

    reason = "bad_resolution"


class ValueRangeError(FrameError):
    """A value outside its field's type (int16 distance, uint8 status, ...)."""

    reason = "out_of_range"


class LineTooLongError(FrameError):
    """Longer than any valid frame (`MAX_LINE_BYTES`)."""

    reason = "too_long"


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor)."""
    return binascii.crc_hqx(data, 0xFFFF)


def encode_frame(frame: ToFFrame) -> bytes:
    """The line the board sends for `frame`, terminator included.

    Raises:
        ValueError: a resolution other than 4x4 or 8x8, or a sequence or timestamp that does
            not fit its field.
    """
    n = frame.distance_mm.size
    if n not in RESOLUTIONS:
        raise ValueError(f"frame has {n} zones; the protocol carries 16 or 64")
    if not 0 <= frame.sequence <= SEQUENCE_MAX:
        raise ValueError(f"sequence {frame.sequence} is outside [0, {SEQUENCE_MAX}]")
    if not 0 <= frame.timestamp_us <= TIMESTAMP_MAX:
        raise ValueError(f"timestamp_us {frame.timestamp_us} is outside [0, {TIMESTAMP_MAX}]")
    values = [
        *frame.distance_mm.ravel().tolist(),
        *frame.status.ravel().tolist(),
        *frame.sigma_mm.ravel().tolist(),
    ]
    header = f"TOF,{PROTOCOL_VERSION},{frame.sequence},{frame.timestamp_us},{n},"
    body = header.encode() + b",".join(b"%d" % v for v in values)
    return b"$%s*%04X\r\n" % (body, crc16(body))


def _integer(fields: list[bytes], index: int) -> int:
    text = fields[index]
    if not _INTEGER.fullmatch(text):
        raise FieldValueError(f"field {index} is not a decimal integer: {text[:24]!r}")
    return int(text)


def _check_range(name: str, value: int, low: int, high: int) -> None:
    if not low <= value <= high:
        raise ValueRangeError(f"{name} = {value} is outside [{low}, {high}]")


def _block(
    fields: list[bytes], start: int, n: int, name: str, bounds: tuple[int, int]
) -> list[int]:
    values = [_integer(fields, i) for i in range(start, start + n)]
    low, high = bounds
    for zone, value in enumerate(values):
        if not low <= value <= high:
            raise ValueRangeError(
                f"field {start + zone} ({name} of zone {zone}) = {value} is outside "
                f"[{low}, {high}]"
            )
    return values


def parse_line(line: bytes) -> ToFFrame:
    """Parses one line (a trailing CR/LF is allowed) into a frame in raw zone order.

    Checks run in the order that names the first real problem: the prefix and `*` (framing),
    the CRC (is the body what the board sent?), then the fields, whose checks mean something
    only once the CRC has passed.

    Raises:
        FrameError: a subclass that says what is wrong.
    """
    line = line.rstrip(b"\r\n")
    if len(line) > MAX_LINE_BYTES:
        raise LineTooLongError(f"line of {len(line)} bytes; no frame is longer than "
                               f"{MAX_LINE_BYTES}")
    if not line.startswith(_PREFIX):
        raise MissingPrefixError(f"line does not start with '$TOF,': {line[:24]!r}")
    star = line.rfind(b"*")
    if star < 0:
        raise MissingCrcError(f"no '*' before a CRC in a line of {len(line)} bytes "
                              f"(cut short?)")
    body, crc_text = line[1:star], line[star + 1:]
    if not _CRC_TEXT.fullmatch(crc_text):
        raise CrcError(f"CRC field {crc_text[:8]!r} is not 4 upper-case hex digits")
    stated, computed = int(crc_text, 16), crc16(body)
    if stated != computed:
        raise CrcError(f"CRC mismatch: the body's CRC is {computed:04X} but the line says "
                       f"{stated:04X}")

    fields = body.split(b",")
    if len(fields) < HEADER_FIELDS:
        raise FieldCountError(f"{len(fields)} fields; a header alone needs {HEADER_FIELDS}")
    version = _integer(fields, 1)
    if version != PROTOCOL_VERSION:
        raise UnsupportedVersionError(f"protocol version {version}; this parser reads "
                                      f"version {PROTOCOL_VERSION}")
    n = _integer(fields, 4)
    if n not in RESOLUTIONS:
        raise UnsupportedResolutionError(f"res = {n}; expected one of {sorted(RESOLUTIONS)}")
    expected = HEADER_FIELDS + 3 * n
    if len(fields) != expected:
        raise FieldCountError(f"{len(fields)} fields for res {n}; expected 5 + 3*{n} = "
                              f"{expected}")
    sequence = _integer(fields, 2)
    _check_range("field 2 (seq)", sequence, 0, SEQUENCE_MAX)
    timestamp_us = _integer(fields, 3)
    _check_range("field 3 (t_us)", timestamp_us, 0, TIMESTAMP_MAX)
    distances = _block(fields, HEADER_FIELDS, n, "distance", DISTANCE_RANGE)
    statuses = _block(fields, HEADER_FIELDS + n, n, "status", STATUS_RANGE)
    sigmas = _block(fields, HEADER_FIELDS + 2 * n, n, "sigma", SIGMA_RANGE)
    side = RESOLUTIONS[n]
    return ToFFrame(
        distance_mm=np.array(distances, np.int16).reshape(side, side),
        status=np.array(statuses, np.uint8).reshape(side, side),
        sigma_mm=np.array(sigmas, np.uint16).reshape(side, side),
        sequence=sequence,
        timestamp_us=timestamp_us,
    )


class FrameAssembler:
    """Turns a byte stream cut into arbitrary chunks into frames.

    A candidate frame starts at `$` and ends at CR, LF or the next `$`; everything else is
    garbage. So a valid line is recovered whatever precedes it (boot banner, noise, a frame cut
    off mid-line) as long as its own bytes arrive intact; a `$` also ends a cut-off candidate,
    so a board that resets mid-line loses only that line. Candidates longer than
    `max_line_bytes` are dropped without being buffered further.

    Attributes:
        rejected: count of rejected candidate lines by `FrameError.reason`.
        garbage_bytes: bytes outside accepted frames, CR and LF not counted.
        text_lines: the last few lines that did not start with `$` (banners, `OK`/`ERR`
            replies, firmware errors), for diagnostics.
        last_rejection: why the last candidate was rejected.
    """

    def __init__(self, max_line_bytes: int = MAX_LINE_BYTES, keep_text_lines: int = 16) -> None:
        self.max_line_bytes = max_line_bytes
        self.rejected: collections.Counter[str] = collections.Counter()
        self.garbage_bytes = 0
        self.text_lines: collections.deque[str] = collections.deque(maxlen=keep_text_lines)
        self.last_rejection = ""
        self._line = bytearray()
        self._length = 0  # of the current line, including bytes not kept

    def feed(self, data: bytes) -> list[ToFFrame]:
        """Consumes a chunk and returns the frames completed by it, in order."""
        frames: list[ToFFrame] = []
        start = 0
        for match in _DELIMITERS.finditer(data):
            self._extend(data[start:match.start()])
            frames.extend(self._end_line())
            if match.group() == b"$":
                self._extend(b"$")
            start = match.end()
        self._extend(data[start:])
        return frames

    def flush(self) -> list[ToFFrame]:
        """Ends the pending line as if a terminator had arrived (e.g. before a reconnect)."""
        return self._end_line()

    def _extend(self, chunk: bytes) -> None:
        self._length += len(chunk)
        room = self.max_line_bytes - len(self._line)
        if room > 0:
            self._line += chunk[:room]

    def _end_line(self) -> list[ToFFrame]:
        line, length = bytes(self._line), self._length
        self._line.clear()
        self._length = 0
        if length == 0:
            return []
        if not line.startswith(b"$"):
            self.garbage_bytes += length
            self.text_lines.append(line.decode("ascii", "replace").strip())
            return []
        try:
            if length > self.max_line_bytes:
                raise LineTooLongError(f"candidate line of {length} bytes exceeds "
                                       f"{self.max_line_bytes}")
            return [parse_line(line)]
        except FrameError as e:
            self.rejected[e.reason] += 1
            self.last_rejection = str(e)
            self.garbage_bytes += length
            return []
