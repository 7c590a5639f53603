"""The stop rule's check after an acquisition, run while the arm moves to the next view.

The check is the box estimate with the new reading folded in and the stop rule on it (with the
interval it reads once the box has held still): most of an iteration's computation. When the
policy does not read the estimate to choose the next view (the paper's utility, NBV, HEU),
nothing waits on it but the stop, so the loop plans and starts the next move first and checks
meanwhile. Should the check say stop, the loop halts the move (`MotionPlanning.halt`) and the
episode ends with the same poses and box as had it checked before moving; the arm waits at a
view only for what the move did not cover.

Two ways to run it, the same answers:

- `threaded`: a worker thread, on the real cell, whose diagram time is wall time. The
  estimator's numba kernels release the GIL (`nogil`) and leave a core to the loop
  (`SPARE_CORES`), so the servo stream's ticks go on.
- not threaded: computed at once, the simulated cell's model of the same thing. Its diagram
  time does not count computation, and a check must not move it either: the frames after it
  would be taken at other times, with other noise, run to run. So a check that says go on is
  known at once and `StopCheck.ready_at` says when the cell would have had it (the loop
  counts the wait past the arm's arrival); one that says stop is known at `ready_at`, where
  the cell would have halted the move (the episode ends there: nothing after it is read).
"""

from __future__ import annotations

import dataclasses as dc
import threading
import time
from collections.abc import Sequence

import numba
import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation.track import EpisodeEstimator
from lrnbv_drake.core.planning.stop import BoxStop
from lrnbv_drake.core.sensing.sensor import ToFFrame

#: Seconds a threaded check may take per reading it folds in before the loop gives up on it
#: as a fault (an estimate takes well under one on the campaigns' objects, 5-30 on the
#: slowest, whose searches stop at `estimation.search_casts`; a resumed session's first
#: check folds in every reading before it).
CHECK_TIMEOUT = 120.0
#: Cores a threaded check's parallel kernels leave to the loop's thread: with none, the servo
#: stream's ticks came up to twice as late (benchmarks/bench_servo_beside_estimate.py).
SPARE_CORES = 1


@dc.dataclass(frozen=True)
class StopCheck:
    """A finished check: why to stop (None: go on) and the time it was (or, modelled, would
    have been) done."""

    reason: str | None
    ready_at: float


class StopWhileMoving:
    """Runs one stop check at a time beside the loop (see the module docstring)."""

    def __init__(self, estimator: EpisodeEstimator, stop: BoxStop | None, *,
                 threaded: bool, timeout: float = CHECK_TIMEOUT) -> None:
        self._estimator, self._stop = estimator, stop
        self._threaded, self._timeout = threaded, timeout
        self._started, self._allowed = 0.0, timeout
        self._thread: threading.Thread | None = None
        self._outcome: StopCheck | BaseException | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None or self._outcome is not None

    def start(self, readings: Sequence[tuple[ToFFrame, np.ndarray]],
              cell_boxes: Sequence[OrientedBox | None], t: float) -> None:
        """Begins the check after `readings` (each with the cell box after it), at time t."""
        if self.running:
            raise RuntimeError("StopWhileMoving.start: the last check has not been collected")
        self._started = t
        readings, cell_boxes = list(readings), list(cell_boxes)
        self._allowed = self._timeout * max(1, len(readings) - len(self._estimator.track.estimates))
        if not self._threaded:
            self._outcome = self._check(readings, cell_boxes, t)
            return
        self._thread = threading.Thread(target=self._run, args=(readings, cell_boxes),
                                        name="stop-check", daemon=True)
        self._thread.start()

    def result(self, t: float) -> StopCheck | None:
        """The check, once it is known at time t (see the module docstring); None before.
        Raises what a threaded check raised (`start` raises it when not threaded), or
        TimeoutError after `timeout` seconds for each reading the check folds in."""
        if self._thread is not None:
            if self._thread.is_alive():
                if t - self._started > self._allowed:
                    raise TimeoutError(f"the stop check (box estimate) has run "
                                       f"{t - self._started:.0f} s, over {self._allowed:.0f} s")
                return None
            self._thread = None
            if isinstance(self._outcome, StopCheck):
                self._outcome = dc.replace(self._outcome, ready_at=t)
        outcome = self._outcome
        if isinstance(outcome, StopCheck) and outcome.reason is not None \
                and t < outcome.ready_at:
            return None
        self._outcome = None
        if isinstance(outcome, BaseException):
            raise outcome
        return outcome

    def _run(self, readings, cell_boxes) -> None:
        numba.set_num_threads(max(1, numba.config.NUMBA_NUM_THREADS - SPARE_CORES))  # per thread
        try:
            self._outcome = self._check(readings, cell_boxes, self._started)
        except BaseException as e:  # handed to the loop's thread by `result`
            self._outcome = e

    def _check(self, readings, cell_boxes, t: float) -> StopCheck:
        started = time.perf_counter()
        with self._estimator.lock:
            track = self._estimator.update(readings, cell_boxes)
            reason = self._stop.update(track) if self._stop is not None else None
        return StopCheck(reason, t + time.perf_counter() - started)
