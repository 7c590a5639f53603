"""`ToFSerialReceiver`: the real VL53L8CX's frames on the same `tof_frame` port as the simulated
sensor, so that the rest of the diagram cannot tell the two apart."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem, OutputPort, State

from lrnbv_drake.core.sensing.sensor import ToFFrame
from lrnbv_drake.drivers.tof_serial import ToFSerialReader, check_resolution


class ToFSerialReceiver(LeafSystem):
    """The real sensor as a Drake system, a drop-in for the simulated `ToFSensor`.

    @system
    name: ToFSerialReceiver
    output_ports:
    - tof_frame
    @endsystem

    Every `period` an unrestricted update copies the driver's newest non-stale frame into
    state; `tof_frame` outputs that state. The update only reads what the driver's thread has
    already parsed, so no output or event ever waits on the serial port. Until a frame arrives
    (and while the board is silent) the state keeps the previous frame, at first an empty one
    with sequence 0; consumers skip sequence 0 and repeated sequences, as with the simulator.
    A frame of another resolution raises SensorError from the update (`check_resolution`):
    the rest of the diagram assumes `resolution`. Run the diagram in real time
    (`Simulator.set_target_realtime_rate(1.0)`).
    """

    def __init__(
        self, driver: ToFSerialReader, period: float = 1 / 15, resolution: int = 8
    ) -> None:
        """
        Args:
            driver: a started driver (the system does not start or close it).
            period: polling period, seconds; the board's frame period or shorter.
            resolution: zones per side of every frame (the empty one output before the
                first frame too).
        """
        super().__init__()
        self._driver = driver
        self._resolution = resolution
        empty = ToFFrame.empty(resolution)
        self._frame_index = self.DeclareAbstractState(AbstractValue.Make(empty))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._Poll)
        self._frame_port = self.DeclareStateOutputPort("tof_frame", self._frame_index)

    def get_tof_frame_output_port(self) -> OutputPort:
        return self._frame_port

    def _Poll(self, context: Context, state: State) -> None:
        frame = self._driver.latest()
        if frame is not None:
            check_resolution(frame, self._resolution, self._driver.port)
            state.get_mutable_abstract_state(self._frame_index).set_value(frame)
