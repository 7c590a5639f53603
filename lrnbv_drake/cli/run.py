"""`lrnbv run`: one reconstruction episode in the simulated cell."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from lrnbv_drake.cli.arg_types import seed
from lrnbv_drake.cli.out_dir import prepare_out_dir
from lrnbv_drake.cli.scenario_args import add_scenario_arguments, load_with_overrides
from lrnbv_drake.core.evaluation import objects
from lrnbv_drake.experiments.episode import SIMULATION_PLANNERS, make_meshcat, run_episode
from lrnbv_drake.station.parts import check_scenario_files
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.station.scenario_checks import check_placement

#: Exit codes: a box was found; the episode ended without finding the object; bad input;
#: Ctrl-C (what was captured is saved).
EXIT_FOUND, EXIT_NOT_FOUND, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

DESCRIPTION = """\
Runs one reconstruction episode in the simulated cell: the planner chooses viewpoints, the
simulated VL53L8CX measures from each, and the episode ends when the planner stops. --out
receives frames.npz (every frame and its sensor pose), report.json (the estimated box, every
pose, the metrics against the true object; docs/report-json.md) and replay.html (open it in a
browser). The object's size and placement are checked before anything runs."""

EPILOG = """\
examples:
  lrnbv run --out out/lrnbv
  lrnbv run --planner heu --object vertical_box --seed 3 --out out/heu
  lrnbv run --object part.stl --object-scale 0.001 --object-pose 0.5,0.05,30 --out out/part
  lrnbv run --scenario examples/scenario.yaml --scenario-text '{max_poses: 10}' --out out/s

exit status: 0 a box was found, 1 the episode found no object, 2 bad input (nothing was
written), 130 interrupted by Ctrl-C (what was captured is saved in --out)."""

PLANNER_HELP = ("lrnbv (the paper's LR-NBV), nbv (its NBV baseline: the same without the "
                "density and visited gains), heu (13 views on an ellipse around the object) "
                "or oracle (knows the object: views that measure each side of its true box, "
                "until the estimate is within 5 mm)")


def _object_pose(text: str) -> tuple[float, float, float]:
    try:
        x, y, yaw = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--object-pose '{text}': expected x,y,yaw (metres, metres, degrees), e.g. 0.5,0,30"
        ) from None
    return x, y, yaw


def add_run_command(subparsers: argparse._SubParsersAction) -> None:
    """Adds `run` to the `lrnbv` parser's subcommands."""
    placed = Scenario().object
    run = subparsers.add_parser("run", help="run one reconstruction episode in the simulated "
                                            "cell", description=DESCRIPTION, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    run.add_argument("--planner", choices=SIMULATION_PLANNERS, default="lrnbv",
                     help=f"{PLANNER_HELP} (default: lrnbv)")
    run.add_argument("--object", help="a built-in object (`lrnbv objects` lists them) or a "
                                      f"mesh file (.obj, .stl, .ply) (default: {placed.name})")
    run.add_argument("--object-scale", type=float,
                     help="mesh units to metres, e.g. 0.001 for a mesh in millimetres, as "
                          "most CAD exports are (default: 1)")
    run.add_argument("--object-pose", type=_object_pose, metavar="X,Y,YAW",
                     help="footprint centre on the table (m, robot base at 0,0) and yaw "
                          f"(degrees) (default: {placed.x:g},{placed.y:g},{placed.yaw_deg:g})")
    run.add_argument("--seed", type=seed,
                     help="seed of every random choice, >= 0 (default: the scenario's, 0)")
    run.add_argument("--out", required=True,
                     help="output folder, created if needed; one holding another run's "
                          "results is refused (see --overwrite)")
    run.add_argument("--overwrite", action="store_true",
                     help="replace the results of an earlier `lrnbv run` in --out")
    add_scenario_arguments(run)
    run.add_argument("--meshcat", action="store_true",
                     help="serve a live Meshcat view on every network interface (port 7000 or "
                          "the next free one: anyone who can reach this machine can watch) "
                          "and play the episode in real time; a replay.html is written "
                          "either way")


def _scenario(args: argparse.Namespace) -> Scenario:
    x, y, yaw = args.object_pose if args.object_pose is not None else (None, None, None)
    return load_with_overrides(args, {
        "object": {"name": args.object, "scale": args.object_scale, "x": x, "y": y,
                   "yaw_deg": yaw},
        "seed": args.seed,
    })


def run_run_command(args: argparse.Namespace) -> int:
    """Runs `lrnbv run`; returns the exit code (`EXIT_*`)."""
    try:
        scenario = _scenario(args)
        # The object's size and place first: a mesh in millimetres read as metres would
        # otherwise fill the memory, and a misplaced one end in "no object found".
        check_placement(scenario, objects.load_object_mesh(scenario.object.name,
                                                           scenario.object.scale))
        check_scenario_files(scenario)  # before --overwrite removes an earlier run
        out_dir = prepare_out_dir(args.out, "run", args.overwrite)
    except (ValueError, FileNotFoundError) as e:
        print(f"lrnbv run: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    meshcat = make_meshcat(live=args.meshcat)
    if args.meshcat and meshcat is not None:
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    try:
        result = run_episode(scenario, args.planner, out_dir, meshcat,
                             realtime_rate=1.0 if args.meshcat else 0.0)
    except KeyboardInterrupt as e:
        # run_episode saves what was captured, then raises with what it saved.
        print(f"lrnbv run: {e or 'interrupted (Ctrl-C) before the first capture'}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    found = _print_summary(result.report, result.wall_seconds, result.out_dir,
                           meshcat is not None)
    if args.meshcat and meshcat is not None and sys.stdin.isatty():
        try:
            input(f"Meshcat stays up at {meshcat.web_url()}; press Enter to exit. ")
        except (EOFError, KeyboardInterrupt):
            print()
    return EXIT_FOUND if found else EXIT_NOT_FOUND


def _print_summary(report: dict[str, Any], wall_seconds: float, out_dir: Path,
                   replay: bool) -> bool:
    """Prints what the episode did; returns whether it found a box."""
    m = report["metrics"]
    print(f"{report['planner']} on {report['object']} (seed {report['seed']}): "
          f"{report['n_poses']} poses ({m['n_useless_poses']} useless), "
          f"{len(report['motion_failures'])} unreachable viewpoints")
    print(f"ended: {report['termination']}")
    if m["box_found"]:
        est = " x ".join(f"{v:.3f}" for v in m["estimated_dims"])
        true = " x ".join(f"{v:.3f}" for v in m["true_dims"])
        print(f"box L x W x H: {est} m (true {true}); IoU {m['iou']:.3f}")
    if report["container"] is not None:
        print(f"container: {report['container']['reason']}")
    print(f"surface coverage: {100 * m['coverage']['0.01']:.1f} % within 1 cm, "
          f"{100 * m['coverage']['0.02']:.1f} % within 2 cm")
    cycle = report["cycle_time"]
    print(f"cycle time {cycle['total_s']:.1f} s: arm motion {cycle['motion_s']:.1f} s, "
          f"waiting for frames {cycle['settle_s']:.1f} s, computation "
          f"{cycle['computation_s']:.1f} s")
    print(f"wall {wall_seconds:.1f} s; wrote {out_dir}/frames.npz, report.json, report.html"
          + (", replay.html" if replay else ""))
    if not m["box_found"]:
        print(f"lrnbv run: no object found: {report['extraction']}", file=sys.stderr)
    return bool(m["box_found"])
