"""`make_cell(scenario, meshcat=None, hardware=False)`: the one builder of the packing cell.

Its exported ports are the same in simulation and on hardware, so whatever drives the cell
does not know which one it has:

- input  `ur5e.position`           commanded joint positions (6,), radians;
- output `ur5e.position_measured`  measured joint positions (6,);
- output `tof.frame`               the latest `ToFFrame`;
- output `tof.pose`                the sensor pose in world (`RigidTransform`), from the measured
                                   joints;
- output `query_object`            SceneGraph's query object (simulation only).

The simulated cell is `station.sim_cell`, the real one `station.hardware_cell`; both return a
`Cell` that carries the plant, the models and (on hardware) the drivers beside the diagram.
"""

from __future__ import annotations

from pydrake.geometry import Meshcat

from lrnbv_drake.station.cell_models import Cell
from lrnbv_drake.station.hardware_cell import make_hardware_cell
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.station.sim_cell import make_sim_cell

__all__ = ["Cell", "make_cell"]


def make_cell(scenario: Scenario, meshcat: Meshcat | None = None,
              hardware: bool = False, bare_table: bool = False) -> Cell:
    """Builds the cell.

    Args:
        scenario: the cell, object and sensor (and on hardware, `scenario.hardware`).
        meshcat: when given, the scene is drawn there.
        hardware: the real cell (UR5e over RTDE, sensor over serial, or the dry run's
            stand-ins) instead of the simulated one; close `cell.hardware` when done.
        bare_table: the cell without its object (commissioning): the simulated table, the
            dry run's simulated board and the drawn scene.
    """
    if hardware:
        return make_hardware_cell(scenario, meshcat, bare_table=bare_table)
    return make_sim_cell(scenario, meshcat, bare_table=bare_table)
