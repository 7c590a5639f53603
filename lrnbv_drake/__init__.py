"""LR-NBV: low-resolution next-best-view perception for robot packing, on Drake."""
