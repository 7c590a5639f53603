"""report.json: what an episode did, the same fields for a simulated episode and a session on
the real cell (docs/metrics.md lists them); the simulation adds metrics against the true
object, the real cell its hardware state."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from pydrake.common.yaml import yaml_dump_typed

from lrnbv_drake.core.acquisition import EpisodeLog, cycle_time
from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.estimation.estimator import BoxEstimate
from lrnbv_drake.core.estimation.track import EstimateTrack
from lrnbv_drake.core.evaluation import metrics
from lrnbv_drake.core.evaluation.objects import PlacedObject, sample_surface
from lrnbv_drake.core.evaluation.packing import PackingDecision, packing_metrics
from lrnbv_drake.core.mapping.extraction import found_box
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.station.parts import container_catalogue, episode_estimator
from lrnbv_drake.station.scenario import Scenario

#: Spacing of the surface samples the coverage metric counts, metres (threshold / 2).
COVERAGE_SPACING = 0.005


#: Decimals of every float in report.json: a nanometre or a nanosecond, so that 0.3 reads
#: 0.3 and not 0.30000000000000004.
REPORT_DECIMALS = 9


def rounded(value: Any) -> Any:
    """`value` with every float rounded to REPORT_DECIMALS (and -0.0 written 0.0)."""
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [rounded(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return round(float(value), REPORT_DECIMALS) + 0.0
    return value.item() if isinstance(value, np.generic) else value


def json_default(value: Any) -> Any:
    """For json.dumps: numpy arrays and scalars as plain lists and numbers."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot record a {type(value).__name__} in JSON")


def _final_extraction(episode_log: EpisodeLog):
    return episode_log.extractions[-1] if episode_log.extractions else None


def estimate_readings(scenario: Scenario, readings: Sequence[tuple[ToFFrame, np.ndarray]],
                      cell_boxes: Sequence[OrientedBox | None]) -> EstimateTrack:
    """The estimate track `extraction.estimator` gives for every (frame, X_WS) of
    `readings`, the cell box after reading i being `cell_boxes[i]`: what the episode's
    `BoxEstimation` system computed, again."""
    return episode_estimator(scenario).update(readings, cell_boxes, final=True)


def errors_after_each_pose(track: EstimateTrack, true: OrientedBox) -> np.ndarray:
    """(n_poses, 3) estimate - truth of the dimensions after each pose: the estimate the
    episode had then (the last row is the reported box's error); NaN before an object is
    found."""
    return np.array([np.full(3, np.nan) if e is None else e.box.dims - true.dims
                     for e in track.estimates]).reshape(-1, 3)


def episode_report(planner: str, scenario: Scenario, episode_log: EpisodeLog,
                   track: EstimateTrack, decision: PackingDecision | None, *,
                   termination: str, wall_seconds: float, sim_seconds: float,
                   map_update_seconds: list[float], report_seconds: float = 0.0
                   ) -> dict[str, Any]:
    """The fields every report has: settings, the estimated box (the last of `track`) and
    its container `decision`, every pose, timings. `report_seconds`: the estimation the loop
    did not already time (the estimates folded in after it ended)."""
    final = _final_extraction(episode_log)
    estimate = track.latest
    cells = found_box(final)
    cycle = cycle_time(episode_log, other_computation=(
        sum(map_update_seconds) + sum(episode_log.clustering_seconds) + report_seconds))
    return {
        "planner": planner,
        "object": scenario.object.name,
        "object_scale": scenario.object.scale,
        "object_pose": [scenario.object.x, scenario.object.y, scenario.object.yaw_deg],
        "seed": scenario.seed,
        "termination": termination,
        "n_poses": len(episode_log.acquisitions),
        "estimated_box": box_entry(scenario, estimate),
        "container": container_entry(decision),
        "cycle_time": {"motion_s": cycle.motion, "settle_s": cycle.settle,
                       "computation_s": cycle.computation, "total_s": cycle.total},
        "extraction": final.reason if final is not None else "no extraction",
        "cell_box": _cell_box_entry(cells),
        "poses": [{
            "index": a.index,
            "time": a.time,
            "q": a.q.tolist(),
            "X_WS": a.X_WS.tolist(),
            "n_valid_zones": int(a.frame.valid.sum()),
            "info": a.info,
        } for a in episode_log.acquisitions],
        "motion_failures": [{"time": t, "position": X[:3, 3].tolist(), "failure": f,
                             "reason": r} for t, X, f, r in episode_log.motion_failures],
        "timing": {
            "wall_seconds": wall_seconds,
            "simulated_seconds": sim_seconds,
            "planning_steps": [{"policy_s": p, "motion_planning_s": m}
                               for p, m in zip(episode_log.policy_seconds,
                                               episode_log.motion_seconds, strict=False)],
            "tree_expansion_s": [a.info["tree_expansion_s"] for a in episode_log.acquisitions
                                 if "tree_expansion_s" in a.info],
            "cache_reevaluation_s": [a.info["cache_reevaluation_s"]
                                     for a in episode_log.acquisitions
                                     if "cache_reevaluation_s" in a.info],
            "map_update_s": list(map_update_seconds),
            "clustering_s": episode_log.clustering_seconds,
            "box_estimate_s": list(track.seconds),
            # Each move's duration (the last one halted when the stop came during it), and
            # the arm's waits at a view for a stop check begun as it moved there.
            "travel_s": list(episode_log.travel_seconds),
            "stop_wait_s": list(episode_log.stop_wait_seconds),
        },
        "scenario": yaml_dump_typed(scenario),
    }


def container_entry(decision: PackingDecision | None) -> dict[str, Any] | None:
    """report.json's `container`: the decision and where its margin came from."""
    if decision is None:
        return None
    chosen = decision.container
    return {
        "name": None if chosen is None else chosen.name,
        "inner": None if chosen is None else list(chosen.inner),
        "cost": None if chosen is None else chosen.cost,
        "orientation": decision.orientation,
        "required": decision.required.tolist(),
        "margin": decision.margin.tolist(),
        "margin_from": decision.margin_from,
        "clearance": decision.clearance,
        "reason": decision.reason,
    }


def _cell_box_entry(box: OrientedBox | None) -> dict[str, Any] | None:
    """The final cell box: where the model and shape fits start, so they can be re-run on
    frames.npz without rebuilding the map."""
    if box is None:
        return None
    return {"center": box.center.tolist(), "dims": box.dims.tolist(), "yaw": float(box.yaw)}


#: What report.json says when the readings misfit the model, and the command that fixes it.
MISFIT_NOTE = ("the readings misfit the sensor model beyond what its noise allows: the "
               "sensor model is not this device's, the sensor's mount or the table is not "
               "where the model assumes, or the object has parts the estimate does not "
               "draw; the interval and the container's margin are widened by the misfit. "
               "Commission the cell with `lrnbv hardware commission` (docs/hardware.md) and "
               "calibrate the model with `lrnbv sensor characterize` "
               "(docs/sensor-calibration.md), then `lrnbv refit` this folder")


def box_entry(scenario: Scenario, estimate: BoxEstimate | None) -> dict[str, Any] | None:
    """report.json's `estimated_box`: the box, and the fit's interval, shape and misfit
    where there is one."""
    if estimate is None:
        return None
    box = estimate.box
    entry = {"estimator": scenario.extraction.estimator, "center": box.center.tolist(),
             "dims": box.dims.tolist(), "yaw": float(box.yaw),
             "yaw_deg": float(np.degrees(box.yaw))}
    if estimate.shape is not None:
        entry.update(
            dims_lower=estimate.dims_lower.tolist(), dims_upper=estimate.dims_upper.tolist(),
            zones=estimate.n_zones, shape=estimate.shape.name(),
            parts=[{"solid": solid, "rounded": rounded, "center": x[:2].tolist(),
                    "yaw": float(x[2]), "dims": x[3:6].tolist(), "rounding": x[6:9].tolist(),
                    "taper": float(x[9])}
                   for x, solid, rounded in zip(estimate.shape.parts, estimate.shape.solid,
                                                estimate.shape.rounded, strict=True)],
            misfit=estimate.misfit,
            table_misfit=None if math.isnan(estimate.table_misfit) else estimate.table_misfit,
            misfit_flag=estimate.misfit_flag)
        if estimate.misfit_flag:
            entry["misfit_note"] = MISFIT_NOTE
    return entry


def episode_metrics(scenario: Scenario, placed: PlacedObject, episode_log: EpisodeLog,
                    estimated: OrientedBox | None) -> metrics.EpisodeMetrics:
    """Box, coverage and pose metrics of an episode against the true object (resting on the
    true table, which a simulated cell may put off `cell.table_height`)."""
    table = placed.table_height
    # The same samples for every planner and trial (seed 0): differences are the planners'.
    samples = sample_surface(placed.mesh, COVERAGE_SPACING, table_height=table, seed=0)
    cells = [e.object_points if e is not None and e.found else np.zeros((0, 3))
             for e in episode_log.extractions]
    return metrics.episode_metrics(estimated, metrics.true_box(placed.mesh.vertices, table),
                                   samples, cells, scenario.mapping.resolution)


def accuracy_metrics(scenario: Scenario, placed: PlacedObject, track: EstimateTrack,
                     decision: PackingDecision | None) -> dict[str, Any]:
    """The box in millimetres against the truth: per-dimension errors, whether the truth lies
    in the reported interval, poses-to-5 mm and -10 mm (`metrics.poses_to_accuracy`) from
    the estimate after each pose, and the container `decision` against the one the true box
    gets (`packing.packing_metrics`)."""
    true = metrics.true_box(placed.mesh.vertices, placed.table_height)
    errors = errors_after_each_pose(track, true)
    out: dict[str, Any] = {
        "true_box": {"center": true.center.tolist(), "dims": true.dims.tolist(),
                     "yaw": float(true.yaw)},
        "dim_errors_mm": None,
        "poses_to_5mm": metrics.poses_to_accuracy(errors, 0.005),
        "poses_to_10mm": metrics.poses_to_accuracy(errors, 0.010),
        "dim_errors_after_each_pose_mm": [
            [None if np.isnan(v) else round(float(v) * 1000, 2) for v in row]
            for row in errors],
    }
    if decision is not None:
        out["packing"] = packing_metrics(decision, true.dims, container_catalogue(scenario))
    if track.latest is not None:
        out.update(against_truth(track.latest, true))
    return out


def against_truth(estimate: BoxEstimate, true: OrientedBox) -> dict[str, Any]:
    """`dim_errors_mm` of `estimate`'s box against the true box, and `truth_in_interval`
    where the report gives an interval (`box_entry`: a fitted shape's)."""
    out: dict[str, Any] = {
        "dim_errors_mm": np.round((estimate.box.dims - true.dims) * 1000, 2).tolist()}
    if estimate.shape is not None:
        lower, upper = estimate.dims_lower, estimate.dims_upper
        out["truth_in_interval"] = ((lower <= true.dims) & (true.dims <= upper)).tolist()
    return out
