"""Whole hardware episodes on fakes: the real RTDE driver on fake ur_rtde modules around a
lagging arm, and the simulated sensor board behind the real serial driver (loop://).

A short HEU episode (two poses, the arm starting at the first) runs to its cap; another gets a
protective stop on the way to its second pose and is then resumed. Every wait is bounded and
nothing asserts on how long anything took."""

from __future__ import annotations

import dataclasses as dc
import gc
import json
import shutil
import threading
import time

import fake_rtde
import numpy as np
import pytest
from pydrake.common.yaml import yaml_dump_typed

from lrnbv_drake.cli.main import main
from lrnbv_drake.core.estimation.track import EpisodeEstimator
from lrnbv_drake.core.mapping.occupancy_map import OccupancyMap
from lrnbv_drake.core.planning.heu import heu_poses
from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.safety import RobotFault
from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.drivers.rtde_robot import RtdeRobot
from lrnbv_drake.drivers.tof_serial import SensorError, SensorTimeout, ToFSerialReader
from lrnbv_drake.experiments import episode, session, session_preflight
from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.experiments.recording import AcquisitionJournal, RecordingError
from lrnbv_drake.experiments.session import SESSION_FILE, SessionError, resume, run_session
from lrnbv_drake.experiments.session_monitor import JOURNAL_FILE, MAP_FILE
from lrnbv_drake.station.cell import make_cell
from lrnbv_drake.station.cell_models import HardwareDrivers, place_object
from lrnbv_drake.station.motion import MotionPlanner
from lrnbv_drake.station.scenario import load_scenario

pytestmark = pytest.mark.usefixtures("compiled_kernels")

SCENARIO = """
max_poses: 2
robot: {robot_ip: fake-ur5e}
sensor: {commissioned: "the simulated board, on the CAD mount"}
hardware: {sensor_driver: simulated}
"""


def _hardware_heu(tmp_path, out, *flags) -> int:
    """`lrnbv hardware` with SCENARIO from a file, HEU, into `out`: its exit code."""
    file = tmp_path / "cell.yaml"
    file.write_text(SCENARIO)
    return main(["hardware", "--scenario", str(file), "--out", str(out), "--planner", "heu",
                 *flags, "--yes"])


def _journal_lines(out) -> int:
    path = out / JOURNAL_FILE
    return len(path.read_text().splitlines()) if path.exists() else 0


@pytest.fixture(autouse=True)
def _garbage_collected_here():
    """Collects each test's garbage on the main thread. A session that failed keeps its
    diagram and Meshcat in a cycle through the error's traceback, and Drake aborts the
    process when a Meshcat is destroyed on another thread, which the next collection may be
    (a later test's reader thread was, about one run in five on two workers)."""
    yield
    gc.collect()


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(data=SCENARIO)


@pytest.fixture(scope="module")
def q_first_pose(scenario):
    """Joints at HEU's first viewpoint: the episodes start there, so only one motion remains."""
    poses = heu_poses(place_object(scenario).mesh.bounds.mean(axis=0), scenario.heu)
    return MotionPlanner(scenario).plan(kinematics.HOME.copy(), poses[0]).q_target


@pytest.fixture(scope="module")
def finished(scenario, q_first_pose, tmp_path_factory):
    """A whole episode; the arm notes how many acquisitions were on disk at every servoJ. It
    lags its targets like servoJ with a 0.1 s lookahead, so it is still moving for a while
    after the planner's trajectory has ended."""
    out = tmp_path_factory.mktemp("heu")
    arm = fake_rtde.FakeArm(q_first_pose, tau=0.1)
    on_disk = []
    arm.on_servo = lambda arm, q: on_disk.append((q, _journal_lines(out)))
    questions = []
    with pytest.MonkeyPatch.context() as mp:
        fake_rtde.install(mp, arm)
        result = run_session(scenario, "heu", out,
                             confirm=lambda text: questions.append(text) or True)
    return result, out, arm, on_disk, questions


def test_the_episode_runs_to_its_cap_on_the_real_drivers(finished):
    result, out, arm, _, questions = finished
    assert result.fault is None and result.termination == "reached the cap of 2 poses"
    assert len(questions) == 1 and "fake-ur5e" in questions[0]
    assert [kind for kind, _ in arm.connections] == ["receive", "receive", "control"]
    names = [name for name in arm.names() if name != "kickWatchdog"]
    assert names.count("servoJ") > 10 and names.count("setWatchdog") == 1
    assert names[-4:-2] == ["servoStop", "stopScript"]  # then both disconnects, in parallel
    assert sorted(names[-2:]) == ["disconnect-control", "disconnect-receive"]
    assert result.moved
    report = json.loads((out / "report.json").read_text())
    assert report["fault"] is None and report["n_poses"] == 2
    assert report["sensor_stats"]["frames"] > 2 and report["sensor_stats"]["bad_crc"] == 0
    assert [p["info"]["ellipse_index"] for p in report["poses"]] == [0, 1]
    frames = np.load(out / "frames.npz")
    assert frames["q"].shape == (2, 6)
    assert (out / MAP_FILE).stat().st_size > 0
    runs = json.loads((out / SESSION_FILE).read_text())["runs"]
    assert len(runs) == 1 and runs[0]["recorded_before"] == 0


def test_a_stop_during_a_move_halts_the_arm_short_of_the_view_on_the_real_drivers(
        scenario, q_first_pose, tmp_path, monkeypatch):
    """The stop check runs in a thread beside the move to the second view (this stop says
    stop after one pose once the arm has begun that move; the estimate is the cell box's,
    made at once): the arm brakes and comes to rest short of the view, and the session ends
    with the one pose on disk and no fault."""
    moving = threading.Event()
    arm = fake_rtde.FakeArm(q_first_pose, tau=0.1)
    targets = []

    def servo(arm, q):
        targets.append(np.array(q, float))
        if np.abs(targets[-1] - q_first_pose).max() > 1e-3:
            moving.set()
    arm.on_servo = servo

    class StopOnceMoving:
        def update(self, track):
            assert moving.wait(10.0)
            return "stop after one pose"
    monkeypatch.setattr(episode, "make_stop", lambda planner, scenario: StopOnceMoving())
    # The cell boxes for the estimate, at once: the stop comes as the move begins.
    monkeypatch.setattr(episode, "episode_estimator", lambda scenario: EpisodeEstimator(None))
    fake_rtde.install(monkeypatch, arm)
    result = run_session(scenario, "heu", tmp_path / "out", confirm=lambda text: True)
    assert result.fault is None and result.termination == "stop after one pose"
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["n_poses"] == 1
    poses = heu_poses(place_object(scenario).mesh.bounds.mean(axis=0), scenario.heu)
    second = MotionPlanner(scenario).plan(q_first_pose, poses[1]).q_target
    assert np.abs(targets[-1] - second).max() > 0.01  # halted short of the second view
    # Braked over several commands, each step shorter than the one before, not cut off.
    steps = np.abs(np.diff(targets, axis=0)).max(axis=1)
    braking = steps[np.argmax(steps):]
    assert len(braking) >= 4 and np.all(np.diff(braking) < 0)
    assert braking[-1] < braking[0] / 3


def test_every_acquisition_is_on_disk_before_the_arm_leaves_its_pose(finished):
    result, out, _, on_disk, _ = finished
    recorded = AcquisitionJournal(out / JOURNAL_FILE).load()
    assert len(recorded) == 2
    for a, logged in zip(recorded, result.log.acquisitions, strict=True):
        np.testing.assert_array_equal(a.frame.distance_mm, logged.frame.distance_mm)
        np.testing.assert_allclose(a.X_WS, logged.X_WS)
    departures, held, repeats = 0, None, 0
    for q, lines in on_disk:
        if held is not None and np.array_equal(q, held):
            repeats += 1
            continue
        # The arm leaves a pose it was parked at (the same command for at least 40 ms).
        if repeats >= 5:
            for k, a in enumerate(recorded):
                if np.abs(held - a.q).max() < 1e-3:
                    departures += 1
                    assert lines >= k + 1, f"left acquisition {k}'s pose with {lines} on disk"
        held, repeats = q, 0
    assert departures == 1  # the arm left the first pose for the second, and that is all


def test_each_frame_was_captured_with_the_arm_still_at_its_recorded_pose(finished, scenario):
    _, out, _, _, _ = finished
    cell = make_cell(scenario).diagram
    context = cell.CreateDefaultContext()
    tof = cell.GetSubsystemByName("tof")
    for a in AcquisitionJournal(out / JOURNAL_FILE).load():
        cell.GetInputPort("ur5e.position").FixValue(context, a.q)
        expected = tof.CaptureFrame(tof.GetMyContextFromRoot(context),
                                    sequence=a.frame.sequence)
        both = a.frame.valid & expected.valid
        assert both.sum() >= 48
        # The gate passes a frame once every joint is slower than still_speed; this arm is
        # then within still_speed * tau = 1 mrad of where it rendered the frame, which moves a
        # zone's footprint about 0.5 mm and so a zone straddling an edge by a few mm. A frame
        # from a moving arm (about 1 rad/s over the gate's window) is cm off in most zones.
        off = np.abs(a.frame.distance_mm[both].astype(int) - expected.distance_mm[both])
        assert np.count_nonzero(off > 2) <= 3 and off.max() <= 10


@pytest.fixture(scope="module")
def stopped(scenario, q_first_pose, tmp_path_factory):
    """An episode whose arm goes into a protective stop on its way to the second pose."""
    out = tmp_path_factory.mktemp("stopped")
    arm = fake_rtde.FakeArm(q_first_pose)
    injected = []

    def stop_when_moving(arm, q):
        if not injected and _journal_lines(out) == 1 and np.abs(q - q_first_pose).max() > 0.01:
            arm.protective_stop, arm.safety_mode = True, 3
            injected.append(len(arm.calls))
    arm.on_servo = stop_when_moving
    with pytest.MonkeyPatch.context() as mp:
        fake_rtde.install(mp, arm)
        result = run_session(scenario, "heu", out, confirm=lambda text: True)
    return result, out, arm, injected


def test_a_protective_stop_stops_saves_and_explains(stopped):
    result, out, arm, injected = stopped
    assert injected, "the arm never left the first pose"
    assert result.fault == "protective_stop"
    assert "protective stop on fake-ur5e" in result.termination
    assert "lrnbv hardware --resume" in result.termination
    after = [c.name for c in arm.calls[injected[0]:] if c.name != "kickWatchdog"]
    assert after.count("servoJ") <= 3  # the receiver sees the stop within a period or two
    assert "servoStop" in after
    assert _journal_lines(out) == 1
    report = json.loads((out / "report.json").read_text())
    assert report["fault"] == "protective_stop" and report["n_poses"] == 1


def test_resume_continues_the_episode_from_where_the_arm_is(stopped, tmp_path):
    _, out, old_arm, _ = stopped
    arm = fake_rtde.FakeArm(old_arm.q)  # cleared on the pendant; the arm did not move since
    with pytest.MonkeyPatch.context() as mp:
        fake_rtde.install(mp, arm)
        result = resume(out, confirm=lambda text: True)
    assert result.fault is None and result.termination == "reached the cap of 2 poses"
    assert result.resumed_from == 1 and result.n_poses == 2
    recorded = AcquisitionJournal(out / JOURNAL_FILE).load()
    assert [a.index for a in recorded] == [0, 1]
    # HEU carries on with the next ellipse pose; diagram time carries on too.
    assert [a.info["ellipse_index"] for a in recorded] == [0, 1]
    assert recorded[1].time > recorded[0].time + 1.0
    np.testing.assert_allclose(recorded[1].q, arm.q, atol=1e-3)
    runs = json.loads((out / SESSION_FILE).read_text())["runs"]
    assert [r["recorded_before"] for r in runs] == [0, 1]
    np.testing.assert_allclose(runs[1]["q_start"], old_arm.q, atol=1e-9)


def _when_moving_to_the_second_pose(out, q_first_pose, act):
    """An on_servo hook that calls act(arm) once, on the way from the first pose to the
    second (one acquisition on disk, the command away from the first pose)."""
    def hook(arm, q):
        if not hook.at and _journal_lines(out) == 1 and np.abs(q - q_first_pose).max() > 0.01:
            hook.at = time.monotonic()
            act(arm)
    hook.at = None
    return hook


def test_a_lost_link_ends_the_run_without_blocking_calls(
        scenario, q_first_pose, tmp_path, monkeypatch):
    """The link goes silent mid-motion: stale getters, isConnected still true, servoJ still
    "accepted", stops that would block. The clock's silence ends the run: no blocking stop is
    called and the drivers are closed before the outputs are written, with everything captured
    on disk. The 3 s bound on that shutdown is asserted against the controller emulator, which
    measures the machine's starvation (tests/test_hardware_faults.py)."""
    arm = fake_rtde.FakeArm(q_first_pose)
    arm.on_servo = hook = _when_moving_to_the_second_pose(tmp_path, q_first_pose,
                                                          fake_rtde.FakeArm.drop_link)
    fake_rtde.install(monkeypatch, arm)
    closed, written = [], []  # when RtdeRobot.disconnect returned, when the outputs began
    disconnect, write = RtdeRobot.disconnect, session.write_outputs
    monkeypatch.setattr(RtdeRobot, "disconnect",
                        lambda self: disconnect(self) or closed.append(time.monotonic()))
    monkeypatch.setattr(session, "write_outputs",
                        lambda *args: written.append(time.monotonic()) or write(*args))
    result = run_session(scenario, "heu", tmp_path, confirm=lambda text: True)
    assert hook.at is not None and result.fault == "disconnected" and result.moved
    assert "no new RTDE data" in result.termination and "watchdog" in result.termination
    dropped = [c for c in arm.calls if c.wall_time >= hook.at]
    assert not {"servoStop", "stopScript"} & {c.name for c in dropped}
    last_servo = max(c.wall_time for c in dropped if c.name == "servoJ")
    assert last_servo < closed[-1] < written[0]  # the stream ended, then closed, then the report
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["fault"] == "disconnected" and report["n_poses"] == 1 == _journal_lines(tmp_path)


def test_an_error_after_motion_says_what_happened_and_what_is_on_disk(
        scenario, q_first_pose, tmp_path, monkeypatch, capsys):
    """The disk fills up while the second acquisition is journaled: the CLI reports a fault
    after motion (exit 1), not "nothing moved" (exit 2), and says what is on disk."""
    arm = fake_rtde.FakeArm(q_first_pose)
    fake_rtde.install(monkeypatch, arm)
    append = AcquisitionJournal.append

    def full_disk(journal, acquisition):
        if acquisition.index == 1:
            raise OSError(28, "No space left on device")
        append(journal, acquisition)
    monkeypatch.setattr(AcquisitionJournal, "append", full_disk)
    out = tmp_path / "out"
    assert _hardware_heu(tmp_path, out) == 1
    err = capsys.readouterr().err
    assert "nothing moved" not in err and "STOPPED (error)" in err
    assert "No space left on device" in err and "the arm may have moved" in err
    assert "1 of 2 acquisitions in acquisitions.jsonl, all of them in frames.npz" in err
    assert f"--resume {out}" in err
    assert np.load(out / "frames.npz")["q"].shape == (2, 6) and _journal_lines(out) == 1


def test_a_report_that_fails_after_motion_is_not_called_nothing_moved(
        scenario, q_first_pose, tmp_path, monkeypatch, capsys):
    """Whatever fails while the report is made, the arm has moved by then: the CLI says so
    (exit 1) and where the acquisitions are, never "nothing moved" (exit 2)."""
    fake_rtde.install(monkeypatch, fake_rtde.FakeArm(q_first_pose))

    def broken_report(*args, **kwargs):
        raise ValueError("the catalogue changed under the session")
    monkeypatch.setattr(session, "episode_report", broken_report)
    out = tmp_path / "out"
    assert _hardware_heu(tmp_path, out) == 1
    err = capsys.readouterr().err
    assert "nothing moved" not in err
    assert "ValueError: the catalogue changed under the session" in err
    assert "2 of 2 acquisitions in acquisitions.jsonl" in err and _journal_lines(out) == 2


def test_a_map_export_that_fails_still_stops_the_arm_and_writes_the_rest(
        scenario, q_first_pose, tmp_path, monkeypatch, capsys):
    """Saving the map raises something other than an OSError (pyoctomap's RuntimeError): the
    arm is still stopped (servoStop before the script stops), frames.npz and report.json are
    still written, and the CLI says what failed (exit 1), not a traceback."""
    arm = fake_rtde.FakeArm(q_first_pose)
    fake_rtde.install(monkeypatch, arm)

    def broken_export(self, path):
        raise RuntimeError("pyoctomap refused to prune node")
    monkeypatch.setattr(OccupancyMap, "export_octomap", broken_export)
    out = tmp_path / "out"
    assert _hardware_heu(tmp_path, out) == 1
    err = capsys.readouterr().err
    assert "Saving what was captured failed: RuntimeError: pyoctomap refused" in err
    names = [n for n in arm.names() if n != "kickWatchdog"]
    assert "servoStop" in names[names.index("servoJ"):names.index("stopScript")]
    assert (out / "frames.npz").exists() and (out / "report.json").exists()
    assert _journal_lines(out) >= 1


def test_a_driver_that_fails_to_close_still_leaves_the_outputs(
        scenario, q_first_pose, tmp_path, monkeypatch, capsys):
    """The drivers close before the report is written, its sensor counters read before they
    close (closing flushes a half-received line). A close that raises anything, not only
    the RuntimeError and OSError every driver's close is allowed, costs neither frames.npz
    nor report.json nor the finished mark (nothing is lost, so there is nothing to resume),
    and the CLI says what failed and what to check (exit 1)."""
    fake_rtde.install(monkeypatch, fake_rtde.FakeArm(q_first_pose))
    close, at_close = HardwareDrivers.close, []

    def broken_close(drivers):
        at_close.append(drivers.sensor.stats)
        close(drivers)
        # What the flush of a half-received line does to the counters (the real board's is
        # mid-line at any moment, the simulated one between frames here).
        monkeypatch.setattr(ToFSerialReader, "stats", property(
            lambda reader: dc.replace(at_close[0], truncated=at_close[0].truncated + 1)))
        raise TypeError("a driver's close took no arguments")
    monkeypatch.setattr(HardwareDrivers, "close", broken_close)
    out = tmp_path / "out"
    assert _hardware_heu(tmp_path, out) == 1
    err = capsys.readouterr().err
    assert "STOPPED (error)" in err and "Closing the drivers failed: TypeError: a driver's " \
        "close took no arguments; check on the pendant that no program is running" in err
    assert np.load(out / "frames.npz")["q"].shape == (2, 6)
    report = json.loads((out / "report.json").read_text())
    assert report["n_poses"] == 2 and report["sensor_stats"] == dc.asdict(at_close[0])
    assert "finished" in json.loads((out / SESSION_FILE).read_text())


def test_a_failure_while_the_episode_is_built_closes_the_robot(scenario, tmp_path, monkeypatch):
    """The robot is connected and the control script uploaded before the rest of the diagram
    is built: if that fails, the script is stopped and both interfaces closed."""
    arm = fake_rtde.FakeArm(kinematics.HOME.copy())
    fake_rtde.install(monkeypatch, arm)

    def broken_policy(*args, **kwargs):
        raise ValueError("the policy could not be built")
    monkeypatch.setattr(episode, "make_policy", broken_policy)
    monkeypatch.setattr(session, "preflight", lambda *args: None)
    with pytest.raises(ValueError, match="the policy could not be built"):
        run_session(scenario, "heu", tmp_path / "out", confirm=lambda text: True)
    names = arm.names()
    assert "stopScript" in names and "disconnect-control" in names
    assert "servoJ" not in names


def test_a_bad_catalogue_is_refused_before_the_arm_is_reached(scenario, tmp_path, monkeypatch,
                                                              capsys):
    fake_rtde.install(monkeypatch, fake_rtde.FakeArm(kinematics.HOME.copy()))
    out = tmp_path / "out"
    assert _hardware_heu(tmp_path, out, "--containers", str(tmp_path / "missing.yaml")) == 2
    assert "field 'packing.containers': cannot read" in capsys.readouterr().err
    assert not out.exists()


def test_resume_takes_a_corrected_catalogue_and_refuses_a_preset(stopped, tmp_path,
                                                                 monkeypatch, capsys):
    """The recovery from a catalogue moved or mistyped: `--resume DIR --containers FILE`."""
    _, out, _, _ = stopped
    copy = tmp_path / "session"
    shutil.copytree(out, copy)
    recorded = json.loads((copy / SESSION_FILE).read_text())
    recorded.pop("finished", None)  # the module's resume test may have finished it
    (copy / SESSION_FILE).write_text(json.dumps(recorded))
    catalogue = tmp_path / "boxes.yaml"
    catalogue.write_text("containers: [{name: only, inner: [0.5, 0.5, 0.5]}]\n")
    used = []

    def stop_at_the_first_check(scenario):
        used.append(scenario)
        raise SessionError("stopped by the test")
    monkeypatch.setattr(session, "check_hardware_config", stop_at_the_first_check)
    with pytest.raises(SessionError, match="stopped by the test"):
        resume(copy, confirm=lambda text: True, containers=str(catalogue))
    assert used[0].packing.containers == str(catalogue)
    assert main(["hardware", "--resume", str(copy), "--preset", "paper"]) == 2
    assert "drop --preset" in capsys.readouterr().err


def test_speed_scaling_refuses_the_start(scenario, q_first_pose, tmp_path, monkeypatch):
    arm = fake_rtde.FakeArm(q_first_pose)
    arm.target_speed_fraction = arm.speed_scaling = 0.7
    fake_rtde.install(monkeypatch, arm)
    with pytest.raises(RobotFault, match="speed slider at 70%") as info:
        run_session(scenario, "heu", tmp_path, confirm=lambda text: True)
    assert info.value.kind == "speed_scaling"
    assert [kind for kind, _ in arm.connections] == ["receive"]


def test_resume_rebuilds_lrnbv_and_does_not_capture_the_start_pose_again(tmp_path):
    """A dry-run folder made from a simulated LR-NBV episode of two poses, resumed for one
    more: the policy goes on at its next iteration, straight to planning."""
    scenario = load_scenario(data="max_poses: 2")
    recorded = run_episode(scenario, "lrnbv", tmp_path / "sim").log.acquisitions
    out = tmp_path / "session"
    out.mkdir()
    journal = AcquisitionJournal(out / JOURNAL_FILE)
    for a in recorded:
        journal.append(a)
    more = load_scenario(data="max_poses: 3", defaults=scenario)
    (out / SESSION_FILE).write_text(json.dumps({
        "planner": "lrnbv", "dry_run": True, "scenario": yaml_dump_typed(more), "runs": []}))

    def never(text):
        raise AssertionError("a dry run asked to move the robot")
    result = resume(out, confirm=never)
    assert result.fault is None and result.n_poses == 3 and result.resumed_from == 2
    assert [a.info.get("iteration") for a in result.log.acquisitions] == [None, 0, 1]
    assert result.log.acquisitions[2].time > recorded[1].time
    assert len(AcquisitionJournal(out / JOURNAL_FILE).load()) == 3


def test_a_dry_run_moves_nothing_and_only_reads_the_robot(scenario, q_first_pose, tmp_path,
                                                          monkeypatch):
    arm = fake_rtde.FakeArm(q_first_pose)
    fake_rtde.install(monkeypatch, arm)
    dry = load_scenario(data="max_poses: 1", defaults=scenario)

    def never(text):
        raise AssertionError("a dry run asked to move the robot")
    result = run_session(dry, "heu", tmp_path, confirm=never, dry_run=True)
    assert result.fault is None and result.n_poses == 1
    assert [kind for kind, _ in arm.connections] == ["receive"]
    assert not [c for c in arm.calls if c.name == "servoJ"]
    np.testing.assert_allclose(result.log.acquisitions[0].q, q_first_pose, atol=1e-9)
    assert json.loads((tmp_path / SESSION_FILE).read_text())["dry_run"]


def test_without_confirmation_nothing_connects_for_control(scenario, q_first_pose, tmp_path,
                                                            monkeypatch):
    arm = fake_rtde.FakeArm(q_first_pose)
    fake_rtde.install(monkeypatch, arm)
    result = run_session(scenario, "heu", tmp_path, confirm=lambda text: False)
    assert result.fault == "declined" and "nothing moved" in result.termination
    assert [kind for kind, _ in arm.connections] == ["receive"]
    assert not (tmp_path / SESSION_FILE).exists()


def test_a_start_pose_in_collision_is_refused_before_anything_moves(scenario, tmp_path,
                                                                     monkeypatch):
    q = kinematics.HOME.copy() + np.array([0, 1.2, 0, 0, 0, 0])  # the forearm in the table
    arm = fake_rtde.FakeArm(q)
    fake_rtde.install(monkeypatch, arm)
    with pytest.raises(SessionError, match="collide with the modelled cell"):
        run_session(scenario, "heu", tmp_path, confirm=lambda text: True)
    assert [kind for kind, _ in arm.connections] == ["receive"]


def test_a_silent_sensor_is_found_before_anything_moves(scenario, q_first_pose, tmp_path,
                                                        monkeypatch):
    arm = fake_rtde.FakeArm(q_first_pose)
    fake_rtde.install(monkeypatch, arm)
    monkeypatch.setattr(session_preflight, "SENSOR_CHECK_TIMEOUT", 0.3)
    silent = load_scenario(data="hardware: {sensor_driver: serial}\n"
                                "sensor: {serial_port: 'loop://'}", defaults=scenario)
    with pytest.raises(SensorTimeout, match="no frame from loop://"):
        run_session(silent, "heu", tmp_path, confirm=lambda text: True)
    assert [kind for kind, _ in arm.connections] == ["receive"]


def test_a_sensor_at_another_resolution_is_found_before_anything_moves(
        scenario, q_first_pose, tmp_path, monkeypatch):
    arm = fake_rtde.FakeArm(q_first_pose)
    fake_rtde.install(monkeypatch, arm)

    class FourByFourBoard(ToFSerialReader):
        def wait_for_frame(self, newer_than_sequence=0, timeout=None):
            return ToFFrame.empty(4, sequence=1)

    monkeypatch.setattr(session_preflight, "ToFSerialReader", FourByFourBoard)
    serial = load_scenario(data="hardware: {sensor_driver: serial}\n"
                                "sensor: {serial_port: 'loop://'}", defaults=scenario)
    with pytest.raises(SensorError, match="loop:// streams 4x4 zones"):
        run_session(serial, "heu", tmp_path, confirm=lambda text: True)
    assert [kind for kind, _ in arm.connections] == ["receive"]


def test_a_folder_with_a_session_is_not_overwritten(finished, scenario):
    with pytest.raises(SessionError, match="--resume"):
        run_session(scenario, "heu", finished[1], confirm=lambda text: True)


def test_the_journal_drops_a_torn_last_line(finished, tmp_path):
    lines = (finished[1] / JOURNAL_FILE).read_text().splitlines()
    torn = tmp_path / JOURNAL_FILE
    torn.write_text(lines[0] + "\n" + lines[1][: len(lines[1]) // 2])
    assert [a.index for a in AcquisitionJournal(torn).load()] == [0]
    torn.write_text(lines[0][:10] + "\n" + lines[1] + "\n")
    with pytest.raises(RecordingError, match="line 1"):
        AcquisitionJournal(torn).load()


def test_an_append_after_a_torn_line_keeps_every_acquisition(finished, tmp_path):
    """A crash (or a full disk) mid-append leaves half a line; the resumed run's appends must
    not join it, and its bytes are kept aside."""
    recorded = AcquisitionJournal(finished[1] / JOURNAL_FILE).load()
    lines = (finished[1] / JOURNAL_FILE).read_text().splitlines()
    dut = AcquisitionJournal(tmp_path / JOURNAL_FILE)
    half = lines[1][: len(lines[1]) // 2]
    dut.path.write_text(lines[0] + "\n" + half)
    dut.append(recorded[1])
    dut.append(recorded[1])
    assert [a.index for a in dut.load()] == [0, recorded[1].index, recorded[1].index]
    assert dut.torn_path.read_text() == half + "\n"


@pytest.mark.parametrize("argv, words", [
    (["hardware", "--resume", "x", "--out", "y"], "drop --out"),
    (["hardware", "--out", "y"], "--robot-ip and --sensor-port required"),
    (["hardware"], "--out DIR is required"),
])
def test_the_cli_rejects_flag_combinations_it_cannot_run(argv, words, capsys):
    assert main(argv) == 2
    assert words in capsys.readouterr().err


def test_the_cli_resumes_nothing_from_an_empty_folder(tmp_path, capsys):
    assert main(["hardware", "--resume", str(tmp_path), "--yes"]) == 2
    assert "nothing to resume" in capsys.readouterr().err


def test_a_finished_session_is_not_resumed(tmp_path, capsys):
    """A dry run whose planner stopped by itself (the pose cap) is finished: resuming it says
    so and plans nothing, where it used to go on planning past the stop."""
    def never(text):
        raise AssertionError("a dry run asked to move the robot")
    out = tmp_path / "session"
    first = run_session(load_scenario(data="max_poses: 1"), "heu", out, confirm=never,
                        dry_run=True)
    assert first.fault is None and first.n_poses == 1
    assert json.loads((out / SESSION_FILE).read_text())["finished"] == first.termination
    with pytest.raises(SessionError, match=r"is finished .*nothing to resume"):
        resume(out, confirm=never)
    assert main(["hardware", "--resume", str(out), "--yes"]) == 2
    assert "is finished" in capsys.readouterr().err
    assert len(AcquisitionJournal(out / JOURNAL_FILE).load()) == 1
