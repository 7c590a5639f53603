"""Recorded episodes copied with their readings perturbed, to replay with
`replay_stop_rules.py`: how far a small change of the readings moves the estimate on the same
views. `--bias` adds one fixed range offset per zone, the same in every frame of every
episode (the real frames' per-zone offsets, about 3 mm rms after a plane is removed:
`../shared/notes/vl53l8cx-behaviour.md` section 9; the simulated device's unit of that seed,
`tof_device.zone_offsets_mm`); `--noise` adds an independent normal
draw to every reading (the control: as large a change, not fixed). Invalid zones stay
invalid; readings stay whole millimetres. Record 0033.

    .venv/bin/python benchmarks/perturbed_readings.py --bias 3 --out /tmp/bias3 \
        out/results/paper/runs/lrnbv__*
    .venv/bin/python benchmarks/replay_stop_rules.py --rules box /tmp/bias3/paper/runs/* > b.jsonl
    .venv/bin/python benchmarks/replay_stop_rules.py --summary b.jsonl
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np

from lrnbv_drake.core.sensing.tof_device import DeviceBehaviour, zone_offsets_mm


def perturbed(distance_mm: np.ndarray, offset_mm: np.ndarray) -> np.ndarray:
    """`distance_mm` (frames, 8, 8) with `offset_mm` (broadcast to it) added where a zone
    read something (> 0), rounded to whole millimetres and kept above zero."""
    d = distance_mm.astype(float)
    return np.where(d > 0, np.maximum(np.rint(d + offset_mm), 1), 0).astype(distance_mm.dtype)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    kind = parser.add_mutually_exclusive_group(required=True)
    kind.add_argument("--bias", type=float, help="rms of the fixed per-zone offsets, mm")
    kind.add_argument("--noise", type=float, help="sigma of the independent noise, mm")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, required=True,
                        help="written as OUT/<campaign>/runs/<episode>")
    parser.add_argument("folders", nargs="+", type=Path,
                        help="episode folders, <campaign>/runs/<episode>")
    args = parser.parse_args()
    bias = zone_offsets_mm(DeviceBehaviour(zone_offset_mm=args.bias or 0.0,
                                           zone_offset_seed=args.seed), 8)
    for i, folder in enumerate(args.folders):
        target = args.out / folder.parent.parent.name / "runs" / folder.name
        shutil.copytree(folder, target, dirs_exist_ok=True)
        frames = dict(np.load(folder / "frames.npz"))
        distance = frames["distance_mm"]
        offset = (bias if args.bias is not None else
                  np.random.default_rng([args.seed, i]).normal(0.0, args.noise, distance.shape))
        frames["distance_mm"] = perturbed(distance, offset)
        np.savez(target / "frames.npz", **frames)
    print(f"{len(args.folders)} episodes written under {args.out}")


if __name__ == "__main__":
    main()
