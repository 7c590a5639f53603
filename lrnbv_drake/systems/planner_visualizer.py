"""PlannerVisualizer: what the planner saw and chose, step by step, in Meshcat.

For every accepted plan it draws the occupied cells (grey) and the object's cells (orange), the
ROI box (yellow), the tree of views (light blue, the best branch dark blue), the cached nodes
(magenta) and the chosen view's axes. Each step's drawing replaces the previous one from the
step's time on, in the live view and in the recording.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Meshcat, Rgba
from pydrake.perception import PointCloud
from pydrake.systems.framework import LeafSystem

from lrnbv_drake.systems.meshcat_steps import show_from

CELL_RGBA = Rgba(0.6, 0.6, 0.6, 1.0)
OBJECT_RGBA = Rgba(0.95, 0.5, 0.1, 1.0)
ROI_RGBA = Rgba(0.95, 0.85, 0.1, 1.0)
TREE_RGBA = Rgba(0.5, 0.75, 1.0, 1.0)
BRANCH_RGBA = Rgba(0.05, 0.2, 0.9, 1.0)
CACHE_RGBA = Rgba(0.9, 0.1, 0.8, 1.0)
AXES_RGBA = (Rgba(1, 0, 0, 1), Rgba(0, 0.8, 0, 1), Rgba(0, 0, 1, 1))


def box_edges(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 12 edges of an axis-aligned box as (3, 12) start and end points."""
    corners = np.array([[(upper if (i >> a) & 1 else lower)[a] for a in range(3)]
                        for i in range(8)])
    pairs = [(i, i | (1 << a)) for i in range(8) for a in range(3) if not (i >> a) & 1]
    return corners[[p[0] for p in pairs]].T, corners[[p[1] for p in pairs]].T


def _cloud(points: np.ndarray) -> PointCloud:
    cloud = PointCloud(len(points))
    cloud.mutable_xyzs()[:] = np.asarray(points, float).T
    return cloud


class PlannerVisualizer(LeafSystem):
    """Input ports `plan` (the planner's dict), `object` (ExtractionResult) and
    `occupied_points` ((N, 3) array)."""

    def __init__(self, meshcat: Meshcat, *, publish_period: float, cell_size: float,
                 prefix: str = "planner"):
        super().__init__()
        self._meshcat = meshcat
        self._cell_size = cell_size
        self._prefix = prefix
        self._drawn_steps: list[int] = []  # side-effect bookkeeping, as Drake's visualizers do
        self.DeclareAbstractInputPort("plan", AbstractValue.Make({}))
        self.DeclareAbstractInputPort("object", AbstractValue.Make(None))
        self.DeclareAbstractInputPort("occupied_points", AbstractValue.Make(np.zeros((0, 3))))
        self.DeclarePeriodicPublishEvent(publish_period, 0.0, self._Publish)
        self.DeclareForcedPublishEvent(self._Publish)

    def _Publish(self, context) -> None:
        plan = self.GetInputPort("plan").Eval(context)
        step = plan.get("step")
        if step is None or (self._drawn_steps and self._drawn_steps[-1] == step):
            return
        m, t = self._meshcat, context.get_time()
        path = f"{self._prefix}/{len(self._drawn_steps):03d}"
        occupied = self.GetInputPort("occupied_points").Eval(context)
        if len(occupied):
            m.SetObject(f"{path}/cells", _cloud(occupied), self._cell_size, CELL_RGBA)
        extraction = self.GetInputPort("object").Eval(context)
        if extraction is not None and extraction.found:
            m.SetObject(f"{path}/object", _cloud(extraction.object_points),
                        self._cell_size * 1.2, OBJECT_RGBA)
        if "roi" in plan:
            m.SetLineSegments(f"{path}/roi", *box_edges(*plan["roi"]), 2.0, ROI_RGBA)
        if "tree_positions" in plan:
            self._draw_tree(path, plan)
        if "ellipse_positions" in plan:
            m.SetObject(f"{path}/ellipse", _cloud(plan["ellipse_positions"]), 0.02, TREE_RGBA)
        X = plan["X_WS"]
        for axis, rgba in enumerate(AXES_RGBA):
            m.SetLineSegments(f"{path}/chosen/{'xyz'[axis]}", X[:3, 3][:, None],
                              (X[:3, 3] + 0.06 * X[:3, axis])[:, None], 4.0, rgba)
        previous = f"{self._prefix}/{len(self._drawn_steps) - 1:03d}" if self._drawn_steps \
            else None
        show_from(m, path, t, previous)
        self._drawn_steps.append(step)

    def _draw_tree(self, path: str, plan: dict) -> None:
        m = self._meshcat
        positions, parents = plan["tree_positions"], plan["tree_parents"]
        children = np.flatnonzero(parents >= 0)
        if len(children):
            m.SetLineSegments(f"{path}/tree/edges", positions[parents[children]].T,
                              positions[children].T, 1.0, TREE_RGBA)
            m.SetObject(f"{path}/tree/nodes", _cloud(positions[1:]), 0.015, TREE_RGBA)
        branch = list(plan["best_branch"])
        if branch:
            chain = [0, *branch]
            m.SetLineSegments(f"{path}/tree/best_branch", positions[chain[:-1]].T,
                              positions[chain[1:]].T, 3.0, BRANCH_RGBA)
        if len(plan["cached_positions"]):
            m.SetObject(f"{path}/cache", _cloud(plan["cached_positions"]), 0.02, CACHE_RGBA)
