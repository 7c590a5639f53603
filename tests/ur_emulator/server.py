"""The emulator process: asyncio servers for the dashboard (29999), RTDE (30004) and the script
port (30003) on one loopback address, the 500 Hz controller cycle, and a JSON-lines control
channel for the test. It runs in its own process because ur_rtde's constructors hold the GIL
while they connect. It exits when its parent dies, after `lifetime` seconds, or on request."""

from __future__ import annotations

import asyncio
import codecs
import contextlib
import ipaddress
import json
import os
import signal
import socket
import struct
import sys
import time
import traceback
from collections.abc import Coroutine
from typing import Any

from .control_script import split_programs
from .controller import Controller
from .dashboard import WELCOME, reply
from .rtde_protocol import HEADER
from .rtde_session import RtdeSession

DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT = 29999, 30004, 30003
CYCLE = 0.002  # e-Series controller cycle (500 Hz)
MAX_WRITE_BUFFER = 1 << 20  # a client that stops reading loses packages beyond this


class EmulatorServer:
    """Sockets and timing around one `Controller`."""

    def __init__(self, host: str, controller: Controller, parent_pid: int | None,
                 lifetime: float, control_port: int = 0) -> None:
        if not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"the emulator listens on loopback addresses only, not {host}")
        self.host = host
        self.controller = controller
        self.parent_pid = parent_pid
        self.lifetime = lifetime
        self.control_port = control_port
        self.links: set[asyncio.StreamWriter] = set()
        self.sessions: set[RtdeSession] = set()
        self.frozen = False
        self.exit_reason = ""

    async def run(self) -> None:
        """Serve until asked to stop; print one JSON 'ready' line once every port listens."""
        self.unfrozen = asyncio.Event()
        self.unfrozen.set()
        self.stopping = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(signum, self._stop, f"signal {signum}")
        servers = [await asyncio.start_server(handler, self.host, port)
                   for handler, port in ((self._dashboard, DASHBOARD_PORT),
                                         (self._rtde, RTDE_PORT), (self._script, SCRIPT_PORT))]
        control = await asyncio.start_server(self._control, self.host, self.control_port)
        port = control.sockets[0].getsockname()[1]
        print(json.dumps({"ready": True, "control_port": port, "pid": os.getpid()}), flush=True)
        tasks = [asyncio.create_task(self._cycle()), asyncio.create_task(self._watch())]
        await self.stopping.wait()
        for task in tasks:
            task.cancel()
        for server in [*servers, control]:
            server.close()
        self._reset_links()
        print(f"ur_emulator: exiting ({self.exit_reason})", file=sys.stderr, flush=True)

    def _stop(self, reason: str) -> None:
        self.exit_reason = self.exit_reason or reason
        self.stopping.set()

    # --- timing ----------------------------------------------------------------------------
    async def _cycle(self) -> None:
        """The controller cycle: a failure stops the emulator rather than freezing its state."""
        loop = asyncio.get_running_loop()
        due = loop.time()
        while True:
            now = self.controller.clock()
            try:
                self.controller.tick(now)
                if not self.frozen:
                    for session in list(self.sessions):
                        session.send_due(now)
            except Exception:
                traceback.print_exc()
                self._stop("the controller cycle failed")
                return
            due += CYCLE
            delay = due - loop.time()
            if delay < -0.05:  # starved of CPU: do not try to catch up
                due = loop.time()
            await asyncio.sleep(max(delay, 0.0))

    async def _watch(self) -> None:
        started = time.monotonic()
        while True:
            await asyncio.sleep(0.25)
            if self.parent_pid is not None and os.getppid() != self.parent_pid:
                self._stop(f"parent {self.parent_pid} is gone")
            elif time.monotonic() - started > self.lifetime:
                self._stop(f"lifetime of {self.lifetime} s reached")

    # --- links -------------------------------------------------------------------------------
    def _send(self, writer: asyncio.StreamWriter, data: bytes) -> None:
        if writer.is_closing() or writer.transport.get_write_buffer_size() > MAX_WRITE_BUFFER:
            return
        writer.write(data)

    @staticmethod
    def _peer(writer: asyncio.StreamWriter) -> str:
        peer = writer.get_extra_info("peername") or ("?", 0)
        return f"{peer[0]}:{peer[1]}"

    def _reset_links(self) -> None:
        """Close every client socket abruptly (RST), as a controller reboot or a cable does."""
        for writer in list(self.links):
            sock = writer.get_extra_info("socket")
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            writer.transport.abort()
        self.links.clear()
        self.sessions.clear()

    def _freeze(self, frozen: bool) -> None:
        self.frozen = frozen
        if frozen:
            self.unfrozen.clear()
        else:
            self.unfrozen.set()
        self.controller.record.add("links", {"event": "freeze" if frozen else "unfreeze"})

    async def _serve_link(self, writer: asyncio.StreamWriter,
                          body: Coroutine[Any, Any, None]) -> None:
        """Run one connection's handler; a closed or reset socket just ends it."""
        self.links.add(writer)
        try:
            await body
        except (asyncio.IncompleteReadError, ConnectionError, OSError):
            pass
        except Exception:  # an emulator bug: show it, drop this connection
            traceback.print_exc()
        finally:
            self.links.discard(writer)
            with contextlib.suppress(OSError, RuntimeError):
                writer.close()

    async def _dashboard(self, reader: asyncio.StreamReader,
                         writer: asyncio.StreamWriter) -> None:
        async def body() -> None:
            await self.unfrozen.wait()
            self._send(writer, (WELCOME + "\n").encode())
            while line := await reader.readline():
                await self.unfrozen.wait()
                command = line.decode("utf-8", "replace").strip()
                answer, close = reply(command, self.controller)
                self.controller.record.add("dashboard", {"command": command, "reply": answer})
                self._send(writer, (answer + "\n").encode())
                if close:
                    await writer.drain()
                    return

        await self._serve_link(writer, body())

    async def _rtde(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        session = RtdeSession(self._peer(writer), self.controller,
                              lambda data: self._send(writer, data))

        async def body() -> None:
            self.sessions.add(session)
            session.note("connect")
            try:
                while True:
                    size, msg = HEADER.unpack(await reader.readexactly(HEADER.size))
                    payload = await reader.readexactly(max(size - HEADER.size, 0))
                    await self.unfrozen.wait()
                    session.handle(msg, payload)
            finally:
                self.sessions.discard(session)
                session.note("close")

        await self._serve_link(writer, body())

    async def _script(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        async def body() -> None:
            decoder = codecs.getincrementaldecoder("utf-8")("replace")
            buffer = ""
            while chunk := await reader.read(1 << 16):
                await self.unfrozen.wait()
                programs, buffer = split_programs(buffer + decoder.decode(chunk))
                for program in programs:
                    self.controller.upload(program)

        await self._serve_link(writer, body())

    # --- control channel ---------------------------------------------------------------------
    async def _control(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(ConnectionError, asyncio.IncompleteReadError):
            while line := await reader.readline():
                try:
                    request = json.loads(line)
                    response = {"ok": True, "result": self._operate(request)}
                except Exception as error:  # reported to the test, not raised here
                    response = {"ok": False, "error": f"{type(error).__name__}: {error}"}
                writer.write(json.dumps(response).encode() + b"\n")
                await writer.drain()
        writer.close()

    def _operate(self, request: dict[str, Any]) -> Any:
        op = request["op"]
        c = self.controller
        if op == "state":
            return {**c.state(), "frozen": self.frozen, "rtde_sessions": len(self.sessions),
                    "links": len(self.links)}
        if op == "record":
            return c.record.as_data()
        if op == "script_text":
            return c.script_text
        if op == "inject":
            c.inject(request["fault"])
        elif op == "clear_faults":
            c.clear_faults()
        elif op == "set_speed_scaling":
            c.set_speed_scaling(float(request["value"]))
        elif op == "freeze":
            self._freeze(True)
        elif op == "unfreeze":
            self._freeze(False)
        elif op == "reset_links":
            c.record.add("links", {"event": "reset"})
            self._reset_links()
        elif op == "shutdown":
            self._stop("shutdown requested")
        elif op != "ping":
            raise ValueError(f"unknown operation {op!r}")
        return None


def serve(host: str, q0: list[float], *, tau: float = 0.03, unlock_delay: float = 5.0,
          parent_pid: int | None = None, lifetime: float = 300.0, control_port: int = 0) -> str:
    """Run an emulator until it stops; returns why it stopped."""
    server = EmulatorServer(host, Controller(q0, tau=tau, unlock_delay=unlock_delay),
                            parent_pid, lifetime, control_port)
    asyncio.run(server.run())
    return server.exit_reason
