"""Bimanual tasks: joint grasp and hand-over, planned on the motion layer, previewed in PyBullet with
physics, approved, and (on request) executed on the hardware.

Public API:
    run_task(TaskOptions(task, scene, object_id=None, work=None, out=None, gui=False, execute=None,
             truth_objects=False, plan_time=5.0, ...)) -> TaskResult
    TaskPlan / Phase: a plan as phases of JointTrajectory per arm; .timeline() -> {arm: JointTrajectory}
    plan_joint_grasp(motion, JointChoice, q_start, width_start) -> TaskPlan
    plan_handover(motion, HandoverChoice, q_start, width_start, object_points) -> TaskPlan
    TaskMotion: the motion layer for one task (IK, OMPL, Cartesian moves, validation, collision contexts)
    preview_plan(plan, inputs, robot, object_id, truth=False) -> PreviewResult
    check_calibration_scene(scene, calibration, path): refuses a calibration of another scene
CLI: ``bijcr task joint-grasp|handover SCENE`` (bimanual_app/tasks/cli.py). See docs/tasks.md.
"""

from ._grasps import GraspSpec, HandoverChoice, JointChoice, handover_candidates, joint_candidates
from ._inputs import TaskInputs, check_calibration_scene, ensure_stages, load_inputs, stage_paths
from ._motion import PlanFailure, TaskMotion
from ._plan import Phase, TaskPlan
from ._planners import plan_handover, plan_joint_grasp
from ._preview import PreviewResult, preview_plan
from ._run import TaskOptions, TaskResult, run_task

__all__ = [
    "run_task", "TaskOptions", "TaskResult", "TaskPlan", "Phase", "plan_joint_grasp", "plan_handover",
    "TaskMotion", "PlanFailure", "preview_plan", "PreviewResult", "GraspSpec", "JointChoice", "HandoverChoice",
    "joint_candidates", "handover_candidates", "TaskInputs", "check_calibration_scene", "ensure_stages",
    "load_inputs", "stage_paths",
]
