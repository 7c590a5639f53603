"""The numba kernels a process would otherwise wait seconds for the first time, compiled into
the on-disk cache (`lrnbv_drake/numba_cache.py`) at once: the box estimator's (every pose,
and the report after a fault on the real cell), the map's (the first acquisition), the gains',
the kinematics', look_at's and the arm's balls' (the first planning iteration). `make` runs
`python -m lrnbv_drake.core.kernels` after installing, and a simulated episode (before its
clock starts) and a hardware session (before it connects) call `compile_kernels`: the cache
is keyed by the source, so any edit leaves it cold.
"""

from __future__ import annotations

import functools

from lrnbv_drake.core.estimation import track
from lrnbv_drake.core.mapping import occupancy_map
from lrnbv_drake.core.planning import utility
from lrnbv_drake.core.robot import kinematics, poses, sure_collision


@functools.cache
def compile_kernels() -> None:
    """Runs each module's `compile_kernels`, once a process: the kernels stay compiled."""
    for module in (track, occupancy_map, utility, kinematics, poses, sure_collision):
        module.compile_kernels()


if __name__ == "__main__":
    compile_kernels()
