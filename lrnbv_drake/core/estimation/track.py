"""The estimate of an episode, pose by pose: what the stop rule watches, the report gives and
the poses-to-accuracy metric reads, so that all three are the same estimates.

Acquisition i is folded in once the object's extraction after it is known (the loop logs it
when it next plans): its cell box is where a cold start begins. The episode's readings and
extractions give the same track however often it is asked, so a recorded episode is
estimated again exactly (`lrnbv refit`).
"""

from __future__ import annotations

import contextlib
import dataclasses as dc
import threading
import time
from collections.abc import Iterator, Sequence

import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation.estimator import BoxEstimate, ShapeEstimator
from lrnbv_drake.core.sensing.sensor import ToFFrame

#: Seconds `EpisodeEstimator.update` waits for a stop check in another thread to finish.
LOCK_TIMEOUT = 300.0


@dc.dataclass(frozen=True)
class EstimateTrack:
    """The estimate after each acquisition folded in (None: no object found yet) and the
    seconds each took."""

    estimates: tuple[BoxEstimate | None, ...] = ()
    seconds: tuple[float, ...] = ()

    @property
    def latest(self) -> BoxEstimate | None:
        return self.estimates[-1] if self.estimates else None


def cells_estimate(box: OrientedBox | None) -> BoxEstimate | None:
    """The cell box as an estimate without an interval (`extraction.estimator: cells`)."""
    return None if box is None else BoxEstimate.of_cells(box)


class EpisodeEstimator:
    """Folds an episode's acquisitions into its estimate track, the shape estimator's, or
    with no estimator the cell boxes themselves."""

    def __init__(self, estimator: ShapeEstimator | None) -> None:
        self._estimator = estimator
        self._track = EstimateTrack()
        #: Held by `update`, and by a stop check in a thread for its estimate and the stop
        #: rule's reading of it (core/planning/stop_while_moving.py): whoever estimates
        #: meanwhile (the report after a fault) waits, at most `LOCK_TIMEOUT`.
        self.lock = threading.RLock()

    @property
    def track(self) -> EstimateTrack:
        return self._track

    def update(self, readings: Sequence[tuple[ToFFrame, np.ndarray]],
               cell_boxes: Sequence[OrientedBox | None], final: bool = False) -> EstimateTrack:
        """The track after every reading whose cell box is known (`cell_boxes[i]` the one
        after reading i; None where no object was found) or, `final`, every reading, the
        last ones started from the last cell box known."""
        with self._locked():
            return self._update(readings, cell_boxes, final)

    def settled(self) -> EstimateTrack:
        """`track` once a stop check estimating in another thread is done."""
        with self._locked():
            return self._track

    @contextlib.contextmanager
    def _locked(self) -> Iterator[None]:
        if not self.lock.acquire(timeout=LOCK_TIMEOUT):
            raise TimeoutError(f"the box estimate waited {LOCK_TIMEOUT:.0f} s for a stop check "
                               f"that is still running")
        try:
            yield
        finally:
            self.lock.release()

    def _update(self, readings: Sequence[tuple[ToFFrame, np.ndarray]],
                cell_boxes: Sequence[OrientedBox | None], final: bool) -> EstimateTrack:
        done = len(self._track.estimates)
        upto = len(readings) if final else min(len(readings), len(cell_boxes))
        estimates, seconds = list(self._track.estimates), list(self._track.seconds)
        for i in range(done, upto):
            cells = cell_boxes[min(i, len(cell_boxes) - 1)] if cell_boxes else None
            started = time.perf_counter()
            if self._estimator is None:
                estimate = cells_estimate(cells)
            else:
                self._estimator.add(*readings[i])
                estimate = self._estimator.estimate(cells)
            estimates.append(estimate)
            seconds.append(time.perf_counter() - started)
        self._track = EstimateTrack(tuple(estimates), tuple(seconds))
        return self._track


def compile_kernels() -> None:
    """Compiles the estimator's kernels into numba's on-disk cache by estimating a box from
    one frame of a flat table and its interval, so that the first estimate of a process (the
    first pose's, a stop check's beside a move, or the report after a fault on the cell) does
    not wait for them
    (`python -m lrnbv_drake.core.kernels`)."""
    from lrnbv_drake.core.sensing.sensor import SensorModelParams
    from lrnbv_drake.core.sensing.tof_device import DeviceBehaviour

    frame = ToFFrame(np.full((8, 8), 400), np.full((8, 8), 5), np.full((8, 8), 5))
    X_WS = np.diag([1.0, -1.0, -1.0, 1.0])
    X_WS[2, 3] = 0.4
    for behaviour in (DeviceBehaviour(), DeviceBehaviour("strongest", 600.0)):
        estimator = ShapeEstimator(SensorModelParams(), behaviour, 0.0, (-1, -1, 1, 1))
        estimator.add(frame, X_WS)
        box = OrientedBox(np.array([0.0, 0.0, 0.025]), np.full(3, 0.05))
        assert estimator.estimate(box).widths is not None  # the interval the stop reads
