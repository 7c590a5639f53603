"""Commissioning on the simulated cell (`lrnbv hardware commission --dry-run`): the arm takes
the planned views of the bare table, every view is on disk before the next motion, and the
fit (`core.calibration.commissioning`) gives the scenario section that `run`, `hardware` and
`refit` take with `--scenario`.

The views are taken and fitted against the CAD mount and the board's own zone order (the
scenario's `sensor.mount` and flips are what is measured, so they are set aside here).
"""

from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np

from lrnbv_drake.core.calibration.commissioning import (
    PARAMETERS,
    CommissioningFit,
    TableView,
    fit_commissioning,
    table_view_poses,
)
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.core.sensing.zone_order import model_flips
from lrnbv_drake.experiments.recording import frames_to_arrays, write_npz_atomically
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.parts import sensor_behaviour, sensor_params
from lrnbv_drake.station.scenario import MountOffset, Scenario
from lrnbv_drake.station.sim_cell import make_sim_cell

#: Frames averaged at each view (two thirds of a second at 15 Hz).
FRAMES_PER_VIEW = 10
#: A table slope worth levelling, degrees: 1 mm over 0.6 m of table. The model assumes a
#: level table.
LEVEL_SLOPE_DEG = 0.1


@dc.dataclass(frozen=True)
class Commissioned:
    """A commissioning run: the fit, the section it writes and what the run took."""

    fit: CommissioningFit
    section: dict
    views: int
    skipped: tuple[str, ...]
    cycle_time_s: float
    notes: tuple[str, ...]


def cad_scenario(scenario: Scenario) -> Scenario:
    """`scenario` with the model on the CAD mount, the board's own zone order and the views
    exactly as planned (no roll about the axis): what commissioning measures against."""
    sensor = dc.replace(scenario.sensor, mount=MountOffset(), flip_x=False, flip_y=False,
                        transpose=False)
    robot = dc.replace(scenario.robot, sensor_roll_step_deg=0.0)
    return dc.replace(scenario, sensor=sensor, robot=robot)


def commission_simulated(scenario: Scenario, out: Path,
                         frames_per_view: int = FRAMES_PER_VIEW) -> Commissioned:
    """Takes the commissioning views on the simulated cell (the device as `device:` sets it,
    the table bare) and fits them; writes `views/NN.npz` as each is taken, then
    `commissioning.yaml` (the section) and `commissioning.json` (values, errors, orders)."""
    cad = cad_scenario(scenario)
    cell = make_sim_cell(cad, bare_table=True)
    motion = MotionPlanner(cad, bare_table=True)
    context = cell.diagram.CreateDefaultContext()
    tof = cell.diagram.GetSubsystemByName("tof")
    period = scenario.sensor.period
    views_dir = Path(out) / "views"
    views_dir.mkdir(parents=True, exist_ok=True)
    q, t, sequence = np.asarray(scenario.robot.initial_position, float), 0.0, 0
    views, skipped = [], []
    center = np.asarray(scenario.extraction.center, float)
    for i, X_WS in enumerate(table_view_poses(center, scenario.cell.table_height)):
        plan = motion.plan(q, X_WS)
        if not plan.ok:
            skipped.append(f"view {i}: {plan.reason}")
            continue
        q = plan.q_target
        t += plan.trajectory.end_time() + (1 + scenario.sensor.settle_frames) * period
        cell.diagram.GetInputPort("ur5e.position").FixValue(context, q)
        frames = []
        for _ in range(frames_per_view):
            sequence += 1
            frames.append(tof.CaptureFrame(tof.GetMyContextFromRoot(context), sequence))
        t += frames_per_view * period
        X_WC = cell.diagram.GetOutputPort("tof.pose").Eval(context).GetAsMatrix4()
        save_view(views_dir / f"{i:02d}.npz", q, X_WC, frames)
        views.append(TableView(X_WC, tuple(frames)))
    fit = fit_commissioning(views, sensor_params(cad), sensor_behaviour(cad),
                            np.asarray(scenario.cell.table_extent, float), center,
                            scenario.cell.table_height)
    flip_x, flip_y, transpose = model_flips(*fit.zone_order)
    section = {
        "sensor": {"mount": {"xyz_mm": _rounded(fit.mount_xyz_mm),
                             "rpy_deg": _rounded(fit.mount_rpy_deg)},
                   "flip_x": flip_x, "flip_y": flip_y, "transpose": transpose},
        "cell": {"table_height": round(fit.table_height_m, 5)},
    }
    notes = []
    slope, slope_sigma = fit.values[7:9], fit.sigma[7:9]
    if np.any((np.abs(slope) > LEVEL_SLOPE_DEG) & (np.abs(slope) > 3 * slope_sigma)):
        notes.append(f"the table slopes {slope[0]:.2f} deg along x and {slope[1]:.2f} deg along "
                     f"y: level it, the model assumes a level table")
    if fit.zone_order != (0, "none"):
        notes.append(f"the board reports its zones turned {fit.zone_order[0]} deg and "
                     f"flipped '{fit.zone_order[1]}' against the model: the section sets "
                     f"flip_x, flip_y and transpose to read it")
    result = Commissioned(fit, section, len(views), tuple(skipped), t, tuple(notes))
    write_commissioning(Path(out), result)
    return result


def save_view(path: Path, q: np.ndarray, X_WC: np.ndarray, frames: list[ToFFrame]) -> None:
    """One view on disk, atomically: its frames (`frames_to_arrays`), joints and CAD sensor
    pose."""
    write_npz_atomically(path, {**frames_to_arrays(frames), "q": np.asarray(q, float),
                                "X_WC": np.asarray(X_WC, float)})


def write_commissioning(out: Path, result: Commissioned) -> None:
    """`commissioning.yaml`, the section for `--scenario`, and `commissioning.json`."""
    import yaml

    fit = result.fit
    header = ("# The sensor's mount, its zone order and the table as `lrnbv hardware commission`"
              "\n# measured them; pass with --scenario (merge into a scenario file by hand).\n")
    (out / "commissioning.yaml").write_text(
        header + yaml.safe_dump(result.section, sort_keys=False, default_flow_style=None))
    (out / "commissioning.json").write_text(json.dumps({
        "values": {name: float(v) for name, v in zip(PARAMETERS, fit.values, strict=True)},
        "standard_errors": {name: float(s) for name, s in zip(PARAMETERS, fit.sigma,
                                                               strict=True)},
        "table_height_at_xy_m": fit.at_xy.tolist(),
        "zone_order": {"rotate": fit.zone_order[0], "flip": fit.zone_order[1]},
        "rms_model_sigmas": fit.rms,
        "orders": [{"rotate": r, "flip": f, "rms_model_sigmas": rms, "mount_turn_deg": turn}
                   for r, f, rms, turn in fit.orders],
        "readings": fit.readings, "views": result.views, "skipped": list(result.skipped),
        "cycle_time_s": result.cycle_time_s, "notes": list(result.notes),
    }, indent=2) + "\n")


def _rounded(values: np.ndarray) -> list[float]:
    return [round(float(v), 3) for v in values]
