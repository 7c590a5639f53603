"""Whole `lrnbv hardware` sessions against the emulator, for the fault tests and the fuzz:
the scenario, the arm's start pose, faults injected while the arm moves, and what a session
left on disk. (The emulator itself, the rest of this package, knows nothing of lrnbv_drake.)"""

from __future__ import annotations

import contextlib
import functools
import json
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .api import UrControllerEmulator
from .record import starved_since

#: The session every test runs: HEU, two poses, the arm starting at the first one, frames
#: rendered by the simulated board, and the speed cap at its maximum (1.0, pi rad/s, above
#: ur_rtde's 3.14 limit for servoJ's own speed argument). The tests are of how the cell
#: meets faults, not of the box: the cell box keeps each step of the diagram short (the
#: shape estimate runs on the real-cell path in test_hardware_session.py).
SCENARIO = """
max_poses: 2
sensor: {commissioned: "the simulated board, on the CAD mount"}
hardware: {sensor_driver: simulated, max_speed_fraction: 1.0}
extraction: {estimator: cells}
"""
#: The commanded target this far (rad) from the start pose means the arm is on its way.
MOVING = 0.02
#: From a fault on the controller to the session's last servoJ, seconds: the status read that
#: sees it (every 8 ms) after the package that carries it (2 ms), and up to CAUSE_WAIT (0.25 s)
#: for the status to name it; `hardware.rtde_timeout` (0.5 s) leaves room for a loaded machine.
#: Below that timeout, so a session that noticed faults only by the link's silence would fail.
NOTICED = 0.5


@functools.cache
def first_pose() -> tuple[float, ...]:
    """Joints at HEU's first viewpoint of the default scenario, where the sessions start, so
    that one motion remains (to the second pose)."""
    from lrnbv_drake.core.planning.heu import heu_poses
    from lrnbv_drake.core.robot import kinematics
    from lrnbv_drake.station.cell_models import place_object
    from lrnbv_drake.station.motion import MotionPlanner
    from lrnbv_drake.station.scenario import load_scenario

    scenario = load_scenario(data=SCENARIO)
    poses = heu_poses(place_object(scenario).mesh.bounds.mean(axis=0), scenario.heu)
    return tuple(MotionPlanner(scenario).plan(kinematics.HOME.copy(), poses[0]).q_target)


def write_scenario(folder: Path) -> Path:
    """The session's scenario file, in `folder`."""
    path = folder / "cell.yaml"
    path.write_text(SCENARIO)
    return path


def cli_args(emu: UrControllerEmulator, scenario: Path, out: Path) -> list[str]:
    """`lrnbv hardware` arguments for a new session against `emu`."""
    return ["hardware", "--robot-ip", emu.host, "--scenario", str(scenario), "--out", str(out),
            "--planner", "heu", "--yes"]


def journal_lines(out: Path) -> int:
    path = out / "acquisitions.jsonl"
    return len(path.read_text().splitlines()) if path.exists() else 0


def on_disk(out: Path) -> tuple[int, int, int]:
    """(journal lines, frames in frames.npz, report.json's n_poses)."""
    frames = np.load(out / "frames.npz")["q"].shape[0]
    return journal_lines(out), frames, json.loads((out / "report.json").read_text())["n_poses"]


class WhenMoving:
    """Runs `act()` once, from a thread, as soon as the session at `out` has one acquisition on
    disk and the emulator's servo target has left `q0` (the arm is on its way to the second
    pose), after `delay` more seconds. `at` is the wall time (time.time()) it acted; `join()`
    waits for it (bounded)."""

    def __init__(self, emu: UrControllerEmulator, out: Path, q0: tuple[float, ...],
                 act: Callable[[], None], delay: float = 0.0, timeout: float = 60.0) -> None:
        self.at: float | None = None
        self._stop = threading.Event()

        def watch() -> None:
            deadline = time.monotonic() + timeout
            while not self._stop.wait(0.01) and time.monotonic() < deadline:
                if journal_lines(out) >= 1 and np.abs(
                        np.array(emu.state()["target"]) - q0).max() > MOVING:
                    if delay and self._stop.wait(delay):
                        return
                    self.at = time.time()
                    act()
                    return

        self._thread = threading.Thread(target=watch, daemon=True)
        self._thread.start()

    def join(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


def servoj_times(record: dict[str, Any]) -> list[float]:
    """When the emulator received each servoJ (wall time)."""
    return [c["t"] for c in record["commands"] if c["name"] == "servoJ"]


def noticed_by(record: dict[str, Any], fault_at: float) -> float:
    """When the session must have stopped servoing after a fault at `fault_at` (wall time):
    NOTICED later, plus the time the emulator itself was starved of CPU since."""
    return fault_at + NOTICED + starved_since(record, fault_at)


@contextlib.contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Raises TimeoutError in the main thread after `seconds` (pytest-timeout is not a
    dependency); a no-op elsewhere."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def expire(signum: int, frame: object) -> None:
        raise TimeoutError(f"ran longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)
