"""`lrnbv hardware commission`: measure the sensor's mount, its zone order and the table from
the arm's own views of the bare table (docs/hardware.md, Commissioning).

    lrnbv hardware commission --robot-ip IP --sensor-port PORT --out DIR [--scenario FILE]
                              [--yes] [--meshcat]
    lrnbv hardware commission --dry-run --out DIR [--scenario FILE]
    lrnbv hardware --resume DIR        (after a stop: takes the views left, then fits)

The arm takes the planned views as a session of `lrnbv hardware` (the same confirmation,
safety checks, journal and faults): every frame is in DIR/acquisitions.jsonl before the next
motion. The fit writes DIR/commissioning.yaml, the section `run`, `hardware` and `refit`
take with --scenario, and DIR/commissioning.json, each value with its standard error. The dry
run plays the views back on the simulated cell, its device as the scenario's `device:` sets
it, in real time.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from lrnbv_drake.cli.out_dir import OutDirError, prepare_out_dir, remove_if_empty
from lrnbv_drake.cli.scenario_args import (
    add_cell_address_arguments,
    add_scenario_arguments,
    load_cell_scenario,
    missing_cell_address,
)
from lrnbv_drake.core.calibration.commissioning import PARAMETERS, CommissioningError
from lrnbv_drake.core.robot.safety import RobotConnectionError, RobotFault
from lrnbv_drake.drivers.tof_serial import SensorError, check_port_exists
from lrnbv_drake.experiments.commissioning import commission_cell, fit_session
from lrnbv_drake.experiments.episode import make_meshcat
from lrnbv_drake.experiments.recording import RecordingError
from lrnbv_drake.experiments.session import SessionError, SessionResult
from lrnbv_drake.station.scenario import ScenarioError
from lrnbv_drake.station.scenario_checks import check_ranges

EXIT_DONE, EXIT_FAULT, EXIT_ERROR = 0, 1, 2


def add_commission_command(subparsers: argparse._SubParsersAction) -> None:
    """Adds `commission` under `lrnbv hardware`."""
    p = subparsers.add_parser("commission", help="measure the sensor's mount, zone order and "
                                                 "the table from views of the bare table",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_cell_address_arguments(p)
    p.add_argument("--out", required=True, help="output folder (new, or empty)")
    p.add_argument("--dry-run", action="store_true",
                   help="commission the simulated cell (its `device:` off the model); nothing "
                        "moves")
    p.add_argument("--yes", action="store_true", help="do not ask before moving the robot")
    p.add_argument("--meshcat", action="store_true",
                   help="serve the live Meshcat view on every interface")
    add_scenario_arguments(p)


def run_commission_command(args: argparse.Namespace, confirm: Callable[[str], bool]) -> int:
    """Runs `lrnbv hardware commission`; returns the exit code. `confirm` asks the operator
    before the arm moves, as for `lrnbv hardware`."""
    problem = missing_cell_address(args)
    if problem is not None:
        print(f"lrnbv hardware commission: error: {problem}", file=sys.stderr)
        return EXIT_ERROR
    new_dir = None
    try:
        scenario = load_cell_scenario(args)
        check_ranges(scenario)
        if not args.dry_run and scenario.hardware.sensor_driver == "serial":
            check_port_exists(scenario.sensor.serial_port)  # before reaching the robot
        new_dir = None if Path(args.out).exists() else Path(args.out)
        out = prepare_out_dir(args.out, "hardware")
        meshcat = make_meshcat(live=args.meshcat)
        if meshcat is not None:
            print(f"Meshcat: {meshcat.web_url()}")
        result = commission_cell(scenario, out, confirm=confirm, meshcat=meshcat,
                                 dry_run=args.dry_run)
    except (ScenarioError, OutDirError, SensorError, SessionError, RobotConnectionError,
            RobotFault, OSError) as e:
        print(f"lrnbv hardware commission: nothing moved: {e}", file=sys.stderr)
        return EXIT_ERROR
    finally:
        if new_dir is not None:  # a start that failed or was declined leaves no empty folder
            remove_if_empty(new_dir)
    return finish_commissioning(result)


def finish_commissioning(result: SessionResult) -> int:
    """After a commissioning session (new or resumed): why it stopped, or its fit, printed;
    the exit code."""
    if result.fault == "declined":
        print(result.termination)
        return EXIT_ERROR
    if result.fault is not None:
        print(f"{result.n_poses} frames; STOPPED ({result.fault}): {result.termination}",
              file=sys.stderr)
        return EXIT_FAULT
    return report_fit(result.out_dir)


def report_fit(out_dir: Path) -> int:
    """Fits the commissioning session in `out_dir` and prints its values; the exit code."""
    try:
        done = fit_session(out_dir)
    except (CommissioningError, RecordingError, OSError) as e:
        print(f"lrnbv hardware commission: the views are in {out_dir}, but the fit failed: {e}"
              f". `lrnbv hardware --resume {out_dir}` fits them again", file=sys.stderr)
        return EXIT_ERROR
    fit = done.fit
    print(f"{done.views} views of the bare table ({len(done.skipped)} unreachable), "
          f"{fit.readings} readings, rms {fit.rms:.2f} model sigmas; cycle time "
          f"{done.cycle_time_s:.1f} s")
    for name, value, sigma in zip(PARAMETERS, fit.values, fit.sigma, strict=True):
        print(f"  {name:26s} {value:9.3f} +- {sigma:.3f}")
    print(f"  zone order: turned {fit.zone_order[0]} deg, flip '{fit.zone_order[1]}'")
    for note in done.notes:
        print(f"note: {note}")
    print(f"wrote {out_dir / 'commissioning.yaml'} (pass it with --scenario) and "
          f"{out_dir / 'commissioning.json'}")
    return EXIT_DONE
