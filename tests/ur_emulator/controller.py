"""The emulated controller's state: RTDE registers, the running program, robot and safety modes,
faults, the RTDE watchdog, and the values every RTDE output field reports. It has no sockets;
the server feeds it client writes and calls `tick()` once per controller cycle."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

from .arm import ArmModel, tcp_pose
from .control_script import (
    Command,
    ControlScript,
    ScriptActions,
    ScriptProgram,
    parse_control_script,
    read_arguments,
)
from .record import Record
from .rtde_protocol import REGISTER_COUNT, default_value, register_of

# runtime_state
STOPPING, STOPPED, PLAYING, PAUSING, PAUSED, RESUMING = range(6)
RUNTIME_NAMES = ("STOPPING", "STOPPED", "PLAYING", "PAUSING", "PAUSED", "RESUMING")
# robot_mode
POWER_OFF, POWER_ON, IDLE, RUNNING = 3, 4, 5, 7
ROBOT_MODE_NAMES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING",
                    3: "POWER_OFF", 4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING",
                    8: "UPDATING_FIRMWARE"}
# safety_mode
NORMAL, PROTECTIVE_STOP, ROBOT_EMERGENCY_STOP = 1, 3, 7
SAFETY_MODE_NAMES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY",
                     5: "SAFEGUARD_STOP", 6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP",
                     8: "VIOLATION", 9: "FAULT"}
# safety_status_bits
BIT_NORMAL, BIT_PROTECTIVE, BIT_ROBOT_ESTOP, BIT_ESTOP, BIT_SAFETY_STOPPED = 0, 2, 6, 7, 10
# robot_status_bits
BIT_POWER_ON, BIT_PROGRAM_RUNNING = 0, 1
JOINT_RUNNING, JOINT_POWER_OFF, JOINT_IDLE = 253, 238, 255

FAULTS = ("protective_stop", "emergency_stop", "not_in_remote_control")
#: A cycle this late means the emulator's process was starved of CPU (a real controller's
#: real-time loop never is): the watchdog does not count the gap, in which the client's
#: writes waited in the socket, unread.
STARVED = 0.02
DEFAULT_VERSION = (5, 15, 1, 1203)


class Controller:
    """One UR e-Series controller with a UR5e arm starting at `q0`."""

    def __init__(self, q0: Sequence[float], tau: float = 0.03, unlock_delay: float = 5.0,
                 version: tuple[int, int, int, int] = DEFAULT_VERSION,
                 serial: str = "20235500042",
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.arm = ArmModel(q0, tau)
        self.record = Record()
        self.version = version
        self.serial = serial
        self.unlock_delay = unlock_delay
        self.clock = clock
        self.started_at = self.now = clock()
        self.in_int = [0] * REGISTER_COUNT
        self.in_double = [0.0] * REGISTER_COUNT
        self.out_int = [0] * REGISTER_COUNT
        self.out_double = [0.0] * REGISTER_COUNT
        self.other_inputs: dict[str, Any] = {}
        self.robot_mode = RUNNING
        self.safety_mode = NORMAL
        self.protective_stop_at: float | None = None
        self.remote_control = True
        self.runtime_state = STOPPED
        self.script: ControlScript | None = None  # the last control script uploaded
        self.script_text = ""  # the last program text received on the script port
        self.program: ScriptProgram | None = None
        self.program_name = "<unnamed>"
        self.loaded_program: str | None = None
        self.watchdog: dict[str, Any] | None = None
        self.speed_fraction = 1.0
        self.snapshot: dict[str, Any] = {}
        self._refresh_snapshot()

    # --- registers as the script sees them -------------------------------------------------
    def read_int(self, index: int) -> int:
        return self.in_int[index]

    def read_double(self, index: int) -> float:
        return self.in_double[index]

    def write_int(self, index: int, value: int) -> None:
        self.out_int[index] = int(value)

    # --- client input ------------------------------------------------------------------------
    def write_inputs(self, values: dict[str, Any]) -> None:
        """Apply one incoming data package: registers, the speed slider, watchdog kicks, and
        the record of commands (a non-zero write to the script's command register)."""
        now = time.time()
        for name, value in values.items():
            register = register_of(name)
            if register is None:
                self.other_inputs[name] = value
            elif register[1] == "int":
                self.in_int[register[2]] = int(value)
            elif register[1] == "double":
                self.in_double[register[2]] = float(value)
        if self.other_inputs.get("speed_slider_mask", 0) & 1 and "speed_slider_fraction" in values:
            self.set_speed_scaling(float(values["speed_slider_fraction"]))
        if self.watchdog is not None and self.watchdog["register"] in values:
            self.watchdog["last_kick"] = self.now
            self.record.add("kicks", now)
        offset = self.script.int_offset if self.script else 0
        command_register = f"input_int_register_{offset}"
        cmd = values.get(command_register, 0)
        if cmd:
            command = self.script.commands.get(cmd) if self.script else None
            args = read_arguments(self.script, self, command) if self.script and command else []
            # controller_time: the last cycle's time, from which the script's next cycle
            # applies the command (the arm integrates toward it from there)
            self.record.add("commands", {"t": now, "controller_time": self.now - self.started_at,
                                         "id": cmd, "name": command.name if command else "unknown",
                                         "args": args})

    # --- programs ----------------------------------------------------------------------------
    def upload(self, text: str) -> None:
        """A script arrived on the script port: replace the running program with it, if the
        controller accepts programs now (remote control, arm running, no safety stop)."""
        script = parse_control_script(text)
        self.script_text = text
        entry: dict[str, Any] = {"size": len(text), "program": "<unparsed>", "started": False,
                                 "protocol": script.summary() if script else None}
        if script is not None:
            self.script = script
            entry["program"] = script.program_name
        reason = self._refusal()
        if reason is None and script is None:
            reason = "not a control script: run and ended at once (not emulated)"
        if reason is not None:
            entry["reason"] = reason
            self.record.add("script_uploads", entry)
            return
        assert script is not None
        self.stop_program("replaced by an uploaded script")
        entry["started"] = True
        self.record.add("script_uploads", entry)
        self.program = ScriptProgram(script, self, self._actions())
        self.program_name = script.program_name
        self.runtime_state = PLAYING
        self.program.start()
        self.record.add("program", {"event": "started", "program": script.program_name})

    def _refusal(self) -> str | None:
        if not self.remote_control:
            return "local mode: the controller takes no scripts"
        if self.robot_mode != RUNNING or self.safety_mode != NORMAL:
            return (f"robot mode {ROBOT_MODE_NAMES[self.robot_mode]}, safety mode "
                    f"{SAFETY_MODE_NAMES.get(self.safety_mode, self.safety_mode)}")
        return None

    def _actions(self) -> ScriptActions:
        return ScriptActions(servoj=self._servoj, servo_stop=self._servo_stop,
                             set_watchdog=self._set_watchdog, executed=self._executed)

    def _servoj(self, target: list[float], settings: list[float]) -> None:
        self.arm.servo(target)

    def _servo_stop(self, deceleration: float) -> None:
        self.arm.hold()

    def _set_watchdog(self, register: str, min_frequency: float, action: str) -> None:
        self.watchdog = {"register": register, "min_frequency": min_frequency,
                         "action": action, "last_kick": self.now}
        self.record.add("watchdog", {"register": register, "min_frequency": min_frequency,
                                     "action": action})

    def _executed(self, command: Command, args: list[float]) -> None:
        self.record.add("executed", {"id": command.cmd_id, "name": command.name, "args": args})

    def stop_program(self, reason: str) -> None:
        """Stop the running program; the arm holds and the watchdogs are removed."""
        if self.runtime_state == STOPPED and self.program is None:
            return
        self.runtime_state = STOPPED
        self.program = None
        self.watchdog = None
        self.arm.hold()
        self.record.add("program", {"event": "stopped", "program": self.program_name,
                                    "reason": reason})

    # --- the controller cycle ----------------------------------------------------------------
    def tick(self, now: float | None = None) -> None:
        """One controller cycle: the script's loop pass, the watchdog, the arm, the outputs."""
        now = self.clock() if now is None else now
        dt, self.now = now - self.now, now
        if self.watchdog is not None and dt > STARVED:
            self.watchdog["last_kick"] += dt
            self.record.add("starved", {"seconds": dt})
        if self.program is not None and self.runtime_state == PLAYING:
            if not self.program.cycle():
                self.stop_program("script ended (stop script command)")
        self._check_watchdog()
        self.arm.speed_scaling = self.speed_fraction
        self.arm.step(dt)
        self._refresh_snapshot()

    def _check_watchdog(self) -> None:
        dog = self.watchdog
        if dog is None or self.runtime_state != PLAYING or dog["min_frequency"] <= 0.0:
            return
        if self.now - dog["last_kick"] <= 1.0 / dog["min_frequency"]:
            return
        silent = self.now - dog["last_kick"]
        self.record.add("watchdog_trips", {
            "register": dog["register"], "min_frequency": dog["min_frequency"],
            "action": dog["action"], "last_kick": time.time() - silent})
        if dog["action"] == "stop":
            self.stop_program("RTDE watchdog: no input update")
        elif dog["action"] == "pause":
            self.runtime_state = PAUSED
            self.arm.hold()
        self.watchdog = None

    # --- faults and commissioning --------------------------------------------------------------
    def inject(self, fault: str) -> None:
        """Put the controller in a fault state (see FAULTS)."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; known: {FAULTS}")
        self.record.add("faults", {"fault": fault, "action": "inject"})
        if fault == "protective_stop":
            self.safety_mode = PROTECTIVE_STOP
            self.protective_stop_at = self.now
            self.stop_program("protective stop")
        elif fault == "emergency_stop":
            self.safety_mode = ROBOT_EMERGENCY_STOP
            self.robot_mode = POWER_OFF
            self.stop_program("emergency stop")
        else:
            self.remote_control = False

    def clear_faults(self) -> None:
        """Release the stops and return to remote control. As on the robot, the program does
        not restart, and after an emergency stop the arm stays off until power on and brake
        release (dashboard)."""
        self.record.add("faults", {"fault": "all", "action": "clear"})
        self.safety_mode = NORMAL
        self.protective_stop_at = None
        self.remote_control = True

    def unlock_protective_stop(self) -> bool:
        """The dashboard's unlock: allowed `unlock_delay` seconds after the stop."""
        if self.safety_mode != PROTECTIVE_STOP:
            return True
        assert self.protective_stop_at is not None
        if self.now - self.protective_stop_at < self.unlock_delay:
            return False
        self.safety_mode = NORMAL
        self.protective_stop_at = None
        return True

    def set_speed_scaling(self, fraction: float) -> None:
        """The speed slider: scales how fast the arm follows its target."""
        if not 0.0 <= fraction <= 1.0 or math.isnan(fraction):
            raise ValueError("speed scaling must be within [0, 1]")
        self.speed_fraction = fraction

    def power(self, on: bool) -> None:
        if not on:
            self.stop_program("power off")
            self.robot_mode = POWER_OFF
        elif self.robot_mode == POWER_OFF and self.safety_mode == NORMAL:
            self.robot_mode = IDLE

    def brake_release(self) -> None:
        if self.robot_mode == IDLE:
            self.robot_mode = RUNNING

    # --- outputs -----------------------------------------------------------------------------
    def status_bits(self) -> tuple[int, int]:
        """(robot_status_bits, safety_status_bits) consistent with the modes."""
        robot = (1 << BIT_POWER_ON) if self.robot_mode in (POWER_ON, IDLE, 6, RUNNING) else 0
        if self.runtime_state == PLAYING:
            robot |= 1 << BIT_PROGRAM_RUNNING
        safety = {NORMAL: 1 << BIT_NORMAL, 2: 1 << 1,
                  PROTECTIVE_STOP: (1 << BIT_PROTECTIVE) | (1 << BIT_SAFETY_STOPPED),
                  ROBOT_EMERGENCY_STOP: (1 << BIT_ROBOT_ESTOP) | (1 << BIT_ESTOP)
                  | (1 << BIT_SAFETY_STOPPED)}.get(self.safety_mode, 0)
        return robot, safety

    def _refresh_snapshot(self) -> None:
        q, qd = self.arm.q.tolist(), self.arm.qd.tolist()
        robot_bits, safety_bits = self.status_bits()
        joint = {POWER_OFF: JOINT_POWER_OFF, IDLE: JOINT_IDLE}.get(self.robot_mode, JOINT_RUNNING)
        pose = tcp_pose(q)
        self.snapshot = {
            "timestamp": self.now - self.started_at, "actual_q": q, "actual_qd": qd,
            "target_q": self.arm.target.tolist(), "target_qd": qd, "actual_TCP_pose": pose,
            "target_TCP_pose": pose, "robot_mode": self.robot_mode,
            "safety_mode": self.safety_mode, "safety_status": self.safety_mode,
            "runtime_state": self.runtime_state, "robot_status_bits": robot_bits,
            "safety_status_bits": safety_bits, "speed_scaling": self.speed_fraction,
            "target_speed_fraction": self.speed_fraction, "joint_mode": [joint] * 6,
            "joint_temperatures": [30.0] * 6, "actual_main_voltage": 48.0,
            "actual_robot_voltage": 48.0 if robot_bits & 1 else 0.0,
            "actual_joint_voltage": [48.0 if robot_bits & 1 else 0.0] * 6,
            "actual_execution_time": 0.2, "payload": 0.0,
        }

    def value(self, name: str, rtde_type: str) -> Any:
        """The current value of an output field (unmodelled fields read zero)."""
        if name in self.snapshot:
            return self.snapshot[name]
        register = register_of(name)
        if register is not None:
            direction, kind, index = register
            if kind == "int":
                return (self.out_int if direction == "output" else self.in_int)[index]
            if kind == "double":
                return (self.out_double if direction == "output" else self.in_double)[index]
        return default_value(rtde_type)

    def state(self) -> dict[str, Any]:
        """The arm and the modes as plain data."""
        return {
            "q": self.arm.q.tolist(), "qd": self.arm.qd.tolist(),
            "target": self.arm.target.tolist(), "tcp_pose": self.snapshot["actual_TCP_pose"],
            "timestamp": self.now - self.started_at, "robot_mode": self.robot_mode,
            "safety_mode": self.safety_mode, "runtime_state": self.runtime_state,
            "runtime": RUNTIME_NAMES[self.runtime_state],
            "program_running": self.runtime_state == PLAYING, "program": self.program_name,
            "speed_scaling": self.speed_fraction, "remote_control": self.remote_control,
            "watchdog": None if self.watchdog is None else dict(self.watchdog),
            "output_int_registers": self.out_int[:3] + self.out_int[24:27],
            "tau": self.arm.tau,
        }
