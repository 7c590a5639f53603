"""`lrnbv refit`: recorded episodes' boxes estimated again, e.g. with a calibrated sensor
model, without moving the arm."""

from __future__ import annotations

import argparse
import json
import sys

from lrnbv_drake.cli.arg_types import positive_int
from lrnbv_drake.cli.scenario_args import add_containers_argument
from lrnbv_drake.experiments.recording import write_atomically
from lrnbv_drake.experiments.refit import RefitError, first_poses, load_episode, refit
from lrnbv_drake.experiments.report import json_default
from lrnbv_drake.station.parts import check_scenario_files
from lrnbv_drake.station.scenario import load_scenario, override

DESCRIPTION = """\
Estimates the box of each recorded episode again from its readings: every frame and sensor
pose in the folder's frames.npz, started from the final cell box in its report.json. The
episode's own scenario is used, with --scenario and --scenario-text over it: a calibrated
sensor model (`lrnbv sensor characterize` writes its `sensor:` section) or another estimator
(`{extraction: {estimator: model}}`). With --poses N, the episode as if it had stopped after
N poses: its first N frames, from the cell box of the map rebuilt from them (whether fewer
poses would have done). Nothing in the folders is changed; --out receives the
results as JSON, one entry per folder with report.json's fields (estimated_box, container,
and the errors against the truth for a simulated episode)."""

EPILOG = """\
examples:
  lrnbv refit out/cell --scenario calibrated_sensor.yaml
  lrnbv refit out/paper/runs/* --scenario-text '{extraction: {estimator: model}}' --out m.json
  lrnbv refit out/cell --poses 6

exit status: 0 every episode gave a box, 1 some found no object, 2 bad input (nothing was
written)."""


def add_refit_command(subparsers: argparse._SubParsersAction) -> None:
    """Adds `refit` to the `lrnbv` parser's subcommands."""
    parser = subparsers.add_parser(
        "refit", help="estimate recorded episodes' boxes again (e.g. with a calibrated "
                      "sensor model)", description=DESCRIPTION, epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", metavar="FOLDER",
                        help="an episode's folder: report.json and frames.npz")
    parser.add_argument("--scenario", help="scenario YAML over each episode's own scenario")
    parser.add_argument("--scenario-text", metavar="YAML",
                        help="scenario fields as YAML, over the file, e.g. "
                             "'{sensor: {sigma0_mm: 8}}'")
    add_containers_argument(parser)
    parser.add_argument("--poses", type=positive_int, metavar="N",
                        help="only the first N poses of each episode (default: all)")
    parser.add_argument("--out", metavar="FILE", help="write the results here as JSON")


def run_refit_command(args: argparse.Namespace) -> int:
    """Runs `lrnbv refit`; returns the exit code."""
    try:
        episodes = [load_episode(folder) for folder in args.folders]
        if args.poses is not None:
            episodes = [first_poses(episode, args.poses) for episode in episodes]
        scenarios = []
        for episode in episodes:
            scenario = load_scenario(filename=args.scenario, data=args.scenario_text,
                                     defaults=episode.scenario)
            if args.containers is not None:
                scenario = override(scenario, {"packing": {"containers": args.containers}})
            check_scenario_files(scenario)
            scenarios.append(scenario)
    except (RefitError, ValueError, FileNotFoundError) as e:
        print(f"lrnbv refit: error: {e}", file=sys.stderr)
        return 2
    results = []
    for episode, scenario in zip(episodes, scenarios, strict=True):
        result = refit(episode, scenario)
        results.append(result)
        print(_summary(result))
    if args.out is not None:
        try:
            write_atomically(args.out, json.dumps(results, indent=1, default=json_default))
        except OSError as e:
            print(f"lrnbv refit: error: --out {args.out}: cannot write it ({e.strerror})",
                  file=sys.stderr)
            return 2
        print(f"wrote {args.out}")
    return 0 if all(r["estimated_box"] is not None for r in results) else 1


def _summary(result: dict) -> str:
    box = result["estimated_box"]
    where = f"{result['folder']} ({result['n_poses']} poses)"
    if box is None:
        return f"{where}: no object found in this episode: no box"
    line = f"{where}: {' x '.join(f'{v:.3f}' for v in box['dims'])} m"
    reported = result["reported_box"]
    if reported is not None:
        line += f" (reported {' x '.join(f'{v:.3f}' for v in reported['dims'])})"
    if "dim_errors_mm" in result:
        line += f"; errors {', '.join(f'{v:+.1f}' for v in result['dim_errors_mm'])} mm"
    if result["container"] is not None:
        line += f"; container {result['container']['name']}"
    return line
