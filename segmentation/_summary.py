"""Per-object summaries: point count, centroid, and a table-aligned oriented bounding box."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._parts import reaches_table
from ._table import TablePlane


@dataclass
class ObjectSummary:
    """One segmented object, in b1 (metres).

    Attributes:
        id: its label (0..K-1).
        points: number of input points with this label.
        centroid: (3,) mean of its points.
        center: (3,) centre of the oriented bounding box.
        rotation: (3, 3) ``R_b1_box``: columns are the box axes in b1 (x the longer horizontal side,
            z the table normal).
        extents: (3,) box size along its axes: length, width, height (m).
    """

    id: int
    points: int
    centroid: np.ndarray
    center: np.ndarray
    rotation: np.ndarray
    extents: np.ndarray

    def as_dict(self) -> dict:
        return {"id": self.id, "points": self.points, "centroid": self.centroid.tolist(),
                "obb": {"center": self.center.tolist(), "rotation": self.rotation.tolist(),
                        "extents": self.extents.tolist()}}


def oriented_box(points_t: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Box of points (M, 3) in the table frame, upright on the table.

    The yaw comes from OpenCV's minimum-area rectangle of the x-y footprint; the sides from the 0.5th and
    99.5th percentiles along the rectangle's axes (stray points do not inflate it); the height from the
    table (when the object reaches it) to the 99.5th percentile of the heights. An upright box rather than
    a free PCA box because objects stand on the table: its height is then their height.
    Returns ``(center_t (3,), yaw, extents (3,))``.
    """
    import cv2

    xy = points_t[:, :2]
    (_, _), (_, _), ang = cv2.minAreaRect(xy.astype(np.float32))
    yaw = np.deg2rad(ang)
    c, s = np.cos(yaw), np.sin(yaw)
    Rz = np.array([[c, -s], [s, c]])
    q = xy @ Rz
    lo, hi = np.percentile(q, [0.5, 99.5], axis=0)
    z = points_t[:, 2]
    top = np.percentile(z, 99.5)
    zmin = float(np.percentile(z, 0.2))
    bottom = 0.0 if reaches_table(zmin, float(top)) else zmin
    ext = np.r_[hi - lo, top - bottom]
    mid = Rz @ (0.5 * (lo + hi))
    if ext[1] > ext[0]:  # x along the longer side
        yaw += np.pi / 2
        ext[:2] = ext[1::-1]
    yaw = (yaw + np.pi / 2) % np.pi - np.pi / 2
    return np.r_[mid, 0.5 * (bottom + top)], float(yaw), ext


def summarize(points: np.ndarray, labels: np.ndarray, table: TablePlane, max_points: int = 40_000,
              seed: int = 0) -> list[ObjectSummary]:
    """Summaries of objects 0..K-1 of ``labels`` (N,) over ``points`` (N, 3, b1)."""
    rng = np.random.default_rng(seed)
    K = int(labels.max()) + 1 if len(labels) and labels.max() >= 0 else 0
    if K == 0:
        return []
    idx = np.flatnonzero(labels >= 0)
    order = idx[np.argsort(labels[idx], kind="stable")]
    counts = np.bincount(labels[idx], minlength=K)
    out = []
    start = 0
    R_t, t_t = table.T_b1_t[:3, :3], table.T_b1_t[:3, 3]
    for k in range(K):
        sel = order[start:start + counts[k]]
        start += counts[k]
        pts = points[sel]
        cen = pts.mean(0)
        if len(pts) > max_points:
            pts = pts[rng.choice(len(pts), max_points, replace=False)]
        center_t, yaw, ext = oriented_box(table.to_table(pts))
        c, s = np.cos(yaw), np.sin(yaw)
        R = R_t @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        out.append(ObjectSummary(k, int(counts[k]), cen, R_t @ center_t + t_t, R, ext))
    return out
