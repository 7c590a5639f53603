"""Writes the paper's four test objects as watertight OBJ meshes into a folder (default: this one).

    .venv/bin/python models/objects/generate_objects.py [OUT_DIR]

Each mesh is in metres, origin at the centre of its footprint and z = 0 on its resting face.
The output is deterministic (same bytes every run); tests/test_objects.py checks that the shipped
files match. README.md beside this script gives the sizes and where they come from.

Without a boolean engine, the non-box objects are *stepped solids*: prisms (or lofts between two
rings of equal vertex count) stacked along one axis, where each cross-section contains the next
or is contained by it. Such a stack's surface is the walls of every section plus, at each step,
the region of one cross-section not covered by the next, which is a true union: one closed,
manifold surface, with no faces buried inside.
"""

from __future__ import annotations

import dataclasses as dc
import itertools
import math
import sys
from pathlib import Path

import numpy as np
import shapely
import trimesh
from shapely.geometry import MultiPolygon, Polygon

from lrnbv_drake.core.evaluation.objects import export_obj

HERE = Path(__file__).resolve().parent


def circle(radius: float, segments: int, centre: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """(segments, 2) counter-clockwise regular polygon with a vertex at angle 0, so with segments
    a multiple of 4 its bounding box is exactly the circle's."""
    angles = 2 * np.pi * np.arange(segments) / segments
    return np.column_stack(
        [centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)]
    )


def rectangle(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """(4, 2) counter-clockwise rectangle."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def region(outer: np.ndarray, holes: tuple[np.ndarray, ...] = ()) -> Polygon:
    """A polygon from a counter-clockwise outer ring and holes (given either way round)."""
    return Polygon(outer, [h[::-1] for h in holes])


@dc.dataclass(frozen=True)
class Section:
    """A slab z0..z1 of a stepped solid: `bottom` is its cross-section at z0 and `top` (same
    rings, same vertex counts, in the same order) at z1; a prism when `top` is None."""

    z0: float
    z1: float
    bottom: Polygon | MultiPolygon
    top: Polygon | MultiPolygon | None = None

    @property
    def upper(self) -> Polygon | MultiPolygon:
        return self.bottom if self.top is None else self.top


def _polygons(shape: Polygon | MultiPolygon) -> list[Polygon]:
    return [p for p in shapely.get_parts(shape) if isinstance(p, Polygon) and not p.is_empty]


def _rings(shape: Polygon | MultiPolygon) -> list[np.ndarray]:
    """Every ring with the material on its left (outer rings counter-clockwise, holes clockwise),
    without the repeated closing vertex."""
    rings = []
    for poly in _polygons(shapely.orient_polygons(shape, exterior_cw=False)):
        rings.append(np.asarray(poly.exterior.coords)[:-1])
        rings += [np.asarray(r.coords)[:-1] for r in poly.interiors]
    return rings


def _cap(shape: Polygon | MultiPolygon, z: float, up: bool) -> np.ndarray:
    """(T, 3, 3) triangles covering a planar region at height z, facing +z if `up`.

    GEOS's constrained Delaunay triangulation adds no vertices and, unlike earcut, keeps every
    ring edge even where holes have collinear edges, so caps meet the walls edge to edge.
    """
    triangles = shapely.get_parts(shapely.constrained_delaunay_triangles(shape))
    if len(triangles) == 0:
        return np.zeros((0, 3, 3))
    tri = np.array([np.asarray(t.exterior.coords)[:3] for t in triangles])
    edge_a, edge_b = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    ccw = edge_a[:, 0] * edge_b[:, 1] - edge_a[:, 1] * edge_b[:, 0] > 0
    flip = ccw != up
    tri[flip] = tri[flip][:, ::-1]
    return np.concatenate([tri, np.full((*tri.shape[:2], 1), z)], axis=2)


def _walls(section: Section) -> np.ndarray:
    """(T, 3, 3) outward-facing side triangles of one section."""
    tris = []
    for low, high in zip(_rings(section.bottom), _rings(section.upper), strict=True):
        if low.shape != high.shape:
            raise ValueError("a lofted section needs rings with equal vertex counts")
        b = np.column_stack([low, np.full(len(low), section.z0)])
        t = np.column_stack([high, np.full(len(high), section.z1)])
        b_next, t_next = np.roll(b, -1, axis=0), np.roll(t, -1, axis=0)
        tris += [np.stack([b, b_next, t_next], axis=1), np.stack([b, t_next, t], axis=1)]
    return np.concatenate(tris)


def stepped_solid(sections: list[Section]) -> trimesh.Trimesh:
    """The closed surface of contiguous sections stacked bottom to top along z."""
    tris = [_cap(sections[0].bottom, sections[0].z0, up=False)]
    for below, above in itertools.pairwise(sections):
        if not math.isclose(below.z1, above.z0):
            raise ValueError(f"sections must touch: {below.z1} != {above.z0}")
        tris.append(_cap(below.upper.difference(above.bottom), below.z1, up=True))
        tris.append(_cap(above.bottom.difference(below.upper), below.z1, up=False))
    tris += [_walls(s) for s in sections]
    tris.append(_cap(sections[-1].upper, sections[-1].z1, up=True))
    triangles = np.concatenate(tris)
    return trimesh.Trimesh(
        vertices=triangles.reshape(-1, 3), faces=np.arange(len(triangles) * 3).reshape(-1, 3)
    )


def rest_on_footprint_centre(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Moves the origin to the centre of the x-y bounding box, on the lowest point."""
    (x0, y0, z0), (x1, y1, _) = mesh.bounds
    mesh.apply_translation([-(x0 + x1) / 2, -(y0 + y1) / 2, -z0])
    return mesh


def box(length: float, width: float, height: float) -> trimesh.Trimesh:
    """A closed box, `length` along x, `width` along y, `height` along z."""
    return rest_on_footprint_centre(trimesh.creation.box(extents=[length, width, height]))


def gripper() -> trimesh.Trimesh:
    """A Robotiq-2F-85-like parallel-jaw gripper lying on its side, jaws half open.

    Built along its approach axis (z here, x once laid down), with the jaws opening along y and
    the broad side of the housing down: coupling disc Ø50 x 12 mm, housing 85 x 60 x 88 mm,
    two fingers 18 x 24 x 50 mm with a 40 mm gap, centred on the housing's mid-plane.
    """
    half_w, depth = 0.0425, 0.060
    mid = depth / 2
    housing = region(rectangle(-half_w, 0.0, half_w, depth))
    fingers = MultiPolygon(
        [
            region(rectangle(-0.038, mid - 0.012, -0.020, mid + 0.012)),
            region(rectangle(0.020, mid - 0.012, 0.038, mid + 0.012)),
        ]
    )
    solid = stepped_solid(
        [
            Section(0.0, 0.012, region(circle(0.025, 48, (0.0, mid)))),
            Section(0.012, 0.100, housing),
            Section(0.100, 0.150, fingers),
        ]
    )
    # Lay it down: approach axis (z) -> x, opening (x) -> y, housing depth (y) -> z.
    solid.apply_transform([[0, 0, 1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    return rest_on_footprint_centre(solid)


def flange() -> trimesh.Trimesh:
    """A DN80 PN16 weld-neck flange (after EN 1092-1 type 11) lying on its face, hub up.

    Plate Ø200 x 20 mm with 8 bolt holes Ø18 on a Ø160 pitch circle; hub tapering from Ø110 at
    the plate to Ø88.9 (the pipe's outside diameter) at 50 mm; bore Ø82.5 (88.9 x 3.2 pipe).
    No raised face, so the flange rests flat on its full face.
    """
    bore = circle(0.04125, 64)
    holes = tuple(
        circle(0.009, 24, (0.080 * math.cos(a), 0.080 * math.sin(a)))
        for a in 2 * np.pi * (np.arange(8) + 0.5) / 8
    )
    plate = region(circle(0.100, 128), (bore, *holes))
    hub = Section(
        0.020, 0.050, region(circle(0.055, 96), (bore,)), region(circle(0.04445, 96), (bore,))
    )
    return rest_on_footprint_centre(stepped_solid([Section(0.0, 0.020, plate), hub]))


OBJECTS = {
    "horizontal_box": lambda: box(0.30, 0.20, 0.12),
    "vertical_box": lambda: box(0.12, 0.10, 0.25),
    "gripper": gripper,
    "flange": flange,
}


def main(out_dir: Path = HERE) -> list[Path]:
    """Writes every object to `out_dir`, refusing any mesh that is not a closed solid."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, build in OBJECTS.items():
        mesh = build()
        if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
            raise RuntimeError(f"{name}: the generated mesh is not a closed, outward solid")
        written.append(export_obj(mesh, out_dir / f"{name}.obj"))
    return written


if __name__ == "__main__":
    for path in main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE):
        print(path)
