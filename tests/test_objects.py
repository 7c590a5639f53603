"""Objects (shipped meshes, loading, placing, sampling) and the cell models that hold them."""

from __future__ import annotations

import importlib.util
import math
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh
from pydrake.geometry import (
    Box,
    Cylinder,
    GeometryInstance,
    MakeRenderEngineVtk,
    Mesh,
    PerceptionProperties,
    RenderEngineVtkParams,
    RenderLabel,
    Role,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import (
    LoadModelDirectives,
    LoadModelDirectivesFromString,
    ProcessModelDirectives,
)
from pydrake.multibody.plant import MultibodyPlant

from lrnbv_drake.core.evaluation import objects
from lrnbv_drake.station.resources import MODELS_DIR, make_parser

OBJECTS_DIR = MODELS_DIR / "objects"
CELL_DIR = MODELS_DIR / "cell"
UR5E_URDF = MODELS_DIR / "ur5e" / "ur5e.urdf"
MOUNT_HEIGHT = 0.025  # tof is 25 mm out of tool0 along its z (tof_mount.sdf)


def regular_polygon_area(n: int, r: float) -> float:
    return n / 2 * r * r * math.sin(2 * math.pi / n)


def readme_table() -> dict[str, tuple[float, float, float, float]]:
    """name -> (L, W, H, volume) from models/objects/README.md."""
    rows = re.findall(
        r"^\| (\w+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| ([\d.e+-]+)",
        (OBJECTS_DIR / "README.md").read_text(),
        flags=re.MULTILINE,
    )
    return {name: tuple(float(v) for v in values) for name, *values in rows}


def lwh(mesh: trimesh.Trimesh) -> tuple[float, float, float]:
    sx, sy, sz = mesh.extents
    return max(sx, sy), min(sx, sy), sz


# --- shipped meshes -------------------------------------------------------------------------

def test_builtins_are_the_papers_four_with_shipped_meshes() -> None:
    assert objects.PAPER_OBJECTS == ("horizontal_box", "vertical_box", "gripper", "flange")
    assert set(objects.PAPER_OBJECTS) <= set(objects.BUILTIN_OBJECTS)
    for entry in objects.BUILTIN_OBJECTS.values():
        assert entry.path.is_file() and entry.description


@pytest.mark.parametrize("name", objects.PAPER_OBJECTS)
def test_mesh_matches_readme_and_is_a_closed_solid_on_its_footprint_origin(name: str) -> None:
    mesh = objects.load_object_mesh(name)
    length, width, height, volume = readme_table()[name]
    np.testing.assert_allclose(lwh(mesh), (length, width, height), atol=1e-7)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(volume, rel=1e-4)
    (x0, y0, z0), (x1, y1, _) = mesh.bounds
    np.testing.assert_allclose([x0 + x1, y0 + y1, z0], 0.0, atol=1e-9)


def test_volumes_match_hand_computation() -> None:
    # Circles are regular polygons: 48 segments for the gripper's disc; 128/64/24 for the
    # flange's outside/bore/holes, 96 for both ends of the conical hub (a frustum of similar
    # polygons: V = h/3 (A1 + A2 + sqrt(A1 A2))).
    gripper = regular_polygon_area(48, 0.025) * 0.012 + 0.085 * 0.060 * 0.088 + 2 * (
        0.018 * 0.024 * 0.050
    )
    bore = regular_polygon_area(64, 0.04125)
    plate = (regular_polygon_area(128, 0.1) - bore - 8 * regular_polygon_area(24, 0.009)) * 0.02
    a1, a2 = regular_polygon_area(96, 0.055), regular_polygon_area(96, 0.04445)
    hub = 0.03 / 3 * (a1 + a2 + math.sqrt(a1 * a2)) - bore * 0.03
    expected = {
        "horizontal_box": 0.30 * 0.20 * 0.12,
        "vertical_box": 0.12 * 0.10 * 0.25,
        "gripper": gripper,
        "flange": plate + hub,
    }
    for name, volume in expected.items():
        assert objects.load_object_mesh(name).volume == pytest.approx(volume, rel=1e-6), name


@pytest.mark.parametrize(
    ("name", "genus"), [("horizontal_box", 0), ("vertical_box", 0), ("gripper", 0), ("flange", 9)]
)
def test_genus(name: str, genus: int) -> None:
    # The flange has a bore and 8 bolt holes: a closed surface of genus 9, Euler number -16.
    assert objects.load_object_mesh(name).euler_number == 2 - 2 * genus


def section_rings(mesh: trimesh.Trimesh, z: float) -> list[shapely.Polygon]:
    """Closed loops of the mesh's horizontal cross-section at height z, as polygons."""
    segments = np.round(trimesh.intersections.mesh_plane(mesh, [0, 0, 1], [0, 0, z])[:, :, :2], 9)
    loops = shapely.get_parts(shapely.line_merge(shapely.MultiLineString(list(segments))))
    assert all(loop.is_ring for loop in loops)
    return [shapely.Polygon(loop) for loop in loops]


def test_flange_plate_has_a_bore_and_eight_bolt_holes_on_the_pitch_circle() -> None:
    flange = objects.load_object_mesh("flange")
    rings = sorted(section_rings(flange, 0.010), key=lambda p: p.area)
    assert len(rings) == 10  # outside, bore, 8 bolt holes
    holes = rings[:8]
    for hole in holes:
        c = hole.centroid
        assert math.hypot(c.x, c.y) == pytest.approx(0.080, abs=1e-6)
        assert hole.area == pytest.approx(regular_polygon_area(24, 0.009), rel=1e-6)
    assert len(section_rings(flange, 0.030)) == 2  # the hub: outside and bore


def test_drake_reads_the_shipped_objs() -> None:
    for name in objects.PAPER_OBJECTS:
        hull = Mesh(str(objects.BUILTIN_OBJECTS[name].path)).GetConvexHull()
        v = np.array([hull.vertex(i) for i in range(hull.num_vertices())])
        np.testing.assert_allclose(v.max(0) - v.min(0), objects.load_object_mesh(name).extents,
                                   atol=1e-7)


def test_generator_reproduces_the_shipped_files_byte_for_byte(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    spec = importlib.util.spec_from_file_location("generate_objects",
                                                  OBJECTS_DIR / "generate_objects.py")
    generator = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "generate_objects", generator)  # dataclasses need it
    spec.loader.exec_module(generator)
    written = generator.main(tmp_path)
    assert sorted(p.name for p in written) == sorted(f"{n}.obj" for n in objects.PAPER_OBJECTS)
    for path in written:
        assert path.read_bytes() == (OBJECTS_DIR / path.name).read_bytes(), path.name


# --- loading ---------------------------------------------------------------------------------

def test_scale_scales_about_the_origin() -> None:
    mesh = objects.load_object_mesh("horizontal_box", scale=0.5)
    np.testing.assert_allclose(mesh.extents, [0.15, 0.10, 0.06], atol=1e-9)
    assert mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj"])
def test_loads_user_mesh_files(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"part{suffix.upper()}"  # the suffix check is case-insensitive
    trimesh.creation.box(extents=[0.1, 0.2, 0.3]).export(path, file_type=suffix[1:])
    mesh = objects.load_object_mesh(str(path))
    np.testing.assert_allclose(mesh.extents, [0.1, 0.2, 0.3], atol=1e-6)
    assert mesh.volume == pytest.approx(0.006, rel=1e-5)


def test_export_obj_round_trips(tmp_path: Path) -> None:
    original = objects.load_object_mesh("gripper")
    path = objects.export_obj(original, tmp_path / "copy.obj")
    copy = objects.load_object_mesh(str(path))
    assert copy.is_watertight
    np.testing.assert_allclose(copy.vertices, original.vertices, atol=1e-8)
    np.testing.assert_array_equal(copy.faces, original.faces)


@pytest.mark.parametrize(
    ("arg", "needles"),
    [
        ("foo", ["unknown object 'foo'", "horizontal_box", "flange", ".obj, .stl or .ply"]),
        ("part.step", ["'part.step'", ".step", ".obj, .stl or .ply"]),
    ],
)
def test_bad_name_or_extension_is_named(arg: str, needles: list[str]) -> None:
    with pytest.raises(ValueError) as err:
        objects.load_object_mesh(arg)
    for needle in needles:
        assert needle in str(err.value)


def test_missing_file_is_named(tmp_path: Path) -> None:
    missing = tmp_path / "nothing.stl"
    with pytest.raises(FileNotFoundError, match=r"nothing\.stl"):
        objects.load_object_mesh(str(missing))


def test_file_without_triangles_is_named(tmp_path: Path) -> None:
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(ValueError, match=r"empty\.obj.*no triangles"):
        objects.load_object_mesh(str(empty))


@pytest.mark.parametrize("scale", [0.0, -1.0, math.nan, math.inf, "big"])
def test_bad_scale_is_named(scale: object) -> None:
    with pytest.raises(ValueError, match=r"scale for 'gripper' must be a positive") as err:
        objects.load_object_mesh("gripper", scale=scale)
    assert repr(scale) in str(err.value)


# --- placing ---------------------------------------------------------------------------------

@pytest.mark.parametrize("table_height", [0.0, 0.05])
def test_place_rests_on_the_table_at_the_footprint_centre_with_rotated_extents(
    table_height: float,
) -> None:
    box = objects.load_object_mesh("horizontal_box")
    placed = objects.place_on_table(box, objects.ObjectPlacement(0.5, -0.1, math.radians(30)),
                                    table_height)
    # Hand computation: a 0.30 x 0.20 footprint turned by 30 degrees spans
    # 0.30 cos 30 + 0.20 sin 30 = 0.359808 along x and 0.30 sin 30 + 0.20 cos 30 = 0.323205
    # along y.
    np.testing.assert_allclose(placed.mesh.extents, [0.359808, 0.323205, 0.12], atol=1e-6)
    np.testing.assert_allclose(placed.mesh.bounds[0, 2], table_height, atol=1e-12)
    np.testing.assert_allclose(placed.mesh.bounds.mean(axis=0)[:2], [0.5, -0.1], atol=1e-12)
    corners = placed.true_box_points()
    np.testing.assert_allclose(corners.mean(axis=0), [0.5, -0.1, table_height + 0.06],
                               atol=1e-12)
    # Corner 1 is corner 0 moved by the length along the turned x axis.
    np.testing.assert_allclose(corners[1] - corners[0], [0.3 * math.cos(math.radians(30)),
                                                         0.3 * math.sin(math.radians(30)), 0.0],
                               atol=1e-12)
    assert placed.true_dimensions() == pytest.approx((0.30, 0.20, 0.12))
    np.testing.assert_allclose(box.bounds, [[-0.15, -0.1, 0], [0.15, 0.1, 0.12]])  # untouched


def test_place_anchors_an_off_centre_user_mesh_and_x_wo_maps_its_file_frame() -> None:
    mesh = trimesh.creation.box(extents=[0.1, 0.3, 0.2])
    mesh.apply_translation([1.0, 2.0, 3.0])  # footprint centre (1, 2), bottom at z = 2.9
    placed = objects.place_on_table(mesh, objects.ObjectPlacement(0.4, 0.2, math.pi / 2))
    np.testing.assert_allclose(placed.mesh.bounds, [[0.25, 0.15, 0.0], [0.55, 0.25, 0.2]],
                               atol=1e-12)
    moved = mesh.vertices @ placed.X_WO[:3, :3].T + placed.X_WO[:3, 3]
    np.testing.assert_allclose(moved, placed.mesh.vertices, atol=1e-12)
    assert placed.true_dimensions() == pytest.approx((0.3, 0.1, 0.2))


# --- surface samples -------------------------------------------------------------------------

def test_samples_leave_out_the_resting_face_only() -> None:
    placed = objects.place_on_table(objects.load_object_mesh("horizontal_box"),
                                    objects.ObjectPlacement(0.5, 0.0), table_height=0.1)
    spacing = 0.01
    points = objects.sample_surface(placed.mesh, spacing, table_height=0.1)
    # Area without the 0.30 x 0.20 bottom: 0.06 top + 2 (0.036 + 0.024) sides = 0.18 m^2.
    assert len(points) == round(0.18 / spacing**2)
    assert points[:, 2].min() > 0.1 + 1e-6
    # On the surface: inside the box and on one of its faces.
    lo, hi = placed.mesh.bounds
    assert np.all((points >= lo - 1e-12) & (points <= hi + 1e-12))
    assert np.all(np.any(np.isclose(points, lo, atol=1e-12) | np.isclose(points, hi, atol=1e-12),
                         axis=1))
    on_top = np.count_nonzero(points[:, 2] > 0.22 - 1e-9)
    assert on_top == pytest.approx(0.06 / 0.18 * len(points), rel=0.15)

    with_bottom = objects.sample_surface(placed.mesh, spacing, exclude_bottom=False,
                                         table_height=0.1)
    assert len(with_bottom) == round(0.24 / spacing**2)
    assert np.count_nonzero(with_bottom[:, 2] < 0.1 + 1e-9) > 0


def test_samples_keep_the_faces_that_do_not_touch_the_table() -> None:
    # The gripper rests on its housing only: the disc and fingers face down above the table.
    gripper = objects.load_object_mesh("gripper")
    resting = objects.resting_faces(gripper)
    assert gripper.area_faces[resting].sum() == pytest.approx(0.085 * 0.088)
    points = objects.sample_surface(gripper, 0.004)
    assert points[:, 2].min() > 1e-6
    assert np.count_nonzero(points[:, 2] < 0.019) > 0  # underside of the fingers, z = 0.018


def test_samples_are_seeded() -> None:
    flange = objects.load_object_mesh("flange")
    a = objects.sample_surface(flange, 0.01, seed=3)
    np.testing.assert_array_equal(a, objects.sample_surface(flange, 0.01, seed=3))
    assert not np.array_equal(a, objects.sample_surface(flange, 0.01, seed=4))


def test_bad_spacing_is_rejected() -> None:
    with pytest.raises(ValueError, match="spacing"):
        objects.sample_surface(objects.load_object_mesh("flange"), 0.0)


# --- cell models -----------------------------------------------------------------------------

def shapes_in_body(plant: MultibodyPlant, scene_graph: SceneGraph, body_name: str,
                   role: Role, ids: bool = False) -> list[tuple[object, RigidTransform]]:
    """(shape, or its GeometryId if `ids`; pose in the body frame) of each geometry with `role`
    on a body."""
    inspector = scene_graph.model_inspector()
    frame_id = plant.GetBodyFrameIdOrThrow(plant.GetBodyByName(body_name).index())
    return [(g if ids else inspector.GetShape(g), inspector.GetPoseInFrame(g))
            for g in inspector.GetGeometries(frame_id, role)]


def parse_alone(sdf: str) -> tuple[MultibodyPlant, SceneGraph]:
    plant, scene_graph = MultibodyPlant(0.0), SceneGraph()
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    make_parser(plant).AddModels(str(CELL_DIR / sdf))
    return plant, scene_graph


def test_table_top_face_is_model_z_zero() -> None:
    plant, scene_graph = parse_alone("table.sdf")
    for role in (Role.kIllustration, Role.kProximity):
        boxes = [(s, X) for s, X in shapes_in_body(plant, scene_graph, "top", role)]
        assert len(boxes) == 5 and all(isinstance(s, Box) for s, _ in boxes)  # top, 4 legs
        assert max(X.translation()[2] + s.height() / 2 for s, X in boxes) == pytest.approx(0.0)
        top = max(boxes, key=lambda b: b[0].width() * b[0].depth())[0]
        assert (top.width(), top.depth(), top.height()) == pytest.approx((1.2, 0.8, 0.04))
        legs_bottom = min(X.translation()[2] - s.height() / 2 for s, X in boxes)
        assert legs_bottom == pytest.approx(-0.75)


def test_tof_frame_and_collision_enclosing_the_mount() -> None:
    plant, scene_graph = parse_alone("tof_mount.sdf")
    plant.Finalize()
    X_BT = plant.GetFrameByName("tof").GetFixedPoseInBodyFrame()
    np.testing.assert_allclose(X_BT.GetAsMatrix4(),
                               RigidTransform([0, 0, MOUNT_HEIGHT]).GetAsMatrix4())
    [(hull, X_BH)] = shapes_in_body(plant, scene_graph, "bracket", Role.kProximity)
    assert isinstance(hull, Cylinder)
    z_lo = X_BH.translation()[2] - hull.length() / 2
    z_hi = X_BH.translation()[2] + hull.length() / 2
    visuals = shapes_in_body(plant, scene_graph, "bracket", Role.kIllustration)
    assert len(visuals) == 3  # adapter disc, standoff, board
    for shape, X in visuals:
        if isinstance(shape, Box):
            radius, half_z = math.hypot(shape.width(), shape.depth()) / 2, shape.height() / 2
        else:
            radius, half_z = shape.radius(), shape.length() / 2
        # Every part is centred on the axis, so it is inside if its corners' radius and its
        # z-range are.
        np.testing.assert_allclose(X.translation()[:2], 0.0, atol=1e-12)
        assert radius <= hull.radius()
        assert z_lo <= X.translation()[2] - half_z and X.translation()[2] + half_z <= z_hi
    assert z_hi == pytest.approx(MOUNT_HEIGHT)  # the board's face is the sensor's face


def test_directives_name_the_cell_layout() -> None:
    directives = LoadModelDirectives(str(CELL_DIR / "cell.dmd.yaml")).directives
    models = {d.add_model.name: d.add_model.file for d in directives if d.add_model}
    assert models == {
        "table": "package://lrnbv_drake_models/cell/table.sdf",
        "ur5e": "package://lrnbv_drake_models/ur5e/ur5e.urdf",
        "tof_mount": "package://lrnbv_drake_models/cell/tof_mount.sdf",
    }
    welds = {(d.add_weld.parent, d.add_weld.child) for d in directives if d.add_weld}
    # The robot stands on the world, not on the table, so a simulated table off its height
    # (device.table_offset_mm) moves alone.
    assert welds == {("world", "table::top"), ("world", "ur5e::base_link"),
                     ("ur5e::tool0", "tof_mount::bracket")}


STUB_UR5E = """<?xml version="1.0"?>
<robot name="ur5e">
  <link name="base_link"/>
  <link name="tool0"/>
  <joint name="stub" type="fixed">
    <parent link="base_link"/><child link="tool0"/>
    <origin xyz="0.5 0.1 0.4" rpy="3.141592653589793 0 0"/>
  </joint>
</robot>
"""


def process_cell(
    text: str, extra_package: Path | None = None
) -> tuple[MultibodyPlant, SceneGraph]:
    """A finalized plant from directives `text`, with an optional extra package folder."""
    plant, scene_graph = MultibodyPlant(0.0), SceneGraph()
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    parser = make_parser(plant)
    if extra_package is not None:
        parser.package_map().AddPackageXml(str(extra_package / "package.xml"))
    ProcessModelDirectives(LoadModelDirectivesFromString(text), parser)
    plant.Finalize()
    return plant, scene_graph


def check_cell_poses(plant: MultibodyPlant) -> None:
    """The world layout of cell.dmd.yaml, for any arm configuration."""
    context = plant.CreateDefaultContext()

    def pose(frame: str, model: str) -> RigidTransform:
        instance = plant.GetModelInstanceByName(model)
        return plant.GetFrameByName(frame, instance).CalcPoseInWorld(context)

    np.testing.assert_allclose(pose("base_link", "ur5e").GetAsMatrix4(), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(pose("top", "table").translation(), [0.3, 0.0, 0.0], atol=1e-12)
    X_WT = pose("tool0", "ur5e") @ RigidTransform([0, 0, MOUNT_HEIGHT])
    np.testing.assert_allclose(pose("tof", "tof_mount").GetAsMatrix4(), X_WT.GetAsMatrix4(),
                               atol=1e-12)


def test_cell_directives_with_a_stub_arm(tmp_path: Path) -> None:
    # Checks the table, mount and welds whether or not the real URDF is there yet.
    (tmp_path / "package.xml").write_text(
        '<?xml version="1.0"?><package format="2"><name>stub_ur5e</name></package>')
    (tmp_path / "ur5e.urdf").write_text(STUB_UR5E)
    text = (CELL_DIR / "cell.dmd.yaml").read_text().replace(
        "package://lrnbv_drake_models/ur5e/ur5e.urdf", "package://stub_ur5e/ur5e.urdf")
    plant, _ = process_cell(text, tmp_path)
    check_cell_poses(plant)
    # Hand-worked: tool0 at (0.5, 0.1, 0.4) pointing down, so tof is 25 mm lower.
    tof = plant.GetFrameByName("tof").CalcPoseInWorld(plant.CreateDefaultContext())
    np.testing.assert_allclose(tof.translation(), [0.5, 0.1, 0.4 - MOUNT_HEIGHT], atol=1e-12)


@pytest.mark.skipif(not UR5E_URDF.is_file(), reason="models/ur5e/ur5e.urdf is not written yet")
def test_cell_directives_parse_with_the_ur5e() -> None:
    plant, scene_graph = process_cell((CELL_DIR / "cell.dmd.yaml").read_text())
    assert plant.num_positions() == 6
    check_cell_poses(plant)
    # The mount touches the wrist's flange: that pair must be filtered (welded together), while
    # the mount against the table must not be.
    inspector = scene_graph.model_inspector()
    [mount] = [g for g, _ in shapes_in_body(plant, scene_graph, "bracket", Role.kProximity,
                                             ids=True)]
    wrist = [g for g, _ in shapes_in_body(plant, scene_graph, "wrist_3_link", Role.kProximity,
                                          ids=True)]
    table = [g for g, _ in shapes_in_body(plant, scene_graph, "top", Role.kProximity, ids=True)]
    assert wrist and all(inspector.CollisionFiltered(mount, g) for g in wrist)
    assert not any(inspector.CollisionFiltered(mount, g) for g in table)


def test_drake_renderer_accepts_exported_objs(tmp_path: Path) -> None:
    # RenderEngineVtk loads the mesh when a perception geometry is registered (no drawing, so
    # no display needed) and refuses an OBJ without normals.
    scene_graph = SceneGraph()
    scene_graph.AddRenderer("vtk", MakeRenderEngineVtk(RenderEngineVtkParams()))
    source = scene_graph.RegisterSource("test")
    stl = tmp_path / "part.stl"
    trimesh.creation.box(extents=[0.1, 0.2, 0.3]).export(stl)
    exported = objects.export_obj(objects.load_object_mesh(str(stl)), tmp_path / "part.obj")
    for path in [exported, *(objects.BUILTIN_OBJECTS[n].path for n in objects.PAPER_OBJECTS)]:
        instance = GeometryInstance(RigidTransform(), Mesh(str(path)), path.name)
        properties = PerceptionProperties()
        properties.AddProperty("label", "id", RenderLabel(1))
        instance.set_perception_properties(properties)
        scene_graph.RegisterAnchoredGeometry(source, instance)


def test_models_never_need_the_network(monkeypatch):
    # With networking off, the whole cell still loads: nothing refers to a remote package.
    monkeypatch.setenv("DRAKE_ALLOW_NETWORK", "none")
    for path in MODELS_DIR.rglob("*"):
        if path.suffix in (".urdf", ".sdf", ".yaml", ".xml"):
            assert "package://drake" not in path.read_text(), path
    plant = MultibodyPlant(0.0)
    parser = make_parser(plant)
    assert not parser.package_map().Contains("drake_models")
    ProcessModelDirectives(LoadModelDirectives(str(CELL_DIR / "cell.dmd.yaml")), plant, parser)
    plant.Finalize()
    assert plant.num_positions() == 6
    assert os.environ["DRAKE_ALLOW_NETWORK"] == "none"
