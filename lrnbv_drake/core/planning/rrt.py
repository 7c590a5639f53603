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

from lrnbv_drake.core.boxes import AlignedBox
from lrnbv_drake.core.planning.config import TreeParams
from lrnbv_drake.core.planning.utility import Gains
from lrnbv_drake.core.robot.poses import look_at_batch

#: Scores a batch of poses (P, 4, 4): raw gains and utilities under the current normaliser.
Scorer = Callable[[np.ndarray], tuple[Gains, np.ndarray]]


@dc.dataclass
class Reach:
    """How the robot reaches a view: IK solutions of many sensor poses (N, 4, 4) at once, as
    (Q, n) with pose i's n[i] solutions best first in Q[i, :n[i]] (Q (N, k, 6)), and whether a
    joint configuration is collision free. `first_free`, where given, finds in one call the
    index of the first collision-free configuration of Q (k, 6), -1 if none: what
    `collision_free` on each in turn finds."""

    ik: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    collision_free: Callable[[np.ndarray], bool]
    first_free: Callable[[np.ndarray], int] | None = None

    def first(self, Q: np.ndarray) -> int:
        """The index of the first collision-free configuration of Q (k, 6), -1 if none."""
        if self.first_free is not None:
            return self.first_free(Q)
        return next((j for j, q in enumerate(Q) if self.collision_free(q)), -1)


@dc.dataclass
class ViewTree:
    """Nodes in insertion order; node 0 is the root (the current pose, not a candidate)."""

    poses: list[np.ndarray]
    parents: list[int]
    gains: list[Gains]
    # The collision-free joint configuration each node was reached with (the root's: None).
    configs: list[np.ndarray | None]

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


def orient(positions: np.ndarray, aims: np.ndarray) -> np.ndarray:
    """(B, A, 4, 4) sensor poses at each of `positions` (B, 3) looking at each aim point."""
    B, A = len(positions), len(aims)
    eyes = np.repeat(positions, A, axis=0)
    return look_at_batch(eyes, np.tile(aims, (B, 1))).reshape(B, A, 4, 4)


def expand_tree(tree: ViewTree | np.ndarray, n: int,
                sample_positions: Callable[[int], np.ndarray], workspace: AlignedBox,
                roi: AlignedBox, score: Scorer, reach: Reach, params: TreeParams,
                steer: bool = True) -> ViewTree:
    """Adds up to `n` candidate views to `tree`, or to a new tree rooted at the pose `tree`
    (4x4), and returns the tree.

    Nodes are added in rounds of `params.round_size`: each node of a round steers from its
    nearest node in the tree as it stood when the round began, and the round's views share one
    IK call and one utility evaluation (which is what makes a tree cheap in Python). Each node
    keeps its view of highest utility among those with a collision-free IK solution; views
    without any IK solution are not scored at all.

    Args:
        sample_positions: draws the (k, 3) positions the next k nodes steer towards.
        workspace: where sensor positions may be.
        roi: the region of interest the views look at.
        score: gains and utilities of a batch of poses.
        reach: IK and collision checks of the robot.
        steer: limit edges to `params.max_edge`; without, a node is placed at the sample
            itself (ExpandRRTCached samples around cached nodes that may be far away).
    """
    if not isinstance(tree, ViewTree):
        tree = ViewTree(poses=[np.asarray(tree, float)], parents=[-1],
                        gains=[Gains(*(np.zeros(1) for _ in range(4)))], configs=[None])
    wanted = tree.size + n
    keep_out = roi.inflate(params.roi_clearance)
    aims = aim_points(roi, params.aim_offset_fraction)
    A = len(aims)
    positions = np.array([X[:3, 3] for X in tree.poses])
    attempts = n * params.max_attempts_per_node
    while tree.size < wanted and attempts > 0:
        batch = min(params.round_size, wanted - tree.size, attempts)
        attempts -= batch
        targets = np.asarray(sample_positions(batch), float).reshape(batch, 3)
        distances = np.linalg.norm(targets[:, None] - positions[None], axis=2)
        nearest = np.argmin(distances, axis=1)
        d = distances[np.arange(batch), nearest]
        step = np.minimum(1.0, params.max_edge / np.maximum(d, 1e-12)) if steer else \
            np.ones(batch)
        new = positions[nearest] + step[:, None] * (targets - positions[nearest])
        keep = workspace.contains(new) & ~keep_out.contains(new)
        if not keep.any():
            continue
        new, nearest = new[keep], nearest[keep]
        poses = orient(new, aims)  # (B, A, 4, 4)
        solutions, n_solutions = reach.ik(poses.reshape(-1, 4, 4))
        has_ik = n_solutions > 0
        if not has_ik.any():
            continue
        gains, scored = score(poses.reshape(-1, 4, 4)[has_ik])
        utilities = np.full(len(has_ik), -np.inf)
        utilities[has_ik] = scored
        index_in_scored = np.cumsum(has_ik) - 1
        fields = gains._fields()
        n_solutions = n_solutions.tolist()
        added = []
        # Each node's views, best first (a stable sort per row, as one call).
        for b, ranked in enumerate(np.argsort(-utilities.reshape(-1, A), axis=1,
                                              kind="stable").tolist()):
            for k in ranked:
                i = b * A + k
                first = reach.first(solutions[i, :n_solutions[i]]) if n_solutions[i] else -1
                if first >= 0:
                    free = solutions[i, first]
                    j = int(index_in_scored[i])
                    tree.poses.append(poses[b, k])
                    tree.parents.append(int(nearest[b]))
                    tree.gains.append(Gains(*(g[j:j + 1] for g in fields)))
                    tree.configs.append(free)
                    added.append(b)
                    break
        if added:
            positions = np.concatenate([positions, new[added]])
    return tree
