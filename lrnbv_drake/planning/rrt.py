"""The receding-horizon tree of sensor poses (the paper's ExpandRRT and ExpandRRTCached).

A tree starts at the current sensor pose. Each new node steers from its nearest tree node
towards a sampled position (at most `max_edge` away), must lie in the workspace and outside the
ROI inflated by a clearance, and takes the orientation of highest utility among a few views
aimed at the ROI (its centre and points around it) that the robot can reach. Branches are the
root-to-leaf paths; the best branch maximises the sum of its nodes' utilities (eq. 6).
"""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Callable

import numpy as np

from lrnbv_drake.boxes import AlignedBox
from lrnbv_drake.planning.utility import Gains
from lrnbv_drake.poses import look_at

#: Scores a batch of poses (P, 4, 4): raw gains and utilities under the current normaliser.
Scorer = Callable[[np.ndarray], tuple[Gains, np.ndarray]]
#: Whether the robot can put the sensor at a pose (IK within limits and no collision).
Reachable = Callable[[np.ndarray], bool]


@dc.dataclass
class TreeParams:
    """Tree growth."""

    # Longest edge between a node and its parent, metres.
    max_edge: float = 0.25
    # Clearance kept between sensor positions and the ROI, metres.
    roi_clearance: float = 0.10
    # Aim points: the ROI centre and four points this fraction of the ROI's size around it.
    aim_offset_fraction: float = 0.25
    # Give up after this many samples per wanted node (unreachable or rejected samples).
    max_attempts_per_node: int = 6


@dc.dataclass
class ViewTree:
    """Nodes in insertion order; node 0 is the root (the current pose, not a candidate)."""

    poses: list[np.ndarray]
    parents: list[int]
    gains: list[Gains]

    @property
    def size(self) -> int:
        """Number of candidate nodes (the root excluded)."""
        return len(self.poses) - 1

    def candidate_gains(self) -> Gains:
        return Gains.concatenate(self.gains[1:])

    def branches(self) -> list[list[int]]:
        """Every root-to-leaf path, as lists of node indices without the root."""
        children = {i for i in self.parents if i >= 0}
        leaves = [i for i in range(1, len(self.poses)) if i not in children]
        paths = []
        for leaf in leaves:
            path, i = [], leaf
            while i > 0:
                path.append(i)
                i = self.parents[i]
            paths.append(path[::-1])
        return paths

    def best_branch(self, utilities: np.ndarray) -> list[int]:
        """The branch of largest summed utility; `utilities[i]` is node i + 1's."""
        branches = self.branches()
        if not branches:
            return []
        sums = [sum(utilities[i - 1] for i in b) for b in branches]
        return branches[int(np.argmax(sums))]


def aim_points(roi: AlignedBox, fraction: float) -> np.ndarray:
    """(5, 3) points a view may look at: the ROI centre and four around it in x and y."""
    c, s = roi.center, roi.size * fraction
    offsets = np.array([[0, 0, 0], [s[0], 0, 0], [-s[0], 0, 0], [0, s[1], 0], [0, -s[1], 0]])
    return c + offsets


def orient(position: np.ndarray, aims: np.ndarray) -> np.ndarray:
    """(A, 4, 4) sensor poses at `position` looking at each aim point."""
    return np.array([look_at(position, a) for a in aims])


def expand_tree(root: np.ndarray, n: int, sample_position: Callable[[], np.ndarray],
                workspace: AlignedBox, roi: AlignedBox, score: Scorer, reachable: Reachable,
                params: TreeParams, steer: bool = True) -> ViewTree:
    """Grows a tree of up to `n` candidate views from the pose `root` (4x4).

    Args:
        sample_position: draws the position the next node steers towards.
        steer: limit edges to `params.max_edge`; without, a node is placed at the sample
            itself (ExpandRRTCached samples around cached nodes that may be far away).
        workspace: where sensor positions may be.
        roi: the region of interest the views look at.
        score: gains and utilities of a batch of poses.
        reachable: whether the robot reaches a pose.
    """
    tree = ViewTree(poses=[np.asarray(root, float)], parents=[-1],
                    gains=[Gains(*(np.zeros(1) for _ in range(4)))])
    keep_out = roi.inflate(params.roi_clearance)
    aims = aim_points(roi, params.aim_offset_fraction)
    positions = [tree.poses[0][:3, 3]]
    for _ in range(n * params.max_attempts_per_node):
        if tree.size >= n:
            break
        target = sample_position()
        distances = np.linalg.norm(np.asarray(positions) - target, axis=1)
        nearest = int(np.argmin(distances))
        step = min(1.0, params.max_edge / max(distances[nearest], 1e-12)) if steer else 1.0
        position = positions[nearest] + step * (target - positions[nearest])
        if not workspace.contains(position[None])[0] or keep_out.contains(position[None])[0]:
            continue
        poses = orient(position, aims)
        gains, utilities = score(poses)
        for k in np.argsort(-utilities, kind="stable"):
            if reachable(poses[k]):
                tree.poses.append(poses[k])
                tree.parents.append(nearest)
                tree.gains.append(gains.take(k))
                positions.append(position)
                break
    return tree
