"""Showing per-step objects in Meshcat so that the exported replay shows them at the right time.

Meshcat animations cannot change geometry, only properties; so each step's geometry is its own
object, hidden at time 0 and shown from its step's time (and the previous step's hidden then,
when it is replaced rather than accumulated).
"""

from __future__ import annotations

from pydrake.geometry import Meshcat


def show_from(meshcat: Meshcat, path: str, time: float, replaces: str | None = None) -> None:
    """Keys `path` visible from `time` on (hidden before), and `replaces` hidden from then."""
    meshcat.SetProperty(path, "visible", False, time_in_recording=0.0)
    meshcat.SetProperty(path, "visible", True, time_in_recording=time)
    if replaces is not None:
        meshcat.SetProperty(replaces, "visible", False, time_in_recording=time)
