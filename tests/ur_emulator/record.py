"""What the emulated controller received and did, kept as plain data so a test can query it
across the process boundary. Times are wall-clock seconds (time.time()), comparable with the
test process's own time.time()."""

from __future__ import annotations

import time
from typing import Any

MAX_ENTRIES = 200_000  # per list: bounds memory if a client streams for the whole lifetime

LISTS = (
    "dashboard",        # {t, command, reply}
    "script_uploads",   # {t, program, size, started, reason, protocol (parsed command table)}
    "commands",         # {t, id, name, args}: every client write of a non-zero command id
    "executed",         # {t, id, name, args}: non-realtime commands the script executed
    "kicks",            # t of every client write to the watchdog register
    "watchdog",         # {t, register, min_frequency, action}: rtde_set_watchdog calls
    "watchdog_trips",   # {t, register, min_frequency, last_kick, action}
    "program",          # {t, event: started|stopped, program, reason}
    "faults",           # {t, fault, action: inject|clear}
    "rtde_sessions",    # {t, peer, event, ...}: connects, recipes, start, pause, closes
    "text_messages",    # {t, peer, message}: text packages from clients
    "links",            # {t, event: freeze|unfreeze|reset}
    "starved",          # {t, seconds}: cycles late by more than STARVED (CPU starvation)
)


def starved_since(record: dict[str, Any], t: float) -> float:
    """Seconds the emulator was starved of CPU after wall time `t`, in a record as
    `Record.as_data` gives it: it read the clients' packages that much later (a real
    controller is never starved)."""
    return sum(s["seconds"] for s in record["starved"] if s["t"] > t)


class Record:
    """Append-only lists, one per kind of event."""

    def __init__(self) -> None:
        self.lists: dict[str, list[Any]] = {name: [] for name in LISTS}
        self.dropped: dict[str, int] = dict.fromkeys(LISTS, 0)

    def add(self, kind: str, entry: Any) -> None:
        """Append an entry; `t` is added to dict entries that have none."""
        if isinstance(entry, dict) and "t" not in entry:
            entry = {"t": time.time(), **entry}
        target = self.lists[kind]
        if len(target) >= MAX_ENTRIES:
            self.dropped[kind] += 1
            return
        target.append(entry)

    def as_data(self) -> dict[str, Any]:
        """A copy as plain data (JSON-serialisable)."""
        data: dict[str, Any] = {name: list(entries) for name, entries in self.lists.items()}
        data["dropped"] = dict(self.dropped)
        return data
