"""The packing decision: which container the estimated box goes in.

The box (length, width, height) is grown, dimension by dimension, by the estimate's margin
(how much larger the object may be than estimated, at the interval's level) and a packing
clearance; a container holds it when, in one of the six axis-aligned orientations, every grown
dimension is within the container's inner dimension. Of those that hold it, the cheapest is
chosen, ties broken by the smaller volume and then the name; when the catalogue gives no costs
(all or nothing: a partial price list would compare prices with guesses, so the loader
refuses it), the smallest by volume. Nothing here reads files: `load_catalogue` parses the
YAML text it is given.
"""

from __future__ import annotations

import dataclasses as dc
import itertools
import math
from collections.abc import Sequence

import numpy as np

from lrnbv_drake.core.estimation.estimator import BoxEstimate
from lrnbv_drake.core.strict_yaml import load_yaml

#: The six ways a box's (L, W, H) can be laid along a container's axes.
ORIENTATIONS: tuple[tuple[int, int, int], ...] = tuple(itertools.permutations(range(3)))


@dc.dataclass(frozen=True)
class Container:
    """A container: its name, inner length x width x height (metres) and optional cost."""

    name: str
    inner: tuple[float, float, float]
    cost: float | None = None

    @property
    def volume(self) -> float:
        return float(np.prod(self.inner))


@dc.dataclass(frozen=True)
class PackingDecision:
    """What was chosen and from which numbers.

    Attributes:
        container: the chosen container; None when nothing holds the box.
        required: (3,) the box's L, W, H grown by margin and clearance, metres.
        margin: (3,) the estimate's margin per dimension, metres.
        clearance: the packing clearance added to every dimension, metres.
        orientation: which grown dimension lies along the container's L, W, H.
        reason: one sentence: what was chosen and why, or what does not fit.
        margin_from: where the margin came from.
    """

    container: Container | None
    required: np.ndarray
    margin: np.ndarray
    clearance: float
    orientation: tuple[int, int, int] | None
    reason: str
    margin_from: str = "the caller"


class CatalogueError(ValueError):
    """A container catalogue that cannot be used; the message names the entry."""


#: An inner side longer than this (metres) is a catalogue written in millimetres.
LONGEST_CONTAINER = 5.0


def _number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def load_catalogue(text: str, source: str = "catalogue") -> list[Container]:
    """Containers from YAML: `containers:` a list of {name, inner: [L, W, H] metres, cost},
    the cost given for every container or for none.

    Raises:
        CatalogueError: naming `source`, the entry and what was expected.
    """
    data = load_yaml(text, source, CatalogueError)
    entries = data.get("containers") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise CatalogueError(f"{source}: expected 'containers:' with a list of containers")
    if set(data) != {"containers"}:
        raise CatalogueError(f"{source}: unknown keys {sorted(set(data) - {'containers'})}; "
                             f"expected only 'containers:'")
    containers, names = [], set()
    for i, entry in enumerate(entries):
        where = f"{source}: containers[{i}]"
        if not isinstance(entry, dict) or set(entry) - {"name", "inner", "cost"}:
            raise CatalogueError(f"{where}: expected a mapping of name, inner and cost, got "
                                 f"{entry!r}")
        name, inner, cost = entry.get("name"), entry.get("inner"), entry.get("cost")
        if not isinstance(name, str) or not name or name in names:
            raise CatalogueError(f"{where}: 'name' must be a new non-empty text, got {name!r}")
        if (not isinstance(inner, list) or len(inner) != 3
                or not all(_number(v) and v > 0 for v in inner)):
            raise CatalogueError(f"{where} ({name}): 'inner' must be three positive lengths "
                                 f"in metres, got {inner!r}")
        if max(inner) > LONGEST_CONTAINER:
            raise CatalogueError(f"{where} ({name}): 'inner' {inner} is longer than "
                                 f"{LONGEST_CONTAINER:g} m; expected metres (if the catalogue "
                                 f"is in millimetres, divide by 1000)")
        if cost is not None and not (_number(cost) and cost >= 0):
            raise CatalogueError(f"{where} ({name}): 'cost' must be a number >= 0, got "
                                 f"{cost!r}")
        names.add(name)
        containers.append(Container(name, tuple(float(v) for v in inner),
                                    None if cost is None else float(cost)))
    unpriced = [c.name for c in containers if c.cost is None]
    if unpriced and len(unpriced) < len(containers):
        raise CatalogueError(f"{source}: no 'cost' for {', '.join(unpriced)}; expected a cost "
                             f"for every container or for none (the choice is then the "
                             f"smallest by volume)")
    return containers


def orientation_holding(required: np.ndarray, container: Container) -> tuple[int, int, int] | None:
    """The first orientation in which `required` (L, W, H) fits inside `container`, if any."""
    inner = np.asarray(container.inner)
    required = np.asarray(required, float)
    for order in ORIENTATIONS:
        if np.all(required[list(order)] <= inner + 1e-12):
            return order
    return None


def _rank(containers: Sequence[Container]) -> list[Container]:
    priced = [c.cost is not None for c in containers]
    if all(priced):
        return sorted(containers, key=lambda c: (c.cost, c.volume, c.name))
    if any(priced):
        raise ValueError("expected a cost for every container or for none; "
                         f"{sum(priced)} of {len(containers)} have one")
    return sorted(containers, key=lambda c: (c.volume, c.name))


def choose_container(dims: np.ndarray, margin: np.ndarray, clearance: float,
                     catalogue: Sequence[Container]) -> PackingDecision:
    """The container for a box of `dims` (L, W, H) known to within `margin` (3,), packed with
    `clearance` (see the module docstring)."""
    dims, margin = np.asarray(dims, float), np.asarray(margin, float)
    if (dims.shape != (3,) or margin.shape != (3,) or not np.all(dims > 0)
            or not np.all(margin >= 0) or not np.all(np.isfinite(np.r_[dims, margin]))):
        raise ValueError(f"expected three finite positive dimensions and three finite margins "
                         f">= 0, got {dims} and {margin}")
    if not (math.isfinite(clearance) and clearance >= 0):
        raise ValueError(f"expected a finite clearance >= 0, got {clearance}")
    if not catalogue:
        raise ValueError("the container catalogue is empty")
    required = dims + margin + clearance
    text = " x ".join(f"{v:.3f}" for v in required)
    for container in _rank(catalogue):
        order = orientation_holding(required, container)
        if order is not None:
            priced = f", cost {container.cost:g}" if container.cost is not None else ""
            return PackingDecision(
                container, required, margin, clearance, order,
                f"{container.name} ({' x '.join(f'{v:.3f}' for v in container.inner)} m "
                f"inner{priced}) holds {text} m (the box plus margin and clearance)")
    largest = max(max(c.inner) for c in catalogue)
    longest = int(np.argmax(required))
    name = ("length", "width", "height")[longest]
    if required[longest] > largest:
        why = (f"its {name} of {required[longest]:.3f} m exceeds every container (the longest "
               f"inner side is {largest:.3f} m)")
    else:
        why = "no container holds all three dimensions in any orientation"
    return PackingDecision(None, required, margin, clearance, None,
                           f"no container holds {text} m: {why}")


def container_for(estimate: BoxEstimate, fixed_margin: float, clearance: float,
                  catalogue: Sequence[Container]) -> PackingDecision:
    """The container for an estimate: its margin is the interval's outer half (which the
    estimator widens where the readings misfit the model), or `fixed_margin` for an estimate
    without an interval (the cell box)."""
    box = estimate.box
    if estimate.dims_upper is None:
        margin, source = np.full(3, fixed_margin), "packing.fixed_margin"
    else:
        margin = np.maximum(estimate.dims_upper - box.dims, 0.0)
        source = f"the estimate's {100 * estimate.confidence:.0f} % profile interval"
        if estimate.misfit_flag:
            source += ", widened by the readings' misfit"
    decision = choose_container(box.dims, margin, clearance, catalogue)
    return dc.replace(decision, margin_from=source)


def packing_metrics(decision: PackingDecision, true_dims: np.ndarray,
                    catalogue: Sequence[Container]) -> dict[str, object]:
    """Against the true box: `fits` (the true box fits the chosen container, no clearance),
    `right_size` (the chosen one is the one the true box gets with the same clearance and no
    margin), and the volume wasted relative to that right-size container."""
    right = choose_container(true_dims, np.zeros(3), decision.clearance, catalogue).container
    chosen = decision.container
    return {
        "fits": chosen is not None and orientation_holding(true_dims, chosen) is not None,
        "right_size": chosen is not None and right is not None and chosen.name == right.name,
        "right_size_container": None if right is None else right.name,
        "wasted_volume": (None if chosen is None or right is None
                          else chosen.volume / right.volume - 1.0),
    }
