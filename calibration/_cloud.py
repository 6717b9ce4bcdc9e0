"""Metric point cloud in b1 from the reconstruction's point maps (paper, "Obtaining Metric-Scale 3D
Representation"): confidence filter, then ``x_b1 = T_b1_w (scale * x_w)``."""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape

#: default confidence rule when no threshold is given: keep conf > AUTO_CONF_FRACTION * median(conf > 0).
#: Confidence scales differ between producers (DUSt3R >= 1, COLMAP maps in (0, 2], synthetic [1, 10]),
#: so a fixed number cannot serve them all; relative to the median it drops the background / hole-filled
#: / depth-edge points every producer marks low, and keeps the body of the map.
AUTO_CONF_FRACTION = 0.2


def auto_conf_threshold(conf: np.ndarray) -> float:
    """The default threshold for confidences ``conf`` (any shape)."""
    pos = conf[conf > 0]
    return float(AUTO_CONF_FRACTION * np.median(pos)) if pos.size else 0.0


def kept_pixels(pts3d: np.ndarray, conf: np.ndarray | None = None, conf_threshold: float | None = None
                ) -> tuple[np.ndarray, float | None]:
    """``(keep (M, H, W) bool, threshold used or None)``: the point-map pixels the metric cloud keeps, finite and
    (with ``conf`` (M, H, W)) of confidence above ``conf_threshold`` (None: :func:`auto_conf_threshold`) and 0."""
    keep = np.all(np.isfinite(pts3d), axis=-1)
    thr = None
    if conf is not None:
        conf = check_shape("conf", conf, pts3d.shape[:3])
        thr = auto_conf_threshold(conf) if conf_threshold is None else float(conf_threshold)
        keep &= (conf > thr) & (conf > 0)
    return keep, thr


def metric_cloud(pts3d: np.ndarray, T_b1_w: np.ndarray, scale: float, conf: np.ndarray | None = None,
                 colors: np.ndarray | None = None, conf_threshold: float | None = None
                 ) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """Confidence-filtered metric points in b1.

    Args:
        pts3d: (M, H, W, 3) point maps in the reconstruction frame w.
        T_b1_w: (4, 4); scale: metric = scale * w units.
        conf: (M, H, W) confidences (higher is better) or None (keep every finite point).
        colors: (M, H, W, 3) uint8 or None.
        conf_threshold: keep ``conf > conf_threshold``; None: :func:`auto_conf_threshold`. Points with
            conf <= 0 are always dropped.

    Returns:
        ``(points (K, 3) float64, colors (K, 3) uint8 or None, info)``.
    """
    pts3d = check_shape("pts3d", pts3d, (None, None, None, 3))
    keep, thr = kept_pixels(pts3d, conf, conf_threshold)
    p = pts3d[keep].astype(np.float64) * scale
    p = p @ np.ascontiguousarray(T_b1_w[:3, :3].T) + T_b1_w[:3, 3]  # contiguous: BLAS, not numpy's slow loop
    c = None
    if colors is not None:
        c = check_shape("colors", colors, pts3d.shape)[keep].astype(np.uint8)
    return p, c, {"points": int(len(p)), "of": int(keep.size), "conf_threshold": thr}
