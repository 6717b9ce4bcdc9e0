"""The one robust plane fitter: Open3D RANSAC, then least squares on a noise-sized window to a fixed point.

Used by the segmentation's table (:func:`segmentation._table.fit_table`), the physics preview's table
(``bimanual_app.simulation.fit_table``) and the plane sweep's dominant plane of sparse SfM points
(``bimanual_app.reconstruction._dense.fit_plane``). Pure functions on arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

COS_HORIZONTAL = float(np.cos(np.deg2rad(35.0)))  # a plane this close to level (normal . up) is horizontal
MIN_RANSAC_POINTS = 50  # default: fewer points left, stop extracting planes


@dataclass
class PlaneFit:
    """A plane ``normal . p + offset = 0`` fitted to points.

    Attributes:
        normal: (3,) unit normal; its sign is as fitted (the caller orients it).
        offset: the plane's offset.
        sigma: robust standard deviation of the distances to the plane of the points near it (0 when the
            window refinement did not run).
        inliers: (M, 3) the points the final least-squares fit used.
        support: RANSAC inliers of the chosen plane (before refinement).
        points: number of points the fit was given.
    """

    normal: np.ndarray
    offset: float
    sigma: float
    inliers: np.ndarray
    support: int
    points: int

    @property
    def fraction(self) -> float:
        """Share of the given points in the final inlier window."""
        return len(self.inliers) / max(self.points, 1)


def ransac_plane(points: np.ndarray, threshold: float, iterations: int = 1000,
                 probability: float = 0.99999) -> tuple[np.ndarray, np.ndarray]:
    """Open3D ``segment_plane`` on ``points`` (N, 3): ``(model (4,) [a, b, c, d], inlier indices (M,))``."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    model, inl = pc.segment_plane(distance_threshold=float(threshold), ransac_n=3, num_iterations=iterations,
                                  probability=probability)
    return np.asarray(model, dtype=np.float64), np.asarray(inl, dtype=np.int64)


def least_squares_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane ``(unit normal (3,), offset)`` through ``points`` (M, 3) (SVD of the centred points)."""
    c = points.mean(0)
    _, _, Vt = np.linalg.svd(points - c, full_matrices=False)
    n = Vt[2]
    return n, float(-n @ c)


def uniform_sample(points: np.ndarray, n_max: int, seed: int = 0, cell: float = 0.01) -> np.ndarray:
    """Up to ``n_max`` points (M, 3) spread evenly over the surfaces: one per ``cell`` voxel.

    Clouds from cameras are densest where the cameras look from close by (the top of a large box), so a
    random subset can hold more box top than table; one point per voxel makes a plane's support its area.
    """
    from ._voxels import voxel_keys

    rng = np.random.default_rng(seed)
    N = len(points)
    if N > 4 * n_max:  # thin out first (a strided pick is O(N/step)): the voxel pass stays cheap
        points = points[rng.integers(0, N // (4 * n_max) + 1):: N // (4 * n_max) + 1]
    _, first = np.unique(voxel_keys(points, cell), return_index=True)
    sample = points[first]
    if len(sample) > n_max:
        sample = sample[rng.choice(len(sample), n_max, replace=False)]
    return sample


def _choose(points: np.ndarray, threshold: float, up: np.ndarray | None, cos_level: float, near: float | None,
            max_planes: int, level_only: bool, iterations: int,
            min_points: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``(model (4,), inlier points)`` of the chosen RANSAC plane, or None.

    Up to ``max_planes`` planes are extracted in turn, biggest first (with ``near``: as many as a room's floor
    and walls seen past the table may be, before it). Without ``up`` the first (biggest)
    wins. With ``up``: the first level one (normal within ``cos_level`` of ``up``) that passes within ``near``
    of the origin, whatever its size (with ``near``, the origin stands on the plane sought: the primary arm's
    base on the table, which a floor seen over a larger area outnumbers in an evenly spread sample); else the
    first level one holding at least a third of the first one's inliers; else (unless ``level_only``) the
    biggest.
    """
    remaining, first, first_count, fallback = points, None, 0, None
    for attempt in range(max_planes):
        if len(remaining) < min_points:
            break
        model, inl = ransac_plane(remaining, threshold, iterations)
        if attempt == 0:
            first_count, first = len(inl), (model, remaining[inl])
            if up is None:
                break
        norm = max(np.linalg.norm(model[:3]), 1e-12)
        is_level = abs(model[:3] @ up) / norm >= cos_level
        if is_level and near is not None and abs(model[3]) / norm < near:
            return model, remaining[inl]
        big = len(inl) >= first_count / 3
        if is_level and big and fallback is None:
            fallback = (model, remaining[inl])
        if near is None and (fallback is not None or not big):
            break  # the first level one is the choice; past a small plane only smaller ones come
        remaining = np.delete(remaining, inl, axis=0)
    if fallback is not None:
        return fallback
    return None if level_only else first


def _refine(points: np.ndarray, inliers: np.ndarray, threshold: float,
            noise_window: float) -> tuple[np.ndarray, float, float, np.ndarray]:
    """Least squares on a window of 2.5 sigma (at least ``threshold``), iterated to a fixed point.

    RANSAC's window truncates the plane's noise, so sigma is measured (median absolute deviation: an
    object's lowest points are few) on all ``points`` within ``max(3 threshold, noise_window)``; the plane
    is refitted on the wider window when that is wider (clouds of misaligned views hold several layers).
    Iterated until the window selects the same points twice: Open3D's RANSAC runs in parallel threads and
    its plane differs a little from run to run despite the seed; the fixed point does not.
    Returns ``(normal, offset, sigma, inlier points)``.
    """
    n, d = least_squares_plane(inliers)
    sigma, prev = 0.0, None
    for _ in range(8):
        r = points @ n + d
        near = np.abs(r) < max(3 * threshold, noise_window)
        if near.sum() < 3:
            break
        sigma = float(1.4826 * np.median(np.abs(r[near] - np.median(r[near]))))
        sel = np.abs(r) < max(threshold, 2.5 * sigma)
        if sel.sum() < 3 or (prev is not None and np.array_equal(sel, prev)):
            break
        prev = sel
        inliers = points[sel]
        n, d = least_squares_plane(inliers)
    return n, d, sigma, inliers


def fit_plane(points: np.ndarray, threshold: float, *, up: np.ndarray | None = None,
              cos_level: float = COS_HORIZONTAL, near: float | None = None, level_only: bool = False,
              max_planes: int = 8, iterations: int = 1000, noise_window: float = 0.03,
              min_points: int = MIN_RANSAC_POINTS, seed: int = 0) -> PlaneFit | None:
    """The dominant plane of ``points`` (N, 3), robust and repeatable.

    Args:
        threshold: RANSAC inlier distance (units of ``points``).
        up: (3,) when given, prefer a level plane (see :func:`_choose`); None: the biggest plane.
        cos_level: how level counts as level (cosine of the largest tilt from ``up``).
        near: with ``up``: prefer level planes passing this close to the origin.
        level_only: with ``up``: None rather than a plane that is not level.
        noise_window: the least the window measuring the plane's noise spans (units of ``points``).
        min_points: no plane is extracted from fewer points than this.
    Returns:
        the :class:`PlaneFit` (normal not oriented), or None when no plane qualifies (too few points; with
        ``level_only``, no level plane).
    """
    import open3d as o3d

    pts = np.asarray(points, dtype=np.float64)
    o3d.utility.random.seed(seed)
    u = None if up is None else np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    chosen = _choose(pts, threshold, u, cos_level, near, max_planes, level_only, iterations, min_points)
    if chosen is None:
        return None
    _, inliers = chosen
    n, d, sigma, inliers = _refine(pts, inliers, threshold, noise_window)
    return PlaneFit(n, d, sigma, inliers, len(chosen[1]), len(pts))
