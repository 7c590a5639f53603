"""Stand-ins for the estimator and the stop rule that a stop check runs
(core/planning/stop_while_moving.py): what the loop's tests need of them and no more."""

import threading
import time

from lrnbv_drake.core.estimation.track import EstimateTrack


class CountingEstimator:
    """An `EpisodeEstimator` stand-in: one empty estimate per cell box, after `release` is
    set (or at once) and `seconds` of sleep; raises `error` when given one."""

    def __init__(self, seconds=0.0, release=None, error=None):
        self.lock = threading.RLock()
        self.seconds, self.release, self.error = seconds, release, error
        self.calls = 0
        self.track = EstimateTrack()

    def update(self, readings, cell_boxes, final=False):
        self.calls += 1
        if self.release is not None:
            assert self.release.wait(5.0)
        time.sleep(self.seconds)
        if self.error is not None:
            raise self.error
        self.track = EstimateTrack((None,) * min(len(readings), len(cell_boxes)))
        return self.track


class StopAfter:
    """A `BoxStop` stand-in: stop once the track holds n estimates."""

    def __init__(self, n):
        self.n = n

    def update(self, track):
        return f"stop after {self.n}" if len(track.estimates) >= self.n else None
