"""A UR e-Series controller emulator that the real ur_rtde client (1.6.5) talks to, for tests.

It answers the dashboard server (29999), RTDE protocol 2 (30004) and the script port (30003)
on a loopback address, runs the register protocol of the control script the client uploads
(command ids read from the script itself), and moves an emulated UR5e. A test drives faults
and reads what the emulator received through `UrControllerEmulator`; `RtdeClientProcess`
holds ur_rtde clients in a child process the test can kill.

    with UrControllerEmulator(host=worker_host(0), q0=HOME) as emu:
        with RtdeClientProcess(emu.host) as client:
            client.connect("control")
            client.call("control", "servoJ", q, 0.5, 0.5, 0.008, 0.1, 300)
        emu.record()["commands"]
"""

from .api import EmulatorError, UrControllerEmulator, worker_host
from .arm import HOME, ArmModel, forward_kinematics, tcp_pose
from .client_runner import ClientError, RtdeClientProcess

__all__ = ["HOME", "ArmModel", "ClientError", "EmulatorError", "RtdeClientProcess",
           "UrControllerEmulator", "forward_kinematics", "tcp_pose", "worker_host"]
