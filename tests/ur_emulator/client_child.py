"""The child side of `RtdeClientProcess`: holds ur_rtde clients and runs the test's requests.

It reads JSON requests on stdin and answers one JSON line each on its own copy of stdout;
ur_rtde's C++ output goes to stderr so that it cannot corrupt the answers. When stdin closes it
exits without running destructors, which would disconnect and can block on a dead link.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from typing import Any

RECEIVE_GETTERS = {  # timestamp first: see timestamp_after in _read
    "timestamp": "getTimestamp", "q": "getActualQ", "qd": "getActualQd",
    "tcp_pose": "getActualTCPPose", "robot_mode": "getRobotMode", "safety_mode": "getSafetyMode",
    "runtime_state": "getRuntimeState", "speed_scaling": "getSpeedScaling",
    "target_speed_fraction": "getTargetSpeedFraction",
    "protective_stopped": "isProtectiveStopped", "emergency_stopped": "isEmergencyStopped",
    "safety_status_bits": "getSafetyStatusBits", "robot_status": "getRobotStatus",
    "connected": "isConnected",
}

Notify = Callable[[dict[str, Any]], None]


def _connect(clients: dict[str, Any], request: dict[str, Any]) -> float:
    kind, host = request["kind"], request["host"]
    started = time.monotonic()
    if kind == "receive":
        import rtde_receive

        clients[kind] = rtde_receive.RTDEReceiveInterface(
            host, request.get("frequency", -1.0), [], False, request.get("upper", False))
    elif kind == "control":
        import rtde_control

        clients[kind] = rtde_control.RTDEControlInterface(
            host, request.get("frequency", -1.0), request.get("flags", 1))
    else:
        import dashboard_client

        clients[kind] = dashboard_client.DashboardClient(host)
        clients[kind].connect()
    return time.monotonic() - started


def _read(clients: dict[str, Any]) -> dict[str, Any]:
    receive = clients["receive"]
    sample = {key: getattr(receive, getter)() for key, getter in RECEIVE_GETTERS.items()}
    # equal to timestamp when every getter read the same data package
    sample["timestamp_after"] = receive.getTimestamp()
    sample["wall_time"] = time.time()
    return sample


def _servo_stream(clients: dict[str, Any], request: dict[str, Any],
                  notify: Notify) -> dict[str, Any]:
    """servoJ along a joint-space ramp from `start` to `end` over `duration` s at `rate` Hz,
    then `hold` s on `end`: the way a driver streams a trajectory."""
    control = clients["control"]
    start, end = request["start"], request["end"]
    rate, duration, hold = request["rate"], request["duration"], request.get("hold", 0.0)
    speed, acceleration, lookahead, gain = request.get("settings", [0.5, 0.5, 0.1, 300.0])
    parent = os.getppid()
    period = 1.0 / rate
    if request.get("watchdog"):
        control.setWatchdog(request["watchdog"])
    notify({"event": "streaming", "t": time.time()})
    began = time.monotonic()
    sent = refused = 0
    target = list(start)
    while (elapsed := time.monotonic() - began) <= min(duration + hold, 60.0):
        if os.getppid() != parent:
            os._exit(1)
        alpha = min(elapsed / duration, 1.0) if duration > 0 else 1.0
        target = [a + (b - a) * alpha for a, b in zip(start, end, strict=True)]
        ok = control.servoJ(target, speed, acceleration, period, lookahead, gain)
        sent, refused = sent + 1, refused + (not ok)
        time.sleep(max(0.0, began + sent * period - time.monotonic()))
    return {"sent": sent, "refused": refused, "elapsed": time.monotonic() - began,
            "last_target": target}


def _operate(clients: dict[str, Any], request: dict[str, Any], notify: Notify) -> Any:
    op = request["op"]
    if op == "connect":
        return _connect(clients, request)
    if op == "call":
        value = getattr(clients[request["kind"]], request["method"])(*request.get("args", []))
        return value if isinstance(value, (bool, int, float, str, list, type(None))) \
            else str(value)
    if op == "read":
        return _read(clients)
    if op == "sample":
        samples, began = [], time.monotonic()
        while time.monotonic() - began < request["duration"]:
            samples.append(_read(clients))
            time.sleep(request.get("period", 0.01))
        return samples
    if op == "servo_stream":
        return _servo_stream(clients, request, notify)
    raise ValueError(f"unknown operation {op!r}")


def child_main() -> None:
    """Serve requests until stdin closes, then exit without running any destructor."""
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # ur_rtde writes to std::cout; keep it out of the answers

    def notify(message: dict[str, Any]) -> None:
        answers.write(json.dumps(message) + "\n")

    clients: dict[str, Any] = {}
    for line in sys.stdin:
        request = json.loads(line)
        try:
            notify({"ok": True, "result": _operate(clients, request, notify)})
        except Exception as error:  # reported to the test
            notify({"ok": False, "error": f"{type(error).__name__}: {error}"})
    os._exit(0)  # the destructors would disconnect, which can block on a dead link




if __name__ == "__main__":
    child_main()
