"""The `$TOF` line protocol: encoding, every rejection reason, the streaming assembler under
fuzzing, and the firmware's C formatter checked against the Python parser."""

from __future__ import annotations

import binascii
import itertools
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.core.sensing.tof_protocol import (
    MAX_LINE_BYTES,
    CrcError,
    FieldCountError,
    FieldValueError,
    FrameAssembler,
    FrameError,
    LineTooLongError,
    MissingCrcError,
    MissingPrefixError,
    UnsupportedResolutionError,
    UnsupportedVersionError,
    ValueRangeError,
    crc16,
    encode_frame,
    parse_line,
)

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware"


def _line(body: str) -> bytes:
    """A line with a correct CRC around `body`, to reach the checks after the CRC."""
    raw = body.encode()
    return b"$%s*%04X\r\n" % (raw, binascii.crc_hqx(raw, 0xFFFF))


def _frame_4x4(sequence: int = 7) -> ToFFrame:
    return ToFFrame(
        distance_mm=np.arange(16).reshape(4, 4) * 100 - 300,
        status=np.array([5, 9, 255, 0] * 4).reshape(4, 4),
        sigma_mm=np.arange(16).reshape(4, 4) * 4000,
        sequence=sequence,
        timestamp_us=123456,
    )


def _assert_same(a: ToFFrame, b: ToFFrame) -> None:
    assert (a.sequence, a.timestamp_us) == (b.sequence, b.timestamp_us)
    for name in ("distance_mm", "status", "sigma_mm"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert getattr(a, name).dtype == getattr(b, name).dtype


def test_crc_is_ccitt_false_with_its_check_value() -> None:
    assert binascii.crc_hqx(b"123456789", 0xFFFF) == 0x29B1
    assert crc16(b"123456789") == 0x29B1


def test_encode_writes_the_hand_worked_line() -> None:
    body = ("TOF,1,7,123456,16,"
            "-300,-200,-100,0,100,200,300,400,500,600,700,800,900,1000,1100,1200,"
            "5,9,255,0,5,9,255,0,5,9,255,0,5,9,255,0,"
            "0,4000,8000,12000,16000,20000,24000,28000,32000,36000,40000,44000,48000,52000,"
            "56000,60000")
    assert encode_frame(_frame_4x4()) == _line(body)


def test_round_trip_keeps_every_value_at_the_type_limits() -> None:
    rng = np.random.default_rng(3)
    frame = ToFFrame(
        distance_mm=rng.integers(-(2**15), 2**15, (8, 8)),
        status=rng.integers(0, 256, (8, 8)),
        sigma_mm=rng.integers(0, 2**16, (8, 8)),
        sequence=2**32 - 1,
        timestamp_us=2**64 - 1,
    )
    frame.distance_mm[0, :2] = (-(2**15), 2**15 - 1)
    frame.sigma_mm[0, 0] = 2**16 - 1
    line = encode_frame(frame)
    assert len(line.rstrip(b"\r\n")) <= MAX_LINE_BYTES
    _assert_same(parse_line(line), frame)


def test_the_widest_frame_is_exactly_the_line_limit() -> None:
    widest = ToFFrame(np.full((8, 8), -(2**15)), np.full((8, 8), 255),
                      np.full((8, 8), 2**16 - 1), sequence=2**32 - 1, timestamp_us=2**64 - 1)
    assert len(encode_frame(widest)) == MAX_LINE_BYTES + 2


def test_encode_refuses_what_the_protocol_cannot_carry() -> None:
    with pytest.raises(ValueError, match="16 or 64"):
        encode_frame(ToFFrame.empty(resolution=5))
    with pytest.raises(ValueError, match="sequence"):
        encode_frame(ToFFrame.empty(sequence=2**32))


GOOD_BODY = encode_frame(_frame_4x4()).decode()[1:-7]  # between '$' and '*'
HEADER = "TOF,1,7,123456,16"
DATA = GOOD_BODY[len(HEADER):]  # ",<48 values>"


@pytest.mark.parametrize(
    ("line", "error", "message"),
    [
        (b"hello world\r\n", MissingPrefixError, "does not start with '\\$TOF,'"),
        (b"$TOG,1,2\r\n", MissingPrefixError, "does not start"),
        (b"$TOF,1,7,123456,16,1,2,3\r\n", MissingCrcError, "no '\\*'"),
        (b"$TOF,1,7*12G4\r\n", CrcError, "not 4 upper-case hex"),
        (b"$TOF,1,7*29b1\r\n", CrcError, "not 4 upper-case hex"),
        (b"$TOF,1,7*29B\r\n", CrcError, "not 4 upper-case hex"),
        (_line("TOF,1,2"), FieldCountError, "3 fields; a header alone needs 5"),
        (_line(HEADER + DATA + ",5"), FieldCountError, "54 fields for res 16; expected "
                                                       "5 \\+ 3\\*16 = 53"),
        (_line(HEADER + DATA.rsplit(",", 1)[0]), FieldCountError, "expected 5 \\+ 3\\*16 = 53"),
        (_line("TOF,x,7,0,16" + DATA), FieldValueError, "field 1 is not a decimal integer"),
        (_line("TOF,1,7,0,16,1.5" + DATA[DATA.index(",", 1):]), FieldValueError,
         "field 5 is not a decimal integer: b'1.5'"),
        (_line("TOF,1,+7,0,16" + DATA), FieldValueError, "field 2 is not"),
        (_line("TOF,1,7, 0,16" + DATA), FieldValueError, "field 3 is not"),
        (_line("TOF,1,1_0,0,16" + DATA), FieldValueError, "field 2 is not"),
        (_line("TOF,2,7,0,16" + DATA), UnsupportedVersionError, "version 2"),
        (_line("TOF,1,7,0,32" + DATA), UnsupportedResolutionError, "res = 32; expected one "
                                                                   "of \\[16, 64\\]"),
        (_line("TOF,1,-1,0,16" + DATA), ValueRangeError, "field 2 \\(seq\\) = -1"),
        (_line("TOF,1,4294967296,0,16" + DATA), ValueRangeError, "seq\\) = 4294967296"),
        (_line("TOF,1,7,-5,16" + DATA), ValueRangeError, "field 3 \\(t_us\\) = -5"),
        (_line("TOF,1,7,0,16,32768" + DATA[DATA.index(",", 1):]), ValueRangeError,
         "field 5 \\(distance of zone 0\\) = 32768 is outside \\[-32768, 32767\\]"),
        (_line("TOF,1,7,0,16,-32769" + DATA[DATA.index(",", 1):]), ValueRangeError,
         "distance of zone 0"),
        (_line(HEADER + DATA.replace(",255,", ",256,", 1)), ValueRangeError,
         "field 23 \\(status of zone 2\\) = 256 is outside \\[0, 255\\]"),
        (_line(HEADER + DATA.replace(",5,", ",-1,", 1)), ValueRangeError,
         "field 21 \\(status of zone 0\\) = -1"),
        (_line(HEADER + DATA.replace(",60000", ",65536")), ValueRangeError,
         "field 52 \\(sigma of zone 15\\) = 65536 is outside \\[0, 65535\\]"),
        (b"$TOF," + b"1," * MAX_LINE_BYTES, LineTooLongError, "no frame is longer"),
    ],
)
def test_each_malformed_line_names_its_fault(line: bytes, error: type, message: str) -> None:
    with pytest.raises(error, match=message) as info:
        parse_line(line)
    assert isinstance(info.value, FrameError)


def test_a_crc_mismatch_names_both_values() -> None:
    good = encode_frame(_frame_4x4())
    stated = good[-6:-2].decode()
    bad = good.replace(b",100,", b",101,", 1)  # one digit changed, CRC kept
    computed = f"{binascii.crc_hqx(bad[1:-7], 0xFFFF):04X}"
    assert computed != stated
    with pytest.raises(CrcError, match=f"the body's CRC is {computed} but the line says "
                                       f"{stated}"):
        parse_line(bad)


def test_assembler_recovers_frames_around_banners_garbage_and_cut_lines() -> None:
    f1, f2, f3 = (_frame_4x4(s) for s in (1, 2, 3))
    cut = encode_frame(f2)[:40]  # cut before its CRC: the board reset mid-line
    bad_crc = encode_frame(f2).replace(b",100,", b",101,", 1)
    stream = (b"boot ok\r\n" + encode_frame(f1) + b"xx" + cut + encode_frame(f3)
              + bad_crc + b"$" + b"9" * 2000 + b"\n" + b"\n\r\r\n")
    dut = FrameAssembler()
    frames = [f for i in range(len(stream)) for f in dut.feed(stream[i:i + 1])]
    assert [f.sequence for f in frames] == [1, 3]
    _assert_same(frames[1], f3)
    assert dict(dut.rejected) == {"no_crc": 1, "bad_crc": 1, "too_long": 1}
    assert dut.garbage_bytes == len(b"boot ok") + 2 + 40 + len(bad_crc) - 2 + 2001
    assert list(dut.text_lines) == ["boot ok", "xx"]


@pytest.mark.parametrize("terminator", [b"\n", b"\r", b"\r\n", b"\n\r"])
def test_assembler_accepts_any_line_ending(terminator: bytes) -> None:
    lines = [encode_frame(_frame_4x4(s))[:-2] + terminator for s in (1, 2)]
    dut = FrameAssembler()
    assert [f.sequence for f in dut.feed(b"".join(lines))] == [1, 2]
    assert dut.garbage_bytes == 0 and not dut.rejected


def test_assembler_holds_a_frame_until_its_line_ends() -> None:
    line = encode_frame(_frame_4x4(5))
    dut = FrameAssembler()
    assert dut.feed(line[:-2]) == []
    assert [f.sequence for f in dut.feed(b"\r")] == [5]


# --- Property-based -----------------------------------------------------------------------

FUZZ = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def frames(draw: st.DrawFn) -> ToFFrame:
    side = draw(st.sampled_from([4, 8]))
    return ToFFrame(
        distance_mm=draw(hnp.arrays(np.int16, (side, side))),
        status=draw(hnp.arrays(np.uint8, (side, side))),
        sigma_mm=draw(hnp.arrays(np.uint16, (side, side))),
        sequence=draw(st.integers(0, 2**32 - 1)),
        timestamp_us=draw(st.integers(0, 2**64 - 1)),
    )


def _chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts} | {0, len(data)})
    return [data[a:b] for a, b in itertools.pairwise(points)]


@FUZZ
@given(frame=frames())
def test_any_frame_round_trips(frame: ToFFrame) -> None:
    _assert_same(parse_line(encode_frame(frame)), frame)


TOKENS = [b"$", b"$TOF,", b"TOF,1,", b",", b"*", b"\r", b"\n", b"16", b"64", b"-", b"255",
          b"0", b"9", b"A", b"\x00", b"\xff", b"*FFFF"]


@FUZZ
@given(data=st.one_of(st.binary(max_size=3000),
                      st.lists(st.sampled_from(TOKENS), max_size=400).map(b"".join)),
       cuts=st.lists(st.integers(0, 4000), max_size=20))
def test_random_bytes_never_crash_the_assembler(data: bytes, cuts: list[int]) -> None:
    dut = FrameAssembler()
    for chunk in _chunked(data, cuts):
        dut.feed(chunk)  # anything but a FrameError caught inside fails the test
    dut.flush()
    assert dut.garbage_bytes <= len(data)


@FUZZ
@given(body=st.text(alphabet="TOF,1690-5x.", max_size=300))
def test_any_body_with_a_valid_crc_parses_or_raises_a_frame_error(body: str) -> None:
    try:
        frame = parse_line(_line(body))
    except FrameError:
        return
    assert parse_line(encode_frame(frame)).sequence == frame.sequence


@st.composite
def noise(draw: st.DrawFn, samples: list[bytes]) -> bytes:
    """Arbitrary bytes, or a frame cut before its CRC (as a reset mid-line leaves it)."""
    cut = draw(st.sampled_from(samples))
    return draw(st.one_of(st.binary(max_size=200),
                          st.integers(0, cut.index(b"*")).map(lambda n: cut[:n])))


@FUZZ
@given(data=st.data(), sent=st.lists(frames(), min_size=1, max_size=5),
       cuts=st.lists(st.integers(0, 20000), max_size=30))
def test_every_intact_frame_is_recovered_in_order_from_noise(
    data: st.DataObject, sent: list[ToFFrame], cuts: list[int]
) -> None:
    # Recoverable: an intact line whatever surrounds it, glued to the noise or not, because
    # its '$' ends whatever came before and its own CRLF ends it. Not recoverable: a line with
    # bytes lost or inserted inside it (its CRC rejects it) - so none is generated here. Noise
    # cannot fake a frame short of forging a CRC over a well-formed body, which random bytes
    # do not do.
    lines = [encode_frame(f) for f in sent]
    stream = b""
    for line in lines:
        stream += data.draw(noise(lines)) + line
    stream += data.draw(noise(lines))
    dut = FrameAssembler()
    got = [f for chunk in _chunked(stream, cuts) for f in dut.feed(chunk)] + dut.flush()
    assert len(got) == len(sent)
    for g, f in zip(got, sent, strict=True):
        _assert_same(g, f)


# --- Firmware framing, compiled on the host ------------------------------------------------


def _firmware_frames() -> tuple[ToFFrame, ToFFrame]:
    """The frames test_tof_frame.c formats, from the same formulas."""
    i = np.arange(64)
    d, s, g = i * 61 - 500, (i * 37) % 256, i * 1040
    d[0], d[63], s[1], g[63] = -32768, 32767, 255, 65535
    big = ToFFrame(d.reshape(8, 8), s.reshape(8, 8), g.reshape(8, 8), 4294967295, 123456789)
    j = np.arange(16)
    small = ToFFrame((j * 100).reshape(4, 4), np.full((4, 4), 5), j.reshape(4, 4), 1, 0)
    return big, small


def test_firmware_formatter_agrees_with_the_python_parser(tmp_path: Path) -> None:
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (cc) on PATH to build firmware/test/test_tof_frame.c")
    exe = tmp_path / "test_tof_frame"
    subprocess.run(
        [cc, "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wconversion", "-Werror",
         "-I", str(FIRMWARE / "tof_frame"), str(FIRMWARE / "test" / "test_tof_frame.c"),
         str(FIRMWARE / "tof_frame" / "tof_frame.c"), "-o", str(exe)],
        check=True, capture_output=True, timeout=60,
    )
    run = subprocess.run([str(exe)], capture_output=True, timeout=10)
    assert run.returncode == 0, run.stderr.decode()
    crc_line, big_line, small_line = run.stdout.splitlines(keepends=True)
    assert crc_line.strip() == b"CRC %04X" % binascii.crc_hqx(b"123456789", 0xFFFF)
    big, small = _firmware_frames()
    for line, frame in ((big_line, big), (small_line, small)):
        assert line.endswith(b"\r\n")
        _assert_same(parse_line(line), frame)
        assert line == encode_frame(frame)  # byte for byte, CRC digits included
