"""Bimanual tasks: joint grasp and hand-over, planned on the motion layer, previewed in PyBullet with
physics, approved, and (on request) executed on the hardware.

Public API (imported lazily, so ``bijcr --help`` loading ``bimanual_app.tasks.cli`` stays light):
    run_task(TaskOptions(task, scene, object_id=None, work=None, out=None, gui=False, execute=None,
             truth_objects=False, plan_time=5.0, ...)) -> TaskResult
    TaskPlan / Phase: a plan as phases of JointTrajectory per arm; .timeline() -> {arm: JointTrajectory}
    plan_joint_grasp(motion, JointChoice, q_start, width_start) -> TaskPlan
    plan_handover(motion, HandoverChoice, q_start, width_start, object_points) -> TaskPlan
    FALLBACKS: name -> what it does, the planner's fallbacks (TaskOptions.leave_out leaves them out; a plan
        lists those it took in info["fallbacks"]); fallback_names(): every name leave_out takes (these, then
        grasping.HANDOVER_FALLBACKS)
    TaskMotion: the motion layer for one task (IK, OMPL, Cartesian moves, validation, collision contexts)
    preview_plan(plan, inputs, robot, object_id, truth=False) -> PreviewResult
    last_loss(preview.object_track) -> {held_after, by, lost_after, rise_m} | None: where a failed preview lost
        the object (the phase after which no arm held it any more)
    check_calibration_scene(scene, calibration, path): refuses a calibration of another scene
    joint_candidates / handover_candidates(grasps_json, path): the tasks' inputs from grasps.json
CLI: ``bijcr task joint-grasp|handover SCENE`` (bimanual_app/tasks/cli.py). See docs/tasks.md.
"""

from __future__ import annotations

from bimanual_app.lazy import lazy_exports

_EXPORTS = {
    "run_task": "_run", "TaskOptions": "_run", "TaskResult": "_run", "fallback_names": "_run",
    "TaskPlan": "_plan", "Phase": "_plan",
    "plan_joint_grasp": "_planners", "plan_handover": "_planners", "FALLBACKS": "_planners",
    "TaskMotion": "_motion", "PlanFailure": "_motion", "robot_points_mask": "_motion",
    "preview_plan": "_preview", "PreviewResult": "_preview", "last_loss": "_preview",
    "GraspSpec": "_grasps", "JointChoice": "_grasps", "HandoverChoice": "_grasps",
    "joint_candidates": "_grasps", "handover_candidates": "_grasps",
    "TaskInputs": "_inputs", "check_calibration_scene": "_inputs", "ensure_stages": "_inputs",
    "load_inputs": "_inputs", "stage_paths": "_inputs",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
