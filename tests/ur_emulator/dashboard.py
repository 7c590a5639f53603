"""The dashboard server's line protocol (port 29999): a welcome line, then one reply line per
command line. Replies follow UR's dashboard server documentation for PolyScope 5; ur_rtde
checks some of them verbatim ("Stopped", "Starting program", "Protective stop releasing")."""

from __future__ import annotations

from .controller import PLAYING, ROBOT_MODE_NAMES, RUNTIME_NAMES, SAFETY_MODE_NAMES, Controller

WELCOME = "Connected: Universal Robots Dashboard Server"
# Commands that move or start the arm, refused in local mode on e-Series.
REMOTE_ONLY = ("play", "stop", "pause", "power on", "power off", "brake release", "load",
               "unlock protective stop", "restart safety", "shutdown")
LOCAL_MODE_REPLY = "Command is not allowed due to safety reasons. Enable remote control."


def polyscope_version(controller: Controller) -> str:
    """The version string, as the RTDE controller version reports it."""
    return ".".join(str(part) for part in controller.version)


def reply(line: str, controller: Controller) -> tuple[str, bool]:
    """(reply line, whether the server closes the connection after it) for one command."""
    command = line.strip()
    lower = command.lower()
    c = controller
    if any(lower == verb or lower.startswith(verb + " ") for verb in REMOTE_ONLY) \
            and not c.remote_control:
        return LOCAL_MODE_REPLY, False
    if lower == "quit":
        return "Disconnected", True
    simple = _query(lower, c)
    if simple is not None:
        return simple, False
    if lower == "stop":
        c.stop_program("dashboard stop")
        return "Stopped", False
    if lower == "play":
        if c.loaded_program is None:
            return "Failed to execute: play", False
        return "Starting program", False  # the loaded .urp itself is not emulated
    if lower == "pause":
        return ("Pausing program", False) if c.runtime_state == PLAYING else \
            ("Failed to execute: pause", False)
    if lower == "power on":
        c.power(True)
        return "Powering on", False
    if lower == "power off":
        c.power(False)
        return "Powering off", False
    if lower == "brake release":
        c.brake_release()
        return "Brake releasing", False
    if lower == "unlock protective stop":
        if c.unlock_protective_stop():
            return "Protective stop releasing", False
        return ("Cannot unlock protective stop until 5s after occurrence. Always inspect cause "
                "of protective stop before unlocking"), False
    if lower.startswith("load "):
        c.loaded_program = command[5:].strip()
        return f"Loading program: {c.loaded_program}", False
    return _message_reply(lower, command), False


def _query(lower: str, c: Controller) -> str | None:
    """Replies of the commands that only read state."""
    if lower in ("polyscopeversion", "version"):
        return f"URSoftware {polyscope_version(c)} (Jun 05 2023)"
    if lower == "get serial number":
        return c.serial
    if lower == "get robot model":
        return "UR5"
    if lower == "is in remote control":
        return "true" if c.remote_control else "false"
    if lower == "robotmode":
        return f"Robotmode: {ROBOT_MODE_NAMES[c.robot_mode]}"
    if lower in ("safetymode", "safetystatus"):
        label = "Safetymode" if lower == "safetymode" else "Safetystatus"
        return f"{label}: {SAFETY_MODE_NAMES.get(c.safety_mode, 'UNDEFINED_SAFETY_MODE')}"
    if lower == "programstate":
        runtime = RUNTIME_NAMES[c.runtime_state]
        return f"{runtime} {c.loaded_program or c.program_name}"
    if lower == "running":
        return f"Program running: {'true' if c.runtime_state == PLAYING else 'false'}"
    if lower == "get loaded program":
        return f"Loaded program: {c.loaded_program}" if c.loaded_program else "No program loaded"
    if lower == "isprogramsaved":
        return f"true {c.loaded_program or '<unnamed>'}"
    if lower == "get operational mode":
        return "NONE"
    return None


def _message_reply(lower: str, command: str) -> str:
    """Replies of the commands that change nothing the emulator models."""
    fixed = {
        "close popup": "closing popup", "close safety popup": "closing safety popup",
        "restart safety": "Restarting safety", "shutdown": "Shutting down",
        "clear operational mode": "No longer controlling the operational mode. Current "
                                  "operational mode: 'AUTOMATIC'.",
    }
    if lower in fixed:
        return fixed[lower]
    if lower.startswith("popup "):
        return "showing popup"
    if lower.startswith("addtolog "):
        return "Added log message"
    if lower.startswith("setuserrole "):
        return f"Setting user role: {command.split(' ', 1)[1]}"
    if lower.startswith("set operational mode "):
        return f"Operational mode '{command.rsplit(' ', 1)[1]}' is set"
    return f"could not understand: '{command}'"
