"""How far the structure search's fit of a recorded flange episode is from the best the
shape model can do on the same readings (record 0031).

The paper flange (models/objects/generate_objects.py) is, in the shape model's terms, a
plate (an upright cylinder 200 mm across, 20 mm high), a hub (an upright cylinder, here
the 99.5 mm mean of its 110-88.9 mm taper, 50 mm high) and a bore (a cylindrical hole
82.5 mm across), all on the object's centre. For each episode the estimate is refitted
from its frames as the episode made it (`lrnbv refit`'s), then the fit and that structure,
refined from the drawing by the estimator's own coordinate search, are scored on the same
zones (the estimator's problem around the true box: every valid zone whose sub-rays pass
within `estimation.margin` of it, its parts kept within the region they span) by the
estimator's information criterion: a structure that scores lower and whose box is nearer
the truth is one the search did not find. Beside them: the best re-class of a part of the
fit (the class move's re-class alone, without its cuts and last polish), and the fit with
every part an upright cylinder at once, refined.

    .venv/bin/python benchmarks/flange_search_gap.py out/results/paper/runs/lrnbv__flange__*
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lrnbv_drake.core.estimation.fit import classings
from lrnbv_drake.core.estimation.shape import HOLE_HEIGHT, ROUNDINGS, Shape
from lrnbv_drake.experiments.refit import load_episode
from lrnbv_drake.station.parts import episode_estimator

UPRIGHT_CYLINDER = ROUNDINGS[0]
#: (diameter, height, solid) of the plate, the hub and the bore, metres.
FLANGE = ((0.200, 0.020, True), (0.0995, 0.050, True), (0.0825, HOLE_HEIGHT, False))


def flange_shape(centre: np.ndarray) -> Shape:
    """The flange's structure (`FLANGE`) standing on the table at `centre` (x, y)."""
    parts = np.array([[*centre, 0.0, d, d, h, *UPRIGHT_CYLINDER] for d, h, _ in FLANGE])
    return Shape(parts, (True,) * len(FLANGE), tuple(s for *_, s in FLANGE))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path)
    args = parser.parse_args()
    for folder in args.folders:
        episode = load_episode(folder)
        scenario, true = episode.scenario, episode.true
        tracked = episode_estimator(scenario)
        fitted = tracked.update(episode.readings, episode.cell_boxes, final=True).latest
        table = scenario.cell.table_height
        # The same estimator's problem around the true box: its zones and the region its
        # parts must stay in.
        problem = tracked._estimator._problem([true])
        fit = problem.evaluate(fitted.shape)
        drawn = problem.refine(problem.evaluate(flange_shape(true.center[:2])), 0.006)
        # The class move's re-class of each part of the fit alone, and every part made an
        # upright cylinder of its footprint at once.
        single = min(problem.score(f) for k in range(len(fit.shape.solid))
                     for f in classings(problem, fit, k, 0.01))
        round_all = fit.shape
        for k, x in enumerate(fit.shape.parts):
            round_all = round_all.with_part(k, np.r_[x[:6], UPRIGHT_CYLINDER], rounded=True)
        round_all = problem.refine(problem.evaluate(round_all), 0.006)
        print(f"{folder.name}: {len(problem)} zones; the search's fit ({fitted.shape.name()}) "
              f"criterion {problem.score(fit):.1f}, worst error "
              f"{1000 * np.abs(fitted.box.dims - true.dims).max():.1f} mm; its best single "
              f"re-class {single:.1f}; every part round {problem.score(round_all):.1f}; the "
              f"drawing's structure refined {problem.score(drawn):.1f}, worst error "
              f"{1000 * np.abs(drawn.shape.box(table).dims - true.dims).max():.1f} mm",
              flush=True)


if __name__ == "__main__":
    main()
