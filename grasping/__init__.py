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
CLI: ``bijcr grasp SCENE_DIR_OR_CLOUD --segments DIR/segments.npz --out DIR [--calibration calibration.json]``.
"""

from ._antipodal import GraspSet, SamplerParams, rotate_about_approach, sample_grasps
from ._arms import Arm, ArmGrasps, TwoArmCheck, make_arms, reachable_grasps
from ._collision import GripperCollider, SceneOctree, grippers_collide, grippers_distance
from ._gripper import GripperModel, GripperShape, load_gripper
from ._handover import Handover, HandoverParams
from ._inputs import SceneCloud, b2b_sigma, load_calibration, load_cloud, load_segments, resolve_inputs, scene_cloud
from ._joint import JointPair
from ._objects import ObjectGeometry, Support, check_graspable, estimate_support, object_geometry
from ._output import draw_plan, plan_to_dict, write_grasps_json
from ._plan import GraspPlan, ObjectPlan, PlanParams, plan_grasps
from ._push import PushParams, push_contacts
from ._reach import ArmReach, ReachFilter, ReachResult, callable_filter, pregrasp_pose
from ._stage import GraspStage, grasp_stage

__all__ = [
    "load_gripper", "GripperModel", "GripperShape",
    "plan_grasps", "PlanParams", "GraspPlan", "ObjectPlan",
    "sample_grasps", "SamplerParams", "GraspSet", "rotate_about_approach",
    "push_contacts", "PushParams", "JointPair", "Handover", "HandoverParams",
    "make_arms", "Arm", "ArmGrasps", "reachable_grasps", "TwoArmCheck",
    "ArmReach", "ReachFilter", "ReachResult", "callable_filter", "pregrasp_pose",
    "GripperCollider", "SceneOctree", "grippers_collide", "grippers_distance",
    "SceneCloud", "scene_cloud", "load_cloud", "load_segments", "load_calibration", "b2b_sigma", "resolve_inputs",
    "ObjectGeometry", "Support", "estimate_support", "object_geometry", "check_graspable",
    "plan_to_dict", "write_grasps_json", "draw_plan", "grasp_stage", "GraspStage",
]
