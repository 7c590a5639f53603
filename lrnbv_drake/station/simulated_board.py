"""A stand-in for the VL53L8CX board: frames of the simulated cell, sent over a serial port.

The dry run (and the end-to-end tests) put it behind the real serial driver: a thread renders
a frame of the scenario's cell at the robot's current joints every frame period, encodes it as
a `$TOF` line (tof_protocol.py) and writes it into the driver's own port. With a pyserial
`loop://` port the driver reads back exactly those bytes, so everything from the serial parser
onwards is the code that runs on the real cell.
"""

from __future__ import annotations

import dataclasses as dc
import logging
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np
from pydrake.systems.framework import Context, Diagram

from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.core.sensing.tof_protocol import encode_frame
from lrnbv_drake.drivers.tof_serial import SensorError, ToFSerialReader
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.station.sim_cell import make_sim_cell
from lrnbv_drake.systems.tof_sensor import ToFSensor

_log = logging.getLogger(__name__)


class SimulatedToFBoard:
    """Renders the scenario's cell (without its object with `bare_table`) at `joints()` every
    `sensor.period` and writes the frames into `driver`'s port (a started driver on
    `loop://`).

    Frames count from sequence 1 and carry the board's clock (microseconds since `start()`),
    like the firmware's `micros()`. The noise is seeded by the scenario seed and the sequence,
    as in simulation. Frames are skipped while the driver's port is closed.
    """

    def __init__(self, scenario: Scenario, joints: Callable[[], Sequence[float]],
                 driver: ToFSerialReader, bare_table: bool = False) -> None:
        self._scenario = scenario
        self._bare_table = bare_table
        self._joints = joints
        self._driver = driver
        self._period = scenario.sensor.period
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None

    def start(self, timeout: float = 60.0) -> SimulatedToFBoard:
        """Starts streaming from a daemon thread, once the thread has built its cell.

        The cell is built in the thread that renders with it: an EGL context belongs to the
        thread that made it current.
        """
        self._thread = threading.Thread(target=self._run, name="simulated ToF board",
                                        daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            self.close()
            raise TimeoutError(f"the simulated sensor board was not ready in {timeout:.0f} s")
        if self._error is not None:
            raise self._error
        return self

    def close(self) -> None:
        """Stops streaming."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self._period + 2.0)

    def _run(self) -> None:
        try:
            cell = make_sim_cell(self._scenario, bare_table=self._bare_table).diagram
            context = cell.CreateDefaultContext()
            tof = cell.GetSubsystemByName("tof")
            # One frame rendered and thrown away: its one-time costs (the device kernels'
            # compile, seconds on a loaded machine) belong to start(), not to the session's
            # wait for the first frame. A real board streams as soon as it is started.
            self._render(cell, context, tof, sequence=0, previous=None)
        except BaseException as e:  # handed to start(), which raises it
            self._error = e
            self._ready.set()
            return
        self._ready.set()
        started = time.monotonic()
        deadline = started
        sequence, frame = 0, None
        while not self._stop.wait(max(0.0, deadline - time.monotonic())):
            deadline += self._period
            if not self._driver.connected:
                continue
            sequence += 1
            try:
                # The context never advances: the board hands each frame the one before it,
                # or every frame would be the first after ranging starts (status 6).
                frame = self._render(cell, context, tof, sequence, previous=frame)
                stamp = round((time.monotonic() - started) * 1e6)
                self._driver.write(encode_frame(dc.replace(frame, timestamp_us=stamp)))
            except SensorError as e:
                _log.warning("simulated board: %s", e)
            except Exception:
                _log.exception("simulated board: rendering a frame failed; the board stops")
                return

    def _render(self, cell: Diagram, context: Context, tof: ToFSensor, sequence: int,
                previous: ToFFrame | None) -> ToFFrame:
        """The frame `sequence` at the robot's current joints."""
        cell.GetInputPort("ur5e.position").FixValue(context, np.asarray(self._joints(), float))
        return tof.CaptureFrame(tof.GetMyContextFromRoot(context), sequence=sequence,
                                previous=previous)
