"""Multi-view consistency of the point maps: drop the points the other views see through.

A foundation model's (or SfM's) per-view point maps disagree where a view's pose or depth is off: a
view registered 2 cm too high lays a second table 2 cm over the real one, and a wrist camera's view of
the other arm or of its own fingers puts floating blobs where the other views see free space. Fused
as they are, those points become phantom obstacles for the collision map and phantom objects for the
segmenter. This is the free-space test of depth-map fusion (as in COLMAP's stereo fusion or KinectFusion's
visibility checks): a point of view v is projected into every other view u; if it lies clearly *in
front of* the surface u sees at that pixel, u looked through the place where the point claims to be
(a vote against it); if it lies on that surface, a vote for it; behind it, u cannot tell (occluded).
A point with at least ``min_votes`` votes against and more against than for is dropped.

Everything stays in the reconstruction's own frame and scale (tolerances are relative to depth). The
intrinsics of each point map are fitted from the map itself (each pixel's camera-frame ray), so the
test needs nothing but ``pts3d`` and ``T_w_c``.

Written with numpy: the test is a projection and a per-pixel comparison over all view pairs, which
Open3D's and pycolmap's fusion only offer on their own depth-map formats and files.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape
from bimanual_app.views import filter3, pinhole_pixels

__all__ = ["confirmed_points", "free_space_outliers", "pointmap_intrinsics", "view_votes"]

TOL_REL = 0.05  # a point is "in front of" a surface when nearer than (1 - TOL_REL) times its depth
MIN_VOTES = 2
# A point its own map marks unsure (low confidence: a surface seen at a grazing angle, a depth edge) is kept
# where this many other views saw a surface at the same place, within CONFIRM_TOL of depth, and none saw
# through it: the multi-view consistency test of depth-map fusion (COLMAP's fusion keeps a pixel that
# enough views agree on), which keeps the steep sides of objects that no view sees squarely
MIN_CONFIRMING_VIEWS = 2
CONFIRM_TOL = 0.01


MAX_FIT_RMS_PX = 1.5  # a point map whose rays a pinhole fits worse than this (pixels) does not vote
MAX_DROP_FRACTION = 0.25  # dropping more than this of the points means the maps disagree wholesale: skip


def pointmap_intrinsics(pts_c: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(4,) ``fx, fy, cx, cy`` of one point map, in its own pixels, by least squares on
    ``col = fx x/z + cx`` and ``row = fy y/z + cy``; NaN when fewer than 3 pixels are valid or the fit's
    RMS exceeds ``MAX_FIT_RMS_PX`` (a map that is not a pinhole image: resampled, distorted).

    Args:
        pts_c: (H, W, 3) points in the camera frame (z forward).
        valid: (H, W) bool, the pixels to fit (finite, z > 0).
    """
    H, W = valid.shape
    if valid.sum() < 3:
        return np.array([np.nan] * 4)
    cols, rows = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    z = pts_c[..., 2][valid]
    out, sq = [], 0.0
    for k, pix in ((0, cols), (1, rows)):
        A = np.stack([pts_c[..., k][valid] / z, np.ones_like(z)], axis=1)
        sol = np.linalg.lstsq(A, pix[valid], rcond=None)[0]
        sq += float(np.mean((A @ sol - pix[valid]) ** 2))
        out.append(sol)
    if np.sqrt(sq / 2) > MAX_FIT_RMS_PX:
        return np.array([np.nan] * 4)
    (fx, cx), (fy, cy) = out
    return np.array([fx, fy, cx, cy])


def points_in_cameras(P_w: np.ndarray, T_w_c: np.ndarray) -> np.ndarray:
    """(V, H, W, 3) each view's points ``P_w`` (V, H, W, 3) float64, world frame, in its own camera frame:
    ``p_c = R^T (p_w - t)`` for ``T_w_c`` (V, 4, 4), one BLAS matmul per view (an einsum over these shapes is
    about 10x slower)."""
    V = len(P_w)
    R, t = np.ascontiguousarray(T_w_c[:, :3, :3]), T_w_c[:, :3, 3]
    return np.matmul((P_w - t[:, None, None, :]).reshape(V, -1, 3), R).reshape(P_w.shape)


def view_votes(pts3d_w: np.ndarray, T_w_c: np.ndarray, valid: np.ndarray | None = None, tol_rel: float = TOL_REL,
               confirm_tol: float = CONFIRM_TOL) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the other views say about each point: ``(against, support, confirm, ok)``, (V, H, W) each.

    ``against``: the views that see through the point (it lies nearer than ``1 - tol_rel`` times the surface
    they see there); ``support``: those that see a surface there within ``tol_rel``; ``confirm``: those within
    the tighter ``confirm_tol``; int32 counts. ``ok``: the points that took part (bool). Views whose map a
    pinhole does not fit do not vote. Args as :func:`free_space_outliers`.
    """
    P = check_shape("pts3d", np.asarray(pts3d_w), (None, None, None, 3)).astype(np.float64)
    V, H, W = P.shape[:3]
    T = check_shape("T_w_c", np.asarray(T_w_c, dtype=np.float64), (V, 4, 4))
    R, t = np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3])  # contiguous: BLAS matmul
    Pc = points_in_cameras(P, T)
    ok = np.all(np.isfinite(Pc), axis=-1) & (np.nan_to_num(Pc[..., 2], nan=-1.0) > 0)
    if valid is not None:
        ok &= check_shape("valid", np.asarray(valid, dtype=bool), (V, H, W))
    K = np.stack([pointmap_intrinsics(Pc[v], ok[v]) for v in range(V)])
    # the surface each view sees near a pixel: nearest / farthest depth over its 3x3 neighbours, so that a
    # point on an object's silhouette is compared with the object, not the background beside it
    Z = np.where(ok, Pc[..., 2], np.inf)
    z_near = filter3(Z, np.minimum)
    z_far = filter3(np.where(ok, Z, -np.inf), np.maximum)
    # per view u, flat over its pixels: where u sees a surface, and the depth bands of "on that surface"
    has = np.isfinite(z_near).reshape(V, -1)
    bands = [((1.0 - tol) * z_near).reshape(V, -1) for tol in (tol_rel, confirm_tol)]
    tops = [((1.0 + tol) * z_far).reshape(V, -1) for tol in (tol_rel, confirm_tol)]
    counts = np.zeros((3, V, H, W), dtype=np.int32)
    for v in range(V):
        X = P[v][ok[v]]  # a view's points at a time: arrays that stay in the cache
        c = np.zeros((3, len(X)), dtype=np.int32)
        for u in range(V):
            if u == v or not np.all(np.isfinite(K[u])):
                continue
            pix, z = pinhole_pixels(X, R[u], t[u], K[u], H, W)
            seen = pix >= 0
            pix[~seen] = 0
            seen &= has[u][pix]
            c[0] += seen & (z < bands[0][u][pix])
            c[1] += seen & (z >= bands[0][u][pix]) & (z <= tops[0][u][pix])
            c[2] += seen & (z >= bands[1][u][pix]) & (z <= tops[1][u][pix])
        counts[:, v][:, ok[v]] = c
    return counts[0], counts[1], counts[2], ok


def free_space_outliers(pts3d_w: np.ndarray, T_w_c: np.ndarray, valid: np.ndarray | None = None,
                        tol_rel: float = TOL_REL, min_votes: int = MIN_VOTES, votes: tuple | None = None) -> np.ndarray:
    """(V, H, W) bool: the points other views see through (see the module docstring).

    Args:
        pts3d_w: (V, H, W, 3) point maps in the reconstruction frame w.
        T_w_c: (V, 4, 4) their camera poses in w.
        valid: (V, H, W) bool, the points taking part (default: every finite point in front of its
            camera). Only valid points vote and are judged.
        tol_rel: relative depth tolerance (0.05: 5 cm at 1 m).
        min_votes: the fewest votes against that can drop a point.
        votes: :func:`view_votes`' result for these arguments, when already computed.

    Views whose map a pinhole does not fit (``pointmap_intrinsics`` NaN) do not vote. When more than
    ``MAX_DROP_FRACTION`` of the points would go, nothing is dropped.
    """
    against, support, _, ok = votes if votes is not None else view_votes(pts3d_w, T_w_c, valid, tol_rel)
    out = ok & (against >= min_votes) & (against > support)
    if out.sum() > MAX_DROP_FRACTION * max(int(ok.sum()), 1):
        # the views disagree wholesale (a reconstruction whose poses and maps do not fit each other):
        # that is for the calibration's own checks to report, not for this filter to hide
        return np.zeros_like(out)
    return out


def confirmed_points(votes: tuple, min_views: int = MIN_CONFIRMING_VIEWS) -> np.ndarray:
    """(V, H, W) bool: the points at least ``min_views`` other views saw on their own surface (within
    :func:`view_votes`' ``confirm_tol``) and none saw through (``votes``: :func:`view_votes`' result)."""
    against, _, confirm, ok = votes
    return ok & (confirm >= min_views) & (against == 0)
