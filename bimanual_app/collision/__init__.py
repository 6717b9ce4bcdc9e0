"""Collision world: arms in frame b1 against the scene map (coal octree), each other and themselves.

Public API:
    SceneMap(points_b1 (N,3), resolution=0.01, ...)       octree + distance field of the scene cloud
    CollisionWorld(robot, T_b1_b2=None, scene=None, *, robot2=None, resolution=0.01, margin=0.01,
                   self_margin=0.0, openings=(0, 0))
        .valid(q1, q2=None) -> bool, .valid_batch(Q1, Q2=None) -> (N,) bool, .explain(q1, q2) -> [str]
        .distance(q1, q2=None) -> DistanceReport (coal distances, closest pairs)
        .cut(mask), .attach(arm, points_b1, q), .detach(arm), .motion_bound(arm, dq)
"""

from bimanual_app.collision._scene_map import SceneMap
from bimanual_app.collision._world import ARM_NAMES, CollisionWorld, DistanceReport

__all__ = ["SceneMap", "CollisionWorld", "DistanceReport", "ARM_NAMES"]
