"""PyBullet preview of bimanual plans with physics: both arms at their base poses, the reconstruction
injected (table plane, one collision body per segmented object), force-limited grippers, recorded frames
and physical success checks.

Public API:
    PreviewWorld(robot, T_b1_b2, gui=False, dt=1/240, recorder=None): the world (frame b1);
        .arms["primary"|"secondary"] -> SimArm, .add_table(TablePlane), .add_object(name, BodyShape, ...),
        .run_plan({arm: trajectory}), .hold(s), .object_pose(obj), .height(obj), .on_table(obj), .close()
    SimArm: .reset(q, width), .command(q, qd), .set_gripper(width, force), .q(), .width(), .tcp_pose(),
        .finger_forces(body), .holds(body), .touches(body)
    TablePlane, BodyShape, fit_table(points, labels), table_from_plane(normal, d, points),
        shape_from_points(points, table, kind="hull"|"box"|"auto"), box_shape(T_b1_o, size, mass, kind),
        trim_outer(points, up), box_from_faces(points, up, table) -> (box, boxness),
        BodyShape.surface_points_b1(), BodyShape.contains(points, margin)
    table_from_segments(points, labels, extras), estimated_shapes(points, labels, table, kind="auto"),
        truth_shapes(gt_objects), match_truth(est, truth), build_world(robot, T_b1_b2, table, est, truth, ...)
    HoldMonitor(world, obj): .lifted_and_held(arms, rise=0.10, hold_s=2.0, exclusive=False) -> HoldVerdict
    Recorder(width, height, fps): frames -> .save_gif(path), .keyframe(name), .save_keyframes(folder)
"""

from ._bodies import (
                      BodyShape,
                      TablePlane,
                      box_from_faces,
                      box_shape,
                      fit_table,
                      remove_outliers,
                      shape_from_points,
                      table_from_plane,
                      trim_outer,
)
from ._checks import HoldMonitor, HoldSample, HoldVerdict
from ._record import Recorder, default_camera
from ._scene import build_world, estimated_shapes, match_truth, table_from_segments, truth_shapes
from ._world import GRIP_FORCE, PreviewWorld, SimArm, SimObject

__all__ = [
    "PreviewWorld", "SimArm", "SimObject", "GRIP_FORCE",
    "TablePlane", "BodyShape", "fit_table", "table_from_plane", "shape_from_points", "box_shape", "remove_outliers",
    "trim_outer", "box_from_faces",
    "table_from_segments", "estimated_shapes", "truth_shapes", "match_truth", "build_world",
    "HoldMonitor", "HoldSample", "HoldVerdict", "Recorder", "default_camera",
]
