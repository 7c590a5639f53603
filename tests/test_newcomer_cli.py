"""`lrnbv` as a new user meets it (issue 14): bad input gets a named error and exit code 2 before
anything is written, results are never overwritten silently, Ctrl-C saves what was captured and
exits 130 without a traceback, and the help says what each command does."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from lrnbv_drake.cli import run as run_cli
from lrnbv_drake.cli.main import main
from lrnbv_drake.cli.out_dir import MARKERS
from lrnbv_drake.station.parts import check_scenario_files
from lrnbv_drake.station.scenario import ScenarioError, load_scenario

WAIT = 90.0  # upper bound of every wait on a subprocess; a passing run never comes near it


#: Ctrl-C as a terminal delivers it: a process inherits an ignored SIGINT, and a test runner
#: started in the background (a CI job, `make test &`) has it ignored, so the child would
#: never see the interrupt the tests send. (Not `preexec_fn`: unsafe with the runner's threads.)
AS_IN_A_TERMINAL = "import signal; signal.signal(signal.SIGINT, signal.default_int_handler)\n"


def _lrnbv(*argv: str, **kwargs) -> subprocess.Popen[str]:
    """`lrnbv ARGV` in its own process group (as a shell runs a foreground command)."""
    code = AS_IN_A_TERMINAL + "import sys; from lrnbv_drake.cli.main import main; " \
        "sys.exit(main())"
    return subprocess.Popen([sys.executable, "-c", code, *argv],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)


def _read_lines(proc: subprocess.Popen[str], n: int) -> list[str]:
    """The first `n` lines of the process's stdout, waiting at most WAIT."""
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(
        proc.stdout.readline().strip() for _ in range(n)), daemon=True)
    reader.start()
    reader.join(WAIT)
    return lines


def _wait_for(condition, what: str) -> None:
    deadline = time.monotonic() + WAIT
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {WAIT} s: {what}")
        time.sleep(0.05)


# --- Bad input: a named error, exit code 2, nothing written ----------------------------------


def test_a_mesh_in_millimetres_is_refused_with_the_scale_to_use(tmp_path, capsys):
    part = tmp_path / "part_mm.stl"
    trimesh.creation.cylinder(radius=75.0, height=150.0).export(part)  # 150 mm, read as m
    out = tmp_path / "out"
    assert main(["run", "--object", str(part), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "150 m across" in err and "--object-scale 0.001" in err
    assert not out.exists()


@pytest.mark.parametrize("argv, words", [
    (["--object-pose", "3,0,0"], "2.5 m from extraction.center"),
    (["--object-pose", "0,0,0"], "robot's base"),
    (["--scenario-text", "{object: {scale: 5}}"], "1.5 x 1 x 0.6 m"),  # a 1.5 m box
    (["--object", "teapot"], "unknown object 'teapot'"),
])
def test_impossible_placements_are_refused_before_anything_runs(argv, words, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", *argv, "--out", str(out)]) == 2
    assert words in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("command", ["run", "benchmark"])
def test_a_negative_seed_is_an_argument_error(command, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--seed", "-1", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert "argument --seed: expected an integer >= 0, got '-1'" in capsys.readouterr().err


@pytest.mark.parametrize("command", [["run"], ["benchmark", "--objects", "flange"]])
def test_out_naming_a_file_or_nothing_is_refused(command, tmp_path, capsys):
    a_file = tmp_path / "notes.txt"
    a_file.write_text("keep me")
    for out, words in ((a_file, "that is a file"), (a_file / "sub", "Not a directory"),
                       ("", "expected a folder name")):
        assert main([*command, "--out", str(out)]) == 2
        assert words in capsys.readouterr().err
    assert a_file.read_text() == "keep me"


def test_out_that_cannot_be_created_is_an_error_not_a_traceback(tmp_path, capsys, monkeypatch):
    def refuse(self, *args, **kwargs):  # as in a read-only folder (tests may run as root)
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "mkdir", refuse)
    assert main(["run", "--out", str(tmp_path / "ro" / "out")]) == 2
    assert "cannot create the folder (Permission denied)" in capsys.readouterr().err


# --- Results are never overwritten silently --------------------------------------------------


@pytest.mark.parametrize("kind", ["hardware", "benchmark", "run"])
def test_run_refuses_a_folder_holding_results(kind, tmp_path, capsys):
    (tmp_path / MARKERS[kind][0]).write_text("{}")
    assert main(["run", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"results of an earlier `lrnbv {kind}`" in err
    assert ("--overwrite" in err) == (kind == "run")
    assert (tmp_path / MARKERS[kind][0]).read_text() == "{}"
    # --overwrite replaces an earlier episode only.
    if kind != "run":
        assert main(["run", "--overwrite", "--out", str(tmp_path)]) == 2
        assert (tmp_path / MARKERS[kind][0]).read_text() == "{}"


@pytest.mark.parametrize("command", ["run", "benchmark"])
@pytest.mark.parametrize("flags, words", [
    (["--containers", "missing.yaml"], "field 'packing.containers': cannot read"),
    (["--scenario-text", "{sensor: {zone_directions: missing.csv}}"],
     "field 'sensor.zone_directions': cannot read"),
])
def test_a_file_the_episode_reads_late_is_checked_before_anything_runs(
        command, flags, words, tmp_path, capsys):
    """A catalogue is read when the report is made, after every pose: a missing one is
    refused first, and an earlier episode that --overwrite would replace is left as it was."""
    if command == "benchmark" and flags[0] == "--scenario-text":
        flags = ["--scenario", str(tmp_path / "s.yaml")]
        (tmp_path / "s.yaml").write_text("sensor: {zone_directions: missing.csv}\n")
    out = tmp_path / "out"
    out.mkdir()
    earlier = [name for name in MARKERS["run"]]
    for name in earlier:
        (out / name).write_text("earlier")
    extra = ["--overwrite"] if command == "run" else ["--objects", "flange"]
    assert main([command, *flags, *extra, "--out", str(out)]) == 2
    assert words in capsys.readouterr().err
    assert all((out / name).read_text() == "earlier" for name in earlier)


def test_a_real_board_is_not_refused_over_the_simulated_devices_files():
    """`device:` is the simulated VL53L8CX's: a session with the real board never reads it."""
    scenario = load_scenario(data="device: {zone_directions: missing.csv}")
    check_scenario_files(scenario, simulated_sensor=False)
    with pytest.raises(ScenarioError, match=r"'device\.zone_directions'"):
        check_scenario_files(scenario)


def test_a_report_page_alone_marks_an_earlier_run(tmp_path, capsys):
    """--overwrite removes every file an episode writes: a report.html left beside new
    results would describe another episode."""
    (tmp_path / "report.html").write_text("earlier")
    assert main(["run", "--out", str(tmp_path)]) == 2
    assert "(report.html)" in capsys.readouterr().err


def test_benchmark_refuses_a_run_or_session_folder(tmp_path, capsys):
    (tmp_path / "report.json").write_text("{}")
    assert main(["benchmark", "--objects", "flange", "--out", str(tmp_path)]) == 2
    assert "results of an earlier `lrnbv run`" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]


def test_a_failed_hardware_start_leaves_no_empty_folder(tmp_path, capsys):
    out = tmp_path / "cell"
    assert main(["hardware", "--robot-ip", "127.0.1.254", "--sensor-port",
                 str(tmp_path / "ttyACM9"), "--out", str(out), "--yes"]) == 2
    assert f"no serial port {tmp_path / 'ttyACM9'}" in capsys.readouterr().err
    # Nothing listens on this loopback address: the connection is refused at once.
    assert main(["hardware", "--robot-ip", "127.0.1.254", "--sensor-port", "/dev/null",
                 "--scenario-text", "{sensor: {commissioned: by hand}}", "--out", str(out),
                 "--yes"]) == 2
    err = capsys.readouterr().err
    assert "nothing moved" in err and "commissioned" not in err
    assert not out.exists()


# --- A run that finds no object exits non-zero ------------------------------------------------


def test_a_run_that_finds_no_object_exits_1(tmp_path, capsys):
    out = tmp_path / "out"
    # Clusters must have more points than two frames can give: nothing is ever an object.
    code = main(["run", "--planner", "heu", "--scenario-text",
                 "{max_poses: 2, extraction: {min_cluster_points: 100000}}",
                 "--out", str(out)])
    assert code == run_cli.EXIT_NOT_FOUND == 1
    assert "no object found" in capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert report["n_poses"] == 2 and report["estimated_box"] is None
    # ... and what it did is there: rerunning into the folder needs --overwrite.
    assert main(["run", "--planner", "heu", "--out", str(out)]) == 2


# --- Ctrl-C -----------------------------------------------------------------------------------

#: Runs `lrnbv run` with the acquisition loop printing each capture and holding after the
#: second, so that the test interrupts an episode that has captured exactly two frames.
HOLD_AFTER_TWO = AS_IN_A_TERMINAL + """
import faulthandler, sys, time
faulthandler.register(signal.SIGUSR1, all_threads=True)  # where it is, should it not exit
from lrnbv_drake.cli.main import main
from lrnbv_drake.core.acquisition import AcquisitionSequencer

step = AcquisitionSequencer.step

def step_and_hold(self, state, *args):
    before = len(state.log.acquisitions)
    state = step(self, state, *args)
    if len(state.log.acquisitions) > before:
        print(f"captured {len(state.log.acquisitions)}", flush=True)
        if len(state.log.acquisitions) == 2:
            time.sleep(600)
    return state

AcquisitionSequencer.step = step_and_hold
sys.exit(main())
"""


def test_ctrl_c_during_run_saves_what_was_captured_and_exits_130(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD_AFTER_TWO, "run", "--planner", "heu", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert _read_lines(proc, 2) == ["captured 1", "captured 2"]
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=WAIT)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGUSR1)  # its threads' stacks onto stderr, then the end
        time.sleep(2.0)
        proc.kill()
        pytest.fail(f"not exited {WAIT} s after Ctrl-C:\n{proc.communicate()[1][-6000:]}")
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert f"what was captured is in {out}" in stderr
    assert np.load(out / "frames.npz")["X_WS"].shape == (2, 4, 4)
    report = json.loads((out / "report.json").read_text())
    assert report["n_poses"] == 2 and report["fault"] == "interrupted"


#: An interrupted command, run as the program and then through `main(argv)`: the SIGINT
#: handler after each, and the exit codes.
INTERRUPTED_TWICE = AS_IN_A_TERMINAL + """
import signal, sys
from lrnbv_drake.cli import main as cli

def interrupted(args):
    raise KeyboardInterrupt

cli.COMMANDS["objects"] = interrupted
sys.argv = ["lrnbv", "objects"]
print(cli.main(["objects"]), signal.getsignal(signal.SIGINT) is signal.SIG_IGN)
print(cli.main(), signal.getsignal(signal.SIGINT) is signal.SIG_IGN)
"""


def test_an_interrupted_program_ignores_a_late_ctrl_c_and_a_caller_keeps_its_handler():
    # A second Ctrl-C during the interpreter's shutdown would otherwise end the process by
    # SIGINT, not with 130 (CI saw it in the benchmark test below).
    done = subprocess.run([sys.executable, "-c", INTERRUPTED_TWICE], capture_output=True,
                          text=True, timeout=WAIT)
    assert done.stdout.split("\n")[:2] == ["130 False", "130 True"], done.stderr


def _group_gone(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    return False


def _benchmark_interrupted(out: Path, interrupt) -> tuple[subprocess.Popen[str], str]:
    """A two-worker HEU benchmark into `out`, `interrupt(proc)` once an episode has started
    in a worker (run_episode makes its folder first); the process and its stderr once it and
    every worker have ended. Should anything fail, the whole group is killed."""
    proc = _lrnbv("benchmark", "--planners", "heu", "--objects", "horizontal_box", "--trials",
                  "3", "--jobs", "2", "--out", str(out))
    try:
        _wait_for(lambda: any((out / "runs").glob("*")) or proc.poll() is not None,
                  "an episode starts")
        interrupt(proc)
        _, stderr = proc.communicate(timeout=WAIT)
        _wait_for(lambda: _group_gone(proc.pid), "the workers end")
    except BaseException:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        raise
    return proc, stderr


def _ctrl_c_twice(proc: subprocess.Popen[str]) -> None:
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C reaches the whole foreground group
    time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGINT)


def test_ctrl_c_twice_stops_a_benchmark_at_once_and_tells_how_to_resume(tmp_path):
    out = tmp_path / "campaign"
    proc, stderr = _benchmark_interrupted(out, _ctrl_c_twice)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert "Resume with the same command" in stderr and str(out) in stderr
    summary = (out / "summary.md").read_text()
    finished = len(list((out / "episodes").glob("*.json")))
    assert f"- episodes: {finished}, finished {finished}, failed 0" in summary


def test_sigterm_stops_a_benchmark_and_its_workers_as_ctrl_c_does(tmp_path):
    """`kill PID` (a job scheduler's stop) reaches the benchmark's process alone: it must end
    its workers and write what finished, not die and leave them running."""
    out = tmp_path / "campaign"
    proc, stderr = _benchmark_interrupted(out, lambda proc: os.kill(proc.pid, signal.SIGTERM))
    assert proc.returncode == 130, stderr
    assert "Resume with the same command" in stderr
    finished = len(list((out / "episodes").glob("*.json")))
    assert f"- episodes: {finished}, finished {finished}, failed 0" in \
        (out / "summary.md").read_text()


# --- Help -------------------------------------------------------------------------------------


def test_help_describes_the_commands_and_version(capsys):
    with pytest.raises(SystemExit):
        main(["--version"])
    assert capsys.readouterr().out.startswith("lrnbv 0.")
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for words in ("Runs one reconstruction episode", "(default: lrnbv)",
                  "(default: horizontal_box)", "(default: 0.5,0,0)", "every network interface",
                  "exit status: 0 a box was found, 1 the episode found no object"):
        assert words in text


def test_sensor_record_refuses_to_replace_a_recording(tmp_path, capsys):
    recording = tmp_path / "flat_0p5m.npz"
    recording.write_bytes(b"an earlier recording")
    assert main(["sensor", "record", "--port", str(tmp_path / "ttyACM9"), "--frames", "1",
                 "--out", str(recording)]) == 2
    assert "pass --overwrite to replace it" in capsys.readouterr().err
    assert recording.read_bytes() == b"an earlier recording"


def test_run_prints_the_container_and_the_cycle_time_and_takes_a_catalogue(tmp_path, capsys):
    catalogue = tmp_path / "mine.yaml"
    catalogue.write_text("containers:\n  - {name: only one, inner: [0.5, 0.4, 0.3]}\n")
    assert main(["run", "--planner", "heu", "--seed", "0", "--out", str(tmp_path / "out"),
                 "--containers", str(catalogue)]) == 0
    printed = capsys.readouterr().out
    assert "container: only one (0.500 x 0.400 x 0.300 m inner) holds" in printed
    assert "cycle time" in printed and "arm motion" in printed
