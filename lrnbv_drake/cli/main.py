"""`lrnbv`: run reconstruction episodes, the paper's campaign, the real sensor and the real
cell, and list the built-in objects."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from lrnbv_drake.cli.benchmark import add_benchmark_command, run_benchmark
from lrnbv_drake.cli.hardware import add_hardware_commands, run_hardware_command
from lrnbv_drake.cli.objects import add_objects_command, run_objects_command
from lrnbv_drake.cli.run import add_run_command, run_run_command
from lrnbv_drake.cli.sensor import add_sensor_commands, run_sensor_command

COMMANDS = {"run": run_run_command, "objects": run_objects_command,
            "benchmark": run_benchmark, "sensor": run_sensor_command,
            "hardware": run_hardware_command}


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lrnbv", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    add_run_command(sub)
    add_objects_command(sub)
    add_benchmark_command(sub)
    add_sensor_commands(sub)
    add_hardware_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    args = _parser().parse_args(argv)
    return COMMANDS[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
