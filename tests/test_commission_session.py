"""Commissioning on the real cell's path, end to end: `lrnbv hardware commission` drives the
emulated UR controller (tests/ur_emulator) through the real ur_rtde client, with frames of the
bare table from the simulated board, its sensor mounted off the CAD and its zones turned. A
protective stop on the way between two views ends the run within 5 s with every view taken
so far whole on disk; `lrnbv hardware --resume` takes the rest and fits. A cell never
commissioned is refused by `lrnbv hardware` before anything moves."""

from __future__ import annotations

import itertools
import json
import threading
import time

import numpy as np
import pytest
from ur_emulator import UrControllerEmulator, worker_host
from ur_emulator.record import starved_since
from ur_emulator.sessions import MOVING, first_pose, journal_lines, servoj_times, time_limit

from lrnbv_drake.cli.main import main
from lrnbv_drake.core.sensing.zone_order import model_flips
from lrnbv_drake.experiments.commissioning import commission_cell
from lrnbv_drake.station.scenario import load_scenario, override

pytest.importorskip("rtde_control")
pytestmark = pytest.mark.usefixtures("compiled_kernels")

_addresses = itertools.count(200)  # the fault tests count from 128 in the same worker
FRAMES = 2
MOUNT_XYZ_MM, MOUNT_RPY_DEG, ROTATE = [2.0, -2.0, 1.0], [1.5, 1.0, 3.0], 90
#: A board's temporal noise (0.7 mm, vl53l8cx-behaviour.md), so that two frames a view fit
#: the mount within the commissioning's own tolerances.
CELL = f"""
device: {{mount: {{xyz_mm: {MOUNT_XYZ_MM}, rpy_deg: {MOUNT_RPY_DEG}}},
          zone_order: {{rotate: {ROTATE}, flip: none}}, sigma0_mm: 0.7, noise_k: 0.0}}
hardware: {{sensor_driver: simulated, max_speed_fraction: 1.0, commission_frames: {FRAMES}}}
"""


def _emulator() -> UrControllerEmulator:
    return UrControllerEmulator(host=worker_host(next(_addresses)), q0=first_pose(),
                                unlock_delay=0.5, lifetime=240.0)


def _between_views(emu: UrControllerEmulator, out, act) -> threading.Thread:
    """Runs `act()` from a thread once two views are on disk and the servo target has left
    the second one (the arm on its way to the third); returns the thread, which records the
    wall time it acted in its `at` list."""
    at: list[float] = []

    def watch() -> None:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            time.sleep(0.01)
            if journal_lines(out) < 2 * FRAMES:
                continue
            last = json.loads((out / "acquisitions.jsonl").read_text().splitlines()[-1])
            if np.abs(np.array(emu.state()["target"]) - last["q"]).max() > MOVING:
                at.append(time.time())
                act()
                return

    thread = threading.Thread(target=watch, daemon=True)
    thread.at = at
    thread.start()
    return thread


def test_a_cell_never_commissioned_is_refused_before_anything_moves(tmp_path, capsys):
    file = tmp_path / "cell.yaml"
    file.write_text(CELL)
    with time_limit(60.0), _emulator() as emu:
        assert main(["hardware", "--robot-ip", emu.host, "--scenario", str(file), "--out",
                     str(tmp_path / "out"), "--planner", "heu", "--yes"]) == 2
        err = capsys.readouterr().err
        assert "nothing moved" in err and "lrnbv hardware commission" in err
        assert not servoj_times(emu.record()) and not (tmp_path / "out").exists()
        # Commissioning asks first, saying the table must be bare; declined, nothing moves.
        asked = []
        result = commission_cell(
            override(load_scenario(filename=file), {"robot": {"robot_ip": emu.host}}),
            tmp_path / "declined", confirm=lambda text: asked.append(text) or False)
        assert result.fault == "declined" and "clear the table" in asked[0]
        assert not servoj_times(emu.record())


def test_commissioning_through_ur_rtde_stops_on_a_fault_and_resumes_to_the_fit(tmp_path,
                                                                               capsys):
    file, out = tmp_path / "cell.yaml", tmp_path / "out"
    file.write_text(CELL)
    with time_limit(200.0), _emulator() as emu:
        trigger = _between_views(emu, out, lambda: emu.inject("protective_stop"))
        code = main(["hardware", "commission", "--robot-ip", emu.host, "--scenario",
                     str(file), "--out", str(out), "--yes"])
        ended = time.time()
        trigger.join(5.0)
        err = capsys.readouterr().err
        assert trigger.at, f"the arm never left the second view; the session:\n{err}"
        assert code == 1 and "STOPPED (protective_stop)" in err
        assert ended - trigger.at[0] < 5.0 + starved_since(emu.record(), trigger.at[0])
        # Stopped between views: the views taken are on disk whole, and nothing is fitted.
        stopped_at = journal_lines(out)
        assert stopped_at >= 2 * FRAMES and stopped_at % FRAMES == 0
        assert not (out / "commissioning.yaml").exists()

        emu.clear_faults()
        assert main(["hardware", "--resume", str(out), "--yes"]) == 0
        assert not emu.state()["program_running"]
        capsys.readouterr()
        assert main(["hardware", "--resume", str(out), "--yes"]) == 2  # done: says where
        assert "is finished" in (err := capsys.readouterr().err) and "commissioning.yaml" in err
    # A fit that did not get written (it failed, or the process ended) is made on resume.
    written = (out / "commissioning.yaml").read_text()
    (out / "commissioning.yaml").unlink()
    assert main(["hardware", "--resume", str(out), "--yes"]) == 0
    assert (out / "commissioning.yaml").read_text().split("commissioned")[0] == \
        written.split("commissioned")[0]
    lines = [json.loads(line) for line in (out / "acquisitions.jsonl").read_text().splitlines()]
    views = [line["info"]["view"] for line in lines]
    assert views[:stopped_at] == sorted(views[:stopped_at])  # the first run's, in order
    assert len(set(views)) >= 12 and all(views.count(v) == FRAMES for v in set(views))
    section = load_scenario(filename=out / "commissioning.yaml")
    assert (section.sensor.flip_x, section.sensor.flip_y, section.sensor.transpose) == \
        model_flips(ROTATE, "none")
    np.testing.assert_allclose(section.sensor.mount.rpy_deg, MOUNT_RPY_DEG, atol=0.2)
    np.testing.assert_allclose(section.sensor.mount.xyz_mm, MOUNT_XYZ_MM, atol=1.5)
    assert abs(section.cell.table_height) < 0.0015  # the table where the model has it
    assert section.sensor.commissioned  # the views of a real arm's sensor
    # The session's cycle time: at least every frame's period, at 15 Hz.
    assert json.loads((out / "commissioning.json").read_text())["cycle_time_s"] > \
        len(lines) / 15
