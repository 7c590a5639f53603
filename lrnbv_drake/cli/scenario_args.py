"""The one way a command's flags set scenario fields: --scenario FILE, then --scenario-text YAML
(as Drake's hardware_sim), then the command's own flags, each through `station.scenario`'s
schema checks."""

from __future__ import annotations

import argparse
from typing import Any

from lrnbv_drake.station.scenario import PRESETS, Scenario, load_scenario, override, preset


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """--scenario FILE and --scenario-text YAML, read in that order (as Drake's hardware_sim);
    a command's own flags override both."""
    add_preset_argument(parser)
    parser.add_argument("--scenario", help="scenario YAML file")
    parser.add_argument("--scenario-text", metavar="YAML",
                        help="scenario fields as YAML, over the file, e.g. "
                             "'{max_poses: 10, sensor: {sigma0_mm: 8}}'")
    add_containers_argument(parser)


def add_preset_argument(parser: argparse.ArgumentParser) -> None:
    """--preset NAME: the scenario to start from, before --scenario and the flags."""
    parser.add_argument("--preset", choices=sorted(PRESETS),
                        help="start from a named configuration: 'paper' is the paper's "
                             "(cell box, Algorithm 1's stop); by default the product's")


def add_containers_argument(parser: argparse.ArgumentParser) -> None:
    """--containers FILE: the container catalogue (packing.containers)."""
    parser.add_argument("--containers", metavar="FILE",
                        help="container catalogue YAML (default: the shipped shipping boxes, "
                             "models/containers/shipping_boxes.yaml)")


def load_with_overrides(args: argparse.Namespace, overrides: dict[str, Any]) -> Scenario:
    """The scenario from --scenario and --scenario-text, then the flags' `overrides` (nested
    like the YAML; fields left None are not set)."""
    scenario = load_scenario(filename=args.scenario, data=args.scenario_text,
                             defaults=preset(args.preset))
    overrides = {**overrides, "packing": {"containers": args.containers}}
    nested = {section: ({k: v for k, v in fields.items() if v is not None}
                        if isinstance(fields, dict) else fields)
              for section, fields in overrides.items() if fields is not None}
    nested = {k: v for k, v in nested.items() if v != {}}
    return override(scenario, nested) if nested else scenario
