"""UR5e kinematics as plain numpy: constants, forward kinematics and the closed-form inverse.

No Drake here, so the planner can rank hundreds of candidate views per iteration in
milliseconds; `tests/test_kinematics.py` checks every number against the MultibodyPlant built
from `models/ur5e/ur5e.urdf` (which `models/ur5e/make_urdf.py` generates from these constants).

Frames (those of the ROS2 `ur_description`, which the URDF reproduces):
- `base_link` is REP-103 aligned (x forward, z up): the frame the cell welds to the table.
  `base` = `base_link` * Rz(pi) is the controller's "Base" frame, the one the teach pendant
  and `getActualTCPPose()` report in, and the DH frame 0.
- `tool0` is the tool flange with UR's tool axes (z out of the flange), the teach pendant's TCP
  with a zero TCP offset and the DH frame 6 (it coincides with `wrist_3_link`). `flange` is the
  same point with ROS-Industrial axes (x out of the flange): `flange` = `tool0` * Rz(-pi/2) *
  Ry(-pi/2). Mount end effectors on `tool0`.
Every transform here is `tool0` expressed in `base` (X_base_tool0), in metres.

The inverse follows the standard analytic solution for UR arms (Hawkins 2013, "Analytic
Inverse Kinematics for the Universal Robots UR-5/UR-10 Arms"), vectorised over targets.
"""

from __future__ import annotations

import numpy as np

#: Standard DH parameters of the UR5e (Universal Robots, "DH parameters for calculations of
#: kinematics and dynamics"), metres and radians. UR's "a" is the common-normal length.
DH_D = np.array([0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996])
DH_A = np.array([0.0, -0.425, -0.3922, 0.0, 0.0, 0.0])
DH_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])

JOINT_NAMES: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
#: Position limits, rad: +-360 deg on every joint (UR5e manual), except the elbow, which ROS
#: limits to +-180 deg because the arm's own structure stops it there.
JOINT_UPPER = np.array([2 * np.pi, 2 * np.pi, np.pi, 2 * np.pi, 2 * np.pi, 2 * np.pi])
JOINT_LOWER = -JOINT_UPPER
#: Maximum joint speed, rad/s (180 deg/s on every UR5e joint).
VELOCITY_LIMIT = np.full(6, np.pi)
#: Joint acceleration limit, rad/s^2. UR publishes none (the controller limits torque); this is
#: the ROS description's placeholder of 180 deg/s^2, to be tuned before it matters.
ACCELERATION_LIMIT = np.full(6, np.pi)
#: Maximum joint torque, N m (UR "max joint torques": size 3 joints 150, size 1 joints 28).
EFFORT_LIMIT = np.array([150.0, 150.0, 150.0, 28.0, 28.0, 28.0])
#: Upright "home": upper arm vertical, forearm horizontal, tool pointing down.
HOME = np.array([0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])

for _array in (DH_D, DH_A, DH_ALPHA, JOINT_UPPER, JOINT_LOWER, VELOCITY_LIMIT,
               ACCELERATION_LIMIT, EFFORT_LIMIT, HOME):
    _array.setflags(write=False)

# Below this |sin(q5)| the wrist is singular (joints 4 and 6 aligned) and q6 is free.
_WRIST_SINGULAR_SIN = 1e-10


def _dh(theta: np.ndarray, i: int) -> np.ndarray:
    """(..., 4, 4) DH transform of joint i (0-based): Rz(theta) Tz(d) Tx(a) Rx(alpha)."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(DH_ALPHA[i]), np.sin(DH_ALPHA[i])
    T = np.zeros((*np.shape(theta), 4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2], T[..., 0, 3] = ct, -st * ca, st * sa, DH_A[i] * ct
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st, ct * ca, -ct * sa, DH_A[i] * st
    T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa, ca, DH_D[i]
    T[..., 3, 3] = 1.0
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms."""
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def wrap_to_pi(q: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(q) + np.pi) % (2 * np.pi) - np.pi


def forward_kinematics(q: np.ndarray) -> np.ndarray:
    """X_base_tool0 for joint positions q.

    Args:
        q: (..., 6) joint positions, rad, in `JOINT_NAMES` order.

    Returns:
        (..., 4, 4) homogeneous transforms of `tool0` in `base` (the teach pendant's TCP pose
        with a zero TCP offset).
    """
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (6,):
        raise ValueError(f"q must have shape (..., 6); got {q.shape}")
    X = _dh(q[..., 0], 0)
    for i in range(1, 6):
        X = X @ _dh(q[..., i], i)
    return X



def sensor_pose(q: np.ndarray, X_W_base: np.ndarray, X_tool0_S: np.ndarray) -> np.ndarray:
    """X_WS (..., 4, 4): the sensor in world for joints q (..., 6), with the controller's
    `base` at X_W_base and the sensor at X_tool0_S on the flange. The one place the sensor
    pose follows from the joints: the cell's `tof.pose`, the motion planner and the safety
    checks all call it."""
    return X_W_base @ forward_kinematics(np.asarray(q, float)) @ X_tool0_S

def inverse_kinematics(
    X: np.ndarray,
    *,
    q6_singular: float | np.ndarray = 0.0,
    lower: np.ndarray = JOINT_LOWER,
    upper: np.ndarray = JOINT_UPPER,
    tol: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """All closed-form solutions for X_base_tool0 targets, vectorised over targets.

    Branch k = 4 * shoulder + 2 * wrist + elbow, each bit picking a sign: shoulder 0 takes
    q1 = phi + asin(d4 / r) and 1 takes q1 = phi + pi - asin(d4 / r) (phi, r: polar angle and
    radius of the wrist centre); wrist 0 gives q5 >= 0 and 1 gives q5 <= 0; elbow 0 gives
    q3 >= 0 and 1 gives q3 <= 0.

    At the wrist singularity (sin q5 ~ 0, joints 4 and 6 aligned) only q4 + q6 is determined:
    q6 is set to `q6_singular` (pass the current q6 to keep the wrist still) and q4 takes the
    rest. Unreachable targets, and branches that do not exist, are simply not ok.

    Args:
        X: (..., 4, 4) targets, `tool0` in `base`.
        q6_singular: q6 to use at the wrist singularity; scalar or broadcastable to X[..., 0, 0].
        lower, upper: (6,) joint limits a solution must respect (the UR5e's by default).
        tol: a branch is ok only if its forward kinematics reproduces the target to within tol
            (metres for position, radians for orientation).

    Returns:
        (Q, ok): Q (..., 8, 6) joint positions wrapped to [-pi, pi), and ok (..., 8) bool.
        Rows that are not ok are zero-filled, never NaN.
    """
    X = np.asarray(X, dtype=float)
    if X.shape[-2:] != (4, 4):
        raise ValueError(f"X must have shape (..., 4, 4); got {X.shape}")
    batch = X.shape[:-2]
    X = X.reshape(-1, 4, 4)
    n = X.shape[0]
    q6_hint = np.broadcast_to(np.asarray(q6_singular, dtype=float), batch).reshape(n)
    d4, d6 = DH_D[3], DH_D[5]
    a2, a3 = DH_A[1], DH_A[2]
    R, p = X[:, :3, :3], X[:, :3, 3]

    with np.errstate(divide="ignore", invalid="ignore"):
        # q1: the wrist centre p5 must sit d4 along joint 2's axis z1 = (s1, -c1, 0).
        p5 = p - d6 * R[:, :, 2]
        r = np.hypot(p5[:, 0], p5[:, 1])
        psi = np.arcsin(np.clip(d4 / r, -1.0, 1.0))
        q1 = np.arctan2(p5[:, 1], p5[:, 0])[:, None] + np.stack([psi, np.pi - psi], axis=1)
        z1 = np.stack([np.sin(q1), -np.cos(q1), np.zeros_like(q1)], axis=-1)  # (n, 2, 3)

        # z1 seen from tool0 is (s5 c6, -s5 s6, c5): gives q5 (two signs) and q6.
        v = np.einsum("nij,nbi->nbj", R, z1)  # (n, 2, 3)
        s5_abs = np.hypot(v[..., 0], v[..., 1])
        sign = np.array([1.0, -1.0])
        q5 = sign * np.arctan2(s5_abs, v[..., 2])[..., None]  # (n, 2, 2)
        q6 = np.arctan2(-sign * v[..., 1, None], sign * v[..., 0, None])
        q6 = np.where(s5_abs[..., None] < _WRIST_SINGULAR_SIN, q6_hint[:, None, None], q6)

        # Joints 2-4 form a planar 3R arm in frame 1: frame 4 in frame 1 gives the rest.
        T01 = _dh(q1, 0)[:, :, None]
        T14 = _inv(T01) @ X[:, None, None] @ _inv(_dh(q6, 5)) @ _inv(_dh(q5, 4))
        px, py = T14[..., 0, 3], T14[..., 1, 3]
        q234 = np.arctan2(T14[..., 1, 0], T14[..., 0, 0])
        c3 = np.clip((px**2 + py**2 - a2**2 - a3**2) / (2 * a2 * a3), -1.0, 1.0)
        q3 = sign * np.arccos(c3)[..., None]  # (n, 2, 2, 2)
        q2 = np.arctan2(py, px)[..., None] - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3))
        q4 = q234[..., None] - q2 - q3

        shape = (n, 2, 2, 2)
        Q = np.stack(
            [np.broadcast_to(q1[:, :, None, None], shape), q2, q3, q4,
             np.broadcast_to(q5[..., None], shape), np.broadcast_to(q6[..., None], shape)],
            axis=-1,
        ).reshape(n, 8, 6)
        Q = wrap_to_pi(Q)

        Xq = forward_kinematics(Q)
        pos_err = np.linalg.norm(Xq[..., :3, 3] - p[:, None], axis=-1)
        # Frobenius distance / sqrt(2) ~ rotation angle for small errors.
        rot_err = np.linalg.norm(Xq[..., :3, :3] - R[:, None], axis=(-2, -1)) / np.sqrt(2)
        ok = (
            (pos_err <= tol)
            & (rot_err <= tol)
            & np.all((Q >= lower) & (Q <= upper), axis=-1)
            & np.all(np.isfinite(Q), axis=-1)
        )
    Q = np.where(ok[..., None], Q, 0.0)
    return Q.reshape(*batch, 8, 6), ok.reshape(*batch, 8)


def nearest_equivalents(
    Q: np.ndarray,
    q_current: np.ndarray,
    *,
    lower: np.ndarray = JOINT_LOWER,
    upper: np.ndarray = JOINT_UPPER,
) -> np.ndarray:
    """Q with each joint moved by the multiple of 2 pi that brings it nearest q_current while
    staying within [lower, upper]: a joint with +-2 pi limits takes the short way round, the
    elbow (+-pi) never does.

    Args:
        Q: (..., 6) joint positions within the limits, e.g. IK solutions, all (..., 8, 6) or
            the (k, 6) ok ones.
        q_current: (6,) current joint positions, or anything broadcastable against Q.

    Returns:
        An array of Q's shape.
    """
    Q = np.asarray(Q, dtype=float)
    q_current = np.asarray(q_current, dtype=float)
    two_pi = 2 * np.pi
    k_lo = np.ceil((lower - Q) / two_pi)
    k_hi = np.floor((upper - Q) / two_pi)
    # |Q + 2 pi k - q| is convex in k: clipping the unconstrained best k is the constrained best.
    k = np.clip(np.round((q_current - Q) / two_pi), k_lo, k_hi)
    return np.clip(Q + two_pi * k, lower, upper)


def closest_solution(
    Q: np.ndarray,
    ok: np.ndarray,
    q_current: np.ndarray,
    *,
    lower: np.ndarray = JOINT_LOWER,
    upper: np.ndarray = JOINT_UPPER,
) -> tuple[np.ndarray, np.ndarray]:
    """The valid IK solution nearest q_current (Euclidean in joint space), taking each joint's
    2 pi equivalents within the limits into account (see `nearest_equivalents`).

    Args:
        Q, ok: (..., 8, 6) and (..., 8) from `inverse_kinematics`.
        q_current: (..., 6) current joint positions (broadcast against Q's batch).

    Returns:
        (q, found): q (..., 6) the chosen solution, and found (...) bool. Where nothing is valid,
        found is False and q is q_current.
    """
    ok = np.asarray(ok, dtype=bool)
    q_current = np.asarray(q_current, dtype=float)
    q_cur = q_current[..., None, :]
    candidates = nearest_equivalents(Q, q_cur, lower=lower, upper=upper)
    dist = np.where(ok, np.linalg.norm(candidates - q_cur, axis=-1), np.inf)
    best = np.argmin(dist, axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    found = np.any(ok, axis=-1)
    return np.where(found[..., None], q, q_current), found
