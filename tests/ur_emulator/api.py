"""`UrControllerEmulator`: starts an emulator process for a test and talks to it over its
JSON-lines control channel. The process is separate because ur_rtde's constructors hold the
GIL while they connect, so an emulator inside the test process would deadlock them."""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from .arm import HOME

PACKAGE_PARENT = Path(__file__).resolve().parent.parent


class EmulatorError(RuntimeError):
    """The emulator did not start, or its control channel failed."""


def worker_host(index: int, worker: str | None = None) -> str:
    """A loopback address of its own for pytest-xdist worker `worker` (default: this process's
    PYTEST_XDIST_WORKER, 'gw3' -> 3) and emulator number `index` (0-253): 127.0.<w+2>.<i+1>.
    The controller ports are fixed, so emulators in parallel need distinct addresses."""
    worker = worker if worker is not None else os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    digits = "".join(ch for ch in worker if ch.isdigit())
    number = int(digits) if digits else 0
    if not 0 <= index < 254 or number > 250:
        raise ValueError("index must be within 0-253 and the worker number within 0-250")
    return f"127.0.{number + 2}.{index + 1}"


class UrControllerEmulator:
    """An emulated UR e-Series controller with a UR5e arm at `q0`, listening on `host`
    (loopback only) on 29999 (dashboard), 30004 (RTDE) and 30003 (script).

    `with UrControllerEmulator(host="127.0.0.2", q0=HOME) as emu:` starts the process and waits
    until every port listens; leaving the block stops it. The process also stops by itself
    when the test process dies and after `lifetime` seconds."""

    def __init__(self, host: str = "127.0.0.1", q0: Sequence[float] = HOME, *,
                 tau: float = 0.03, unlock_delay: float = 5.0, lifetime: float = 300.0,
                 start_timeout: float = 15.0, request_timeout: float = 5.0) -> None:
        self.host = host
        self.q0 = [float(v) for v in q0]
        self.tau = tau
        self.unlock_delay = unlock_delay
        self.lifetime = lifetime
        self.start_timeout = start_timeout
        self.request_timeout = request_timeout
        self.process: subprocess.Popen[str] | None = None
        self.control_port: int | None = None
        self._log = tempfile.NamedTemporaryFile(prefix="ur_emulator_", suffix=".log",
                                                delete=False)

    # --- process -----------------------------------------------------------------------------
    def start(self) -> UrControllerEmulator:
        """Start the process and wait for its 'ready' line (every port listening)."""
        command = [sys.executable, "-m", "ur_emulator", "--host", self.host,
                   "--q0", *map(repr, self.q0), "--tau", repr(self.tau),
                   "--unlock-delay", repr(self.unlock_delay), "--lifetime", repr(self.lifetime),
                   "--parent-pid", str(os.getpid())]
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PACKAGE_PARENT),
                                                          env.get("PYTHONPATH")]))
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=self._log,
                                        stdin=subprocess.DEVNULL, text=True, env=env)
        assert self.process.stdout is not None
        ready, _, _ = select.select([self.process.stdout], [], [], self.start_timeout)
        line = self.process.stdout.readline() if ready else ""
        try:
            self.control_port = int(json.loads(line)["control_port"])
        except (ValueError, KeyError, TypeError):
            self.kill()
            raise EmulatorError(f"emulator on {self.host} did not start: {line!r}\n"
                                f"{self.log()}") from None
        return self

    def __enter__(self) -> UrControllerEmulator:
        return self.start()

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()

    def close(self, timeout: float = 3.0) -> None:
        """Ask the process to stop (SIGTERM), kill it if it does not; remove its log."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
        if self.process is not None and self.process.stdout is not None:
            self.process.stdout.close()
        self._log.close()
        Path(self._log.name).unlink(missing_ok=True)

    def kill(self) -> None:
        """SIGKILL the process: every socket closes at once, as when the controller reboots."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(5.0)

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    @property
    def log_path(self) -> Path:
        """The file with the process's stderr (removed by `close()`)."""
        return Path(self._log.name)

    def log(self) -> str:
        """What the process wrote to stderr."""
        return self.log_path.read_text(errors="replace")

    # --- control channel -----------------------------------------------------------------------
    def request(self, op: str, **arguments: Any) -> Any:
        """One control-channel operation; raises EmulatorError if it fails."""
        if self.control_port is None:
            raise EmulatorError("the emulator is not started")
        message = json.dumps({"op": op, **arguments}).encode() + b"\n"
        try:
            with socket.create_connection((self.host, self.control_port),
                                          timeout=self.request_timeout) as sock:
                sock.sendall(message)
                reply = sock.makefile("rb").readline()
        except OSError as error:
            raise EmulatorError(f"control channel on {self.host}: {error}") from error
        if not reply:
            raise EmulatorError(f"control channel on {self.host}: no reply to {op}")
        response = json.loads(reply)
        if not response["ok"]:
            raise EmulatorError(response["error"])
        return response["result"]

    def state(self) -> dict[str, Any]:
        """The arm (q, qd, target, tcp_pose), the modes, whether the program runs."""
        return self.request("state")

    def record(self) -> dict[str, Any]:
        """Everything received and done so far (see record.LISTS)."""
        return self.request("record")

    def script_text(self) -> str:
        """The last program text received on the script port."""
        return self.request("script_text")

    def inject(self, fault: str) -> None:
        """'protective_stop', 'emergency_stop', 'not_in_remote_control', or the link faults
        'freeze' and 'link_reset' (as `freeze()` and `reset_links()`)."""
        if fault == "freeze":
            self.freeze()
        elif fault == "link_reset":
            self.reset_links()
        else:
            self.request("inject", fault=fault)

    def clear_faults(self) -> None:
        """Release the stops and the local mode, and unfreeze the links."""
        self.request("clear_faults")
        self.request("unfreeze")

    def set_speed_scaling(self, value: float) -> None:
        """The speed slider (0-1): reported as speed_scaling, slows the arm's following."""
        self.request("set_speed_scaling", value=value)

    def freeze(self) -> None:
        """Stop answering on every socket, keeping them open (a hung controller or link)."""
        self.request("freeze")

    def unfreeze(self) -> None:
        self.request("unfreeze")

    def reset_links(self) -> None:
        """Close every client socket with a reset; the ports keep listening."""
        self.request("reset_links")

    def wait_for(self, condition: Callable[[dict[str, Any]], bool], timeout: float,
                 what: str = "record") -> dict[str, Any]:
        """Poll `record()` (or `state()`) until `condition` holds; returns the last value."""
        deadline = time.monotonic() + timeout
        while True:
            value = self.record() if what == "record" else self.state()
            if condition(value) or time.monotonic() > deadline:
                return value
            time.sleep(0.02)
