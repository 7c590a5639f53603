"""OctoMap's key layout, shared by the kernels, the map and the export: a cell's OctoMap key is
its global index plus KEY_OFFSET on each axis."""

#: OctoMap's key offset (tree_max_val for a 16-level tree): key = cell index + KEY_OFFSET.
KEY_OFFSET = 32768
#: OctoMap's number of tree levels below the root.
TREE_DEPTH = 16
