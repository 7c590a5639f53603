"""UR5e IK poses per second: our closed form (all 8 branches) against Drake's InverseKinematics.

Targets are tool0 poses in `base` from random configurations within the joint limits (so all
are reachable). Ours runs vectorised over every target in one call, and one pose per call; Drake
solves position + orientation constraints (1 mm, 1 degree) from HOME on the first `--drake`
targets, building one InverseKinematics per target as a planner would. Targets: ours >= 1000
poses/s and >= 100x Drake's rate.

    .venv/bin/python benchmarks/bench_ik.py [--targets 10000] [--single 1000] [--drake 100]
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time

import numpy as np
from pydrake.math import RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.plant import MultibodyPlant
from pydrake.solvers import SnoptSolver, Solve

from lrnbv_drake.core.robot import kinematics as kin
from lrnbv_drake.station.resources import make_parser, package_url

POSITION_TOL = 1e-3
ANGLE_TOL = np.deg2rad(1.0)
# Solvers meet constraints to about 1e-6; allow that when checking their answers.
FEASIBILITY_SLACK = 1e-5


def _ours_ok(X: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(solved, recovered): some branch is ok; the source configuration is among them."""
    Q, ok = kin.inverse_kinematics(X)
    gap = np.abs(kin.wrap_to_pi(Q - q[:, None])).max(axis=-1)
    return ok.any(axis=-1), np.where(ok, gap, np.inf).min(axis=-1) < 1e-8


def _drake_solve(X: np.ndarray) -> tuple[float, float]:
    """(seconds, success rate) of Drake IK on targets X, seeded with HOME."""
    plant = MultibodyPlant(0.0)
    make_parser(plant).AddModels(url=package_url("ur5e/ur5e.urdf"))
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base_link"))
    plant.Finalize()
    base, tool0 = plant.GetFrameByName("base"), plant.GetFrameByName("tool0")
    snopt = SnoptSolver()
    successes = 0
    start = time.perf_counter()
    for X_target in X:
        ik = InverseKinematics(plant)
        p = X_target[:3, 3]
        ik.AddPositionConstraint(tool0, np.zeros(3), base, p - POSITION_TOL, p + POSITION_TOL)
        ik.AddOrientationConstraint(
            base, RotationMatrix(X_target[:3, :3]), tool0, RotationMatrix(), ANGLE_TOL
        )
        ik.prog().SetInitialGuess(ik.q(), kin.HOME)
        result = snopt.Solve(ik.prog()) if snopt.available() else Solve(ik.prog())
        if result.is_success():
            # Check the answer as the constraints define it: a box on position, an angle bound.
            X_q = kin.forward_kinematics(result.GetSolution(ik.q()))
            R_err = X_target[:3, :3].T @ X_q[:3, :3]
            angle = np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1.0, 1.0))
            in_box = np.abs(X_q[:3, 3] - p).max() <= POSITION_TOL + FEASIBILITY_SLACK
            successes += in_box and angle <= ANGLE_TOL + FEASIBILITY_SLACK
    return time.perf_counter() - start, successes / len(X)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=10_000, help="targets for the batch call")
    parser.add_argument("--single", type=int, default=1000, help="targets solved one per call")
    parser.add_argument("--drake", type=int, default=100, help="targets given to Drake")
    parser.add_argument("--repeats", type=int, default=5, help="batch calls timed (best kept)")
    args = parser.parse_args()

    q = np.random.default_rng(0).uniform(kin.JOINT_LOWER, kin.JOINT_UPPER, (args.targets, 6))
    X = kin.forward_kinematics(q)

    batch_s = np.inf
    for _ in range(args.repeats):
        start = time.perf_counter()
        kin.inverse_kinematics(X)
        batch_s = min(batch_s, time.perf_counter() - start)
    solved, recovered = _ours_ok(X, q)

    start = time.perf_counter()
    for X_target in X[: args.single]:
        kin.inverse_kinematics(X_target)
    single_s = time.perf_counter() - start

    drake_s, drake_success = _drake_solve(X[: args.drake])

    batch_rate = args.targets / batch_s
    single_rate = args.single / single_s
    drake_rate = args.drake / drake_s
    solver = "SNOPT" if SnoptSolver().available() else "default solver"
    print(f"$ {shlex.join([os.path.relpath(sys.executable), *sys.argv])}")
    print(
        f"UR5e IK, {args.targets} reachable tool0 targets from random joint positions (seed 0), "
        f"{os.cpu_count()} cores"
    )
    print(
        f"  ours, vectorised ({args.targets} poses/call, best of {args.repeats}): "
        f"{batch_rate:10.0f} poses/s  success {100 * solved.mean():5.1f}%  "
        f"source configuration among the 8 branches {100 * recovered.mean():5.1f}%"
    )
    print(f"  ours, one pose per call ({args.single} poses):        {single_rate:10.0f} poses/s")
    print(
        f"  Drake InverseKinematics + {solver}, seed HOME ({args.drake} poses, 1 mm / 1 deg): "
        f"{drake_rate:8.1f} poses/s  success {100 * drake_success:5.1f}%"
    )
    print(
        f"  speed ratio vs Drake: vectorised {batch_rate / drake_rate:8.0f}x, "
        f"one per call {single_rate / drake_rate:6.0f}x   target >= 100x"
    )
    met = min(batch_rate, single_rate) >= 1000 and batch_rate / drake_rate >= 100
    print(
        f"  targets (>= 1000 poses/s both ways, vectorised >= 100x Drake): "
        f"{'met' if met else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
