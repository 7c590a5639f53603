"""The frame gate alone (core.sensing.frame_gate): worked timings, no Drake."""

import numpy as np

from lrnbv_drake.core.sensing.frame_gate import FrameGate
from lrnbv_drake.core.sensing.sensor import ToFFrame

STILL, MOVING = np.zeros(6), np.r_[0.0, 0.5, 0, 0, 0, 0]
dut = FrameGate(latency=0.1, still_speed=0.01, timeout=1.0, first_timeout=3.0)


def _frame(sequence, board_us):
    return ToFFrame(np.full((8, 8), 400), np.full((8, 8), 5), np.full((8, 8), 6),
                    sequence=sequence, timestamp_us=board_us)


def test_a_frame_seen_after_the_arm_was_still_for_the_latency_passes_restamped():
    s = FrameGate.start(0.0)
    r = dut.update(s, 0.05, _frame(1, 999), STILL)
    assert r.frame is None  # started moving at 0.0: 0.0 is not before 0.05 - 0.1
    r = dut.update(r.state, 0.2, _frame(2, 1999), STILL)
    assert r.frame.sequence == 2 and r.frame.timestamp_us == 100_000  # 0.2 - latency
    assert r.frame.distance_mm[0, 0] == 400


def test_a_frame_the_arm_may_have_moved_during_is_seen_but_never_passed():
    s = dut.update(FrameGate.start(0.0), 1.0, _frame(1, 10), STILL).state
    s = dut.update(s, 1.50, _frame(1, 10), MOVING).state  # the same frame: no news
    r = dut.update(s, 1.55, _frame(2, 20), STILL)
    assert r.frame is None  # the arm moved at 1.50, within [1.45, 1.55]
    r = dut.update(r.state, 1.56, _frame(2, 20), STILL)
    assert r.frame is None  # seen already: not passed later either
    r = dut.update(r.state, 1.70, _frame(3, 30), STILL)
    assert r.frame.timestamp_us == 1_600_000


def test_silence_is_measured_from_the_last_new_frame_with_a_longer_first_allowance():
    s = FrameGate.start(0.0)
    r = dut.update(s, 2.9, ToFFrame.empty(), STILL)
    assert (r.silence, r.timed_out) == (2.9, False)  # before the first frame: 3 s allowed
    r = dut.update(s, 3.1, ToFFrame.empty(), STILL)
    assert r.timed_out
    s = dut.update(s, 1.0, _frame(5, 50), STILL).state
    assert not dut.update(s, 1.9, _frame(5, 50), STILL).timed_out
    r = dut.update(s, 2.1, _frame(5, 50), STILL)
    assert r.timed_out and abs(r.silence - 1.1) < 1e-12


def test_a_speed_that_is_not_a_number_counts_as_moving():
    s = dut.update(FrameGate.start(0.0), 1.0, _frame(1, 10), STILL).state
    s = dut.update(s, 1.50, _frame(1, 10), np.r_[np.nan, 0, 0, 0, 0, 0]).state
    assert dut.update(s, 1.55, _frame(2, 20), STILL).frame is None  # as after MOVING
