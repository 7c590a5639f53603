"""Fitting a shape (`shape`) to the readings: one robust objective, a coordinate search, and
the shape's structure chosen by an information criterion.

The objective is the soft-L1 sum of every fitted zone's residual in the model's sigma
(`forward._loss`). Sub-ray sampling makes it piecewise constant in the parts' sides, so it is
minimised by a coordinate grid search: each side, the top, the yaw, the rounding and the
taper of each part in turn, every candidate of a grid in one kernel call that re-casts only
the sub-rays that reach what the coordinate moves before the surface they see now (the
others' depths cannot change).

Which shape (a box, a rounded or tapered part, more parts, holes) is chosen by the Bayesian
information criterion with the noise scale unknown, n ln(C / n) + k ln n for a cost C over n
zones and k parameters: a box is a solid part with its rounding fixed at zero, and a richer
shape is kept only where it explains the readings by more than its parameters would explain
noise, measured against the misfit the readings leave (on a device the model does not
explain, that misfit is large and a part must explain that much more).
"""

from __future__ import annotations

import dataclasses as dc
import math
from collections.abc import Callable

import numpy as np
import scipy.cluster.hierarchy

from lrnbv_drake.core.estimation import forward
from lrnbv_drake.core.estimation.forward import NO_CLIP, ReadingRule, ZoneRays
from lrnbv_drake.core.estimation.shape import (
    HOLE_HEIGHT,
    ROUNDINGS,
    SIDES,
    TAPER,
    TAPERED,
    TOP,
    YAW,
    Shape,
    box_shape,
    halves,
    moved,
    stepped,
)

#: A zone the shape does not explain: its residual beyond this many sigmas (a chance of
#: about 0.3 % for the model's noise); and how many such zones a structure move needs.
OUTLIER = 3.0
MIN_OUTLIERS = 3
#: The tapers a tapered class is started from, the best fitting kept.
TAPER_STARTS = (-0.6, -0.3, 0.0, 0.3, 0.6, 0.9)
#: Residual, sigmas, of the zones a part or a hole is proposed around: lower than an
#: outlier's, as a thin part (a plate on the table) moves each zone by a sigma or two; the
#: information criterion then decides whether the part stays.
PROPOSAL = 2.0


def bic(cost: float, n: int, k: int) -> float:
    """The information criterion with the noise scale unknown (the module doc)."""
    return n * math.log(max(cost, 1e-12) / n) + k * math.log(n)


@dc.dataclass(frozen=True)
class Fit:
    """A shape and what it predicts: each sub-ray's depth, each zone's reading and loss."""

    shape: Shape
    depths: np.ndarray
    predicted: np.ndarray
    costs: np.ndarray

    @property
    def cost(self) -> float:
        return float(self.costs.sum())


class Problem:
    """The zones one estimate fits, the table's depths along their sub-rays and the rule
    that turns depths into readings; every cost of the search."""

    def __init__(self, rays: ZoneRays, table: float, extent: np.ndarray, rule: ReadingRule,
                 loss_scale: float, no_return: float, step: float,
                 region: tuple[np.ndarray, np.ndarray] | None = None,
                 budget: float = math.inf, taper: bool = False) -> None:
        self.rays, self.table, self.rule = rays, table, rule
        # Whether a shape's one solid may be tried tapered (`classings`, `choose_structure`).
        self.taper = taper
        # The search's work: the sub-ray casts of its candidate grids (`trials`, most of its
        # time), and how many it may make before every further grid is skipped (a search
        # past it keeps the best shape it has).
        self.casts, self.budget = 0, budget
        self.loss = (loss_scale, no_return)
        self.step = step
        # (lower, upper) world corners the solid parts must stay within: the zones were
        # chosen there, so beyond it nothing in the fit would bound a part.
        self.region = region
        self.base = forward.table_depths(rays.origins, rays.directions, table, extent)
        # `reclassed` results by (id(fit), k, rounding, span), each with its fit (held, so
        # that its id is not reused), so that the interval takes the class move's refits of
        # the same fit rather than redo them.
        self._reclassed: dict[tuple, tuple[Fit, Fit]] = {}

    def inside(self, xs: np.ndarray) -> np.ndarray:
        """(len(xs),) whether each part's box lies within the region."""
        if self.region is None:
            return np.ones(len(xs), bool)
        c, s = np.abs(np.cos(xs[:, 2])), np.abs(np.sin(xs[:, 2]))
        reach = np.stack([c * xs[:, 3] + s * xs[:, 4], s * xs[:, 3] + c * xs[:, 4]], 1) / 2
        lo, hi = self.region
        return (np.all(xs[:, :2] - reach >= lo[:2], axis=1)
                & np.all(xs[:, :2] + reach <= hi[:2], axis=1)
                & (self.table + xs[:, 5] <= hi[2]))

    def __len__(self) -> int:
        return len(self.rays)

    def score(self, fit: Fit) -> float:
        return bic(fit.cost, len(self), fit.shape.n_params)

    def _losses(self, depths, zones=slice(None)):
        r = self.rays
        return forward.zone_losses(depths, r.measured[zones], r.sigma[zones],
                                   *self.rule.args(), *self.loss)

    def evaluate(self, shape: Shape, clip: np.ndarray = NO_CLIP, zones: np.ndarray | None = None
                 ) -> Fit:
        """`shape`'s predictions and losses (of the zones `zones` only, if given)."""
        r, zones = self.rays, slice(None) if zones is None else zones
        depths = forward.shape_depths(r.origins[zones], r.directions[zones], r.planes[zones],
                                      shape.parts, np.array(shape.solid), self.base[zones],
                                      self.table, clip)
        return Fit(shape, depths, *self._losses(depths, zones))

    def _updated(self, fit: Fit, shape: Shape, zones: np.ndarray) -> Fit:
        """`fit` with `shape`, its zones `zones` evaluated again (the others unchanged)."""
        part = self.evaluate(shape, zones=zones)
        depths, predicted, costs = fit.depths.copy(), fit.predicted.copy(), fit.costs.copy()
        depths[zones], predicted[zones], costs[zones] = part.depths, part.predicted, part.costs
        return Fit(shape, depths, predicted, costs)

    def near(self, x: np.ndarray, grow: float) -> np.ndarray:
        """Indices of the zones with a sub-ray through part x's box grown by `grow` on every
        side (the only zones its searches can change)."""
        region = x.copy()
        region[3:6] += 2 * grow
        return np.flatnonzero(self.rays.crossing(region, self.table - grow).any(axis=1))

    def _moving(self, fit: Fit, k: int, coordinate: int, lo: float, hi: float,
                near: np.ndarray) -> np.ndarray:
        """(len(near), m) the sub-rays of zones `near` a grid of part k's coordinate from
        `lo` to `hi` can change: those that enter the region the grid sweeps (the slab a
        box's side or top sweeps, all of a rounded part's box, as its rounding scales with
        its sides, or the disc its yaw turns in) no farther than the depth they see now.
        Every candidate is the part outside that region, so a surface seen in front of it
        stays the first one seen. The region holds the part as it is too (a grid left with
        only the candidates inside `region` may not hold it)."""
        x, rays, shape = fit.shape.parts[k], self.rays, fit.shape
        lo, hi = min(lo, 0.0), max(hi, 0.0)
        whole = shape.rounded[k] or shape.tapered[k]  # every side moves the whole part
        if coordinate in SIDES and not whole:
            axis = 3 + coordinate // 2
            region = moved(moved(x, coordinate, hi), coordinate ^ 1, -(x[axis] + lo) + 1e-4)
            return rays.crossing(region, self.table, near, fit.depths)
        if coordinate == TOP and not whole:
            region = x.copy()
            region[5] = hi - lo + 1e-4
            return rays.crossing(region, self.table + x[5] + lo, near, fit.depths)
        region = x.copy()
        if coordinate == YAW:
            region[3] = region[4] = math.hypot(x[3], x[4])
        elif coordinate <= TOP:
            region = moved(x, coordinate, hi)
        elif coordinate == TAPER:  # its box grows with the taper's size (`moved`)
            ends = np.clip(x[TAPER] + np.array([lo, hi]), -1.0, 1.0)
            region = moved(x, TAPER, ends[np.argmax(np.abs(ends))])
        return rays.crossing(region, self.table, near, fit.depths)

    def trials(self, fit: Fit, k: int, coordinate: int, xs: np.ndarray, lo: float, hi: float,
               near: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(zones, losses): the zones (of `near`) a grid `xs` of part k's coordinate can
        change and their losses (len(xs), len(zones)) at each candidate."""
        if self.casts >= self.budget:
            return near[:0], np.zeros((len(xs), 0))
        moving = self._moving(fit, k, coordinate, lo, hi, near)
        rows = np.flatnonzero(moving.any(axis=1))
        zones = near[rows]
        starts = np.r_[0, np.cumsum(moving[rows].sum(axis=1))]
        subrays = np.nonzero(moving[rows])[1]
        r, s = self.rays, fit.shape
        self.casts += len(subrays) * len(xs) * len(s.solid)
        return zones, forward.grid_costs(
            r.origins, r.directions, r.measured, r.sigma, zones, starts, subrays, s.parts,
            np.array(s.solid), k, xs, fit.depths, self.base, self.table, *self.rule.args(),
            *self.loss)

    def reclassed(self, fit: Fit, k: int, rounding: tuple[float, float, float] | None,
                  span: float, tapered: bool = False) -> Fit:
        """Part k of `fit` as a box (`rounding` None) or with `rounding`, its taper free or
        not, from the part of the same volume untapered, searched within `span` (two sweeps
        of its coordinates)."""
        key = (id(fit), k, rounding, span, tapered)
        if key in self._reclassed:
            return self._reclassed[key][1]
        shape = fit.shape
        x = np.r_[shape.parts[k][:6], (0, 0, 0) if rounding is None else rounding, 0]
        if rounding is not None and not shape.rounded[k]:
            x[3:6] *= _volume_scale(np.array(rounding))
        flags = {"rounded": rounding is not None, "tapered": tapered}
        # A taper starts where it fits best on a grid: one sweep moves it at most 0.3.
        trial = min((self.evaluate(shape.with_part(k, np.r_[x[:9], tau], **flags))
                     for tau in (TAPER_STARTS if tapered else (0.0,))), key=lambda f: f.cost)
        out = self.refine(trial, span, only=k, max_sweeps=2)
        self._reclassed[key] = (fit, out)
        return out

    def forget_reclassed(self, keep: Fit | None = None) -> None:
        """Drops the kept refits (`reclassed`) of every fit but `keep`: an estimate keeps its
        problem for its interval, read later or never."""
        self._reclassed = {key: value for key, value in self._reclassed.items()
                           if value[0] is keep}

    def refine(self, fit: Fit, span: float, only: int | None = None, max_sweeps: int = 4
               ) -> Fit:
        """A coordinate search of every part (or part `only`): each coordinate on a grid of
        steps about a quarter of `span` (the sides and top; the yaw and rounding in
        proportion), moved while its best lies at the grid's edge, then of the finest
        steps."""
        fine = (self.step,) * 5 + (math.radians(0.2),) + (0.02,) * 4
        coarse = (span / 4,) * 5 + (math.radians(1.5) * span / 0.03,) + (min(span * 5, 0.25),) * 4
        for _ in range(max_sweeps):
            before = fit.cost
            for k in range(len(fit.shape.rounded)) if only is None else (only,):
                near = self.near(fit.shape.parts[k], 2 * span + 0.01)
                for coordinate in fit.shape.coordinates(k):
                    steps = (coarse[coordinate], fine[coordinate])
                    for step in steps if steps[0] > 3 * steps[1] else steps[1:]:
                        fit = self._line(fit, k, coordinate, step, 3 * span, near)
            if fit.cost >= before - 1e-9:
                break
        return fit

    def _line(self, fit: Fit, k: int, coordinate: int, step: float, reach: float,
              near: np.ndarray) -> Fit:
        """Part k's coordinate on a grid of +-3 `step`s, re-centred on its best while that
        lies at the edge, at most `reach` (sides and top) from where it started; a solid's
        candidates beyond the region left out."""
        travelled = 0.0
        while True:
            x = fit.shape.parts[k]
            centre = x[coordinate] if coordinate > YAW else 0.0
            grid = centre + step * np.arange(-3, 4)
            xs = np.array([moved(x, coordinate, g) for g in grid])
            if fit.shape.solid[k]:
                keep = self.inside(xs)
                if not keep.any():
                    return fit
                grid, xs = grid[keep], xs[keep]
            zones, trials = self.trials(fit, k, coordinate, xs, grid[0] - centre,
                                        grid[-1] - centre, near)
            if len(zones) == 0:
                return fit
            totals = trials.sum(axis=1)
            # Of the candidates within 1e-9 of the lowest, the least move: equal costs say
            # nothing about which, and a sum's last bits would otherwise decide.
            tied = np.flatnonzero(totals <= totals.min() + 1e-9)
            best = int(tied[np.argmin(np.abs(grid[tied] - centre))])
            if totals[best] >= fit.costs[zones].sum() - 1e-9:
                return fit
            fit = self._updated(fit, fit.shape.with_part(k, xs[best]), zones)
            travelled += abs(grid[best] - centre)
            if best not in (0, len(grid) - 1) or coordinate > YAW or travelled >= reach:
                return fit


def _volume_scale(r: np.ndarray) -> np.ndarray:
    """How much a box's sides grow for the rounding `r` (one of `ROUNDINGS`) of the same
    volume: by the rounded axes' share of the cut (an upright cylinder's footprint is
    pi / 4 of its box's, an ellipsoid's volume pi / 6)."""
    share = {2: math.pi / 4, 3: math.pi / 6}[int(r.sum())]
    return np.where(r > 0, share ** (-1 / r.sum()), 1.0)


def classings(problem: Problem, fit: Fit, k: int, span: float, box: bool = True
              ) -> list[Fit]:
    """Part k as a box (unless not `box`), as each rounding (`ROUNDINGS`) and, the shape's
    only solid, as a tapered box and a tapered upright cylinder (`TAPERED`, where the
    problem allows a taper); a hole as a box or an upright cylinder. Each searched within
    `span` from the part of the same volume.

    A taper is a class of a whole solid (a cone, a pyramid, a bucket): on a part among
    others it draws a skirt at its base or an overhang at its top that the other parts hide
    from the readings, which then barely bound the box (a dumbbell's bar 30 mm beyond its
    discs)."""
    shape = fit.shape
    roundings = ROUNDINGS if shape.solid[k] else ROUNDINGS[:1]
    tapered = TAPERED if problem.taper and shape.solid[k] and sum(shape.solid) == 1 else ()
    return ([problem.reclassed(fit, k, r, span) for r in ((None,) if box else ()) + roundings]
            + [problem.reclassed(fit, k, r, span, tapered=True) for r in tapered])


def _classed(problem: Problem, fit: Fit, k: int, span: float) -> Fit:
    """The best of part k's `classings` by the information criterion."""
    return min(classings(problem, fit, k, span), key=problem.score)


def _grouped(points: np.ndarray) -> np.ndarray:
    """The largest group of `points` by single linkage at 3 cm."""
    if len(points) < 2:
        return points
    groups = scipy.cluster.hierarchy.fcluster(
        scipy.cluster.hierarchy.linkage(points, "single"), 0.03, criterion="distance")
    return points[groups == np.bincount(groups).argmax()]


def _proposed(problem: Problem, fit: Fit, solid: bool) -> tuple[np.ndarray | None, int]:
    """A box part around the largest group of the points where the readings put a surface
    nearer than the shape does (a solid part it lacks: residuals below -`PROPOSAL` sigmas,
    above the table) or farther, inside its footprint (a hole: above `PROPOSAL`), a
    centimetre beyond them for a solid, and how many zones ask for it; None where there is
    none."""
    r, shape = problem.rays, fit.shape
    residual = (r.measured - np.nan_to_num(fit.predicted, nan=np.inf)) / r.sigma
    zones = np.flatnonzero(residual < -PROPOSAL if solid else residual > PROPOSAL)
    points = r.origins[zones] + r.measured[zones, None] * r.directions[zones].mean(axis=1)
    yaw = shape.parts[0, 2]
    rotation = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    if solid:
        points = points[points[:, 2] > problem.table + 0.005]
    else:
        box = shape.box(problem.table)
        local = (points[:, :2] - box.center[:2]) @ np.array(
            [[math.cos(box.yaw), -math.sin(box.yaw)], [math.sin(box.yaw), math.cos(box.yaw)]])
        points = points[np.all(np.abs(local) < box.dims[:2] / 2, axis=1)]
    points = _grouped(points)
    if len(points) < MIN_OUTLIERS:
        return None, 0
    local = points[:, :2] @ rotation
    grow = 0.01 if solid else 0.0
    lo, hi = local.min(axis=0) - grow, local.max(axis=0) + grow
    height = max(points[:, 2].max() - problem.table + 0.005, 0.01) if solid else HOLE_HEIGHT
    return np.array([*(rotation @ ((lo + hi) / 2)), yaw, *np.maximum(hi - lo, 0.01), height,
                     0, 0, 0, 0]), len(points)


@dc.dataclass(frozen=True)
class Move:
    """A change of the shape's structure the readings may ask for: `kind` "class" (part k
    re-classed or cut in two), "solid" or "hole" (a part added), with the outlier zones
    that ask for it."""

    kind: str
    k: int
    evidence: int
    # The part a "solid" or "hole" move adds.
    part: np.ndarray | None = dc.field(default=None, compare=False)


def _outliers(problem: Problem, fit: Fit) -> np.ndarray:
    r = problem.rays
    return np.abs((r.measured - np.nan_to_num(fit.predicted, nan=np.inf)) / r.sigma) > OUTLIER


def moves(problem: Problem, fit: Fit, max_parts: int) -> list[Move]:
    """The structure moves the readings ask for, most asked first: a part or a hole added
    where at least `MIN_OUTLIERS` zones ask for it (`_proposed`), then each part re-classed,
    asked for by the zones that see it (its class, chosen on fewer readings, is revisited as
    they grow) and first where most of them are outliers (residuals beyond `OUTLIER`)."""
    outlier = _outliers(problem, fit)
    shape, found = fit.shape, []
    if len(shape.solid) < max_parts:
        # A tapered solid takes no second one (`classings`), a hole it may; its class move
        # steps it into two (`shape.stepped`).
        for kind in ("hole",) if any(shape.tapered) else ("solid", "hole"):
            part, asking = _proposed(problem, fit, kind == "solid")
            if part is not None:
                found.append(Move(kind, -1, asking, part))
    found.sort(key=lambda m: -m.evidence)
    near = [problem.near(x, 0.01) for x in shape.parts]
    return ([m for m in found if m.evidence >= MIN_OUTLIERS]
            + sorted((Move("class", k, len(z)) for k, z in enumerate(near)),
                     key=lambda m: -int(outlier[near[m.k]].sum())))


def _tried(problem: Problem, fit: Fit, move: Move, max_parts: int) -> list[Fit]:
    """The shapes `move` proposes, each searched near it."""
    shape, n = fit.shape, len(fit.shape.solid)
    if move.kind == "class":
        out = [_classed(problem, fit, move.k, 0.01)]
        if shape.solid[move.k] and n < max_parts:
            out += [problem.refine(problem.evaluate(halves(shape, move.k, axis)),
                                   shape.parts[move.k][3 + axis] / 4, max_sweeps=1)
                    for axis in (0, 1)]
            # A tapered solid takes no second part (`moves`); stepped, it leaves the taper.
            if shape.tapered[move.k] and shape.parts[move.k][TAPER] > 0:
                out.append(problem.refine(problem.evaluate(stepped(shape, move.k)),
                                          shape.parts[move.k][3:5].max() / 4, max_sweeps=1))
        return out
    grown = problem.evaluate(shape.added(move.part, move.kind == "solid"))
    return [_classed(problem, grown, n, max(0.02, move.part[3:5].max() / 2))]


def choose_structure(problem: Problem, fit: Fit, max_parts: int, budget: int,
                     skip: Callable[[Move], bool] = lambda move: False
                     ) -> tuple[Fit, list[Move]]:
    """Greedy moves on the shape's structure, each polished and kept where it lowers `bic`:
    dropping a part, a box around the estimate, and the `moves` the readings ask for that
    `skip` does not refuse, at most `budget` of those. Returns the fit and the moves tried
    and refused."""
    refused = []
    while True:
        shape = fit.shape
        # A part is dropped where, unrefined, it costs less than twice its parameters'
        # price: refining the rest may win the difference back; more it cannot.
        trials = [t for t in (problem.evaluate(shape.without(k)) for k in range(len(shape.solid))
                              if not shape.solid[k] or sum(shape.solid) > 1)
                  if problem.score(t) - problem.score(fit)
                  < (shape.n_params - t.shape.n_params) * math.log(len(problem))]
        # The simplest shape, a box around the estimate, is always tried again: a structure
        # chosen on the first readings must not hold on after more readings explain it away.
        # So is that box tapered (a cone or a pyramid stacked from parts).
        if len(shape.solid) > 1 or shape.rounded[0] or shape.tapered[0]:
            boxed = problem.evaluate(box_shape(shape.box(problem.table), problem.table))
            trials.append(problem.refine(boxed, 0.01))
            if len(shape.solid) > 1 and problem.taper:
                trials += [problem.reclassed(boxed, 0, r, 0.01, tapered=True) for r in TAPERED]
        asked = [m for m in moves(problem, fit, max_parts) if not skip(m)][:max(budget, 0)]
        for move in asked:
            trials += _tried(problem, fit, move, max_parts)
        budget -= len(asked)
        if not trials:
            return fit, refused
        best = min((problem.refine(t, 0.005, max_sweeps=2) for t in trials), key=problem.score)
        if problem.score(best) >= problem.score(fit) - 1e-9:
            return fit, refused + asked
        fit = best
        if budget <= 0:
            return fit, refused
