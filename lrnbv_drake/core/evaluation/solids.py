"""Closed solids built from trimesh primitives and booleans (manifold3d), each standing on
z = 0 unless placed: the building blocks of the generated shapes (`shape_classes`)."""

from __future__ import annotations

import math

import numpy as np
import trimesh

#: Segments of a full circle (cylinders, tori) and subdivisions of a sphere.
SEGMENTS = 48
SUBDIVISIONS = 3


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One draw in [lo, hi)."""
    return float(rng.uniform(lo, hi))


def box(x: float, y: float, z: float, at: tuple[float, float, float] = (0, 0, 0)
        ) -> trimesh.Trimesh:
    """A box of sides x, y, z standing on z = at[2], centred on (at[0], at[1])."""
    mesh = trimesh.creation.box(extents=(x, y, z))
    mesh.apply_translation((at[0], at[1], at[2] + z / 2))
    return mesh


def cylinder(radius: float, height: float, at: tuple[float, float, float] = (0, 0, 0)
             ) -> trimesh.Trimesh:
    """An upright cylinder standing on z = at[2]."""
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=SEGMENTS)
    mesh.apply_translation((at[0], at[1], at[2] + height / 2))
    return mesh


def bore(radius: float, height: float, at: tuple[float, float] = (0, 0)) -> trimesh.Trimesh:
    """A cylinder to cut through a solid `height` tall standing on z = 0: 5 mm past each
    face, so that the difference leaves no skin."""
    return cylinder(radius, height + 0.01, (at[0], at[1], -0.005))


def lying(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """`mesh` turned a quarter about y, so that its z axis lies along x."""
    mesh = mesh.copy()
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0)))
    return mesh


def ellipsoid(a: float, b: float, c: float, at: tuple[float, float, float] = (0, 0, 0)
              ) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=SUBDIVISIONS, radius=1.0)
    mesh.apply_scale((a, b, c))
    mesh.apply_translation(at)
    return mesh


def union(*parts: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.boolean.union(list(parts), engine="manifold")


def common(*parts: trimesh.Trimesh) -> trimesh.Trimesh:
    """What every one of `parts` holds."""
    return trimesh.boolean.intersection(list(parts), engine="manifold")


def minus(mesh: trimesh.Trimesh, *cut: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.boolean.difference([mesh, *cut], engine="manifold")


def hull(*rings: np.ndarray) -> trimesh.Trimesh:
    """The convex hull of (n, 3) rings of points: a prism, a frustum or a wedge."""
    return trimesh.convex.convex_hull(np.concatenate(rings))


def polygon(radius: float, sides: int, z: float) -> np.ndarray:
    """(sides, 3) a regular polygon of circumradius `radius` at height z."""
    angles = 2 * np.pi * np.arange(sides) / sides
    return np.column_stack([radius * np.cos(angles), radius * np.sin(angles),
                            np.full(sides, z)])
