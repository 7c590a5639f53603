"""The UR controller emulator against the real ur_rtde client (1.6.5).

The clients run in a child process (`RtdeClientProcess`) that each test kills at its end:
their constructors hold the GIL, and `disconnect()`/`stopScript()` and the destructors can
block for minutes on a dead link. Every emulator gets a loopback address of its own, so the
tests run under pytest-xdist and no client from an earlier test can reach a later emulator.
"""

from __future__ import annotations

import itertools
import math
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from ur_emulator import (
    HOME,
    ArmModel,
    ClientError,
    RtdeClientProcess,
    UrControllerEmulator,
    forward_kinematics,
    tcp_pose,
    worker_host,
)
from ur_emulator.arm import rotation_vector
from ur_emulator.control_script import split_programs
from ur_emulator.record import starved_since
from ur_emulator.sessions import time_limit

pytest.importorskip("rtde_control")

TEST_TIMEOUT = 45.0  # seconds, per test
TAU = 0.03  # the emulated arm's lag time constant
SERVO = (0.5, 0.5, 0.1, 300.0)  # speed, acceleration, lookahead time, gain
FLAG_UPLOAD_SCRIPT, FLAG_UPPER_RANGE_REGISTERS = 1, 8
_addresses = itertools.count()


@pytest.fixture(autouse=True)
def each_test_bounded() -> Iterator[None]:
    """Fail a test that runs longer than TEST_TIMEOUT (pytest-timeout is not a dependency)."""
    with time_limit(TEST_TIMEOUT):
        yield


@pytest.fixture
def host() -> str:
    return worker_host(next(_addresses))


@pytest.fixture
def emu(host: str) -> Iterator[UrControllerEmulator]:
    with UrControllerEmulator(host=host, q0=HOME, tau=TAU, unlock_delay=0.5,
                              lifetime=90.0) as emulator:
        yield emulator


@pytest.fixture
def client(emu: UrControllerEmulator) -> Iterator[RtdeClientProcess]:
    with RtdeClientProcess(emu.host, timeout=15.0) as process:
        yield process


def _away_from_home(offsets: tuple[float, ...]) -> list[float]:
    return [h + d for h, d in zip(HOME, offsets, strict=True)]


def _read_until(client: RtdeClientProcess, condition: Callable[[dict], bool],
                timeout: float = 2.0) -> dict:
    """Receive-interface readings until `condition` holds or `timeout` passes; the last one."""
    deadline = time.monotonic() + timeout
    while not condition(reading := client.read()) and time.monotonic() < deadline:
        time.sleep(0.01)
    return reading


# --- the models, without processes ------------------------------------------------------------
def test_forward_kinematics_matches_the_ur5e_geometry() -> None:
    # All joints at zero: the arm lies along -x, the wrist offsets d4, d6 along -y, d5 down.
    zero = forward_kinematics([0.0] * 6)
    np.testing.assert_allclose(zero[:3, 3], [-0.425 - 0.3922, -0.1333 - 0.0996, 0.1625 - 0.0997],
                               atol=1e-12)
    # Home: upper arm up, forearm back along -x, flange pointing down.
    np.testing.assert_allclose(tcp_pose(HOME)[:3], [-0.3922 - 0.0997, -0.1333,
                                                    0.1625 + 0.425 - 0.0996], atol=1e-12)
    rng = np.random.default_rng(0)
    for q in [*rng.uniform(-np.pi, np.pi, (50, 6)), [0.0, 0.0, 0.0, 0.0, np.pi, 0.0]]:
        rotation = forward_kinematics(q)[:3, :3]
        rotvec = rotation_vector(rotation)
        angle = np.linalg.norm(rotvec)
        assert angle <= np.pi + 1e-9
        axis = rotvec / angle
        skew = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        rodrigues = np.eye(3) + np.sin(angle) * skew + (1 - np.cos(angle)) * skew @ skew
        np.testing.assert_allclose(rodrigues, rotation, atol=1e-9)


def test_arm_follows_a_step_as_a_first_order_lag_slowed_by_speed_scaling() -> None:
    for scaling in (1.0, 0.5):
        arm = ArmModel([0.0] * 6, tau=TAU)
        arm.speed_scaling = scaling
        arm.servo([0.05] * 6)  # small enough to stay under the joint speed limit
        for _ in range(50):
            arm.step(0.002)
        expected = 0.05 * (1.0 - math.exp(-0.1 * scaling / TAU))
        np.testing.assert_allclose(arm.q, expected, rtol=1e-9)
    arm = ArmModel([0.0] * 6, tau=TAU)
    arm.servo([1.0] * 6)
    arm.step(0.002)
    np.testing.assert_allclose(arm.qd, math.pi)  # a big step is capped at 180 deg/s


def test_the_script_port_splits_programs_from_statements() -> None:
    programs, rest = split_programs("def a():\n  x = 1\n  end\nend\nstopl(1.0)\ndef b():\n  y")
    assert programs == ["def a():\n  x = 1\n  end\nend\n", "stopl(1.0)\n"]
    assert rest == "def b():\n  y"


# --- the real client ----------------------------------------------------------------------------
def test_receive_interface_reads_the_emulated_arm(host: str) -> None:
    q0 = _away_from_home((0.1, -0.2, 0.3, 0.0, 0.1, -0.4))
    with UrControllerEmulator(host=host, q0=q0, lifetime=60.0) as emu, \
            RtdeClientProcess(host) as client:
        client.connect("receive")
        first = client.read()
        time.sleep(0.3)
        second = client.read()
        np.testing.assert_allclose(first["q"], q0, atol=1e-12)
        np.testing.assert_allclose(first["tcp_pose"], tcp_pose(q0), atol=1e-12)
        assert first["qd"] == [0.0] * 6
        assert (first["safety_mode"], first["robot_mode"]) == (1, 7)
        assert first["safety_status_bits"] == 1 and not first["protective_stopped"]
        assert 0.2 < second["timestamp"] - first["timestamp"] < 0.6
        outputs = [s for s in emu.record()["rtde_sessions"] if s["event"] == "outputs"]
        assert outputs[0]["frequency"] == 500.0  # the client's e-Series default


def _predicted_q(commands: list[dict], q0: list[float], t: float) -> np.ndarray:
    """The lag model run over the servoJ targets the emulator received, at controller time t."""
    q = np.array(q0, float)
    for command, following in zip(commands, [*commands[1:], None], strict=True):
        start = command["controller_time"]
        if start >= t:
            break
        end = min(t, following["controller_time"] if following else t)
        if end <= start:  # overwritten within the same controller cycle
            continue
        target = np.array(command["args"][:6])
        q = target + (q - target) * math.exp(-(end - start) / TAU)
    return q


def test_servoj_stream_moves_the_arm_with_the_lag_and_servo_stop_is_recorded(
        emu: UrControllerEmulator, client: RtdeClientProcess) -> None:
    client.connect("control")
    record = emu.record()
    upload = record["script_uploads"][0]
    protocol = upload["protocol"]
    assert upload["started"] and upload["size"] > 30_000 and protocol["program"] == "rtde_control"
    kinds = {kind: int(cmd_id) for cmd_id, (_, kind, _) in protocol["commands"].items()
             if kind != "other"}
    assert set(kinds) == {"servoj", "servo_stop", "set_watchdog", "stop_script"}
    servoj_registers = protocol["commands"][str(kinds["servoj"])][2]
    assert servoj_registers == [f"double{i}" for i in range(11)]
    assert [d["command"] for d in record["dashboard"]][:2] == ["PolyscopeVersion",
                                                               "get serial number"]

    end = _away_from_home((0.4, -0.3, 0.0, 0.0, 0.0, 0.2))  # 0.5 rad/s on joint 0
    velocity = 0.5
    with RtdeClientProcess(emu.host) as observer:
        observer.connect("receive")
        observer.send("sample", duration=1.3, period=0.005)
        streamed = client.request("servo_stream", start=list(HOME), end=end, duration=0.8,
                                  hold=0.3, rate=250, settings=list(SERVO))
        samples = observer.result(10.0)
        final = observer.read()
    assert streamed["refused"] == 0 and streamed["sent"] > 200
    servojs = [c for c in emu.record()["commands"] if c["id"] == kinds["servoj"]]
    assert len(servojs) == streamed["sent"]
    assert servojs[-1]["args"] == [*end, SERVO[0], SERVO[1], 1 / 250, SERVO[2], SERVO[3]]
    # While the target ramps at v the arm trails it by v * tau. Replaying the lag model over
    # the targets the emulator received must predict every reading (same data package for
    # timestamp and q) to within 4 ms of travel, and the trailing must show on the ramp.
    ramp_end = servojs[0]["controller_time"] + 0.75
    lagging = 0
    for sample in samples:
        t = sample["timestamp"]
        if t != sample["timestamp_after"] or t < servojs[0]["controller_time"]:
            continue
        predicted = _predicted_q(servojs, list(HOME), t)
        assert np.max(np.abs(np.array(sample["q"]) - predicted)) < velocity * 0.004 + 1e-6, t
        latest = [c for c in servojs if c["controller_time"] <= t][-1]["args"][0]
        lagging += t < ramp_end and latest - sample["q"][0] > 0.5 * velocity * TAU
    assert lagging > 50
    # After 0.3 s of hold the lag has decayed by exp(-10): the arm is on the target.
    np.testing.assert_allclose(final["q"], end, atol=velocity * TAU * math.exp(-8.0))
    np.testing.assert_allclose(final["tcp_pose"], tcp_pose(end), atol=1e-5)

    assert client.call("control", "servoStop", 2.5) is True
    stops = [c for c in emu.record()["executed"] if c["id"] == kinds["servo_stop"]]
    assert [s["args"] for s in stops] == [[2.5]]


def _read_by(record: dict, killed_at: float) -> float:
    """When the emulator has read all a client killed at `killed_at` sent: 50 ms later, plus
    any time it was itself starved of CPU since (it then moves its last kick later too)."""
    return killed_at + 0.05 + starved_since(record, killed_at)


def _stream_then_kill(client: RtdeClientProcess,
                      watchdog: float | None) -> tuple[float, list[float]]:
    """Stream servoJ along a ramp and on, SIGKILL the client mid-stream (after the ramp);
    (wall time of the kill, the target streamed last)."""
    end = _away_from_home((0.5, 0.0, 0.0, 0.0, 0.0, 0.0))
    client.send("servo_stream", start=list(HOME), end=end, duration=0.6, hold=30.0, rate=125,
                settings=list(SERVO), watchdog=watchdog)
    client.wait_event("streaming", 10.0)
    time.sleep(0.8)  # past the ramp: the last target is `end`
    return client.kill(), end


@pytest.mark.parametrize("flags, register", [
    pytest.param(FLAG_UPLOAD_SCRIPT, "input_int_register_0", id="lower-registers"),
    pytest.param(FLAG_UPLOAD_SCRIPT | FLAG_UPPER_RANGE_REGISTERS, "input_int_register_24",
                 id="upper-range-registers"),
])
def test_watchdog_stops_the_script_when_the_client_dies(
        emu: UrControllerEmulator, client: RtdeClientProcess, flags: int, register: str) -> None:
    client.connect("control", flags=flags)
    killed_at, _ = _stream_then_kill(client, watchdog=5.0)  # the product's frequency
    record = emu.wait_for(lambda r: r["watchdog_trips"], timeout=2.0)
    offset = record["script_uploads"][0]["protocol"]["int_offset"]
    assert offset == (24 if flags & FLAG_UPPER_RANGE_REGISTERS else 0)
    assert [(w["register"], w["min_frequency"], w["action"]) for w in record["watchdog"]] == \
        [(register, 5.0, "stop")]
    assert len(record["kicks"]) > 50  # every servoJ package writes the watched register
    trip = record["watchdog_trips"][0]
    assert trip["register"] == register
    # Nothing was written after the client died: 50 ms for the emulator to read its socket,
    # plus any time it was itself starved of CPU after the kill (it then moves its last kick
    # later, as a real controller does not starve).
    assert killed_at - 0.5 < trip["last_kick"] <= _read_by(record, killed_at)
    assert trip["t"] - killed_at < 1.0  # 0.2 s of silence at 5 Hz, plus scheduling
    stopped = [p for p in record["program"] if p["event"] == "stopped"]
    assert [p["reason"] for p in stopped] == ["RTDE watchdog: no input update"]
    state = emu.state()
    assert not state["program_running"] and state["runtime"] == "STOPPED"
    time.sleep(0.1)
    assert emu.state()["q"] == state["q"]  # the arm holds


def test_without_watchdog_the_script_keeps_servoing_after_the_client_dies(
        emu: UrControllerEmulator, client: RtdeClientProcess) -> None:
    client.connect("control")
    killed_at, end = _stream_then_kill(client, watchdog=None)
    time.sleep(1.0)
    state = emu.state()
    record = emu.record()
    assert state["program_running"] and state["runtime"] == "PLAYING"
    assert record["watchdog"] == [] and record["watchdog_trips"] == []
    assert [p["event"] for p in record["program"]] == ["started"]
    assert record["commands"][-1]["t"] <= _read_by(record, killed_at)
    np.testing.assert_allclose(state["q"], end, atol=1e-9)  # still servoing the last target


@pytest.mark.parametrize("fault, safety_mode, robot_mode, flag", [
    pytest.param("protective_stop", 3, 7, "protective_stopped", id="protective-stop"),
    pytest.param("emergency_stop", 7, 3, "emergency_stopped", id="emergency-stop"),
])
def test_safety_stops_stop_the_program_and_servoj_is_refused(
        emu: UrControllerEmulator, client: RtdeClientProcess, fault: str, safety_mode: int,
        robot_mode: int, flag: str) -> None:
    client.connect("receive")
    client.connect("control")
    assert client.call("control", "servoJ", list(HOME), *SERVO[:2], 0.008, *SERVO[2:])
    emu.inject(fault)
    reading = _read_until(client, lambda r: r["safety_mode"] != 1)
    assert reading[flag] and (reading["safety_mode"], reading["robot_mode"]) == \
        (safety_mode, robot_mode)
    assert reading["runtime_state"] == 1  # STOPPED
    assert not reading["robot_status"] & 2  # the program-running bit
    # The control interface reads its own data packages: under load its view of the stop
    # can trail the receive interface's by a package or two (a servoJ then still went out).
    deadline = time.monotonic() + 2.0
    while client.call("control", "isProgramRunning") and time.monotonic() < deadline:
        time.sleep(0.01)
    assert client.call("control", "isProgramRunning") is False
    started = time.monotonic()
    assert client.call("control", "servoJ", list(HOME), *SERVO[:2], 0.008, *SERVO[2:],
                       timeout=5.0) is False
    assert time.monotonic() - started < 1.0


def test_protective_stop_unlocks_through_the_dashboard_only_after_the_delay(
        emu: UrControllerEmulator, client: RtdeClientProcess) -> None:
    client.connect("dashboard")
    client.connect("receive")
    emu.inject("protective_stop")
    with pytest.raises(ClientError, match="Unlock protective stop failure"):
        client.call("dashboard", "unlockProtectiveStop")
    time.sleep(0.6)  # the emulator's unlock delay is 0.5 s (5 s on a real e-Series)
    client.call("dashboard", "unlockProtectiveStop")
    assert _read_until(client, lambda r: r["safety_mode"] == 1)["safety_mode"] == 1
    assert client.call("dashboard", "safetymode") == "Safetymode: NORMAL"
    assert client.call("dashboard", "robotmode") == "Robotmode: RUNNING"


def test_link_freeze_leaves_the_receive_interface_with_stale_values(
        emu: UrControllerEmulator, client: RtdeClientProcess) -> None:
    client.connect("receive")
    before = client.request("sample", duration=0.2, period=0.02)
    assert before[-1]["timestamp"] - before[0]["timestamp"] > 0.1
    emu.freeze()
    # Packages already in flight: past them once two readings 0.1 s apart agree (at most 5 s,
    # on a loaded machine the last ones may arrive late).
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        first = client.read()["timestamp"]
        time.sleep(0.1)
        if client.read()["timestamp"] == first:
            break
    frozen = client.request("sample", duration=0.5, period=0.02)
    assert len({s["timestamp"] for s in frozen}) == 1
    assert all(s["q"] == frozen[0]["q"] and s["connected"] for s in frozen)
    assert emu.state()["timestamp"] - frozen[0]["timestamp"] > 0.5  # the controller runs on


def test_link_reset_disconnects_the_receive_interface(
        emu: UrControllerEmulator, client: RtdeClientProcess) -> None:
    client.connect("receive")
    assert client.read()["connected"]
    emu.reset_links()
    reading = _read_until(client, lambda r: not r["connected"])
    assert not reading["connected"]
    assert [e["event"] for e in emu.record()["links"]] == ["reset"]
    assert emu.state()["links"] == 0


def test_after_an_emergency_stop_the_script_runs_again_only_once_powered_and_released(
        emu: UrControllerEmulator, client: RtdeClientProcess) -> None:
    client.connect("control")
    client.connect("dashboard")
    emu.inject("emergency_stop")
    emu.clear_faults()  # the button is released; the arm stays off, as on the robot
    assert client.call("control", "reuploadScript")
    time.sleep(0.2)
    assert client.call("control", "isProgramRunning") is False
    assert "POWER_OFF" in emu.record()["script_uploads"][-1]["reason"]
    client.call("dashboard", "powerOn")
    client.call("dashboard", "brakeRelease")
    assert client.call("dashboard", "robotmode") == "Robotmode: RUNNING"
    assert client.call("control", "reuploadScript")
    deadline = time.monotonic() + 2.0
    while not client.call("control", "isProgramRunning") and time.monotonic() < deadline:
        time.sleep(0.01)
    assert client.call("control", "servoJ", list(HOME), *SERVO[:2], 0.008, *SERVO[2:])


def test_speed_scaling_is_reported_to_the_receive_interface(
        emu: UrControllerEmulator, client: RtdeClientProcess) -> None:
    client.connect("receive")
    assert client.read()["speed_scaling"] == 1.0
    emu.set_speed_scaling(0.5)
    reading = _read_until(client, lambda r: r["speed_scaling"] != 1.0)
    assert (reading["speed_scaling"], reading["target_speed_fraction"]) == (0.5, 0.5)


def test_control_interface_refuses_a_robot_not_in_remote_control(
        emu: UrControllerEmulator, client: RtdeClientProcess) -> None:
    emu.inject("not_in_remote_control")
    with pytest.raises(ClientError, match="remote control"):
        client.connect("control")
    record = emu.record()
    assert {"command": "is in remote control", "reply": "false"}.items() <= \
        record["dashboard"][-1].items()
    assert record["script_uploads"] == []


def test_emulator_stops_by_itself_after_its_lifetime_and_when_its_parent_dies(host: str) -> None:
    with UrControllerEmulator(host=host, lifetime=0.5) as emu:
        assert emu.process is not None
        emu.process.wait(5.0)
        assert "lifetime" in emu.log()
    # A parent that exits without stopping its emulator.
    parent = subprocess.run(
        [sys.executable, "-c", "import os, sys; sys.path.insert(0, sys.argv[1]);"
         "from ur_emulator import UrControllerEmulator as E;"
         "e = E(host=sys.argv[2]).start(); print(e.process.pid, e.log_path, flush=True);"
         "os._exit(0)", os.path.dirname(__file__), host],
        capture_output=True, text=True, timeout=20.0, check=True)
    pid, log_path = parent.stdout.split()
    os.unlink(log_path)
    orphan = int(pid)
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline and _running(orphan):
        time.sleep(0.05)
    assert not _running(orphan)


def _running(pid: int) -> bool:
    """Whether pid is a live process (a zombie is not)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False
