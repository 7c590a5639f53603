"""OctoMap's sensor model: the update probabilities, and their float32 log-odds as OctoMap
stores them, which the kernels add."""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np


def logodds(probability: float) -> np.float32:
    """Log-odds of a probability, rounded to float32 exactly as OctoMap stores it."""
    return np.float32(math.log(probability / (1.0 - probability)))


@dc.dataclass(frozen=True)
class OccupancyUpdate:
    """OctoMap's occupancy update parameters (probabilities), OctoMap's defaults.

    Args:
        prob_hit: probability of occupancy applied for a ray endpoint.
        prob_miss: probability applied to cells a ray passes through.
        clamp_min: lower clamp of a cell's probability.
        clamp_max: upper clamp.
        occupancy_threshold: a cell is occupied when its probability is at least this.
    """

    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    occupancy_threshold: float = 0.5

    def __post_init__(self) -> None:
        probs = (self.prob_hit, self.prob_miss, self.clamp_min, self.clamp_max,
                 self.occupancy_threshold)
        if not all(0.0 < p < 1.0 for p in probs):
            raise ValueError(f"OccupancyUpdate probabilities must be in (0, 1); got {self}")
        if not (self.clamp_min < self.clamp_max and self.prob_miss < 0.5 < self.prob_hit):
            raise ValueError(f"OccupancyUpdate needs clamp_min < clamp_max and miss < 0.5 < hit; "
                             f"got {self}")

    def log_odds_array(self) -> np.ndarray:
        """(5,) float32 [hit, miss, clamp_min, clamp_max, threshold] log-odds, for the kernels."""
        return np.array([logodds(self.prob_hit), logodds(self.prob_miss),
                         logodds(self.clamp_min), logodds(self.clamp_max),
                         logodds(self.occupancy_threshold)], dtype=np.float32)
