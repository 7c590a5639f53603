"""`lrnbv`: run reconstruction episodes and list the built-in objects."""

from __future__ import annotations

import argparse
import dataclasses as dc
import logging
import sys
from collections.abc import Sequence

from lrnbv_drake.cli.hardware import add_hardware_commands, run_hardware_command
from lrnbv_drake.cli.sensor import add_sensor_commands, run_sensor_command
from lrnbv_drake.core import objects
from lrnbv_drake.experiments.campaign import add_benchmark_command, run_benchmark
from lrnbv_drake.experiments.episode import PLANNERS, make_meshcat, run_episode
from lrnbv_drake.station.scenario import Scenario, load_scenario


def _object_pose(text: str) -> tuple[float, float, float]:
    try:
        x, y, yaw = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--object-pose '{text}': expected x,y,yaw (metres, metres, degrees), e.g. 0.5,0,30"
        ) from None
    return x, y, yaw


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lrnbv", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run one reconstruction episode in the simulated cell")
    run.add_argument("--planner", choices=PLANNERS, default="lrnbv")
    run.add_argument("--object", help="a built-in object (see `lrnbv objects`) or a mesh file "
                                      "(.obj, .stl, .ply)")
    run.add_argument("--object-scale", type=float, help="mesh units to metres (default 1)")
    run.add_argument("--object-pose", type=_object_pose, metavar="X,Y,YAW",
                     help="footprint centre on the table (m) and yaw (degrees)")
    run.add_argument("--seed", type=int, help="seed of every random choice (default 0)")
    run.add_argument("--out", required=True, help="output folder")
    run.add_argument("--scenario", help="scenario YAML file; the flags above override it")
    run.add_argument("--meshcat", action="store_true",
                     help="serve a live Meshcat view and play the episode in real time (a "
                          "replay.html is written either way)")

    sub.add_parser("objects", help="list the built-in objects")
    add_benchmark_command(sub)
    add_sensor_commands(sub)
    add_hardware_commands(sub)
    return parser


def _scenario(args: argparse.Namespace) -> Scenario:
    scenario = load_scenario(filename=args.scenario) if args.scenario else Scenario()
    obj = scenario.object
    if args.object is not None:
        obj = dc.replace(obj, name=args.object)
    if args.object_scale is not None:
        obj = dc.replace(obj, scale=args.object_scale)
    if args.object_pose is not None:
        x, y, yaw = args.object_pose
        obj = dc.replace(obj, x=x, y=y, yaw_deg=yaw)
    seed = scenario.seed if args.seed is None else args.seed
    return dc.replace(scenario, object=obj, seed=seed)


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    args = _parser().parse_args(argv)
    if args.command == "benchmark":
        return run_benchmark(args)
    if args.command == "sensor":
        return run_sensor_command(args)
    if args.command == "hardware":
        return run_hardware_command(args)
    if args.command == "objects":
        for name in objects.PAPER_OBJECTS:
            print(f"{name:16s} {objects.BUILTIN_OBJECTS[name].description}")
        for name, entry in objects.BUILTIN_OBJECTS.items():
            if name not in objects.PAPER_OBJECTS:
                print(f"{name:16s} {entry.description}")
        return 0
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
    result = run_episode(scenario, args.planner, args.out, meshcat,
                         realtime_rate=1.0 if args.meshcat else 0.0)
    report = result.report
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
    print(f"wall {result.wall_seconds:.1f} s; wrote {result.out_dir}/frames.npz, report.json"
          + (", replay.html" if meshcat is not None else ""))
    if args.meshcat and meshcat is not None and sys.stdin.isatty():
        input(f"Meshcat stays up at {meshcat.web_url()}; press Enter to exit. ")
    return 0


if __name__ == "__main__":
    sys.exit(main())
