"""Motion planning for one or both arms in frame b1: OMPL paths, time parametrisation, dense validation.

Public API:
    BimanualSetup(robot, T_b1_b2=None, points_b1=None, *, margin=0.01, speed=0.5, ...)
        .plan_reach(arm, T_b1_target, q_now, position_only=False) -> MotionPlan
        .plan_configurations(arms, q_start, goals, q_now) -> MotionPlan   (one arm, or both: 12 DoF)
        .ik(arm, T_b1_target, q_current) -> IKResult, .world (CollisionWorld), .check(q_now)
    MotionPlan: success, message, trajectories (arm -> Trajectory(times, q)), validation, to_json()
    plan_path(space, q_start, goals) -> PathResult; JointSpace(world, arms, hold)
    parametrize(waypoints, vmax, amax) -> BlendedTrajectory; validate_samples(space, times, Q)
    default_ready(robot) -> (J,) a configuration clear of the table
CLI: ``bijcr reach`` (bimanual_app/planning/cli.py).
"""

from bimanual_app.planning._motion import BimanualSetup, MotionPlan, Trajectory, default_ready
from bimanual_app.planning._ompl_plan import PathResult, plan_path
from bimanual_app.planning._space import JointSpace
from bimanual_app.planning._time import BlendedTrajectory, parametrize
from bimanual_app.planning._validate import ValidationReport, validate_samples

__all__ = [
    "BimanualSetup", "MotionPlan", "Trajectory", "default_ready", "PathResult", "plan_path", "JointSpace",
    "BlendedTrajectory", "parametrize", "ValidationReport", "validate_samples",
]
