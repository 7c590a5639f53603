"""The ObjectClustering system on its own: fixed input, evaluated output, caching on the input."""

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from lrnbv_drake.core.boxes import AlignedBox
from lrnbv_drake.core.mapping.extraction import ExtractionParams, ExtractionStatus
from lrnbv_drake.systems.object_clustering import ObjectClustering

RES = 0.01
PARAMS = ExtractionParams(workspace=AlignedBox([-0.3, -0.3, -0.05], [0.3, 0.3, 0.5]))


def box_scan() -> np.ndarray:
    """Cell centres of a 10 x 6 x 5 cm box standing on the table at the origin, grid-aligned,
    seen from above: its top cells, its +x side cells and the table cells around it."""
    i, j = np.meshgrid(np.arange(-5, 5), np.arange(-3, 3), indexing="ij")
    top = np.column_stack([i.ravel(), j.ravel(), np.full(i.size, 4)])  # cells z in [0.04, 0.05]
    jj, kk = np.meshgrid(np.arange(-3, 3), np.arange(0, 5), indexing="ij")
    side = np.column_stack([np.full(jj.size, 4), jj.ravel(), kk.ravel()])
    ti, tj = np.meshgrid(np.arange(-15, 15), np.arange(-15, 15), indexing="ij")
    table = np.column_stack([ti.ravel(), tj.ravel(), np.full(ti.size, -1)])  # cells z in [-0.01, 0]
    table = table[~((np.abs(table[:, 0] + 0.5) < 5) & (np.abs(table[:, 1] + 0.5) < 3))]
    return (np.vstack([top, side, table]) + 0.5) * RES


def test_ports_are_declared():
    dut = ObjectClustering(PARAMS)
    assert dut.get_input_port().get_name() == "occupied_points"
    assert dut.get_output_port().get_name() == "object"
    assert dut.params is PARAMS


def test_output_boxes_a_synthetic_box_scan():
    dut = ObjectClustering(PARAMS)
    context = dut.CreateDefaultContext()
    dut.get_input_port().FixValue(context, box_scan())
    result = dut.get_output_port().Eval(context)
    assert result.status is ExtractionStatus.FOUND and result.found
    # The cells span x in [-0.05, 0.05], y in [-0.03, 0.03], z up to 0.05, on a table at 0.
    np.testing.assert_allclose(result.dimensions, [0.10, 0.06, 0.05], atol=1e-9)
    np.testing.assert_allclose(result.center, [0.0, 0.0, 0.025], atol=1e-9)
    np.testing.assert_allclose(result.aligned_box.lower, [-0.05, -0.03, 0.0], atol=1e-9)
    np.testing.assert_allclose(result.roi.upper, [0.10, 0.08, 0.10], atol=1e-9)


def test_output_tracks_the_input():
    dut = ObjectClustering(PARAMS)
    context = dut.CreateDefaultContext()
    port = dut.get_input_port().FixValue(context, np.zeros((0, 3)))
    empty = dut.get_output_port().Eval(context)
    assert empty.status is ExtractionStatus.NO_POINTS and not empty.found
    port.GetMutableData().set_value(box_scan())
    assert dut.get_output_port().Eval(context).status is ExtractionStatus.FOUND


def test_unconnected_input_is_an_error():
    dut = ObjectClustering()
    with pytest.raises(RuntimeError):
        dut.get_output_port().Eval(dut.CreateDefaultContext())


def test_default_params_in_a_diagram():
    builder = DiagramBuilder()
    dut = builder.AddSystem(ObjectClustering())
    builder.ExportInput(dut.get_input_port(), "occupied_points")
    builder.ExportOutput(dut.get_output_port(), "object")
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    diagram.get_input_port().FixValue(context, box_scan())
    result = diagram.get_output_port().Eval(context)
    np.testing.assert_allclose(result.dimensions, [0.10, 0.06, 0.05], atol=1e-9)
