"""CPU densification of a sparse SfM model: plane-sweep stereo along the table normal.

Why this and not interpolating the sparse depths: sparse SIFT points are few on an object's smooth
faces and interpolating between them draws "tents" from an object's top down to the table, which glues
objects to the table for the segmentation stage. A plane sweep tests, for every pixel, a stack of
planes and keeps the one where the neighbouring views agree photometrically (normalised cross
correlation), so object boundaries stay sharp where there is texture. The planes are parallel to the
dominant plane of the sparse points (the table in a table-top capture): then the stack only needs to
span the table-to-object-top range, which the sparse points give, and the plane homographies are exact
for the table and for the tops of objects. Without a dominant plane it sweeps fronto-parallel planes
in inverse depth instead. Each depth is kept only where at least one other view's depth map agrees
(geometric consistency), which removes most of the wrong matches on weak texture.

Everything here is pure functions on arrays (OpenCV convention, pinhole); cost is about
``views x planes x sources`` small image warps (a few seconds for 18 views at 320x240 on one core).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from bimanual_app.transforms import apply_T, check_shape, check_T, inv_T

__all__ = ["DenseOptions", "fit_plane", "sweep_planes", "plane_sweep", "consistency_counts", "choose_sources",
           "fill_horizontal_holes", "FILL_CONF"]

FILL_CONF = 0.1  # confidence of hole-filled pixels: below any matched pixel (>= min_score)


@dataclass
class DenseOptions:
    """Plane-sweep settings."""

    work_width: int = 320        # images are matched at this width
    planes: int = 64             # planes in the sweep
    window: int = 15             # NCC window (pixels at work resolution; large: plain table-top texture)
    sources: int = 4             # neighbouring views per reference view
    min_score: float = 0.3       # NCC below this is no match
    min_texture: float = 0.005   # NCC window std (intensity 0..1) below this is untextured
    rel_tol: float = 0.01        # depth agreement between views, relative
    min_plane_inliers: float = 0.3  # below this fraction the sweep is fronto-parallel
    fill_holes: bool = True      # fill untextured holes bordered by one horizontal surface
    fill_min_area: int = 30      # holes smaller than this (work pixels) are left alone
    fill_max_spread: float = 0.02  # border heights must agree within this fraction of the camera height


def fit_plane(xyz: np.ndarray, centres: np.ndarray, threshold: float, seed: int = 0) -> tuple[np.ndarray, float, float]:
    """Dominant plane of points ``xyz`` (P, 3), oriented towards the cameras.

    The segmentation's plane fitter (:func:`segmentation.fit_plane`: Open3D RANSAC refined by least squares
    to a fixed point) on the sparse points as they are: the world frame of an SfM model has no "up", so the
    biggest plane wins, and its units are arbitrary, so the noise window is set by ``threshold`` alone.

    Args:
        centres: (M, 3) camera centres; the normal is flipped so that the cameras are on its + side.
        threshold: inlier distance (same units as xyz).
    Returns ``(n (3,), d, inlier_fraction)`` with ``n . x + d`` the signed height above the plane.
    """
    from segmentation import fit_plane as robust_plane

    xyz = check_shape("xyz", xyz, (None, 3))
    fit = robust_plane(xyz, float(threshold), iterations=2000, noise_window=0.0, min_points=10, seed=seed)
    if fit is None:
        return np.array([0.0, 0.0, 1.0]), 0.0, 0.0
    n, d = fit.normal, fit.offset
    if np.median(centres @ n + d) < 0:
        n, d = -n, -d
    return n, float(d), fit.fraction


def sweep_planes(n_w: np.ndarray, d_w: float, heights: np.ndarray, T_w_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planes ``n . x + d = h`` (world) in a camera's frame: ``n_c . X_c = c_k``.

    Returns ``(n_c (3,), c (D,))`` for heights ``h`` (D,).
    """
    T_w_c = check_T("T_w_c", T_w_c)
    n_c = T_w_c[:3, :3].T @ n_w
    c = np.asarray(heights, dtype=np.float64) - d_w - float(n_w @ T_w_c[:3, 3])
    return n_c, c


def _box(img: np.ndarray, k: int) -> np.ndarray:
    return cv2.boxFilter(img, -1, (k, k), normalize=True, borderType=cv2.BORDER_REFLECT)


def _mean_of_top(arrays: list[np.ndarray], top: int) -> np.ndarray:
    """Element-wise mean of the ``top`` largest of a few same-shaped arrays.

    A bubble-sort network of element-wise min/max: for the 1-6 sources used here it is several times
    faster than ``np.sort`` / ``argmin`` along a stacked axis.
    """
    a = list(arrays)
    n = len(a)
    for i in range(n):
        for j in range(n - 1 - i):
            lo, hi = np.minimum(a[j], a[j + 1]), np.maximum(a[j], a[j + 1])
            a[j], a[j + 1] = lo, hi
    return sum(a[n - top:]) / top


def plane_sweep(ref: np.ndarray, K_ref: np.ndarray, T_w_ref: np.ndarray, sources: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                n_c: np.ndarray, c: np.ndarray, opts: DenseOptions) -> tuple[np.ndarray, np.ndarray]:
    """Plane-sweep depth of one reference view.

    Args:
        ref: (H, W) float32 grey image (0..1) of the reference view (pinhole, undistorted).
        K_ref: (3, 3) its intrinsics; T_w_ref: (4, 4) its pose.
        sources: per neighbouring view (grey (H', W') float32, K (3, 3), T_w_c (4, 4)).
        n_c, c: the planes ``n_c . X = c_k`` (D,) in the reference camera frame (see sweep_planes).
    Returns ``(depth (H, W), score (H, W))``: depth along the optical axis (0 where none) and the
    aggregated NCC of the winning plane (-1 where none).
    """
    check_shape("ref", ref, (None, None))
    H, W = ref.shape
    k = opts.window
    mu_r = _box(ref, k)
    var_r = np.maximum(_box(ref * ref, k) - mu_r * mu_r, 0)
    textured = np.sqrt(var_r) > opts.min_texture
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K_ref).T
    nr = rays @ n_c
    Kinv = np.linalg.inv(K_ref)
    D, S = len(c), len(sources)
    top = max(1, (S + 1) // 2)
    vol = np.full((D, H, W), -1.0, np.float32)
    for kk in range(D):
        scores: list[np.ndarray] = []
        for img, K_s, T_w_s in sources:
            T_s_r = inv_T(T_w_s) @ T_w_ref
            Hm = K_s @ (T_s_r[:3, :3] + np.outer(T_s_r[:3, 3], n_c) / c[kk]) @ Kinv
            # border -1 (outside the 0..1 intensities) marks pixels that fall outside the source image;
            # not NaN: the running sums of a box filter would spread a NaN along the whole row
            warped = cv2.warpPerspective(img, Hm, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
            outside = warped < -0.5
            mu_w = _box(warped, k)
            var_w = _box(warped * warped, k) - mu_w * mu_w
            cov = _box(ref * warped, k) - mu_r * mu_w
            with np.errstate(invalid="ignore", divide="ignore"):
                ncc = cov / np.sqrt(np.maximum(var_r * var_w, 1e-12))
            bad = _box(outside.astype(np.float32), k) > 0
            ncc[bad | ~np.isfinite(ncc) | (var_w < opts.min_texture ** 2)] = -1.0
            scores.append(ncc.astype(np.float32, copy=False))
        # mean of the best half of the sources (a source that does not see the pixel must not veto it)
        vol[kk] = _mean_of_top(scores, top)
    best = np.argmax(vol, axis=0)
    score = np.take_along_axis(vol, best[None], 0)[0]
    # sub-plane refinement: vertex of the parabola through the neighbouring planes' scores
    lo = np.take_along_axis(vol, np.clip(best - 1, 0, D - 1)[None], 0)[0]
    hi = np.take_along_axis(vol, np.clip(best + 1, 0, D - 1)[None], 0)[0]
    den = lo - 2 * score + hi
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.where((best > 0) & (best < D - 1) & (den < -1e-6), 0.5 * (lo - hi) / den, 0.0)
    kf = best + np.clip(off, -0.5, 0.5)
    cf = np.interp(kf, np.arange(D), c)
    with np.errstate(invalid="ignore", divide="ignore"):
        depth = cf / nr
    ok = textured & (score >= opts.min_score) & np.isfinite(depth) & (depth > 0)
    return np.where(ok, depth, 0.0), np.where(ok, score, -1.0).astype(np.float32)


def consistency_counts(depths: list[np.ndarray], Ks: list[np.ndarray], T_w_cs: np.ndarray,
                       neighbours: list[list[int]], rel_tol: float) -> list[np.ndarray]:
    """For every pixel with a depth, how many neighbouring views' depth maps agree with it.

    A pixel of view i (depth z) is back-projected, projected into view j, and agrees when view j's depth
    at that pixel is within ``rel_tol`` (relative) of the point's depth in j.
    Returns per view an (H, W) int array.
    """
    out = []
    for i, depth in enumerate(depths):
        H, W = depth.shape
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        has = depth > 0
        X_c = np.stack([u[has], v[has], np.ones(has.sum())], -1) @ np.linalg.inv(Ks[i]).T * depth[has][:, None]
        X_w = apply_T(T_w_cs[i], X_c)
        count = np.zeros(has.sum(), np.int64)
        for j in neighbours[i]:
            Xj = apply_T(inv_T(T_w_cs[j]), X_w)
            z = Xj[:, 2]
            with np.errstate(invalid="ignore", divide="ignore"):
                p = Xj @ Ks[j].T
                uj, vj = np.rint(p[:, 0] / z), np.rint(p[:, 1] / z)
            Hj, Wj = depths[j].shape
            inside = (z > 0) & (uj >= 0) & (uj < Wj) & (vj >= 0) & (vj < Hj)
            dj = np.zeros_like(z)
            dj[inside] = depths[j][vj[inside].astype(int), uj[inside].astype(int)]
            count += inside & (dj > 0) & (np.abs(dj - z) <= rel_tol * z)
        full = np.zeros((H, W), np.int64)
        full[has] = count
        out.append(full)
    return out


def choose_sources(obs_points: list[np.ndarray], k: int, min_shared: int = 8) -> list[list[int]]:
    """Neighbouring views of each view: the ``k`` views sharing the most sparse points with it.

    ``obs_points``: per view the (k_i,) indices of the sparse points it observes.
    """
    sets = [set(p.tolist()) for p in obs_points]
    out = []
    for i, si in enumerate(sets):
        shared = sorted(((len(si & sj), j) for j, sj in enumerate(sets) if j != i), reverse=True)
        pick = [j for n, j in shared[:k] if n >= min_shared]
        out.append(pick or [j for _, j in shared[:1]])
    return out


def fill_horizontal_holes(depth: np.ndarray, K: np.ndarray, T_w_c: np.ndarray, n_w: np.ndarray, d_w: float,
                          max_spread: float, min_area: int, min_border: float = 0.5) -> np.ndarray:
    """Fill holes of a depth map (H, W) (0 = none) that are enclosed by one horizontal surface.

    Untextured patches (the inside of a plain box top, a plain stretch of table) get no depth from the
    NCC sweep. In a table-top scene most surfaces are horizontal, so a hole inside the image whose border
    is mostly seen (``min_border``) and lies at one height above the table (spread of the border heights
    below ``max_spread``, same units as the poses) is filled with that horizontal plane.
    Holes bordered by several heights (an object's side, a gap between an object and the table) stay
    empty: filling them would glue objects to the table. So do holes that run off the image: a plain
    table beside a box top is often bordered only by the box's edge, and its border says "box height",
    wrongly (measured on rendered scenes: 10-40 % of such fills were wrong; a photometric test of the
    candidate planes over the whole hole did not tell them apart on plain texture).
    Returns a (H, W) bool mask of the pixels filled (``depth`` is filled in place).
    """
    H, W = depth.shape
    valid = depth > 0
    filled = np.zeros((H, W), bool)
    if valid.sum() < 10:
        return filled
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
    heights = np.full((H, W), np.nan)
    X_w = apply_T(T_w_c, rays[valid] * depth[valid][:, None])
    heights[valid] = X_w @ n_w + d_w
    n_c = T_w_c[:3, :3].T @ n_w
    offset = d_w + float(n_w @ T_w_c[:3, 3])
    nr = rays @ n_c
    count, labels, stats, _ = cv2.connectedComponentsWithStats((~valid).astype(np.uint8), connectivity=4)
    kernel = np.ones((3, 3), np.uint8)
    for lab in range(1, count):
        x, y, w, h, area = stats[lab]
        if area < min_area or x == 0 or y == 0 or x + w == W or y + h == H:
            continue
        x0, y0, x1, y1 = x - 2 if x >= 2 else 0, max(y - 2, 0), min(x + w + 2, W), min(y + h + 2, H)
        comp = labels[y0:y1, x0:x1] == lab
        around = cv2.dilate(comp.astype(np.uint8), kernel, iterations=2).astype(bool) & ~comp
        hs = heights[y0:y1, x0:x1][around & valid[y0:y1, x0:x1]]
        if len(hs) < 10 or len(hs) < min_border * around.sum():
            continue
        lo, hi = np.percentile(hs, [10, 90])
        if hi - lo > max_spread:
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (float(np.median(hs)) - offset) / nr[y0:y1, x0:x1]
        ok = comp & np.isfinite(z) & (z > 0)
        depth[y0:y1, x0:x1][ok] = z[ok]
        filled[y0:y1, x0:x1] |= ok
    return filled
