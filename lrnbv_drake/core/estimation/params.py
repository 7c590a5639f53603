"""The estimator's settings: the scenario's `estimation:` section.

No `from __future__ import annotations` here: Drake's YAML loader reads the fields' types.
"""

import dataclasses as dc


@dc.dataclass
class EstimationParams:
    """The estimator's settings (`estimation:` in a scenario); lengths in metres."""

    # Soft-L1 scale of a zone's residual, sigmas: beyond it a zone counts linearly, so a
    # reading of something else (the arm, a neighbour) cannot drag the shape.
    loss_scale: float = 2.0
    # Residual, sigmas, of a zone the shape predicts no return for.
    no_return: float = 5.0
    # Zones whose sub-rays pass within this of the estimate or the cell box are fitted, and
    # the shape may grow this far beyond them in one pose.
    margin: float = 0.06
    # Most parts (solids and holes) a shape may have.
    max_parts: int = 4
    # Finest step of the search's sides and tops.
    step: float = 0.0005
    # Cost rise that bounds a dimension's interval (2.71: 90 % for one degree of freedom),
    # scaled by the misfit where the readings misfit the model.
    interval_level: float = 2.71
    # Farthest an interval reaches beyond the estimate on a side no reading bounds.
    interval_reach: float = 0.1
    # Sub-ray casts a search (and, apart, an interval) may make before it keeps the best
    # shape it has (`fit.Problem`): about 25 s on one core, so that a shape the model
    # cannot draw does not hold the cell for minutes a pose.
    search_casts: float = 5e8
    # Whether the shape's one solid may taper (a cone, a pyramid, a bucket, a cup; records
    # 0039 and 0040).
    taper: bool = True
