"""UR5e kinematics without Drake: constants, forward kinematics and the closed-form inverse.

No Drake here, so the planner can rank hundreds of candidate views per iteration in
milliseconds; `tests/test_kinematics.py` checks every number against the MultibodyPlant built
from `models/ur5e/ur5e.urdf` (which `models/ur5e/make_urdf.py` generates from these constants).
The numeric core is numba kernels looping over targets: the planner asks for ~10 at a time,
which vectorised numpy spent mostly in per-call overhead.

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
Inverse Kinematics for the Universal Robots UR-5/UR-10 Arms"), batched over targets.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba.extending import register_jitable

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

# cos and sin of the DH twists, for the kernels (computed once: they are constants).
_COS_ALPHA, _SIN_ALPHA = np.cos(DH_ALPHA), np.sin(DH_ALPHA)

# Below this |sin(q5)| the wrist is singular (joints 4 and 6 aligned) and q6 is free.
_WRIST_SINGULAR_SIN = 1e-10


def _as_kernel_array(a: np.ndarray) -> np.ndarray:
    """`a` as a C-contiguous, writeable float64 array (a copy only if needed): numba compiles a
    kernel once per argument type, and read-only (`HOME`) or strided arrays are other types."""
    a = np.ascontiguousarray(a, dtype=float)
    return a if a.flags.writeable else a.copy()


def _filled(shape: tuple[int, ...], value: float | np.ndarray) -> np.ndarray:
    """A new float64 array of `shape` with `value` broadcast into it: a kernel argument as
    `_as_kernel_array` makes them, without np.broadcast_to's ~2 us per call."""
    out = np.empty(shape)
    out[...] = value
    return out


@register_jitable
def _wrap(q):
    """q wrapped to [-pi, pi): the one formula, numpy on arrays from Python (`wrap_to_pi`)
    and scalar inside the kernels."""
    return (q + np.pi) % (2 * np.pi) - np.pi


def wrap_to_pi(q: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return _wrap(np.asarray(q))


@numba.njit(cache=True)
def _dh(theta, i, out):
    """out (4, 4) = DH transform of joint i (0-based): Rz(theta) Tz(d) Tx(a) Rx(alpha)."""
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = _COS_ALPHA[i], _SIN_ALPHA[i]
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = ct, -st * ca, st * sa, DH_A[i] * ct
    out[1, 0], out[1, 1], out[1, 2], out[1, 3] = st, ct * ca, -ct * sa, DH_A[i] * st
    out[2, 0], out[2, 1], out[2, 2], out[2, 3] = 0.0, sa, ca, DH_D[i]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0


@numba.njit(cache=True)
def _inv(T, out):
    """out (4, 4) = inverse of the rigid transform T."""
    for i in range(3):
        for j in range(3):
            out[i, j] = T[j, i]
        out[i, 3] = -(T[0, i] * T[0, 3] + T[1, i] * T[1, 3] + T[2, i] * T[2, 3])
        out[3, i] = 0.0
    out[3, 3] = 1.0


@numba.njit(cache=True)
def _mul_right(A, B):
    """A = A @ B for (4, 4) matrices, in place (row by row, so no temporary)."""
    for i in range(4):
        a0, a1, a2, a3 = A[i, 0], A[i, 1], A[i, 2], A[i, 3]
        for j in range(4):
            A[i, j] = a0 * B[0, j] + a1 * B[1, j] + a2 * B[2, j] + a3 * B[3, j]


@numba.njit(cache=True)
def _fk(q, out):
    """out (4, 4) = X_base_tool0 for one configuration q (6,): the product of the DH
    transforms. The only forward kinematics: `forward_kinematics` and the IK's check use it."""
    D = np.empty((4, 4))
    _dh(q[0], 0, out)
    for i in range(1, 6):
        _dh(q[i], i, D)
        _mul_right(out, D)


@numba.njit(cache=True)
def _fk_kernel(q):
    """(n, 4, 4) forward kinematics of (n, 6) configurations."""
    X = np.empty((q.shape[0], 4, 4))
    for n in range(q.shape[0]):
        _fk(q[n], X[n])
    return X


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
    return _fk_kernel(_as_kernel_array(q.reshape(-1, 6))).reshape(*q.shape[:-1], 4, 4)


def sensor_pose(q: np.ndarray, X_W_base: np.ndarray, X_tool0_S: np.ndarray) -> np.ndarray:
    """X_WS (..., 4, 4): the sensor in world for joints q (..., 6), with the controller's
    `base` at X_W_base and the sensor at X_tool0_S on the flange. The one place the sensor
    pose follows from the joints: the cell's `tof.pose`, the motion planner and the safety
    checks all call it."""
    return X_W_base @ forward_kinematics(np.asarray(q, float)) @ X_tool0_S


@numba.njit(cache=True)
def _clip_unit(x):
    """x clipped to [-1, 1]; NaN stays NaN (an unreachable target stays not ok)."""
    return -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)


@numba.njit(cache=True, error_model="numpy")
def _ik_kernel(X, q6_hint, lower, upper, tol):
    """`inverse_kinematics` on (n, 4, 4) targets: (Q (n, 8, 6), ok (n, 8)). Scalar loops, as a
    planner's few targets per call would spend their time in numpy's per-call overhead."""
    n = X.shape[0]
    Q = np.zeros((n, 8, 6))
    ok = np.zeros((n, 8), dtype=np.bool_)
    d4, d6 = DH_D[3], DH_D[5]
    a2, a3 = DH_A[1], DH_A[2]
    T16, T14, D, D_inv, Xq = (np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4)),
                              np.empty((4, 4)), np.empty((4, 4)))
    q = np.empty(6)
    for t in range(n):
        Xt = X[t]
        # q1: the wrist centre p5 must sit d4 along joint 2's axis z1 = (s1, -c1, 0).
        p5x = Xt[0, 3] - d6 * Xt[0, 2]
        p5y = Xt[1, 3] - d6 * Xt[1, 2]
        psi = math.asin(_clip_unit(d4 / math.hypot(p5x, p5y)))
        phi = math.atan2(p5y, p5x)
        for shoulder in range(2):
            q[0] = phi + (psi if shoulder == 0 else np.pi - psi)
            z1x, z1y, z1z = math.sin(q[0]), -math.cos(q[0]), 0.0
            # z1 seen from tool0 is (s5 c6, -s5 s6, c5): gives q5 (two signs) and q6.
            v0 = Xt[0, 0] * z1x + Xt[1, 0] * z1y + Xt[2, 0] * z1z
            v1 = Xt[0, 1] * z1x + Xt[1, 1] * z1y + Xt[2, 1] * z1z
            v2 = Xt[0, 2] * z1x + Xt[1, 2] * z1y + Xt[2, 2] * z1z
            s5_abs = math.hypot(v0, v1)
            # Joints 2-4 form a planar 3R arm in frame 1: frame 4 in frame 1 gives the rest.
            _dh(q[0], 0, D)
            _inv(D, T16)
            _mul_right(T16, Xt)  # tool0 in frame 1
            for wrist in range(2):
                sign = 1.0 - 2.0 * wrist
                q[4] = sign * math.atan2(s5_abs, v2)
                q[5] = math.atan2(-sign * v1, sign * v0)
                if s5_abs < _WRIST_SINGULAR_SIN:
                    q[5] = q6_hint[t]
                T14[:] = T16
                _dh(q[5], 5, D)
                _inv(D, D_inv)
                _mul_right(T14, D_inv)
                _dh(q[4], 4, D)
                _inv(D, D_inv)
                _mul_right(T14, D_inv)
                px, py = T14[0, 3], T14[1, 3]
                q234 = math.atan2(T14[1, 0], T14[0, 0])
                c3 = _clip_unit((px**2 + py**2 - a2**2 - a3**2) / (2 * a2 * a3))
                for elbow in range(2):
                    k = 4 * shoulder + 2 * wrist + elbow
                    q[2] = (1.0 - 2.0 * elbow) * math.acos(c3)
                    q[1] = math.atan2(py, px) - math.atan2(a3 * math.sin(q[2]),
                                                           a2 + a3 * math.cos(q[2]))
                    q[3] = q234 - q[1] - q[2]
                    valid = True
                    for j in range(6):
                        Q[t, k, j] = _wrap(q[j])
                        valid &= (math.isfinite(Q[t, k, j]) and lower[j] <= Q[t, k, j]
                                  and Q[t, k, j] <= upper[j])
                    _fk(Q[t, k], Xq)
                    pos_err2 = 0.0
                    rot_err2 = 0.0
                    for i in range(3):
                        pos_err2 += (Xq[i, 3] - Xt[i, 3]) ** 2
                        for j in range(3):
                            rot_err2 += (Xq[i, j] - Xt[i, j]) ** 2
                    # Frobenius distance / sqrt(2) ~ rotation angle for small errors.
                    ok[t, k] = (valid and math.sqrt(pos_err2) <= tol
                                and math.sqrt(rot_err2) / math.sqrt(2.0) <= tol)
                    if not ok[t, k]:
                        Q[t, k, :] = 0.0
    return Q, ok


def inverse_kinematics(
    X: np.ndarray,
    *,
    q6_singular: float | np.ndarray = 0.0,
    lower: np.ndarray = JOINT_LOWER,
    upper: np.ndarray = JOINT_UPPER,
    tol: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """All closed-form solutions for a batch of X_base_tool0 targets.

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
    Q, ok = _ik_kernel(_as_kernel_array(X.reshape(-1, 4, 4)),
                       _filled(batch, q6_singular).reshape(-1),
                       _filled((6,), lower), _filled((6,), upper), float(tol))
    return Q.reshape(*batch, 8, 6), ok.reshape(*batch, 8)


def compile_kernels() -> None:
    """Compiles the kinematics kernels into numba's on-disk cache: cold, the first IK of every
    process (the first planning iteration) would wait seconds for them. `make` runs this after
    installing (`python -m lrnbv_drake.core.kernels`)."""
    Q, ok = inverse_kinematics(forward_kinematics(HOME)[None])
    ranked_solutions(Q, ok, HOME, VELOCITY_LIMIT)


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


def ranked_solutions(Q: np.ndarray, ok: np.ndarray, q_current: np.ndarray,
                     max_velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pose's solutions at their `nearest_equivalents`, the valid ones first by the time
    the slowest joint needs from q_current (a stable sort): (Q (N, k, 6), n (N,)), pose i's
    n[i] valid ones in Q[i, :n[i]]. Q (N, k, 6) and ok (N, k) from `inverse_kinematics`. One
    kernel: in numpy the planner's IK calls spent about 90 us each in per-op overhead (19 now)."""
    return _ranked_kernel(_as_kernel_array(Q), np.ascontiguousarray(ok, dtype=np.bool_),
                          _as_kernel_array(q_current), _filled((6,), JOINT_LOWER),
                          _filled((6,), JOINT_UPPER), _as_kernel_array(max_velocity))


@numba.njit(cache=True, error_model="numpy")
def _ranked_kernel(Q, ok, q_current, lower, upper, max_velocity):
    """`ranked_solutions`, with numpy's arithmetic op for op (the same bits): rint for
    np.round, a NaN passing np.clip."""
    N, k = ok.shape
    two_pi = 2 * np.pi
    near = np.empty((k, 6))
    cost = np.empty(k)
    order = np.empty(k, np.int64)
    out = np.empty((N, k, 6))
    n = np.zeros(N, np.int64)
    for i in range(N):
        for j in range(k):
            worst = 0.0
            for m in range(6):
                x = Q[i, j, m]
                lo = np.ceil((lower[m] - x) / two_pi)
                hi = np.floor((upper[m] - x) / two_pi)
                turns = np.rint((q_current[m] - x) / two_pi)
                turns = lo if turns < lo else turns
                turns = hi if turns > hi else turns
                y = x + two_pi * turns
                y = lower[m] if y < lower[m] else y
                y = upper[m] if y > upper[m] else y
                near[j, m] = y
                worst = max(worst, abs(y - q_current[m]) / max_velocity[m])
            cost[j] = worst if ok[i, j] else np.inf
            n[i] += ok[i, j]
        for j in range(k):  # insertion sort: stable, as numpy's "stable"
            r = j
            while r > 0 and cost[order[r - 1]] > cost[j]:
                order[r] = order[r - 1]
                r -= 1
            order[r] = j
        for r in range(k):
            out[i, r] = near[order[r]]
    return out, n


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
