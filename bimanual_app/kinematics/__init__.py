"""Kinematics: forward kinematics lives on ``RobotModel`` (bimanual_app.robots); IK lives here.

Public API:
    IKSolver(robot, link=None, tol_pos=1e-4, tol_rot=1e-3, ...).solve(T_target, q_current=None,
             position_only=False, n_solutions=1) -> IKResult
    IKSolver.solve_many(T_targets (N,4,4), q_current=None | (J,) | (N,J), ..., screen=False) -> [IKResult] * N
             (the same results as N ``solve`` calls; all targets' seeds descend together, vectorised;
             ``screen``: targets with no closed-form branch within the limits fail without a descent)
    IKSolver.screen(T_targets (N,4,4), hint (J,) | (N,J)) -> [str] * N | None   ('' where a closed-form branch
             lies within the limits, else why no solve can succeed; None for a chain without a closed form)
    For an arm with a wrist centre (the Piper) the seeds after the current configuration are the closed-form
    branches (``_analytic``: ``wrist_chain``, ``ik_branches``), polished by the same damped least squares.
    solve_ik(robot, T_target, q_current=None, **kw) -> IKResult   (caches one IKSolver per robot and link)

Two arms holding one object (``_lift``, used by the grasp stage and the joint-grasp planner):
    lift_candidates(centre, up, lift, lift_min, ...) -> LiftCandidates   (sampled end poses of the object's lift)
    arms_ik(arms {name: LiftArm}, S {name: T_b1_g}, candidates) -> {name: (Q, ok)}   (batched, staged IK)
    lift_costs(candidates, ik, arms, terms=LIFT_COSTS) -> {term: (N,)};  rank_lifts(...) -> (K,) best first
    object_motion(candidates, i, path=LIFT_PATHS[0]) -> (K, 4, 4)   (the object's motion along candidate i, 1 cm
                 steps; LIFT_PATHS: over which part of the rise it moves sideways)
    along(candidates, s) -> (N, 4, 4)   (every candidate's motion at fraction s of its lift)

Straight moves on one IK branch (``_path``, the task planner's Cartesian moves):
    line_poses(T0, T1, n=None) -> (n, 4, 4)   (a pose every WAYPOINT_STEP m and 0.05 rad, ends included)
    follow_poses({arm: solve}, {arm: (K,4,4)}, {arm: q0 (J,)}) -> ({arm: (K',J)}, PathFailure | None)
    MAX_JOINT_JUMP: rad per waypoint step above which a step is split to tell a branch switch from fast motion
"""

from __future__ import annotations

from bimanual_app.kinematics._ik import IKResult, IKSolver
from bimanual_app.kinematics._lift import (
    LIFT_COSTS,
    LIFT_PATHS,
    LiftArm,
    LiftCandidates,
    along,
    arms_ik,
    lift_candidates,
    lift_costs,
    object_motion,
    rank_lifts,
)
from bimanual_app.kinematics._path import MAX_JOINT_JUMP, WAYPOINT_STEP, PathFailure, follow_poses, line_poses

__all__ = ["IKResult", "IKSolver", "solve_ik", "LIFT_COSTS", "LIFT_PATHS", "LiftArm", "LiftCandidates", "along", "arms_ik",
           "lift_candidates", "lift_costs", "object_motion", "rank_lifts", "MAX_JOINT_JUMP", "WAYPOINT_STEP",
           "PathFailure", "follow_poses", "line_poses"]

_CACHE: dict[tuple[int, str | None], IKSolver] = {}


def solve_ik(robot, T_target, q_current=None, link: str | None = None, position_only: bool = False,
             n_solutions: int = 1) -> IKResult:
    """IK of ``link`` (default: gripper frame, else ee link) to ``T_target`` (4,4) in the robot's base frame."""
    key = (id(robot), link)
    solver = _CACHE.get(key)
    if solver is None or solver.robot is not robot:
        solver = _CACHE[key] = IKSolver(robot, link=link)
    return solver.solve(T_target, q_current=q_current, position_only=position_only, n_solutions=n_solutions)
