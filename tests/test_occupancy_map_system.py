"""OccupancyMapSystem alone: fixed inputs, forced and periodic updates, outputs against
`OccupancyMap.insert_frame` called directly."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.analysis import Simulator

from lrnbv_drake.core.mapping import OccupancyMap
from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry
from lrnbv_drake.systems.occupancy_map import OccupancyMapSystem

BOUNDS = ((-0.6, -0.6, -0.1), (0.6, 0.6, 0.9))
GEOMETRY = ZoneGeometry(flip_x=True)
X_WS = RigidTransform(RollPitchYaw(np.pi + 0.3, 0.2, 0.1), [0.05, -0.03, 0.62])


def make_frame(sequence: int, seed: int = 0) -> ToFFrame:
    rng = np.random.default_rng(seed)
    return ToFFrame(distance_mm=rng.integers(200, 700, size=(8, 8)),
                    status=rng.choice([5, 5, 5, 9, 255], size=(8, 8)),
                    sigma_mm=np.full((8, 8), 7), sequence=sequence)


def reference(frames: list[ToFFrame], mode: str = "ray", max_range: float | None = None
              ) -> OccupancyMap:
    m = OccupancyMap(0.01, bounds=BOUNDS)
    for f in frames:
        m.insert_frame(f, GEOMETRY, X_WS.GetAsMatrix4(), mode=mode, max_range=max_range)
    return m


def assert_same_map(a: OccupancyMap, b: OccupancyMap) -> None:
    (ia, va), (ib, vb) = a.known_cells(), b.known_cells()
    np.testing.assert_array_equal(ia, ib)
    np.testing.assert_array_equal(va, vb)


@pytest.mark.parametrize("mode", ["ray", "cone"])
def test_forced_update_inserts_each_frame_once(mode):
    dut = OccupancyMapSystem(BOUNDS, resolution=0.01, mode=mode, geometry=GEOMETRY,
                             max_range=0.8, period=None)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("X_WS").FixValue(context, X_WS)
    frame = make_frame(sequence=7)
    dut.GetInputPort("tof_frame").FixValue(context, frame)

    dut.ExecuteForcedEvents(context)
    expected = reference([frame], mode, max_range=0.8)
    points = dut.GetOutputPort("occupied_points").Eval(context)
    assert len(points) > 0
    np.testing.assert_array_equal(points, expected.occupied_centers())
    the_map = dut.GetOutputPort("map").Eval(context)
    assert the_map is dut.occupancy_map
    assert_same_map(the_map, expected)

    dut.ExecuteForcedEvents(context)  # same sequence: ignored
    assert the_map.n_scans == 1 and len(dut.insert_seconds) == 1
    assert_same_map(the_map, expected)

    again = make_frame(sequence=8)  # same readings, new capture: inserted
    dut.GetInputPort("tof_frame").FixValue(context, again)
    dut.ExecuteForcedEvents(context)
    assert the_map.n_scans == 2
    assert_same_map(the_map, reference([frame, again], mode, max_range=0.8))
    np.testing.assert_array_equal(dut.GetOutputPort("occupied_points").Eval(context),
                                  the_map.occupied_centers())


def test_periodic_update_in_simulator():
    dut = OccupancyMapSystem(BOUNDS, geometry=GEOMETRY, period=0.1)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("X_WS").FixValue(context, X_WS)
    frame = make_frame(sequence=1, seed=3)
    dut.GetInputPort("tof_frame").FixValue(context, frame)
    simulator = Simulator(dut, context)
    simulator.AdvanceTo(0.35)  # events at 0, 0.1, 0.2, 0.3; one frame
    assert dut.occupancy_map.n_scans == 1
    assert context.get_abstract_state(0).get_value().last_sequence == 1
    assert_same_map(dut.GetOutputPort("map").Eval(context), reference([frame]))

    second = make_frame(sequence=2, seed=4)
    dut.GetInputPort("tof_frame").FixValue(context, second)
    simulator.AdvanceTo(0.45)
    assert dut.occupancy_map.n_scans == 2
    np.testing.assert_array_equal(dut.GetOutputPort("occupied_points").Eval(context),
                                  reference([frame, second]).occupied_centers())


def test_state_copies_share_the_map():
    dut = OccupancyMapSystem(BOUNDS, period=None)
    context = dut.CreateDefaultContext()
    clone = context.Clone()
    assert clone.get_abstract_state(0).get_value().map is dut.occupancy_map
    assert context.get_abstract_state(0).get_value().last_sequence is None


def test_constructor_checks():
    with pytest.raises(ValueError, match="mode"):
        OccupancyMapSystem(BOUNDS, mode="beam")
    with pytest.raises(ValueError, match="period"):
        OccupancyMapSystem(BOUNDS, period=0.0)
    with pytest.raises(ValueError, match="max_range"):
        OccupancyMapSystem(BOUNDS, free_no_target=True)


def test_sequence_zero_means_no_frame_yet():
    dut = OccupancyMapSystem(bounds=((-1, -1, -1), (1, 1, 1)), period=None)
    context = dut.CreateDefaultContext()
    frame = ToFFrame(np.full((8, 8), 500), np.full((8, 8), 5), np.full((8, 8), 5), sequence=0)
    dut.GetInputPort("tof_frame").FixValue(context, frame)
    dut.GetInputPort("X_WS").FixValue(context, RigidTransform())
    dut.ExecuteForcedEvents(context)
    assert dut.occupancy_map.n_scans == 0
    assert len(dut.insert_seconds) == 0


def test_a_frame_marked_inserted_is_not_inserted_again():
    """A map filled directly (a resumed session's recorded frames), its last frame still on
    the input: only a later frame goes in."""
    dut = OccupancyMapSystem(BOUNDS, geometry=GEOMETRY, period=None)
    context = dut.CreateDefaultContext()
    recorded = [make_frame(sequence=6, seed=1), make_frame(sequence=7, seed=2)]
    for frame in recorded:
        dut.occupancy_map.insert_frame(frame, GEOMETRY, X_WS.GetAsMatrix4())
    dut.mark_inserted(context, 7)
    dut.GetInputPort("X_WS").FixValue(context, X_WS)
    dut.GetInputPort("tof_frame").FixValue(context, recorded[-1])
    dut.ExecuteForcedEvents(context)
    assert dut.occupancy_map.n_scans == 2 and dut.insert_seconds == []
    assert_same_map(dut.GetOutputPort("map").Eval(context), reference(recorded))
    after = make_frame(sequence=8, seed=3)
    dut.GetInputPort("tof_frame").FixValue(context, after)
    dut.ExecuteForcedEvents(context)
    assert dut.occupancy_map.n_scans == 3
    assert_same_map(dut.occupancy_map, reference([*recorded, after]))
    # The mark is the context's: another context of the system has not seen frame 7.
    assert dut.CreateDefaultContext().get_abstract_state(0).get_value().last_sequence is None


def test_recorded_frames_rebuild_the_map_the_updates_built():
    """A resumed session's map: the recorded (frame, pose) pairs give the map that inserting
    them one update at a time gave, in cone mode too, and the last is marked inserted."""
    frames = [make_frame(sequence=s, seed=s) for s in (3, 4, 5)]
    poses = [X_WS.GetAsMatrix4(), RigidTransform(RollPitchYaw(np.pi, 0.0, 0.4),
                                                 [0.1, 0.0, 0.55]).GetAsMatrix4()] * 2
    live = OccupancyMapSystem(BOUNDS, geometry=GEOMETRY, mode="cone", max_range=2.0,
                              period=None)
    live_context = live.CreateDefaultContext()
    for frame, X in zip(frames, poses, strict=False):
        live.GetInputPort("tof_frame").FixValue(live_context, frame)
        live.GetInputPort("X_WS").FixValue(live_context, RigidTransform(X))
        live.ExecuteForcedEvents(live_context)
    dut = OccupancyMapSystem(BOUNDS, geometry=GEOMETRY, mode="cone", max_range=2.0,
                             period=None)
    context = dut.CreateDefaultContext()
    dut.insert_recorded(context, list(zip(frames, poses, strict=False)))
    assert_same_map(dut.occupancy_map, live.occupancy_map)
    dut.GetInputPort("tof_frame").FixValue(context, frames[-1])
    dut.GetInputPort("X_WS").FixValue(context, RigidTransform(poses[2]))
    dut.ExecuteForcedEvents(context)
    assert dut.occupancy_map.n_scans == 3  # the last recorded frame is not inserted twice
