"""The classes of generated shapes (`object_family`): each a function of a seeded generator
that builds one mesh, its sizes drawn within its class's ranges, from the solids of `solids`
(trimesh and manifold3d); a factory where a class takes its ranges as arguments."""

from __future__ import annotations

import itertools
import math

import numpy as np
import shapely
import trimesh

from lrnbv_drake.core.evaluation.solids import (
    SEGMENTS,
    bore,
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


def boxes(lo: tuple[float, float, float], hi: tuple[float, float, float]):
    return lambda rng: box(*(uniform(rng, a, b) for a, b in zip(lo, hi, strict=True)))


def lying_box(rng: np.random.Generator) -> trimesh.Trimesh:
    return box(uniform(rng, 0.22, 0.30), uniform(rng, 0.06, 0.09), uniform(rng, 0.05, 0.07))


def can(rng: np.random.Generator) -> trimesh.Trimesh:
    return cylinder(uniform(rng, 0.033, 0.0425), uniform(rng, 0.10, 0.13))


def tub(rng: np.random.Generator) -> trimesh.Trimesh:
    radius, height = uniform(rng, 0.075, 0.10), uniform(rng, 0.08, 0.12)
    return minus(cylinder(radius, height), cylinder(radius - 0.004, height, (0, 0, 0.004)))


def lying_cylinder(rng: np.random.Generator) -> trimesh.Trimesh:
    return lying(cylinder(uniform(rng, 0.035, 0.05), uniform(rng, 0.18, 0.26)))


def sphere(rng: np.random.Generator) -> trimesh.Trimesh:
    r = uniform(rng, 0.04, 0.06)
    return ellipsoid(r, r, r)


def fruit(lo: float, hi: float):
    def build(rng: np.random.Generator) -> trimesh.Trimesh:
        size = uniform(rng, lo, hi)
        return ellipsoid(size / 2, size / 2 * uniform(rng, 0.85, 0.95),
                         size / 2 * uniform(rng, 0.8, 0.9))
    return build


def bottle_upright(rng: np.random.Generator) -> trimesh.Trimesh:
    radius, body = uniform(rng, 0.032, 0.04), uniform(rng, 0.15, 0.19)
    neck_r, neck = uniform(rng, 0.012, 0.015), uniform(rng, 0.04, 0.06)
    shoulder = trimesh.creation.cone(radius=radius, height=radius * 1.2, sections=SEGMENTS)
    shoulder.apply_translation((0, 0, body))
    return union(cylinder(radius, body), shoulder, cylinder(neck_r, body + neck))


def bottle(rng: np.random.Generator) -> trimesh.Trimesh:
    return lying(bottle_upright(rng))


def gable_carton(side: tuple[float, float], height: tuple[float, float]):
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


def mug(radius: tuple[float, float], height: tuple[float, float]):
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


def plate(rng: np.random.Generator) -> trimesh.Trimesh:
    r, h = uniform(rng, 0.11, 0.135), uniform(rng, 0.032, 0.04)
    well = trimesh.creation.cone(radius=r * 0.8, height=h * 4, sections=SEGMENTS)
    well.apply_transform(trimesh.transformations.rotation_matrix(math.pi, (1, 0, 0)))
    well.apply_translation((0, 0, h + h * 4 - 0.012))
    return minus(cylinder(r, h), well)


def flange(rng: np.random.Generator) -> trimesh.Trimesh:
    r, plate = uniform(rng, 0.06, 0.08), uniform(rng, 0.012, 0.018)
    hub_r, hub = r * uniform(rng, 0.4, 0.5), uniform(rng, 0.03, 0.045)
    holes = [bore(0.006, plate, (0.8 * r * math.cos(a), 0.8 * r * math.sin(a)))
             for a in np.arange(6) * math.pi / 3 + math.pi / 6]
    solid = union(cylinder(r, plate), cylinder(hub_r, plate + hub))
    return minus(solid, bore(hub_r * 0.7, plate + hub), *holes)


def l_shape(rng: np.random.Generator) -> trimesh.Trimesh:
    length, width, arm, h = (uniform(rng, 0.16, 0.22), uniform(rng, 0.11, 0.16),
                             uniform(rng, 0.04, 0.06), uniform(rng, 0.04, 0.08))
    return union(box(length, arm, h, (0, -(width - arm) / 2, 0)),
                  box(arm, width, h, (-(length - arm) / 2, 0, 0)))


def bracket(rng: np.random.Generator) -> trimesh.Trimesh:
    length, base, up, t = (uniform(rng, 0.10, 0.16), uniform(rng, 0.06, 0.10),
                           uniform(rng, 0.06, 0.10), uniform(rng, 0.005, 0.008))
    return union(box(length, base, t), box(length, t, up, (0, (base - t) / 2, 0)))


def channel(rng: np.random.Generator) -> trimesh.Trimesh:
    length, width, h, t = (uniform(rng, 0.18, 0.24), uniform(rng, 0.08, 0.11),
                           uniform(rng, 0.05, 0.07), uniform(rng, 0.008, 0.012))
    return minus(box(length, width, h), box(length + 0.01, width - 2 * t, h, (0, 0, t)))


def ring(outer: tuple[float, float], hole: float, height: tuple[float, float]):
    def build(rng: np.random.Generator) -> trimesh.Trimesh:
        r, h = uniform(rng, *outer), uniform(rng, *height)
        return minus(cylinder(r, h), bore(r * hole, h))
    return build


def two_blocks(rng: np.random.Generator) -> trimesh.Trimesh:
    a, b, gap = uniform(rng, 0.07, 0.10), uniform(rng, 0.05, 0.08), uniform(rng, 0.02, 0.04)
    h1, h2 = uniform(rng, 0.06, 0.10), uniform(rng, 0.04, 0.08)
    x1, x2 = -(gap + b) / 2, (gap + a) / 2
    bridge = box(gap + 0.02, 0.015, 0.008, ((x1 + x2) / 2, 0, 0))
    return union(box(a, a, h1, (x1, 0, 0)), box(b, b, h2, (x2, 0, 0)), bridge)


def dumbbell(rng: np.random.Generator) -> trimesh.Trimesh:
    r, disc, bar = uniform(rng, 0.035, 0.05), uniform(rng, 0.025, 0.04), uniform(rng, 0.16, 0.24)
    plates = [lying(cylinder(r, disc, (0, 0, x))) for x in (-bar / 2, bar / 2 - disc)]
    rod = lying(cylinder(0.012, bar, (0, 0, -bar / 2)))
    return union(*plates, rod)


def blob(parts: tuple[int, int], size: tuple[float, float]):
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


def cone(rng: np.random.Generator) -> trimesh.Trimesh:
    return trimesh.creation.cone(radius=uniform(rng, 0.05, 0.07), height=uniform(rng, 0.12, 0.18),
                                 sections=SEGMENTS)


def pyramid(rng: np.random.Generator) -> trimesh.Trimesh:
    side, height = uniform(rng, 0.12, 0.18), uniform(rng, 0.08, 0.14)
    return hull(polygon(side / math.sqrt(2), 4, 0.0), np.array([[0.0, 0.0, height]]))


def bucket(rng: np.random.Generator) -> trimesh.Trimesh:
    top, height = uniform(rng, 0.06, 0.08), uniform(rng, 0.12, 0.16)
    return hull(polygon(top * uniform(rng, 0.65, 0.8), SEGMENTS, 0.0),
                 polygon(top, SEGMENTS, height))


def wedge(rng: np.random.Generator) -> trimesh.Trimesh:
    length, width, height = (uniform(rng, 0.15, 0.22), uniform(rng, 0.08, 0.12),
                             uniform(rng, 0.06, 0.10))
    base = np.array([[x, y, 0.0] for x in (-length / 2, length / 2)
                     for y in (-width / 2, width / 2)])
    return hull(base, np.array([[length / 2, y, height] for y in (-width / 2, width / 2)]))


def hex_prism(rng: np.random.Generator) -> trimesh.Trimesh:
    radius, height = uniform(rng, 0.04, 0.06) / math.cos(math.pi / 6), uniform(rng, 0.04, 0.08)
    return hull(polygon(radius, 6, 0.0), polygon(radius, 6, height))


def bowl(rng: np.random.Generator) -> trimesh.Trimesh:
    """A bowl: the lower part of an ellipsoidal shell, open upward, on a foot ring."""
    r, depth, wall = uniform(rng, 0.06, 0.09), uniform(rng, 0.5, 0.7), 0.004
    shell = minus(ellipsoid(r, r, r * depth),
                   ellipsoid(r - wall, r - wall, r * depth - wall),
                   box(2.2 * r, 2.2 * r, r, (0, 0, 0)))
    return union(shell, cylinder(0.4 * r, 0.012, (0, 0, -r * depth - 0.004)))


def vase(rng: np.random.Generator) -> trimesh.Trimesh:
    """A vase: a belly over its base, a waist and a flared lip, each stretch a frustum."""
    r, h = uniform(rng, 0.04, 0.055), uniform(rng, 0.18, 0.26)
    rings = [polygon(r * uniform(rng, 0.7, 0.8), SEGMENTS, 0.0),
             polygon(r, SEGMENTS, h * uniform(rng, 0.3, 0.4)),
             polygon(r * uniform(rng, 0.45, 0.6), SEGMENTS, h * uniform(rng, 0.7, 0.8)),
             polygon(r * uniform(rng, 0.7, 0.85), SEGMENTS, h)]
    return union(*(hull(a, b) for a, b in itertools.pairwise(rings)))


def prism_lying(rng: np.random.Generator) -> trimesh.Trimesh:
    """A triangular prism lying on a face, as a chocolate bar's pack."""
    side, length = uniform(rng, 0.04, 0.06), uniform(rng, 0.18, 0.25)
    profile = shapely.Polygon([(-side / 2, 0), (side / 2, 0), (0, side * math.sqrt(3) / 2)])
    mesh = trimesh.creation.extrude_polygon(profile, length)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (1, 0, 0)))
    return mesh


def spool(rng: np.random.Generator) -> trimesh.Trimesh:
    """A spool standing: a hub between two discs, the upper one overhanging it."""
    r, disc, height = uniform(rng, 0.04, 0.06), uniform(rng, 0.006, 0.01), uniform(rng, 0.05, 0.09)
    return union(cylinder(r, disc), cylinder(r * uniform(rng, 0.4, 0.6), height),
                  cylinder(r, disc, (0, 0, height - disc)))


def dome(rng: np.random.Generator) -> trimesh.Trimesh:
    """Half an ellipsoid on its flat side (a computer mouse, a dome lid)."""
    a = uniform(rng, 0.05, 0.07)
    return minus(ellipsoid(a, a * uniform(rng, 0.6, 0.8), uniform(rng, 0.03, 0.05)),
                  box(3 * a, 3 * a, a, (0, 0, -a)))


def torus(rng: np.random.Generator) -> trimesh.Trimesh:
    """A ring of round section lying flat (a swim ring, a seal)."""
    return trimesh.creation.torus(major_radius=uniform(rng, 0.05, 0.07),
                                  minor_radius=uniform(rng, 0.012, 0.02),
                                  major_sections=SEGMENTS, minor_sections=16)


#: The pouch's ellipsoid's semi-axes across, in its box's sides: past a half, so that the
#: box cuts flat sides into it.
POUCH_BULGE = 0.62


def pouch(rng: np.random.Generator) -> trimesh.Trimesh:
    """A filled pouch lying flat (a bag of rice, a pillow pack): a flat ellipsoid cut by a
    box, so that flat sides meet at rounded corners under a bulging top."""
    length, width, thick = (uniform(rng, 0.15, 0.22), uniform(rng, 0.10, 0.15),
                            uniform(rng, 0.03, 0.05))
    return common(ellipsoid(POUCH_BULGE * length, POUCH_BULGE * width, thick / 2,
                            (0, 0, thick / 2)),
                  box(length, width, thick))


def horseshoe(rng: np.random.Generator) -> trimesh.Trimesh:
    """Half a torus lying flat (a horseshoe, a curved handle): a footprint open on one side."""
    big, small = uniform(rng, 0.05, 0.07), uniform(rng, 0.01, 0.016)
    reach = big + small + 0.01
    ring = trimesh.creation.torus(major_radius=big, minor_radius=small,
                                  major_sections=SEGMENTS, minor_sections=16)
    return minus(ring, box(2 * reach, reach, 2 * reach, (0, -reach / 2, -reach)))


def pear(rng: np.random.Generator) -> trimesh.Trimesh:
    """A pear standing: a round body and a smaller round top sunk into it."""
    body = uniform(rng, 0.035, 0.045)
    top = body * uniform(rng, 0.6, 0.7)
    return union(ellipsoid(body, body, 0.9 * body, (0, 0, 0.9 * body)),
                 ellipsoid(top, top, top, (0, 0, 1.8 * body + 0.5 * top)))


def cone_lying(rng: np.random.Generator) -> trimesh.Trimesh:
    """A cone lying on its side (a carrot, a piping bag): tilted by its half angle, so that a
    line of its surface from the base's rim to the apex rests on the table."""
    radius, height = uniform(rng, 0.03, 0.045), uniform(rng, 0.15, 0.22)
    cone = trimesh.creation.cone(radius=radius, height=height, sections=SEGMENTS)
    cone.apply_transform(trimesh.transformations.rotation_matrix(
        math.pi / 2 + math.atan2(radius, height), (0, 1, 0)))
    return cone


def lidded_box(rng: np.random.Generator) -> trimesh.Trimesh:
    """A box with its lid on (a shoe box): the lid overhangs the sides by 3-6 mm."""
    length, width, height = (uniform(rng, 0.26, 0.33), uniform(rng, 0.17, 0.21),
                             uniform(rng, 0.10, 0.13))
    lid, over = uniform(rng, 0.025, 0.04), uniform(rng, 0.003, 0.006)
    return union(box(length, width, height - 0.001),
                 box(length + 2 * over, width + 2 * over, lid, (0, 0, height - lid)))


#: Centre spacing of touching round parts in their radius: a little less than touching,
#: so that they are one body.
TOUCHING = 1.96


def balls(rng: np.random.Generator) -> trimesh.Trimesh:
    """Three balls touching in a triangle (oranges in a net, a pack of tennis balls)."""
    r = uniform(rng, 0.03, 0.036)
    side = TOUCHING * r
    centres = side / math.sqrt(3) * np.array(
        [[math.cos(a), math.sin(a)] for a in (0, 2 * math.pi / 3, 4 * math.pi / 3)])
    return union(*(ellipsoid(r, r, r, (x, y, r)) for x, y in centres))


def six_pack(rng: np.random.Generator) -> trimesh.Trimesh:
    """Six cans in two rows of three (a drinks pack)."""
    r, h = uniform(rng, 0.031, 0.034), uniform(rng, 0.11, 0.123)
    return union(*(cylinder(r, h, (TOUCHING * r * i, TOUCHING * r * j, 0))
                   for i in range(3) for j in range(2)))


def pipe_lying(rng: np.random.Generator) -> trimesh.Trimesh:
    """A pipe lying (a tube, a cardboard core): a hollow cylinder on its side."""
    outer, wall, length = (uniform(rng, 0.025, 0.04), uniform(rng, 0.003, 0.005),
                           uniform(rng, 0.20, 0.30))
    return lying(minus(cylinder(outer, length), bore(outer - wall, length)))


def hammer(rng: np.random.Generator) -> trimesh.Trimesh:
    """A hammer lying flat: a round handle resting on the table and a block head across its
    end, taller than the handle is thick."""
    radius, length = uniform(rng, 0.012, 0.016), uniform(rng, 0.25, 0.32)
    along, across, tall = (uniform(rng, 0.025, 0.035), uniform(rng, 0.10, 0.13),
                           uniform(rng, 0.034, 0.04))
    handle = lying(cylinder(radius, length))
    handle.apply_translation((0, 0, radius))
    return union(handle, box(along, across, tall, (length - along / 2, 0, 0)))


def stepped_box(rng: np.random.Generator) -> trimesh.Trimesh:
    """Two boxes stacked, the upper smaller and off the lower's centre (a box on a box)."""
    length, width, low = (uniform(rng, 0.18, 0.25), uniform(rng, 0.12, 0.16),
                          uniform(rng, 0.05, 0.08))
    top = np.array([length * uniform(rng, 0.5, 0.75), width * uniform(rng, 0.5, 0.75)])
    shift = (np.array([length, width]) - top) / 2 * rng.uniform(0.4, 1.0, 2)
    return union(box(length, width, low),
                 box(*top, uniform(rng, 0.04, 0.07), (*shift, low - 0.001)))


def star(points: int, outer: float, inner: float) -> shapely.Polygon:
    """A star of `points` tips at radius `outer`, its notches at `inner`."""
    angles = np.pi * np.arange(2 * points) / points
    radii = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return shapely.Polygon(np.c_[radii * np.cos(angles), radii * np.sin(angles)])


def star_prism(rng: np.random.Generator) -> trimesh.Trimesh:
    """A five-pointed star lying flat (a cookie cutter, a badge): a footprint of notches."""
    outer = uniform(rng, 0.05, 0.07)
    return trimesh.creation.extrude_polygon(star(5, outer, outer * uniform(rng, 0.45, 0.55)),
                                            uniform(rng, 0.026, 0.04))


def gear(rng: np.random.Generator) -> trimesh.Trimesh:
    """A spur gear lying flat, its bore through it (a machined part): 16-24 teeth."""
    outer, depth = uniform(rng, 0.06, 0.08), uniform(rng, 0.006, 0.01)
    teeth = int(rng.integers(16, 25))
    # Each tooth a trapezoid: its flanks' feet at the root, its top half as wide.
    angles = 2 * np.pi / teeth * (np.arange(teeth)[:, None] + np.array([0, 0.15, 0.35, 0.5]))
    radii = np.array([outer - depth, outer, outer, outer - depth])
    profile = shapely.Polygon(np.c_[(radii * np.cos(angles)).ravel(),
                                    (radii * np.sin(angles)).ravel()])
    bore = shapely.Point(0, 0).buffer(outer * uniform(rng, 0.2, 0.3), quad_segs=SEGMENTS // 4)
    return trimesh.creation.extrude_polygon(profile.difference(bore), uniform(rng, 0.026, 0.035))


def flattened(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh.apply_scale((1.0, 1.0, 0.35))
    return mesh


def plush(rng: np.random.Generator) -> trimesh.Trimesh:
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
