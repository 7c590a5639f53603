"""Scenario loading: defaults, overrides, and errors that name the bad field."""

import pickle
from pathlib import Path

import numpy as np
import pytest
import yaml
from pydrake.common.yaml import yaml_dump_typed

from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.resources import MODELS_DIR
from lrnbv_drake.station.scenario import Scenario, ScenarioError, load_scenario, override, preset


def test_defaults_and_override(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("seed: 7\nobject: {name: flange, x: 0.4}\nsensor: {sigma0_mm: 3}\n")
    dut = load_scenario(filename=path, data="object: {yaw_deg: 30}")
    assert dut.seed == 7
    assert dut.object.name == "flange"
    assert dut.object.x == 0.4
    assert dut.object.yaw_deg == 30.0  # the string overrides the file, field by field
    assert dut.sensor.sigma0_mm == 3.0
    assert dut.sensor.resolution == Scenario().sensor.resolution


@pytest.mark.parametrize(("text", "field"), [
    ("sed: 3", "sed"),
    ("seed: abc", "seed"),
    ("object: {x: far}", "object.x"),
    ("object: {colour: red}", "object.colour"),
    ("robot: {initial_position: [0, 0, x, 0, 0, 0]}", "robot.initial_position[2]"),
    ("sensor: {flip_x: 3}", "sensor.flip_x"),
    ("sensor: 5", "sensor"),
])
def test_malformed_file_names_the_field(tmp_path, text, field):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as e:
        load_scenario(filename=path)
    assert f"'{field}'" in str(e.value)
    assert str(path) in str(e.value)


def test_unparsable_and_missing_files(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("object: {name: [unclosed\n")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(filename=path)
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(filename=tmp_path / "missing.yaml")


def test_the_example_scenario_loads():
    from pathlib import Path

    dut = load_scenario(filename=Path(__file__).parent.parent / "examples" / "scenario.yaml")
    assert dut.seed == 7
    assert (dut.object.name, dut.object.yaw_deg) == ("vertical_box", 20.0)
    assert dut.mapping.insertion == "ray"
    assert dut.planner.weights.density == 0.05
    assert dut.planner.num_cached_nodes == Scenario().planner.num_cached_nodes


ONE_OF_EVERYTHING = Path(__file__).parent / "scenarios" / "one_of_everything.yaml"


def _leaves(data, path=""):
    """(path, value) of every leaf of a dumped scenario."""
    if isinstance(data, dict):
        for key, value in data.items():
            yield from _leaves(value, f"{path}.{key}" if path else key)
    else:
        yield path, data


def _one_of_everything():
    return override(load_scenario(filename=ONE_OF_EVERYTHING),
                    {"cell": {"directives": str(MODELS_DIR / "cell" / "cell.dmd.yaml")},
                     "packing": {"containers": str(MODELS_DIR / "containers"
                                                   / "shipping_boxes.yaml")}})


def test_one_of_everything_sets_every_field_away_from_its_default():
    dut = dict(_leaves(yaml.safe_load(yaml_dump_typed(_one_of_everything()))))
    default = dict(_leaves(yaml.safe_load(yaml_dump_typed(Scenario()))))
    assert default.keys() <= dut.keys()  # optional fields (device:) dump only when set
    at_default = [k for k in default if dut[k] == default[k]]
    assert at_default == [], f"fields left at their default: {at_default}"


def test_one_of_everything_round_trips_through_pickle():
    dut = _one_of_everything()
    assert yaml_dump_typed(pickle.loads(pickle.dumps(dut))) == yaml_dump_typed(dut)


def test_one_of_everything_runs_a_short_episode(tmp_path):
    scenario = _one_of_everything()
    result = run_episode(scenario, "lrnbv", tmp_path)
    report = result.report
    assert report["n_poses"] == scenario.max_poses == 3
    assert report["termination"] == "reached the cap of 3 poses"
    frames = np.load(tmp_path / "frames.npz")
    assert frames["distance_mm"].shape == (3, 4, 4)  # the 4x4 mode reached the sensor
    assert report["seed"] == 3 and report["object"] == "vertical_box"
    # The cell box has no interval: the container's margin is packing.fixed_margin.
    assert report["container"]["margin"] == [0.012] * 3


def test_an_override_replaces_only_the_fields_it_names():
    base = load_scenario(data="robot: {speed_fraction: 0.3}")
    dut = override(base, {"robot": {"robot_ip": "10.0.0.2"}})
    assert (dut.robot.robot_ip, dut.robot.speed_fraction) == ("10.0.0.2", 0.3)
    with pytest.raises(ScenarioError, match=r"robot\.speed"):
        override(base, {"robot": {"speed": 1}})


def test_the_paper_preset_sets_the_papers_estimator_stop_utility_and_search_and_nothing_else():
    paper, product = preset("paper"), preset(None)
    assert (paper.extraction.estimator, paper.planner.stop.rule,
            paper.planner.travel_discount, paper.planner.search_upper[2],
            paper.planner.lead_points, paper.planner.first_view) == ("cells", "paper", 0.0,
                                                                     0.3, 0, "home")
    assert (product.extraction.estimator, product.planner.stop.rule,
            product.planner.travel_discount, product.planner.search_upper[2],
            product.planner.lead_points, product.planner.first_view) == ("shape", "box", 0.0,
                                                                         0.08, 3, "drop_zone")
    paper.extraction.estimator, paper.planner.stop.rule = "shape", "box"
    paper.planner.search_upper = product.planner.search_upper
    paper.planner.lead_points = product.planner.lead_points
    paper.planner.first_view = product.planner.first_view
    assert yaml_dump_typed(paper) == yaml_dump_typed(product)
    with pytest.raises(ScenarioError, match="unknown preset 'papers'"):
        preset("papers")
