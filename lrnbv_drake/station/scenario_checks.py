"""Checks a scenario's values, and where its object sits in the cell, before anything is built.

`check_against_schema` checks the types (an int where an int belongs) against the
scenario's dataclasses; the rest check what the types cannot: ranges
(`samples_per_iteration: -5` would plan nothing, `max_poses: 0` would still take a pose), YAML
that a plain load accepts but means two things (a duplicate key), and placements the episode
could never resolve (a 150 m mesh read in millimetres, an object outside the mapped volume or
inside the robot's base), so that each fails at once with the field named and what was
expected, instead of minutes later, out of memory or with "no object found".
The `hardware` section is `station.hardware_cell.check_hardware_config`'s; the simulation-only
`device` section is not read here (only the simulated sensor may read it, test_device_section).
"""

from __future__ import annotations

import dataclasses as dc
import math
import types
import typing
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

from lrnbv_drake.core.evaluation import objects
from lrnbv_drake.core.sensing.sensor import ROLL_STEPS_DEG, ROLL_STEPS_TEXT
from lrnbv_drake.core.sensing.tof_device import (
    ACCURACY_LAWS,
    MERGED_DEPTHS,
    PROFILES,
    TARGET_ORDERS,
)
from lrnbv_drake.core.sensing.tof_protocol import RESOLUTIONS
from lrnbv_drake.core.sensing.zone_order import ZONE_FLIPS, ZONE_ROTATIONS
from lrnbv_drake.core.strict_yaml import load_yaml

if TYPE_CHECKING:  # scenario.py calls these checks while loading; only the type is needed
    from lrnbv_drake.station.scenario import Scenario


class ScenarioError(ValueError):
    """A scenario file or string that does not match the schema (or its ranges)."""

#: Radius around the robot's base axis (the world origin, cell/cell.dmd.yaml) that no object
#: may reach into, metres: the UR5e's base is 0.15 m across, its shoulder turns above it.
BASE_CLEARANCE = 0.10
#: A mesh larger than this, metres, is no object on a table: its units are not metres, and
#: `check_placement` suggests the first of `UNIT_SCALES` (factor, unit) it would fit at.
NOT_METRES = 10.0
UNIT_SCALES = ((0.001, "millimetres"), (0.01, "centimetres"))

# --- Value ranges ----------------------------------------------------------------------------

#: (field path, test of the value, what was expected).
Rule = tuple[str, Callable[[Any], bool], str]


def _number(ok: Callable[[float], bool], expected: str) -> tuple[Callable[[Any], bool], str]:
    return (lambda v: math.isfinite(v) and ok(v)), expected


def _at_least(lo: float) -> tuple[Callable[[Any], bool], str]:
    return _number(lambda v: v >= lo, f"a number >= {lo:g}")


def _above(lo: float) -> tuple[Callable[[Any], bool], str]:
    return _number(lambda v: v > lo, f"a number > {lo:g}")


def _vector(n: int) -> tuple[Callable[[Any], bool], str]:
    return ((lambda v: len(v) == n and all(math.isfinite(x) for x in v)),
            f"{n} finite numbers")


def _one_of(*choices: str) -> tuple[Callable[[Any], bool], str]:
    return (lambda v: v in choices), "one of " + ", ".join(repr(c) for c in choices)


_FRACTION = _number(lambda v: 0 < v <= 1, "a fraction in (0, 1]")
_RECTANGLE = ((lambda v: len(v) == 4 and all(math.isfinite(x) for x in v)
               and v[0] < v[2] and v[1] < v[3]),
              "[x_min, y_min, x_max, y_max], finite, each min below its max")
_FINITE = _number(lambda v: True, "a finite number")

RULES: tuple[Rule, ...] = tuple((path, *test) for path, test in (
    ("seed", _at_least(0)),
    ("max_poses", _at_least(1)),
    ("robot.initial_position", _vector(6)),
    ("robot.speed_fraction", _FRACTION),
    ("robot.acceleration_fraction", _FRACTION),
    ("robot.collision_check_step", _above(0)),
    ("robot.collision_padding", _at_least(0)),
    ("cell.table_height", _FINITE),
    ("cell.table_reflectance", _FRACTION),
    ("cell.table_extent", _RECTANGLE),
    ("cell.drop_zone", _RECTANGLE),
    ("cell.max_item_height", _above(0)),
    ("cell.workspace_lower", _vector(3)),
    ("cell.workspace_upper", _vector(3)),
    ("object.scale", _above(0)),
    ("object.x", _FINITE),
    ("object.y", _FINITE),
    ("object.yaw_deg", _FINITE),
    ("object.reflectance", _FRACTION),
    ("sensor.resolution", ((lambda v: v in RESOLUTIONS.values()),
                           f"one of {sorted(RESOLUTIONS.values())} (the VL53L8CX's modes)")),
    ("sensor.fov_deg", _number(lambda v: 0 < v < 180, "an angle in (0, 180) degrees")),
    ("sensor.subsamples", _at_least(1)),
    ("sensor.min_share", _FRACTION),
    ("sensor.cluster_gap_mm", _above(0)),
    ("sensor.sigma0_mm", _at_least(0)),
    ("sensor.noise_k", _at_least(0)),
    ("sensor.target_order", _one_of(*TARGET_ORDERS)),
    ("sensor.merge_mm", _at_least(0)),
    ("sensor.merged_depth", _one_of(*MERGED_DEPTHS)),
    ("sensor.period", _above(0)),
    ("sensor.settle_frames", _at_least(0)),
    ("sensor.baud", _at_least(1)),
    ("device.min_share", _FRACTION),
    ("device.cluster_gap_mm", _above(0)),
    ("device.sigma0_mm", _at_least(0)),
    ("device.noise_k", _at_least(0)),
    ("device.profile", _one_of(*PROFILES)),
    ("device.target_order", _one_of(*TARGET_ORDERS)),
    ("device.merge_mm", _at_least(0)),
    ("device.merged_depth", _one_of(*MERGED_DEPTHS)),
    ("device.sharpener_bleed", _number(lambda v: 0 <= v <= 1, "a share in [0, 1]")),
    ("device.accuracy", _one_of(*ACCURACY_LAWS)),
    ("device.ambient_klux", _at_least(0)),
    ("device.reported_sigma_spread", _at_least(0)),
    ("device.zone_offset_mm", _at_least(0)),
    ("device.zone_offset_seed", _at_least(0)),
    ("device.integration_steps", _at_least(1)),
    ("sensor.mount.xyz_mm", _vector(3)),
    ("sensor.mount.rpy_deg", _vector(3)),
    ("device.mount.xyz_mm", _vector(3)),
    ("device.mount.rpy_deg", _vector(3)),
    ("device.zone_order.rotate", ((lambda v: v in ZONE_ROTATIONS),
                                  f"one of {ZONE_ROTATIONS} (degrees counter-clockwise)")),
    ("device.zone_order.flip", _one_of(*ZONE_FLIPS)),
    ("device.table_offset_mm", _FINITE),
    ("packing.clearance", _at_least(0)),
    ("packing.fixed_margin", _at_least(0)),
    ("mapping.resolution", _above(0)),
    ("mapping.lower", _vector(3)),
    ("mapping.upper", _vector(3)),
    ("mapping.insertion", _one_of("ray", "cone")),
    ("mapping.cone_subrays", _at_least(1)),
    ("mapping.max_range", _FINITE),
    ("extraction.table_tolerance", _at_least(0)),
    ("extraction.dbscan_eps", _above(0)),
    ("extraction.dbscan_min_samples", _at_least(1)),
    ("extraction.min_cluster_points", _at_least(1)),
    ("extraction.center", _vector(2)),
    ("extraction.max_center_distance", _above(0)),
    ("extraction.roi_margin", _at_least(0)),
    ("extraction.estimator", _one_of("shape", "cells")),
    ("estimation.loss_scale", _above(0)),
    ("estimation.no_return", _above(0)),
    ("estimation.margin", _above(0)),
    ("estimation.max_parts", _at_least(1)),
    ("estimation.step", _above(0)),
    ("estimation.interval_level", _above(0)),
    ("estimation.interval_reach", _above(0)),
    ("estimation.search_casts", _above(0)),
    ("planner.num_iterations", _at_least(1)),
    ("heu.n_poses", _at_least(1)),
    ("heu.semi_axis_x", _above(0)),
    ("heu.semi_axis_y", _above(0)),
    ("heu.height", _FINITE),
    ("heu.start_angle", _FINITE),
    ("planner.samples_per_iteration", _at_least(1)),
    ("planner.num_cached_nodes", _at_least(0)),
    ("planner.visited_cell_size", _above(0)),
    ("planner.weights.exploration", _at_least(0)),
    ("planner.weights.density", _at_least(0)),
    ("planner.weights.quality", _at_least(0)),
    ("planner.weights.visited", _at_least(0)),
    ("planner.gains.max_range", _above(0)),
    ("planner.gains.rays_per_zone", _at_least(1)),
    ("planner.gains.density_radius", _above(0)),
    ("planner.tree.max_edge", _above(0)),
    ("planner.tree.roi_clearance", _at_least(0)),
    ("planner.tree.aim_offset_fraction", _at_least(0)),
    ("planner.tree.max_attempts_per_node", _at_least(1)),
    ("planner.tree.round_size", _at_least(1)),
    ("planner.cache_threshold", _FINITE),
    ("planner.cached_sample_spread", _at_least(0)),
    ("planner.travel_discount", _at_least(0)),
    ("robot.self_filter_padding", _at_least(0)),
    ("robot.sensor_roll_step_deg", _number(lambda v: v in ROLL_STEPS_DEG, ROLL_STEPS_TEXT)),
    ("planner.stop.rule", _one_of("paper", "box")),
    ("planner.first_view", _one_of("drop_zone", "home")),
    ("planner.utility", _one_of("paper", "box")),
    ("planner.box_exploration", _at_least(0)),
    ("planner.weights.box", _at_least(0)),
    ("planner.stop.tolerance", _above(0)),
    ("planner.stop.stable_poses", _at_least(1)),
    ("planner.stop.min_poses", _at_least(1)),
    ("planner.stop.interval_width", _above(0)),
    ("planner.search_lower", _vector(3)),
    ("planner.search_upper", _vector(3)),
    ("planner.lead_points", _at_least(0)),
    ("planner.lead_margin", _at_least(0)),
    ("visualization.publish_period", _above(0)),
))

#: Boxes given as two corners: every lower coordinate must be below the upper one.
BOXES: tuple[tuple[str, str], ...] = (
    ("cell.workspace_lower", "cell.workspace_upper"),
    ("mapping.lower", "mapping.upper"),
    ("planner.search_lower", "planner.search_upper"),
)


def _field(scenario: Scenario, path: str) -> Any:
    value: Any = scenario
    for name in path.split("."):
        value = getattr(value, name)
    return value


def check_ranges(scenario: Scenario, fields_only: bool = False) -> None:
    """Raises ScenarioError naming the first field whose value is out of its range (`RULES`)
    and, unless `fields_only` (a scenario one source of several has set so far), the first
    pair of fields that disagree (`BOXES`, the search region above the table); the types are
    already checked when the scenario is loaded."""
    for path, ok, expected in RULES:
        value = _field(scenario, path)
        if value is not None and not ok(value):  # None: an optional field left unset
            raise ScenarioError(f"field '{path}': expected {expected}, got {value!r}")
    if fields_only:
        return
    top = scenario.cell.table_height + scenario.extraction.table_tolerance
    if not scenario.planner.search_upper[2] > top:
        raise ScenarioError(
            f"field 'planner.search_upper': its z {scenario.planner.search_upper[2]:g} m is not "
            f"above the table top plus extraction.table_tolerance ({top:g} m), so nothing "
            f"found in the search region could be the object; expected a world z above it "
            f"(the default searches the table's lowest 8 cm)")
    for lower_path, upper_path in BOXES:
        lower, upper = _field(scenario, lower_path), _field(scenario, upper_path)
        if not all(lo < hi for lo, hi in zip(lower, upper, strict=True)):
            raise ScenarioError(f"fields '{lower_path}' {lower} and '{upper_path}' {upper}: "
                                "expected every lower coordinate below the upper one")


# --- YAML ------------------------------------------------------------------------------------


def parse_yaml(text: str, label: str) -> Any:
    """`text` parsed as YAML, or ScenarioError naming `label` (e.g. "scenario file 'x.yaml'"),
    the line and column, and the problem; a duplicate key is an error."""
    return load_yaml(text, label, ScenarioError)


# --- The object in the cell ------------------------------------------------------------------


def _type_name(tp: typing.Any) -> str:
    return getattr(tp, "__name__", str(tp))


def _check_value(value: typing.Any, tp: typing.Any, path: str) -> None:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        errors = []
        for option in typing.get_args(tp):
            if option is type(None):  # `X | None`: None is fine, anything else must be an X
                if value is None:
                    return
                continue
            try:
                _check_value(value, option, path)
                return
            except ScenarioError as e:
                errors.append(str(e))
        raise ScenarioError(errors[-1])
    if dc.is_dataclass(tp) or hasattr(tp, "__fields__"):
        if not isinstance(value, dict):
            raise ScenarioError(f"field '{path}': expected a mapping of {tp.__name__} fields, "
                                f"got {value!r}")
        check_against_schema(value, tp, path)
        return
    if origin is list:
        if not isinstance(value, list):
            raise ScenarioError(f"field '{path}': expected a list, got {value!r}")
        (item,) = typing.get_args(tp)
        for i, v in enumerate(value):
            _check_value(v, item, f"{path}[{i}]")
        return
    if tp is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif tp is bool:
        ok = isinstance(value, bool)
    elif tp is str:
        ok = isinstance(value, str)
    else:
        ok = True
    if not ok:
        raise ScenarioError(f"field '{path}': expected {_type_name(tp)}, got {value!r}")


def check_against_schema(data: typing.Any, schema: type, path: str = "") -> None:
    """Raises ScenarioError naming the first field of `data` that does not fit `schema`."""
    if not isinstance(data, dict):
        raise ScenarioError(f"expected a mapping of {schema.__name__} fields at "
                            f"'{path or '<top>'}', got {data!r}")
    if dc.is_dataclass(schema):
        hints = typing.get_type_hints(schema)
    else:  # a Drake struct bound with its serialisable fields, e.g. VisualizationConfig
        hints = {f.name: f.type for f in schema.__fields__}
    names = set(hints)
    for key, value in data.items():
        where = f"{path}.{key}" if path else str(key)
        if key not in names:
            raise ScenarioError(f"field '{where}' is not part of {schema.__name__}; expected "
                                f"one of {sorted(names)}")
        _check_value(value, hints[key], where)


def _dims(values: Sequence[float]) -> str:
    return " x ".join(f"{v:.3g}" for v in values) + " m"


def _unit_hint(extents: np.ndarray, fits: Callable[[np.ndarray], bool]) -> str:
    """What to do about a mesh too large for the cell: the scale to try when it is so large
    that its units cannot be metres."""
    if max(extents) > NOT_METRES:
        for factor, unit in UNIT_SCALES:
            if fits(extents * factor):
                return (f"; if the mesh is in {unit}, set object.scale to {factor:g} "
                        f"(--object-scale {factor:g})")
    return "; scale it down (object.scale, --object-scale) or enlarge the mapped volume"


def _footprint_distance(placed: objects.PlacedObject, point_xy: np.ndarray) -> float:
    """Horizontal distance from `point_xy` to the object's footprint (its true box seen from
    above), 0 inside it."""
    R, t = placed.X_WO[:2, :2], placed.X_WO[:2, 3]
    local = R.T @ (np.asarray(point_xy, float) - t)
    lo, hi = placed.box_min_O[:2], placed.box_max_O[:2]
    return float(np.linalg.norm(np.maximum(np.maximum(lo - local, local - hi), 0.0)))


def check_placement(scenario: Scenario, mesh: trimesh.Trimesh | None = None) -> None:
    """Raises ScenarioError when the scenario's object, placed as it says, could never be found:
    larger than the mapped volume (with the scale to try when it looks like millimetres),
    lower than the table tolerance, reaching into the robot's base, farther from
    `extraction.center` than `extraction.max_center_distance`, or out of the mapped volume.

    `mesh` is the object's mesh already loaded at its scale (else it is loaded here); cheap
    next to an episode, so callers run it before building anything.
    """
    o, m, e = scenario.object, scenario.mapping, scenario.extraction
    table = scenario.cell.table_height
    if mesh is None:
        try:
            mesh = objects.load_object_mesh(o.name, o.scale)
        except (ValueError, FileNotFoundError) as err:
            raise ScenarioError(f"field 'object.name': {err}") from err
    lower, upper = np.asarray(m.lower, float), np.asarray(m.upper, float)
    room = np.array([*sorted(upper[:2] - lower[:2]), upper[2] - table])
    extents = np.asarray(mesh.extents, float)

    def fits(size: np.ndarray) -> bool:
        return bool(np.all(np.array([*sorted(size[:2]), size[2]]) <= room))

    def plausible(size: np.ndarray) -> bool:
        return fits(size) and size[2] > e.table_tolerance

    label = f"object '{o.name}' at scale {o.scale:g}"
    if not fits(extents):
        raise ScenarioError(
            f"{label} is {_dims(extents)} ({max(extents):.3g} m across): larger than the "
            f"mapped volume, {_dims(upper - lower)} (mapping.lower, mapping.upper)"
            + _unit_hint(extents, plausible))
    if extents[2] <= e.table_tolerance:
        raise ScenarioError(
            f"{label} is {extents[2]:.3g} m tall: not above extraction.table_tolerance "
            f"({e.table_tolerance:g} m), so every point on it is taken for the table")
    placed = objects.place_on_table(
        mesh, objects.ObjectPlacement(o.x, o.y, math.radians(o.yaw_deg)), table)
    where = f"{label} placed at x = {o.x:g}, y = {o.y:g} m (object.x, object.y)"
    if _footprint_distance(placed, np.zeros(2)) < BASE_CLEARANCE:
        raise ScenarioError(
            f"{where} reaches within {BASE_CLEARANCE:g} m of the robot's base axis at (0, 0): "
            f"it would stand inside the robot; place it in front, e.g. x = 0.5, y = 0")
    distance = math.dist((o.x, o.y), e.center)
    if distance > e.max_center_distance:
        raise ScenarioError(
            f"{where} is {distance:.3g} m from extraction.center {list(e.center)}: the object "
            f"is looked for within extraction.max_center_distance = "
            f"{e.max_center_distance:g} m of it; place it there or move extraction.center")
    box_lo, box_hi = placed.mesh.bounds
    if np.any(box_lo < lower) or np.any(box_hi > upper):
        raise ScenarioError(
            f"{where} spans {np.round(box_lo, 3).tolist()} to {np.round(box_hi, 3).tolist()} "
            f"m: out of the mapped volume {list(m.lower)} to {list(m.upper)} "
            f"(mapping.lower, mapping.upper)")
