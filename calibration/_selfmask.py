"""Pixels of a wrist camera that see its own gripper (the rig), found from the point maps alone.

A wrist camera moves with its gripper, so the fingers sit at the same place in every image of that arm,
at the same depth: in the camera's own frame their points barely change from view to view, while every
point of the scene moves as the camera moves. Left in the fused cloud they become floating blobs at
each capture pose, which every later stage (segmentation, collision map, grasp clearance) would take
for obstacles. Real wrist cameras (Piper with a RealSense, Franka hand cameras) see their fingers the
same way; this finds them with no mesh and no calibration of the gripper.

Written with numpy because it is a per-pixel statistic over the views, not a geometry operation any of
the point-cloud libraries offer.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape

from ._fusion import points_in_cameras

__all__ = ["wrist_rig_pixels"]

MIN_AGREE = 0.6  # fraction of an arm's views in which a pixel must sit at the same camera-frame point
REL_TOL = 0.05  # "the same point": within this fraction of its distance from the camera
NEAR_FRACTION = 0.5  # and nearer than this fraction of the view's median depth (the rig is close)


def _nanmedian0(a: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=0)`` (NaN where a column has no number), the same values: the middle of the
    sorted numbers, the mean of the two middle ones for an even count. numpy computes it for a short axis
    through masked arrays, about ten times slower than sorting (NaNs sort last)."""
    s = np.sort(a, axis=0)
    n = np.sum(~np.isnan(a), axis=0)
    h = n // 2
    lo = np.take_along_axis(s, np.where(n % 2 == 1, h, np.maximum(h - 1, 0))[None], axis=0)[0]
    hi = np.take_along_axis(s, h[None], axis=0)[0]  # n = 0: index 0 is a NaN already
    return np.where(n > 0, (lo + hi) / 2.0, np.nan)


def wrist_rig_pixels(pts3d_w: np.ndarray, T_w_c: np.ndarray, min_agree: float = MIN_AGREE,
                     rel_tol: float = REL_TOL, near_fraction: float = NEAR_FRACTION) -> np.ndarray:
    """(H, W) bool: the pixels where one arm's wrist camera sees its own rig.

    Args:
        pts3d_w: (V, H, W, 3) point maps of one arm's V views in the reconstruction frame w (any scale;
            non-finite points are allowed).
        T_w_c: (V, 4, 4) the matching camera poses in w.
        min_agree: a pixel is the rig when, in at least this fraction of the views, its camera-frame
            point lies within ``rel_tol`` (relative to its distance) of the pixel's median camera-frame
            point, and nearer than ``near_fraction`` of that view's median depth.

    With fewer than 3 views nothing can be told apart (a scene point seen from two nearby poses also
    barely moves): returns all False.
    """
    P = check_shape("pts3d", np.asarray(pts3d_w), (None, None, None, 3))
    T = check_shape("T_w_c", np.asarray(T_w_c, dtype=np.float64), (P.shape[0], 4, 4))
    V, H, W = P.shape[:3]
    if V < 3:
        return np.zeros((H, W), dtype=bool)
    Pc = points_in_cameras(P.astype(np.float64), T)
    finite = np.all(np.isfinite(Pc), axis=-1)
    Pc = np.where(finite[..., None], Pc, np.nan)
    med = _nanmedian0(Pc)  # pixels empty in every view give NaN medians, which fail the test below
    dist = np.linalg.norm(med, axis=-1)
    dev = np.linalg.norm(Pc - med, axis=-1)
    z = Pc[..., 2]
    z_view = np.array([np.nanmedian(z[v][finite[v]]) if finite[v].any() else np.inf for v in range(V)])
    with np.errstate(invalid="ignore"):
        same = (dev <= rel_tol * dist) & (z < near_fraction * z_view[:, None, None]) & finite
    return same.mean(axis=0) >= min_agree
