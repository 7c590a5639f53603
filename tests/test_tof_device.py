"""The datasheet device (`core/sensing/tof_device.py`): each knob alone on a hand-built zone, the
datasheet's noise and detection limit worked by hand, ST's zone table, and a frame that
integrates a moving sensor. The ideal profile is `zone_readings` itself (and the closed loop's
frames are unchanged: tests/test_tof_sensor_system.py, tests/test_scenario.py)."""

from __future__ import annotations

import dataclasses as dc

import numpy as np
import pytest
from pydrake.geometry import Box
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.multibody.tree import PrismaticJoint, SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lrnbv_drake.core.sensing.sensor import (
    STATUS_NO_TARGET,
    STATUS_VALID,
    NoiseModel,
    SensorModelParams,
    ZoneGeometry,
    frame_rng,
    zone_readings,
)
from lrnbv_drake.core.sensing.tof_device import (
    PROFILES,
    SIGNAL_LIMIT_DARK,
    STATUS_BLURRED,
    STATUS_MERGED,
    STATUS_NEW_TARGET,
    STATUS_NO_WRAP_CHECK,
    DeviceBehaviour,
    datasheet_sigma_mm,
    device_readings,
    st_zone_centres_deg,
    zone_offsets_mm,
)
from lrnbv_drake.systems.tof_sensor import (
    ToFSensor,
    add_tof_renderer,
    render_zone_depths,
    sample_zone_depths,
    tof_depth_camera,
)

NOISELESS = SensorModelParams(noise=NoiseModel(sigma0_mm=0.0, k=0.0))
ZONE = (3, 4)  # the zone the hand-built scenes put two surfaces in
K2 = NOISELESS.subsamples**2


def _scene(near_m, near_rho, far_m, far_rho, near_share=0.5):
    """(depth, reflectance), (8, 8, 64): a wall at `far_m` everywhere; in ZONE, the first
    `near_share` of the samples see a surface at `near_m` instead."""
    depth = np.full((8, 8, K2), far_m)
    rho = np.full((8, 8, K2), far_rho)
    n = round(near_share * K2)
    depth[ZONE][:n], rho[ZONE][:n] = near_m, near_rho
    return depth, rho


def _read(behaviour, depth, rho, previous=None, params=NOISELESS, seed=0):
    return device_readings(depth, params, behaviour, frame_rng(seed, 1), reflectance=rho,
                           previous=previous, sequence=1)


def _zone(frame):
    return int(frame.distance_mm[ZONE]), int(frame.status[ZONE])


def test_strongest_order_reports_the_bright_far_surface_closest_the_dim_near_one():
    # Dim 5 % plane at 0.3 m and bright 90 % at 1.0 m, half the zone each, 700 mm apart:
    # signals 0.5 * 0.05 / 0.09 = 0.28 and 0.5 * 0.9 / 1.0 = 0.45.
    depth, rho = _scene(0.3, 0.05, 1.0, 0.9)
    strongest = DeviceBehaviour(target_order="strongest", merge_mm=600.0)
    assert _zone(_read(strongest, depth, rho)) == (1000, STATUS_VALID)
    closest = dc.replace(strongest, target_order="closest")
    assert _zone(_read(closest, depth, rho)) == (300, STATUS_VALID)
    # Bright near, dim far: both orders agree on the near one.
    depth, rho = _scene(0.3, 0.9, 1.0, 0.05)
    assert _zone(_read(strongest, depth, rho)) == (300, STATUS_VALID)


@pytest.mark.parametrize(("merged_depth", "expected_mm"), [
    # signal-weighted: (0.5/0.16 * 400 + 0.5/0.25 * 500) / (0.5/0.16 + 0.5/0.25) = 439.0
    ("signal", 439), ("nearest", 400), ("farthest", 500)])
def test_surfaces_100_mm_apart_merge_into_one_status_9_return(merged_depth, expected_mm):
    depth, rho = _scene(0.4, 0.5, 0.5, 0.5)
    behaviour = DeviceBehaviour(merge_mm=600.0, merged_depth=merged_depth)
    assert _zone(_read(behaviour, depth, rho)) == (expected_mm, STATUS_MERGED)
    # Zones that see the wall alone stay status 5 at its depth.
    frame = _read(behaviour, depth, rho)
    assert (int(frame.distance_mm[0, 0]), int(frame.status[0, 0])) == (500, STATUS_VALID)


def test_without_merging_the_ideal_rule_would_report_the_near_surface():
    depth, _ = _scene(0.4, 0.5, 0.5, 0.5)
    ideal = zone_readings(depth.reshape(8, 8, 8, 8), NOISELESS, frame_rng(0, 1))
    assert _zone(ideal) == (400, STATUS_VALID)


@pytest.mark.parametrize("knob", [{"illumination": True}, {"startup_statuses": True},
                                  {"reported_sigma_spread": 0.2}])
def test_one_knob_on_the_ideal_device_keeps_its_share_rule(knob):
    """Closest order without merging keeps the ideal rule, as `DeviceBehaviour` documents: a
    sliver under `min_share` (9 % against 25 %) is not the zone's target, one over it is. A
    single knob used to send the zone to signal detection, which reported the sliver."""
    behaviour = DeviceBehaviour(**knob)
    assert not behaviour.ideal and behaviour.merge_mm == 0
    previous = _read(behaviour, *_scene(0.5, 0.5, 1.0, 0.5))  # past the start-up statuses
    for share, expected_mm in ((6 / 64, 1000), (20 / 64, 500)):
        depth, rho = _scene(0.5, 0.5, 1.0, 0.5, near_share=share)
        ideal = zone_readings(depth.reshape(8, 8, 8, 8), NOISELESS, frame_rng(0, 1))
        assert _zone(ideal)[0] == expected_mm
        assert int(_read(behaviour, depth, rho, previous=previous).distance_mm[ZONE]) \
            == expected_mm


def test_a_unit_s_zone_offsets_are_the_same_in_every_frame_with_their_rms():
    """Each zone reads a wall at 500 mm off by its own offset, the same in two frames of
    different noise draws (a noiseless model here: the offset is all that moves it); over
    the 64 zones the offsets' rms is the 3 mm asked, within the spread 64 draws allow
    (their rms' relative standard error is 1 / sqrt(128), 9 %), and another seed is
    another unit."""
    depth, rho = _scene(0.5, 0.5, 0.5, 0.5)
    unit = DeviceBehaviour(zone_offset_mm=3.0, zone_offset_seed=7)
    frames = [NOISELESS.geometry.to_row_major(_read(unit, depth, rho, seed=seed).distance_mm)
              for seed in (1, 2)]
    offsets = frames[0].astype(float) - 500.0
    assert np.array_equal(frames[0], frames[1])
    assert np.sqrt(np.mean(offsets ** 2)) == pytest.approx(3.0, rel=0.3)
    assert np.array_equal(offsets, np.rint(500.0 + zone_offsets_mm(unit, 8)) - 500.0)
    other = NOISELESS.geometry.to_row_major(
        _read(dc.replace(unit, zone_offset_seed=8), depth, rho).distance_mm)
    assert np.mean(other != frames[0]) > 0.5


def test_the_sharpener_bleeds_a_near_target_into_its_neighbours():
    # A whole zone at 0.1 m over a wall at 0.5 m (UM3109 4.8's example). A 4-neighbour sees
    # the wall (its own samples and 2 % of its three other neighbours') and 2 % of the near
    # zone's samples at 25 times the signal each: 400 mm apart, they merge, pulled towards
    # 100 mm by the signal weights.
    depth, rho = _scene(0.1, 0.5, 0.5, 0.5, near_share=1.0)
    behaviour = DeviceBehaviour(merge_mm=600.0, sharpener_bleed=0.02)
    frame = _read(behaviour, depth, rho)
    s_near, s_wall = 0.02 * 0.5 / 0.1**2, (1 + 3 * 0.02) * 0.5 / 0.5**2  # per sample
    expected = (s_near * 100 + s_wall * 500) / (s_near + s_wall)  # 371.8 mm
    r, c = ZONE
    for neighbour in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
        assert int(frame.distance_mm[neighbour]) == round(expected)
        assert int(frame.status[neighbour]) == STATUS_MERGED
    assert int(frame.distance_mm[r - 1, c - 1]) == 500  # diagonal: no bleed
    # The near zone itself merges 4 x 2 % of the wall: (50 * 100 + 0.16 * 500) / 50.16.
    assert _zone(frame) == (round((50 * 100 + 0.16 * 500) / 50.16), STATUS_MERGED)
    # Seen alone, the bled target is reported with status 12: a neighbour of a bright near
    # zone that looks at nothing within range.
    depth[np.isclose(depth, 0.5)] = np.inf
    frame = _read(behaviour, depth, rho)
    assert (int(frame.distance_mm[r - 1, c]), int(frame.status[r - 1, c])) == (
        100, STATUS_BLURRED)


def test_a_17_percent_wall_is_detected_below_and_lost_beyond_the_dark_range_limit():
    behaviour = DeviceBehaviour(merge_mm=600.0)
    params = dc.replace(NOISELESS, max_range_mm=4000)
    assert SIGNAL_LIMIT_DARK == pytest.approx(0.17 / 2.45**2)
    for d, seen in ((2.3, True), (2.6, False)):
        frame = _read(behaviour, np.full((8, 8, K2), d), np.full((8, 8, K2), 0.17),
                      params=params)
        assert np.all(frame.status == (STATUS_VALID if seen else STATUS_NO_TARGET))
    # 5 klux: the limit drops to 1.15 m.
    bright = dc.replace(behaviour, ambient_klux=5.0)
    frame = _read(bright, np.full((8, 8, K2), 1.3), np.full((8, 8, K2), 0.17), params=params)
    assert np.all(frame.status == STATUS_NO_TARGET)


def test_datasheet_sigma_worked_by_hand():
    # 54 %, dark, centre zone, 1 m: +-5 % of 1000 mm at 2.7 sigma -> 18.52 mm.
    assert datasheet_sigma_mm(1000.0, 0.54, 0.0, 0.0) == pytest.approx(50 / 2.7)
    # 17 %, 5 klux, corner: 8 + 4 = 12 % of 1000 mm -> 44.4 mm.
    assert datasheet_sigma_mm(1000.0, 0.17, 5.0, 1.0) == pytest.approx(120 / 2.7)
    # Below 200 mm the +-12 mm floor (54 %, dark) wins: 4.44 mm at 100 mm.
    assert datasheet_sigma_mm(100.0, 0.54, 0.0, 0.0) == pytest.approx(12 / 2.7)


def test_the_datasheet_noise_has_the_datasheet_spread():
    behaviour = DeviceBehaviour(merge_mm=600.0, accuracy="datasheet")
    depth, rho = np.full((8, 8, K2), 1.0), np.full((8, 8, K2), 0.54)
    readings = np.array([_read(behaviour, depth, rho, seed=s).distance_mm[3:5, 3:5]
                         for s in range(400)], float)
    assert np.std(readings) == pytest.approx(50 / 2.7, rel=0.1)


def test_first_frame_is_status_6_and_a_newly_acquired_zone_status_10():
    behaviour = DeviceBehaviour(startup_statuses=True)
    depth, rho = _scene(0.4, 0.5, 0.5, 0.5)
    first = _read(behaviour, depth, rho)
    assert np.all(first.status == STATUS_NO_WRAP_CHECK)
    second = _read(behaviour, depth, rho, previous=first)
    assert np.all(second.status == STATUS_VALID)
    depth[0, 0] = np.inf  # zone (0, 0) loses its target, then gets it back
    third = _read(behaviour, depth, rho, previous=second)
    assert third.status[0, 0] == STATUS_NO_TARGET
    depth[0, 0] = 0.5
    fourth = _read(behaviour, depth, rho, previous=third)
    assert fourth.status[0, 0] == STATUS_NEW_TARGET
    assert np.all(np.delete(fourth.status.ravel(), 0) == STATUS_VALID)


def test_st_zone_table_shape():
    table = st_zone_centres_deg(8).reshape(8, 8, 2)
    assert table[0, 0, 0] == pytest.approx(-23.0) and table[7, 7, 1] == pytest.approx(23.0)
    np.testing.assert_allclose(table[3, 4:, 0], [3.0, 9.0, 14.8, 19.8], atol=0.1)
    np.testing.assert_allclose(table[..., 0], -table[:, ::-1, 0])  # symmetric
    np.testing.assert_allclose(table[..., 1], table[..., 0].T)  # same in y as in x


def test_a_corner_zone_samples_the_scene_around_its_table_direction():
    """The renderer's pixels that a zone samples lie within its footprint around the table's
    direction, not the uniform grid's: an image holding each pixel's own tan x and tan y."""
    geometry = ZoneGeometry(centres_deg=st_zone_centres_deg(8))
    params = dc.replace(NOISELESS, geometry=geometry)
    camera = tof_depth_camera(params)
    info = camera.core().intrinsics()
    u = (np.arange(info.width()) + 0.5 - info.center_x()) / info.focal_x()
    v = (np.arange(info.height()) + 0.5 - info.center_y()) / info.focal_y()
    tan_x = sample_zone_depths(np.broadcast_to(u[None, :], (v.size, u.size)), camera, params)
    tan_y = sample_zone_depths(np.broadcast_to(v[:, None], (v.size, u.size)), camera, params)
    half = np.deg2rad(geometry.zone_deg) / 2
    centres = np.deg2rad(np.reshape(geometry.centres_deg, (8, 8, 2)))
    for axis, tan in ((0, tan_x), (1, tan_y)):
        offset = np.arctan(tan) - centres[:, :, None, None, axis]
        assert np.all(np.abs(offset) < half)
    assert np.rad2deg(np.arctan(tan_x[0, 0]).mean()) == pytest.approx(-23.0, abs=0.1)


def test_a_frame_integrated_while_moving_mixes_the_poses_it_passed():
    """The sensor slides sideways at 0.6 m/s in front of a box edge; a frame of three renders
    differs from a frame at rest at its end pose, and equals the model's reduction of the
    three renders pooled."""
    period, steps, speed = 1 / 15, 3, 0.6
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    plant.mutable_gravity_field().set_gravity_vector([0, 0, 0])
    slider = plant.AddRigidBody("slider", SpatialInertia.SolidBoxWithMass(1, 0.1, 0.1, 0.1))
    joint = plant.AddJoint(PrismaticJoint("x", plant.world_frame(), slider.body_frame(),
                                          [1, 0, 0]))
    # Sensor looks along world z; the wall at 0.5 m, a box face at 0.3 m for x >= 0.02.
    plant.RegisterVisualGeometry(plant.world_body(), RigidTransform([0, 0, 0.55]),
                                 Box(4, 4, 0.1), "wall", [1, 1, 1, 1])
    plant.RegisterVisualGeometry(plant.world_body(), RigidTransform([1.02, 0, 0.35]),
                                 Box(2, 2, 0.1), "box", [1, 1, 1, 1])
    plant.Finalize()
    add_tof_renderer(scene_graph)
    frame_id = plant.GetBodyFrameIdOrThrow(slider.index())
    dut = builder.AddSystem(ToFSensor(frame_id, RigidTransform(), NOISELESS, period=period,
                                      integration_steps=steps))
    builder.Connect(scene_graph.get_query_output_port(), dut.get_geometry_query_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    root = simulator.get_mutable_context()
    plant_context = plant.GetMyMutableContextFromRoot(root)
    joint.set_translation_rate(plant_context, speed)
    simulator.AdvanceTo((steps - 1) * period / steps + 1e-9)
    moving = dut.get_tof_frame_output_port().Eval(dut.GetMyContextFromRoot(root))
    assert moving.sequence == 1
    assert moving.timestamp_us == round((steps - 1) * period / steps * 1e6)

    context = diagram.CreateDefaultContext()
    renders = []
    for j in range(steps):
        joint.set_translation(plant.GetMyMutableContextFromRoot(context),
                              speed * j * period / steps)
        renders.append(render_zone_depths(scene_graph.get_query_output_port().Eval(
            scene_graph.GetMyContextFromRoot(context)), dut.camera, frame_id,
            RigidTransform(), NOISELESS).reshape(8, 8, -1))
    pooled = zone_readings(np.concatenate(renders, axis=-1), NOISELESS, frame_rng(0, 1))
    at_rest = zone_readings(renders[-1].reshape(8, 8, 8, 8), NOISELESS, frame_rng(0, 1))
    np.testing.assert_array_equal(moving.distance_mm, pooled.distance_mm)
    assert np.any(moving.distance_mm != at_rest.distance_mm)


def test_profiles_are_the_documented_sets_of_knobs():
    ideal = PROFILES["ideal"]  # the sensor model itself
    assert (ideal.behaviour, ideal.zone_directions, ideal.integration_steps) == (None, None, 1)
    ds = PROFILES["datasheet"]
    assert (ds.behaviour.target_order, ds.behaviour.merge_mm, ds.zone_directions) == (
        "strongest", 600.0, "st")
    with pytest.raises(ValueError, match="target_order"):
        DeviceBehaviour(target_order="nearest")
