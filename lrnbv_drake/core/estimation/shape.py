"""The fitted shape: solid parts minus holes, each a box standing on the table with a
quadric rounding and a taper (`forward` module doc), the moves of one coordinate the
search makes, and the cuts of a part into two that its structure moves make."""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation.forward import PART_SIZE

#: The roundings a solid part is tried with: an upright cylinder, an ellipsoid, and a
#: cylinder lying along either side (`forward` module doc); a hole is a box or the first.
ROUNDINGS = ((1.0, 1.0, 0.0), (1.0, 1.0, 1.0), (0.0, 1.0, 1.0), (1.0, 0.0, 1.0))
#: The roundings a solid part is tried with tapered: a box (a frustum of a pyramid) and an
#: upright cylinder (of a cone).
TAPERED = (None, (1.0, 1.0, 0.0))
#: Smallest side of a part, metres.
MIN_SIDE = 0.002
#: A hole's height: it runs from the table up through every solid.
HOLE_HEIGHT = 2.0
#: Coordinates of a part: its four sides (moved outward), its top, its yaw, its rounding
#: (6-8) and its taper.
SIDES, TOP, YAW, TAPER = (0, 1, 2, 3), 4, 5, 9

@dc.dataclass(frozen=True)
class Shape:
    """Solid parts minus holes (`PART_SIZE` numbers each), which parts have their rounding
    free (the others are boxes) and which their taper (the others untapered)."""

    parts: np.ndarray
    rounded: tuple[bool, ...]
    solid: tuple[bool, ...]
    tapered: tuple[bool, ...] | None = None

    def __post_init__(self) -> None:
        if self.parts.ndim != 2 or self.parts.shape[1] != PART_SIZE:
            raise ValueError(f"Shape.parts: shape {self.parts.shape}, expected (n, {PART_SIZE})")
        if self.tapered is None:
            object.__setattr__(self, "tapered", (False,) * len(self.solid))

    @property
    def n_params(self) -> int:
        return sum(len(self.coordinates(k)) for k in range(len(self.solid)))

    def coordinates(self, k: int) -> tuple[int, ...]:
        """The coordinates part k is searched in (a hole has no top, no vertical rounding
        and no taper; a tapered part no vertical rounding)."""
        rounding = (6, 7) if self.tapered[k] or not self.solid[k] else (6, 7, 8)
        return ((0, 1, 2, 3) + (TOP,) * self.solid[k] + (YAW,) + rounding * self.rounded[k]
                + (TAPER,) * self.tapered[k])

    def with_part(self, k: int, x: np.ndarray, rounded: bool | None = None,
                  tapered: bool | None = None) -> Shape:
        parts = self.parts.copy()
        parts[k] = x
        flags, tapers = list(self.rounded), list(self.tapered)
        if rounded is not None:
            flags[k] = rounded
        if tapered is not None:
            tapers[k] = tapered
        return dc.replace(self, parts=parts, rounded=tuple(flags), tapered=tuple(tapers))

    def added(self, x: np.ndarray, solid: bool, rounded: bool = False) -> Shape:
        return dc.replace(self, parts=np.vstack([self.parts, x]),
                          rounded=(*self.rounded, rounded), solid=(*self.solid, solid),
                          tapered=(*self.tapered, False))

    def without(self, k: int) -> Shape:
        keep = [i for i in range(len(self.rounded)) if i != k]
        return dc.replace(self, parts=self.parts[keep],
                          rounded=tuple(self.rounded[i] for i in keep),
                          solid=tuple(self.solid[i] for i in keep),
                          tapered=tuple(self.tapered[i] for i in keep))

    def name(self) -> str:
        """"box", "rounded", "tapered" or "N parts" (holes counted apart)."""
        solids, holes = sum(self.solid), len(self.solid) - sum(self.solid)
        single = [(r, x) for r, x, s in zip(self.rounded, self.parts, self.solid, strict=True)
                  if s]
        text = (f"{solids} parts" if solids > 1 else
                "tapered" if any(x[TAPER] != 0 for _, x in single) else
                "rounded" if any(r and np.any(x[6:9] > 0) for r, x in single)
                else "box")
        return text + (f", {holes} hole{'s' * (holes > 1)}" if holes else "")

    def footprint(self) -> np.ndarray:
        """(n, 2) points whose convex hull is the material's footprint's: the solids'
        outlines outside every hole, and the holes' outlines inside a solid (a hole that
        cuts a solid's end off moves its end)."""
        outline, uncut, inner = self._material()
        return np.concatenate([outline[uncut], inner])

    def _material(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The solids' outline points, which of them no hole covers, and the holes' outline
        points that lie in a solid and in no other hole."""
        solids = self.parts[np.array(self.solid)]
        holes = self.parts[~np.array(self.solid)]
        outline = np.concatenate([_outline(x) for x in solids])
        inner = np.concatenate([_outline(x) for x in holes] or [np.zeros((0, 2))])
        inner = inner[_covered(solids, inner, 1e-9) & ~_covered(holes, inner, -1e-9)]
        return outline, ~_covered(holes, outline, -1e-9), inner

    def box(self, table: float) -> OrientedBox:
        """The material's bounding box: a single solid's own box where no hole cuts its
        outline, else the minimum-area box of the footprint (`footprint`); the solids' where
        holes cover them all (a search's trial)."""
        solids = self.parts[np.array(self.solid)]
        height = float(solids[:, 5].max())
        outline, uncut, inner = self._material()
        if len(solids) == 1 and uncut.all():
            x = solids[0]
            return OrientedBox(np.array([x[0], x[1], table + height / 2]),
                               np.array([x[3], x[4], height]), float(x[2]))
        points = np.concatenate([outline[uncut], inner])
        if len(points) == 0:
            points = outline
        return OrientedBox.from_points(np.c_[points, np.full(len(points), table + height)],
                                       floor_z=table)


def box_shape(box: OrientedBox, table: float) -> Shape:
    """One solid box part with the footprint and top of `box` (at least MIN_SIDE each way)."""
    return Shape(part_of_box(box, table)[None], (False,), (True,))


def part_of_box(box: OrientedBox, table: float) -> np.ndarray:
    """A box part with the footprint and top of `box` (at least MIN_SIDE each way)."""
    dims = np.maximum(box.dims, MIN_SIDE)
    top = max(box.center[2] + box.dims[2] / 2 - table, MIN_SIDE)
    return np.array([box.center[0], box.center[1], box.yaw, dims[0], dims[1], top, 0, 0, 0, 0])


def moved(x: np.ndarray, coordinate: int, value: float) -> np.ndarray:
    """Part x with a side moved outward by `value` (0-3), its top raised (4), its yaw turned
    (5), its rounding's r (6-8) set to `value` (within [0, 1]) or its taper (9, within
    [-1, 1]) turned about its section at mid-height, which stays: a taper alone would move
    the top's edges, which the readings see best, and the base's against each other."""
    y = x.copy()
    if coordinate in SIDES:
        axis = 3 + coordinate // 2
        value = max(value, MIN_SIDE - y[axis])
        sign = 1.0 if coordinate % 2 else -1.0
        c, s = math.cos(y[2]), math.sin(y[2])
        u = (c, s) if axis == 3 else (-s, c)
        y[axis] += value
        y[0] += sign * value / 2 * u[0]
        y[1] += sign * value / 2 * u[1]
    elif coordinate == TOP:
        y[5] = max(y[5] + value, MIN_SIDE)
    elif coordinate == YAW:
        y[2] += value
    elif coordinate == TAPER:
        value = min(max(value, -1.0), 1.0)
        y[3:5] *= (1.0 - abs(y[TAPER]) / 2) / (1.0 - abs(value) / 2)
        y[TAPER] = value
    else:
        y[coordinate] = min(max(value, 0.0), 1.0)
    return y


def halves(shape: Shape, k: int, axis: int) -> Shape:
    """Solid part k cut across its side `axis` (0: length, 1: width) into two boxes."""
    x = np.r_[shape.parts[k][:6], 0, 0, 0, 0]
    size = x[3 + axis]
    return (shape.without(k).added(moved(x, 2 * axis + 1, -size / 2), True)
            .added(moved(x, 2 * axis, -size / 2), True))


def stepped(shape: Shape, k: int) -> Shape:
    """Solid part k, tapered narrowing upward, as two untapered parts standing on the table:
    the lower half of its height with its section at a quarter of the height, and the whole
    height with its section at three quarters (a frustum stepped once: a flange's plate and
    hub, which a taper draws with a skirt)."""
    x = shape.parts[k]
    lower, upper = np.r_[x[:9], 0.0], np.r_[x[:9], 0.0]
    lower[3:5] *= 1.0 - x[TAPER] / 4
    lower[5] /= 2
    upper[3:5] *= 1.0 - 3 * x[TAPER] / 4
    return (shape.without(k).added(lower, True, shape.rounded[k])
            .added(upper, True, shape.rounded[k]))


def _outline(x: np.ndarray) -> np.ndarray:
    """(n, 2) world points of part x's footprint outline: its quadric rounding's ellipse
    within its box, and the box's sides within the rounding."""
    t = np.linspace(0, 2 * np.pi, 96, endpoint=False)
    s = np.linspace(-1, 1, 33)
    a, b = x[3] / 2, x[4] / 2
    local = np.concatenate([
        np.stack([a * np.cos(t) / math.sqrt(max(x[6], 1e-9)),
                  b * np.sin(t) / math.sqrt(max(x[7], 1e-9))], axis=1),
        np.stack([np.r_[a * s, a * s, np.full(33, a), np.full(33, -a)],
                  np.r_[np.full(33, b), np.full(33, -b), b * s, b * s]], axis=1)])
    c, sn = math.cos(x[2]), math.sin(x[2])
    world = local @ np.array([[c, sn], [-sn, c]]) + x[:2]
    return world[_within(x, world, 1e-9)]


def _covered(parts: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    """(n,) whether each of `points` lies in any of `parts` (`_within`)."""
    covered = np.zeros(len(points), bool)
    for x in parts:
        covered |= _within(x, points, tol)
    return covered


def _within(x: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    """(n,) whether world `points` (n, 2) lie in part x's footprint grown by `tol` (shrunk
    where negative)."""
    c, sn = math.cos(x[2]), math.sin(x[2])
    local = (points - x[:2]) @ np.array([[c, -sn], [sn, c]])
    a, b = x[3] / 2 + tol, x[4] / 2 + tol
    if a <= 0 or b <= 0:
        return np.zeros(len(points), bool)
    return ((np.abs(local[:, 0]) <= a) & (np.abs(local[:, 1]) <= b)
            & (x[6] * (local[:, 0] / a) ** 2 + x[7] * (local[:, 1] / b) ** 2 <= 1 + tol))
