"""Scenario loading: defaults, overrides, and errors that name the bad field."""

import pytest

from lrnbv_drake.station.scenario import Scenario, ScenarioError, load_scenario


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
    assert dut.mapping.insertion == "cone"
    assert dut.planner.weights.density == 0.05
    assert dut.planner.num_cached_nodes == Scenario().planner.num_cached_nodes
