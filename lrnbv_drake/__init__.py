"""LR-NBV: low-resolution next-best-view perception for robot packing, on Drake."""

from lrnbv_drake.numba_cache import use_versioned_cache

use_versioned_cache()
