"""`ObjectClustering`: the object extraction step (`extraction.extract_object`) as a system."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem

from lrnbv_drake.core.mapping.extraction import ExtractionParams, extract_object


class ObjectClustering(LeafSystem):
    """Finds and boxes the object among the occupied cells of the map.

    Input ports:
        occupied_points: abstract (N, 3) float64 ndarray, world-frame centres of the occupied
            cells (an empty (0, 3) array is fine). Must be connected or fixed.

    Output ports:
        object: abstract `ExtractionResult` (status, boxes, dimensions, ROI). Computed on demand
            and cached: it depends on the input only, so it is recomputed only when the
            occupied points change, not every time step.
    """

    def __init__(self, params: ExtractionParams | None = None) -> None:
        super().__init__()
        self._params = params if params is not None else ExtractionParams()
        self._points_port = self.DeclareAbstractInputPort(
            "occupied_points", AbstractValue.Make(np.zeros((0, 3)))
        )
        self.DeclareAbstractOutputPort(
            "object",
            lambda: AbstractValue.Make(extract_object(np.zeros((0, 3)), self._params)),
            self._calc_object,
            prerequisites_of_calc={self.input_port_ticket(self._points_port.get_index())},
        )

    @property
    def params(self) -> ExtractionParams:
        """The extraction settings."""
        return self._params

    def _calc_object(self, context: Context, output: AbstractValue) -> None:
        output.set_value(extract_object(self._points_port.Eval(context), self._params))
