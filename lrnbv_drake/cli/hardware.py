"""`lrnbv hardware`: run an episode on the real cell, rehearse it, or resume it.

    lrnbv hardware --robot-ip IP --sensor-port PORT --out DIR [--scenario FILE]
                   [--planner lrnbv] [--dry-run] [--yes] [--meshcat]
    lrnbv hardware --resume DIR [--robot-ip IP] [--sensor-port PORT] [--yes] [--meshcat]
    lrnbv hardware commission [--dry-run] --out DIR ...  (cli/commission.py)

Before the first motion it describes what is about to happen and asks for `yes` on stdin
(`--yes` skips the question; a dry run never asks). Everything captured is in DIR as it
happens; after a stop, fix the cause and `--resume DIR`. docs/hardware.md has the details.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lrnbv_drake.cli.commission import (
    add_commission_command,
    finish_commissioning,
    report_fit,
    run_commission_command,
)
from lrnbv_drake.cli.out_dir import OutDirError, prepare_out_dir, remove_if_empty
from lrnbv_drake.cli.scenario_args import (
    add_cell_address_arguments,
    add_scenario_arguments,
    load_cell_scenario,
    missing_cell_address,
)
from lrnbv_drake.core.robot.safety import RobotConnectionError, RobotFault
from lrnbv_drake.drivers.tof_serial import SensorError, check_port_exists
from lrnbv_drake.experiments.commissioning import unfitted
from lrnbv_drake.experiments.episode import PLANNERS, make_meshcat
from lrnbv_drake.experiments.session import SessionError, SessionResult, resume, run_session
from lrnbv_drake.station.parts import COMMISSION
from lrnbv_drake.station.scenario import ScenarioError
from lrnbv_drake.station.scenario_checks import check_placement

#: Exit codes: the planner ended the episode; a fault stopped it; it could not start.
EXIT_DONE, EXIT_FAULT, EXIT_ERROR = 0, 1, 2


def ask_on_stdin(message: str) -> bool:
    """Prints `message` and returns whether the operator typed yes."""
    print(message)
    try:
        return input("Move the robot? Type 'yes' to go on: ").strip().lower() == "yes"
    except EOFError:
        return False


def add_hardware_commands(subparsers: argparse._SubParsersAction) -> None:
    """Adds `hardware` to the `lrnbv` parser's subcommands."""
    p = subparsers.add_parser("hardware", help="run, rehearse or resume an episode on the "
                                               "real UR5e and sensor",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_cell_address_arguments(p)
    p.add_argument("--out", help="output folder of a new session (new, or empty)")
    add_scenario_arguments(p)
    p.add_argument("--planner", choices=PLANNERS, default="lrnbv",
                   help="viewpoint planner, as for `lrnbv run` (default: lrnbv)")
    p.add_argument("--dry-run", action="store_true",
                   help="rehearse: play the commands back in Meshcat with simulated frames; "
                        "nothing moves (the robot, if --robot-ip is given, is only read)")
    p.add_argument("--yes", action="store_true", help="do not ask before moving the robot")
    p.add_argument("--meshcat", action="store_true",
                   help="serve the live Meshcat view on every interface (by default on "
                        "localhost; a replay.html is written either way)")
    p.add_argument("--resume", metavar="DIR", help="continue the session recorded in DIR")
    add_commission_command(p.add_subparsers(dest="hardware_command", required=False,
                                            metavar="{commission}"))


def _check_args(args: argparse.Namespace) -> str | None:
    """What is wrong with the combination of flags, if anything."""
    if args.resume is not None:
        extra = [flag for flag, given in (("--out", args.out is not None),
                                          ("--scenario", args.scenario is not None),
                                          ("--scenario-text", args.scenario_text is not None),
                                          ("--preset", args.preset is not None),
                                          ("--dry-run", args.dry_run)) if given]
        if extra:
            return (f"--resume takes the scenario (but for --robot-ip, --sensor-port and "
                    f"--containers), planner and dry-run choice from the session; drop "
                    f"{', '.join(extra)}")
        return None
    if args.out is None:
        return "--out DIR is required (or --resume DIR)"
    return missing_cell_address(args)


def run_hardware_command(args: argparse.Namespace) -> int:
    """Runs a command parsed by `add_hardware_commands`; returns the exit code."""
    confirm = (lambda message: True) if args.yes else ask_on_stdin
    if args.hardware_command == "commission":
        return run_commission_command(args, confirm)
    problem = _check_args(args)
    if problem is not None:
        print(f"lrnbv hardware: error: {problem}", file=sys.stderr)
        return EXIT_ERROR
    if args.resume is not None and unfitted(args.resume):  # every view taken, none fitted
        return report_fit(Path(args.resume))
    new_dir = None
    try:
        if args.resume is None:
            scenario = load_cell_scenario(args)
            check_placement(scenario)
            if not args.dry_run and scenario.hardware.sensor_driver == "serial":
                check_port_exists(scenario.sensor.serial_port)  # before reaching the robot
            new_dir = None if Path(args.out).exists() else Path(args.out)
            out_dir = prepare_out_dir(args.out, "hardware")
    except (ScenarioError, OutDirError, SensorError) as e:
        print(f"lrnbv hardware: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    meshcat = make_meshcat(live=args.meshcat)
    if meshcat is not None:
        print(f"Meshcat: {meshcat.web_url()}")
    try:
        if args.resume is not None:
            result = resume(args.resume, confirm=confirm, meshcat=meshcat,
                            robot_ip=args.robot_ip, sensor_port=args.sensor_port,
                            containers=args.containers)
        else:
            result = run_session(scenario, args.planner, out_dir, confirm=confirm,
                                 meshcat=meshcat, dry_run=args.dry_run)
    except (SessionError, ScenarioError, RobotConnectionError, RobotFault, SensorError,
            OSError) as e:
        print(f"lrnbv hardware: nothing moved: {e}", file=sys.stderr)
        return EXIT_ERROR
    finally:
        if new_dir is not None:  # a start that failed or was declined leaves no empty folder
            remove_if_empty(new_dir)
    if result.planner == COMMISSION:  # a commissioning session carried on
        return finish_commissioning(result)
    return _summarize(result)


def _summarize(result: SessionResult) -> int:
    resumed = f" ({result.resumed_from} from earlier runs)" if result.resumed_from else ""
    print(f"{result.n_poses} poses{resumed}; wrote {result.out_dir}")
    if result.fault == "declined":
        print(result.termination)
        return EXIT_ERROR
    if result.fault is not None:
        print(f"STOPPED ({result.fault}): {result.termination}", file=sys.stderr)
        return EXIT_FAULT
    print(f"ended: {result.termination}")
    _print_box(result.out_dir / "report.json")
    return EXIT_DONE


def _print_box(report_path: Path) -> None:
    """The box and its container from the session's report: the product of the run."""
    report = json.loads(report_path.read_text())
    box = report.get("estimated_box")
    if box is None:
        print(f"no object found: {report['extraction']}")
        return
    dims = " x ".join(f"{v:.3f}" for v in box["dims"])
    print(f"box L x W x H: {dims} m ({box['estimator']} estimate)")
    if report.get("container") is not None:
        print(f"container: {report['container']['reason']}")

