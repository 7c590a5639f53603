"""`device:` is how the simulated VL53L8CX behaves; perception and planning must never read it,
or an estimator would be scored on data from its own model (no inverse crime)."""

import ast
from pathlib import Path

import numpy as np

from lrnbv_drake.station.parts import device_params, sensor_params
from lrnbv_drake.station.scenario import load_scenario

PACKAGE = Path(__file__).resolve().parents[1] / "lrnbv_drake"
#: The only modules that may touch the device: where it is declared, turned into parameters,
#: and handed to the simulated sensor.
ALLOWED = {"station/scenario.py", "station/parts.py", "station/sim_cell.py",
           "station/calibration_bench.py"}


def _device_uses(path: Path) -> list[int]:
    """Lines of `path` that read a scenario's `device` (`scenario.device`, `self._scenario.
    device`, ...) or use `device_params` or `device_profile`."""
    def scenario_name(node: ast.AST) -> bool:
        name = node.attr if isinstance(node, ast.Attribute) else getattr(node, "id", "")
        return "scenario" in name

    tree = ast.parse(path.read_text())
    return [node.lineno for node in ast.walk(tree)
            if (isinstance(node, ast.Attribute) and node.attr == "device"
                and scenario_name(node.value))
            or (isinstance(node, ast.Name) and node.id in ("device_params", "device_profile"))]


def test_only_the_simulated_sensor_reads_the_device_section():
    offenders = {}
    for path in PACKAGE.rglob("*.py"):
        relative = path.relative_to(PACKAGE).as_posix()
        lines = _device_uses(path)
        if lines and relative not in ALLOWED:
            offenders[relative] = lines
    assert offenders == {}
    # The check can fail: the allowed modules do use it.
    assert _device_uses(PACKAGE / "station" / "sim_cell.py")


def test_device_fields_default_to_the_model_and_override_it_one_by_one():
    scenario = load_scenario(data="sensor: {min_share: 0.3, sigma0_mm: 6}\n"
                                  "device: {sigma0_mm: 9, cluster_gap_mm: 40}")
    model, device = sensor_params(scenario), device_params(scenario)
    assert (model.min_share, model.noise.sigma0_mm, model.cluster_gap_mm) == (0.3, 6.0, 25.0)
    assert (device.min_share, device.noise.sigma0_mm, device.cluster_gap_mm) == (0.3, 9.0, 40.0)
    assert device.noise.k == model.noise.k
    np.testing.assert_equal(device.geometry.directions(), model.geometry.directions())


def test_the_ideal_device_follows_the_model_and_the_datasheet_one_does_not():
    from lrnbv_drake.station.parts import device_profile

    model = load_scenario(data="sensor: {zone_directions: st, merge_mm: 300, "
                               "target_order: strongest}")
    ideal = device_profile(model)
    assert (ideal.behaviour.merge_mm, ideal.behaviour.target_order) == (300.0, "strongest")
    np.testing.assert_equal(device_params(model).geometry.directions(),
                            sensor_params(model).geometry.directions())
    datasheet = device_profile(load_scenario(data="device: {profile: datasheet, merge_mm: 450}"))
    assert (datasheet.behaviour.merge_mm, datasheet.zone_directions) == (450.0, "st")
    assert datasheet.behaviour.sharpener_bleed > 0
