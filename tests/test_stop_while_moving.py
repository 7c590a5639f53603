"""StopWhileMoving alone: the stop check beside the loop, in a thread and as its timed model."""

import threading
import time

import numpy as np
import pytest
from stop_stand_ins import CountingEstimator, StopAfter

from lrnbv_drake.core.planning.stop_while_moving import StopWhileMoving


def _readings(n):
    return [(None, np.eye(4))] * n, [None] * n


@pytest.mark.parametrize("threaded", [False, True])
def test_the_check_says_stop_once_the_track_is_long_enough_either_way(threaded):
    dut = StopWhileMoving(CountingEstimator(), StopAfter(2), threaded=threaded)
    reasons = []
    for n in (1, 2):
        dut.start(*_readings(n), t=float(n))
        while (check := dut.result(t=100.0)) is None:
            time.sleep(0.001)
        reasons.append(check.reason)
    assert reasons == [None, "stop after 2"] and not dut.running


def test_a_threaded_check_is_not_ready_while_it_runs_and_a_second_cannot_start():
    release = threading.Event()
    dut = StopWhileMoving(CountingEstimator(release=release), StopAfter(1), threaded=True)
    dut.start(*_readings(1), t=0.0)
    assert dut.result(t=1.0) is None and dut.running
    with pytest.raises(RuntimeError, match="not been collected"):
        dut.start(*_readings(1), t=1.0)
    release.set()
    while (check := dut.result(t=2.0)) is None:
        time.sleep(0.001)
    assert check.reason == "stop after 1"


def test_the_timed_model_says_go_on_at_once_and_stop_when_the_check_would_be_done():
    """Modelled, a check that says go on is known at once (the diagram's time, and so the
    frames after it, must not depend on how long it took) with the time it would have been
    done; one that says stop is known only from that time."""
    dut = StopWhileMoving(CountingEstimator(seconds=0.05), StopAfter(2), threaded=False)
    dut.start(*_readings(1), t=10.0)
    go_on = dut.result(t=10.0)
    assert go_on.reason is None and 10.05 <= go_on.ready_at < 11.0
    dut.start(*_readings(2), t=20.0)
    assert dut.result(t=20.04) is None  # it took at least 0.05 s
    stop = dut.result(t=21.0)
    assert stop.reason == "stop after 2" and 20.05 <= stop.ready_at < 21.0


def test_a_threaded_check_is_done_when_it_is_collected():
    dut = StopWhileMoving(CountingEstimator(), None, threaded=True)
    dut.start(*_readings(1), t=3.0)
    while (check := dut.result(t=3.5)) is None:
        time.sleep(0.001)
    assert check.ready_at == 3.5


@pytest.mark.parametrize("threaded", [False, True])
def test_what_the_check_raises_reaches_the_loop(threaded):
    dut = StopWhileMoving(CountingEstimator(error=ValueError("bad frame")), None,
                          threaded=threaded)
    with pytest.raises(ValueError, match="bad frame"):
        dut.start(*_readings(1), t=0.0)
        while dut.result(t=100.0) is None:
            time.sleep(0.001)


def test_a_threaded_check_that_runs_too_long_is_a_fault_named_so():
    """The timeout is per reading the check folds in: 3 x 5 s here (a resumed session's
    first check folds in every reading before it)."""
    release = threading.Event()
    dut = StopWhileMoving(CountingEstimator(release=release), None, threaded=True, timeout=5.0)
    dut.start(*_readings(3), t=0.0)
    assert dut.result(t=14.0) is None
    with pytest.raises(TimeoutError, match="stop check"):
        dut.result(t=16.0)
    release.set()
