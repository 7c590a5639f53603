"""The interface between the acquisition loop and a viewpoint planner (HEU, NBV, LR-NBV).

The loop (`systems/nbv_planner.py`) asks the policy for ranked candidate sensor poses, moves to
the first one the robot can reach without collision, captures, lets the map and the clustering
catch up, and asks again, until the policy says it is done.
"""

from __future__ import annotations

import abc
import dataclasses as dc
from typing import Any

import numpy as np


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
    """

    time: float
    q: np.ndarray
    X_WS: np.ndarray
    occupancy: Any = None
    extraction: Any = None
    n_acquisitions: int = 0


@dc.dataclass
class Proposal:
    """A policy's answer: candidate sensor poses, best first, or done with a reason.

    `info` describes the proposal (it is logged with the acquisition it leads to);
    `candidate_info`, when given, holds one dict per candidate, merged into it; `debug` holds
    arrays worth drawing (tree, cache, ROI), not logged.
    """

    candidates: list[np.ndarray] = dc.field(default_factory=list)
    done: bool = False
    reason: str = ""
    info: dict[str, Any] = dc.field(default_factory=dict)
    candidate_info: list[dict[str, Any]] | None = None
    debug: dict[str, Any] = dc.field(default_factory=dict)


class ViewpointPolicy(abc.ABC):
    """Chooses where the sensor looks next."""

    #: Short name used in reports ("heu", "nbv", "lrnbv").
    name: str = "policy"
    #: Whether the loop captures a frame at the start pose before the first proposal.
    capture_initial: bool = False

    @abc.abstractmethod
    def propose(self, observation: Observation) -> Proposal:
        """Candidate poses for the next acquisition, or done."""

    def accepted(self, index: int, observation: Observation) -> None:  # noqa: B027
        """Called when the loop moves to `candidates[index]` of the last proposal."""
