"""Collision world: arms in frame b1 against the scene map (coal octree), each other and themselves.

Public API:
    SceneMap(points_b1 (N,3), resolution=0.01, ...)       octree + distance field of the scene cloud
    shared_scene_map(points_b1, resolution, pad, crop)    the same, built once per process per cloud
    clear_shared_maps()                                   frees the maps shared_scene_map keeps
    CollisionWorld(robot, T_b1_b2=None, scene=None, *, robot2=None, resolution=0.01, margin=0.01,
                   self_margin=0.0, openings=(0, 0), crop=True, scene_exempt=(), T_b1_b=None)
        .valid(q1, q2=None) -> bool, .valid_batch(Q1, Q2=None) -> (N,) bool, .explain(q1, q2) -> [str]
        .distance(q1, q2=None) -> DistanceReport (coal distances, closest pairs)
        .cut(mask), .attach(arm, points_b1, q), .detach(arm), .motion_bound(arm, dq)
        .near_arms(points_b1 (N,3), [q1, q2], pad) -> (N,) bool: the points the arms take up there
"""

from bimanual_app.collision._scene_map import SceneMap, clear_shared_maps, shared_scene_map
from bimanual_app.collision._world import ARM_NAMES, CollisionWorld, DistanceReport

__all__ = ["SceneMap", "shared_scene_map", "clear_shared_maps", "CollisionWorld", "DistanceReport", "ARM_NAMES"]
