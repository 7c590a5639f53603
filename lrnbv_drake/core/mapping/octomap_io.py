"""The map as an OctoMap tree: the size OctoMap's pruned tree would have, and the `.ot`/`.bt`
export, which has to prune the pyoctomap tree the way OctoMap would for the files to match."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lrnbv_drake.core.mapping.keys import KEY_OFFSET, TREE_DEPTH

if TYPE_CHECKING:
    from lrnbv_drake.core.mapping.occupancy_map import OccupancyMap


def prune_plan(keys: np.ndarray, values: np.ndarray) -> tuple[int, list[np.ndarray]]:
    """Structure of the pruned octree holding these finest-level leaves.

    OctoMap collapses an inner node whose 8 children are all leaves with equal log-odds (not the
    root). Pruning a full tree bottom-up gives the same structure as OctoMap's incremental
    pruning after non-lazy updates.

    Args:
        keys: (N, 3) OctoMap keys of known leaves.
        values: (N,) float32 log-odds.

    Returns:
        (size, collapsed): `size` is the number of nodes, root included, i.e. OctoMap's
        `OcTree::size()`; `collapsed[d]` holds the keys at depth d ((M, 3), key >> (16 - d)) of
        the nodes that become leaves, for d = 0..16 (empty at 0 and 16).
    """
    collapsed: list[np.ndarray] = [np.zeros((0, 3), np.int64) for _ in range(TREE_DEPTH + 1)]
    if len(keys) == 0:
        return 0, collapsed
    k = np.asarray(keys, dtype=np.int64)
    val = np.asarray(values, dtype=np.float32)
    is_leaf = np.ones(len(k), dtype=bool)
    subtree = np.ones(len(k), dtype=np.int64)  # nodes in each node's pruned subtree
    for depth in range(TREE_DEPTH, 0, -1):
        parent = k >> 1
        code = (parent[:, 0] << 32) | (parent[:, 1] << 16) | parent[:, 2]
        uniq, first, inv = np.unique(code, return_index=True, return_inverse=True)
        m = len(uniq)
        n_children = np.bincount(inv, minlength=m)
        n_leaf_children = np.bincount(inv, weights=is_leaf, minlength=m)
        vmin = np.full(m, np.inf, dtype=np.float64)
        vmax = np.full(m, -np.inf, dtype=np.float64)
        np.minimum.at(vmin, inv, val)
        np.maximum.at(vmax, inv, val)
        collapse = (n_children == 8) & (n_leaf_children == 8) & (vmin == vmax)
        if depth == 1:
            collapse[:] = False  # the root is never pruned
        collapsed[depth - 1] = parent[first[collapse]]
        children_size = np.bincount(inv, weights=subtree, minlength=m).astype(np.int64)
        subtree = np.where(collapse, 1, 1 + children_size)
        k = parent[first]
        val = np.where(collapse, vmin, vmax).astype(np.float32)
        is_leaf = collapse
    return int(subtree.sum()), collapsed



def _known_leaves(occupancy_map: OccupancyMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The known cells: ((N, 3) grid indices, (N, 3) OctoMap keys, (N,) float32 log-odds)."""
    idx, values = occupancy_map.known_cells()
    return idx, idx + occupancy_map.index_offset + KEY_OFFSET, values


def octree_size(occupancy_map: OccupancyMap) -> int:
    """`OccupancyMap.octree_size`."""
    _, keys, values = _known_leaves(occupancy_map)
    return prune_plan(keys, values)[0]


def export_octomap(occupancy_map: OccupancyMap, path: str | Path) -> None:
    """`OccupancyMap.export_octomap`."""
    from pyoctomap import OcTree  # only the export needs it

    path = Path(path)
    if path.suffix not in (".ot", ".bt"):
        raise ValueError(f"export_octomap writes .ot or .bt files; got {path}")
    res = occupancy_map.resolution
    m = occupancy_map.occupancy_update
    tree = OcTree(res)
    tree.setProbHit(m.prob_hit)
    tree.setProbMiss(m.prob_miss)
    tree.setClampingThresMin(m.clamp_min)
    tree.setClampingThresMax(m.clamp_max)
    tree.setOccupancyThres(m.occupancy_threshold)
    idx, keys, values = _known_leaves(occupancy_map)
    centers = occupancy_map.cell_centers(idx)
    # One pyoctomap call per distinct log-odds value (a few dozen at most).
    uniq, inv, n_per_value = np.unique(values, return_inverse=True, return_counts=True)
    groups = np.split(centers[np.argsort(inv, kind="stable")], np.cumsum(n_per_value)[:-1])
    for value, group in zip(uniq, groups, strict=True):
        tree.updateNodes(group, float(value), lazy_eval=True)
    tree.updateInnerOccupancy()
    _, collapsed = prune_plan(keys, values)
    for depth in range(TREE_DEPTH - 1, 0, -1):
        for k in collapsed[depth]:
            corner = (k << (TREE_DEPTH - depth)) - KEY_OFFSET
            node = tree.search((corner + 0.5) * res, depth)
            if not tree.pruneNode(node):
                raise RuntimeError(f"pyoctomap refused to prune node {k} at depth {depth}")
    ok = tree.write(str(path)) if path.suffix == ".ot" else tree.writeBinary(str(path))
    if not ok:
        raise OSError(f"pyoctomap could not write {path}")
