"""`lrnbv objects`: the built-in objects, the paper's first."""

from __future__ import annotations

import argparse

from lrnbv_drake.core import objects


def add_objects_command(subparsers: argparse._SubParsersAction) -> None:
    """Adds `objects` to the `lrnbv` parser's subcommands."""
    subparsers.add_parser("objects", help="list the built-in objects")


def run_objects_command(args: argparse.Namespace) -> int:
    """Prints one line per built-in object; returns the exit code."""
    for name in objects.PAPER_OBJECTS:
        print(f"{name:16s} {objects.BUILTIN_OBJECTS[name].description}")
    for name, entry in objects.BUILTIN_OBJECTS.items():
        if name not in objects.PAPER_OBJECTS:
            print(f"{name:16s} {entry.description}")
    return 0
