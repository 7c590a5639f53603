"""The register protocol of ur_rtde's control script, read from the script the client uploads and
run natively (the emulator does not interpret URScript in general).

The script polls input int register 0 (24 with the upper-range flag) every controller cycle.
0 means idle: it answers "ready" (1) on output int register 0. A "realtime" command (servoJ and
the like) is executed on every cycle it is in the register and answered "ready". Any other
command is executed once and answered "done" (2) until the client writes 0 again. The command
ids, their argument registers, the realtime set and the stop-script id all come from the text:
the `if cmd == N` branches of `process_cmd` and the main loop's realtime test.
"""

from __future__ import annotations

import dataclasses as dc
import re
from collections.abc import Callable
from typing import Protocol

READY = 1
DONE = 2

_BRANCH = re.compile(r"^[ \t]*(?:el)?if\s+cmd\s*==\s*(\d+)\s*:", re.MULTILINE)
_PROCESS_CMD = re.compile(r"^[ \t]*def\s+process_cmd\s*\(\s*cmd\s*\)\s*:", re.MULTILINE)
_STOP_ID = re.compile(r"return\s+cmd\s*!=\s*(\d+)")
_REALTIME = re.compile(r"^[ \t]*if\s+(cmd\s*==\s*\d+(?:\s+or\s+cmd\s*==\s*\d+)+)\s*:",
                       re.MULTILINE)
# The client injects the offset after the comment that ends the line, so the value is the
# first token of the next line: "reg_offset_int = # int register offset\n24    global ...".
_OFFSET = re.compile(r"reg_offset_(int|float)\s*=\s*(?:#[^\n]*\n\s*)?(\d+)")
_READERS = ("q_from_input_float_registers", "pose_from_input_float_registers",
            "read_input_float_reg", "read_input_integer_reg")
_READ_OR_CALL = re.compile(rf"\b(?P<reader>{'|'.join(_READERS)})\((?P<index>\d+)\)"
                           r"|\b(?P<call>\w+)\(")
_TEXTMSG = re.compile(r'textmsg\("([^"]*)"')
_COMMENT = re.compile(r"^\s*#\s*(\w+)\s*$", re.MULTILINE)
_WATCHDOG = re.compile(r'rtde_set_watchdog\("(input_int_register_(\d+))"\s*,\s*\w+\s*,\s*'
                       r'"(\w+)"\)')
_PROGRAM_NAME = re.compile(r"^def\s+(\w+)\s*\(\s*\)\s*:", re.MULTILINE)
_HELPER = re.compile(r"^([ \t]+)(?:def|thread)\s+(\w+)\s*\(", re.MULTILINE)


@dc.dataclass(frozen=True)
class Command:
    """One branch of `process_cmd`: its id, a name (its textmsg or comment), what the emulator
    does with it, and the registers it reads in order: ('double'|'int', index before offset)."""

    cmd_id: int
    name: str
    kind: str  # servoj | servo_stop | set_watchdog | stop_script | other
    arguments: tuple[tuple[str, int], ...]
    realtime: bool


@dc.dataclass(frozen=True)
class ControlScript:
    """What the emulator needs of an uploaded control script."""

    program_name: str
    int_offset: int
    float_offset: int
    commands: dict[int, Command]
    realtime_ids: frozenset[int]
    stop_id: int | None
    watchdog_register: str
    watchdog_action: str
    size: int

    def ids_of(self, kind: str) -> list[int]:
        """The ids of the commands of one kind (normally one)."""
        return [c.cmd_id for c in self.commands.values() if c.kind == kind]

    def summary(self) -> dict[str, object]:
        """Plain data for the record: id -> [name, kind, argument registers (with offset)]."""
        offsets = {"int": self.int_offset, "double": self.float_offset}
        table = {str(c.cmd_id): [c.name, c.kind, [f"{kind}{index + offsets[kind]}"
                                                  for kind, index in c.arguments]]
                 for c in self.commands.values()}
        return {"program": self.program_name, "int_offset": self.int_offset,
                "float_offset": self.float_offset, "realtime_ids": sorted(self.realtime_ids),
                "stop_id": self.stop_id, "watchdog_register": self.watchdog_register,
                "watchdog_action": self.watchdog_action, "commands": table, "size": self.size}


_PROGRAM_START = re.compile(r"(def|sec)\s+\w+\s*\(\s*\)\s*:")
_PROGRAM_END = re.compile(r"^end[ \t]*\r?\n", re.MULTILINE)


def split_programs(buffer: str) -> tuple[list[str], str]:
    """Complete programs in what the script port received so far, and the incomplete rest.
    A program is a `def name():` block closed by `end` at the start of a line; any other
    line is a statement of its own."""
    programs: list[str] = []
    while True:
        buffer = buffer.lstrip("\r\n")
        line_end = buffer.find("\n")
        if line_end < 0:
            return programs, buffer
        if not _PROGRAM_START.match(buffer):
            programs.append(buffer[:line_end + 1])
            buffer = buffer[line_end + 1:]
            continue
        end = _PROGRAM_END.search(buffer, line_end + 1)
        if end is None:
            return programs, buffer
        programs.append(buffer[:end.end()])
        buffer = buffer[end.end():]


def _helpers(header: str) -> dict[str, str]:
    """Bodies of the functions the script defines before process_cmd, by name (a body ends
    where the next function at the same indentation starts)."""
    matches = list(_HELPER.finditer(header))
    return {m.group(2): header[m.end():matches[i + 1].start() if i + 1 < len(matches)
                               else len(header)] for i, m in enumerate(matches)}


def _arguments(body: str, helpers: dict[str, str]) -> tuple[tuple[str, int], ...]:
    """Registers a branch reads, itself or through the helper functions it calls (such as
    exec_stopl_stopj), in order of appearance."""
    found: list[tuple[str, int]] = []
    for match in _READ_OR_CALL.finditer(body):
        if match.group("reader") is None:
            nested = _arguments(helpers[match.group("call")], {}) \
                if match.group("call") in helpers else ()
            found.extend(e for e in nested if e not in found)
            continue
        reader, index = match.group("reader"), int(match.group("index"))
        if reader.endswith("_registers"):
            entries = [("double", index + i) for i in range(6)]
        else:
            entries = [("int" if "integer" in reader else "double", index)]
        found.extend(e for e in entries if e not in found)
    return tuple(found)


def _kind(cmd_id: int, body: str, stop_id: int | None) -> str:
    if cmd_id == stop_id:
        return "stop_script"
    if "rtde_set_watchdog(" in body:
        return "set_watchdog"
    if re.search(r"\bservo_target\s*=", body) and "q_from_input_float_registers" in body:
        return "servoj"
    if re.search(r"\bkill\s+servo_thrd\b", body) and re.search(r"\bstop[lj]\(", body):
        return "servo_stop"
    return "other"


def parse_control_script(text: str) -> ControlScript | None:
    """The register protocol of an uploaded script, None if the script has no `process_cmd`
    (it is some other program, not ur_rtde's control script)."""
    start = _PROCESS_CMD.search(text)
    if start is None:
        return None
    end = text.find("# HEADER_END", start.end())
    section = text[start.end(): end if end >= 0 else len(text)]
    stop_match = _STOP_ID.search(section)
    stop_id = int(stop_match.group(1)) if stop_match else None
    loop = text[end:] if end >= 0 else text
    realtime_match = _REALTIME.search(loop)
    realtime = frozenset(int(n) for n in re.findall(r"\d+", realtime_match.group(1))) \
        if realtime_match else frozenset()
    offsets = {kind: int(value) for kind, value in _OFFSET.findall(text)}
    helpers = {name: body for name, body in _helpers(text[:start.start()]).items()
               if name not in _READERS}
    branches = list(_BRANCH.finditer(section))
    commands: dict[int, Command] = {}
    int_offset = offsets.get("int", 0)
    watchdog = (f"input_int_register_{int_offset}", "stop")
    for i, branch in enumerate(branches):
        cmd_id = int(branch.group(1))
        body_end = branches[i + 1].start() if i + 1 < len(branches) else len(section)
        body = section[branch.end():body_end]
        kind = _kind(cmd_id, body, stop_id)
        names = _TEXTMSG.findall(body) or _COMMENT.findall(body) or [f"cmd_{cmd_id}"]
        name = names[0].removesuffix(" done")
        commands[cmd_id] = Command(cmd_id, name, kind, _arguments(body, helpers),
                                   cmd_id in realtime)
        if kind == "set_watchdog":
            watchdog = _watchdog_call(body, int_offset) or watchdog
    program = _PROGRAM_NAME.search(text)
    return ControlScript(program.group(1) if program else "<unnamed>", int_offset,
                         offsets.get("float", 0), commands, realtime, stop_id, *watchdog,
                         len(text))


def _watchdog_call(body: str, int_offset: int) -> tuple[str, str] | None:
    """(register, action) of the rtde_set_watchdog call the script makes at this offset: the
    one whose register matches the offset, else the last (the `else` branch)."""
    calls = _WATCHDOG.findall(body)
    for register, index, action in calls:
        if int(index) == int_offset:
            return register, action
    return (calls[-1][0], calls[-1][2]) if calls else None


class Registers(Protocol):
    """The RTDE registers the script reads and writes."""

    def read_int(self, index: int) -> int: ...
    def read_double(self, index: int) -> float: ...
    def write_int(self, index: int, value: int) -> None: ...


def read_arguments(script: ControlScript, registers: Registers, command: Command) -> list[float]:
    """The argument registers of a command, in the order the script reads them."""
    return [float(registers.read_int(index + script.int_offset)) if kind == "int"
            else registers.read_double(index + script.float_offset)
            for kind, index in command.arguments]


@dc.dataclass
class ScriptActions:
    """What executing a command does to the controller: servoj(target, args),
    servo_stop(deceleration), set_watchdog(register, min_frequency, action),
    executed(command, args) for the record."""

    servoj: Callable[[list[float], list[float]], None]
    servo_stop: Callable[[float], None]
    set_watchdog: Callable[[str, float, str], None]
    executed: Callable[[Command, list[float]], None]


class ScriptProgram:
    """The main loop of the control script, one `cycle()` per controller cycle (sync())."""

    def __init__(self, script: ControlScript, registers: Registers,
                 actions: ScriptActions) -> None:
        self.script = script
        self.registers = registers
        self.actions = actions
        self.executing = False

    def start(self) -> None:
        """What the script does before its loop: async progress 'finished', then 'ready'."""
        self.registers.write_int(self.script.int_offset + 2, 65536)
        self._signal(READY)

    def _signal(self, value: int) -> None:
        self.registers.write_int(self.script.int_offset, value)

    def cycle(self) -> bool:
        """One pass of `while keep_running`; False when the script ends."""
        cmd = self.registers.read_int(self.script.int_offset)
        if cmd in self.script.realtime_ids:
            keep_running = self._process(cmd)
            self._signal(READY)
            return keep_running
        if cmd == 0:
            self.executing = False
            self._signal(READY)
            return True
        keep_running = True
        if not self.executing:
            keep_running = self._process(cmd)
        self.executing = True
        return keep_running

    def _process(self, cmd: int) -> bool:
        command = self.script.commands.get(cmd)
        if command is not None:
            args = read_arguments(self.script, self.registers, command)
            if command.kind == "servoj":
                self.actions.servoj(args[:6], args[6:])
            elif command.kind == "servo_stop":
                self.actions.servo_stop(args[0] if args else 0.0)
            elif command.kind == "set_watchdog":
                self.actions.set_watchdog(self.script.watchdog_register,
                                          args[0] if args else 0.0, self.script.watchdog_action)
            if not command.realtime:
                self.actions.executed(command, args)
        if cmd == self.script.stop_id:
            return False
        self._signal(DONE)
        return True
