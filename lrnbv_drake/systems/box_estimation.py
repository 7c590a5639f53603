"""`BoxEstimation`: the episode's box estimate as a Drake system, a thin wrapper of
`core.estimation.track.EpisodeEstimator`."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem

from lrnbv_drake.core.acquisition import EpisodeLog, estimator_inputs
from lrnbv_drake.core.estimation.track import EpisodeEstimator, EstimateTrack


class BoxEstimation(LeafSystem):
    """Estimates the object's box from the episode's readings, pose by pose.

    @system
    name: BoxEstimation
    input_ports:
    - log
    output_ports:
    - box_estimate
    @endsystem

    `log` is the acquisition loop's `EpisodeLog`; `box_estimate` the `EstimateTrack`: the
    estimate after each acquisition whose extraction the log holds (the loop logs it when
    it next plans; the stop rule reads this port then when it checks before planning, and
    shares this system's estimator when it checks during the move), the latest last. Like
    the map, the estimator keeps its warm start outside the Context: the output is computed
    whenever it is asked (not cached), folds in only what is new, and one system serves one
    episode.
    """

    def __init__(self, estimator: EpisodeEstimator) -> None:
        super().__init__()
        self._estimator = estimator
        self._log = self.DeclareAbstractInputPort("log", AbstractValue.Make(EpisodeLog()))
        self.DeclareAbstractOutputPort(
            "box_estimate", lambda: AbstractValue.Make(EstimateTrack()),
            self._calc).disable_caching_by_default()

    def _update(self, context: Context, final: bool) -> EstimateTrack:
        log: EpisodeLog = self._log.Eval(context)
        return self._estimator.update(*estimator_inputs(log), final=final)

    def _calc(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self._update(context, final=False))

    @property
    def made(self) -> EstimateTrack:
        """The estimates made so far, without making any (once a stop check running beside
        the move has made its own)."""
        return self._estimator.settled()

    def final_track(self, context: Context) -> EstimateTrack:
        """The track with every acquisition folded in, those after the last extraction from
        its cell box: what the report gives when an episode ended before it planned again
        (a fault, Ctrl-C)."""
        return self._update(context, final=True)
