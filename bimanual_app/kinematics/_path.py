"""Straight moves on one IK branch: the task planner's rule for every Cartesian move.

A straight move is a list of gripper poses (``line_poses``: one every ``WAYPOINT_STEP`` m and 0.05 rad), each
solved by IK seeded with the previous waypoint's solution. Consecutive solutions that differ by more than
``MAX_JOINT_JUMP`` (any joint) are either fast but continuous motion (near a wrist singularity joints 4 and 6
trade large opposite turns over a few millimetres) or a switch to another IK branch, which the arm cannot
follow along the line. :func:`follow_poses` tells them apart by splitting the step in 2, 4, 8 (poses
interpolated, slerp): a continuous motion's largest joint step shrinks with the sub-steps; a branch switch's
does not. A step is accepted once its jump is within ``MAX_JOINT_JUMP / parts``, or once it has nearly halved
with the last split (to 0.6 of it) and is within half the limit.

Passing within a fraction of a millimetre of a wrist singularity, joints 4 and 6 turn by up to pi over less
than the finest split, and no split shrinks that jump; yet the joint-space line between the two solutions
keeps the gripper on the move (at the singularity only their sum moves the gripper). Given the arms' forward
kinematics (``fk``), such a step is accepted when every configuration on that joint-space line, sampled
every ``CONTINUITY_SAMPLE`` rad, puts the gripper within ``CONTINUITY_TOL_M`` of the step's segment and
``CONTINUITY_TOL_RAD`` of its orientation; the samples become waypoints (the time parametrisation slows the
fast joints). A switch to another branch sweeps the gripper off the line between the two solutions.

The grasp stage's reach check (``grasping.ArmReach``) keeps a coarser rule of its own, which also stands in
for the planner's fallbacks around these moves (docs/grasping.md: this rule there was measured and lost
held-out scenes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import make_T, rotation_angle_between

__all__ = ["WAYPOINT_STEP", "MAX_JOINT_JUMP", "PathFailure", "line_poses", "follow_poses"]

WAYPOINT_STEP = 0.01  # m between the waypoints of a straight move
WAYPOINT_TURN = 0.05  # rad between the waypoints of a straight move
MAX_JOINT_JUMP = 0.35  # rad between consecutive waypoints: more is a branch switch unless splitting shrinks it
SPLITS = (1, 2, 4, 8)  # parts a step is split in, in turn, while its jump stays over the limit
CONTINUITY_SAMPLE = 0.02  # rad: joint-space spacing of the samples that check an unsplittable jump
CONTINUITY_TOL_M = 0.002  # m: ... the gripper stays this close to the step's segment
CONTINUITY_TOL_RAD = 0.03  # rad: ... and this close to its orientation

# solve(T (4,4), q_seed (J,), n_solutions, max_seeds) -> IKResult (bimanual_app.kinematics.IKResult)
Solve = Callable[[np.ndarray, np.ndarray, int, int], object]
# fk(Q (N, J)) -> (N, 4, 4) gripper poses in the frame of that arm's poses
Forward = Callable[[np.ndarray], np.ndarray]


@dataclass
class PathFailure:
    """Why a straight move cannot be followed.

    kind: 'reach' (a pose without IK solution) or 'branch' (a step that stays a jump however split).
    index: the waypoint (1..K-1) whose step failed. arm: the arm that failed ('reach'; '' for 'branch': all).
    T: (4, 4) the pose that failed ('reach'); jump: the last split's largest joint step (rad, 'branch');
    step: the length of that split's sub-steps (m, 'branch'). message: the IK's message ('reach').
    """

    kind: str
    index: int
    arm: str = ""
    T: np.ndarray | None = None
    jump: float = 0.0
    step: float = 0.0
    message: str = ""


def line_poses(T0: np.ndarray, T1: np.ndarray, n: int | None = None) -> np.ndarray:
    """(n, 4, 4) poses on the straight line T0 -> T1 (4, 4) (orientation by slerp), by default one every
    ``WAYPOINT_STEP`` m and ``WAYPOINT_TURN`` rad (at least 2: both ends)."""
    from scipy.spatial.transform import Rotation, Slerp

    R01 = Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]]))
    if n is None:
        dist = float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]))
        ang = float(np.linalg.norm((R01[0].inv() * R01[1]).as_rotvec()))
        n = max(2, int(np.ceil(max(dist / WAYPOINT_STEP, ang / WAYPOINT_TURN))) + 1)
    s = np.linspace(0.0, 1.0, n)
    R = Slerp([0.0, 1.0], R01)(s).as_matrix()
    P = T0[:3, 3] + s[:, None] * (T1[:3, 3] - T0[:3, 3])
    return np.stack([make_T(R[i], P[i]) for i in range(n)])


def follow_poses(solve: dict[str, Solve], poses: dict[str, np.ndarray], q0: dict[str, np.ndarray],
                 max_jump: float = MAX_JOINT_JUMP, fk: dict[str, Forward] | None = None
                 ) -> tuple[dict[str, np.ndarray], PathFailure | None]:
    """Joint waypoints of arms moving through their poses together, on one IK branch each (module docstring).

    solve: arm -> IK function (``Solve``); poses: arm -> (K, 4, 4) poses in that solver's frame, the same K for
    every arm (a split step splits every arm's); q0: arm -> (J,) the configuration at the first pose; fk: arm ->
    forward kinematics (``Forward``), which lets a jump no split shrinks pass when the joint-space line keeps the
    gripper on the move (module docstring; without it such a jump is a branch switch).
    Returns (arm -> (K', J) joint waypoints, K' >= K, the first q0; None) or, when the move cannot be
    followed, (the waypoints up to the failed step, the ``PathFailure``).
    """
    arms = list(poses)
    K = len(poses[arms[0]])
    if any(len(poses[a]) != K for a in arms):
        raise ValueError("follow_poses: every arm needs the same number of poses")
    Q = {a: [np.asarray(q0[a], dtype=np.float64)] for a in arms}
    for k in range(1, K):
        sub, fail = _split_step(solve, {a: (poses[a][k - 1], poses[a][k]) for a in arms},
                                {a: Q[a][-1] for a in arms}, max_jump, fk)
        if fail is not None:
            fail.index = k
            return {a: np.stack(Q[a]) for a in arms}, fail
        for a in arms:
            Q[a].extend(sub[a])
    return {a: np.stack(Q[a]) for a in arms}, None


def _split_step(solve: dict[str, Solve], ends: dict, q: dict, max_jump: float,
                fk: dict[str, Forward] | None = None) -> tuple[dict, PathFailure | None]:
    """One step of ``follow_poses``: arm -> (T0, T1) from the configurations ``q`` (arm -> (J,)), split in
    ``SPLITS`` parts until accepted, else checked along the joint-space line (``_on_the_line``, with ``fk``).
    Returns (arm -> [sub-step solutions], None) or ({}, the failure)."""
    prev = np.inf
    for parts in SPLITS:
        sub, jump = {}, 0.0
        for a, (T0, T1) in ends.items():
            qa, sub[a] = q[a], []
            for T in line_poses(T0, T1, parts + 1)[1:]:  # the step's sub-steps, its end last
                r = solve[a](T, qa, 1, 4)
                if r.success and np.max(np.abs(r.q - qa)) > max_jump / parts:
                    # the previous solution did not converge as a seed and another seed found another branch:
                    # ask for several solutions, the closest to the previous one comes first
                    r2 = solve[a](T, qa, 4, 16)
                    r = r2 if r2.success else r
                if not r.success:
                    return {}, PathFailure("reach", 0, a, T, message=r.message)
                jump = max(jump, float(np.max(np.abs(r.q - qa))))
                sub[a].append(r.q)
                qa = r.q
        if jump <= max_jump / parts or (jump <= 0.6 * prev and jump <= max_jump / 2):
            return sub, None
        prev = jump
    if fk is not None:
        joined = _on_the_line(fk, ends, q, sub, max_jump / SPLITS[-1])
        if joined is not None:
            return joined, None
    step = max(float(np.linalg.norm(T1[:3, 3] - T0[:3, 3])) for T0, T1 in ends.values()) / SPLITS[-1]
    return {}, PathFailure("branch", 0, jump=jump, step=step)


def _on_the_line(fk: dict[str, Forward], ends: dict, q: dict, sub: dict, limit: float) -> dict | None:
    """The finest split's sub-steps (arm -> [(J,)] after ``q``) with every jump over ``limit`` (rad) replaced by
    samples of its joint-space line, or None when some sample leaves the sub-step's segment (a branch switch).
    Every arm gets the same samples (their straight joint lines, for one clock)."""
    arms = list(sub)
    n_sub = len(sub[arms[0]])
    segs = {a: line_poses(*ends[a], n_sub + 1) for a in arms}  # the sub-steps' poses, as _split_step made them
    out = {a: [] for a in arms}
    for i in range(n_sub):
        qa = {a: (q[a] if i == 0 else sub[a][i - 1]) for a in arms}
        jump = max(float(np.max(np.abs(sub[a][i] - qa[a]))) for a in arms)
        n = int(np.ceil(jump / CONTINUITY_SAMPLE)) if jump > limit else 1
        s = np.linspace(0.0, 1.0, n + 1)[1:, None]
        for a in arms:
            Qs = qa[a] + s * (sub[a][i] - qa[a])
            if n > 1 and not _near_segment(fk[a](Qs), segs[a][i], segs[a][i + 1]):
                return None
            out[a].extend(Qs)
    return out


def _near_segment(T: np.ndarray, T0: np.ndarray, T1: np.ndarray) -> bool:
    """Whether every pose of ``T`` (N, 4, 4) lies within ``CONTINUITY_TOL_M`` of the segment T0 -> T1 (4, 4)
    and within ``CONTINUITY_TOL_RAD`` of T0's or T1's orientation."""
    d = T1[:3, 3] - T0[:3, 3]
    u = np.clip((T[:, :3, 3] - T0[:3, 3]) @ d / max(float(d @ d), 1e-18), 0.0, 1.0)
    off = np.linalg.norm(T[:, :3, 3] - (T0[:3, 3] + u[:, None] * d), axis=1)
    R = T[:, :3, :3]
    turn = np.minimum(rotation_angle_between(R, T0[:3, :3]), rotation_angle_between(R, T1[:3, :3]))
    return bool(off.max() <= CONTINUITY_TOL_M and turn.max() <= CONTINUITY_TOL_RAD)
