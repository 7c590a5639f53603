"""The objects to reconstruct: the paper's four built-in meshes or a user's mesh file, placed on
the table, with the ground truth the metrics compare against.

No Drake here: the simulator adds the OBJ that `export_obj` writes (Drake parses only OBJ among
OBJ/STL/PLY) at `PlacedObject.X_WO`, and the metrics read `PlacedObject` and `sample_surface`.

Conventions:
- World z is up and the table top is the plane z = `table_height` (0 in the shipped cell).
- A built-in mesh is in metres with its origin at the centre of its footprint (the centre of its
  x-y bounding box) and z = 0 on its resting face, so placing it at z = 0 rests it on the table.
- The *true box* of an object is its own axis-aligned bounding box carried into the world by
  `X_WO`: for the built-in objects it is their canonical L x W x H box.
"""

from __future__ import annotations

import dataclasses as dc
import math
import os
from pathlib import Path

import numpy as np
import trimesh

from lrnbv_drake.core.evaluation import object_family

OBJECTS_DIR = Path(__file__).resolve().parents[3] / "models" / "objects"
MESH_SUFFIXES: tuple[str, ...] = (".obj", ".stl", ".ply")
#: Most surface samples `sample_surface` draws: 50 m^2 at the coverage metric's 5 mm spacing,
#: over six times the surface of the largest box the cell maps. A mesh read in the wrong units
#: (150 m for a 150 mm part) would otherwise ask for billions of points, tens of GiB.
MAX_SURFACE_SAMPLES = 2_000_000


@dc.dataclass(frozen=True)
class BuiltinObject:
    """A shipped object mesh (models/objects/README.md gives its size and source)."""

    path: Path
    description: str


BUILTIN_OBJECTS: dict[str, BuiltinObject] = {
    "horizontal_box": BuiltinObject(
        OBJECTS_DIR / "horizontal_box.obj", "shipping carton lying flat, 0.30 x 0.20 x 0.12 m"
    ),
    "vertical_box": BuiltinObject(
        OBJECTS_DIR / "vertical_box.obj", "product box standing upright, 0.12 x 0.10 x 0.25 m"
    ),
    "gripper": BuiltinObject(
        OBJECTS_DIR / "gripper.obj",
        "parallel-jaw gripper (Robotiq-2F-85-like) lying on its side, 0.150 x 0.085 x 0.060 m",
    ),
    "flange": BuiltinObject(
        OBJECTS_DIR / "flange.obj",
        "DN80 PN16 weld-neck flange lying on its face, 8 bolt holes, 0.200 x 0.200 x 0.050 m",
    ),
}
#: The paper's four test objects, in the order of its results figure.
PAPER_OBJECTS: tuple[str, ...] = ("horizontal_box", "vertical_box", "gripper", "flange")
#: The generated family (`object_family`): shapes nobody tuned the estimator on.
FAMILY_OBJECTS: tuple[str, ...] = tuple(object_family.FAMILY)
#: The held-out shapes (`object_family`): measured, never developed against.
HELD_OUT_OBJECTS: tuple[str, ...] = tuple(object_family.HELD_OUT)


def is_builtin(name: str) -> bool:
    """Whether `name` is a shipped mesh, a member of the generated family or held out."""
    return name in BUILTIN_OBJECTS or object_family.generated(name) is not None


def describe(name: str) -> str:
    """What a built-in object is, in a line."""
    if name in BUILTIN_OBJECTS:
        return BUILTIN_OBJECTS[name].description
    shape = object_family.generated(name)
    held_out = "held out, " if name in object_family.HELD_OUT else ""
    return f"{held_out}{shape.kind}: {shape.description}"


def _expected_input() -> str:
    return ("expected one of the paper's objects (" + ", ".join(PAPER_OBJECTS) + "), a "
            "family object (`lrnbv objects` lists them) or a path to an .obj, .stl or .ply file")


def load_object_mesh(name_or_path: str | os.PathLike[str], scale: float = 1.0) -> trimesh.Trimesh:
    """Loads a built-in object by name (a shipped mesh or a family member), or any OBJ/STL/PLY
    file, scaled about its origin.

    Raises:
        ValueError: unknown name, unsupported extension, a file without triangles, or a scale
            that is not a positive finite number.
        FileNotFoundError: a mesh path that does not exist.
    """
    label = os.fspath(name_or_path)
    try:
        factor = float(scale)
    except (TypeError, ValueError):
        factor = math.nan
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"scale for '{label}' must be a positive finite number; got {scale!r}")
    if object_family.generated(label) is not None:
        mesh = object_family.family_mesh(label)
        if factor != 1.0:
            mesh.apply_scale(factor)
        return mesh
    if label in BUILTIN_OBJECTS:
        path = BUILTIN_OBJECTS[label].path
    else:
        path = Path(label)
        suffix = path.suffix.lower()
        if not suffix:
            raise ValueError(f"unknown object '{label}': {_expected_input()}")
        if suffix not in MESH_SUFFIXES:
            raise ValueError(
                f"unsupported mesh file extension '{path.suffix}' of '{label}': "
                "expected .obj, .stl or .ply"
            )
    if not path.is_file():
        raise FileNotFoundError(f"mesh file '{path}' for '{label}' does not exist")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as err:  # trimesh raises many types for a malformed file
        raise ValueError(f"could not read a mesh from '{label}': {err}") from err
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"'{label}' contains no triangles: expected a triangle mesh")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"'{label}' has vertices that are not finite numbers (NaN or inf)")
    thickness = _thinnest_extent(mesh.vertices)
    if thickness < MIN_THICKNESS * max(float(np.max(mesh.extents)), 1e-12):
        raise ValueError(f"'{label}' is flat: across its thinnest direction it spans "
                         f"{thickness:.3g} mesh units, {thickness / max(mesh.extents):.1e} of "
                         f"its size; a sensor sees a solid, expected a mesh with thickness")
    # OBJ normals (export_obj writes one per face) split shared corners; rejoin them so a closed
    # surface reads back closed.
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    if factor != 1.0:
        mesh.apply_scale(factor)
    return mesh


#: Thinnest a mesh may be across any direction, as a share of its largest extent: a sheet
#: without thickness has no convex hull to plan motions around (`cell_models`).
MIN_THICKNESS = 1e-4


def _thinnest_extent(vertices: np.ndarray) -> float:
    """How far the vertices spread along their direction of least spread."""
    centred = vertices - vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    along = centred @ axes[-1]
    return float(along.max() - along.min())


@dc.dataclass(frozen=True)
class ObjectPlacement:
    """Where an object rests on the table: its footprint centre (x, y), m, and yaw about z, rad."""

    x: float
    y: float
    yaw: float = 0.0


@dc.dataclass(frozen=True, eq=False)
class PlacedObject:
    """An object resting on the table.

    Args:
        mesh: the mesh in the world frame.
        X_WO: (4, 4) pose in the world of the frame the input mesh was given in, so a simulator
            can add the same mesh file at this pose.
        box_min_O: (3,) lower corner of the mesh's own bounding box, in that frame.
        box_max_O: (3,) upper corner.
        table_height: z of the table top it rests on, m (off the scenario's where the
            simulated table is, `device.table_offset_mm`).
    """

    mesh: trimesh.Trimesh
    X_WO: np.ndarray
    box_min_O: np.ndarray
    box_max_O: np.ndarray
    table_height: float = 0.0

    def true_box_points(self) -> np.ndarray:
        """(8, 3) world corners of the true box; corner i takes the upper x, y, z bound where
        bit 0, 1, 2 of i is set."""
        bits = (np.arange(8)[:, None] >> np.arange(3)) & 1
        corners_O = np.where(bits == 1, self.box_max_O, self.box_min_O)
        return corners_O @ self.X_WO[:3, :3].T + self.X_WO[:3, 3]

    def true_dimensions(self) -> tuple[float, float, float]:
        """(L, W, H) of the true box, m: the horizontal sides with L >= W, and the height."""
        sx, sy, sz = (self.box_max_O - self.box_min_O).tolist()
        return max(sx, sy), min(sx, sy), sz


def place_on_table(
    mesh: trimesh.Trimesh, placement: ObjectPlacement, table_height: float = 0.0
) -> PlacedObject:
    """Rests `mesh` on the table: its lowest point on z = `table_height` and the centre of its
    x-y bounding box at (x, y), turned by the yaw about that centre. The input is not changed."""
    box_min, box_max = (np.array(b, dtype=float) for b in mesh.bounds)
    anchor = np.array([(box_min[0] + box_max[0]) / 2, (box_min[1] + box_max[1]) / 2, box_min[2]])
    c, s = math.cos(placement.yaw), math.sin(placement.yaw)
    X_WO = np.eye(4)
    X_WO[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    X_WO[:3, 3] = np.array([placement.x, placement.y, table_height]) - X_WO[:3, :3] @ anchor
    world = mesh.copy()
    world.apply_transform(X_WO)
    return PlacedObject(mesh=world, X_WO=X_WO, box_min_O=box_min, box_max_O=box_max,
                        table_height=table_height)


def _obj_number(value: float) -> str:
    # Adding 0.0 turns a rounded -0.0 into 0.0, so the same geometry always prints the same bytes.
    return f"{round(value, 8) + 0.0:.8f}"


def export_obj(mesh: trimesh.Trimesh, path: str | os.PathLike[str]) -> Path:
    """Writes `mesh` as a plain OBJ for Drake, byte-identical for identical meshes, and returns
    the path.

    Vertices at 10 nm resolution, and one normal per face (deduplicated): Drake's renderer
    refuses an OBJ without normals, and per-face normals shade flat faces flat.
    """
    if len(mesh.faces) == 0:
        raise ValueError(f"cannot write '{os.fspath(path)}': the mesh has no triangles")
    normals, normal_of_face = np.unique(
        np.round(mesh.face_normals, 6) + 0.0, axis=0, return_inverse=True
    )
    lines = ["# lrnbv_drake object mesh, metres"]
    lines += ["v " + " ".join(_obj_number(c) for c in v) for v in mesh.vertices.tolist()]
    lines += ["vn " + " ".join(f"{c:.6f}" for c in n) for n in normals.tolist()]
    lines += [
        "f " + " ".join(f"{i + 1}//{n + 1}" for i in face)
        for face, n in zip(mesh.faces.tolist(), normal_of_face.ravel().tolist(), strict=True)
    ]
    out = Path(path)
    out.write_text("\n".join(lines) + "\n", encoding="ascii")
    return out


def resting_faces(
    mesh: trimesh.Trimesh, table_height: float = 0.0, tolerance: float = 1e-3
) -> np.ndarray:
    """(F,) bool: faces lying on the table (every corner within `tolerance` of it and the normal
    pointing down). No sensor can see them, so coverage does not count them."""
    corners_z = mesh.vertices[mesh.faces][:, :, 2]
    on_table = np.all(np.abs(corners_z - table_height) <= tolerance, axis=1)
    return on_table & (mesh.face_normals[:, 2] < -0.99)


def sample_surface(
    mesh: trimesh.Trimesh,
    spacing: float,
    exclude_bottom: bool = True,
    table_height: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """(N, 3) points drawn uniformly by area over the surface, about one per `spacing`^2,
    leaving out the faces resting on the table when `exclude_bottom` (the coverage reference).

    Raises:
        ValueError: a spacing that is not a positive length, or more than
            `MAX_SURFACE_SAMPLES` points (a mesh far too large, e.g. millimetres read as metres).
    """
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive finite length, m; got {spacing!r}")
    weights = np.array(mesh.area_faces, dtype=float)
    if exclude_bottom:
        weights[resting_faces(mesh, table_height)] = 0.0
    count = round(weights.sum() / spacing**2)
    if count > MAX_SURFACE_SAMPLES:
        raise ValueError(
            f"the mesh is {max(mesh.extents):.3g} m across with {weights.sum():.3g} m^2 of "
            f"surface: {count:.3g} samples at {spacing:g} m spacing, more than the "
            f"{MAX_SURFACE_SAMPLES:.0e} allowed; if it is in millimetres, scale it by 0.001")
    if count == 0:
        return np.zeros((0, 3))
    points, _ = trimesh.sample.sample_surface(mesh, count, face_weight=weights, seed=seed)
    return np.asarray(points)
