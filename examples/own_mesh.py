"""Reconstruct your own object: any OBJ, STL or PLY mesh, scaled and placed on the table.

    .venv/bin/python examples/own_mesh.py path/to/part.stl 0.001

Without arguments it makes a 12 x 8 x 5 cm part (in millimetres) with trimesh and uses that.
The same from the command line:

    .venv/bin/lrnbv run --object part.stl --object-scale 0.001 --object-pose 0.5,0.02,25 --out out

Most CAD exports are in millimetres: the scale 0.001 turns them into metres. `check_placement`
refuses a mesh whose size or place the cell cannot handle before anything runs, and says why
(a 120 m part read in the wrong units, an object outside the mapped volume), as `lrnbv run`
does.
"""

import sys
import tempfile
from pathlib import Path

import trimesh

from lrnbv_drake.experiments.episode import run_episode
from lrnbv_drake.station.scenario import Scenario, ScenarioError
from lrnbv_drake.station.scenario_checks import check_placement

if len(sys.argv) > 1:
    mesh_path, scale = sys.argv[1], float(sys.argv[2]) if len(sys.argv) > 2 else 1.0
else:
    mesh_path = str(Path(tempfile.mkdtemp()) / "part.stl")
    trimesh.creation.box(extents=(120.0, 80.0, 50.0)).export(mesh_path)
    scale = 0.001

scenario = Scenario(seed=1)
scenario.object.name = mesh_path
scenario.object.scale = scale
scenario.object.x, scenario.object.y, scenario.object.yaw_deg = 0.5, 0.02, 25.0
try:
    check_placement(scenario)
except ScenarioError as e:
    sys.exit(f"own_mesh.py: {e}")
report = run_episode(scenario, "lrnbv", "out/example_own_mesh").report
m = report["metrics"]
if not m["box_found"]:
    sys.exit(f"no object found: {report['extraction']}")
est, true = (" x ".join(f"{1000 * v:.0f}" for v in m[k]) for k in ("estimated_dims", "true_dims"))
print(f"{report['n_poses']} poses, IoU {m['iou']:.3f}, estimated {est} mm, true {true} mm")
