"""The real ur_rtde clients in a child process a test can SIGKILL (the test side; the child
is `client_child`).

A test needs this because the clients can block for minutes on a dead link (`disconnect()`,
`stopScript()`, `servoStop()`, and the destructors, which disconnect), can crash in their
background reconnect, and because killing the client mid-stream is how a crashed host looks to
the controller.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from .api import PACKAGE_PARENT


class ClientError(RuntimeError):
    """A client call raised in the child, or the child did not answer in time."""


class RtdeClientProcess:
    """A child process holding ur_rtde clients for `host`. Leaving the `with` block kills it
    (SIGKILL): its clients never disconnect cleanly, so nothing can block the test."""

    def __init__(self, host: str, timeout: float = 20.0) -> None:
        self.host = host
        self.timeout = timeout
        self.process: subprocess.Popen[str] | None = None
        self._lines: queue.Queue[dict[str, Any] | None] = queue.Queue()
        self.events: list[dict[str, Any]] = []
        self._log = tempfile.NamedTemporaryFile(prefix="ur_client_", suffix=".log",
                                                delete=False)

    def __enter__(self) -> RtdeClientProcess:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PACKAGE_PARENT),
                                                          env.get("PYTHONPATH")]))
        self.process = subprocess.Popen(
            [sys.executable, "-m", "ur_emulator.client_child"], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=self._log, text=True, env=env)
        threading.Thread(target=self._pump, daemon=True).start()
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.kill()
        self._log.close()
        Path(self._log.name).unlink(missing_ok=True)

    def log(self) -> str:
        """What the child and ur_rtde wrote to stderr and std::cout."""
        return Path(self._log.name).read_text(errors="replace")

    def _pump(self) -> None:
        assert self.process is not None and self.process.stdout is not None
        for line in self.process.stdout:
            self._lines.put(json.loads(line))
        self.process.stdout.close()
        self._lines.put(None)

    def _next(self, timeout: float) -> dict[str, Any]:
        try:
            message = self._lines.get(timeout=timeout)
        except queue.Empty:
            raise ClientError(f"no answer from the client process within {timeout} s") from None
        if message is None:
            raise ClientError("the client process ended")
        return message

    def request(self, op: str, timeout: float | None = None, **arguments: Any) -> Any:
        """Send one request and wait for its answer."""
        self.send(op, **arguments)
        return self.result(timeout)

    def result(self, timeout: float | None = None) -> Any:
        """The answer to the request sent last (events on the way are kept in `events`)."""
        deadline = time.monotonic() + (timeout or self.timeout)
        while True:
            message = self._next(max(deadline - time.monotonic(), 0.0))
            if "event" in message:
                self.events.append(message)
                continue
            if not message["ok"]:
                raise ClientError(message["error"])
            return message["result"]

    def send(self, op: str, **arguments: Any) -> None:
        """Send a request without waiting for its answer (get it with `result()`)."""
        assert self.process is not None and self.process.stdin is not None
        try:
            self.process.stdin.write(json.dumps({"op": op, **arguments}) + "\n")
            self.process.stdin.flush()
        except (BrokenPipeError, ValueError):
            raise ClientError(f"the client process ended ({self.process.poll()})") from None

    def wait_event(self, name: str, timeout: float) -> dict[str, Any]:
        """Wait for a notification such as 'streaming'."""
        message = self._next(timeout)
        if message.get("event") != name:
            raise ClientError(f"expected the event {name!r}, got {message}")
        self.events.append(message)
        return message

    def connect(self, kind: str, timeout: float | None = None, **options: Any) -> float:
        """Construct the 'receive', 'control' or 'dashboard' client; returns seconds taken."""
        return self.request("connect", timeout, kind=kind, host=self.host, **options)

    def call(self, kind: str, method: str, *args: Any, timeout: float | None = None) -> Any:
        return self.request("call", timeout, kind=kind, method=method, args=list(args))

    def read(self) -> dict[str, Any]:
        """One reading of the receive interface's getters (client_child.RECEIVE_GETTERS)."""
        return self.request("read")

    def kill(self) -> float:
        """SIGKILL the child; returns the wall time by which it is dead (taken after the
        wait: a time taken before the kill would miss what the child sent if this process
        were preempted between the two)."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(5.0)
        killed_at = time.time()
        if self.process is not None and self.process.stdin is not None:
            with contextlib.suppress(OSError):
                self.process.stdin.close()
        return killed_at


