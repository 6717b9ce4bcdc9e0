"""The joint lift's object motion chosen inside both arms' reach: a bimanual IK map over object poses.

Both grippers hold one rigid object, so each gripper's pose during the lift is the object's motion applied
to its grasp: ``T_b1_g(t) = T_move(t) @ S[arm]``. With the gripper's orientation tied to the object's, an arm
whose grasp is tilted steeply (a grasp from above, towards the other arm) often runs into a joint limit a few
centimetres above the table even though the position alone is well within reach, and lifting straight up
fails. This module samples the object's end pose of the lift (height, horizontal shift, a small turn about
``up``, all rigid motions about the object's centre), solves both arms' IK for every sample in one batch,
and scores each feasible sample by a list of named, weighted cost terms (both arms' joint-limit margin and
distance from a wrist singularity, the joint travel, the shift, the turn and the height given up). The
planner then checks the best ones' swept object and straight paths in score order.

Pure functions on arrays; the IK solvers and the Jacobians come in as arguments.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import check_shape, perpendicular_basis, so3_exp

__all__ = ["LiftCandidates", "LiftArm", "LiftCost", "LIFT_COSTS", "LIFT_PATHS", "lift_candidates", "along", "object_motion", "arms_ik",
           "lift_costs", "rank_lifts"]


@dataclass(frozen=True)
class LiftCandidates:
    """Sampled end poses of the object's lift (N of them).

    T_end: (N, 4, 4) rigid motion of the object at the end of the lift, in b1 (p_end = T_end @ p_start).
    height: (N,) rise along ``up`` (m); shift: (N, 3) horizontal move (m); yaw: (N,) turn about ``up``
    through ``centre`` (rad); centre: (3,) the object's centre in b1; up: (3,) unit.
    """

    T_end: np.ndarray
    height: np.ndarray
    shift: np.ndarray
    yaw: np.ndarray
    centre: np.ndarray
    up: np.ndarray

    def __len__(self) -> int:
        return len(self.height)


def _motion(centre: np.ndarray, up: np.ndarray, height: np.ndarray, shift: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 4, 4): turn by ``yaw`` about ``up`` through ``centre``, then translate by ``height * up + shift``."""
    R = so3_exp(np.asarray(yaw, dtype=np.float64)[:, None] * up)  # turns about ``up``
    T = np.zeros((len(height), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = centre - R @ centre + height[:, None] * up + shift
    T[:, 3, 3] = 1.0
    return T


def lift_candidates(centre: np.ndarray, up: np.ndarray, lift: float, lift_min: float, radius: float = 0.08,
                    n_heights: int = 4, n_rings: int = 2, n_dirs: int = 8,
                    yaws: tuple = (0.0, 0.2, -0.2, 0.4, -0.4)) -> LiftCandidates:
    """The sampled end poses of the lift: ``n_heights`` heights from ``lift`` down to ``lift_min``, times the
    horizontal shifts (none, and ``n_dirs`` directions on ``n_rings`` rings out to ``radius`` m), times the
    turns ``yaws`` (rad) about ``up`` through ``centre`` (3,). Straight up by ``lift`` comes first."""
    centre = check_shape("centre", np.asarray(centre, dtype=np.float64), (3,))
    up = check_shape("up", np.asarray(up, dtype=np.float64), (3,))
    up = up / np.linalg.norm(up)
    if not 0.0 < lift_min <= lift:
        raise ValueError(f"lift_candidates: need 0 < lift_min <= lift, got {lift_min}, {lift}")
    e1, e2 = perpendicular_basis(up)
    ang = 2 * np.pi * np.arange(n_dirs) / n_dirs
    dirs = np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2
    rings = radius * np.arange(1, n_rings + 1) / n_rings
    shifts = np.vstack([np.zeros((1, 3))] + [r * dirs for r in rings])
    heights = np.linspace(lift, lift_min, n_heights) if n_heights > 1 else np.array([lift])
    H, Si, Y = np.meshgrid(heights, np.arange(len(shifts)), np.asarray(yaws, dtype=np.float64), indexing="ij")
    H, Si, Y = H.ravel(), Si.ravel(), Y.ravel()
    return LiftCandidates(_motion(centre, up, H, shifts[Si], Y), H, shifts[Si], Y, centre, up)


# How the object goes to a lift's end pose: over which part of the rise (fractions of it) the horizontal shift
# and the turn are done. Shifting early takes the object away from the table and the arm's reach limit
# first; rising first takes it clear of a neighbour's top before it moves sideways. The first is the one the
# IK search follows (``along``); the planner tries the others where the first sweeps the object through the map.
LIFT_PATHS: tuple[tuple[str, float, float], ...] = (
    ("", 0.0, 0.5),
    ("rising before it moves sideways", 0.5, 1.0),
    ("moving sideways all the way up", 0.0, 1.0),
)


def _side(s: np.ndarray, start: float, end: float) -> np.ndarray:
    """The fraction of the shift and turn done at fractions ``s`` of the rise (0 before ``start``, 1 after ``end``)."""
    return np.clip((np.asarray(s, dtype=np.float64) - start) / (end - start), 0.0, 1.0)


def along(c: LiftCandidates, s: float) -> np.ndarray:
    """(N, 4, 4) every candidate's object motion at fraction ``s`` (0..1) of its lift along the first of
    ``LIFT_PATHS``: the rise is linear, the horizontal shift and the turn are done over its first half."""
    side = float(_side(s, *LIFT_PATHS[0][1:]))
    return _motion(c.centre, c.up, s * c.height, side * c.shift, side * c.yaw)


def object_motion(c: LiftCandidates, i: int, step: float = 0.01, path: tuple[str, float, float] = LIFT_PATHS[0]
                  ) -> np.ndarray:
    """(K, 4, 4) the object's motion to candidate ``i``'s end pose, waypoints about ``step`` m apart: the rise
    is linear, the horizontal shift and the turn are done over the part of it ``path`` (one of ``LIFT_PATHS``:
    name, start and end fractions) says; by default its first half (away from the table and the neighbours
    first, then the rest of the way up). Starts at the identity."""
    travel = float(np.hypot(c.height[i], np.linalg.norm(c.shift[i])))
    n = max(2, int(np.ceil(travel / step)) + 1)
    s = np.linspace(0.0, 1.0, n)
    side = _side(s, path[1], path[2])
    return _motion(c.centre, c.up, s * c.height[i], side[:, None] * c.shift[i], side * c.yaw[i])


@dataclass(frozen=True)
class LiftArm:
    """One arm as the lift search sees it.

    solve: ``(T_b1_targets (N,4,4), q_seeds (N,J)) -> (Q (N,J), ok (N,) bool)``, the IK solution of each
        gripper target in b1 reached from its seed (batched); jacobian: ``Q (N,J) -> (N,6,J)``;
    lower, upper: (J,) joint limits; q0: (J,) the configuration holding the object at the start of the lift.
    """

    solve: Callable
    jacobian: Callable
    lower: np.ndarray
    upper: np.ndarray
    q0: np.ndarray

    @classmethod
    def from_solver(cls, solver, T_b_b1: np.ndarray, q0: np.ndarray, max_seeds: int = 1,
                    on_solve: Callable[[int], None] | None = None) -> LiftArm:
        """An arm on an :class:`~bimanual_app.kinematics.IKSolver` of its gripper frame, whose base is
        ``T_b_b1`` (4,4) from b1: each target solved by ``solve_many`` from its own seed with ``max_seeds``
        seeds (1: the seed only, so the solution continues the seed's IK branch; a failed lane keeps its
        seed), and the frame's Jacobian (Pinocchio, LOCAL). ``on_solve(n)`` is told of every n targets."""
        import pinocchio as pin

        T_b_b1 = check_shape("T_b_b1", np.asarray(T_b_b1, dtype=np.float64), (4, 4))

        def solve(T, Q0):
            if on_solve is not None:
                on_solve(len(T))
            rs = solver.solve_many(T_b_b1 @ T, Q0, max_seeds=max_seeds)
            return np.stack([r.q if r.success else q for r, q in zip(rs, Q0)]), np.array([r.success for r in rs])

        def jacobian(Q):
            data = solver.model.createData()
            return np.stack([pin.computeFrameJacobian(solver.model, data, q, solver.fid, pin.LOCAL) for q in Q])

        return cls(solve, jacobian, solver.lower, solver.upper, np.asarray(q0, dtype=np.float64))


def arms_ik(arms: dict, S: dict, c: LiftCandidates, stages: tuple = (0.25, 0.5, 0.75, 1.0),
            max_jump: float = 1.5) -> dict:
    """Both arms' IK for the grippers carried along every candidate's lift: arm -> (Q (N,J) at the end pose,
    ok (N,) bool). ``arms[arm]`` is a :class:`LiftArm`, ``S[arm]`` (4,4) the gripper's pose in b1 holding the
    object. The solves follow the lift through the fractions ``stages`` (the last 1), each seeded with the
    previous one's solution (the first with the configuration holding the object), as the straight path's
    IK will be; a candidate fails where a stage has no solution or a joint turns more than ``max_jump`` rad
    between stages (another IK branch)."""
    out = {}
    for arm, A in arms.items():
        T_g = check_shape(f"S[{arm}]", np.asarray(S[arm], dtype=np.float64), (4, 4))
        Q = np.tile(np.asarray(A.q0, dtype=np.float64), (len(c), 1))
        ok = np.ones(len(c), dtype=bool)
        for s in stages:
            Qs, oks = A.solve(along(c, s) @ T_g, Q)
            Qs, oks = np.asarray(Qs, dtype=np.float64), np.asarray(oks, dtype=bool)
            if Qs.shape != Q.shape or oks.shape != ok.shape:
                raise ValueError(f"arms_ik: the {arm} solver returned shapes {Qs.shape}, {oks.shape}")
            ok &= oks & (np.abs(Qs - Q).max(axis=1) <= max_jump)
            Q = np.where(ok[:, None], Qs, Q)  # failed lanes keep their last solution: the costs stay finite
        out[arm] = (Q, ok)
    return out


@dataclass(frozen=True)
class LiftCost:
    """One named cost term: ``fn(candidates, ik, arms) -> (N,)`` (``ik`` from :func:`arms_ik`, ``arms`` arm ->
    :class:`LiftArm`), summed with ``weight``."""

    name: str
    weight: float
    fn: Callable


def _margin(c, ik, arms, soft: float = 0.4) -> np.ndarray:
    """Both arms' shortfall of the least joint-limit margin below ``soft`` rad, relative (0 when every joint
    is ``soft`` away from its limits): an end pose at a limit leaves the path no room."""
    out = np.zeros(len(c))
    for arm, (Q, _) in ik.items():
        m = np.minimum(Q - arms[arm].lower, arms[arm].upper - Q).min(axis=1)
        out += np.clip(soft - m, 0.0, soft) / soft
    return out


def _singular(c, ik, arms, soft: float = 0.05) -> np.ndarray:
    """Both arms' closeness to a singularity: the shortfall of the Jacobian's least singular value below
    ``soft``, relative."""
    out = np.zeros(len(c))
    for arm, (Q, _) in ik.items():
        sv = np.linalg.svd(arms[arm].jacobian(Q), compute_uv=False)[:, -1]
        out += np.clip(soft - sv, 0.0, soft) / soft
    return out


def _travel(c, ik, arms) -> np.ndarray:
    """Both arms' largest joint change from the start of the lift (rad): a long way in joint space is more
    likely to cross a limit or a branch between the ends."""
    return sum(np.abs(Q - arms[arm].q0).max(axis=1) for arm, (Q, _) in ik.items())


LIFT_COSTS = (
    LiftCost("joint-limit margin", 2.0, _margin),
    LiftCost("singularity", 1.0, _singular),
    LiftCost("joint travel", 0.3, _travel),
    LiftCost("shift", 0.5, lambda c, ik, arms: np.linalg.norm(c.shift, axis=1) / 0.1),
    LiftCost("turn", 0.5, lambda c, ik, arms: np.abs(c.yaw) / 0.4),
    # the height dominates: the task needs the object a set height up and held there, and an object sags in
    # the grippers under its weight (by centimetres where the estimate was lighter than the object), so a
    # lift planned just past that height leaves no room for the sag; the other terms choose within a height
    # and the lower heights stay behind as fallbacks
    LiftCost("height given up", 10.0, lambda c, ik, arms: (c.height.max() - c.height) / 0.05),
)


def lift_costs(c: LiftCandidates, ik: dict, arms: dict, terms: tuple = LIFT_COSTS) -> dict:
    """Each cost term of the candidates, weighted: name -> (N,)."""
    return {t.name: t.weight * np.asarray(t.fn(c, ik, arms), dtype=np.float64) for t in terms}


def rank_lifts(c: LiftCandidates, ik: dict, costs: dict) -> np.ndarray:
    """Indices of the candidates both arms reach, cheapest first (total of ``costs``)."""
    ok = np.logical_and.reduce([v[1] for v in ik.values()])
    total = np.sum(list(costs.values()), axis=0)
    idx = np.flatnonzero(ok)
    return idx[np.argsort(total[idx], kind="stable")]
