"""Running an episode on the real cell: confirmation, crash-safe recording, faults and resume.

`run_session` checks the robot's current pose against the model (`session_preflight`), asks
for an explicit confirmation, builds the episode with the hardware cell
(`build_episode(..., hardware=True)`) and runs it in real time. The output folder fills up as
the episode goes:

- `session.json`    the scenario actually used (YAML), the planner, and one entry per run
                    (start joints, wall time, acquisitions already recorded);
- `acquisitions.jsonl`  one JSON line per acquisition (frame, sensor pose, joints, time, the
                    planner's info), appended and fsynced as soon as the planner logs it, which
                    is before it plans the next motion;
- `map.ot`          the occupancy map (OctoMap .ot, exact log-odds) after each insertion,
                    replaced atomically;
- `frames.npz`, `report.json`, `replay.html`  written at the end, also after a fault.

A stop on the controller, reduced mode, speed scaling, a lost connection, a refused command, a
silent sensor, an unexpected error or Ctrl-C stops the arm, saves, and ends the run with a
message that says what happened, what is on disk and what to do; once the arm may have moved
nothing is raised (`SessionResult.moved` tells the two apart). Shutting down is bounded: the
journal is written first, then the arm is stopped (unless the link is lost), then the drivers
are closed, each step bounded (`RtdeRobot.disconnect`), and only then are `frames.npz` and
`report.json` written, from what is already in memory. `resume(out_dir)` then continues the
episode from wherever the arm is now (see its docstring for what it rebuilds).

Dry run (`dry_run=True`): the hardware diagram with no hardware. The `PlaybackRobot` plays
every command back as the measured joints (each command still passes the sender's checks) and
the `SimulatedToFBoard` renders frames of the scenario's modelled cell through the real serial
driver. Meshcat shows every planned motion; nothing moves. It connects to the robot only to
read where it is (read-only RTDE), when `robot.robot_ip` is set, so the preview starts from
the real pose. It runs in real time, so it also rehearses the timing.
"""

from __future__ import annotations

import dataclasses as dc
import json
import logging
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Context

from lrnbv_drake.core.acquisition import Acquisition, EpisodeLog
from lrnbv_drake.core.kernels import compile_kernels
from lrnbv_drake.drivers.tof_serial import SerialStats
from lrnbv_drake.experiments.episode import (
    PLANNERS,
    EpisodeDiagram,
    EpisodeRun,
    build_episode,
    final_estimates,
    run_loop,
    write_outputs,
)
from lrnbv_drake.experiments.recording import (
    AcquisitionJournal,
    RecordingError,
    write_atomically,
)
from lrnbv_drake.experiments.report import episode_report
from lrnbv_drake.experiments.session_monitor import JOURNAL_FILE, SessionMonitor
from lrnbv_drake.experiments.session_preflight import (
    SessionError,
    check_sensor,
    preflight,
    read_robot,
)
from lrnbv_drake.station.hardware_cell import check_hardware_config
from lrnbv_drake.station.parts import COMMISSION, check_scenario_files, packing_decision
from lrnbv_drake.station.scenario import Scenario, load_scenario, override

_log = logging.getLogger(__name__)

SESSION_FILE = "session.json"

Confirm = Callable[[str], bool]


@dc.dataclass
class SessionResult:
    """What a session did.

    Attributes:
        out_dir: the output folder.
        termination: why it ended, as a sentence (the fault's message after a fault, with
            what is on disk).
        fault: None when the planner ended the episode; else "declined", "interrupted",
            "sensor", "error" (an unexpected exception: `error`, logged with its traceback)
            or a `RobotFault.kind`.
        log: the planner's log, recorded acquisitions first after a resume.
        resumed_from: acquisitions recorded before this run.
        realtime_resets: times the realtime pacing was restarted after a lag.
        moved: the arm may have moved (a real run got as far as commanding it); False for a
            dry run and for a run the operator declined.
        error: the unexpected exception, when `fault` is "error".
        planner: the session's policy (`PLANNERS`, or `COMMISSION`).
    """

    out_dir: Path
    termination: str
    fault: str | None
    log: EpisodeLog
    resumed_from: int = 0
    realtime_resets: int = 0
    moved: bool = False
    error: Exception | None = None
    planner: str = ""

    @property
    def n_poses(self) -> int:
        return len(self.log.acquisitions)


class _HeldInterrupt:
    """Holds Ctrl-C while the session saves and closes, so that one pressed then cannot leave
    frames.npz and report.json unwritten (every step of that is bounded); `pending` says
    whether one came. Only the main thread can hold it."""

    def __init__(self) -> None:
        self.pending = False
        self._previous: Any = None
        self._holding = False

    def hold(self) -> None:
        if not self._holding and threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._note)
            self._holding = True

    def _note(self, signum: int, frame: object) -> None:
        self.pending = True

    def release(self) -> None:
        if self._holding:
            signal.signal(signal.SIGINT, self._previous)
            self._holding = False


# --- Starting and resuming -------------------------------------------------------------------


def _confirmation_text(scenario: Scenario, planner: str, out_dir: Path) -> str:
    r, c, hw = scenario.robot, scenario.cell, scenario.hardware
    task = (f"to take the commissioning views of the bare table ({hw.commission_frames} "
            f"frames each): clear the table" if planner == COMMISSION else
            f"with the {planner} planner, up to {scenario.max_poses} poses")
    return (f"About to move the UR5e at {r.robot_ip} {task}, joints at most "
            f"{np.rad2deg(np.pi * r.speed_fraction):.0f} deg/s (refused above "
            f"{np.rad2deg(np.pi * hw.max_speed_fraction):.0f}).\n"
            f"The sensor stays in {c.workspace_lower} .. {c.workspace_upper} m (world, "
            f"+{hw.workspace_margin} m along motions) and {hw.min_table_clearance} m above the "
            f"table. Frames: {scenario.sensor.serial_port}. Recording to {out_dir}.\n"
            f"Keep a hand on the emergency stop.")


def _write_session(out_dir: Path, scenario: Scenario, planner: str, dry_run: bool,
                   q_start: np.ndarray, recorded: int) -> None:
    path = out_dir / SESSION_FILE
    session = json.loads(path.read_text()) if path.exists() else {
        "planner": planner, "dry_run": dry_run, "scenario": yaml_dump_typed(scenario),
        "runs": []}
    session["runs"].append({"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                            "q_start": q_start.tolist(), "recorded_before": recorded})
    write_atomically(path, json.dumps(session, indent=2))


def _record_finish(out_dir: Path, termination: str) -> None:
    """Marks the session finished (its planner stopped by itself, everything saved), so that
    `resume` says so instead of planning past the stop."""
    path = out_dir / SESSION_FILE
    session = json.loads(path.read_text())
    session["finished"] = termination
    write_atomically(path, json.dumps(session, indent=2))


def _report(planner: str, scenario: Scenario, parts: EpisodeDiagram, run: EpisodeRun,
            result: SessionResult, dry_run: bool, sensor_stats: SerialStats) -> dict[str, Any]:
    track, report_seconds = final_estimates(parts, run.context)
    report = episode_report(planner, scenario, run.log, track,
                            packing_decision(scenario, track.latest),
                            termination=result.termination, wall_seconds=run.wall_seconds,
                            sim_seconds=run.sim_seconds,
                            map_update_seconds=parts.map_system.insert_seconds,
                            report_seconds=report_seconds)
    report.update({
        "dry_run": dry_run,
        "robot_ip": scenario.robot.robot_ip,
        "sensor_port": scenario.sensor.serial_port,
        "fault": result.fault,
        "resumed_from": result.resumed_from,
        "realtime_resets": result.realtime_resets,
        "wall_seconds": run.wall_seconds,
        "sensor_stats": dc.asdict(sensor_stats),
    })
    return report


def run_session(scenario: Scenario, planner: str, out_dir: str | Path, *, confirm: Confirm,
                meshcat: Meshcat | None = None, dry_run: bool = False) -> SessionResult:
    """Runs one episode on the real cell (or, with `dry_run`, its rehearsal; see the module
    docstring) and records it in `out_dir`, which must not hold a session already.

    Args:
        scenario: the cell; `robot.robot_ip` and `sensor.serial_port` name the hardware.
        planner: "lrnbv", "nbv" or "heu", or `COMMISSION` (the views of the bare table).
        out_dir: the output folder.
        confirm: asked with a description of what is about to happen before anything can
            move; the run goes ahead only if it returns True. Not asked in a dry run.
        meshcat: live view, and a replay.html at the end.
        dry_run: no robot moves and no sensor is read.

    Raises:
        SessionError, ScenarioError, RobotConnectionError, RobotFault: before anything moved;
            SessionError also for a sensor never commissioned (`sensor.commissioned` empty)
            on a real run of a planner.
    """
    out_dir = Path(out_dir)
    if not dry_run and planner != COMMISSION and not scenario.sensor.commissioned:
        raise SessionError(
            "the sensor was never commissioned (sensor.commissioned is empty): its mount, "
            "zone order and the table are the CAD's, and a board whose zones are turned or "
            "a bracket a degree off costs centimetres. Run `lrnbv hardware commission` and "
            "pass its commissioning.yaml with --scenario (or set sensor.commissioned to say "
            "how they were checked)")
    if (out_dir / SESSION_FILE).exists():
        raise SessionError(f"{out_dir} already holds a session: continue it with `lrnbv "
                           f"hardware --resume {out_dir}` or choose another folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    return _run(scenario, planner, out_dir, [], confirm, meshcat, dry_run)


def resume(out_dir: str | Path, *, confirm: Confirm, meshcat: Meshcat | None = None,
           robot_ip: str | None = None, sensor_port: str | None = None,
           containers: str | None = None) -> SessionResult:
    """Continues a recorded session from the arm's current pose.

    Rebuilt from the folder: the scenario and planner (`session.json`); every recorded
    acquisition, re-inserted into a fresh map in order (the same map the run had, as the map
    is a function of the frames and poses) and the last one marked as inserted
    (`OccupancyMapSystem.mark_inserted`); the planner's log, given as its `history` (so
    `max_poses` and the acquisition count carry on, the report lists every pose, and it
    starts by planning); the policy's progress (`ViewpointPolicy.restore`: HEU's next
    ellipse pose, LR-NBV's iteration count and visited cells). Not rebuilt: LR-NBV's view
    cache, its sampler's random state and its utility normaliser's running maxima start
    fresh, and the motion failures, planning times and per-pose extractions of the earlier
    runs are not in the new log. The resumed episode is therefore a faithful continuation for
    HEU, and for LR-NBV a valid one that an uninterrupted run would not have reproduced
    exactly. Diagram time carries on from the last recorded acquisition.

    A finished session (its planner stopped by itself and everything was saved) is not
    resumed: `SessionError` says so.

    Args:
        out_dir: a folder `run_session` wrote.
        confirm, meshcat: as for `run_session` (a dry-run session resumes as a dry run).
        robot_ip, sensor_port, containers: replace the recorded ones (e.g. a renumbered USB
            port, a catalogue moved or corrected).
    """
    out_dir = Path(out_dir)
    path = out_dir / SESSION_FILE
    if not path.exists():
        raise SessionError(f"{out_dir} holds no {SESSION_FILE}: nothing to resume")
    session = json.loads(path.read_text())
    if session.get("finished"):
        what = ("its fit is in commissioning.yaml and commissioning.json, its views in "
                f"{JOURNAL_FILE}" if session["planner"] == COMMISSION else
                "its box and poses are in report.json")
        raise SessionError(f"the session in {out_dir} is finished ({session['finished']}): "
                           f"nothing to resume; {what}. Start a new session in another folder "
                           f"to measure again")
    scenario = load_scenario(data=session["scenario"])
    if robot_ip is not None:
        scenario = override(scenario, {"robot": {"robot_ip": robot_ip}})
    if sensor_port is not None:
        scenario = override(scenario, {"sensor": {"serial_port": sensor_port}})
    if containers is not None:
        scenario = override(scenario, {"packing": {"containers": containers}})
    try:
        recorded = AcquisitionJournal(out_dir / JOURNAL_FILE).load()
    except RecordingError as e:
        raise SessionError(f"cannot resume: {e}") from e
    return _run(scenario, session["planner"], out_dir, recorded, confirm, meshcat,
                session["dry_run"])


def _run(scenario: Scenario, planner: str, out_dir: Path, recorded: list[Acquisition],
         confirm: Confirm, meshcat: Meshcat | None, dry_run: bool) -> SessionResult:
    if planner not in (*PLANNERS, COMMISSION):
        raise SessionError(f"unknown planner '{planner}': expected one of {', '.join(PLANNERS)}")
    if dry_run:
        scenario = override(scenario, {"hardware": {"robot_driver": "playback",
                                                    "sensor_driver": "simulated"}})
    check_hardware_config(scenario)
    check_scenario_files(scenario, scenario.hardware.sensor_driver == "simulated")
    # After the checks, before anything connects: a cache an update left cold compiles for
    # half a minute.
    compile_kernels()
    if scenario.robot.robot_ip:
        q_start = read_robot(scenario, must_be_ready=not dry_run)
    elif recorded:  # a dry run without a robot resumes at the last recorded pose
        q_start = recorded[-1].q
    else:
        q_start = np.asarray(scenario.robot.initial_position, float)
    preflight(scenario, q_start)
    if scenario.hardware.sensor_driver == "serial":
        check_sensor(scenario)
    scenario = override(scenario, {"robot": {"initial_position": q_start.tolist()}})
    if not dry_run and not confirm(_confirmation_text(scenario, planner, out_dir)):
        return SessionResult(out_dir, "the operator did not confirm: nothing moved",
                             "declined", EpisodeLog(acquisitions=list(recorded)),
                             resumed_from=len(recorded), planner=planner)
    # Connected first (the control script uploaded, nothing moves yet): a controller that
    # refuses leaves no session behind.
    parts = build_episode(scenario, planner, meshcat, hardware=True,
                          history=EpisodeLog(acquisitions=recorded) if recorded else None)
    try:
        _write_session(out_dir, scenario, planner, dry_run, q_start, len(recorded))
    except BaseException:
        parts.cell.hardware.close()
        raise
    monitors: list[SessionMonitor] = []
    problems: list[str] = []  # what could not be saved, and why
    saved = True  # frames.npz and report.json
    held = _HeldInterrupt()

    def make_monitor(simulator: Simulator) -> SessionMonitor:
        monitors.append(SessionMonitor(simulator, parts, out_dir, len(recorded)))
        return monitors[-1]

    def on_stop(context: Context, fault: str | None) -> None:
        """Journals what is not yet on disk, then stops the arm (bounded) unless the sender
        has already done so or the link is gone; from here on Ctrl-C waits."""
        held.hold()
        try:
            monitors[-1].record(context)
        except OSError as e:
            problems.append(f"appending to {JOURNAL_FILE} failed: {e}")
        except Exception as e:  # e.g. the map's export: the arm stops anyway
            problems.append(f"saving what was captured failed: {type(e).__name__}: {e}")
        if fault in (None, "interrupted", "sensor", "error"):
            try:
                parts.cell.hardware.robot.servo_stop(scenario.hardware.stop_deceleration)
            except (RuntimeError, ValueError) as e:
                _log.warning("stopping the arm failed: %s", e)

    try:
        try:
            run = run_loop(parts, realtime_rate=1.0, recorded=recorded,
                           make_monitor=make_monitor, on_stop=on_stop, interrupt_hint=(
                               f"the arm was stopped. Continue with `lrnbv hardware --resume "
                               f"{out_dir}`"))
        finally:
            # After on_stop (the journal on disk, the arm stopped) the drivers close before
            # the report, whose figures take longer the more poses there are, so that the
            # shutdown after a lost link waits on nothing but its own bounded steps. The
            # sensor's counters are read first: closing flushes a half-received line.
            sensor_stats = parts.cell.hardware.sensor.stats
            closing_failed = _close_drivers(parts)
        if run.error is not None:
            _log.error("unexpected error during the session", exc_info=run.error)
        result = SessionResult(out_dir, run.termination, run.fault, run.log,
                               resumed_from=len(recorded),
                               realtime_resets=monitors[-1].realtime_resets,
                               moved=not dry_run, error=run.error, planner=planner)
        try:
            write_outputs(out_dir, run, _report(planner, scenario, parts, run, result, dry_run,
                                                sensor_stats), meshcat, scenario)
        except Exception as e:  # the arm has moved: said as such, never as "nothing moved"
            saved = False
            problems.append(f"writing frames.npz and report.json failed: "
                            f"{type(e).__name__}: {e}")
    finally:
        held.release()
    if run.fault is None and not problems:
        try:
            _record_finish(out_dir, result.termination)
        except OSError as e:
            problems.append(f"marking {SESSION_FILE} finished failed: {e}")
    if run.fault == "error" or problems:
        result.termination = _after_the_fact(result, monitors[-1].written, problems, saved)
        result.fault = result.fault or "error"  # not done: what it left is not all on disk
    if closing_failed:  # everything is on disk, but the cell may not be as it should
        result.termination += f". {closing_failed}"
        result.fault = result.fault or "error"
    if held.pending:
        result.termination += " (Ctrl-C while saving waited until everything was on disk)"
    return result


def _close_drivers(parts: EpisodeDiagram) -> str:
    """Closes the cell's drivers (every one, whatever another raises); what failed, as a
    sentence, or ''."""
    try:
        parts.cell.hardware.close()
    except Exception as e:  # a driver's bug; RuntimeError and OSError are only logged
        _log.error("closing the drivers failed", exc_info=e)
        return (f"Closing the drivers failed: {type(e).__name__}: {e}; check on the pendant "
                f"that no program is running")
    return ""


def _after_the_fact(result: SessionResult, journaled: int, problems: list[str],
                    saved: bool) -> str:
    """The termination of a run that failed in an unexpected way or could not save
    everything: what happened, what is on disk, what to do."""
    what = (f"unexpected error after {result.n_poses} acquisitions (the arm "
            f"{'may have moved' if result.moved else 'did not move'}): {result.termination}"
            if result.fault == "error" else result.termination)
    on_disk = (f"on disk in {result.out_dir}: {journaled} of {result.n_poses} acquisitions "
               f"in {JOURNAL_FILE}" + (", all of them in frames.npz and report.json" if saved
                                       else ""))
    hint = (f"fix the cause, then continue with `lrnbv hardware --resume {result.out_dir}`"
            if result.moved else "")
    return ". ".join(part[0].upper() + part[1:] for part in (what, *problems, on_disk, hint)
                     if part)
