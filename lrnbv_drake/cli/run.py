"""`lrnbv run`: one reconstruction episode in the simulated cell."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from lrnbv_drake.cli.scenario_args import add_scenario_arguments, load_with_overrides
from lrnbv_drake.core import objects
from lrnbv_drake.experiments.episode import PLANNERS, make_meshcat, run_episode
from lrnbv_drake.station.scenario import Scenario

EXIT_INTERRUPTED = 130


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
    run = subparsers.add_parser("run", help="run one reconstruction episode in the simulated "
                                            "cell")
    run.add_argument("--planner", choices=PLANNERS, default="lrnbv")
    run.add_argument("--object", help="a built-in object (see `lrnbv objects`) or a mesh file "
                                      "(.obj, .stl, .ply)")
    run.add_argument("--object-scale", type=float, help="mesh units to metres (default 1)")
    run.add_argument("--object-pose", type=_object_pose, metavar="X,Y,YAW",
                     help="footprint centre on the table (m) and yaw (degrees)")
    run.add_argument("--seed", type=int, help="seed of every random choice (default 0)")
    run.add_argument("--out", required=True, help="output folder")
    add_scenario_arguments(run)
    run.add_argument("--meshcat", action="store_true",
                     help="serve a live Meshcat view and play the episode in real time (a "
                          "replay.html is written either way)")


def _scenario(args: argparse.Namespace) -> Scenario:
    x, y, yaw = args.object_pose if args.object_pose is not None else (None, None, None)
    return load_with_overrides(args, {
        "object": {"name": args.object, "scale": args.object_scale, "x": x, "y": y,
                   "yaw_deg": yaw},
        "seed": args.seed,
    })


def run_run_command(args: argparse.Namespace) -> int:
    """Runs `lrnbv run`; returns the exit code."""
    try:
        scenario = _scenario(args)
        # Fail on a bad object before anything is built.
        objects.load_object_mesh(scenario.object.name, scenario.object.scale)
    except (ValueError, FileNotFoundError) as e:
        print(f"lrnbv: error: {e}", file=sys.stderr)
        return 2
    meshcat = make_meshcat(live=args.meshcat)
    if args.meshcat and meshcat is not None:
        print(f"Meshcat: {meshcat.web_url()}")
    try:
        result = run_episode(scenario, args.planner, args.out, meshcat,
                             realtime_rate=1.0 if args.meshcat else 0.0)
    except KeyboardInterrupt as e:
        print(f"lrnbv run: {e}", file=sys.stderr)
        return EXIT_INTERRUPTED
    _print_summary(result.report, result.wall_seconds, result.out_dir, meshcat is not None)
    if args.meshcat and meshcat is not None and sys.stdin.isatty():
        input(f"Meshcat stays up at {meshcat.web_url()}; press Enter to exit. ")
    return 0


def _print_summary(report: dict[str, Any], wall_seconds: float, out_dir, replay: bool) -> None:
    m = report["metrics"]
    print(f"{report['planner']} on {report['object']} (seed {report['seed']}): "
          f"{report['n_poses']} poses ({m['n_useless_poses']} useless), "
          f"{len(report['motion_failures'])} unreachable viewpoints")
    print(f"ended: {report['termination']}")
    if m["box_found"]:
        est = " x ".join(f"{v:.3f}" for v in m["estimated_dims"])
        true = " x ".join(f"{v:.3f}" for v in m["true_dims"])
        print(f"box L x W x H: {est} m (true {true}); IoU {m['iou']:.3f}")
    else:
        print(f"no object found: {report['extraction']}")
    print(f"surface coverage: {100 * m['coverage']['0.01']:.1f} % within 1 cm, "
          f"{100 * m['coverage']['0.02']:.1f} % within 2 cm")
    print(f"wall {wall_seconds:.1f} s; wrote {out_dir}/frames.npz, report.json"
          + (", replay.html" if replay else ""))
