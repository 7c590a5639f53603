"""Each dimension's interval: the farthest each side of the box moves with the cost within a
set amount of the lowest found (a profile of the same objective the fit minimises),
widened to hold the box of every other class of a part that the readings fit within it.

The moves hold the shape's class where it is, so they alone would leave out a shape the
readings explain as well but the information criterion did not afford (a fruit fitted as a
box 1-2 cm smaller than the ellipsoid it is): which class is right is as uncertain as the
cost says, not as the criterion's choice says."""

from __future__ import annotations

import dataclasses as dc
import math
from collections.abc import Callable

import numpy as np

from lrnbv_drake.core.estimation.fit import Fit, Problem, classings
from lrnbv_drake.core.estimation.forward import NO_CLIP
from lrnbv_drake.core.estimation.shape import TAPER, TOP, Shape, moved, part_of_box


def profile(cost: Callable[[float], float], reach: float, rise: float, best: float,
            step: float, span: float) -> float:
    """The farthest a move can go, at most `reach`, with `cost(move)` within `rise` of the
    lowest cost met: scanned every `step` until the moves since the farthest one within
    span more than `span` (or `reach` is met), then bisected between that move and the next
    scanned to a 0.5 mm bracket, whose middle is returned. The objective is a staircase,
    not monotone in a move: a zone flipping as a side crosses its sub-rays can rise above
    the level a step before the cost falls back, so the first move that rises does not
    bound the side; a rise held over about a zone's footprint (`span`) does. The level is
    the lowest cost met, not `best`, as a cost that falls before it rises bounds nothing."""
    if not (step > 0 and span >= 0):
        raise ValueError(f"profile needs step > 0 and span >= 0; got step {step}, span {span}")
    moves: list[float] = []
    costs: list[float] = []
    while True:
        moves.append(min(step * (len(moves) + 1), reach))
        costs.append(cost(moves[-1]))
        lowest = min(best, min(costs))
        within = [i for i, c in enumerate(costs) if c - lowest < rise]
        inside = moves[within[-1]] if within else 0.0
        if moves[-1] >= reach or moves[-1] - inside > span:
            break
    if within and within[-1] == len(moves) - 1:
        return reach
    outside = moves[within[-1] + 1] if within else moves[0]
    while outside - inside > 0.0005:
        mid = (inside + outside) / 2
        c = cost(mid)
        lowest = min(lowest, c)
        if c - lowest >= rise:
            outside = mid
        else:
            inside = mid
    return (inside + outside) / 2


def _extended(shape: Shape, direction: np.ndarray, support: float, value: float) -> Shape:
    """`shape` with every solid reaching `support` along the horizontal `direction` (within
    a millimetre) extended by `value` along it, each along its side most aligned with it."""
    for k, x in enumerate(shape.parts):
        if not shape.solid[k]:
            continue
        alone = Shape(x[None], (True,), (True,))
        if float(np.max(alone.footprint() @ direction)) < support - 0.001:
            continue
        c, s = math.cos(x[2]), math.sin(x[2])
        along = np.array([c * direction[0] + s * direction[1],
                          -s * direction[0] + c * direction[1]])
        axis = int(np.argmax(np.abs(along)))
        shape = shape.with_part(k, moved(x, 2 * axis + (1 if along[axis] > 0 else 0),
                                         value / abs(along[axis])))
    return shape


def intervals(problem: Problem, fit: Fit, rise: float, reach: float, floor: float,
              span: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """(lower, upper) of the box's length, width and height over the shapes whose cost lies
    within `rise` of the lowest found: the fit and each solid part re-classed (`classings`,
    searched within a centimetre), each shape's `slice_bounds` to the rise left above its
    own cost; and whether the fit is the criterion's choice among them (`Problem.score`).
    The level is the lowest cost's, as a profile's is the best fit's: a class the criterion
    did not afford may explain the readings better than the fit, and the fit's cost would
    then let every shape rise by that difference too. The fit's box is always held (within
    `floor` a side), even where such a class leaves it no rise. `span`: `slice_bounds`'."""
    shape = fit.shape
    others = [other for k in range(len(shape.solid)) if shape.solid[k]
              # A box part's own class is the fit: only a rounded or tapered part is tried
              # as a box.
              for other in classings(problem, fit, k, 0.01,
                                     box=shape.rounded[k] or shape.tapered[k])]
    level = min([fit.cost] + [other.cost for other in others]) + rise
    # The fit's box with `slice_bounds`' floor on each side (the top's alone on the height).
    dims, sides = shape.box(problem.table).dims, floor * np.array([2.0, 2.0, 1.0])
    lower, upper = dims - sides, dims + sides
    for trial in [fit, *others]:
        left = level - trial.cost
        if left > 0.0:
            low, high = slice_bounds(problem, trial, left, reach, floor, span)
            lower, upper = np.minimum(lower, low), np.maximum(upper, high)
    chosen = all(problem.score(other) >= problem.score(fit) for other in others)
    return np.maximum(lower, 0.0), upper, chosen


def slice_bounds(problem: Problem, fit: Fit, rise: float, reach: float, floor: float,
                 span: float) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of the box's length, width and height: how far each of its sides can
    move in (every solid clipped by it) and out (the solids that reach it extended, a part
    narrowing upward raised along its faces), the rest held, with the cost within `rise`
    (`profile`, scanned every two floors: the sub-ray pitch, widened by the misfit as the
    floor is; `span` about a zone's footprint), and at least `floor`. Each move re-evaluates
    only the zones crossing the slab it can sweep."""
    shape = fit.shape
    box = shape.box(problem.table)
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    moves_in, moves_out = np.zeros(5), np.zeros(5)
    for i in range(5):
        slab = part_of_box(box, problem.table)
        if i == TOP:
            normal, support = np.array([0.0, 0.0, 1.0]), problem.table + box.dims[2]
            slab[3:5] += 2 * reach
            slab[5] = 2 * reach
            bottom = support - reach
        else:
            axis = np.array([c, s]) if i < 2 else np.array([-s, c])
            normal = np.r_[axis if i % 2 else -axis, 0.0]
            support = float(normal[:2] @ box.center[:2]) + box.dims[i // 2] / 2
            slab[:2] = box.center[:2] + normal[:2] * (box.dims[i // 2] / 2)
            slab[3 + i // 2] = 2 * reach
            slab[4 - i // 2] += 2 * reach
            slab[5] += reach
            bottom = problem.table
        zones = np.flatnonzero(problem.rays.crossing(slab, bottom).any(axis=1))
        base = fit.cost - float(fit.costs[zones].sum())

        def cost(trial: Shape, clip: np.ndarray = NO_CLIP, zones=zones, base=base) -> float:
            return base + problem.evaluate(trial, clip, zones).cost

        def inward(value: float, normal=normal, support=support, cost=cost) -> float:
            return cost(shape, np.r_[normal, support - value])

        def outward(value: float, normal=normal, support=support, i=i, cost=cost) -> float:
            if i != TOP:
                return cost(_extended(shape, normal[:2], support, value))
            parts = shape.parts.copy()
            tall = np.array(shape.solid) & (parts[:, 5] >= box.dims[2] - 0.001)
            # A part narrowing upward rises along its faces, its taper growing with it.
            narrowing = tall & (parts[:, TAPER] > 0.0)
            parts[narrowing, TAPER] = np.minimum(
                parts[narrowing, TAPER] * (1.0 + value / parts[narrowing, 5]), 1.0)
            parts[tall, 5] += value
            return cost(dc.replace(shape, parts=parts))

        moves_in[i] = max(profile(inward, reach, rise, fit.cost, 2 * floor, span), floor)
        moves_out[i] = max(profile(outward, reach, rise, fit.cost, 2 * floor, span), floor)

    def pairs(v: np.ndarray) -> np.ndarray:
        return np.array([v[0] + v[1], v[2] + v[3], v[4]])
    return np.maximum(box.dims - pairs(moves_in), 0.0), box.dims + pairs(moves_out)
