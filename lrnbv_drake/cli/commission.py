"""`lrnbv hardware commission`: measure the sensor's mount, its zone order and the table from
the arm's own views of the bare table (docs/hardware.md, Commissioning).

    lrnbv hardware commission --dry-run --out DIR [--scenario FILE] [--frames N]

Each view is on disk (DIR/views/NN.npz) before the next motion; the fit writes
DIR/commissioning.yaml, the section `run`, `hardware` and `refit` take with --scenario, and
DIR/commissioning.json, each value with its standard error. Only the simulated cell runs so
far (--dry-run, the device as the scenario's `device:` sets it); on the real arm the command
refuses.
"""

from __future__ import annotations

import argparse
import sys

from lrnbv_drake.cli.out_dir import OutDirError, prepare_out_dir
from lrnbv_drake.cli.scenario_args import add_scenario_arguments, load_with_overrides
from lrnbv_drake.core.calibration.commissioning import PARAMETERS, CommissioningError
from lrnbv_drake.experiments.commissioning import FRAMES_PER_VIEW, commission_simulated
from lrnbv_drake.station.scenario import ScenarioError
from lrnbv_drake.station.scenario_checks import check_ranges

EXIT_DONE, EXIT_ERROR = 0, 2


def add_commission_command(subparsers: argparse._SubParsersAction) -> None:
    """Adds `commission` under `lrnbv hardware`."""
    p = subparsers.add_parser("commission", help="measure the sensor's mount, zone order and "
                                                 "the table from views of the bare table",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output folder (new, or empty)")
    p.add_argument("--dry-run", action="store_true",
                   help="commission the simulated cell (its `device:` off the model)")
    p.add_argument("--frames", type=int, default=FRAMES_PER_VIEW,
                   help=f"frames averaged at each view (default {FRAMES_PER_VIEW})")
    add_scenario_arguments(p)


def run_commission_command(args: argparse.Namespace) -> int:
    """Runs `lrnbv hardware commission`; returns the exit code."""
    if not args.dry_run:
        print("lrnbv hardware commission: error: only --dry-run (the simulated cell) runs so "
              "far; commissioning the real arm is not built yet, and nothing moved",
              file=sys.stderr)
        return EXIT_ERROR
    if args.frames < 1:
        print(f"lrnbv hardware commission: error: --frames must be >= 1; got {args.frames}",
              file=sys.stderr)
        return EXIT_ERROR
    try:
        scenario = load_with_overrides(args, {})
        check_ranges(scenario)
        out = prepare_out_dir(args.out, "hardware commission")
        result = commission_simulated(scenario, out, args.frames)
    except (ScenarioError, OutDirError, CommissioningError) as e:
        print(f"lrnbv hardware commission: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    fit = result.fit
    print(f"{result.views} views of the bare table ({len(result.skipped)} unreachable), "
          f"{fit.readings} readings, rms {fit.rms:.2f} model sigmas; cycle time "
          f"{result.cycle_time_s:.1f} s")
    for name, value, sigma in zip(PARAMETERS, fit.values, fit.sigma, strict=True):
        print(f"  {name:26s} {value:9.3f} +- {sigma:.3f}")
    print(f"  zone order: turned {fit.zone_order[0]} deg, flip '{fit.zone_order[1]}'")
    for note in result.notes:
        print(f"note: {note}")
    print(f"wrote {out / 'commissioning.yaml'} (pass it with --scenario) and "
          f"{out / 'commissioning.json'}")
    return EXIT_DONE
