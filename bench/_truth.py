"""Ground-truth stage outputs for the task bench's reference rows (synthetic scenes only).

- ``gt`` (ground-truth transforms): calibration.json from ground_truth.yaml, the true metric cloud
  (``bimanual_app.synth.ground_truth_cloud``) as scene_b1.ply and the true depth views it comes from as
  views.npz; the segmenter and the grasp stage then run on it as in the pipeline.
- ``oracle`` (ground-truth transforms and objects): the same, and segments.npz labelled with the true
  objects (the label each rendered pixel's mask gives its point) instead of the segmenter's: what the
  planners can do with perfect perception of what the cameras saw.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np

VOXEL = 0.002  # the true cloud's spacing (m): one point per 2 mm cube, the first seen
# Objects with fewer true points than this are left as background: a few pixels at the edge of a view
# (an object hidden behind another) define no shape to grasp; at 2 mm spacing this is about 2 cm^2 of surface.
MIN_OBJECT_POINTS = 50
TABLE_BAND = 0.003  # table band of a noise-free cloud: the segmenter's smallest (segmentation._table.MIN_BAND)


def truth_cloud(scene_path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (N, 3) b1 metres, colours (N, 3) uint8, true object id (N,) int32 or -1) of a synthetic scene."""
    from bimanual_app.synth import ground_truth_cloud

    return ground_truth_cloud(scene_path, voxel=VOXEL)


def write_gt_calibration(scene_path: Path, cal_dir: Path, cloud=None) -> float:
    """calibration.json from the ground truth and the true cloud as scene_b1.ply (when missing, or always
    when ``cloud`` = (points, colours) is given); returns the seconds spent."""
    import open3d as o3d

    from bimanual_app.io_utils import atomic_path, write_json
    from bimanual_app.scene import load_scene
    from bimanual_app.scene.truth import ground_truth_views
    from bimanual_app.views import VIEWS_FILE, write_views

    if cloud is None and (cal_dir / "calibration.json").exists() and (cal_dir / "scene_b1.ply").exists():
        return 0.0
    t = time.perf_counter()
    scene = load_scene(scene_path)
    gt = scene.ground_truth
    T_b1_w = np.linalg.inv(np.asarray(gt.extras["T_w_b1"], dtype=np.float64))
    pts, cols = cloud if cloud is not None else truth_cloud(scene_path)[:2]
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.colors = o3d.utility.Vector3dVector(cols.astype(np.float64) / 255.0)
    cal_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(cal_dir / "scene_b1.ply") as tmp:
        o3d.io.write_point_cloud(str(tmp), pc)
    # the true depth views, as `bijcr calibrate` writes the estimated ones (what the cameras saw through)
    write_views(cal_dir / VIEWS_FILE, ground_truth_views(scene_path))
    write_json(cal_dir / "calibration.json", {
        "format": 1, "scene": scene.name, "scale": gt.scale, "T_e1_c1": gt.T_e1_c1, "T_e2_c2": gt.T_e2_c2,
        "T_b1_w": T_b1_w, "T_b2_w": np.linalg.inv(gt.T_b1_b2) @ T_b1_w, "T_b1_b2": gt.T_b1_b2,
        "views_used": {"primary": len(scene.primary), "secondary": len(scene.secondary)},
        "residuals": {"rotation_rad": 0.0, "translation_m": 0.0}, "method": "ground truth (bench/tasks.py)"})
    return time.perf_counter() - t


def oracle_segments(points: np.ndarray, truth_ids: np.ndarray, T_b1_t: np.ndarray, table_size):
    """A ``segmentation.SegmentResult`` holding the true objects of a cloud.

    Args:
        points: (N, 3) b1 metres.
        truth_ids: (N,) int: the true object id of each point (ground_truth.yaml ``objects[].id``), -1 for
            the table, the floor and anything else that is no object.
        T_b1_t: (4, 4) the true table frame (z up, origin on the top face), ground_truth.yaml ``table``.
        table_size: its length and width (m).
    Returns:
        The result (labels (N,) int32: -1 table/background, 0..K-1 objects, largest first as the segmenter
        numbers them; ``stats["truth_ids"]``: the true id of each label) for ``segmentation.write_segments``.
    """
    from segmentation import SegmentResult, TablePlane
    from segmentation._summary import summarize  # the segmenter's own boxes, so both rows describe objects alike

    points = np.asarray(points, dtype=np.float64)
    truth_ids = np.asarray(truth_ids).astype(np.int64)
    if points.ndim != 2 or points.shape[1] != 3 or truth_ids.shape != (len(points),):
        raise ValueError(f"oracle_segments: points (N, 3) and truth_ids (N,), got {points.shape}, {truth_ids.shape}")
    T_b1_t = np.asarray(T_b1_t, dtype=np.float64).reshape(4, 4)
    ids, counts = np.unique(truth_ids[truth_ids >= 0], return_counts=True)
    keep = [int(i) for i, c in sorted(zip(ids, counts), key=lambda ic: (-ic[1], ic[0])) if c >= MIN_OBJECT_POINTS]
    labels = np.full(len(points), -1, dtype=np.int32)
    for new, old in enumerate(keep):
        labels[truth_ids == old] = new
    n = T_b1_t[:3, 2]
    half = 0.5 * np.asarray(table_size, dtype=np.float64).reshape(-1)[:2]
    outline = np.array([[-half[0], -half[1]], [half[0], -half[1]], [half[0], half[1]], [-half[0], half[1]]])
    table = TablePlane(normal=n, offset=float(-n @ T_b1_t[:3, 3]), sigma=0.0, min_height=TABLE_BAND, T_b1_t=T_b1_t,
                       outline=outline, extent=2.0 * half, inliers=int(np.count_nonzero(labels < 0)),
                       fraction=float(np.mean(labels < 0)) if len(labels) else 0.0)
    stats = {"source": "ground truth (bench oracle)", "truth_ids": keep,
             "left_as_background": [int(i) for i in ids if int(i) not in keep]}
    return SegmentResult(labels=labels, table=table, objects=summarize(points, labels, table), voxel=VOXEL,
                         stats=stats)


def write_oracle_inputs(scene_path: Path, work: Path) -> float:
    """calibration/ (ground truth, true cloud) and segments/ (true objects) under ``work`` when
    segments.npz is missing; the grasp stage's old output is removed then. Returns the seconds spent."""
    from bimanual_app.scene import load_scene
    from segmentation import write_segments

    seg_dir = work / "segments"
    if (seg_dir / "segments.npz").exists() and (work / "calibration" / "scene_b1.ply").exists():
        return 0.0
    t = time.perf_counter()
    shutil.rmtree(work / "grasps", ignore_errors=True)
    pts, cols, ids = truth_cloud(scene_path)
    # the cloud and its labels are written together, so the labels follow the PLY's point order
    write_gt_calibration(scene_path, work / "calibration", cloud=(pts, cols))
    table = load_scene(scene_path).ground_truth.extras["table"]
    res = oracle_segments(pts, ids, np.asarray(table["T_b1_t"]), table["size"][:2])
    write_segments(seg_dir, res, pts, source=str(work / "calibration" / "scene_b1.ply"))
    return time.perf_counter() - t
