"""--out: the folder a command writes into, checked before anything runs.

A folder holds the results of one kind of run: an episode (`lrnbv run`), a session on the
real cell (`lrnbv hardware`) or a campaign (`lrnbv benchmark`). No command overwrites another
run's results without being told: `benchmark` resumes its own campaign, `hardware` continues
its session with --resume, and `run` replaces an earlier episode only with --overwrite.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from lrnbv_drake.experiments.session import JOURNAL_FILE, SESSION_FILE

#: What marks a folder as holding each command's results, looked for in this order (a
#: session folder also holds a report.json).
MARKERS: dict[str, tuple[str, ...]] = {
    "hardware": (SESSION_FILE, JOURNAL_FILE),
    "benchmark": ("results.csv", "episodes"),
    "run": ("report.json", "frames.npz", "replay.html", "report.html"),
}
#: How a command carries on with a folder of its own results it refuses.
_CARRY_ON = {"hardware": "continue the session with `lrnbv hardware --resume {dir}`",
             "run": "pass --overwrite to replace them"}


class OutDirError(ValueError):
    """--out names a folder the command cannot or must not write into."""


def results_in(folder: Path) -> tuple[str | None, list[str]]:
    """(the command whose results `folder` holds, the files that say so); (None, []) when it
    holds none."""
    for command, names in MARKERS.items():
        found = [n for n in names if (folder / n).exists()]
        if found:
            return command, found
    return None, []


def prepare_out_dir(text: str, command: str, overwrite: bool = False) -> Path:
    """The folder `--out text` names, created (with its parents) and checked writable.

    Refused: an empty name, a file, a folder that cannot be created or written, and a folder
    holding another run's results; except that `benchmark` takes its own campaign's folder
    (to resume it) and `run --overwrite` an earlier episode's, whose files are removed first.

    Raises:
        OutDirError: naming the folder, what is wrong and what to do.
    """
    if not text.strip():
        raise OutDirError("--out '': expected a folder name (--out . for the current folder)")
    folder = Path(text)
    if folder.exists() and not folder.is_dir():
        raise OutDirError(f"--out {folder}: that is a file; expected a folder (new, or one an "
                          f"earlier `lrnbv {command}` wrote)")
    kind, found = results_in(folder) if folder.is_dir() else (None, [])
    if kind is not None and not (kind == command == "benchmark" or
                                 (kind == command == "run" and overwrite)):
        hint = "choose another folder" + (
            f", or {_CARRY_ON[kind].format(dir=folder)}" if kind == command else "")
        raise OutDirError(f"--out {folder} holds the results of an earlier `lrnbv {kind}` "
                          f"({', '.join(found)}); nothing was written: {hint}")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutDirError(f"--out {folder}: cannot create the folder ({e.strerror})") from e
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutDirError(f"--out {folder}: the folder is not writable")
    if kind == "run":  # --overwrite: no file of the earlier episode may outlive it
        for name in found:
            (folder / name).unlink()
    return folder


def remove_if_empty(folder: Path) -> None:
    """Removes `folder` if nothing was written into it (a run that failed at the start)."""
    with contextlib.suppress(OSError):
        folder.rmdir()
