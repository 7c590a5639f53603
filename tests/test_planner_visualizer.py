"""PlannerVisualizer alone, and the ROI box's edges."""

import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams

from lrnbv_drake.core.mapping.extraction import ExtractionParams, extract_object
from lrnbv_drake.systems.planner_visualizer import PlannerVisualizer, box_edges


def test_box_edges_are_the_twelve_edges():
    starts, ends = box_edges(np.zeros(3), np.array([1.0, 2.0, 3.0]))
    lengths = np.sort(np.linalg.norm(ends - starts, axis=0))
    np.testing.assert_allclose(lengths, [1] * 4 + [2] * 4 + [3] * 4)
    # Every edge runs along one axis between two corners.
    assert np.all(np.count_nonzero(ends - starts, axis=0) == 1)


@pytest.fixture(scope="module")
def meshcat():
    return Meshcat(MeshcatParams(host="localhost"))


def _box_cells():
    g = np.arange(0.005, 0.1, 0.01)
    x, y = np.meshgrid(g + 0.4, g - 0.05)
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 0.055)])


def test_draws_one_step_per_plan(meshcat):
    dut = PlannerVisualizer(meshcat, publish_period=0.1, cell_size=0.01, prefix="test_plan")
    context = dut.CreateDefaultContext()
    cells = _box_cells()
    extraction = extract_object(cells, ExtractionParams(dbscan_eps=0.02))
    assert extraction.found
    dut.GetInputPort("object").FixValue(context, extraction)
    dut.GetInputPort("occupied_points").FixValue(context, cells)
    dut.GetInputPort("plan").FixValue(context, {})
    dut.ForcedPublish(context)
    assert not meshcat.HasPath("/drake/test_plan/000")  # no plan yet
    plan = {"step": 1, "X_WS": np.eye(4), "roi": (np.zeros(3), np.ones(3)),
            "tree_positions": np.array([[0, 0, 1], [0.1, 0, 1], [0.2, 0, 1.0]]),
            "tree_parents": np.array([-1, 0, 1]), "best_branch": np.array([1, 2]),
            "cached_positions": np.array([[0.3, 0.3, 0.5]])}
    dut.GetInputPort("plan").FixValue(context, plan)
    dut.ForcedPublish(context)
    dut.ForcedPublish(context)  # the same step is not drawn twice
    for part in ("cells", "object", "roi", "tree/edges", "tree/best_branch", "cache",
                 "chosen/z"):
        assert meshcat.HasPath(f"/drake/test_plan/000/{part}"), part
    assert not meshcat.HasPath("/drake/test_plan/001")
    dut.GetInputPort("plan").FixValue(context, {**plan, "step": 2})
    dut.ForcedPublish(context)
    assert meshcat.HasPath("/drake/test_plan/001/roi")
