"""The generated family of objects and the held-out shapes (core/evaluation/object_family.py)
and a user's awkward meshes: sharp, thin and open ones run an episode, a flat one is refused
naming the file."""

import argparse
import math

import numpy as np
import pytest
import shapely
import trimesh

from lrnbv_drake.cli.benchmark import add_benchmark_command, config_from_args
from lrnbv_drake.cli.main import main
from lrnbv_drake.core.evaluation import object_family, objects
from lrnbv_drake.experiments.campaign.plan import FAMILY_PLACEMENT, resolve_objects
from lrnbv_drake.station.scenario import ExtractionConfig

#: The classes the family must hold (issue: boxes to blobs; then the first held-out set's
#: tapering solids and prism, and the second's bowl, vase, spool and dome).
CLASSES = {"box", "cylinder", "sphere", "bottle", "carton", "mug", "plate", "bracket", "ring",
           "two parts", "blob", "taper", "prism", "bowl", "vase", "spool", "dome",
           "bag", "pear"}


def test_the_family_holds_thirty_shapes_of_every_class_from_3_to_35_cm():
    kinds = [shape.kind for shape in object_family.FAMILY.values()]
    assert len(kinds) >= 30 and set(kinds) == CLASSES
    sizes = [max(objects.load_object_mesh(name).extents) for name in object_family.FAMILY]
    assert 0.025 <= min(sizes) <= 0.035 and 0.30 <= max(sizes) <= 0.35


@pytest.mark.parametrize("name", [*object_family.FAMILY, *object_family.HELD_OUT])
def test_each_shape_is_a_closed_solid_resting_on_its_canonical_box(name):
    mesh = objects.load_object_mesh(name)
    assert mesh.is_watertight and mesh.volume > 0
    (x0, y0, z0), (x1, y1, _) = mesh.bounds
    assert z0 == pytest.approx(0.0, abs=1e-9)
    assert (x0 + x1, y0 + y1) == pytest.approx((0.0, 0.0), abs=1e-9)
    # Its axis-aligned box is its minimum-area box, the longer side along x: the truth a
    # packing engineer would measure.
    hull = shapely.MultiPoint(mesh.vertices[:, :2]).convex_hull
    assert shapely.minimum_rotated_rectangle(hull).area == pytest.approx(
        (x1 - x0) * (y1 - y0), rel=1e-6)
    assert x1 - x0 >= y1 - y0 - 1e-9
    # Taller than the table band, or a campaign refuses it (the map takes it for the table).
    assert mesh.extents[2] > ExtractionConfig().table_tolerance


def test_a_shape_is_the_same_every_time_it_is_built():
    shape = object_family.FAMILY["blob"]
    first, second = (object_family.canonical(shape.build(np.random.default_rng(shape.seed)))
                     for _ in range(2))
    np.testing.assert_array_equal(first.vertices, second.vertices)
    np.testing.assert_array_equal(first.vertices, objects.load_object_mesh("blob").vertices)


def test_the_campaign_takes_the_family_by_name_and_places_it_over_the_table():
    assert [o.label for o in resolve_objects("family")] == list(object_family.FAMILY)
    rng = np.random.default_rng(0)
    x, y, yaw = FAMILY_PLACEMENT.sample(rng)
    assert 0.42 <= x <= 0.58 and -0.12 <= y <= 0.12 and -180 <= yaw <= 180


#: A solid's volume over its bounding box's, worked out by hand: a cone on a regular 48-gon,
#: a third of its base's area 24 r^2 sin(pi / 24) over its minimum-area box's, the square
#: across its flats (2 r cos(pi / 48))^2 (pi / 12 on a circle); a pyramid 1 / 3, a wedge and
#: a triangular prism 1 / 2, a regular hexagonal prism (3 sqrt(3) / 2 r^2) / (2 r sqrt(3) r)
#: = 3 / 4, a box 1.
BOX_SHARE = {"cone": 2 * math.sin(math.pi / 24) / math.cos(math.pi / 48) ** 2,
             "pyramid": 1 / 3, "wedge": 1 / 2, "hex_prism": 3 / 4, "box_tiny": 1.0,
             "prism_lying": 1 / 2}


@pytest.mark.parametrize("name", list(BOX_SHARE))
def test_a_polyhedral_shape_fills_the_share_of_its_box_its_solid_does(name):
    mesh = objects.load_object_mesh(name)
    assert mesh.volume / np.prod(mesh.extents) == pytest.approx(BOX_SHARE[name], rel=1e-6)


def test_a_dome_is_half_an_ellipsoid_and_a_torus_fills_its_box_as_a_torus_does():
    """Half an ellipsoid fills pi / 6 of its box, within an icosphere's facets' 1 %; a torus
    of radii R and r, 2 pi^2 R r^2 of (2 (R + r))^2 2 r, its section a 16-gon of
    (16 / 2 pi) sin(2 pi / 16) of its circle's area (its 48-gon's path within 0.1 %)."""
    dome = objects.load_object_mesh("dome")
    assert dome.volume / np.prod(dome.extents) == pytest.approx(math.pi / 6, rel=0.01)
    torus = objects.load_object_mesh("torus")
    r = torus.extents[2] / 2
    big = torus.extents[0] / 2 - r
    share = math.pi ** 2 * big * r / (4 * (big + r) ** 2) * 8 / math.pi * math.sin(math.pi / 8)
    assert torus.volume / np.prod(torus.extents) == pytest.approx(share, rel=1e-3)


def test_a_cone_lying_rests_on_a_line_from_its_rim_to_its_apex():
    """Tilted by its half angle atan(r / h), the cone touches the table at its apex and one
    rim point, a slant L = sqrt(r^2 + h^2) apart, and its rim's top stands 2 r cos(atan(r /
    h)) = 2 r h / L high: r and h from those two, its volume is a third of its 48-gon base's
    area 24 r^2 sin(pi / 24) times h."""
    mesh = objects.load_object_mesh("cone_lying")
    low = mesh.vertices[mesh.vertices[:, 2] < 1e-9]
    assert len(low) == 2
    slant, height = np.linalg.norm(low[0] - low[1]), mesh.extents[2]
    # r h = height slant / 2 and r^2 + h^2 = slant^2: (h - r)^2 = slant^2 - height slant.
    h_plus_r = math.sqrt(slant ** 2 + height * slant)
    h_minus_r = math.sqrt(slant ** 2 - height * slant)
    r, h = (h_plus_r - h_minus_r) / 2, (h_plus_r + h_minus_r) / 2
    assert 0.03 <= r <= 0.045 and 0.15 <= h <= 0.22
    assert mesh.volume == pytest.approx(24 * r ** 2 * math.sin(math.pi / 24) * h / 3, rel=1e-6)


def test_a_shoe_box_lid_overhangs_its_body_by_3_to_6_mm_a_side():
    mesh = objects.load_object_mesh("lidded_box")
    z = mesh.vertices[:, 2]
    body = np.ptp(mesh.vertices[z < 1e-9, :2], axis=0)
    over = (mesh.extents[:2] - body) / 2
    assert over[1] == pytest.approx(over[0], abs=1e-6) and 0.003 <= over[0] <= 0.006


def test_a_six_pack_is_two_rows_of_three_cans():
    """Cans of radius r at 1.96 r centre to centre (48-gons, a vertex on each axis): 2 r +
    2 x 1.96 r = 5.92 r long and 3.96 r wide."""
    mesh = objects.load_object_mesh("six_pack")
    r = mesh.extents[1] / 3.96
    assert 0.031 <= r <= 0.034 and mesh.extents[0] == pytest.approx(5.92 * r, rel=1e-6)


def test_a_star_has_the_area_of_its_ten_triangles():
    """A five-pointed star of tips at R and notches at r from its centre: ten triangles of
    area R r sin(pi / 5) / 2, times its thickness."""
    mesh = objects.load_object_mesh("star_prism")
    top = mesh.vertices[np.isclose(mesh.vertices[:, 2], mesh.extents[2])]
    radii = np.linalg.norm(top[:, :2] - top[:, :2].mean(axis=0), axis=1)
    assert len(top) == 10
    area = 5 * radii.max() * radii.min() * math.sin(math.pi / 5)
    assert mesh.volume == pytest.approx(area * mesh.extents[2], rel=1e-6)


def test_a_pipe_is_open_along_its_axis_and_its_wall_is_3_to_5_mm():
    mesh = objects.load_object_mesh("pipe_lying")
    radius = mesh.extents[2] / 2
    along = mesh.ray.intersects_any([[-1.0, 0.0, radius]], [[1.0, 0.0, 0.0]])
    hits, _, _ = mesh.ray.intersects_location([[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]])
    z = np.sort(hits[:, 2])[::-1]
    assert not along[0] and len(z) == 4
    assert z[0] == pytest.approx(2 * radius) and 0.003 <= z[0] - z[1] <= 0.005


def test_a_gear_has_16_to_24_teeth_round_a_bore():
    mesh = objects.load_object_mesh("gear")
    top = mesh.vertices[np.isclose(mesh.vertices[:, 2], mesh.extents[2])]
    radii = np.linalg.norm(top[:, :2] - mesh.centroid[:2], axis=1)
    tips = np.isclose(radii, radii.max(), atol=1e-6).sum()
    assert tips % 2 == 0 and 16 <= tips // 2 <= 24
    assert not mesh.ray.intersects_any([[*mesh.centroid[:2], 1.0]], [[0.0, 0.0, -1.0]])[0]


def test_a_stepped_box_carries_a_smaller_box_off_its_centre():
    mesh = objects.load_object_mesh("stepped_box")
    z = mesh.vertices[:, 2]
    upper = mesh.vertices[np.isclose(z, mesh.extents[2]), :2]
    lower = mesh.vertices[z < 1e-9, :2]
    assert np.all(upper.min(axis=0) >= lower.min(axis=0) - 1e-9)
    assert np.all(upper.max(axis=0) <= lower.max(axis=0) + 1e-9)
    assert np.linalg.norm(upper.mean(axis=0) - lower.mean(axis=0)) > 0.005


def test_the_bucket_widens_from_its_base_to_its_top():
    mesh = objects.load_object_mesh("bucket")
    z = mesh.vertices[:, 2]
    base, top = (np.ptp(mesh.vertices[np.isclose(z, level), 0])
                 for level in (0.0, mesh.extents[2]))
    assert 0.65 <= base / top <= 0.8 and top == pytest.approx(mesh.extents[0])


def test_the_held_out_shapes_are_no_family_member_and_are_placed_as_the_family(tmp_path):
    assert not set(object_family.HELD_OUT) & set(object_family.FAMILY)
    # A shape that joined the family from a held-out set is the shape it was measured as.
    seeds = [shape.seed for shape in (*object_family.FAMILY.values(),
                                      *object_family.HELD_OUT.values())]
    assert len(set(seeds)) == len(seeds) and object_family.FAMILY["cone"].seed == 2000
    assert object_family.FAMILY["bowl"].seed == 3000
    assert object_family.FAMILY["pouch"].seed == 4000
    assert min((shape.seed for shape in object_family.HELD_OUT.values()),
               default=object_family.HELD_OUT_SEEDS) == object_family.HELD_OUT_SEEDS == 5000
    assert [o.label for o in resolve_objects("held_out")] == list(object_family.HELD_OUT)
    parser = argparse.ArgumentParser(prog="lrnbv")
    add_benchmark_command(parser.add_subparsers(dest="command", required=True))
    for spec, placement in (("held_out", FAMILY_PLACEMENT), ("paper", None)):
        config = config_from_args(parser.parse_args(
            ["benchmark", "--objects", spec, "--out", str(tmp_path / spec)]))
        assert config.placement == placement


def _fin(path):
    """A knife-thin fin, 0.8 mm thick: its edges are sharper than Drake's mesh distance
    queries accept."""
    mesh = trimesh.creation.box(extents=(0.2, 0.0008, 0.08))
    mesh.apply_translation((0, 0, 0.04))
    mesh.export(path)


def _open_box(path):
    """A box without its top face: not watertight."""
    box = trimesh.creation.box(extents=(0.15, 0.1, 0.08))
    box.apply_translation((0, 0, 0.04))
    trimesh.Trimesh(box.vertices, box.faces[box.face_normals[:, 2] < 0.5]).export(path)


@pytest.mark.parametrize("make", [None, _fin, _open_box], ids=["gable_carton", "fin", "open"])
def test_sharp_thin_and_open_meshes_run_an_episode_to_a_report(tmp_path, make):
    """The gable-top carton's ridge and a fin's edges crashed Drake's distance queries on the
    object's mesh before the first pose; its proximity geometry is now its convex hull."""
    name = "gable_carton"
    if make is not None:
        name = str(tmp_path / "object.stl")
        make(name)
    out = tmp_path / "out"
    assert main(["run", "--planner", "heu", "--object", name, "--out", str(out),
                 "--scenario-text", "{heu: {n_poses: 3}, max_poses: 3}"]) == 0
    assert (out / "report.json").is_file()


def test_a_flat_mesh_is_refused_naming_the_file_before_anything_runs(tmp_path, capsys):
    path = tmp_path / "sheet.obj"
    trimesh.Trimesh([[0, 0, 0.05], [0.1, 0, 0.05], [0, 0.1, 0.05]], [[0, 1, 2]]).export(path)
    out = tmp_path / "out"
    assert main(["run", "--object", str(path), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert str(path) in error and "flat" in error
    assert not out.exists()
