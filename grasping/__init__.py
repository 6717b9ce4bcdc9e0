"""Grasps for the Piper parallel gripper on segmented objects, in the primary base frame b1.

Public API:
    load_gripper(robot="piper") -> GripperModel        finger / palm geometry from the robot's URDF
    plan_grasps(cloud, gripper, arms, T_b1_b2, params) -> GraspPlan
        per object: antipodal single-arm grasps, each arm's reachable ones, joint pairs, a hand-over
    make_arms(robot, gripper, T_b1_b2) -> {"primary": Arm, "secondary": Arm}   (IK + collision reach filters)
    sample_grasps(geo, support, gripper, collider, others, params) -> (GraspSet, stats)
    ArmReach / ReachResult / ReachFilter               pluggable reachability: T_b_g (N,4,4) -> mask + joints
    callable_filter(predicate)                          a reach filter from a plain predicate on poses (tests)
    scene_cloud(points, labels) / load_cloud / load_segments / load_calibration / b2b_sigma / resolve_inputs
    write_grasps_json(path, plan) / plan_to_dict(plan) / draw_plan(path, plan, points, labels)
    rotate_about_approach(T_b_g)                        the same grasp turned 180 degrees about z
    grasp_stage(cloud, segments, out_dir, calibration=None, ...) -> GraspStage   (bijcr grasp / run)
    redraw_handovers(cloud, segments, calibration, object_id, refused_picks) -> [hand-over dicts]   the search
        run again on one object without picks a task's preview saw fail (nothing written)
    lift_clear(collider, scene, lifts, T_b1_g, width, margin) -> (C,) bool   a gripper clear along sampled lifts
    HANDOVER_FALLBACKS: name -> what it does, the hand-over search's fallbacks (grasp_stage(leave_out=...))
CLI: ``bijcr grasp SCENE_DIR_OR_CLOUD --segments DIR/segments.npz --out DIR [--calibration calibration.json]``.
"""

from __future__ import annotations

from bimanual_app.lazy import lazy_exports

# name -> private module; imported on first use (PEP 562), so that ``bijcr --help`` and a mistyped
# ``bijcr grasp`` answer without loading scipy, Open3D or coal.
_EXPORTS = {
    "GraspSet": "_antipodal", "SamplerParams": "_antipodal", "rotate_about_approach": "_antipodal", "sample_grasps": "_antipodal",
    "Arm": "_arms", "ArmGrasps": "_arms", "TwoArmCheck": "_arms", "make_arms": "_arms", "reachable_grasps": "_arms",
    "GripperCollider": "_collision", "SceneOctree": "_collision", "grippers_collide": "_collision", "grippers_distance": "_collision",
    "GripperModel": "_gripper", "GripperShape": "_gripper", "load_gripper": "_gripper",
    "Handover": "_handover", "HandoverParams": "_handover", "HANDOVER_FALLBACKS": "_handover",
    "SceneCloud": "_inputs", "b2b_sigma": "_inputs", "load_calibration": "_inputs", "load_cloud": "_inputs", "load_segments": "_inputs", "resolve_inputs": "_inputs", "scene_cloud": "_inputs",
    "JointPair": "_joint", "lift_clear": "_joint",
    "ObjectGeometry": "_objects", "Support": "_objects", "check_graspable": "_objects", "estimate_support": "_objects", "object_geometry": "_objects",
    "draw_plan": "_output", "plan_to_dict": "_output", "write_grasps_json": "_output",
    "GraspPlan": "_plan", "ObjectPlan": "_plan", "PlanParams": "_plan", "plan_grasps": "_plan",
    "PushParams": "_push", "push_contacts": "_push",
    "ArmReach": "_reach", "ReachFilter": "_reach", "ReachResult": "_reach", "callable_filter": "_reach", "pregrasp_pose": "_reach",
    "GraspStage": "_stage", "grasp_stage": "_stage", "redraw_handovers": "_stage",
}

__all__ = [
    "load_gripper", "GripperModel", "GripperShape", "plan_grasps", "PlanParams", "GraspPlan",
    "ObjectPlan", "sample_grasps", "SamplerParams", "GraspSet", "rotate_about_approach", "push_contacts",
    "PushParams", "JointPair", "lift_clear", "Handover", "HandoverParams", "make_arms", "Arm",
    "ArmGrasps", "reachable_grasps", "TwoArmCheck", "ArmReach", "ReachFilter", "ReachResult",
    "callable_filter", "pregrasp_pose", "GripperCollider", "SceneOctree", "grippers_collide", "grippers_distance",
    "SceneCloud", "scene_cloud", "load_cloud", "load_segments", "load_calibration", "b2b_sigma",
    "resolve_inputs", "ObjectGeometry", "Support", "estimate_support", "object_geometry", "check_graspable",
    "plan_to_dict", "write_grasps_json", "draw_plan", "grasp_stage", "GraspStage", "redraw_handovers",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
