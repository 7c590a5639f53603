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


def add_cell_address_arguments(parser: argparse.ArgumentParser) -> None:
    """--robot-ip and --sensor-port: where the real cell's robot and sensor are."""
    parser.add_argument("--robot-ip", help="the UR controller's address (robot.robot_ip)")
    parser.add_argument("--sensor-port",
                        help="the sensor board's serial port (sensor.serial_port)")


def missing_cell_address(args: argparse.Namespace) -> str | None:
    """What a real (not --dry-run) run lacks of --robot-ip and --sensor-port, unless a
    --scenario may set them; None if nothing."""
    missing = [f for f in ("robot_ip", "sensor_port") if getattr(args, f) is None]
    if args.dry_run or not missing or args.scenario is not None:
        return None
    return (f"{' and '.join('--' + f.replace('_', '-') for f in missing)} required "
            f"(or a --scenario that sets them, or --dry-run)")


def load_cell_scenario(args: argparse.Namespace) -> Scenario:
    """The scenario (`load_with_overrides`) with --robot-ip and --sensor-port over it."""
    return load_with_overrides(args, {"robot": {"robot_ip": args.robot_ip},
                                      "sensor": {"serial_port": args.sensor_port}})


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
