"""Commissioning a cell (`lrnbv hardware commission`): the arm takes the planned views of the
bare table through the episode's own acquisition loop (the `TableViews` policy,
`hardware.commission_frames` frames at each view), and the fit
(`core.calibration.commissioning`) gives the scenario section that `run`, `hardware` and
`refit` take with `--scenario`.

On the real cell, and in its dry run (the playback robot and the simulated board, in real
time), the views are a session of `experiments.session`: every frame is in
`acquisitions.jsonl` before the next motion, a fault stops the arm, and `lrnbv hardware
--resume DIR` carries on and then fits. `commission_simulated` takes the same views on the
simulated cell as fast as it computes (the benchmark, the campaigns, the tests).

The views are taken and fitted against the CAD mount and the board's own zone order (the
scenario's `sensor.mount` and flips are what is measured, so they are set aside here).
"""

from __future__ import annotations

import dataclasses as dc
import json
import time
from pathlib import Path

import numpy as np
from pydrake.geometry import Meshcat

from lrnbv_drake.core.acquisition import EpisodeLog, cycle_time
from lrnbv_drake.core.calibration.commissioning import (
    PARAMETERS,
    VIEW,
    CommissioningError,
    CommissioningFit,
    fit_commissioning,
    table_view_poses,
    views_of,
)
from lrnbv_drake.core.planning.policy import FRAME_OF_VIEW
from lrnbv_drake.core.sensing.zone_order import model_flips
from lrnbv_drake.experiments.episode import build_episode, run_loop
from lrnbv_drake.experiments.recording import AcquisitionJournal, save_frames, write_atomically
from lrnbv_drake.experiments.session import (
    SESSION_FILE,
    Confirm,
    SessionResult,
    run_session,
)
from lrnbv_drake.experiments.session_monitor import JOURNAL_FILE
from lrnbv_drake.station.parts import COMMISSION, sensor_behaviour, sensor_params
from lrnbv_drake.station.scenario import MountOffset, Scenario, load_scenario

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


def commissioning_scenario(scenario: Scenario) -> Scenario:
    """`scenario` as commissioning runs it: the model on the CAD mount and the board's own
    zone order (what is measured), the views exactly as planned (no roll about the axis),
    and room for every frame of every view."""
    sensor = dc.replace(scenario.sensor, mount=MountOffset(), flip_x=False, flip_y=False,
                        transpose=False, commissioned="")
    robot = dc.replace(scenario.robot, sensor_roll_step_deg=0.0)
    views = len(table_view_poses(np.zeros(2), 0.0))
    return dc.replace(scenario, sensor=sensor, robot=robot,
                      max_poses=views * scenario.hardware.commission_frames)


def commission_simulated(scenario: Scenario, out: Path) -> Commissioned:
    """Takes the commissioning views on the simulated cell (the device as `device:` sets it,
    the table bare) and fits them; writes `frames.npz` (every frame with its pose and joints),
    `commissioning.yaml` (the section) and `commissioning.json` (values, errors, orders)."""
    scenario = commissioning_scenario(scenario)
    run = run_loop(build_episode(scenario, COMMISSION))
    if run.fault is not None:
        raise CommissioningError(f"the simulated views stopped: {run.termination}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_frames(out / "frames.npz", run.log.acquisitions)
    return commissioned(scenario, run.log, out, real=False,
                        cycle_seconds=cycle_time(run.log).total)


def commission_cell(scenario: Scenario, out_dir: Path, *, confirm: Confirm,
                    meshcat: Meshcat | None = None, dry_run: bool = False) -> SessionResult:
    """Takes the views on the real cell (or its dry run) as a session in `out_dir`
    (`experiments.session.run_session`); `fit_session` then fits them."""
    return run_session(commissioning_scenario(scenario), COMMISSION, out_dir,
                       confirm=confirm, meshcat=meshcat, dry_run=dry_run)


def fit_session(out_dir: Path) -> Commissioned:
    """Fits the views of the commissioning session in `out_dir` (`acquisitions.jsonl`: every
    view whole, before and after any stop) and writes its section. Only a session on the
    real arm marks the section commissioned (`sensor.commissioned`): a dry run's is of the
    simulated board.

    Raises:
        CommissioningError: the views cannot tell a value apart, or the folder holds no
            commissioning session.
    """
    out_dir = Path(out_dir)
    session = json.loads((out_dir / SESSION_FILE).read_text())
    if session["planner"] != COMMISSION:
        raise CommissioningError(f"{out_dir} holds a {session['planner']} session, not a "
                                 f"commissioning one")
    log = EpisodeLog(acquisitions=AcquisitionJournal(out_dir / JOURNAL_FILE).load())
    report = out_dir / "report.json"  # the session's cycle time (its last run's, if resumed)
    cycle = (json.loads(report.read_text())["cycle_time"]["total_s"] if report.exists()
             else float("nan"))
    return commissioned(load_scenario(data=session["scenario"]), log, out_dir,
                        real=not session["dry_run"], cycle_seconds=cycle)


def unfitted(out_dir: Path) -> bool:
    """Whether `out_dir` holds a finished commissioning session whose fit was not written
    (it failed, or the process ended first): `fit_session` fits it again."""
    path = Path(out_dir) / SESSION_FILE
    if not path.exists() or (Path(out_dir) / "commissioning.yaml").exists():
        return False
    session = json.loads(path.read_text())
    return session["planner"] == COMMISSION and bool(session.get("finished"))


def commissioned(scenario: Scenario, log: EpisodeLog, out: Path, real: bool,
                 cycle_seconds: float) -> Commissioned:
    """Fits the views in `log` (taken under `commissioning_scenario`, in `cycle_seconds`),
    writes `commissioning.yaml` and `commissioning.json` into `out`, and returns them; with
    `real` (the views of a real sensor) the section says the cell was commissioned.

    Raises:
        CommissioningError: the views cannot tell a value apart (naming it).
    """
    center = np.asarray(scenario.extraction.center, float)
    frames = scenario.hardware.commission_frames
    views = views_of(log.acquisitions, frames)
    fit = fit_commissioning(views, sensor_params(scenario), sensor_behaviour(scenario),
                            np.asarray(scenario.cell.table_extent, float), center,
                            scenario.cell.table_height)
    flip_x, flip_y, transpose = model_flips(*fit.zone_order)
    stamp = time.strftime("%Y-%m-%d %H:%M %Z")
    section = {
        "sensor": {"mount": {"xyz_mm": _rounded(fit.mount_xyz_mm),
                             "rpy_deg": _rounded(fit.mount_rpy_deg)},
                   "flip_x": flip_x, "flip_y": flip_y, "transpose": transpose},
        "cell": {"table_height": round(fit.table_height_m, 5)},
    }
    if real:
        section["sensor"]["commissioned"] = f"{stamp}, lrnbv hardware commission into {out}"
    notes = []
    slope, slope_sigma = fit.values[7:9], fit.sigma[7:9]
    if np.any((np.abs(slope) > LEVEL_SLOPE_DEG) & (np.abs(slope) > 3 * slope_sigma)):
        notes.append(f"the table slopes {slope[0]:.2f} deg along x and {slope[1]:.2f} deg along "
                     f"y: level it, the model assumes a level table")
    if fit.zone_order != (0, "none"):
        notes.append(f"the board reports its zones turned {fit.zone_order[0]} deg and "
                     f"flipped '{fit.zone_order[1]}' against the model: the section sets "
                     f"flip_x, flip_y and transpose to read it")
    planned = table_view_poses(center, scenario.cell.table_height)
    taken = {a.info[VIEW] for a in log.acquisitions
             if VIEW in a.info and a.info.get(FRAME_OF_VIEW, 0) == frames - 1}
    skipped = tuple(f"view {k}: {_why_not(planned[k], log)}" for k in range(len(planned))
                    if k not in taken)
    result = Commissioned(fit, section, len(views), skipped, cycle_seconds, tuple(notes))
    write_commissioning(out, result)
    return result


def _why_not(X_WS: np.ndarray, log: EpisodeLog) -> str:
    """The motion planner's reason for not reaching the view at `X_WS`."""
    reasons = [reason for _, X, _, reason in log.motion_failures
               if np.allclose(np.asarray(X)[:3, 3], X_WS[:3, 3])]
    return reasons[-1] if reasons else "not reached"


def write_commissioning(out: Path, result: Commissioned) -> None:
    """`commissioning.yaml`, the section for `--scenario`, and `commissioning.json`."""
    import yaml

    fit = result.fit
    header = ("# The sensor's mount, its zone order and the table as `lrnbv hardware commission`"
              "\n# measured them; pass with --scenario (merge into a scenario file by hand).\n")
    write_atomically(out / "commissioning.yaml", header + yaml.safe_dump(
        result.section, sort_keys=False, default_flow_style=None))
    write_atomically(out / "commissioning.json", json.dumps({
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
