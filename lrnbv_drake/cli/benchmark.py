"""`lrnbv benchmark`: the paper's evaluation campaign, every planner on every object for several
trials, run in parallel processes (or Ray tasks), resumable, and summarised.

The command line only: the campaign itself is `lrnbv_drake.experiments.campaign`, whose `run`
module tells what `--out` DIR holds and how rerunning the same command resumes.
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import math
import os
import shlex
import sys
from pathlib import Path

from lrnbv_drake.cli.arg_types import positive_int, seed
from lrnbv_drake.cli.out_dir import OutDirError, prepare_out_dir
from lrnbv_drake.cli.run import EXIT_BAD_INPUT, EXIT_INTERRUPTED
from lrnbv_drake.cli.scenario_args import add_containers_argument, add_preset_argument
from lrnbv_drake.experiments.campaign.plan import (
    BACKENDS,
    FAMILY_PLACEMENT,
    CampaignConfig,
    CampaignError,
    PlacementRange,
    load_objects,
    plan_episodes,
)
from lrnbv_drake.experiments.campaign.run import CampaignInterrupted, run_campaign
from lrnbv_drake.experiments.episode import SIMULATION_PLANNERS
from lrnbv_drake.station.parts import check_scenario_files
from lrnbv_drake.station.scenario import ScenarioError, load_scenario, override, preset
from lrnbv_drake.station.scenario_checks import check_placement

EPILOG = """\
DIR receives summary.md, results.csv, figure.png and coverage_curves.png, rewritten after every
run from every episode in DIR. Ctrl-C stops the running episodes at once, writes those outputs
for the finished ones and prints the command that resumes.

exit status: 0 every episode finished, 1 some failed (rerun the command to retry them), 2 bad
input (nothing run), 130 interrupted by Ctrl-C."""


def _planners(text: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(p.strip() for p in text.split(",") if p.strip()))
    unknown = [p for p in names if p not in SIMULATION_PLANNERS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"--planners '{text}': {', '.join(unknown) or 'none given'} not available; "
            f"expected a comma-separated subset of {', '.join(SIMULATION_PLANNERS)}")
    return names


def _interval(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        lo = hi = math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise argparse.ArgumentTypeError(f"expected MIN,MAX with MIN <= MAX, got '{text}'")
    return lo, hi


def add_benchmark_command(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds `benchmark` to the `lrnbv` command's subparsers."""
    default = PlacementRange()
    parser = subparsers.add_parser(
        "benchmark", help="run the paper's campaign: every planner on every object, N trials",
        description=__doc__.split("\n\n")[0], epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--planners", type=_planners, default=SIMULATION_PLANNERS,
                        help="comma-separated planners (default: "
                             f"{','.join(SIMULATION_PLANNERS)})")
    parser.add_argument("--objects", default="paper",
                        help="paper (the four), family (the generated shapes, placed at "
                             "random over the table unless --random-placement says where), "
                             "held_out (shapes measured, never developed against; placed as "
                             "the family), all (paper and family), a folder of .obj/.stl/.ply "
                             "meshes, or comma-separated built-in names or mesh files "
                             "(default: paper)")
    parser.add_argument("--trials", type=positive_int, default=5,
                        help="trials per planner and object (default 5)")
    parser.add_argument("--out", required=True,
                        help="campaign folder; rerun the same command to resume (planners, "
                             "objects and trials may grow); a folder holding another kind "
                             "of run is refused")
    parser.add_argument("--jobs", type=positive_int, default=os.cpu_count() or 1,
                        help="episodes run at once (default: the CPU count)")
    parser.add_argument("--backend", choices=BACKENDS, default="local",
                        help="local processes, or Ray tasks (needs the 'ray' extra) "
                             "(default: local)")
    parser.add_argument("--ray-address",
                        help="a running Ray cluster (default: start a local one with --jobs CPUs)")
    parser.add_argument("--scenario", help="scenario YAML: cell, sensor, object scale and "
                                           "placement; its object is replaced by --objects")
    add_containers_argument(parser)
    add_preset_argument(parser)
    parser.add_argument("--seed", type=seed,
                        help="base seed, >= 0, from which each (object, trial) derives its "
                             "own (default: the scenario's, 0)")
    parser.add_argument("--random-placement", action="store_true",
                        help="a random object x, y, yaw per trial (the same for every planner)")
    parser.add_argument("--x-range", type=_interval, metavar="MIN,MAX",
                        help=f"random placement x, m (default {default.x[0]},{default.x[1]})")
    parser.add_argument("--y-range", type=_interval, metavar="MIN,MAX",
                        help=f"random placement y, m (default {default.y[0]},{default.y[1]})")
    parser.add_argument("--yaw-range", type=_interval, metavar="MIN,MAX",
                        help=f"random placement yaw, degrees (default "
                             f"{default.yaw_deg[0]:g},{default.yaw_deg[1]:g})")
    parser.add_argument("--replay", action="store_true",
                        help="write each episode's Meshcat replay.html (slower)")
    return parser


def config_from_args(args: argparse.Namespace) -> CampaignConfig:
    """The campaign the parsed arguments describe; checks every object mesh loads and every
    episode's placement (as `lrnbv run` does) before anything runs."""
    scenario = load_scenario(filename=args.scenario, defaults=preset(args.preset))
    if args.containers is not None:
        scenario = override(scenario, {"packing": {"containers": args.containers}})
    check_scenario_files(scenario)
    found = load_objects(args.objects, scenario.object.scale)
    given = {flag: (field, value) for flag, field, value in (
        ("--x-range", "x", args.x_range), ("--y-range", "y", args.y_range),
        ("--yaw-range", "yaw_deg", args.yaw_range)) if value is not None}
    if given and not args.random_placement:
        raise CampaignError(f"{', '.join(given)} set the random placement's ranges; add "
                            f"--random-placement (without it every trial uses the scenario's "
                            f"placement)")
    placement = (PlacementRange(**dict(given.values())) if args.random_placement
                 else FAMILY_PLACEMENT if args.objects in ("family", "held_out") else None)
    config = CampaignConfig(
        out_dir=Path(args.out), planners=tuple(args.planners), objects=found,
        trials=args.trials, scenario=scenario,
        seed=scenario.seed if args.seed is None else args.seed, placement=placement,
        jobs=args.jobs, backend=args.backend, ray_address=args.ray_address, replay=args.replay)
    for episode in plan_episodes(dc.replace(config, planners=config.planners[:1])):
        check_placement(episode.scenario)
    return dc.replace(config, out_dir=prepare_out_dir(args.out, "benchmark"))


def _command_line(args: argparse.Namespace) -> str:
    """The command as typed, when `lrnbv.cli.main` recorded it."""
    words = getattr(args, "command_line", None)
    return shlex.join(words) if words else "lrnbv benchmark ... (as before)"


def run_benchmark(args: argparse.Namespace) -> int:
    """`lrnbv benchmark`: 0 when every episode finished, 1 when some failed, 2 on bad input,
    130 on Ctrl-C (the outputs then cover the episodes finished so far)."""
    try:
        config = config_from_args(args)
        records = run_campaign(config)
    except (CampaignError, ScenarioError, OutDirError) as e:
        print(f"lrnbv benchmark: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except CampaignInterrupted as e:
        print(f"\nlrnbv benchmark: interrupted (Ctrl-C): {e}; the running ones were stopped. "
              f"{args.out}/summary.md, results.csv and the figures cover every finished "
              f"episode. Resume with the same command:\n  {_command_line(args)}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    failed = [r["campaign"]["episode"] for r in records if r["campaign"]["status"] != "ok"]
    print(f"{len(records) - len(failed)} of {len(records)} episodes finished; wrote "
          f"{config.out_dir}/results.csv, summary.md, figure.png, coverage_curves.png")
    if failed:
        print(f"{len(failed)} failed ({', '.join(failed)}): see {config.out_dir}/episodes/; "
              "rerun the same command to retry them", file=sys.stderr)
        return 1
    return 0
