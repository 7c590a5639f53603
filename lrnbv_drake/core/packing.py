"""The packing decision: which container the estimated box goes in.

The box (length, width, height) is grown, dimension by dimension, by the estimate's margin
(how much larger the object may be than estimated, at the interval's level) and a packing
clearance; a container holds it when, in one of the six axis-aligned orientations, every grown
dimension is within the container's inner dimension. Of those that hold it, the cheapest is
chosen, ties broken by the smaller volume and then the name; when the catalogue gives no costs
(all or nothing: a partial price list would compare prices with guesses), the smallest by
volume. Nothing here reads files: `load_catalogue` parses the YAML text it is given.
"""

from __future__ import annotations

import dataclasses as dc
import itertools
from collections.abc import Sequence

import numpy as np
import yaml

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
    """

    container: Container | None
    required: np.ndarray
    margin: np.ndarray
    clearance: float
    orientation: tuple[int, int, int] | None
    reason: str


class CatalogueError(ValueError):
    """A container catalogue that cannot be used; the message names the entry."""


def load_catalogue(text: str, source: str = "catalogue") -> list[Container]:
    """Containers from YAML: `containers:` a list of {name, inner: [L, W, H] metres, cost}.

    Raises:
        CatalogueError: naming `source`, the entry and what was expected.
    """
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise CatalogueError(f"{source}: not valid YAML: {e}") from e
    entries = data.get("containers") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise CatalogueError(f"{source}: expected 'containers:' with a list of containers")
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
                or not all(isinstance(v, (int, float)) and v > 0 for v in inner)):
            raise CatalogueError(f"{where} ({name}): 'inner' must be three positive lengths "
                                 f"in metres, got {inner!r}")
        if cost is not None and not (isinstance(cost, (int, float)) and cost >= 0):
            raise CatalogueError(f"{where} ({name}): 'cost' must be a number >= 0, got "
                                 f"{cost!r}")
        names.add(name)
        containers.append(Container(name, tuple(float(v) for v in inner),
                                    None if cost is None else float(cost)))
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
    if all(c.cost is not None for c in containers):
        return sorted(containers, key=lambda c: (c.cost, c.volume, c.name))
    return sorted(containers, key=lambda c: (c.volume, c.name))


def choose_container(dims: np.ndarray, margin: np.ndarray, clearance: float,
                     catalogue: Sequence[Container]) -> PackingDecision:
    """The container for a box of `dims` (L, W, H) known to within `margin` (3,), packed with
    `clearance` (see the module docstring)."""
    dims, margin = np.asarray(dims, float), np.asarray(margin, float)
    if dims.shape != (3,) or margin.shape != (3,) or np.any(dims <= 0) or np.any(margin < 0):
        raise ValueError(f"expected three positive dimensions and three margins >= 0, got "
                         f"{dims} and {margin}")
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
