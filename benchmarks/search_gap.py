"""How far the structure search's fit of a recorded episode is from the best the shape model
can do on the same readings (records 0031, 0041, 0042), for the objects whose true structure
the model draws: the paper flange, the pouch, the three balls and the ellipsoids (the
family's ball, fruit and melon).

In the shape model's terms the paper flange (models/objects/generate_objects.py) is a plate
(an upright cylinder 200 mm across, 20 mm high), a hub (an upright cylinder, here the 99.5
mm mean of its 110-88.9 mm taper, 50 mm high) and a bore (a cylindrical hole 82.5 mm
across), all on the object's centre; the pouch (`object_family`) one part, its true box
with the rounding (0.5 / 0.62)^2 across and 1 up (an ellipsoid 1.24 times its box's sides
across, cut by the box); the balls three spheres of the true height, on the centres of the
mesh's three clusters of vertices; an ellipsoid one part rounded (1, 1, 1) in its true
box. For each episode the estimate is refitted from its
frames as the episode made it (`lrnbv refit`'s), then the fit and that structure, refined
from the drawing by the estimator's own coordinate search, are scored on the same zones
(the estimator's problem around the true box: every valid zone whose sub-rays pass within
`estimation.margin` of it, its parts kept within the region they span) by the estimator's
information criterion: a structure that scores lower and whose box is nearer the truth is
one the search did not find. Beside them: the best re-class of a part of the fit (the class
move's re-class alone, without its cuts and last polish), the fit with every part an
upright cylinder at once, refined, and the best of the fit's rounded parts cut tighter
(`cut_tighter`), refined, with the share of its gain over the fit that comes from mixed
zones (those whose sub-rays, in either shape, meet both the shape and what lies behind it).

    .venv/bin/python benchmarks/search_gap.py out/results/paper/runs/lrnbv__flange__* \
        out/results/held_out/runs/lrnbv__{pouch,balls}__* out/results/family/runs/lrnbv__melon__*
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import scipy.cluster.vq

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation.fit import Fit, Problem, classings
from lrnbv_drake.core.estimation.shape import HOLE_HEIGHT, ROUNDINGS, Shape
from lrnbv_drake.core.evaluation.objects import load_object_mesh
from lrnbv_drake.core.evaluation.shape_classes import POUCH_BULGE
from lrnbv_drake.experiments.refit import load_episode
from lrnbv_drake.station.parts import episode_estimator

UPRIGHT_CYLINDER = ROUNDINGS[0]
#: (diameter, height, solid) of the plate, the hub and the bore, metres.
FLANGE = ((0.200, 0.020, True), (0.0995, 0.050, True), (0.0825, HOLE_HEIGHT, False))


def flange_shape(true: OrientedBox) -> Shape:
    """The flange's structure (`FLANGE`) standing on the table at the true box's centre."""
    parts = np.array([[*true.center[:2], 0.0, d, d, h, *UPRIGHT_CYLINDER, 0.0]
                      for d, h, _ in FLANGE])
    return Shape(parts, (True,) * len(FLANGE), tuple(s for *_, s in FLANGE))


def pouch_shape(true: OrientedBox) -> Shape:
    """The pouch: its true box cut by its ellipsoid (`POUCH_BULGE` of its sides across)."""
    across = (0.5 / POUCH_BULGE) ** 2
    return Shape(np.array([[*true.center[:2], true.yaw, *true.dims, across, across, 1.0, 0.0]]),
                 (True,), (True,))


def balls_shape(true: OrientedBox) -> Shape:
    """The three balls: spheres of the true height on the mesh's three clusters of
    vertices, turned and moved as the true box is."""
    centres, _ = scipy.cluster.vq.kmeans2(load_object_mesh("balls").vertices[:, :2], 3,
                                          seed=0, minit="++")
    c, s = np.cos(true.yaw), np.sin(true.yaw)
    world = true.center[:2] + centres @ np.array([[c, s], [-s, c]])
    d = true.dims[2]
    parts = np.array([[x, y, 0.0, d, d, d, 1.0, 1.0, 1.0, 0.0] for x, y in world])
    return Shape(parts, (True,) * 3, (True,) * 3)


def ellipsoid_shape(true: OrientedBox) -> Shape:
    """An ellipsoid in the true box."""
    return Shape(np.array([[*true.center[:2], true.yaw, *true.dims, 1.0, 1.0, 1.0, 0.0]]),
                 (True,), (True,))


def mixed(problem: Problem, fit: Fit) -> np.ndarray:
    """(zones,) whether some but not all of a zone's sub-rays meet the fit's shape."""
    on = fit.depths < problem.base - 1e-9
    return on.any(axis=1) & ~on.all(axis=1)


#: The scales of a rounded part's box cut tighter about its quadric (`cut_tighter`).
CUTS = (0.95, 0.9, 0.85, 0.8)


def cut_tighter(shape: Shape, k: int, scale: float) -> Shape:
    """Part k's box scaled by `scale` across each rounded horizontal axis, its rounding there
    by scale^2: the same quadric cut by a tighter box (a joint move of a side and the
    rounding, which the coordinate search makes one at a time)."""
    x = shape.parts[k].copy()
    for axis in (0, 1):
        if x[6 + axis] > 0:
            x[3 + axis] *= scale
            x[6 + axis] *= scale ** 2
    return shape.with_part(k, x)


#: The true structure by object name.
STRUCTURES = {"flange": flange_shape, "pouch": pouch_shape, "balls": balls_shape,
              "ball": ellipsoid_shape, "fruit": ellipsoid_shape, "melon": ellipsoid_shape}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path)
    args = parser.parse_args()
    for folder in args.folders:
        episode = load_episode(folder)
        scenario, true = episode.scenario, episode.true
        name = scenario.object.name
        if name not in STRUCTURES:
            raise SystemExit(f"{folder}: object {name!r}; expected one of {sorted(STRUCTURES)}")
        tracked = episode_estimator(scenario)
        fitted = tracked.update(episode.readings, episode.cell_boxes, final=True).latest
        table = scenario.cell.table_height
        # The same estimator's problem around the true box: its zones and the region its
        # parts must stay in.
        problem = tracked._estimator._problem([true])
        fit = problem.evaluate(fitted.shape)
        drawn = problem.refine(problem.evaluate(STRUCTURES[name](true)), 0.006)
        # The class move's re-class of each part of the fit alone, and every part made an
        # upright cylinder of its footprint at once.
        single = min(problem.score(f) for k in range(len(fit.shape.solid))
                     for f in classings(problem, fit, k, 0.01))
        round_all = fit.shape
        for k, x in enumerate(fit.shape.parts):
            round_all = round_all.with_part(k, np.r_[x[:6], UPRIGHT_CYLINDER, 0.0], rounded=True,
                                            tapered=False)
        round_all = problem.refine(problem.evaluate(round_all), 0.006)
        cut = min((problem.refine(problem.evaluate(cut_tighter(fit.shape, k, scale)), 0.006)
                   for k in range(len(fit.shape.solid)) if fit.shape.rounded[k]
                   for scale in CUTS), key=problem.score, default=fit)
        gain = fit.costs - cut.costs
        print(f"{folder.name}: {len(problem)} zones; the search's fit ({fitted.shape.name()}) "
              f"criterion {problem.score(fit):.1f}, worst error "
              f"{1000 * np.abs(fitted.box.dims - true.dims).max():.1f} mm; its best single "
              f"re-class {single:.1f}; every part round {problem.score(round_all):.1f}; the "
              f"rounded part cut tighter {problem.score(cut):.1f}, worst error "
              f"{1000 * np.abs(cut.shape.box(table).dims - true.dims).max():.1f} mm; the "
              f"drawing's structure refined {problem.score(drawn):.1f}, worst error "
              f"{1000 * np.abs(drawn.shape.box(table).dims - true.dims).max():.1f} mm; of "
              f"the cut's cost gain over the fit {gain.sum():.1f}, mixed zones "
              f"{gain[mixed(problem, fit) | mixed(problem, cut)].sum():.1f}", flush=True)


if __name__ == "__main__":
    main()
