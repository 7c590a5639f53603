"""The process that holds ur_rtde for `RtdeRobot` (drivers/rtde_robot.py): `python -m
lrnbv_drake.drivers.rtde_client`, one JSON request per line on stdin, one answer per line.

ur_rtde 1.6.5 lives here rather than in the session's process because, against a controller
emulator (tests/ur_emulator), its constructors hold the GIL while they connect, its
`stopScript`, `servoStop` and destructors block for up to 300 s on a dead link, and its control
interface crashed with SIGSEGV in 5 of 8 runs when it reconnected after a link reset. Here a
crash or a hang costs the session its robot link, which it handles, not its process, and the
session can always end this process (SIGKILL at worst). Only the standard library and the
wheel are imported, so it starts fast.

The control script's RTDE watchdog (`setWatchdog`) stops the script when the client's
writes stop. Every servoJ feeds it; between them a keeper thread kicks it while the diagram's
last sign of life (a `kick` or a `servo_j` request) is less than `watchdog_hold` old, so a
planning step that holds the diagram does not trip it but a stalled diagram does. When the
session's process dies, stdin closes and this process exits at once, without destructors:
the kicks stop and the watchdog stops the arm. Requests run one at a time; the keeper kicks
only between them, since a kick writes the command register a running command is using.
"""

from __future__ import annotations

import importlib
import json
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any, BinaryIO

#: ur_rtde's RTDEControlInterface flags (rtde_control.RTDEControlInterface.FLAG_*).
FLAG_UPLOAD_SCRIPT = 1
FLAG_UPPER_RANGE_REGISTERS = 8
#: How long closing waits for each of its steps, seconds: a live link answers stopScript and the
#: dashboard in milliseconds and a disconnect in 0.5 s; a dead one would block for minutes.
CLOSE_STEP_TIMEOUT = 0.75
#: The controller's clock must advance within this long for the link to count as alive when
#: closing, seconds (it advances every 2 ms on e-Series, 8 ms on CB3).
ALIVE_WINDOW = 0.1
#: The keeper's longest gap between kicks, seconds (at most a quarter of the watchdog period).
MAX_KICK_PERIOD = 0.02


def _bounded(*calls: Callable[[], Any], timeout: float) -> bool:
    """Runs `calls` in daemon threads at once; whether all returned, without raising, within
    `timeout`. A call still blocked is abandoned (the process exits with os._exit)."""
    failed: list[Exception] = []

    def run(call: Callable[[], Any]) -> None:
        try:
            call()
        except Exception as e:  # a failed step of a best-effort close
            failed.append(e)

    threads = [threading.Thread(target=run, args=(call,), daemon=True) for call in calls]
    for thread in threads:
        thread.start()
    deadline = time.monotonic() + timeout
    for thread in threads:
        thread.join(max(deadline - time.monotonic(), 0.0))
    return not failed and not any(thread.is_alive() for thread in threads)


class Clients:
    """ur_rtde's receive and (optionally) control interfaces, and the watchdog keeper."""

    def __init__(self) -> None:
        self.robot_ip = ""
        self.receive: Any = None
        self.control: Any = None
        self.lock = threading.Lock()  # one ur_rtde control call at a time
        self.heartbeat = time.monotonic()
        self.hold = 0.0
        self.closing = threading.Event()

    def connect(self, robot_ip: str, frequency: float, upper_range_registers: bool,
                control: bool, watchdog_frequency: float, watchdog_hold: float) -> None:
        """Connects (imports the wheel now, so that a missing one is the caller's error)."""
        self.robot_ip = robot_ip
        rtde_receive = importlib.import_module("rtde_receive")
        self.receive = rtde_receive.RTDEReceiveInterface(robot_ip, frequency, [], False,
                                                         upper_range_registers)
        if not control:
            return
        rtde_control = importlib.import_module("rtde_control")
        flags = FLAG_UPLOAD_SCRIPT | (FLAG_UPPER_RANGE_REGISTERS if upper_range_registers
                                      else 0)
        self.control = rtde_control.RTDEControlInterface(robot_ip, frequency, flags)
        if not self.control.setWatchdog(watchdog_frequency):
            raise RuntimeError(f"the controller's script refused setWatchdog"
                               f"({watchdog_frequency}): it is not running")
        self.hold = watchdog_hold
        self.heartbeat = time.monotonic()
        period = min(MAX_KICK_PERIOD, 0.25 / watchdog_frequency)
        threading.Thread(target=self._keep, args=(period,), daemon=True).start()

    def _keep(self, period: float) -> None:
        while not self.closing.wait(period):
            silent = time.monotonic() - self.heartbeat
            if silent < period or silent > self.hold:
                continue  # the diagram feeds it, or it stalled: let the watchdog stop it
            if self.lock.acquire(blocking=False):  # a request is running: it writes, or blocks
                try:
                    if self.closing.is_set():  # close() set it before its stopScript
                        return
                    self.control.kickWatchdog()
                finally:
                    self.lock.release()

    def read(self) -> dict[str, Any]:
        r, c = self.receive, self.control
        return {
            "q": r.getActualQ(), "qd": r.getActualQd(), "tcp_pose": r.getActualTCPPose(),
            "controller_time": r.getTimestamp(), "robot_mode": r.getRobotMode(),
            "safety_mode": r.getSafetyMode(), "protective_stop": r.isProtectiveStopped(),
            "emergency_stop": r.isEmergencyStopped(),
            "connected": r.isConnected() and (c is None or c.isConnected()),
            "program_running": c is not None and c.isProgramRunning(),
            "speed_scaling": r.getSpeedScaling(),
            "target_speed_fraction": r.getTargetSpeedFraction(),
        }

    def kick(self) -> None:
        self.heartbeat = time.monotonic()
        with self.lock:
            self.control.kickWatchdog()

    def servo_j(self, *args: Any) -> bool:
        self.heartbeat = time.monotonic()
        with self.lock:
            return self.control.servoJ(*args)

    def servo_stop(self, deceleration: float) -> bool:
        with self.lock:
            return self.control.servoStop(deceleration)

    def link_alive(self) -> bool:
        """Whether the controller's clock still advances (ur_rtde's isConnected turns false
        about 2.5 s after a silent drop; the getters keep the last package forever). A getter
        that raises says the link is broken: not alive, so closing asks the dashboard."""
        try:
            if self.receive is None or not self.receive.isConnected():
                return False
            first = self.receive.getTimestamp()
            deadline = time.monotonic() + ALIVE_WINDOW
            while time.monotonic() < deadline:
                if self.receive.getTimestamp() != first:
                    return True
                time.sleep(0.002)
        except Exception:  # any error of ur_rtde's here means a broken link
            return False
        return False

    def close(self) -> dict[str, bool]:
        """Stops the keeper; ends the control script; disconnects. Every step is bounded,
        and none that blocks on a dead link is tried on one.

        On a live link: stopScript, then both disconnects. Otherwise the control interface
        may have reconnected by itself (after a link reset it does so within 0.2 s, long
        before the session, which saves first, closes) and uploaded its script again,
        without the watchdog: the dashboard's `stop` (a connection of its own) ends it,
        while the disconnects stop further reconnecting."""
        self.closing.set()
        alive = self.link_alive()
        stopped = False
        if self.control is not None and alive:
            with self.lock:
                stopped = _bounded(self.control.stopScript, timeout=CLOSE_STEP_TIMEOUT)
        closing = [client.disconnect for client in (self.control, self.receive)
                   if client is not None]
        if self.control is not None and not alive:
            closing.append(self._dashboard_stop)
        done = _bounded(*closing, timeout=CLOSE_STEP_TIMEOUT)
        return {"link_alive": alive, "script_stopped": stopped or (not alive and done)}

    def _dashboard_stop(self) -> None:
        dashboard = importlib.import_module("dashboard_client").DashboardClient(self.robot_ip)
        dashboard.connect(int(CLOSE_STEP_TIMEOUT * 1000))
        dashboard.stop()
        dashboard.disconnect()

    def stop_program(self, robot_ip: str) -> bool:
        """The dashboard's `stop`, bounded, for a session whose client crashed (ur_rtde's
        reconnect after a link reset can crash after uploading its script again)."""
        self.robot_ip = robot_ip
        return _bounded(self._dashboard_stop, timeout=CLOSE_STEP_TIMEOUT)


def serve(requests: BinaryIO, answers: BinaryIO) -> Clients:
    """Answers requests until `close` or the end of `requests` (the session is gone).

    A request is {"id", "op", "args"}; the answer {"id", "ok", "result"} or {"id", "ok":
    false, "type", "error"}. `kick` gets no answer. Returns the clients, still alive: freed,
    ur_rtde's destructors would disconnect, which sleeps 0.5 s per interface and can block
    on a dead link."""
    clients = Clients()
    operations: dict[str, Callable[..., Any]] = {
        "connect": clients.connect, "read": clients.read, "kick": clients.kick,
        "servo_j": clients.servo_j, "servo_stop": clients.servo_stop, "close": clients.close,
        "stop_program": clients.stop_program}
    for line in requests:
        request = json.loads(line)
        op = request["op"]
        try:
            answer = {"ok": True, "result": operations[op](*request.get("args", []))}
        except Exception as e:  # handed to the session, which decides
            answer = {"ok": False, "type": type(e).__name__, "error": str(e)}
        if op != "kick" or not answer["ok"]:
            answers.write(json.dumps({"id": request["id"], **answer}).encode() + b"\n")
            answers.flush()
        if op in ("close", "stop_program"):
            return clients
    clients.closing.set()
    return clients


def main() -> None:
    """The child's entry point: answers on a private copy of stdout, since ur_rtde prints to
    std::cout; ignores Ctrl-C, which the session handles (it stops the arm through here)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    answers = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    try:
        _clients = serve(os.fdopen(0, "rb"), answers)  # held to the exit: no destructor runs
        answers.flush()
    except BaseException:  # e.g. the session died mid-answer (a broken pipe), a bad request
        traceback.print_exc()
        os._exit(1)  # the traceback still holds serve's frame, and the clients in it
    os._exit(0)


if __name__ == "__main__":
    main()
