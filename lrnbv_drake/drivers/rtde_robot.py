"""The UR5e through ur_rtde: the one driver that talks to a real controller.

ur_rtde itself runs in a child process (`drivers/rtde_client.py`, which says why); this side
sends it one request at a time over two pipes and bounds every wait, so nothing the client
or the controller does can hang the session or crash it.
"""

from __future__ import annotations

import itertools
import json
import os
import select
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from lrnbv_drake.core.robot.safety import RobotConnectionError, RobotFault, RobotReading

#: Longest waits for the client, seconds. Connecting uploads a 42 kB script and checks the
#: dashboard; a reading or a servoJ answers in well under a millisecond on a live link (its
#: getters return the last package, servoJ only writes registers), so a second only covers a
#: client the OS did not schedule (a busy PC); servoStop waits while the script's stopl
#: decelerates the tool; closing takes at most stopScript plus the disconnects
#: (rtde_client.CLOSE_STEP_TIMEOUT each), after which the client is killed.
CONNECT_TIMEOUT = 30.0
CALL_TIMEOUT = 1.0
STOP_TIMEOUT = 2.0
CLOSE_TIMEOUT = 2.5


class ClientLink:
    """Requests to the ur_rtde client over a pipe pair, one at a time (a lock: the simulated
    sensor board reads the joints from its own thread), each bounded by a timeout. Answers
    to requests that timed out are recognised by their id and dropped."""

    def __init__(self, to_client: int, from_client: int, kill: Callable[[], None],
                 describe_exit: Callable[[], str | None]) -> None:
        self._to_client = to_client
        self._from_client = from_client
        self._kill = kill
        self._describe_exit = describe_exit
        self._ids = itertools.count(1)
        self._buffer = b""
        self._lock = threading.Lock()
        self.failed = ""  # why the client cannot be used any more, once it cannot

    def notify(self, op: str, *args: Any) -> None:
        """Sends a request that gets no answer."""
        with self._lock:
            self._send(next(self._ids), op, args)

    def request(self, op: str, *args: Any, timeout: float) -> Any:
        """Sends a request and returns its result.

        Raises:
            ValueError: ur_rtde raised it (an argument out of its range).
            RuntimeError: ur_rtde raised something else, or the client died, or it did not
                answer within `timeout` (then a blocking call is in progress and the client
                is marked failed).
        """
        with self._lock:
            request_id = next(self._ids)
            self._send(request_id, op, args)
            deadline = time.monotonic() + timeout
            while True:
                answer = self._next_answer(deadline, op, timeout)
                if answer.get("id") == request_id:
                    break
        if answer["ok"]:
            return answer["result"]
        kind = ValueError if answer["type"] == "ValueError" else RuntimeError
        raise kind(answer["error"])

    def _send(self, request_id: int, op: str, args: tuple) -> None:
        if self.failed:
            raise RuntimeError(self.failed)
        line = json.dumps({"id": request_id, "op": op, "args": list(args)}).encode() + b"\n"
        try:
            os.write(self._to_client, line)
        except OSError as e:
            self.failed = f"the ur_rtde client is gone ({self._exit_text()}): {e}"
            raise RuntimeError(self.failed) from e

    def _next_answer(self, deadline: float, op: str, timeout: float) -> dict[str, Any]:
        while b"\n" not in self._buffer:
            remaining = deadline - time.monotonic()
            try:
                ready = select.select([self._from_client], [], [], max(remaining, 0.0))[0]
                chunk = os.read(self._from_client, 65536) if ready else b""
            except (OSError, ValueError) as e:  # closed under us: the link is being closed
                raise RuntimeError(f"the ur_rtde client is closed ({e})") from e
            if not ready:
                self.failed = (f"the ur_rtde client did not answer {op} within {timeout} s "
                               f"(a call blocked on a dead link?)")
                raise RuntimeError(self.failed)
            if not chunk:
                self.failed = f"the ur_rtde client ended ({self._exit_text()})"
                raise RuntimeError(self.failed)
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return json.loads(line)

    def _exit_text(self) -> str:
        return self._describe_exit() or "still running"

    def kill(self) -> None:
        """Ends the client at once."""
        self.failed = self.failed or "the ur_rtde client was closed"
        self._kill()


def spawn_client() -> ClientLink:
    """Starts `python -m lrnbv_drake.drivers.rtde_client`; its stderr is the session's."""
    process = subprocess.Popen([sys.executable, "-m", "lrnbv_drake.drivers.rtde_client"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    assert process.stdin is not None and process.stdout is not None

    def kill() -> None:
        if process.poll() is None:
            process.kill()
        process.wait()
        process.stdin.close()
        process.stdout.close()

    def describe_exit() -> str | None:
        code = process.poll()
        if code is None:
            return None
        return f"killed by signal {-code}" if code < 0 else f"exit code {code}"

    return ClientLink(process.stdin.fileno(), process.stdout.fileno(), kill, describe_exit)


class RtdeRobot:
    """The UR5e through ur_rtde's `RTDEReceiveInterface` and `RTDEControlInterface`, held by a
    child process (`spawn_client`).

    Constructing it connects; with `control`, it also uploads ur_rtde's control script (which
    needs the robot in Remote Control mode) and sets the script's RTDE watchdog to
    `watchdog_frequency` (Hz, > 0): the controller stops the script when this
    client has not written for 1/f s. `kick_watchdog` feeds it from the diagram, and the
    client keeps feeding it while the diagram is held for at most `watchdog_hold` s.

    Raises:
        ValueError: `control` without a watchdog (`watchdog_frequency` <= 0): a client that
            dies would leave the script servoing its last target.
        RobotConnectionError: ur_rtde's RuntimeError, with the usual causes appended.
    """

    def __init__(self, robot_ip: str, *, frequency: float = -1.0,
                 upper_range_registers: bool = False, control: bool = True,
                 watchdog_frequency: float = 5.0, watchdog_hold: float = 60.0) -> None:
        if control and not watchdog_frequency > 0:
            raise ValueError(f"watchdog_frequency must be > 0 Hz with control (a client that "
                             f"dies would leave the script servoing its last target), got "
                             f"{watchdog_frequency}")
        self.robot_ip = robot_ip
        self.control = control
        self._link = spawn_client()
        try:
            self._link.request("connect", robot_ip, frequency, upper_range_registers, control,
                               watchdog_frequency, watchdog_hold, timeout=CONNECT_TIMEOUT)
        except (RuntimeError, ValueError) as e:
            self._link.kill()
            raise _connection_error(robot_ip, e) from e

    def read(self) -> RobotReading:
        """The controller's latest package. Raises RuntimeError when the client failed."""
        r = self._link.request("read", timeout=CALL_TIMEOUT)
        return RobotReading(**{**r, **{k: np.array(r[k], float)
                                       for k in ("q", "qd", "tcp_pose")}})

    def kick_watchdog(self) -> None:
        if self.control:
            self._link.notify("kick")

    def servo_j(self, q: Sequence[float], speed: float, acceleration: float, time: float,
                lookahead_time: float, gain: float) -> bool:
        if not self.control:
            raise RobotFault("refused", f"the connection to {self.robot_ip} is read-only")
        # The binding takes positional arguments only (arg0..arg5).
        return bool(self._link.request("servo_j", [float(v) for v in q], speed, acceleration,
                                       time, lookahead_time, gain, timeout=CALL_TIMEOUT))

    def servo_stop(self, deceleration: float) -> bool:
        """servoStop(deceleration): the script's stopl, m/s^2 at the tool. Raises RuntimeError
        when it does not return within STOP_TIMEOUT (the link died under it)."""
        if not self.control:
            raise RobotFault("refused", f"the connection to {self.robot_ip} is read-only")
        return bool(self._link.request("servo_stop", deceleration, timeout=STOP_TIMEOUT))

    def disconnect(self) -> None:
        """Closes within CLOSE_TIMEOUT: the client ends the control script if the link is
        alive, disconnects, and exits. A client that failed (blocked in a call on a dead
        link, or crashed) is killed at once, and a fresh one asks the dashboard to stop
        whatever runs, since ur_rtde may have uploaded its script again, without the
        watchdog, before it crashed. Without a kick, the watchdog stops the session's own
        script."""
        failed = self._link.failed
        if not failed:
            try:
                self._link.request("close", timeout=CLOSE_TIMEOUT)
            except (RuntimeError, ValueError) as e:
                # Killed below; an error answer is no clean close either: the client may have
                # skipped stopScript, so the dashboard is asked too.
                failed = self._link.failed or str(e)
        self._link.kill()
        if failed and self.control:
            link = spawn_client()
            try:
                link.request("stop_program", self.robot_ip, timeout=CLOSE_TIMEOUT)
            except (RuntimeError, ValueError):
                pass  # nothing answers there: the watchdog is all that is left
            link.kill()


def _connection_error(robot_ip: str, error: Exception) -> RobotConnectionError:
    return RobotConnectionError(
        f"cannot connect to the UR controller at {robot_ip} over RTDE: {error}. Check that the "
        f"address is right and reachable (ping it), that the robot is in Remote Control mode "
        f"(pendant: Settings > System > Remote Control, then the Local/Remote switch at the "
        f"top right), and that no other RTDE client, EtherNet/IP, PROFINET or MODBUS unit "
        f"holds the RTDE input registers (or set hardware.upper_range_registers)")
