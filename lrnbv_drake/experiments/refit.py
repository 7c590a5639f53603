"""The box of a recorded episode estimated again from its readings, with another sensor model
or estimator, without moving the arm (`lrnbv refit`).

Why: the box is fitted to the raw zone readings through the sensor model
(docs/box-estimation.md), so a calibration made after a session (`lrnbv sensor
characterize`), other estimator settings or another estimator change what the same readings
say. An episode's folder (`lrnbv run`, a campaign's `runs/*`, `lrnbv hardware`) keeps every
frame with its sensor pose (frames.npz) and the scenario it ran (report.json): that is all
the estimate needs. The map is rebuilt from the frames, pose by pose, for the cell box after
each (the map is a function of its frames and of the mapping and extraction settings), so
under the episode's own scenario the estimate is the episode's, pose by pose; nothing is
simulated again.
"""

from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path
from typing import Any

import numpy as np

from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.mapping.extraction import extract_object, found_box
from lrnbv_drake.core.robot.poses import offset_transform
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.experiments.recording import frames_from_arrays, load_recording
from lrnbv_drake.experiments.report import (
    against_truth,
    box_entry,
    container_entry,
    estimate_readings,
    rounded,
)
from lrnbv_drake.station.parts import extraction_params, map_system, packing_decision
from lrnbv_drake.station.scenario import MountOffset, Scenario, recorded_scenario
from lrnbv_drake.station.scenario_checks import check_ranges


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
    # The object's cell box after each reading (None where none was found), from the map
    # rebuilt from the readings with the episode's mapping and extraction settings.
    cell_boxes: list[OrientedBox | None]
    # The box the episode reported (report.json's `estimated_box`), or None.
    reported: dict[str, Any] | None
    # The true box of a simulated episode; None on the real cell.
    true: OrientedBox | None


def _box(entry: dict[str, Any] | None) -> OrientedBox | None:
    if entry is None:
        return None
    return OrientedBox(np.array(entry["center"], float), np.array(entry["dims"], float),
                       float(entry["yaw"]))


def cell_boxes(scenario: Scenario, readings: list[tuple[ToFFrame, np.ndarray]]
               ) -> list[OrientedBox | None]:
    """The object's cell box after each reading, in the map built from them in order."""
    occupancy = map_system(scenario, period=None)
    context = occupancy.CreateDefaultContext()
    params = extraction_params(scenario)
    boxes = []
    for reading in readings:
        occupancy.insert_recorded(context, [reading])
        boxes.append(found_box(extract_object(occupancy.occupancy_map.occupied_centers(),
                                              params)))
    return boxes


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
        scenario = recorded_scenario(report["scenario"])
        arrays = load_recording(frames_path)
        readings = list(zip(frames_from_arrays(arrays), arrays["X_WS"], strict=True))
    except (OSError, ValueError, KeyError, IndexError) as e:
        raise RefitError(f"{folder}: cannot read the episode ({type(e).__name__}: {e})") from e
    if len(readings) != report.get("n_poses"):
        raise RefitError(f"{frames_path}: {len(readings)} frames, but {report_path} has "
                         f"{report.get('n_poses')} poses; expected the two files of one episode")
    true = report.get("metrics", {}).get("true_box")
    return RecordedEpisode(folder, scenario, readings, cell_boxes(scenario, readings),
                           report.get("estimated_box"), _box(true))


def first_poses(episode: RecordedEpisode, n: int) -> RecordedEpisode:
    """`episode` as if it had stopped after `n` poses: its first `n` readings and the cell
    boxes it had after them. Why: whether fewer poses would have done, e.g. how a looser stop
    rule would have fared on readings taken on the real cell.

    Raises:
        RefitError: `n` is not between 1 and the episode's number of poses.
    """
    if not 1 <= n <= len(episode.readings):
        raise RefitError(f"{episode.folder}: cannot take its first {n} poses, it has "
                         f"{len(episode.readings)}; expected 1 to {len(episode.readings)}")
    if n == len(episode.readings):
        return episode
    return dc.replace(episode, readings=episode.readings[:n],
                      cell_boxes=episode.cell_boxes[:n], reported=None)


def remounted(readings: list[tuple[ToFFrame, np.ndarray]], recorded: MountOffset,
              commissioned: MountOffset) -> list[tuple[ToFFrame, np.ndarray]]:
    """`readings` with each sensor pose moved from the mount it was recorded under to
    another: X_WS' = X_WS X_CS(recorded)^-1 X_CS(commissioned), the same flange pose."""
    change = (np.linalg.inv(offset_transform(recorded.xyz_mm, recorded.rpy_deg))
              @ offset_transform(commissioned.xyz_mm, commissioned.rpy_deg))
    return [(frame, np.asarray(X_WS, float) @ change) for frame, X_WS in readings]


def refit(episode: RecordedEpisode, scenario: Scenario) -> dict[str, Any]:
    """The box, its interval and container from `episode`'s readings under `scenario` (the
    episode's own, or it with a calibrated `sensor:` section, a commissioned mount, other
    `estimation:` settings or another estimator), with the errors against the truth for a
    simulated episode. The fields are report.json's. A commissioned `sensor.mount` moves
    every recorded sensor pose to it (`remounted`); the map is rebuilt under `scenario`.

    Raises:
        ScenarioError: a field of `scenario` out of range or not one of its choices.
    """
    check_ranges(scenario)
    readings = episode.readings
    if scenario.sensor.mount != episode.scenario.sensor.mount:
        readings = remounted(readings, episode.scenario.sensor.mount, scenario.sensor.mount)
    # The map under `scenario`'s mapping and extraction settings, which may not be the
    # episode's (a tenth of a second for 20 frames).
    track = estimate_readings(scenario, readings, cell_boxes(scenario, readings))
    entry = box_entry(scenario, track.latest)
    out: dict[str, Any] = {
        "folder": str(episode.folder),
        "estimated_box": entry,
        "container": container_entry(packing_decision(scenario, track.latest)),
        "reported_box": episode.reported,
        "n_poses": len(episode.readings),
        "box_estimate_s": list(track.seconds),
    }
    if episode.true is not None and track.latest is not None:
        out.update(against_truth(track.latest, episode.true))
    return rounded(out)
