"""Faults on the real cell, end to end (issue 12): `lrnbv hardware` drives the emulated UR
controller (tests/ur_emulator) through the real ur_rtde client, which the driver runs in its
own child process, with frames from the simulated board; one test per fault.

Each test asserts on what the emulator received and did (its record and state) and on the
files on disk. The only time bounds are the issue's: a fault ends the session within 5 s, a
lost link's drivers are closed within 3 s of its being noticed (`hardware.rtde_timeout`,
0.5 s, after it happened), and the watchdog stops the script within 1 s of the session's
death. The sessions run in this process (the CLI's `main`), except the one that is killed.
"""

from __future__ import annotations

import itertools
import subprocess
import sys
import time
from collections.abc import Callable

import pytest
from ur_emulator import RtdeClientProcess, UrControllerEmulator, worker_host
from ur_emulator.record import starved_since
from ur_emulator.sessions import (
    WhenMoving,
    cli_args,
    first_pose,
    journal_lines,
    noticed_by,
    on_disk,
    servoj_times,
    time_limit,
    write_scenario,
)

from lrnbv_drake.cli.main import main
from lrnbv_drake.core.robot.safety import RobotFault
from lrnbv_drake.drivers.rtde_robot import RtdeRobot
from lrnbv_drake.station.hardware_config import HardwareConfig

pytest.importorskip("rtde_control")
pytestmark = pytest.mark.usefixtures("compiled_kernels")

TEST_TIMEOUT = 60.0  # seconds, per test
_addresses = itertools.count(128)  # test_ur_emulator.py counts from 0 in the same worker


def _emulator() -> UrControllerEmulator:
    return UrControllerEmulator(host=worker_host(next(_addresses)), q0=first_pose(),
                                unlock_delay=0.5, lifetime=120.0)


def _power_on(emu: UrControllerEmulator) -> None:
    """After an emergency stop: release the button, then power on and release the brakes
    through the dashboard server, as an operator does."""
    emu.clear_faults()
    with RtdeClientProcess(emu.host) as client:
        client.connect("dashboard")
        client.call("dashboard", "powerOn")
        client.call("dashboard", "brakeRelease")


#: fault: (how to inject it, RobotFault.kind, words of the message, how to recover)
FAULTS: dict[str, tuple[Callable[[UrControllerEmulator], None], str, str,
                        Callable[[UrControllerEmulator], None]]] = {
    "protective_stop": (lambda emu: emu.inject("protective_stop"), "protective_stop",
                        "clear the stop on the pendant", UrControllerEmulator.clear_faults),
    "emergency_stop": (lambda emu: emu.inject("emergency_stop"), "emergency_stop",
                       "release the emergency stop button", _power_on),
    "speed_scaling": (lambda emu: emu.set_speed_scaling(0.5), "speed_scaling",
                      "Set the speed slider on the pendant to 100 %",
                      lambda emu: emu.set_speed_scaling(1.0)),
    "freeze": (UrControllerEmulator.freeze, "disconnected", "no new RTDE data",
               UrControllerEmulator.unfreeze),
    "link_reset": (UrControllerEmulator.reset_links, "disconnected",
                   "lost the RTDE connection", lambda emu: None),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_fault_mid_motion_stops_saves_explains_and_resumes(fault, tmp_path, capsys,
                                                             monkeypatch):
    inject, kind, words, recover = FAULTS[fault]
    scenario, out = write_scenario(tmp_path), tmp_path / "out"
    noticed = []  # when the session made each RobotFault: when it noticed the fault
    made = RobotFault.__init__
    monkeypatch.setattr(RobotFault, "__init__",
                        lambda self, *a, **k: noticed.append(time.time()) or made(self, *a, **k))
    closed = []  # when each RtdeRobot.disconnect returned: the link's shutdown done
    disconnect = RtdeRobot.disconnect
    monkeypatch.setattr(RtdeRobot, "disconnect",
                        lambda self: disconnect(self) or closed.append(time.time()))
    with time_limit(TEST_TIMEOUT), _emulator() as emu:
        trigger = WhenMoving(emu, out, first_pose(), lambda: inject(emu))
        code = main(cli_args(emu, scenario, out))
        ended = time.time()
        trigger.join()
        err = capsys.readouterr().err
        record = emu.record()  # before recovering: a frozen link's packages arrive then
        # Nothing of the session's runs on: the stop, the watchdog (a frozen link), the
        # dashboard (after a reset, ur_rtde reconnects and uploads its script again) or
        # stopScript ended every script it started.
        assert not emu.state()["program_running"]
        assert trigger.at is not None, f"the arm never left the first pose; the session:\n{err}"
        assert code == 1 and f"STOPPED ({kind})" in err and words in err
        assert "lrnbv hardware --resume OUT_DIR" in err and "nothing moved" not in err
        # Every bound is wall time on a loaded machine: it gets the CPU starvation the
        # emulator measured since the fault, as noticed_by does (a real cell is not starved).
        starved = starved_since(record, trigger.at)
        assert ended - trigger.at < 5.0 + starved
        if kind == "disconnected":  # noticed (after rtde_timeout), then shut down in 3 s
            at = min(t for t in noticed if t >= trigger.at)
            assert min(t for t in closed if t >= at) - at < 3.0 + starved
        assert max(servoj_times(record)) < noticed_by(record, trigger.at)
        assert record["watchdog"][0]["min_frequency"] == HardwareConfig().watchdog_frequency
        assert on_disk(out) == (1, 1, 1)  # the acquisition before the fault, everywhere
        recover(emu)
        assert main(["hardware", "--resume", str(out), "--yes"]) == 0
        assert on_disk(out) == (2, 2, 2)
        assert not emu.state()["program_running"]


def test_the_watchdog_stops_the_script_within_1_s_when_the_session_is_killed(tmp_path):
    scenario, out = write_scenario(tmp_path), tmp_path / "out"
    with time_limit(TEST_TIMEOUT), _emulator() as emu:
        log = tmp_path / "session.err"
        with log.open("wb") as err:
            session = subprocess.Popen([sys.executable, "-m", "lrnbv_drake.cli.main",
                                        *cli_args(emu, scenario, out)],
                                       stdout=subprocess.DEVNULL, stderr=err)
        killed = []
        trigger = WhenMoving(emu, out, first_pose(),
                             lambda: killed.append(time.time()) or session.kill())
        try:
            session.wait(45.0)
        finally:
            session.kill()
            trigger.join()
        assert killed, ("the arm never left the first pose; the session exited "
                        f"{session.returncode}:\n{log.read_text()[-3000:]}")
        record = emu.wait_for(lambda r: r["watchdog_trips"], timeout=2.0)
        (trip,) = record["watchdog_trips"]
        # On a loaded machine the emulator itself notices late by the CPU it was starved of.
        assert trip["t"] - killed[0] < 1.0 + starved_since(record, killed[0])
        assert [p["reason"] for p in record["program"] if p["event"] == "stopped"] == \
            ["RTDE watchdog: no input update"]
        state = emu.wait_for(lambda s: s["links"] == 0, timeout=3.0, what="state")
        assert not state["program_running"] and state["links"] == 0  # the client exited too
        assert journal_lines(out) == 1


@pytest.mark.parametrize("setup, flags, words", [
    pytest.param(lambda emu: emu.set_speed_scaling(0.5), [],
                 ("nothing moved", "speed slider at 50%"), id="speed-scaling"),
    pytest.param(lambda emu: emu.inject("not_in_remote_control"), [],
                 ("nothing moved", "Remote Control mode"), id="not-in-remote-control"),
    pytest.param(lambda emu: None, ["--scenario-text", "{hardware: {max_speed_fraction: 1.5}}"],
                 ("field 'hardware.max_speed_fraction'",), id="max-speed-fraction"),
])
def test_a_cell_that_cannot_run_is_refused_before_anything_moves(setup, flags, words,
                                                                 tmp_path, capsys):
    scenario = write_scenario(tmp_path)
    with time_limit(TEST_TIMEOUT), _emulator() as emu:
        setup(emu)
        code = main([*cli_args(emu, scenario, tmp_path / "out"), *flags])
        record = emu.record()
    err = capsys.readouterr().err
    assert code == 2 and all(word in err for word in words)
    assert record["script_uploads"] == [] and servoj_times(record) == []
    assert not (tmp_path / "out").exists()
