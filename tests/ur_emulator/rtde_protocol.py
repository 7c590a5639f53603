"""RTDE protocol version 2 as the controller speaks it on port 30004: package framing, the types
of the named fields, and recipes that encode the data packages.

Every package is a big-endian uint16 size (header included) and a uint8 type, then the payload.
The client names the fields it wants; the controller answers with their types and a recipe id
and from then on sends (outputs) or expects (inputs) the values packed in that order.
"""

from __future__ import annotations

import dataclasses as dc
import re
import struct
from collections.abc import Callable, Iterable
from enum import IntEnum
from typing import Any

PROTOCOL_VERSION = 2
HEADER = struct.Struct(">HB")


class Msg(IntEnum):
    """Package types (ASCII letters)."""

    REQUEST_PROTOCOL_VERSION = ord("V")
    GET_URCONTROL_VERSION = ord("v")
    TEXT_MESSAGE = ord("M")
    DATA_PACKAGE = ord("U")
    SETUP_OUTPUTS = ord("O")
    SETUP_INPUTS = ord("I")
    START = ord("S")
    PAUSE = ord("P")


# struct codes of each RTDE type (vectors repeat the element code)
TYPE_CODES: dict[str, str] = {
    "BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
    "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I",
}
VECTOR_LENGTHS = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}

_V6 = "VECTOR6D"
# Outputs of an e-Series controller (UR's RTDE guide, PolyScope 5.x), registers aside.
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE", "target_q": _V6, "target_qd": _V6, "target_qdd": _V6,
    "target_current": _V6, "target_moment": _V6, "actual_q": _V6, "actual_qd": _V6,
    "actual_qdd": _V6, "actual_current": _V6, "actual_current_as_torque": _V6,
    "actual_moment": _V6, "joint_control_output": _V6, "actual_TCP_pose": _V6,
    "actual_TCP_speed": _V6, "actual_TCP_force": _V6, "target_TCP_pose": _V6,
    "target_TCP_speed": _V6, "actual_digital_input_bits": "UINT64", "joint_temperatures": _V6,
    "actual_execution_time": "DOUBLE", "robot_mode": "INT32", "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32", "safety_status": "INT32", "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE", "target_speed_fraction": "DOUBLE", "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE", "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE", "actual_joint_voltage": _V6,
    "actual_digital_output_bits": "UINT64", "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D", "elbow_velocity": "VECTOR3D", "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32", "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE", "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE", "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE", "tool_mode": "UINT32", "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE", "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32", "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE", "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32", "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE", "payload_cog": "VECTOR3D", "payload_inertia": _V6,
    "script_control_line": "UINT32", "ft_raw_wrench": _V6,
    "joint_position_deviation_ratio": "DOUBLE", "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
}
# Inputs a client may set up, registers aside.
INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8", "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8", "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": _V6,
}
_REGISTER = re.compile(r"(input|output)_(int|double|bit)_register_(\d+)$")
REGISTER_COUNT = 48  # int and double registers 0-23 (lower) and 24-47 (upper range)


def register_of(name: str) -> tuple[str, str, int] | None:
    """('input'|'output', 'int'|'double'|'bit', index) for a register field name."""
    match = _REGISTER.match(name)
    if match is None:
        return None
    direction, kind, index = match.group(1), match.group(2), int(match.group(3))
    valid = 64 <= index < 128 if kind == "bit" else index < REGISTER_COUNT
    return (direction, kind, index) if valid else None


def _register_type(name: str) -> str | None:
    register = register_of(name)
    if register is None:
        return None
    return {"int": "INT32", "double": "DOUBLE", "bit": "BOOL"}[register[1]]


def output_type(name: str) -> str | None:
    """The type the controller reports for an output field, None if it has no such field
    (input registers can be read back as outputs too)."""
    return OUTPUT_TYPES.get(name) or _register_type(name)


def input_type(name: str) -> str | None:
    """The type of a field a client may write, None if it is not writable."""
    if name in INPUT_TYPES:
        return INPUT_TYPES[name]
    register = register_of(name)
    return _register_type(name) if register is not None and register[0] == "input" else None


def default_value(rtde_type: str) -> Any:
    """What the controller sends for a field the emulator does not model: zeros."""
    if rtde_type in VECTOR_LENGTHS:
        return [0.0 if rtde_type.endswith("D") else 0] * VECTOR_LENGTHS[rtde_type]
    return 0.0 if rtde_type == "DOUBLE" else False if rtde_type == "BOOL" else 0


def frame(msg: int, payload: bytes = b"") -> bytes:
    """One package: header and payload."""
    return HEADER.pack(HEADER.size + len(payload), msg) + payload


def split_names(payload: bytes) -> list[str]:
    """The comma-separated field names of a setup package (the client ends them with a comma)."""
    return [name for name in payload.decode("ascii", "replace").split(",") if name]


@dc.dataclass
class Recipe:
    """A numbered list of typed fields, packed in order after the recipe id."""

    recipe_id: int
    names: list[str]
    types: list[str]
    frequency: float = 0.0
    _struct: struct.Struct = dc.field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._struct = struct.Struct(">B" + "".join(TYPE_CODES[t] for t in self.types))

    def encode(self, value_of: Callable[[str, str], Any]) -> bytes:
        """A data package with each field's value from `value_of(name, type)`."""
        flat: list[Any] = [self.recipe_id]
        for name, rtde_type in zip(self.names, self.types, strict=True):
            value = value_of(name, rtde_type)
            if rtde_type in VECTOR_LENGTHS:
                flat.extend(value)
            else:
                flat.append(value)
        return frame(Msg.DATA_PACKAGE, self._struct.pack(*flat))

    def decode(self, payload: bytes) -> dict[str, Any]:
        """The named values of a data package payload (recipe id byte included)."""
        flat = iter(self._struct.unpack(payload))
        next(flat)  # recipe id
        values: dict[str, Any] = {}
        for name, rtde_type in zip(self.names, self.types, strict=True):
            count = VECTOR_LENGTHS.get(rtde_type)
            values[name] = [next(flat) for _ in range(count)] if count else next(flat)
        return values


def setup_reply(msg: int, recipe_id: int, types: Iterable[str]) -> bytes:
    """Answer to a setup package: the recipe id (0 if refused) and the types, comma-separated."""
    return frame(msg, bytes([recipe_id]) + ",".join(types).encode("ascii"))


def text_message(message: str, source: str = "URControl", level: int = 1) -> bytes:
    """A text message package (protocol 2: length-prefixed message and source, then the level:
    0 exception, 1 error, 2 warning, 3 info)."""
    body, origin = message.encode()[:255], source.encode()[:255]
    return frame(Msg.TEXT_MESSAGE, bytes([len(body)]) + body + bytes([len(origin)]) + origin
                 + bytes([level]))


def parse_text_message(payload: bytes) -> str:
    """The message of a text message package sent by a client (protocol 2 layout)."""
    if not payload:
        return ""
    return payload[1:1 + payload[0]].decode("utf-8", "replace")
