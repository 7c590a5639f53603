"""`lrnbv objects`: the built-in objects, the paper's first, then the generated family, then
the held-out shapes."""

from __future__ import annotations

import argparse

from lrnbv_drake.core.evaluation import objects


def add_objects_command(subparsers: argparse._SubParsersAction) -> None:
    """Adds `objects` to the `lrnbv` parser's subcommands."""
    subparsers.add_parser("objects", help="list the built-in objects")


def run_objects_command(args: argparse.Namespace) -> int:
    """Prints one line per built-in object; returns the exit code."""
    for name in (*objects.PAPER_OBJECTS, *objects.FAMILY_OBJECTS, *objects.HELD_OUT_OBJECTS):
        print(f"{name:20s} {objects.describe(name)}")
    return 0
