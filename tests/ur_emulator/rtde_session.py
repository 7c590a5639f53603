"""One RTDE client connection as the controller sees it: the setup handshake, the recipes it
set up, and the data packages it is due at its output frequency. No sockets here: packages
come in through `handle()` and go out through the `send` callback."""

from __future__ import annotations

import struct
from collections.abc import Callable

from .controller import Controller
from .rtde_protocol import (
    PROTOCOL_VERSION,
    Msg,
    Recipe,
    frame,
    input_type,
    output_type,
    parse_text_message,
    setup_reply,
    split_names,
    text_message,
)

MAX_FREQUENCY = 500.0  # e-Series


class RtdeSession:
    """Recipes and start/pause state of one connection."""

    def __init__(self, peer: str, controller: Controller, send: Callable[[bytes], None]) -> None:
        self.peer = peer
        self.controller = controller
        self.send = send
        self.outputs: list[Recipe] = []
        self.inputs: dict[int, Recipe] = {}
        self.started = False
        self.next_due: list[float] = []
        self.protocol = 1

    def note(self, event: str, **details: object) -> None:
        """Record an event of this connection."""
        self.controller.record.add("rtde_sessions", {"peer": self.peer, "event": event,
                                                     **details})

    def handle(self, msg: int, payload: bytes) -> None:
        """Answer one package from the client."""
        if msg == Msg.REQUEST_PROTOCOL_VERSION:
            version = struct.unpack(">H", payload[:2])[0] if len(payload) >= 2 else 0
            accepted = version == PROTOCOL_VERSION
            if accepted:
                self.protocol = version
            self.note("protocol", version=version, accepted=accepted)
            self.send(frame(msg, bytes([accepted])))
        elif msg == Msg.GET_URCONTROL_VERSION:
            self.send(frame(msg, struct.pack(">4I", *self.controller.version)))
        elif msg == Msg.SETUP_OUTPUTS:
            self._setup_outputs(payload)
        elif msg == Msg.SETUP_INPUTS:
            self._setup_inputs(payload)
        elif msg == Msg.START:
            self.started = True
            now = self.controller.clock()
            self.next_due = [now] * len(self.outputs)
            self.note("start")
            self.send(frame(msg, b"\x01"))
        elif msg == Msg.PAUSE:
            self.started = False
            self.note("pause")
            self.send(frame(msg, b"\x01"))
        elif msg == Msg.DATA_PACKAGE:
            self._data(payload)
        elif msg == Msg.TEXT_MESSAGE:
            self.controller.record.add("text_messages", {"peer": self.peer,
                                                         "message": parse_text_message(payload)})
        else:
            self.send(text_message(f"Unknown package type {msg}", level=1))

    def _setup_outputs(self, payload: bytes) -> None:
        frequency = struct.unpack(">d", payload[:8])[0] if len(payload) >= 8 else 0.0
        names = split_names(payload[8:])
        types = [output_type(name) or "NOT_FOUND" for name in names]
        if "NOT_FOUND" in types or not names:
            self.note("outputs refused", names=names, types=types)
            self.send(setup_reply(Msg.SETUP_OUTPUTS, 0, types))
            return
        used = min(max(frequency, 1.0), MAX_FREQUENCY)
        recipe = Recipe(len(self.outputs) + 1, names, types, used)
        self.outputs.append(recipe)
        self.next_due.append(self.controller.clock())
        self.note("outputs", recipe_id=recipe.recipe_id, frequency=frequency, names=names)
        self.send(setup_reply(Msg.SETUP_OUTPUTS, recipe.recipe_id, types))

    def _setup_inputs(self, payload: bytes) -> None:
        names = split_names(payload)
        types = [input_type(name) or "NOT_FOUND" for name in names]
        if "NOT_FOUND" in types or not names:
            self.note("inputs refused", names=names, types=types)
            self.send(setup_reply(Msg.SETUP_INPUTS, 0, types))
            return
        recipe = Recipe(len(self.inputs) + 1, names, types)
        self.inputs[recipe.recipe_id] = recipe
        self.note("inputs", recipe_id=recipe.recipe_id, names=names)
        self.send(setup_reply(Msg.SETUP_INPUTS, recipe.recipe_id, types))

    def _data(self, payload: bytes) -> None:
        recipe = self.inputs.get(payload[0]) if payload else None
        if recipe is None:
            self.send(text_message(f"Unknown input recipe {payload[:1].hex()}", level=1))
            return
        try:
            values = recipe.decode(payload)
        except struct.error:
            self.send(text_message(f"Bad data package for recipe {recipe.recipe_id}", level=1))
            return
        self.controller.write_inputs(values)

    def send_due(self, now: float) -> None:
        """Send the output packages that are due; a late recipe skips the missed ones."""
        if not self.started:
            return
        for i, recipe in enumerate(self.outputs):
            if now < self.next_due[i]:
                continue
            self.send(recipe.encode(self.controller.value))
            period = 1.0 / recipe.frequency
            self.next_due[i] += period
            if self.next_due[i] < now - period:
                self.next_due[i] = now + period
