"""HEU: the paper's heuristic baseline, evenly spaced poses on an ellipse around the object.

It is given the object's position (the others are not) and visits `n_poses` poses evenly spaced
in angle on a horizontal ellipse centred above it, each looking at the object's centre. A pose
the robot cannot reach is skipped, and the number of skipped poses is reported.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lrnbv_drake.core.planning.config import HeuParams
from lrnbv_drake.core.planning.policy import Observation, Proposal, Recorded, ViewpointPolicy
from lrnbv_drake.core.robot.poses import look_at


def heu_poses(target: np.ndarray, params: HeuParams) -> list[np.ndarray]:
    """The ellipse's sensor poses (4x4 X_WS), each looking at `target`."""
    target = np.asarray(target, float)
    angles = params.start_angle + 2 * np.pi * np.arange(params.n_poses) / params.n_poses
    eyes = target + np.column_stack([params.semi_axis_x * np.cos(angles),
                                     params.semi_axis_y * np.sin(angles),
                                     np.full(params.n_poses, params.height)])
    return [look_at(eye, target) for eye in eyes]


class HeuPolicy(ViewpointPolicy):
    """Visits the ellipse's poses in order; done after the last."""

    name = "heu"
    capture_initial = False

    def __init__(self, object_center: np.ndarray, params: HeuParams | None = None):
        self.params = params or HeuParams()
        self.poses = heu_poses(object_center, self.params)
        self._next = 0

    def propose(self, observation: Observation) -> Proposal:
        if self._next >= len(self.poses):
            return Proposal(done=True, reason=f"visited the {len(self.poses)} ellipse poses")
        return Proposal(candidates=self.poses[self._next:],
                        debug={"ellipse_positions": np.array([X[:3, 3] for X in self.poses])},
                        candidate_info=[{"ellipse_index": i}
                                        for i in range(self._next, len(self.poses))])

    def accepted(self, index: int, observation: Observation) -> None:
        self._next += index + 1

    def restore(self, acquisitions: Sequence[Recorded]) -> None:
        """Goes on after the last ellipse pose visited: the ones before it were visited or
        skipped as unreachable, as `accepted` would have left them. Reads the logged
        `ellipse_index`, so it does not depend on how the candidates were ranked."""
        visited = [int(a.info["ellipse_index"]) for a in acquisitions
                   if "ellipse_index" in a.info]
        if visited:
            self._next = max(visited) + 1
