"""Calibrating the sensor model's mixed-zone rule (docs/sensor-calibration.md): a board edge
swept across the field of view over a farther board, and the model's rule (target order,
merge distance, merged depth, min_share) that predicts what the zones the edge crosses
report. Numbers only, no files; the noise and the zone directions are
`core.calibration.sensor_model`'s."""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np

from lrnbv_drake.core.sensing.sensor import (
    STATUS_NO_TARGET,
    STATUS_VALID,
    NoiseModel,
    SensorModelParams,
    ZoneGeometry,
)
from lrnbv_drake.core.sensing.tof_device import (
    MERGED_DEPTHS,
    STATUS_MERGED,
    DeviceBehaviour,
    device_readings,
)

# --- The mixed-zone rule from a board edge swept across the field of view --------------------

#: What a zone reports in an edge sweep: nothing, the near board, the far board, or one target
#: merged from both (status 9); -1 where a frame's status says none of these.
NONE, NEAR, FAR, MERGED = 0, 1, 2, 3
OUTCOMES = ("none", "near", "far", "merged")


def edge_scene_depths(geometry: ZoneGeometry, subsamples: int, edge_deg: float,
                      near_mm: float, far_mm: float) -> np.ndarray:
    """(res, res, k, k) perpendicular depths, metres, row-major, over each zone's sub-samples
    of a near board covering the angles x >= `edge_deg` in front of a far board."""
    ax = geometry.sub_angles_xy_rad(subsamples)[..., 0]
    return np.where(ax >= math.radians(edge_deg), near_mm, far_mm) / 1000.0


def near_share(geometry: ZoneGeometry, subsamples: int, edge_deg: np.ndarray) -> np.ndarray:
    """(n, res, res) share of each zone's sub-samples on the near board, per edge angle."""
    ax = geometry.sub_angles_xy_rad(subsamples)[..., 0]
    edge = np.radians(np.asarray(edge_deg, float))[:, None, None, None, None]
    return (ax[None] >= edge).mean(axis=(-2, -1))


def outcomes(distance_mm: np.ndarray, status: np.ndarray, near_mm: np.ndarray,
             far_mm: np.ndarray) -> np.ndarray:
    """What each reading says (NONE, NEAR, FAR or MERGED; -1 for other statuses): status 9 is
    a merged target, status 5 the board whose depth it is nearer."""
    near = np.asarray(near_mm, float)
    far = np.asarray(far_mm, float)
    nearer = np.abs(distance_mm - near) < np.abs(distance_mm - far)
    out = np.full(np.shape(status), -1, np.int8)
    out[status == STATUS_NO_TARGET] = NONE
    out[(status == STATUS_VALID) & nearer] = NEAR
    out[(status == STATUS_VALID) & ~nearer] = FAR
    out[status == STATUS_MERGED] = MERGED
    return out


@dc.dataclass(frozen=True)
class EdgeSteps:
    """An edge sweep reduced to one observation per edge position and zone.

    Attributes:
        edge_deg, near_mm, far_mm: (m,) the geometry of each step.
        observed: (m, res, res) the outcome most of the step's frames report (-1 where no
            frame's status says, or two outcomes tie: the zone flickers between them there,
            and neither is what it reports).
        merged_mm: (m, res, res) mean depth of the frames reporting a merged target (NaN where
            none does).
    """

    edge_deg: np.ndarray
    near_mm: np.ndarray
    far_mm: np.ndarray
    observed: np.ndarray
    merged_mm: np.ndarray


def edge_steps(distance_mm: np.ndarray, status: np.ndarray, edge_deg: np.ndarray,
               near_mm: np.ndarray, far_mm: np.ndarray) -> EdgeSteps:
    """Groups an edge sweep's frames (row-major, with each frame's geometry) by step."""
    geometry = np.stack([np.asarray(v, float) for v in (edge_deg, near_mm, far_mm)], axis=-1)
    steps, index = np.unique(geometry, axis=0, return_inverse=True)
    seen = outcomes(distance_mm, status, geometry[:, 1, None, None], geometry[:, 2, None, None])
    votes = np.zeros((len(steps), *status.shape[1:], len(OUTCOMES)))
    for o in range(len(OUTCOMES)):
        np.add.at(votes[..., o], index.ravel(), seen == o)
    merged = seen == MERGED
    total = np.zeros(votes.shape[:-1])
    np.add.at(total, index.ravel(), np.where(merged, distance_mm, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        merged_mm = total / votes[..., MERGED]
    top = votes.max(axis=-1)
    single = (votes == top[..., None]).sum(axis=-1) == 1
    observed = np.where((top > 0) & single, votes.argmax(axis=-1), -1)
    return EdgeSteps(steps[:, 0], steps[:, 1], steps[:, 2], observed, merged_mm)


def predict_edge(steps: EdgeSteps, params: SensorModelParams, behaviour: DeviceBehaviour
                 ) -> tuple[np.ndarray, np.ndarray]:
    """What the model (`params`, `behaviour`; its noise left out) reports at each step:
    (outcomes, depths in mm), each (m, res, res) row-major."""
    params = dc.replace(params, noise=NoiseModel(0.0, 0.0))
    geometry, k = params.geometry, params.subsamples
    rng = np.random.default_rng(0)  # draws multiplied by a zero sigma: unused
    depth, status = [], []
    for e, n, f in zip(steps.edge_deg, steps.near_mm, steps.far_mm, strict=True):
        frame = device_readings(edge_scene_depths(geometry, k, e, n, f), params, behaviour, rng)
        depth.append(geometry.to_row_major(frame.distance_mm))
        status.append(geometry.to_row_major(frame.status))
    depth, status = np.array(depth, float), np.array(status)
    return outcomes(depth, status, steps.near_mm[:, None, None],
                    steps.far_mm[:, None, None]), depth


@dc.dataclass(frozen=True)
class MixedZoneFit:
    """The model's rule for a zone that sees two surfaces, fitted to an edge sweep.

    Attributes:
        target_order, merge_mm, merged_depth, min_share: the rule (`SensorConfig`'s fields).
        merge_bounds_mm: the separations the sweeps bracket merge_mm with: the largest that
            merged and the smallest that did not (0 and inf where none did or all did).
        agreement: share of the mixed zones (both boards in the footprint) whose outcome the
            rule predicts, over every step.
        zones: mixed zones (zone and step pairs) with an outcome.
        merged_rms_mm: rms between observed and predicted depth of the merged zones, per
            `MERGED_DEPTHS` rule (NaN where none merged).
        candidates: agreement of each (target_order, merge_mm) rule tried.
        warning: set when the sweeps do not pin a parameter down.
    """

    target_order: str
    merge_mm: float
    merged_depth: str
    min_share: float
    merge_bounds_mm: tuple[float, float]
    agreement: float
    zones: int
    merged_rms_mm: dict[str, float]
    candidates: dict[tuple[str, float], float]
    warning: str = ""


def fit_min_share(share: np.ndarray, observed: np.ndarray, default: float) -> float:
    """The share above which a zone reports the near board, from zones that report either
    board alone: the threshold between two observed shares that misclassifies fewest, at
    most 0.5. The model's rule asks the nearest surface holding `min_share` of the zone, the
    same of both boards: above 0.5 neither holds it between 1 - min_share and min_share, and
    the model predicts no target where the device reports the far board (a device switching
    at 0.75: a fit of 0.69 agreed on 54 % of the mixed zones, 0.5 on 69 %)."""
    keep = (observed == NEAR) | (observed == FAR)
    s, near = share[keep], observed[keep] == NEAR
    if not (near.any() and (~near).any()):
        return default
    levels = np.unique(s)
    cuts = np.concatenate([[levels[0] / 2], (levels[:-1] + levels[1:]) / 2,
                           [(levels[-1] + 1) / 2]])
    errors = [np.sum(near != (s >= t)) for t in cuts]
    return min(float(cuts[int(np.argmin(errors))]), 0.5)


def fit_mixed_zone_rule(steps: EdgeSteps, params: SensorModelParams) -> MixedZoneFit:
    """The model's rule (target order, merge distance, merged depth, min_share) that predicts
    most of the mixed zones' outcomes in an edge sweep.

    Every rule the sweeps can tell apart is tried with the model's own reduction
    (`predict_edge` on `edge_scene_depths`, the zones' sub-samples being near or far by the
    known edge): the nearest surface holding `min_share` (fitted as the share where zones turn
    to the near board), or the closest or strongest target with surfaces merging below each
    merge distance the sweeps' separations bracket. Agreement counts only zones whose
    sub-samples see both boards: the rest say nothing about mixing. Among rules that merge,
    the merged depth is the one nearest the observed merged depths.

    Args:
        steps: from `edge_steps`, row-major.
        params: the model: zone geometry (calibrated directions where known), sub-samples,
            surface gap; its `min_share` where the sweeps cannot fit it.
    """
    geometry, k = params.geometry, params.subsamples
    share = near_share(geometry, k, steps.edge_deg)
    mixed = (share > 0) & (share < 1) & (steps.observed >= 0)
    if not mixed.any():
        raise ValueError("no zone saw both boards in the edge sweep: sweep the edge across "
                         "the field of view")
    separations = np.unique(steps.far_mm - steps.near_mm)
    if separations[0] <= 0:
        raise ValueError("the edge sweep's near board must be nearer than its far board")
    merges = [0.0, *((separations[:-1] + separations[1:]) / 2).tolist(),
              1.5 * float(separations[-1])]
    min_share = fit_min_share(share[mixed], steps.observed[mixed], params.min_share)
    candidates, predictions = {}, {}
    rules = [("closest", 0.0)] + [(order, m) for order in ("closest", "strongest")
                                  for m in merges if (order, m) != ("closest", 0.0)]
    model = dc.replace(params, min_share=min_share)
    for order, m in rules:  # at the default merged depth: the outcomes do not depend on it
        predictions[(order, m)] = predict_edge(steps, model, DeviceBehaviour(target_order=order,
                                                                             merge_mm=m))
        candidates[(order, m)] = float(np.mean(predictions[(order, m)][0][mixed]
                                               == steps.observed[mixed]))
    order, merge = max(rules, key=lambda r: candidates[r])  # the first best: simplest
    rms = {}
    predicted, default_depth = predictions[(order, merge)]
    both = mixed & (steps.observed == MERGED) & (predicted == MERGED)
    for rule in MERGED_DEPTHS:
        if merge == 0 or not both.any():
            rms[rule] = math.nan
            continue
        depth = (default_depth if rule == DeviceBehaviour().merged_depth else predict_edge(
            steps, model, DeviceBehaviour(target_order=order, merge_mm=merge,
                                          merged_depth=rule))[1])
        rms[rule] = float(np.sqrt(np.mean((depth[both] - steps.merged_mm[both]) ** 2)))
    merged_depth = (min(MERGED_DEPTHS, key=lambda r: rms[r]) if both.any() and merge > 0
                    else MERGED_DEPTHS[0])
    below = separations[separations < merge]
    above = separations[separations > merge]
    bounds = (float(below.max()) if below.size else 0.0,
              float(above.min()) if above.size else math.inf)
    warning = ""
    if merge > separations[-1]:
        warning = (f"every sweep merged: merge_mm is only known to exceed {separations[-1]:.0f} "
                   f"mm; sweep with a larger separation of the boards")
    elif merge > 0 and not both.any():
        warning = "no merged zone to fit merged_depth with"
    return MixedZoneFit(order, float(merge), merged_depth, min_share, bounds,
                        candidates[(order, merge)], int(mixed.sum()), rms, candidates, warning)
