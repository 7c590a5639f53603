"""The numba kernels a process would otherwise wait seconds for the first time, compiled into
the on-disk cache (`lrnbv_drake/numba_cache.py`) at once: the shape estimate's (the report,
also the one after a fault on the real cell), the kinematics' and look_at's (the first
planning iteration). `make` runs `python -m lrnbv_drake.core.kernels` after installing.
"""

from __future__ import annotations

from lrnbv_drake.core import height_map_fit, kinematics, poses


def compile_kernels() -> None:
    """Runs each module's `compile_kernels`."""
    for module in (height_map_fit, kinematics, poses):
        module.compile_kernels()


if __name__ == "__main__":
    compile_kernels()
