"""Configurations that surely collide, or are surely free, without Drake: balls inside the
arm's collision geometry, and balls holding it, tested against boxes and against each other.

About half the IK solutions a planning iteration checks collide, and SceneGraph's exact check
of a colliding configuration takes about three times as long as of a free one. A ball that lies
inside a link's geometry and reaches into the table, or into a ball of another link the checker
does not filter, proves the collision in a microsecond: two shapes' signed distance is at most
that of any two balls inside them. The dual proves a configuration free: where every ball of a
set whose union holds each link keeps clear, by more than the checker's padding, of a box
holding each shape of the cell and of every ball of each link the checker tests it against,
every pair of shapes does, and the exact check would say free (pairs across one joint
whose distance no configuration changes are measured once and left out). Nine in ten of the
configurations the inner balls leave are free, and the outer balls pass nearly all of them. So
`settle` answers "collides", "free" or "ask the exact checker", never wrongly, and the
planner's answers do not change (station/arm_balls.py builds the balls from the plant's
geometry; tests/test_sure_collision.py checks them against SceneGraph).
"""

from __future__ import annotations

import dataclasses as dc

import numba
import numpy as np

from lrnbv_drake.core.robot.kinematics import _as_kernel_array, _dh, _mul_right

#: What `settle` answers of a configuration.
COLLIDES, FREE, UNSETTLED = 1, 0, -1


@dc.dataclass(frozen=True)
class ArmBalls:
    """Balls inside (or holding) the arm's collision geometry and what each must keep clear
    of. Inner balls: a pair nearer than its reach proves a collision. Outer balls: every pair
    farther than its reach proves the configuration free."""

    # (m,) int: the DH frame each ball rides on, 0 the controller's `base`, i the frame after
    # joint i (6 is `tool0`).
    frame: np.ndarray
    # (m, 3): each ball's centre in its frame, metres.
    centre: np.ndarray
    # (m,): each ball's radius, metres (the reaches below hold it).
    radius: np.ndarray
    # (k, 4, 4): X_G_W, the world expressed in each of the cell's boxes' frames.
    box_from_world: np.ndarray
    # (k, 3): each box's half extents, metres.
    box_half: np.ndarray
    # (p, 2) int: (ball, box) pairs; the ball reaches the box where its centre lies nearer
    # the box than `ball_box_reach` (signed distance, negative inside).
    ball_box: np.ndarray
    # (p,): the ball's radius plus the checker's padding of the pair, metres (and a margin:
    # less for inner balls, more for outer).
    ball_box_reach: np.ndarray
    # (s, 2) int: ball pairs on bodies the checker tests against each other; they reach each
    # other where their centres are nearer than `ball_ball_reach`.
    ball_ball: np.ndarray
    # (s,): the two radii plus the checker's padding of the pair, metres (and the margin).
    ball_ball_reach: np.ndarray

    def __post_init__(self) -> None:
        # Kernel arguments once, not per call: the planner asks about one configuration at
        # a time.
        for field in dc.fields(self):
            value = getattr(self, field.name)
            kind = np.int64 if field.name in ("frame", "ball_box", "ball_ball") else float
            object.__setattr__(self, field.name, np.ascontiguousarray(value, dtype=kind))


def arm_frames(q: np.ndarray, X_W_base: np.ndarray) -> np.ndarray:
    """(7, 4, 4): the DH frames of joints q (6,) in world, `base` at X_W_base: frame 0 is
    `base`, frame i the one after joint i (6 is `tool0`)."""
    frames = np.empty((7, 4, 4))
    _frames(_as_kernel_array(q), _as_kernel_array(X_W_base), frames, np.empty((4, 4)))
    return frames


def settle(Q: np.ndarray, X_W_base: np.ndarray, inner: ArmBalls,
           outer: ArmBalls | None = None) -> np.ndarray:
    """(n,) int8: for each configuration of Q (n, 6), COLLIDES where `inner`'s balls prove it
    collides, FREE where every pair of `outer`'s (balls holding the geometry) keeps clear of
    its reach, UNSETTLED otherwise (ask the exact checker). Without `outer`, nothing is FREE."""
    o = inner if outer is None else outer
    return _kernel(_as_kernel_array(np.asarray(Q, float).reshape(-1, 6)),
                   _as_kernel_array(X_W_base), *_arguments(inner), *_arguments(o),
                   outer is not None, False)


def first_unrejected(Q: np.ndarray, X_W_base: np.ndarray, inner: ArmBalls,
                     outer: ArmBalls | None = None) -> tuple[int, int]:
    """(i, `settle`'s answer FREE or UNSETTLED) for the first configuration Q[i] of Q (n, 6)
    the inner balls do not reject, or (n, COLLIDES) if they reject all; settles no further.
    One call for a view's IK solutions, best first, of which the planner takes the first free:
    a call per configuration cost more in overhead than the balls."""
    Q = _as_kernel_array(np.asarray(Q, float).reshape(-1, 6))
    if len(Q) == 0:
        return 0, COLLIDES
    o = inner if outer is None else outer
    codes = _kernel(Q, _as_kernel_array(X_W_base), *_arguments(inner), *_arguments(o),
                    outer is not None, True)
    return (len(Q), COLLIDES) if codes[-1] == COLLIDES else (len(codes) - 1, int(codes[-1]))


def _arguments(b: ArmBalls) -> tuple[np.ndarray, ...]:
    return (b.frame, b.centre, b.box_from_world, b.box_half, b.ball_box, b.ball_box_reach,
            b.ball_ball, b.ball_ball_reach)


@numba.njit(cache=True)
def _frames(q, X_W_base, frames, D):
    """frames (7, 4, 4) = the DH frames of q in world (`arm_frames`)."""
    frames[0] = X_W_base
    for i in range(6):
        frames[i + 1] = frames[i]
        _dh(q[i], i, D)
        _mul_right(frames[i + 1], D)


@numba.njit(cache=True)
def _box_distance(p, X, half):
    """Signed distance from world point p to the box of half extents `half` whose frame sees
    the world as X (negative inside)."""
    outside, inside = 0.0, -np.inf
    for i in range(3):
        d = abs(X[i, 0] * p[0] + X[i, 1] * p[1] + X[i, 2] * p[2] + X[i, 3]) - half[i]
        outside += max(d, 0.0) ** 2
        inside = max(inside, d)
    return np.sqrt(outside) + min(inside, 0.0)


@numba.njit(cache=True)
def _place(frames, frame, centre, world):
    """world (m, 3) = the balls' centres in world, their frames at `frames`."""
    for b in range(len(frame)):
        X = frames[frame[b]]
        for r in range(3):
            world[b, r] = (X[r, 0] * centre[b, 0] + X[r, 1] * centre[b, 1]
                           + X[r, 2] * centre[b, 2] + X[r, 3])


@numba.njit(cache=True)
def _nearest(world, box_from_world, box_half, ball_box, ball_box_reach, ball_ball,
             ball_ball_reach, overlap):
    """With `overlap`: whether some pair is nearer than its reach; without: whether some
    pair is not farther than its reach (the balls do not prove the configuration free)."""
    for j in range(len(ball_box)):
        b, k = ball_box[j, 0], ball_box[j, 1]
        d = _box_distance(world[b], box_from_world[k], box_half[k])
        if d < ball_box_reach[j] if overlap else d <= ball_box_reach[j]:
            return True
    for j in range(len(ball_ball)):
        a, b = ball_ball[j, 0], ball_ball[j, 1]
        d2 = ((world[a, 0] - world[b, 0]) ** 2 + (world[a, 1] - world[b, 1]) ** 2
              + (world[a, 2] - world[b, 2]) ** 2)
        r2 = ball_ball_reach[j] ** 2
        if d2 < r2 if overlap else d2 <= r2:
            return True
    return False


@numba.njit(cache=True)
def _kernel(Q, X_W_base, frame, centre, box_from_world, box_half, ball_box, ball_box_reach,
            ball_ball, ball_ball_reach, o_frame, o_centre, o_box_from_world, o_box_half,
            o_ball_box, o_ball_box_reach, o_ball_ball, o_ball_ball_reach, prove_free, stop):
    """`settle`'s answers; with `stop`, only those up to the first not COLLIDES."""
    frames = np.empty((7, 4, 4))
    D = np.empty((4, 4))
    world = np.empty((len(frame), 3))
    o_world = np.empty((len(o_frame), 3))
    out = np.full(Q.shape[0], UNSETTLED, np.int8)
    for n in range(Q.shape[0]):
        _frames(Q[n], X_W_base, frames, D)
        _place(frames, frame, centre, world)
        if _nearest(world, box_from_world, box_half, ball_box, ball_box_reach, ball_ball,
                    ball_ball_reach, True):
            out[n] = COLLIDES
        elif prove_free:
            _place(frames, o_frame, o_centre, o_world)
            if not _nearest(o_world, o_box_from_world, o_box_half, o_ball_box,
                            o_ball_box_reach, o_ball_ball, o_ball_ball_reach, False):
                out[n] = FREE
        if stop and out[n] != COLLIDES:
            return out[:n + 1]
    return out


def compile_kernels() -> None:
    """Compiles the balls' kernel into numba's on-disk cache: cold, the first planning
    iteration of every process would wait for it (`core/kernels.py`)."""
    balls = ArmBalls(frame=[0], centre=np.zeros((1, 3)), radius=[0.01],
                     box_from_world=np.eye(4)[None], box_half=np.full((1, 3), 0.1),
                     ball_box=[[0, 0]], ball_box_reach=[0.01], ball_ball=np.zeros((0, 2)),
                     ball_ball_reach=np.zeros(0))
    settle(np.zeros((1, 6)), np.eye(4), balls, balls)
