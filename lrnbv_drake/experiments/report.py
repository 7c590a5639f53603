"""report.json: what an episode did, the same fields for a simulated episode and a session on
the real cell (docs/metrics.md lists them); the simulation adds metrics against the true
object, the real cell its hardware state."""

from __future__ import annotations

from typing import Any

import numpy as np
from pydrake.common.yaml import yaml_dump_typed

from lrnbv_drake.core import metrics
from lrnbv_drake.core.acquisition import EpisodeLog
from lrnbv_drake.core.objects import PlacedObject, sample_surface
from lrnbv_drake.station.scenario import Scenario

#: Spacing of the surface samples the coverage metric counts, metres (threshold / 2).
COVERAGE_SPACING = 0.005


def json_default(value: Any) -> Any:
    """For json.dumps: numpy arrays and scalars as plain lists and numbers."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot record a {type(value).__name__} in JSON")


def _final_extraction(episode_log: EpisodeLog):
    return episode_log.extractions[-1] if episode_log.extractions else None


def episode_report(planner: str, scenario: Scenario, episode_log: EpisodeLog, *,
                   termination: str, wall_seconds: float, sim_seconds: float,
                   map_update_seconds: list[float]) -> dict[str, Any]:
    """The fields every report has: settings, the estimated box, every pose, timings."""
    final = _final_extraction(episode_log)
    found = final is not None and final.found
    return {
        "planner": planner,
        "object": scenario.object.name,
        "object_scale": scenario.object.scale,
        "object_pose": [scenario.object.x, scenario.object.y, scenario.object.yaw_deg],
        "seed": scenario.seed,
        "termination": termination,
        "n_poses": len(episode_log.acquisitions),
        "estimated_box": ({"center": final.oriented_box.center.tolist(),
                           "dims": final.oriented_box.dims.tolist(),
                           "yaw": float(final.oriented_box.yaw)} if found else None),
        "extraction": final.reason if final is not None else "no extraction",
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
        },
        "scenario": yaml_dump_typed(scenario),
    }


def episode_metrics(scenario: Scenario, placed: PlacedObject,
                    episode_log: EpisodeLog) -> metrics.EpisodeMetrics:
    """Box, coverage and pose metrics of an episode against the true object."""
    final = _final_extraction(episode_log)
    estimated = final.oriented_box if final is not None and final.found else None
    table = scenario.cell.table_height
    # The same samples for every planner and trial (seed 0): differences are the planners'.
    samples = sample_surface(placed.mesh, COVERAGE_SPACING, table_height=table, seed=0)
    cells = [e.object_points if e is not None and e.found else np.zeros((0, 3))
             for e in episode_log.extractions]
    return metrics.episode_metrics(estimated, metrics.true_box(placed.mesh.vertices, table),
                                   samples, cells, scenario.mapping.resolution)
