"""What a motion planner answers, without Drake: a `MotionPlan` holding any trajectory that can
be sampled, or the `MotionFailure` that explains why there is none.

The acquisition loop (`core.acquisition`) only needs these; the planner that makes them
(`station.motion.MotionPlanner`) checks collisions in Drake's SceneGraph.
"""

from __future__ import annotations

import dataclasses as dc
import enum
from typing import Protocol

import numpy as np


class Trajectory(Protocol):
    """A joint trajectory (Drake's `PiecewisePolynomial` is one)."""

    def value(self, t: float) -> np.ndarray: ...
    def end_time(self) -> float: ...


class MotionFailure(enum.Enum):
    """Why a sensor pose cannot be reached."""

    OUTSIDE_WORKSPACE = "outside_workspace"
    UNREACHABLE = "unreachable"
    TARGET_IN_COLLISION = "target_in_collision"
    PATH_IN_COLLISION = "path_in_collision"
    PATH_OUTSIDE_WORKSPACE = "path_outside_workspace"


@dc.dataclass
class MotionPlan:
    """A planned motion, or why there is none."""

    failure: MotionFailure | None
    reason: str
    q_target: np.ndarray | None = None
    trajectory: Trajectory | None = None

    @property
    def ok(self) -> bool:
        return self.failure is None


class MotionPlanning(Protocol):
    """Plans a motion from joints `q_current` to sensor pose `X_WS` (4x4), starting at
    `start_time`; a failure is returned, never raised. The pose reached may be X_WS rolled
    about the optical axis by a symmetry of the zone grid (the same view); what a frame saw is
    placed by the pose measured at capture, never the planned one. `halt` stops a motion
    under way (the stop rule may end the episode during one)."""

    def plan(self, q_current: np.ndarray, X_WS: np.ndarray, start_time: float = 0.0
             ) -> MotionPlan: ...
    def halt(self, trajectory: Trajectory, t: float) -> Trajectory:
        """`trajectory`, one this planner made, brought to rest from time t without leaving
        its checked path."""
        ...
