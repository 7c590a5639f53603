"""`OccupancyMapSystem`: the occupancy map as a Drake system, fed with ToF frames.

The map itself (`lrnbv_drake.core.mapping.OccupancyMap`, tens of MB) lives outside the Context: the
abstract state holds a handle to it plus the sequence number of the last inserted frame. Drake
deep-copies abstract state (Value[object] clones with `copy.deepcopy`, and the Simulator clones
the state around every unrestricted update); deep copies of the handle share the map, so a copy
costs microseconds. The price: the map is not context-pure. Every Context made from this system
shares one map, and neither restoring an old Context nor re-initialising a Simulator undoes an
insertion; make a new system (or `OccupancyMap.copy()`) for an independent map.
"""

from __future__ import annotations

import dataclasses as dc
import time
from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import Context, EventStatus, LeafSystem, State

from lrnbv_drake.core.mapping import BoundsLike, OccupancyMap, OccupancyUpdate
from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry


@dc.dataclass
class MapState:
    """The abstract state: the shared map and the sequence of the last frame inserted into it
    (None before the first). Deep copies share the map."""

    map: OccupancyMap
    last_sequence: int | None = None

    def __deepcopy__(self, memo: dict) -> MapState:
        return MapState(self.map, self.last_sequence)


class OccupancyMapSystem(LeafSystem):
    """Inserts each new VL53L8CX frame into an occupancy map.

    Input ports:
        tof_frame: abstract `ToFFrame`.
        X_WS: abstract `RigidTransform`, the sensor pose in world when the frame was captured.

    Output ports:
        map: abstract `OccupancyMap`, the live map (a handle, not a snapshot).
        occupied_points: abstract (N, 3) float64 ndarray, centres of the occupied cells.

    Updates: an unrestricted update event reads both inputs and inserts the frame when its
    `sequence` is not 0 (no frame yet) and differs from the last inserted one; a frame
    already inserted is ignored, so a sensor may hold its output between captures. The event
    is periodic (every `period` seconds from t = 0) unless `period` is None, and is also
    declared as a forced event, so `ExecuteForcedEvents(context)` inserts the current frame at
    once (tests, or a diagram that drives captures itself).

    Args:
        bounds: ((x0, y0, z0), (x1, y1, z1)) box the map covers, world frame, metres.
        resolution: cell edge, metres.
        mode: "ray" (one ray per zone) or "cone" (k x k sub-rays per zone); see
            `mapping.frame_scan`.
        geometry: zone layout of the sensor; the VL53L8CX default if None.
        max_range: OctoMap's maxrange, metres; None for unlimited.
        period: update period, seconds; None for forced updates only.
        cone_k: sub-rays per zone side in cone mode.
        free_no_target: let no-target zones (status 255) free their rays up to max_range.
        occupancy_update: occupancy update parameters; OctoMap's defaults if None.
    """

    def __init__(
        self,
        bounds: BoundsLike,
        resolution: float = 0.01,
        mode: str = "ray",
        geometry: ZoneGeometry | None = None,
        max_range: float | None = None,
        period: float | None = 0.05,
        cone_k: int = 5,
        free_no_target: bool = False,
        occupancy_update: OccupancyUpdate | None = None,
    ) -> None:
        super().__init__()
        if mode not in ("ray", "cone"):
            raise ValueError(f"mode must be 'ray' or 'cone'; got {mode!r}")
        if period is not None and not period > 0:
            raise ValueError(f"period must be > 0 or None; got {period}")
        if free_no_target and max_range is None:
            raise ValueError("free_no_target needs a max_range")
        self._map = OccupancyMap(resolution, bounds=bounds, occupancy_update=occupancy_update)
        self._geometry = geometry if geometry is not None else ZoneGeometry()
        self._insert_args = dict(mode=mode, max_range=max_range, cone_k=cone_k,
                                 free_no_target=free_no_target)
        self._insert_seconds: list[float] = []

        self._frame_port = self.DeclareAbstractInputPort(
            "tof_frame", AbstractValue.Make(ToFFrame.empty(self._geometry.resolution)))
        self._pose_port = self.DeclareAbstractInputPort(
            "X_WS", AbstractValue.Make(RigidTransform()))
        self._state_index = self.DeclareAbstractState(AbstractValue.Make(MapState(self._map)))
        # Outputs follow the map, i.e. the state, not the inputs: a new frame on the input
        # changes nothing downstream until it is inserted.
        state_ticket = {self.abstract_state_ticket(self._state_index)}
        self.DeclareAbstractOutputPort("map", lambda: AbstractValue.Make(self._map),
                                       self._calc_map, prerequisites_of_calc=state_ticket)
        self.DeclareAbstractOutputPort("occupied_points",
                                       lambda: AbstractValue.Make(np.zeros((0, 3))),
                                       self._calc_occupied_points,
                                       prerequisites_of_calc=state_ticket)
        if period is not None:
            self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)
        self.DeclareForcedUnrestrictedUpdateEvent(self._update)

    @property
    def occupancy_map(self) -> OccupancyMap:
        """The map every Context of this system shares."""
        return self._map

    def mark_inserted(self, context: Context, sequence: int) -> None:
        """Records in this system's `context` that the frame numbered `sequence` is already in
        the map, so the update ignores it while it stays on the input.

        For a map filled directly: e.g. a resumed session inserts its recorded frames into
        `occupancy_map` itself, and the last of them is still on the planner's output. Like
        any frame, a later one with another sequence is inserted.
        """
        self.ValidateContext(context)
        context.get_mutable_abstract_state(self._state_index).set_value(
            MapState(self._map, sequence))

    def insert_recorded(self, context: Context,
                        recorded: Sequence[tuple[ToFFrame, np.ndarray]]) -> None:
        """Inserts recorded (frame, X_WS 4x4) pairs into the map, in order, with this
        system's insertion settings, and marks the last as inserted (`mark_inserted`): the
        map a run had, rebuilt from what it recorded (a resumed session)."""
        for frame, X_WS in recorded:
            self._map.insert_frame(frame, self._geometry, np.asarray(X_WS, float),
                                   **self._insert_args)
        if recorded:
            self.mark_inserted(context, recorded[-1][0].sequence)

    @property
    def insert_seconds(self) -> list[float]:
        """Wall-clock seconds each frame insertion took, in order (for run reports; like the
        map, shared by all Contexts)."""
        return list(self._insert_seconds)

    def _update(self, context: Context, state: State) -> EventStatus:
        frame: ToFFrame = self._frame_port.Eval(context)
        current: MapState = context.get_abstract_state(self._state_index).get_value()
        # Sequence 0 is a sensor's "nothing captured yet" (ToFFrame.empty()).
        if frame.sequence == 0 or frame.sequence == current.last_sequence:
            return EventStatus.DidNothing()
        X_WS: RigidTransform = self._pose_port.Eval(context)
        t0 = time.perf_counter()
        current.map.insert_frame(frame, self._geometry, X_WS.GetAsMatrix4(),
                                 **self._insert_args)
        self._insert_seconds.append(time.perf_counter() - t0)
        state.get_mutable_abstract_state(self._state_index).set_value(
            MapState(current.map, frame.sequence))
        return EventStatus.Succeeded()

    def _calc_map(self, context: Context, output: AbstractValue) -> None:
        output.set_value(context.get_abstract_state(self._state_index).get_value().map)

    def _calc_occupied_points(self, context: Context, output: AbstractValue) -> None:
        state: MapState = context.get_abstract_state(self._state_index).get_value()
        output.set_value(state.map.occupied_centers())
