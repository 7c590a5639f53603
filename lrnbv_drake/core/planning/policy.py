"""The interface between the acquisition loop and a viewpoint planner (HEU, NBV, LR-NBV).

The loop (`systems/nbv_planner.py`) asks the policy for ranked candidate sensor poses, moves to
the first one the robot can reach without collision, captures, lets the map and the clustering
catch up, and asks again, until the policy says it is done.
"""

from __future__ import annotations

import abc
import dataclasses as dc
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

#: The key under which the loop records, in an acquisition's info, which candidate of the
#: proposal it moved to (absent for a capture no proposal led to, such as the initial one).
CANDIDATE_RANK = "candidate_rank"
#: The key of an acquisition's info that numbers it among its view's frames (0 first; only
#: where the proposal asked for more than one, `Proposal.frames`).
FRAME_OF_VIEW = "frame_of_view"


@dc.dataclass
class Observation:
    """What a policy knows when it chooses the next viewpoint.

    Args:
        time: simulation (or wall) time, seconds.
        q: current joint positions.
        X_WS: current sensor pose in world (4x4).
        occupancy: the occupancy map (an `OccupancyMap`), or None before the first capture.
        extraction: the latest object extraction (`ExtractionResult`), or None.
        n_acquisitions: frames captured so far.
        estimate: the reported estimate after the last frame (a `BoxEstimate`), or None.
    """

    time: float
    q: np.ndarray
    X_WS: np.ndarray
    occupancy: Any = None
    extraction: Any = None
    n_acquisitions: int = 0
    estimate: Any = None


@dc.dataclass
class Proposal:
    """A policy's answer: candidate sensor poses, best first, or done with a reason.

    `frames` consecutive frames are recorded at the view, each an acquisition (a
    calibration averages them; a planner takes one). `info` describes the proposal (it is
    logged with each acquisition it leads to);
    `candidate_info`, when given, holds one dict per candidate, merged into it; `debug` holds
    arrays worth drawing (tree, cache, ROI), not logged.
    """

    candidates: list[np.ndarray] = dc.field(default_factory=list)
    done: bool = False
    reason: str = ""
    frames: int = 1
    info: dict[str, Any] = dc.field(default_factory=dict)
    candidate_info: list[dict[str, Any]] | None = None
    debug: dict[str, Any] = dc.field(default_factory=dict)


class Recorded(Protocol):
    """What `ViewpointPolicy.restore` reads of a past acquisition (`nbv_planner.Acquisition`
    has it): its number, capture time, joints, sensor pose (4x4) and the logged info."""

    index: int
    time: float
    q: np.ndarray
    X_WS: np.ndarray
    info: dict[str, Any]


class ViewpointPolicy(abc.ABC):
    """Chooses where the sensor looks next."""

    #: Short name used in reports ("heu", "nbv", "lrnbv").
    name: str = "policy"
    #: Whether the loop captures a frame at the start pose before the first proposal.
    capture_initial: bool = False
    #: Whether `propose` reads `Observation.estimate`: the loop then makes the estimate and
    #: checks the stop before proposing, not while the arm moves (stop_while_moving.py).
    reads_estimate: bool = False

    @abc.abstractmethod
    def propose(self, observation: Observation) -> Proposal:
        """Candidate poses for the next acquisition, or done."""

    def accepted(self, index: int, observation: Observation) -> None:  # noqa: B027
        """Called when the loop moves to `candidates[index]` of the last proposal."""

    def restore(self, acquisitions: Sequence[Recorded]) -> None:
        """Puts a new policy where it would be had it made `acquisitions` itself, ready for its
        next proposal: used to resume a recorded episode. Call it once, before `propose`.

        The default replays `accepted` for every acquisition a proposal led to, which restores
        a policy whose progress lives in `accepted`. The loop's observation at that moment is
        not recorded, so each replay gets one rebuilt from the acquisition itself. A policy
        that also learns in `propose` overrides this.
        """
        for a in acquisitions:
            if CANDIDATE_RANK in a.info:
                self.accepted(int(a.info[CANDIDATE_RANK]), Observation(
                    time=a.time, q=a.q, X_WS=a.X_WS, n_acquisitions=a.index))
