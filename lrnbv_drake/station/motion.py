"""Moving the sensor to a pose: analytic IK, collision checks in SceneGraph, a limited trajectory.

For a target sensor pose the planner takes every IK branch of the pose and of the pose rolled
about the sensor's optical axis by the allowed steps (`robot.sensor_roll_step_deg`: the same
view, its square grid of zones in another order) whose configuration is collision free
(robot against table, object and itself, with padding), and to each the straight joint-space
path, a detour over the object and the path through the home configuration. Of these it keeps
the quickest whose every segment is collision free and keeps the sensor inside the workspace
all along (the hardware's safety limits refuse any command that leaves it): a straight path
to another branch is often quicker than a detour to the nearest. The result is a typed
`MotionPlan`: a failure says why and never raises, so an episode can try another viewpoint.

Trajectories are synchronised trapezoidal velocity profiles through the waypoints (stopping at
each), represented exactly as a cubic-Hermite `PiecewisePolynomial` (a quadratic is a cubic).
"""

from __future__ import annotations

import itertools
import logging
import math

import numpy as np
from pydrake.planning import SceneGraphCollisionChecker
from pydrake.trajectories import PiecewisePolynomial

from lrnbv_drake.core.robot import kinematics
from lrnbv_drake.core.robot.motion import MotionFailure, MotionPlan
from lrnbv_drake.core.robot.poses import look_at
from lrnbv_drake.core.robot.sure_collision import (
    COLLIDES,
    FREE,
    UNSETTLED,
    first_unrejected,
    settle,
)
from lrnbv_drake.core.sensing.sensor import ROLL_STEPS_DEG, ROLL_STEPS_TEXT
from lrnbv_drake.station.arm_balls import build_arm_balls, build_outer_balls
from lrnbv_drake.station.cell_models import add_cell_models, fixed_pose, sensor_on_tool0
from lrnbv_drake.station.resources import make_robot_diagram_builder
from lrnbv_drake.station.scenario import Scenario

_log = logging.getLogger(__name__)

#: Model instances that move with the arm (the sensor mount is welded to tool0).
ROBOT_MODEL_NAMES = ("ur5e", "tof_mount")


def trapezoidal_trajectory(waypoints: np.ndarray, max_velocity: np.ndarray,
                           max_acceleration: np.ndarray, start_time: float = 0.0
                           ) -> PiecewisePolynomial:
    """Joint trajectory through `waypoints` (n, 6), stopping at each, with every joint within
    its velocity and acceleration limits and all joints arriving together on each segment.

    Each segment scales one path parameter s in [0, 1] with the trapezoid (or triangle) that the
    most limiting joint allows; other joints follow proportionally.
    """
    waypoints = np.atleast_2d(np.asarray(waypoints, float))
    breaks, q_knots, v_knots = [start_time], [waypoints[0]], [np.zeros(waypoints.shape[1])]
    t = start_time
    for q0, q1 in itertools.pairwise(waypoints):
        dq = q1 - q0
        moving = np.abs(dq) > 1e-12
        if not moving.any():
            continue
        s_vel = np.min(max_velocity[moving] / np.abs(dq[moving]))
        s_acc = np.min(max_acceleration[moving] / np.abs(dq[moving]))
        t_acc = s_vel / s_acc
        # Triangle: the peak speed is never reached. Within 1e-9 of it the cruise would last
        # ~1e-16 s, a break that does not increase once added to a later start time.
        if s_vel * t_acc >= 1.0 - 1e-9:
            t_acc = np.sqrt(1.0 / s_acc)
            s_peak = s_acc * t_acc
            knots = [(t_acc, 0.5, s_peak), (2 * t_acc, 1.0, 0.0)]
        else:
            s_ramp = 0.5 * s_vel * t_acc
            t_cruise = (1.0 - 2 * s_ramp) / s_vel
            knots = [(t_acc, s_ramp, s_vel), (t_acc + t_cruise, 1.0 - s_ramp, s_vel),
                     (2 * t_acc + t_cruise, 1.0, 0.0)]
        for dt, s, s_dot in knots:
            breaks.append(t + dt)
            q_knots.append(q0 + s * dq)
            v_knots.append(s_dot * dq)
        t = breaks[-1]
    if len(breaks) == 1:  # no motion at all: hold the position for an instant
        breaks.append(start_time + 1e-3)
        q_knots.append(waypoints[0])
        v_knots.append(np.zeros(waypoints.shape[1]))
    return PiecewisePolynomial.CubicHermite(np.array(breaks), np.column_stack(q_knots),
                                            np.column_stack(v_knots))


def halted(trajectory: PiecewisePolynomial, t: float, max_acceleration: np.ndarray
           ) -> PiecewisePolynomial:
    """`trajectory` from time t brought to rest as soon as the joints' accelerations allow.

    Every joint decelerates uniformly over the same time, so the arm stays on the line in
    joint space it was moving along: a segment of `trapezoidal_trajectory`'s, whose every
    point was checked for collisions. The trapezoid's own braking is the limiting joint's at
    its limit, the same rate as this one's, so the arm stops no later on the segment than the
    trapezoid would have (before its end)."""
    t = min(max(t, trajectory.start_time()), trajectory.end_time())
    q = np.asarray(trajectory.value(t), float).ravel()
    v = np.asarray(trajectory.EvalDerivative(t, 1), float).ravel()
    duration = float(np.max(np.abs(v) / max_acceleration))
    if duration < 1e-9:  # at rest already: hold for an instant
        return PiecewisePolynomial.CubicHermite(np.array([t, t + 1e-3]), np.column_stack([q, q]),
                                                np.zeros((q.size, 2)))
    return PiecewisePolynomial.CubicHermite(np.array([t, t + duration]),
                                            np.column_stack([q, q + 0.5 * duration * v]),
                                            np.column_stack([v, np.zeros_like(v)]))


def _roll(angle: float) -> np.ndarray:
    """X_S_S' (4x4): a rotation by `angle` about the sensor's optical axis (z)."""
    c, s = math.cos(angle), math.sin(angle)
    X = np.eye(4)
    X[:2, :2] = [[c, -s], [s, c]]
    return X


class MotionPlanner:
    """Plans collision-free, limited motions of the sensor for one scenario's cell."""

    def __init__(self, scenario: Scenario, bare_table: bool = False):
        """`bare_table`: plan around the cell without its object (commissioning)."""
        builder = make_robot_diagram_builder()
        # Kept: its meshes' files must outlive the checker's reads of them (the outer balls').
        self._cell = add_cell_models(builder.plant(), scenario, bare_table=bare_table)
        plant = builder.plant()
        plant.Finalize()
        self._model = builder.Build()
        robot = [plant.GetModelInstanceByName(n) for n in ROBOT_MODEL_NAMES
                 if plant.HasModelInstanceNamed(n)]
        # Drake says at INFO how many contexts it allocates, on every construction: to a
        # user of the Python API that is noise, so this one call logs warnings only.
        drake_log = logging.getLogger("drake")
        level = drake_log.level
        drake_log.setLevel(max(drake_log.getEffectiveLevel(), logging.WARNING))
        try:
            self._checker = SceneGraphCollisionChecker(
                model=self._model,
                robot_model_instances=robot,
                edge_step_size=scenario.robot.collision_check_step,
                env_collision_padding=scenario.robot.collision_padding,
                self_collision_padding=0.0,
            )
        finally:
            drake_log.setLevel(level)
        self.X_W_base = fixed_pose(plant, "world", "base").GetAsMatrix4()
        # Balls inside the arm's geometry reject most colliding configurations, balls holding
        # it pass most free ones, in microseconds before the exact check
        # (core/robot/sure_collision.py).
        self._balls = build_arm_balls(self._checker, self.X_W_base)
        self._outer_balls = build_outer_balls(self._checker, self.X_W_base)
        if self._outer_balls is None:
            _log.warning("MotionPlanner: a collision shape no ball or box can hold; every "
                         "configuration the inner balls do not reject goes to SceneGraph")
        self.X_tool0_S = sensor_on_tool0(plant, scenario).GetAsMatrix4()
        self._X_base_W = np.linalg.inv(self.X_W_base)
        self._X_S_tool0 = np.linalg.inv(self.X_tool0_S)
        self.workspace = (np.asarray(scenario.cell.workspace_lower, float),
                          np.asarray(scenario.cell.workspace_upper, float))
        self.max_velocity = kinematics.VELOCITY_LIMIT * scenario.robot.speed_fraction
        self.max_acceleration = kinematics.ACCELERATION_LIMIT * \
            scenario.robot.acceleration_fraction
        self.home = kinematics.HOME.copy()
        # The rolls about the optical axis a view may take (`robot.sensor_roll_step_deg`):
        # only the square grid's symmetries, or a rolled view would see other directions.
        step = scenario.robot.sensor_roll_step_deg
        if step not in ROLL_STEPS_DEG:
            raise ValueError(f"robot.sensor_roll_step_deg: expected {ROLL_STEPS_TEXT}, got "
                             f"{step!r}")
        self._rolls = np.stack([_roll(math.radians(a)) for a in
                                (np.arange(0.0, 360.0, step) if step > 0 else [0.0])])
        self._path_step = scenario.robot.collision_check_step
        # Height of the sensor over the table on a detour over the object (`_detours`).
        self._over_height = scenario.cell.table_height + 0.45
        # The arm's collision geometry, for `near_robot` (the self filter). Not the sensor's
        # mount: its front face is the sensor's, so every reading under the padding would be
        # "robot".
        self._context = self._model.CreateDefaultContext()
        arm = plant.GetModelInstanceByName("ur5e")
        self._arm_geometries = {g for body in plant.GetBodyIndices(arm)
                                for g in plant.GetCollisionGeometriesForBody(plant.get_body(body))}

    def travel_time(self, q: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """Seconds the direct synchronised trapezoid from joints q takes to each of the
        configurations Q (n, 6): the duration `trapezoidal_trajectory` gives a straight move
        (a path through home takes longer)."""
        dq = np.abs(np.atleast_2d(np.asarray(Q, float)) - np.asarray(q, float))
        with np.errstate(divide="ignore", invalid="ignore"):  # dq = 0: no motion, 0 s
            s_vel = np.min(self.max_velocity / dq, axis=1)
            s_acc = np.min(self.max_acceleration / dq, axis=1)
            t_acc = s_vel / s_acc
            t = np.where(s_vel * t_acc >= 1.0, 2 * np.sqrt(1.0 / s_acc), t_acc + 1.0 / s_vel)
        return np.where(np.isfinite(s_vel), t, 0.0)

    def sensor_pose(self, q: np.ndarray) -> np.ndarray:
        """X_WS (4x4) for joint positions q, from the analytic forward kinematics."""
        return kinematics.sensor_pose(q, self.X_W_base, self.X_tool0_S)

    def collision_free(self, q: np.ndarray) -> bool:
        """Whether configuration q keeps the robot clear of the cell and of itself."""
        q = np.asarray(q, float)
        settled = settle(q, self.X_W_base, self._balls, self._outer_balls)[0]
        if settled != UNSETTLED:
            return bool(settled == FREE)
        return bool(self._checker.CheckConfigCollisionFree(q))

    def first_free(self, Q: np.ndarray) -> int:
        """The index of the first collision-free configuration of Q (k, 6), -1 if none: what
        `collision_free` on each in turn finds, the balls' part in one kernel call."""
        Q = np.asarray(Q, float).reshape(-1, 6)
        start = 0
        while True:
            i, settled = first_unrejected(Q[start:], self.X_W_base, self._balls,
                                          self._outer_balls)
            if settled == COLLIDES:
                return -1
            if settled == FREE or self._checker.CheckConfigCollisionFree(Q[start + i]):
                return start + i
            start += i + 1

    def near_robot(self, q: np.ndarray, points: np.ndarray, padding: float) -> np.ndarray:
        """(n,) bool: which world points (n, 3) lie within `padding` of the arm's collision
        geometry (or inside it) at joints q: readings of the arm itself (core/robot/self_filter.py).
        Not safe to call from two threads at once (one context)."""
        plant, scene_graph = self._model.plant(), self._model.scene_graph()
        plant.SetPositions(plant.GetMyMutableContextFromRoot(self._context), np.asarray(q, float))
        query = scene_graph.get_query_output_port().Eval(
            scene_graph.GetMyContextFromRoot(self._context))
        return np.array([any(d.id_G in self._arm_geometries
                             for d in query.ComputeSignedDistanceToPoint(p, padding))
                         for p in np.asarray(points, float).reshape(-1, 3)], bool)

    def ik_batch(self, X_WS: np.ndarray, q_current: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The IK solutions of many sensor poses (N, 4, 4) in one call: (Q, n), pose i's n[i]
        solutions (as `ik` gives them) in Q[i, :n[i]], Q (N, 8 r, 6) for the r rolls the
        sensor may take about its optical axis (`robot.sensor_roll_step_deg`). Arrays, not a
        list of N arrays: the planner reads the solutions of only the few views it tries."""
        X_WS = np.asarray(X_WS, float).reshape(-1, 4, 4)
        X_base_tool0 = self._X_base_W @ (X_WS[:, None] @ self._rolls) @ self._X_S_tool0
        Q, ok = kinematics.inverse_kinematics(X_base_tool0.reshape(-1, 4, 4))
        per_pose = Q.shape[1] * len(self._rolls)
        return kinematics.ranked_solutions(Q.reshape(len(X_WS), per_pose, 6),
                                           ok.reshape(len(X_WS), per_pose), q_current,
                                           self.max_velocity)

    def ik(self, X_WS: np.ndarray, q_current: np.ndarray) -> np.ndarray:
        """All IK solutions for sensor pose X_WS and its allowed rolls about the optical axis,
        each joint at its 2-pi equivalent nearest q_current, sorted by the time the slowest
        joint needs (nearest first). Shape (k, 6)."""
        Q, n = self.ik_batch(X_WS, np.asarray(q_current, float))
        return Q[0, :n[0]]

    def plan(self, q_current: np.ndarray, X_WS: np.ndarray, start_time: float = 0.0
             ) -> MotionPlan:
        """Plans a motion from joints `q_current` to sensor pose `X_WS` (4x4), or to it rolled
        about the optical axis by an allowed step where that is the nearer configuration."""
        q_current = np.asarray(q_current, float)
        p = np.asarray(X_WS)[:3, 3]
        lower, upper = self.workspace
        if np.any(p < lower) or np.any(p > upper):
            return MotionPlan(MotionFailure.OUTSIDE_WORKSPACE,
                              f"sensor position {np.round(p, 3).tolist()} is outside the "
                              f"workspace {lower.tolist()} .. {upper.tolist()}")
        candidates = self.ik(X_WS, q_current)
        if len(candidates) == 0:
            return MotionPlan(MotionFailure.UNREACHABLE,
                              f"no IK solution within joint limits for sensor position "
                              f"{np.round(p, 3).tolist()}")
        free = [q for q in candidates if self.collision_free(q)]
        if not free:
            return MotionPlan(MotionFailure.TARGET_IN_COLLISION,
                              f"all {len(candidates)} IK solutions collide with the cell or "
                              f"the robot itself")
        via = self._detours(q_current, p)
        free = np.array(free)
        # (len(free), 1 + len(via)): the straight path's duration to each branch, then the
        # path's through each via point, stopping there.
        to_via = self.travel_time(q_current, np.array(via))
        durations = np.column_stack([self.travel_time(q_current, free),
                                     *(t + self.travel_time(v, free)
                                       for t, v in zip(to_via, via, strict=True))])
        first_leg_clear = {}  # a via point's first leg, the same for every branch
        leaves_workspace = 0
        for flat in np.argsort(durations, axis=None, kind="stable"):
            j, route = divmod(int(flat), durations.shape[1])
            if route == 0:
                waypoints = np.array([q_current, free[j]])
                clear = self._checker.CheckEdgeCollisionFree(q_current, free[j])
            else:
                v = via[route - 1]
                waypoints = np.array([q_current, v, free[j]])
                if route not in first_leg_clear:
                    first_leg_clear[route] = self._checker.CheckEdgeCollisionFree(q_current, v)
                clear = (first_leg_clear[route]
                         and self._checker.CheckEdgeCollisionFree(v, free[j]))
            if not clear:
                continue
            if not self.path_in_workspace(waypoints):
                leaves_workspace += 1
                continue
            trajectory = trapezoidal_trajectory(waypoints, self.max_velocity,
                                                self.max_acceleration, start_time)
            return MotionPlan(None, "ok", q_target=free[j], trajectory=trajectory)
        if leaves_workspace:
            return MotionPlan(MotionFailure.PATH_OUTSIDE_WORKSPACE,
                              f"{len(free)} collision-free IK solutions, but every "
                              f"collision-free joint-space path to them (direct or through "
                              f"home) takes the sensor outside the workspace")
        return MotionPlan(MotionFailure.PATH_IN_COLLISION,
                          f"{len(free)} collision-free IK solutions, but every joint-space "
                          f"path to them (direct or through home) collides")

    def halt(self, trajectory: PiecewisePolynomial, t: float) -> PiecewisePolynomial:
        """`trajectory` brought to rest from time t on its path (`halted`)."""
        return halted(trajectory, t, self.max_acceleration)

    def _detours(self, q_current: np.ndarray, target: np.ndarray) -> list[np.ndarray]:
        """Configurations to pass through around whatever lies between the sensor at
        q_current and `target` (a position): over it, the sensor looking down 0.45 m above
        the table midway between the two, and home. Between two low views on
        either side of the object the straight joint path sweeps the sensor through the
        object: through home such moves took 9.4-10.0 s, over it 3.4-3.8 s (three of the ten
        moves of `make run`)."""
        middle = (self.sensor_pose(q_current)[:3, 3] + target) / 2
        over = look_at(np.array([middle[0], middle[1], self._over_height]),
                       np.array([middle[0], middle[1], self._over_height - 1.0]))
        return [*self.ik(over, q_current)[:1], self.home]

    def path_in_workspace(self, waypoints: np.ndarray) -> bool:
        """Whether the sensor stays inside the workspace along the straight joint-space
        segments through `waypoints` (n, 6), sampled every `collision_check_step` rad of the
        largest joint motion (the same resolution as the collision checks)."""
        lower, upper = self.workspace
        for a, b in itertools.pairwise(np.asarray(waypoints, float)):
            n = max(2, int(np.ceil(np.max(np.abs(b - a)) / self._path_step)) + 1)
            s = np.linspace(0.0, 1.0, n)[:, None]
            p = self.sensor_pose(a + s * (b - a))[:, :3, 3]
            if np.any(p < lower) or np.any(p > upper):
                return False
        return True
