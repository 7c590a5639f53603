"""The object's box estimated from every reading so far, pose by pose: the one estimate the
stop rule watches and the report gives.

Each `estimate` refits the shape (`shape`, `fit`) from the last one (a warm start, 6 mm
around it) and, before the first or where the last estimate lies outside the object's cell
box, from the cell box (3 cm around it), keeping the lower information criterion; then it
tries the structure moves the readings ask for (all of them from a cold start, one a pose
after), and bounds each dimension by its profile interval (`interval`). A warm refit the
readings misfit while the bare table fits the model is searched again cold, from both starts:
a warm path can keep a structure the first readings chose that a cold one would not.

The misfit says how well the model explains the readings: the fit's cost per degree of
freedom over what the loss gives for noise of the model's sigma (1 for readings the model
explains), and the same for the zones that see only the bare table, which no shape explains,
so their misfit is the sensor model's alone. Where the misfit exceeds 1 every interval is
widened as a least-squares one is by the reduced chi-square: its cost rise scaled by the
misfit and its floor (half the sub-ray pitch) by the misfit's square root.
"""

from __future__ import annotations

import dataclasses as dc
import functools
import math
from collections.abc import Callable

import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation import forward
from lrnbv_drake.core.estimation.fit import Fit, Problem, choose_structure
from lrnbv_drake.core.estimation.forward import ReadingRule, ZoneRays, zone_rays
from lrnbv_drake.core.estimation.interval import intervals
from lrnbv_drake.core.estimation.params import EstimationParams
from lrnbv_drake.core.estimation.shape import Shape, box_shape, part_of_box
from lrnbv_drake.core.sensing.sensor import SensorModelParams, ToFFrame
from lrnbv_drake.core.sensing.tof_device import DeviceBehaviour


@dc.dataclass(frozen=True)
class BoxEstimate:
    """The estimated box, how sure it is, and how well the readings fit the model; the cell
    box (`of_cells`) has no interval, shape or misfit. The interval is computed the first
    time it is read (a stop rule reads it only once the box has held still)."""

    box: OrientedBox
    # What was fitted: the parts (forward.PART_SIZE numbers each) and their kinds.
    shape: Shape | None
    # Fit cost, zones fitted and the misfits (the module doc): the fit's and the table's.
    cost: float = math.nan
    n_zones: int = 0
    misfit: float = math.nan
    table_misfit: float = math.nan
    # Whether the readings misfit the model beyond what its noise allows (`misfit_limit`).
    misfit_flag: bool = False
    # The interval's confidence for one dimension: a cost rise of 2.71 is 0.90.
    confidence: float = math.nan
    # () -> (3,) lower and upper bounds of (length, width, height) at the profile level, and
    # whether no class the interval tries is the criterion's choice over the fit
    # (`interval.intervals`); None for the cell box.
    interval: Callable[[], tuple[np.ndarray, np.ndarray, bool]] | None = dc.field(
        default=None, repr=False, compare=False)

    @staticmethod
    def of_cells(box: OrientedBox) -> BoxEstimate:
        return BoxEstimate(box, None)

    @functools.cached_property
    def _bounds(self) -> tuple[np.ndarray, np.ndarray, bool] | None:
        return None if self.interval is None else self.interval()

    @property
    def dims_lower(self) -> np.ndarray | None:
        return None if self._bounds is None else self._bounds[0]

    @property
    def dims_upper(self) -> np.ndarray | None:
        return None if self._bounds is None else self._bounds[1]

    @property
    def chosen(self) -> bool | None:
        """Whether the criterion keeps the fit's class against every class the interval
        tries (a search that re-classed every part would keep this box); None without an
        interval."""
        return None if self._bounds is None else self._bounds[2]

    @property
    def widths(self) -> np.ndarray | None:
        """(3,) each dimension's interval width; None without an interval."""
        return None if self._bounds is None else self._bounds[1] - self._bounds[0]


def confidence(rise: float) -> float:
    """The probability that a chi-square of one degree of freedom stays below `rise`: how
    often a profile interval of that cost rise holds the truth where the model is right."""
    return math.erf(math.sqrt(rise / 2))


def _expected_loss(scale: float) -> float:
    """The soft-L1 loss's mean for a residual of one sigma's Gaussian noise."""
    z, w = np.polynomial.hermite_e.hermegauss(60)
    return float(np.sum(w * 2 * scale ** 2 * (np.sqrt(1 + (z / scale) ** 2) - 1))
                 / math.sqrt(2 * math.pi))


#: The misfit above which the readings are said not to be explained by the model: their
#: scatter about it more than sqrt(1.5), 1.22 times its noise. The model's own simulated
#: device leaves up to about 1.2-1.4 with the right shape (its renderer samples each
#: sub-ray up to a quarter of a sample pitch off, docs/box-estimation.md).
MISFIT_FLAG = 1.5


def misfit_limit(dof: int) -> float:
    """The misfit that flags the readings (`MISFIT_FLAG`), or that noise of the model's
    sigma exceeds with a chance of about 0.1 % (three standard deviations of a reduced
    chi-square of `dof` degrees of freedom), whichever is larger."""
    return max(MISFIT_FLAG, 1.0 + 3.0 * math.sqrt(2.0 / max(dof, 1)))


class ShapeEstimator:
    """The estimate kept up to date pose by pose (see the module doc): `add` each
    acquisition, then `estimate`."""

    def __init__(self, model: SensorModelParams, behaviour: DeviceBehaviour,
                 table_height: float, table_extent: tuple[float, float, float, float],
                 params: EstimationParams | None = None) -> None:
        self._model, self._table = model, table_height
        self._extent = np.asarray(table_extent, float)
        self._rule = ReadingRule.of(model, behaviour)
        self.params = params or EstimationParams()
        self._rays: list[ZoneRays] = []
        self._noise = _expected_loss(self.params.loss_scale)
        # The evidence (zones asking) at which each structure move was last refused: it is
        # tried again only once twice as many zones ask for it.
        self._refused: dict[tuple[str, int], int] = {}
        self.last: BoxEstimate | None = None
        # The last estimate's problem, whose kept refits the next estimate drops.
        self._last_problem: Problem | None = None

    def add(self, frame: ToFFrame, X_WS: np.ndarray) -> None:
        """Stores the valid zones of one acquisition."""
        self._rays.append(zone_rays(frame, X_WS, self._model))

    def _problem(self, boxes: list[OrientedBox]) -> Problem:
        """The zones whose sub-rays pass within `margin` of `boxes`, and the region they
        span, which the shape's solids must stay in."""
        p = self.params
        rays = ZoneRays.concatenate(self._rays, self._model.subsamples ** 2)
        keep = np.zeros(len(rays), bool)
        corners = []
        for box in boxes:
            x = part_of_box(box, self._table - p.margin)
            x[3:6] += 2 * p.margin
            keep |= rays.crossing(x, self._table - p.margin).any(axis=1)
            corners.append(OrientedBox(np.r_[x[:2], self._table - p.margin + x[5] / 2],
                                       x[3:6], x[2]).corners())
        corners = np.concatenate(corners)
        return Problem(rays.take(keep), self._table, self._extent, self._rule, p.loss_scale,
                       p.no_return, p.step, (corners.min(axis=0), corners.max(axis=0)),
                       p.search_casts, p.taper)

    def _pitch(self, problem: Problem) -> float:
        """The sub-rays' spacing at the fitted zones' median range: the objective is a
        staircase of steps about this far apart, so no side is located closer than half
        of it."""
        return float(np.median(problem.rays.measured)
                     * math.radians(self._model.geometry.zone_deg) / self._model.subsamples)

    def _table_misfit(self, shape: Shape) -> tuple[float, int]:
        """The misfit of the zones that see only the table, far from the shape, and their
        number."""
        rays = ZoneRays.concatenate(self._rays, self._model.subsamples ** 2)
        x = part_of_box(shape.box(self._table), self._table)
        x[3:6] += 2 * self.params.margin
        far = ~rays.crossing(x, self._table).any(axis=1)
        if not far.any():
            return math.nan, 0
        problem = Problem(rays.take(far), self._table, self._extent, self._rule,
                          self.params.loss_scale, self.params.no_return, self.params.step)
        costs = problem.evaluate(Shape(np.zeros((0, forward.PART_SIZE)), (), ())).costs
        return float(costs.mean() / self._noise), len(costs)

    def _search(self, problem: Problem, starts: list[tuple[Shape, float, int]],
                cold: bool) -> Fit:
        """The best of `starts` ((shape, span, sweeps) each) refined, and its structure searched:
        every move the readings ask for from a cold start, one from a warm one (the last
        estimate alone), whose refused moves are remembered."""
        fit = min((problem.refine(problem.evaluate(shape), span, max_sweeps=sweeps)
                   for shape, span, sweeps in starts), key=problem.score)
        if cold:
            self._refused = {}
        fit, refused = choose_structure(
            problem, fit, self.params.max_parts, budget=3 * self.params.max_parts if cold else 1,
            skip=lambda m: self._refused.get((m.kind, m.k), 0) * 2 >= m.evidence)
        self._refused.update({(m.kind, m.k): m.evidence for m in refused})
        return fit

    def _misfits(self, problem: Problem, fit: Fit) -> tuple[float, bool, float, bool]:
        """The fit's misfit and whether it is flagged; the same for the bare table's zones."""
        dof = len(problem) - fit.shape.n_params
        misfit = fit.cost / max(dof, 1) / self._noise
        table_misfit, n_table = self._table_misfit(fit.shape)
        return (misfit, misfit > misfit_limit(dof), table_misfit,
                table_misfit > misfit_limit(n_table))

    def estimate(self, start: OrientedBox | None = None) -> BoxEstimate | None:
        """Refits (the module doc) from the last estimate and, before the first or where
        less than half the last one's footprint lies inside `start` (the cell box, which
        mixed zones make larger than the object), from `start`; the last estimate again
        when no reading sees either. A warm refit the readings misfit while the bare table
        fits the model (so the shape, not the sensor model, is what is wrong) is searched
        again from both, cold."""
        last = self.last
        starts = []
        if last is not None:
            starts.append((last.shape, 0.006, 2))
        if start is not None and (last is None or last.box.footprint_share(start) < 0.5):
            starts.append((box_shape(start, self._table), 0.03, 4))
        if not starts or not self._rays:
            return last
        problem = self._problem([s[0].box(self._table) for s in starts])
        if len(problem) <= 9:
            return last
        cold = last is None or len(starts) > 1
        fit = self._search(problem, starts, cold)
        misfit, flag, table_misfit, table_flag = self._misfits(problem, fit)
        if flag and not table_flag and not cold and start is not None:
            # The warm fit is a start of the cold search, which keeps it unless it finds
            # a shape of lower criterion on the same zones.
            starts = [(fit.shape, 0.006, 2), (box_shape(start, self._table), 0.03, 4)]
            problem = self._problem([s[0].box(self._table) for s in starts])
            fit = self._search(problem, starts, cold=True)
            misfit, flag, table_misfit, table_flag = self._misfits(problem, fit)
        rise = self.params.interval_level * max(1.0, misfit)
        pitch = self._pitch(problem)
        floor = pitch / 2 * math.sqrt(max(1.0, misfit))
        # A zone's footprint at the same range: a side the cost keeps above the level over
        # it is bounded (`profile`).
        footprint = pitch * self._model.subsamples
        # The interval may take the search's refits of this fit, no other's, and no earlier
        # estimate's: a later read of one of those computes them again.
        problem.forget_reclassed(keep=fit)
        if self._last_problem is not None:
            self._last_problem.forget_reclassed()
        self._last_problem = problem

        def interval() -> tuple[np.ndarray, np.ndarray, bool]:
            problem.casts = 0  # the interval's own budget
            bounds = intervals(problem, fit, rise, self.params.interval_reach, floor,
                               footprint)
            problem.forget_reclassed()
            return bounds
        self.last = BoxEstimate(
            fit.shape.box(self._table), fit.shape, fit.cost, len(problem), misfit,
            table_misfit, flag or table_flag, confidence(self.params.interval_level), interval)
        return self.last
