"""The generated family of objects the estimator is developed and measured against: shapes
nobody tuned it on, from flat cartons to mugs, rings, two parts with a gap, soft blobs and
tapering solids; and the held-out shapes, measured but never developed against: a pouch, a
horseshoe, a pear, a cone lying, a shoe box with its lid and three balls (record 0037: a
set held out joins the family once a change is made for it, and a new one is held out).

Each shape is built here from the solids of `solids` (trimesh and manifold3d), its sizes drawn
from its own seeded generator within its class's ranges, so the family is the same on every
machine and nothing is shipped or downloaded. A shape is turned about z so that its axis-aligned
box is its minimum-area box, and rests with its lowest point at z = 0 and its footprint centred
on the origin, as the built-in meshes do (`objects.py`): its true box is then the box a packing
engineer would measure.
"""

from __future__ import annotations

import dataclasses as dc
import functools
import itertools
import math
from collections.abc import Callable

import numpy as np
import shapely
import trimesh

from lrnbv_drake.core.evaluation.solids import (
    SEGMENTS,
    box,
    common,
    cylinder,
    ellipsoid,
    hull,
    lying,
    minus,
    polygon,
    uniform,
    union,
)


@dc.dataclass(frozen=True)
class FamilyShape:
    """One member of the family: its class, what it stands for, and how it is built."""

    kind: str
    description: str
    build: Callable[[np.random.Generator], trimesh.Trimesh]
    seed: int


# --- the classes --------------------------------------------------------------------------

def _boxes(lo: tuple[float, float, float], hi: tuple[float, float, float]):
    return lambda rng: box(*(uniform(rng, a, b) for a, b in zip(lo, hi, strict=True)))


def _lying_box(rng: np.random.Generator) -> trimesh.Trimesh:
    return box(uniform(rng, 0.22, 0.30), uniform(rng, 0.06, 0.09), uniform(rng, 0.05, 0.07))


def _can(rng: np.random.Generator) -> trimesh.Trimesh:
    return cylinder(uniform(rng, 0.033, 0.0425), uniform(rng, 0.10, 0.13))


def _tub(rng: np.random.Generator) -> trimesh.Trimesh:
    radius, height = uniform(rng, 0.075, 0.10), uniform(rng, 0.08, 0.12)
    return minus(cylinder(radius, height), cylinder(radius - 0.004, height, (0, 0, 0.004)))


def _lying_cylinder(rng: np.random.Generator) -> trimesh.Trimesh:
    return lying(cylinder(uniform(rng, 0.035, 0.05), uniform(rng, 0.18, 0.26)))


def _sphere(rng: np.random.Generator) -> trimesh.Trimesh:
    r = uniform(rng, 0.04, 0.06)
    return ellipsoid(r, r, r)


def _fruit(lo: float, hi: float):
    def build(rng: np.random.Generator) -> trimesh.Trimesh:
        size = uniform(rng, lo, hi)
        return ellipsoid(size / 2, size / 2 * uniform(rng, 0.85, 0.95),
                         size / 2 * uniform(rng, 0.8, 0.9))
    return build


def _bottle_upright(rng: np.random.Generator) -> trimesh.Trimesh:
    radius, body = uniform(rng, 0.032, 0.04), uniform(rng, 0.15, 0.19)
    neck_r, neck = uniform(rng, 0.012, 0.015), uniform(rng, 0.04, 0.06)
    shoulder = trimesh.creation.cone(radius=radius, height=radius * 1.2, sections=SEGMENTS)
    shoulder.apply_translation((0, 0, body))
    return union(cylinder(radius, body), shoulder, cylinder(neck_r, body + neck))


def _bottle(rng: np.random.Generator) -> trimesh.Trimesh:
    return lying(_bottle_upright(rng))


def _gable_carton(side: tuple[float, float], height: tuple[float, float]):
    def build(rng: np.random.Generator) -> trimesh.Trimesh:
        s, h = uniform(rng, *side), uniform(rng, *height)
        roof = s * 0.5
        # The gable: a prism whose ridge runs along y, and the sealed fin along its top.
        profile = shapely.Polygon([(-s / 2, 0), (s / 2, 0), (0, roof)])
        gable = trimesh.creation.extrude_polygon(profile, s)
        gable.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (1, 0, 0)))
        gable.apply_translation((0, s / 2, h))
        fin = box(0.003, s, 0.012, (0, 0, h + roof - 0.004))
        return union(box(s, s, h), gable, fin)
    return build


def _mug(radius: tuple[float, float], height: tuple[float, float]):
    def build(rng: np.random.Generator) -> trimesh.Trimesh:
        r, h = uniform(rng, *radius), uniform(rng, *height)
        reach = uniform(rng, 0.025, 0.035)  # how far the handle stands out of the body
        handle = trimesh.creation.torus(major_radius=h * 0.3, minor_radius=0.006,
                                        major_sections=SEGMENTS, minor_sections=12)
        handle.apply_scale((reach / (h * 0.3), 1.0, 1.0))
        handle.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (1, 0, 0)))
        handle.apply_translation((r, 0, h * 0.5))
        inside = cylinder(r - 0.004, h, (0, 0, 0.006))
        return minus(union(cylinder(r, h), handle), inside)
    return build


def _plate(rng: np.random.Generator) -> trimesh.Trimesh:
    r, h = uniform(rng, 0.11, 0.135), uniform(rng, 0.032, 0.04)
    well = trimesh.creation.cone(radius=r * 0.8, height=h * 4, sections=SEGMENTS)
    well.apply_transform(trimesh.transformations.rotation_matrix(math.pi, (1, 0, 0)))
    well.apply_translation((0, 0, h + h * 4 - 0.012))
    return minus(cylinder(r, h), well)


def _flange(rng: np.random.Generator) -> trimesh.Trimesh:
    r, plate = uniform(rng, 0.06, 0.08), uniform(rng, 0.012, 0.018)
    hub_r, hub = r * uniform(rng, 0.4, 0.5), uniform(rng, 0.03, 0.045)
    holes = [cylinder(0.006, plate + 0.01, (0.8 * r * math.cos(a), 0.8 * r * math.sin(a), -0.005))
             for a in np.arange(6) * math.pi / 3 + math.pi / 6]
    solid = union(cylinder(r, plate), cylinder(hub_r, plate + hub))
    return minus(solid, cylinder(hub_r * 0.7, plate + hub + 0.01, (0, 0, -0.005)), *holes)


def _l_shape(rng: np.random.Generator) -> trimesh.Trimesh:
    length, width, arm, h = (uniform(rng, 0.16, 0.22), uniform(rng, 0.11, 0.16),
                             uniform(rng, 0.04, 0.06), uniform(rng, 0.04, 0.08))
    return union(box(length, arm, h, (0, -(width - arm) / 2, 0)),
                  box(arm, width, h, (-(length - arm) / 2, 0, 0)))


def _bracket(rng: np.random.Generator) -> trimesh.Trimesh:
    length, base, up, t = (uniform(rng, 0.10, 0.16), uniform(rng, 0.06, 0.10),
                           uniform(rng, 0.06, 0.10), uniform(rng, 0.005, 0.008))
    return union(box(length, base, t), box(length, t, up, (0, (base - t) / 2, 0)))


def _channel(rng: np.random.Generator) -> trimesh.Trimesh:
    length, width, h, t = (uniform(rng, 0.18, 0.24), uniform(rng, 0.08, 0.11),
                           uniform(rng, 0.05, 0.07), uniform(rng, 0.008, 0.012))
    return minus(box(length, width, h), box(length + 0.01, width - 2 * t, h, (0, 0, t)))


def _ring(outer: tuple[float, float], hole: float, height: tuple[float, float]):
    def build(rng: np.random.Generator) -> trimesh.Trimesh:
        r, h = uniform(rng, *outer), uniform(rng, *height)
        return minus(cylinder(r, h), cylinder(r * hole, h + 0.01, (0, 0, -0.005)))
    return build


def _two_blocks(rng: np.random.Generator) -> trimesh.Trimesh:
    a, b, gap = uniform(rng, 0.07, 0.10), uniform(rng, 0.05, 0.08), uniform(rng, 0.02, 0.04)
    h1, h2 = uniform(rng, 0.06, 0.10), uniform(rng, 0.04, 0.08)
    x1, x2 = -(gap + b) / 2, (gap + a) / 2
    bridge = box(gap + 0.02, 0.015, 0.008, ((x1 + x2) / 2, 0, 0))
    return union(box(a, a, h1, (x1, 0, 0)), box(b, b, h2, (x2, 0, 0)), bridge)


def _dumbbell(rng: np.random.Generator) -> trimesh.Trimesh:
    r, disc, bar = uniform(rng, 0.035, 0.05), uniform(rng, 0.025, 0.04), uniform(rng, 0.16, 0.24)
    plates = [lying(cylinder(r, disc, (0, 0, x))) for x in (-bar / 2, bar / 2 - disc)]
    rod = lying(cylinder(0.012, bar, (0, 0, -bar / 2)))
    return union(*plates, rod)


def _blob(parts: tuple[int, int], size: tuple[float, float]):
    """A soft irregular shape: a union of random ellipsoids, each centred inside an earlier
    one so that the union is one body."""
    def build(rng: np.random.Generator) -> trimesh.Trimesh:
        scale = uniform(rng, *size)
        centres, semis = [np.zeros(3)], [scale * rng.uniform(0.2, 0.35, 3)]
        for _ in range(int(rng.integers(parts[0], parts[1] + 1)) - 1):
            j = int(rng.integers(len(centres)))
            centres.append(centres[j] + rng.uniform(-0.8, 0.8, 3) * semis[j])
            semis.append(scale * rng.uniform(0.12, 0.28, 3))
        return union(*(ellipsoid(*s, at=tuple(c)) for c, s in zip(centres, semis, strict=True)))
    return build


def _cone(rng: np.random.Generator) -> trimesh.Trimesh:
    return trimesh.creation.cone(radius=uniform(rng, 0.05, 0.07), height=uniform(rng, 0.12, 0.18),
                                 sections=SEGMENTS)


def _pyramid(rng: np.random.Generator) -> trimesh.Trimesh:
    side, height = uniform(rng, 0.12, 0.18), uniform(rng, 0.08, 0.14)
    return hull(polygon(side / math.sqrt(2), 4, 0.0), np.array([[0.0, 0.0, height]]))


def _bucket(rng: np.random.Generator) -> trimesh.Trimesh:
    top, height = uniform(rng, 0.06, 0.08), uniform(rng, 0.12, 0.16)
    return hull(polygon(top * uniform(rng, 0.65, 0.8), SEGMENTS, 0.0),
                 polygon(top, SEGMENTS, height))


def _wedge(rng: np.random.Generator) -> trimesh.Trimesh:
    length, width, height = (uniform(rng, 0.15, 0.22), uniform(rng, 0.08, 0.12),
                             uniform(rng, 0.06, 0.10))
    base = np.array([[x, y, 0.0] for x in (-length / 2, length / 2)
                     for y in (-width / 2, width / 2)])
    return hull(base, np.array([[length / 2, y, height] for y in (-width / 2, width / 2)]))


def _hex_prism(rng: np.random.Generator) -> trimesh.Trimesh:
    radius, height = uniform(rng, 0.04, 0.06) / math.cos(math.pi / 6), uniform(rng, 0.04, 0.08)
    return hull(polygon(radius, 6, 0.0), polygon(radius, 6, height))


def _bowl(rng: np.random.Generator) -> trimesh.Trimesh:
    """A bowl: the lower part of an ellipsoidal shell, open upward, on a foot ring."""
    r, depth, wall = uniform(rng, 0.06, 0.09), uniform(rng, 0.5, 0.7), 0.004
    shell = minus(ellipsoid(r, r, r * depth),
                   ellipsoid(r - wall, r - wall, r * depth - wall),
                   box(2.2 * r, 2.2 * r, r, (0, 0, 0)))
    return union(shell, cylinder(0.4 * r, 0.012, (0, 0, -r * depth - 0.004)))


def _vase(rng: np.random.Generator) -> trimesh.Trimesh:
    """A vase: a belly over its base, a waist and a flared lip, each stretch a frustum."""
    r, h = uniform(rng, 0.04, 0.055), uniform(rng, 0.18, 0.26)
    rings = [polygon(r * uniform(rng, 0.7, 0.8), SEGMENTS, 0.0),
             polygon(r, SEGMENTS, h * uniform(rng, 0.3, 0.4)),
             polygon(r * uniform(rng, 0.45, 0.6), SEGMENTS, h * uniform(rng, 0.7, 0.8)),
             polygon(r * uniform(rng, 0.7, 0.85), SEGMENTS, h)]
    return union(*(hull(a, b) for a, b in itertools.pairwise(rings)))


def _prism_lying(rng: np.random.Generator) -> trimesh.Trimesh:
    """A triangular prism lying on a face, as a chocolate bar's pack."""
    side, length = uniform(rng, 0.04, 0.06), uniform(rng, 0.18, 0.25)
    profile = shapely.Polygon([(-side / 2, 0), (side / 2, 0), (0, side * math.sqrt(3) / 2)])
    mesh = trimesh.creation.extrude_polygon(profile, length)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (1, 0, 0)))
    return mesh


def _spool(rng: np.random.Generator) -> trimesh.Trimesh:
    """A spool standing: a hub between two discs, the upper one overhanging it."""
    r, disc, height = uniform(rng, 0.04, 0.06), uniform(rng, 0.006, 0.01), uniform(rng, 0.05, 0.09)
    return union(cylinder(r, disc), cylinder(r * uniform(rng, 0.4, 0.6), height),
                  cylinder(r, disc, (0, 0, height - disc)))


def _dome(rng: np.random.Generator) -> trimesh.Trimesh:
    """Half an ellipsoid on its flat side (a computer mouse, a dome lid)."""
    a = uniform(rng, 0.05, 0.07)
    return minus(ellipsoid(a, a * uniform(rng, 0.6, 0.8), uniform(rng, 0.03, 0.05)),
                  box(3 * a, 3 * a, a, (0, 0, -a)))


def _torus(rng: np.random.Generator) -> trimesh.Trimesh:
    """A ring of round section lying flat (a swim ring, a seal)."""
    return trimesh.creation.torus(major_radius=uniform(rng, 0.05, 0.07),
                                  minor_radius=uniform(rng, 0.012, 0.02),
                                  major_sections=SEGMENTS, minor_sections=16)


def _pouch(rng: np.random.Generator) -> trimesh.Trimesh:
    """A filled pouch lying flat (a bag of rice, a pillow pack): a flat ellipsoid cut by a
    box, so that flat sides meet at rounded corners under a bulging top."""
    length, width, thick = (uniform(rng, 0.15, 0.22), uniform(rng, 0.10, 0.15),
                            uniform(rng, 0.03, 0.05))
    return common(ellipsoid(0.62 * length, 0.62 * width, thick / 2, (0, 0, thick / 2)),
                  box(length, width, thick))


def _horseshoe(rng: np.random.Generator) -> trimesh.Trimesh:
    """Half a torus lying flat (a horseshoe, a curved handle): a footprint open on one side."""
    big, small = uniform(rng, 0.05, 0.07), uniform(rng, 0.01, 0.016)
    reach = big + small + 0.01
    ring = trimesh.creation.torus(major_radius=big, minor_radius=small,
                                  major_sections=SEGMENTS, minor_sections=16)
    return minus(ring, box(2 * reach, reach, 2 * reach, (0, -reach / 2, -reach)))


def _pear(rng: np.random.Generator) -> trimesh.Trimesh:
    """A pear standing: a round body and a smaller round top sunk into it."""
    body = uniform(rng, 0.035, 0.045)
    top = body * uniform(rng, 0.6, 0.7)
    return union(ellipsoid(body, body, 0.9 * body, (0, 0, 0.9 * body)),
                 ellipsoid(top, top, top, (0, 0, 1.8 * body + 0.5 * top)))


def _cone_lying(rng: np.random.Generator) -> trimesh.Trimesh:
    """A cone lying on its side (a carrot, a piping bag): tilted by its half angle, so that a
    line of its surface from the base's rim to the apex rests on the table."""
    radius, height = uniform(rng, 0.03, 0.045), uniform(rng, 0.15, 0.22)
    cone = trimesh.creation.cone(radius=radius, height=height, sections=SEGMENTS)
    cone.apply_transform(trimesh.transformations.rotation_matrix(
        math.pi / 2 + math.atan2(radius, height), (0, 1, 0)))
    return cone


def _lidded_box(rng: np.random.Generator) -> trimesh.Trimesh:
    """A box with its lid on (a shoe box): the lid overhangs the sides by 3-6 mm."""
    length, width, height = (uniform(rng, 0.26, 0.33), uniform(rng, 0.17, 0.21),
                             uniform(rng, 0.10, 0.13))
    lid, over = uniform(rng, 0.025, 0.04), uniform(rng, 0.003, 0.006)
    return union(box(length, width, height - 0.001),
                 box(length + 2 * over, width + 2 * over, lid, (0, 0, height - lid)))


def _balls(rng: np.random.Generator) -> trimesh.Trimesh:
    """Three balls touching in a triangle (oranges in a net, a pack of tennis balls)."""
    r = uniform(rng, 0.03, 0.036)
    side = 1.96 * r  # a little less than touching, so that the balls are one body
    centres = side / math.sqrt(3) * np.array(
        [[math.cos(a), math.sin(a)] for a in (0, 2 * math.pi / 3, 4 * math.pi / 3)])
    return union(*(ellipsoid(r, r, r, (x, y, r)) for x, y in centres))


def _flattened(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh.apply_scale((1.0, 1.0, 0.35))
    return mesh


def _plush(rng: np.random.Generator) -> trimesh.Trimesh:
    """A seated plush toy: a body, a head, two arms, two legs and two ears."""
    s = uniform(rng, 0.14, 0.22)
    body = ellipsoid(0.28 * s, 0.22 * s, 0.32 * s, (0, 0, 0.32 * s))
    head = ellipsoid(0.22 * s, 0.2 * s, 0.2 * s, (0.02 * s, 0, 0.78 * s))
    ears = [ellipsoid(0.07 * s, 0.03 * s, 0.09 * s, (0, y * 0.14 * s, 0.98 * s)) for y in (-1, 1)]
    arms = [ellipsoid(0.09 * s, 0.2 * s, 0.08 * s, (0.05 * s, y * 0.3 * s, 0.42 * s))
            for y in (-1, 1)]
    legs = [ellipsoid(0.22 * s, 0.09 * s, 0.08 * s, (0.25 * s, y * 0.12 * s, 0.08 * s))
            for y in (-1, 1)]
    return union(body, head, *ears, *arms, *legs)


#: The family by name, in class order. Every shape has its own seed, so adding one changes
#: no other.
FAMILY: dict[str, FamilyShape] = {}
#: The held-out shapes by name: measured (`--objects held_out`), never developed against.
HELD_OUT: dict[str, FamilyShape] = {}
#: The held-out set's first seed: each set held out in turn takes new ones (the first set's
#: 2000, the second's 3000), so that none repeats a family member's.
HELD_OUT_SEEDS = 4000


def _add(name: str, kind: str, description: str,
         build: Callable[[np.random.Generator], trimesh.Trimesh],
         into: dict[str, FamilyShape] = FAMILY, seed: int | None = None) -> None:
    """`seed`: by default the next of the registry's own (the family's from 1000, the
    held-out set's from `HELD_OUT_SEEDS`); a shape that joined the family from a held-out
    set keeps the seed it was measured with."""
    into[name] = FamilyShape(kind, description, build, seed=len(into) + (
        HELD_OUT_SEEDS if into is HELD_OUT else 1000) if seed is None else seed)


_add("box_flat", "box", "a flat carton lying, 22-30 x 15-22 x 3-5 cm",
     _boxes((0.22, 0.15, 0.03), (0.30, 0.22, 0.05)))
_add("box_small", "box", "a small cube, 4-5 cm", _boxes((0.04, 0.04, 0.04), (0.05, 0.05, 0.05)))
_add("box_cube", "box", "a cube-like box, 10-14 cm",
     _boxes((0.10, 0.10, 0.10), (0.14, 0.14, 0.14)))
_add("box_tall", "box", "a tall box standing, 6-9 x 5-7 x 22-30 cm",
     _boxes((0.06, 0.05, 0.22), (0.09, 0.07, 0.30)))
_add("box_lying", "box", "a long box lying, 22-30 x 6-9 x 5-7 cm", _lying_box)
_add("box_large", "box", "a large carton, 30-35 x 20-25 x 15-20 cm",
     _boxes((0.30, 0.20, 0.15), (0.35, 0.25, 0.20)))
_add("can", "cylinder", "a can standing, 6.6-8.5 cm across, 10-13 cm tall", _can)
_add("tub", "cylinder", "an open tub standing, 15-20 cm across, 8-12 cm tall", _tub)
_add("cylinder_lying", "cylinder", "a cylinder lying, 7-10 cm across, 18-26 cm long",
     _lying_cylinder)
_add("ball", "sphere", "a ball, 8-12 cm", _sphere)
_add("fruit", "sphere", "an orange-like ellipsoid, 7-9 cm", _fruit(0.07, 0.09))
_add("melon", "sphere", "a melon-like ellipsoid, 18-22 cm", _fruit(0.18, 0.22))
_add("bottle_standing", "bottle", "a bottle standing, 6.4-8 cm across, 19-25 cm tall",
     _bottle_upright)
_add("bottle_lying", "bottle", "a bottle lying on its side", _bottle)
_add("gable_carton", "carton", "a gable-top carton, 7-9.5 cm square, 17-20 cm to the eaves",
     _gable_carton((0.07, 0.095), (0.17, 0.20)))
_add("gable_carton_small", "carton", "a small gable-top carton, 5.5-6.5 cm square",
     _gable_carton((0.055, 0.065), (0.09, 0.12)))
_add("mug", "mug", "a mug with a handle, 8-9 cm across, 9-10 cm tall",
     _mug((0.04, 0.045), (0.09, 0.10)))
_add("mug_wide", "mug", "a wide low cup with a handle, 10-11 cm across",
     _mug((0.05, 0.055), (0.07, 0.08)))
_add("plate", "plate", "a deep plate, 22-27 cm across, 3.2-4 cm tall, with its well", _plate)
_add("flange_small", "plate", "a small flange, 12-16 cm, a hub and six holes", _flange)
_add("l_shape", "bracket", "an L-shaped part lying flat, 16-22 x 11-16 cm", _l_shape)
_add("bracket", "bracket", "an angle bracket, a base and an upright plate", _bracket)
_add("channel", "bracket", "a U channel lying open side up, 18-24 cm", _channel)
_add("tape_roll", "ring", "a roll of tape, 10-12 cm across, 5 cm tall",
     _ring((0.05, 0.06), 0.7, (0.045, 0.055)))
_add("washer", "ring", "a flat ring, 16-20 cm across, 3-4 cm thick",
     _ring((0.08, 0.10), 0.5, (0.03, 0.04)))
_add("two_blocks", "two parts", "two blocks with a 2-4 cm gap, a thin bridge at the base",
     _two_blocks)
_add("dumbbell", "two parts", "a dumbbell lying, two discs on a bar", _dumbbell)
_add("blob_small", "blob", "a union of 2-3 random ellipsoids, about 9 cm",
     _blob((2, 3), (0.12, 0.16)))
_add("blob", "blob", "a union of 3-4 random ellipsoids, about 19 cm", _blob((3, 4), (0.22, 0.28)))
_add("blob_large", "blob", "a union of 4-6 random ellipsoids, about 30 cm",
     _blob((4, 6), (0.34, 0.42)))
_add("blob_flat", "blob", "a flat union of random ellipsoids, about 20 cm",
     lambda rng: _flattened(_blob((3, 5), (0.28, 0.34))(rng)))
_add("plush", "blob", "a seated plush toy, 14-22 cm tall", _plush)

# Held out until the taper (record 0039), with their held-out seeds.
_add("cone", "taper", "a cone standing, 10-14 cm across, 12-18 cm tall", _cone, seed=2000)
_add("pyramid", "taper", "a square pyramid, 12-18 cm at the base, 8-14 cm tall", _pyramid,
     seed=2001)
_add("bucket", "taper", "a bucket, 12-16 cm across the top, 65-80 % of it at the base, "
     "12-16 cm tall", _bucket, seed=2002)
_add("wedge", "taper", "a wedge, 15-22 x 8-12 cm, rising to 6-10 cm at its back", _wedge,
     seed=2003)
_add("hex_prism", "prism", "a hexagonal prism standing, 8-12 cm across flats, 4-8 cm tall",
     _hex_prism, seed=2004)
_add("box_tiny", "box", "a cube of 2.5-3.5 cm, smaller than a zone's footprint",
     _boxes((0.025, 0.025, 0.025), (0.035, 0.035, 0.035)), seed=2005)

# Held out until the held-out rule's second turn (record 0041), with their held-out seeds.
_add("bowl", "bowl", "a bowl on a foot ring, 12-18 cm across, 4-7 cm tall",
     _bowl, seed=3000)
_add("vase", "vase", "a vase, 8-11 cm across its belly, a waist and a flared lip, "
     "18-26 cm tall", _vase, seed=3001)
_add("prism_lying", "prism", "a triangular prism lying on a face, 4-6 cm sides, 18-25 cm long",
     _prism_lying, seed=3002)
_add("spool", "spool", "a spool standing, 8-12 cm discs on a narrower hub, 5-9 cm tall",
     _spool, seed=3003)
_add("dome", "dome", "half an ellipsoid on its flat side, 10-14 cm long, 3-5 cm tall", _dome,
     seed=3004)
_add("torus", "ring", "a torus lying flat, 12-18 cm across, 2.4-4 cm thick", _torus, seed=3005)

_add("pouch", "bag", "a filled pouch lying flat, 15-22 x 10-15 cm, 3-5 cm thick", _pouch,
     HELD_OUT)
_add("horseshoe", "ring", "half a torus lying flat, 12-17 cm across, 2-3.2 cm thick",
     _horseshoe, HELD_OUT)
_add("pear", "pear", "a pear standing: a round body 7-9 cm across and a smaller top",
     _pear, HELD_OUT)
_add("cone_lying", "taper", "a cone lying on its side, 6-9 cm across, 15-22.5 cm long",
     _cone_lying, HELD_OUT)
_add("lidded_box", "box", "a shoe box, 26-33 x 17-21 x 10-13 cm, its lid overhanging by "
     "3-6 mm", _lidded_box, HELD_OUT)
_add("balls", "sphere", "three balls of 6-7.2 cm touching in a triangle", _balls, HELD_OUT)


def canonical(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """`mesh` turned about z so that its axis-aligned box is its minimum-area box (the longer
    side along x), its footprint centred on the origin and its lowest point at z = 0."""
    footprint = shapely.MultiPoint(mesh.vertices[:, :2]).convex_hull
    rectangle = np.asarray(shapely.minimum_rotated_rectangle(footprint).exterior.coords)[:4]
    edge = rectangle[1] - rectangle[0]
    if np.linalg.norm(edge) < np.linalg.norm(rectangle[2] - rectangle[1]):
        edge = rectangle[2] - rectangle[1]
    out = mesh.copy()
    out.apply_transform(trimesh.transformations.rotation_matrix(
        -math.atan2(edge[1], edge[0]), (0, 0, 1)))
    (x0, y0, z0), (x1, y1, _) = out.bounds
    out.apply_translation((-(x0 + x1) / 2, -(y0 + y1) / 2, -z0))
    return out


def generated(name: str) -> FamilyShape | None:
    """The family's or the held-out shapes' member `name`, or None."""
    return FAMILY.get(name) or HELD_OUT.get(name)


@functools.cache
def _built(name: str) -> trimesh.Trimesh:
    shape = generated(name)
    return canonical(shape.build(np.random.default_rng(shape.seed)))


def family_mesh(name: str) -> trimesh.Trimesh:
    """A copy of the family's or the held-out shapes' `name`, in metres, resting on z = 0
    (see the module doc).

    Raises:
        KeyError: `name` is in neither.
    """
    if generated(name) is None:
        raise KeyError(name)
    return _built(name).copy()
