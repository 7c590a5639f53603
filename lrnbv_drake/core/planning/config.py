"""Parameters of the viewpoint planners, loadable from scenario YAML.

The defaults are the paper's Table 1 where it gives a value; docs/algorithm.md explains every
other default. This module has no `from __future__ import annotations` because Drake's YAML
loader reads the dataclass field types.
"""

import dataclasses as dc
import math


@dc.dataclass
class UtilityWeights:
    """Weights of the four gains (Table 1), and of the box gain (not the paper's: 0 in
    `utility: paper`)."""

    exploration: float = 500.0
    density: float = 0.05
    quality: float = 0.08
    visited: float = 500.0
    box: float = 0.0


@dc.dataclass
class GainParams:
    """How the gains are computed."""

    # Length of each gain ray (the paper's t = 1), metres.
    max_range: float = 1.0
    # Sub-rays per zone side (1: one ray through each zone centre).
    rays_per_zone: int = 1
    # Radius r_d of the neighbourhood counted by the density gain, metres.
    density_radius: float = 0.02
    # Divide Ge, Gd and Gq by their running maxima so that Table 1's weights compare like with
    # like (as the FKIE planner the paper builds on does).
    normalize: bool = True


@dc.dataclass
class TreeParams:
    """Growth of the tree of views."""

    # Longest edge between a node and its parent, metres.
    max_edge: float = 0.25
    # Clearance kept between sensor positions and the ROI, metres.
    roi_clearance: float = 0.10
    # Aim points: the ROI centre and four points this fraction of the ROI's size around it.
    aim_offset_fraction: float = 0.25
    # Give up after this many samples per wanted node (unreachable or rejected samples).
    max_attempts_per_node: int = 6
    # Nodes added per round: a round's nodes steer from the tree as it was when the round
    # began, and share one utility evaluation and one IK call.
    round_size: int = 10


@dc.dataclass
class StopParams:
    """When an LR-NBV or NBV episode ends, besides the pose cap (core/planning/stop.py)."""

    # "paper": Algorithm 1, line 24 alone. "box" (the product's default): also once every
    # dimension of the reported estimate has moved less than `tolerance` (m) over the last
    # `stable_poses` poses, `min_poses` were taken and its interval is narrower than
    # `interval_width` (m) on every dimension, and no class of a part the interval tries is
    # the information criterion's choice over the fit's (core/planning/stop.py). One pose
    # confirms: the interval guards the sides a second would (docs/decisions/0025).
    rule: str = "box"
    tolerance: float = 0.005
    stable_poses: int = 1
    min_poses: int = 4
    interval_width: float = 0.02
    # Make the estimate after a pose, and check this rule on it, while the arm moves to the
    # next view, halting the move if it says stop, for every planner that does not read the
    # estimate to choose the view (core/planning/stop_while_moving.py): the same poses and box as
    # false, which checks before planning, in a shorter cycle.
    while_moving: bool = True


@dc.dataclass
class PlannerParams:
    """LR-NBV's parameters."""

    # Hard cap on iterations (acquisitions after the first), Table 1's num_iterations.
    num_iterations: int = 300
    # Samples per tree, n (Table 1's sample_per_iteration).
    samples_per_iteration: int = 50
    # Cached nodes kept at the first iteration, m_0; m_i falls linearly to 0 at num_iterations.
    num_cached_nodes: int = 50
    # Cell size of the visited grid, metres (Table 1's visited_cells_grid_size).
    visited_cell_size: float = 0.18
    weights: UtilityWeights = dc.field(default_factory=UtilityWeights)
    gains: GainParams = dc.field(default_factory=GainParams)
    tree: TreeParams = dc.field(default_factory=TreeParams)
    # tau: off-branch nodes with a utility above this are cached.
    cache_threshold: float = 0.0
    # Spread of the samples drawn around a cached node by ExpandRRTCached, metres.
    cached_sample_spread: float = 0.05
    # Where to look for the object while none has been found (world box, metres): the table's
    # lowest 8 cm, which every object on it fills in part; views scored over a taller box
    # look level across it into nothing (docs/decisions/0005).
    search_lower: list[float] = dc.field(default_factory=lambda: [0.25, -0.3, 0.0])
    search_upper: list[float] = dc.field(default_factory=lambda: [0.75, 0.3, 0.08])
    # Where the search looks instead once at least this many occupied cells stand above the
    # table inside its footprint, too few for a cluster (`ExtractionResult.loose_points`):
    # their box down to the table, grown by `lead_margin` (0: the search region always).
    lead_points: int = 3
    lead_margin: float = 0.05
    stop: StopParams = dc.field(default_factory=StopParams)
    # What a view is worth: "paper", U = we Ge + wd Gd + wq Gq + wv Gv (`weights`, Table 1);
    # "box", (Gb + `box_exploration` Ge) over the seconds to reach the view and take its
    # frame, each gain over its running maximum, plus Gv (core/planning/box_gain.py).
    utility: str = "paper"
    # The box utility's weight of the exploration gain, which finds parts not yet seen.
    box_exploration: float = 0.5
    # The first frame: "drop_zone" (the product's), straight down over `cell.drop_zone`, the
    # whole zone in view (core/planning/first_view.py); "home" (the paper's), at the start
    # pose before the first proposal.
    first_view: str = "drop_zone"
    # lambda, 1/s: a view's positive utility is multiplied by exp(-lambda t), t the time the
    # arm takes to reach it from where it is (the receding-horizon NBV planners' discount).
    # 0 (the paper's: utilities as they are) is the default: accuracy before cycle time
    # (docs/decisions/0007).
    travel_discount: float = 0.0


@dc.dataclass
class HeuParams:
    """HEU's ellipse of viewpoints (core/planning/heu.py)."""

    # Number of poses (13 in the paper).
    n_poses: int = 13
    # Semi-axes of the ellipse along world x and y, metres.
    semi_axis_x: float = 0.22
    semi_axis_y: float = 0.28
    # Height of the ellipse above the object's centre, metres.
    height: float = 0.25
    # Angle of the first pose about the object (pi: on the robot's side), radians.
    start_angle: float = math.pi
