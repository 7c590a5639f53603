"""`lrnbv`: estimate the box of an unknown object with a UR5e and an 8x8 time-of-flight sensor,
in the simulated cell or the real one (LR-NBV, Preziosa et al.)."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

from lrnbv_drake.cli.benchmark import add_benchmark_command, run_benchmark
from lrnbv_drake.cli.compare import add_compare_command, run_compare_command
from lrnbv_drake.cli.hardware import add_hardware_commands, run_hardware_command
from lrnbv_drake.cli.objects import add_objects_command, run_objects_command
from lrnbv_drake.cli.refit import add_refit_command, run_refit_command
from lrnbv_drake.cli.results import add_results_command, run_results
from lrnbv_drake.cli.run import EXIT_INTERRUPTED, add_run_command, run_run_command
from lrnbv_drake.cli.sensor import add_sensor_commands, run_sensor_command

COMMANDS = {"run": run_run_command, "objects": run_objects_command,
            "benchmark": run_benchmark, "sensor": run_sensor_command,
            "hardware": run_hardware_command, "refit": run_refit_command,
            "results": run_results, "compare": run_compare_command}

EPILOG = """\
start with:
  lrnbv objects                                  the built-in objects
  lrnbv run --out out/run                        one simulated episode (see run --help)
  lrnbv benchmark --trials 5 --out out/paper     the paper's campaign, resumable
  lrnbv sensor stream --port /dev/ttyACM0        the real sensor, live
  lrnbv hardware --dry-run --out out/cell        rehearse the real cell; nothing moves
  lrnbv refit out/cell --scenario sensor.yaml    a recorded episode's box, recalibrated
  lrnbv results family                           regenerate docs/results.md's family tables
  lrnbv compare BEFORE AFTER                     two campaigns, episode by episode

`lrnbv COMMAND --help` describes each command. Exit status: 0 done, 1 the run ended without
its result (no object found, failed episodes, a fault), 2 bad input, 130 interrupted (Ctrl-C).
README.md and docs/ have the rest."""


def _version() -> str:
    try:
        return version("lrnbv-drake")
    except PackageNotFoundError:  # imported from a source tree that was never installed
        return "unknown (not installed)"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lrnbv", description=__doc__, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_run_command(sub)
    add_objects_command(sub)
    add_benchmark_command(sub)
    add_sensor_commands(sub)
    add_hardware_commands(sub)
    add_refit_command(sub)
    add_results_command(sub)
    add_compare_command(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Parses `argv` (default: the command line), runs the command and returns its exit code;
    Ctrl-C anywhere a command does not handle it returns 130 without a traceback. Run as the
    program (no `argv`), an interrupted command leaves Ctrl-C ignored for the exit."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    # Drake's INFO lines ("Meshcat listening ...", "Allocating contexts ...") are about its
    # internals: the commands print what a user needs (the Meshcat URL with --meshcat).
    logging.getLogger("drake").setLevel(logging.WARNING)
    words = list(sys.argv[1:] if argv is None else argv)
    args = _parser().parse_args(words)
    args.command_line = ["lrnbv", *words]  # to tell how to resume
    try:
        code = COMMANDS[args.command](args)
    except KeyboardInterrupt:
        print(f"\nlrnbv {args.command}: interrupted (Ctrl-C)", file=sys.stderr)
        code = EXIT_INTERRUPTED
    if code == EXIT_INTERRUPTED and argv is None \
            and threading.current_thread() is threading.main_thread():
        # Run as the program, everything saved and only exiting left: a second Ctrl-C landing
        # while the interpreter shuts down would turn 130 into a death by SIGINT or a stray
        # traceback. (A caller that passes `argv` keeps its own handler.) The exit stays
        # bounded: every thread still running then is a daemon, or one of the height map's two
        # descents, which end within seconds.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(main())
