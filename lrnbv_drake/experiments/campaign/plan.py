"""What a campaign runs: its settings, the objects, and every (planner, object, trial) episode
with its paired seed and placement.

Seeds are paired: each (object, trial) gets its own seed, derived from (base seed, object,
trial) by `numpy.random.SeedSequence` and independent of the planner, so on the same (object,
trial) every planner sees the same sensor-noise stream and the same placement. The U tests
compare planners on the same draws, and adding a planner later compares it on those too.
"""

from __future__ import annotations

import dataclasses as dc
import hashlib
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.common.yaml import yaml_dump_typed

from lrnbv_drake.core.evaluation import objects
from lrnbv_drake.station.scenario import Scenario

#: Where episodes run: local processes (or this one), or Ray tasks.
BACKENDS = ("local", "ray")


class CampaignError(ValueError):
    """Settings that cannot make a campaign, or a DIR holding a different one."""


@dc.dataclass(frozen=True)
class CampaignObject:
    """An object of the campaign: `label` names it in file names and tables, `source` is what
    the scenario loads (a built-in name or an absolute mesh path)."""

    label: str
    source: str


@dc.dataclass(frozen=True)
class PlacementRange:
    """Where `--random-placement` puts an object: uniform footprint centre (m) and yaw (deg).
    The default keeps all 13 HEU poses around every paper object reachable (checked at the
    corners; beyond x = 0.5 the far poses over the tall vertical box leave the arm's reach)."""

    x: tuple[float, float] = (0.45, 0.50)
    y: tuple[float, float] = (-0.08, 0.08)
    yaw_deg: tuple[float, float] = (-180.0, 180.0)

    def sample(self, rng: np.random.Generator) -> tuple[float, float, float]:
        """One (x, y, yaw_deg)."""
        return tuple(float(rng.uniform(lo, hi)) for lo, hi in (self.x, self.y, self.yaw_deg))


#: Where `--objects family` (and `held_out`) places its shapes by default: the part of the
#: table the arm views from every side (an object there keeps most of HEU's 13 poses
#: reachable).
FAMILY_PLACEMENT = PlacementRange(x=(0.42, 0.58), y=(-0.12, 0.12))


@dc.dataclass
class CampaignConfig:
    """One campaign: what runs (planners x objects x trials) and how."""

    out_dir: Path
    planners: tuple[str, ...]
    objects: tuple[CampaignObject, ...]
    trials: int
    # The cell, sensor and placement; its object name is replaced by each of `objects`.
    scenario: Scenario = dc.field(default_factory=Scenario)
    # Base seed every episode's seed derives from.
    seed: int = 0
    # Random placement per trial; None keeps the scenario's.
    placement: PlacementRange | None = None
    # Parallel episodes (local processes, or Ray CPUs of a local Ray instance); 1 runs them in
    # this process, one after the other.
    jobs: int = 1
    backend: str = "local"
    # A running Ray cluster to use instead of starting a local one.
    ray_address: str | None = None
    # Write each episode's Meshcat replay.html (slower).
    replay: bool = False


@dc.dataclass(frozen=True)
class Episode:
    """One (planner, object, trial) with its fully specified scenario."""

    planner: str
    object: CampaignObject
    trial: int
    scenario: Scenario
    # Hash of the scenario (seed, placement, cell, sensor): what resuming checks.
    fingerprint: str
    replay: bool = False

    @property
    def key(self) -> str:
        """`<planner>__<object>__<trial>`: the episode's file names."""
        return f"{self.planner}__{self.object.label}__{self.trial}"

    def campaign_fields(self) -> dict[str, Any]:
        """What the campaign adds to the episode's report: who, which draw, where."""
        obj = self.scenario.object
        return {"episode": self.key, "planner": self.planner, "object": self.object.label,
                "object_source": self.object.source, "trial": self.trial,
                "seed": self.scenario.seed, "object_pose": [obj.x, obj.y, obj.yaw_deg],
                "fingerprint": self.fingerprint, "run_dir": f"runs/{self.key}"}


def trial_streams(base_seed: int, label: str, trial: int) -> tuple[int, np.random.Generator]:
    """(episode seed, placement generator) of one (object, trial), the same for every planner.

    Two children of one SeedSequence, so the seed and the placement are independent streams;
    the object enters by a CRC of its label, stable across processes (unlike `hash`).
    """
    root = np.random.SeedSequence([base_seed, zlib.crc32(label.encode()), trial])
    seed_child, placement_child = root.spawn(2)
    # 31 bits: a seed any consumer takes as a non-negative int.
    seed = int(seed_child.generate_state(1)[0]) >> 1
    return seed, np.random.default_rng(placement_child)


def plan_episodes(config: CampaignConfig) -> list[Episode]:
    """Every (planner, object, trial), objects and trials outermost so that the planners of
    one (object, trial) run close together."""
    episodes = []
    for obj in config.objects:
        for trial in range(config.trials):
            seed, rng = trial_streams(config.seed, obj.label, trial)
            placed = config.scenario.object
            x, y, yaw = ((placed.x, placed.y, placed.yaw_deg) if config.placement is None
                         else config.placement.sample(rng))
            scenario = dc.replace(config.scenario, seed=seed, object=dc.replace(
                placed, name=obj.source, x=x, y=y, yaw_deg=yaw))
            fingerprint = hashlib.sha256(yaml_dump_typed(scenario).encode()).hexdigest()[:16]
            episodes.extend(Episode(p, obj, trial, scenario, fingerprint, config.replay)
                            for p in config.planners)
    return episodes


def resolve_objects(spec: str) -> tuple[CampaignObject, ...]:
    """`paper`, `family`, `held_out`, `all` (the paper's and the family), a folder of meshes,
    or comma-separated built-in names / mesh files."""
    expected = ("expected paper, family, held_out, all, a folder of .obj/.stl/.ply meshes, or "
                "comma-separated built-in objects (`lrnbv objects`) or mesh files")
    if spec == "paper":
        return tuple(CampaignObject(n, n) for n in objects.PAPER_OBJECTS)
    if spec == "family":
        return tuple(CampaignObject(n, n) for n in objects.FAMILY_OBJECTS)
    if spec == "held_out":
        return tuple(CampaignObject(n, n) for n in objects.HELD_OUT_OBJECTS)
    if spec == "all":
        return tuple(CampaignObject(n, n) for n in (*objects.PAPER_OBJECTS,
                                                    *objects.FAMILY_OBJECTS))
    folder = Path(spec)
    if folder.is_dir():
        meshes = sorted(p for p in folder.iterdir()
                        if p.is_file() and p.suffix.lower() in objects.MESH_SUFFIXES)
        if not meshes:
            raise CampaignError(f"--objects '{spec}': the folder holds no .obj, .stl or .ply "
                                "file")
    else:
        meshes = []
        for item in filter(None, (s.strip() for s in spec.split(","))):
            if objects.is_builtin(item):
                meshes.append(item)
            elif Path(item).suffix.lower() in objects.MESH_SUFFIXES:
                meshes.append(Path(item))
            else:
                raise CampaignError(f"--objects '{spec}': unknown object '{item}': {expected}")
        if not meshes:
            raise CampaignError(f"--objects '{spec}': no object given: {expected}")
    found = tuple(CampaignObject(m, m) if isinstance(m, str) else
                  CampaignObject(m.stem, str(m.resolve())) for m in meshes)
    labels = [o.label for o in found]
    if len(set(labels)) != len(labels):
        raise CampaignError(f"--objects '{spec}': two objects share a name in {labels}: "
                            "rename one, the name keys its files")
    return found


def load_objects(spec: str, scale: float) -> tuple[CampaignObject, ...]:
    """`resolve_objects`, then every mesh loaded once at `scale`: a broken file stops the
    campaign before any episode runs rather than failing each of its episodes."""
    found = resolve_objects(spec)
    for obj in found:
        try:
            objects.load_object_mesh(obj.source, scale)
        except (ValueError, FileNotFoundError) as e:
            raise CampaignError(f"--objects '{spec}': {e}") from e
    return found
