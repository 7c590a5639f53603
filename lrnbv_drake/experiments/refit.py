"""The box of a recorded episode estimated again from its readings, with another sensor model
or estimator, without moving the arm (`lrnbv refit`).

Why: the box is fitted to the raw zone readings through the sensor model
(docs/box-estimation.md), so a calibration made after a session (`lrnbv sensor
characterize`) or another estimator changes what the same readings say. An episode's folder
(`lrnbv run`, a campaign's `runs/*`, `lrnbv hardware`) keeps every frame with its sensor pose
(frames.npz) and the final cell box and the scenario it ran (report.json): that is all the
estimate needs, so nothing is simulated again. Only an episode cut short (`first_poses`)
rebuilds its map, from its own frames, for the cell box it had then.
"""

from __future__ import annotations

import dataclasses as dc
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.perception import extract_object
from lrnbv_drake.core.sensor import ToFFrame
from lrnbv_drake.experiments.recording import frames_from_arrays, load_recording
from lrnbv_drake.experiments.report import (
    against_truth,
    box_entry,
    container_entry,
    fit_readings,
    found_box,
    packing_decision,
    rounded,
)
from lrnbv_drake.station.parts import extraction_params, map_system
from lrnbv_drake.station.scenario import Scenario, load_scenario


class RefitError(ValueError):
    """A folder that does not hold a recorded episode, naming the file and what is wrong."""


@dc.dataclass
class RecordedEpisode:
    """What `refit` needs of an episode's folder."""

    folder: Path
    # The scenario the episode ran, as report.json recorded it.
    scenario: Scenario
    # Every frame with its sensor pose X_WS (4, 4), in the order they were taken.
    readings: list[tuple[ToFFrame, np.ndarray]]
    # The object's final cell box, where the fits start; None when no object was found.
    cells: OrientedBox | None
    # The box the episode reported (report.json's `estimated_box`), or None.
    reported: dict[str, Any] | None
    # The true box of a simulated episode; None on the real cell.
    true: OrientedBox | None


def _box(entry: dict[str, Any] | None) -> OrientedBox | None:
    if entry is None:
        return None
    return OrientedBox(np.array(entry["center"], float), np.array(entry["dims"], float),
                       float(entry["yaw"]))


def load_episode(folder: str | Path) -> RecordedEpisode:
    """Reads `folder`'s report.json and frames.npz.

    Raises:
        RefitError: a file missing or unreadable, or the two disagreeing (frames.npz holding
            another number of frames than report.json's poses).
    """
    folder = Path(folder)
    report_path, frames_path = folder / "report.json", folder / "frames.npz"
    for path in (report_path, frames_path):
        if not path.is_file():
            raise RefitError(f"{path}: no such file; expected an episode's folder (written "
                             f"by `lrnbv run`, `lrnbv benchmark` under runs/, or "
                             f"`lrnbv hardware`)")
    try:
        report = json.loads(report_path.read_text())
        scenario = load_scenario(data=report["scenario"])
        arrays = load_recording(frames_path)
        readings = list(zip(frames_from_arrays(arrays), arrays["X_WS"], strict=True))
    except (OSError, ValueError, KeyError, IndexError) as e:
        raise RefitError(f"{folder}: cannot read the episode ({type(e).__name__}: {e})") from e
    if len(readings) != report.get("n_poses"):
        raise RefitError(f"{frames_path}: {len(readings)} frames, but {report_path} has "
                         f"{report.get('n_poses')} poses; expected the two files of one episode")
    true = report.get("metrics", {}).get("true_box")
    return RecordedEpisode(folder, scenario, readings, _box(report.get("cell_box")),
                           report.get("estimated_box"), _box(true))


def first_poses(episode: RecordedEpisode, n: int) -> RecordedEpisode:
    """`episode` as if it had stopped after `n` poses: its first `n` readings, and the cell box
    the extraction finds in the map rebuilt from them (the episode's own mapping and
    extraction settings: the same map and cells the episode had after its n-th pose).

    Why: whether fewer poses would have done, e.g. how a looser stop rule would have fared on
    readings taken on the real cell.

    Raises:
        RefitError: `n` is not between 1 and the episode's number of poses.
    """
    if not 1 <= n <= len(episode.readings):
        raise RefitError(f"{episode.folder}: cannot take its first {n} poses, it has "
                         f"{len(episode.readings)}; expected 1 to {len(episode.readings)}")
    if n == len(episode.readings):
        return episode
    readings = episode.readings[:n]
    occupancy = map_system(episode.scenario, period=None)
    occupancy.insert_recorded(occupancy.CreateDefaultContext(), readings)
    extraction = extract_object(occupancy.occupancy_map.occupied_centers(),
                                extraction_params(episode.scenario))
    return dc.replace(episode, readings=readings, cells=found_box(extraction), reported=None)


def refit(episode: RecordedEpisode, scenario: Scenario) -> dict[str, Any]:
    """The box, its interval and container from `episode`'s readings under `scenario` (the
    episode's own, or it with a calibrated `sensor:` section or another estimator), with the
    errors against the truth for a simulated episode. The fields are report.json's."""
    started = time.perf_counter()
    box, fit = fit_readings(scenario, episode.readings, episode.cells)
    seconds = time.perf_counter() - started
    entry = box_entry(scenario, box, fit)
    out: dict[str, Any] = {
        "folder": str(episode.folder),
        "estimated_box": entry,
        "container": container_entry(scenario, packing_decision(scenario, box, fit,
                                                                episode.cells),
                                     fit, episode.cells),
        "reported_box": episode.reported,
        "n_poses": len(episode.readings),
        "box_estimate_s": seconds,
    }
    if episode.true is not None and entry is not None:
        out.update(against_truth(entry, episode.true))
    return rounded(out)
