"""When an episode has seen enough: the stop rule tied to the box.

The paper stops when the best new view is no better than the worst cached one (Algorithm 1,
line 24); measured here, that left LR-NBV taking 12-24 poses on the boxes while the box had
stopped changing after 7-9, and the same object and planner stopping after 10 or 26 poses.
The product's question is whether the box is known, so `BoxStop` asks the box: after each
pose the sensor-model estimate is refitted (warm-started), and the episode ends when every
dimension has moved less than `tolerance` over the last `stable_poses` poses, once at least
`min_poses` were taken, and the readings bound every dimension to within `interval_width`.

Why the second condition: a box can hold still because no new view sees one of its sides. On
the horizontal box (seed 0) LR-NBV stopped after 7 poses with the far end unseen: the length
was 3 mm off by luck, its interval 12 cm wide, and the container two sizes too large. The
width is the readings' part of the box fit's profile interval (`BoxFit.readings_width`), so
a side nobody saw from outside keeps the episode going. It is taken at the estimator's own
`interval_cost` (`planner.stop.interval_cost`, 5, above the reported interval's 2.71): a side
that only a reading or two hold raises the cost slowly, and at 2.71 it was bounded one pose
and 10 cm open the next.
"""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Sequence

import numpy as np

from lrnbv_drake.core.box_fit import BoxEstimator
from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.sensor import ToFFrame


@dc.dataclass(frozen=True)
class BoxStopParams:
    """`BoxStop`'s thresholds."""

    # Largest change of any dimension, metres, over the last `stable_poses` poses.
    tolerance: float = 0.005
    # Poses over which the dimensions must hold still (2: three estimates in a row).
    stable_poses: int = 2
    # Fewest poses before the rule may stop.
    min_poses: int = 4
    # Widest the readings may leave any dimension (`BoxFit.readings_width`), metres.
    interval_width: float = 0.02

    def __post_init__(self) -> None:
        if (not self.tolerance > 0 or self.stable_poses < 1 or self.min_poses < 1
                or not self.interval_width > 0):
            raise ValueError(f"BoxStopParams needs tolerance > 0, stable_poses >= 1, "
                             f"min_poses >= 1 and interval_width > 0; got {self}")


class BoxStop:
    """Ends an episode once the box estimate holds still (see the module docstring).

    `update` takes the acquisitions so far and the object's cell box after the last one (the
    estimate's start before it has one) and returns why to stop, or None.
    """

    def __init__(self, estimator: BoxEstimator, params: BoxStopParams | None = None) -> None:
        self._estimator = estimator
        self.params = params or BoxStopParams()
        self._seen = 0
        self.dims: list[np.ndarray | None] = []

    def update(self, acquisitions: Sequence[tuple[ToFFrame, np.ndarray]],
               cell_box: OrientedBox | None) -> str | None:
        """Folds in the acquisitions not seen yet and refits; why to stop, or None."""
        for frame, X_WS in acquisitions[self._seen:]:
            self._estimator.add(frame, X_WS)
            fit = self._estimator.estimate(cell_box, interval=False)
            self.dims.append(None if fit is None else fit.box.dims.copy())
        self._seen = len(acquisitions)
        p = self.params
        recent = self.dims[-(p.stable_poses + 1):]
        if len(self.dims) < max(p.min_poses, p.stable_poses + 1) or any(d is None
                                                                         for d in recent):
            return None
        spread = np.ptp(np.array(recent), axis=0)
        if not np.all(spread < p.tolerance):
            return None
        fit = self._estimator.estimate(cell_box)  # the same box, now with its interval
        # No width: the refit found no reading near the box and handed back an older fit.
        if fit is None or fit.readings_width is None or not np.all(
                fit.readings_width <= p.interval_width):
            return None
        return (f"the box held still: every dimension moved less than "
                f"{1000 * p.tolerance:.0f} mm over the last {p.stable_poses} poses and the "
                f"readings bound each within {1000 * p.interval_width:.0f} mm "
                f"({' x '.join(f'{v:.3f}' for v in recent[-1])} m)")
