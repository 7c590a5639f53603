"""`SessionMonitor`: what a session on the real cell does after every Simulator step, writing
the journal and the map as they grow and keeping the realtime pacing honest
(experiments/session.py runs it)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Context, EventStatus

from lrnbv_drake.experiments.episode import EpisodeDiagram, episode_log
from lrnbv_drake.experiments.recording import AcquisitionJournal, write_atomically

JOURNAL_FILE = "acquisitions.jsonl"
MAP_FILE = "map.ot"
#: When the diagram falls this far behind the wall clock (a long planning step), the
#: realtime pacing restarts from now instead of racing to catch up: catching up would play
#: the trajectory faster than planned.
MAX_REALTIME_LAG = 0.02


class SessionMonitor:
    """The Simulator's monitor for a hardware run: after every step it appends the planner's
    new acquisitions to the journal and snapshots the map after each insertion, and it
    restarts the realtime pacing when the diagram lags the wall clock."""

    def __init__(self, simulator: Simulator, parts: EpisodeDiagram, out_dir: Path,
                 recorded: int) -> None:
        self._simulator = simulator
        self._parts = parts
        self._map = parts.map_system.occupancy_map
        self._journal = AcquisitionJournal(out_dir / JOURNAL_FILE)
        self._map_path = out_dir / MAP_FILE
        self.written = recorded  # acquisitions in the journal
        self._map_scans = self._map.n_scans
        self._pace: tuple[float, float] | None = None
        self.realtime_resets = 0

    def __call__(self, root_context: Context) -> EventStatus:
        self.record(root_context)
        self._keep_pace(root_context)
        return EventStatus.Succeeded()

    def record(self, root_context: Context) -> None:
        """Writes what has not been written yet."""
        for acquisition in episode_log(self._parts, root_context).acquisitions[self.written:]:
            self._journal.append(acquisition)
            self.written += 1
        if self._map.n_scans != self._map_scans:
            with tempfile.TemporaryDirectory() as folder:
                scratch = Path(folder) / MAP_FILE
                self._map.export_octomap(scratch)
                write_atomically(self._map_path, scratch.read_bytes())
            self._map_scans = self._map.n_scans

    def _keep_pace(self, root_context: Context) -> None:
        now, t = time.monotonic(), root_context.get_time()
        if self._pace is not None:
            wall0, t0 = self._pace
            if (now - wall0) - (t - t0) <= MAX_REALTIME_LAG:
                return
            self._simulator.ResetStatistics()
            self.realtime_resets += 1
        self._pace = (now, t)
