"""`station.scenario_checks` (issue 14): out-of-range values, duplicate YAML keys and objects
the episode could never find fail at once, naming the field and what was expected."""

from __future__ import annotations

import dataclasses as dc
from pathlib import Path

import pytest
import trimesh

from lrnbv_drake.core.evaluation import objects
from lrnbv_drake.station.scenario import Scenario, ScenarioError, load_scenario
from lrnbv_drake.station.scenario_checks import (
    BASE_CLEARANCE,
    RULES,
    check_placement,
    check_ranges,
    parse_yaml,
)


def test_the_defaults_and_the_examples_pass():
    check_ranges(Scenario())
    check_placement(Scenario())
    example = load_scenario(filename=Path(__file__).parents[1] / "examples" / "scenario.yaml")
    check_ranges(example)
    check_placement(example)


@pytest.mark.parametrize("text, message", [
    ("{planner: {samples_per_iteration: -5}}",
     "field 'planner.samples_per_iteration': expected a number >= 1, got -5"),
    ("{max_poses: 0}", "field 'max_poses': expected a number >= 1, got 0"),
    ("{seed: -1}", "field 'seed': expected a number >= 0, got -1"),
    ("{sensor: {resolution: 6}}", "field 'sensor.resolution': expected one of [4, 8]"),
    ("{sensor: {min_share: 1.5}}", "expected a fraction in (0, 1], got 1.5"),
    ("{extraction: {estimator: fancy}}",
     "field 'extraction.estimator': expected one of 'shape', 'cells', got 'fancy'"),
    ("{mapping: {resolution: .nan}}", "field 'mapping.resolution': expected a number > 0"),
    ("{estimation: {interval_level: 0}}",
     "field 'estimation.interval_level': expected a number > 0, got 0"),
    ("{estimation: {search_casts: -1}}",
     "field 'estimation.search_casts': expected a number > 0, got -1"),
    ("{heu: {semi_axis_y: 0}}", "field 'heu.semi_axis_y': expected a number > 0, got 0"),
    ("{planner: {stop: {rule: early}}}",
     "field 'planner.stop.rule': expected one of 'paper', 'box', got 'early'"),
    ("{robot: {sensor_roll_step_deg: 45}}",
     "field 'robot.sensor_roll_step_deg': expected 0, 90 or 180 (the square grid's "
     "symmetries), got 45"),
    ("{robot: {initial_position: [0, 0, 0]}}",
     "field 'robot.initial_position': expected 6 finite numbers"),
    ("{mapping: {lower: [0, 0, 1.0]}}",
     "fields 'mapping.lower' [0.0, 0.0, 1.0] and 'mapping.upper' [1.0, 0.6, 0.9]: expected "
     "every lower coordinate below the upper one"),
    # A negative clearance would put a 0.12 m tall box into a 0.10 m tall container.
    ("{packing: {clearance: -0.05}}", "field 'packing.clearance': expected a number >= 0"),
    ("{packing: {fixed_margin: .nan}}", "field 'packing.fixed_margin': expected a number >= 0"),
    ("{device: {min_share: 5.0}}", "field 'device.min_share': expected a fraction in (0, 1]"),
    ("{device: {sigma0_mm: -3}}", "field 'device.sigma0_mm': expected a number >= 0"),
    # `X | None` fields: None leaves them unset, anything else must be an X.
    ("{device: {min_share: abc}}", "field 'device.min_share': expected float, got 'abc'"),
    ("{device: {illumination: 3}}", "field 'device.illumination': expected bool, got 3"),
])
def test_values_out_of_range_name_the_field_and_the_range(text, message):
    with pytest.raises(ScenarioError) as error:
        check_ranges(load_scenario(data=text))
    assert message in str(error.value)


def test_a_range_error_names_the_file_that_set_the_value(tmp_path):
    file = tmp_path / "cell.yaml"
    file.write_text("max_poses: 0\n")
    with pytest.raises(ScenarioError, match=r"scenario file '.*cell\.yaml': field 'max_poses'"):
        load_scenario(file)
    with pytest.raises(ScenarioError, match=r"^scenario string: field 'max_poses'"):
        load_scenario(data="{max_poses: 0}")


def test_a_search_region_under_the_table_is_refused_where_it_is_set():
    """The default search region reaches 8 cm above a table at 0: on a table at 0.1 m the
    planner's ROI came out upside down mid-episode."""
    with pytest.raises(ScenarioError, match=r"'planner.search_upper': its z 0.08 m is not above"):
        load_scenario(data="{cell: {table_height: 0.1}}")
    raised = "{cell: {table_height: 0.1}, planner: {search_upper: [0.75, 0.3, 0.3]}}"
    assert load_scenario(data=raised).planner.search_upper[2] == 0.3


def test_a_pair_of_fields_split_between_a_file_and_a_string_is_checked_as_a_whole(tmp_path):
    file = tmp_path / "cell.yaml"
    file.write_text("planner: {search_lower: [0.25, -0.3, 0.1]}\n")
    scenario = load_scenario(file, data="planner: {search_upper: [0.75, 0.3, 0.4]}")
    assert scenario.planner.search_lower[2] == 0.1 and scenario.planner.search_upper[2] == 0.4


def test_every_rule_names_a_field_of_the_scenario():
    scenario = Scenario()
    for path, ok, _ in RULES:
        value = scenario
        for name in path.split("."):
            value = getattr(value, name)
        assert value is None or ok(value), path  # the default passes it (None: unset)


def test_yaml_errors_name_the_file_line_and_duplicate_key():
    with pytest.raises(ScenarioError) as error:
        parse_yaml("seed: 1\nsensor:\n  sigma0_mm: 5\n  sigma0_mm: 8\n", "scenario file 'c.yaml'")
    assert str(error.value) == (
        "scenario file 'c.yaml', line 4, column 3: not valid YAML: the key 'sigma0_mm' is "
        "given twice (first on line 3); expected each key once")
    with pytest.raises(ScenarioError, match=r"^scenario file 'c.yaml', line 2, column 1: "):
        parse_yaml("object: {name: flange\n", "scenario file 'c.yaml'")
    # A merge key may repeat its base's keys; that is no duplicate.
    assert parse_yaml("b: &b {x: 1, y: 2}\nc: {<<: *b, x: 3}\n", "s") == {
        "b": {"x": 1, "y": 2}, "c": {"x": 3, "y": 2}}


def test_a_mesh_in_millimetres_gets_the_scale_to_use():
    part = trimesh.creation.box(extents=(120.0, 80.0, 50.0))  # millimetres, read as metres
    with pytest.raises(ScenarioError) as error:
        check_placement(Scenario(), part)
    assert "120 x 80 x 50 m (120 m across)" in str(error.value)
    assert "set object.scale to 0.001 (--object-scale 0.001)" in str(error.value)
    part.apply_scale(0.001)
    check_placement(Scenario(), part)
    # A box too big but in metres gets no unit hint.
    with pytest.raises(ScenarioError) as error:
        check_placement(Scenario(), trimesh.creation.box(extents=(1.5, 1.5, 1.5)))
    assert "larger than the mapped volume" in str(error.value)
    assert "millimetres" not in str(error.value)


def test_placements_the_episode_could_never_resolve():
    box = objects.load_object_mesh("horizontal_box")  # 0.30 x 0.20 x 0.12 m

    def place(**fields):
        scenario = Scenario()
        scenario.object = dc.replace(scenario.object, **fields)
        check_placement(scenario, box)

    place(x=0.5, y=0.0)
    # The footprint's near edge, 0.15 m before its centre, at 0.10 m from the base's axis:
    # just clear of it; a millimetre closer is not.
    place(x=BASE_CLEARANCE + 0.15 + 1e-6, y=0.0)
    with pytest.raises(ScenarioError, match="robot's base axis"):
        place(x=BASE_CLEARANCE + 0.15 - 1e-3, y=0.0)
    with pytest.raises(ScenarioError, match="robot's base axis"):
        place(x=0.0, y=0.0)
    with pytest.raises(ScenarioError, match=r"is 2\.5 m from extraction\.center"):
        place(x=3.0)
    # Within reach of the extraction but hanging out of the mapped volume (y <= 0.6).
    scenario = load_scenario(data="{extraction: {center: [0.5, 0.45], max_center_distance: 0.5}}")
    scenario.object = dc.replace(scenario.object, x=0.5, y=0.55)
    with pytest.raises(ScenarioError, match="out of the mapped volume"):
        check_placement(scenario, box)


def test_an_object_lower_than_the_table_tolerance_is_refused():
    plate = trimesh.creation.box(extents=(0.2, 0.2, 0.02))
    with pytest.raises(ScenarioError, match=r"0\.02 m tall: not above extraction\.table_tolerance"):
        check_placement(Scenario(), plate)


def test_an_unknown_object_names_the_field():
    scenario = load_scenario(data="{object: {name: teapot}}")
    with pytest.raises(ScenarioError, match=r"field 'object\.name': unknown object 'teapot'"):
        check_placement(scenario)


def test_surface_sampling_refuses_a_mesh_far_too_large():
    # 54 m^2 of surface at 5 mm spacing: 2.16 million points, over the cap; the check comes
    # before any allocation, so a 150 m mesh (billions of points) fails as fast.
    cube = trimesh.creation.box(extents=(3.0, 3.0, 3.0))
    with pytest.raises(ValueError, match=r"if it is in millimetres, scale it by 0\.001"):
        objects.sample_surface(cube, 0.005, exclude_bottom=False)
    assert objects.MAX_SURFACE_SAMPLES < 54 / 0.005**2
    assert len(objects.sample_surface(cube, 0.01, exclude_bottom=False)) == 540_000


@pytest.mark.parametrize("section, field, bad", [
    ("mapping", "insertion", "cones"), ("extraction", "estimator", "model"),
    ("planner", "stop", "early")])
def test_a_scenario_built_in_code_is_checked_where_an_episode_or_a_refit_starts(
        heu_run, section, field, bad):
    """A scenario made with dataclasses.replace skips the loader's checks: the episode's
    builder and the refit run them, before anything is made, naming the field."""
    from lrnbv_drake.experiments.episode import build_episode
    from lrnbv_drake.experiments.refit import load_episode, refit

    scenario = Scenario()
    part = getattr(scenario, section)
    if field == "stop":
        part = dc.replace(part, stop=dc.replace(part.stop, rule=bad))
        path = "planner.stop.rule"
    else:
        part = dc.replace(part, **{field: bad})
        path = f"{section}.{field}"
    scenario = dc.replace(scenario, **{section: part})
    for start in (lambda: build_episode(scenario, "lrnbv"),
                  lambda: refit(load_episode(heu_run), scenario)):
        with pytest.raises(ScenarioError, match=f"field '{path}': expected one of .* got "
                                                f"'{bad}'"):
            start()
