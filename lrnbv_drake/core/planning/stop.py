"""When an episode has seen enough: the stop rule tied to the reported box.

The paper stops when the best new view is no better than the worst cached one (Algorithm 1,
line 24); measured here, that left LR-NBV taking 12-24 poses on the boxes while the box had
stopped changing after 7-9. The product's question is whether the box is known, so `BoxStop`
asks the estimate the episode reports (`estimation.track`, the same estimates): the episode
ends once every dimension has moved less than `tolerance` over the last `stable_poses`
poses, at least `min_poses` were taken, and the estimate's interval is narrower than
`interval_width` on every dimension. The interval is the reported one, so a side that no
view has bounded from outside (its interval reaching `estimation.interval_reach` out) keeps
the episode going however still the box holds; and so does a part the interval finds
another class of that the information criterion would choose over the fit's, by any margin
(`BoxEstimate.chosen`): the search kept that part's class from fewer readings, and the box
may change once it looks again (record 0027).
"""

from __future__ import annotations

import numpy as np

from lrnbv_drake.core.estimation.estimator import BoxEstimate
from lrnbv_drake.core.estimation.track import EstimateTrack
from lrnbv_drake.core.planning.config import StopParams


class BoxStop:
    """Ends an episode once the reported estimate is known (the module docstring)."""

    def __init__(self, params: StopParams) -> None:
        if (not params.tolerance > 0 or params.stable_poses < 1 or params.min_poses < 1
                or not params.interval_width > 0):
            raise ValueError(f"planner.stop needs tolerance > 0, stable_poses >= 1, "
                             f"min_poses >= 1 and interval_width > 0; got {params}")
        self.params = params

    def held_still(self, track: EstimateTrack) -> tuple[BoxEstimate, ...] | None:
        """The last `stable_poses` + 1 estimates of `track` where at least `min_poses` were
        taken and every dimension moved less than `tolerance` over them, else None."""
        p, estimates = self.params, track.estimates
        recent = estimates[-(p.stable_poses + 1):]
        if (len(estimates) < max(p.min_poses, p.stable_poses + 1)
                or any(e is None or e.interval is None for e in recent)):
            return None
        spread = np.ptp(np.array([e.box.dims for e in recent]), axis=0)
        return recent if np.all(spread < p.tolerance) else None

    def update(self, track: EstimateTrack) -> str | None:
        """Why to stop after the last estimate of `track`, or None."""
        p, recent = self.params, self.held_still(track)
        # The interval is read only once the box has held still: it costs a profile of
        # every side and a refit of every part's every class.
        if (recent is None or not np.all(recent[-1].widths <= p.interval_width)
                or not recent[-1].chosen):
            return None
        return (f"the box held still and is known: every dimension moved less than "
                f"{1000 * p.tolerance:.0f} mm over the last "
                f"{'pose' if p.stable_poses == 1 else f'{p.stable_poses} poses'}, its "
                f"interval is narrower than {1000 * p.interval_width:.0f} mm and no other "
                f"class fits better "
                f"({' x '.join(f'{v:.3f}' for v in recent[-1].box.dims)} m)")
