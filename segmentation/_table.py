"""The table: a robust plane fit (Open3D RANSAC, refined by least squares) and what lies above it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.io_utils import InputError, Problem

from ._params import SegmentParams
from ._plane import COS_HORIZONTAL, fit_plane, uniform_sample

# Clouds whose robust extent (2-98th percentile, largest axis) is outside this range are not metric.
MAX_SCENE_EXTENT = 10.0
MIN_SCENE_EXTENT = 0.05
MAX_TABLE_EXTENT = 8.0  # a table longer than this: not metres (a "table the size of a house")
MIN_TABLE_EXTENT = 0.25  # on both sides: the top of a large box (<= 0.22 m wide) is not a table
MIN_BAND, MAX_BAND = 0.003, 0.012  # the table band (points this high are table): 3.5 sigma, within these
NEAR_B1 = 0.2  # the primary arm stands on the table: its plane passes this close to b1's origin


@dataclass
class TablePlane:
    """The table plane in b1.

    Attributes:
        normal: (3,) unit normal, pointing to the side the objects stand on.
        offset: plane is ``normal . p + offset = 0``.
        sigma: robust standard deviation (m) of the inliers' distances to the plane.
        min_height: points at most this high are table.
        T_b1_t: (4, 4) table frame: z = normal, origin on the plane below the inliers' centroid.
        outline: (K, 2) convex hull of the inliers in the table frame's x-y (m).
        extent: (2,) size (m) of the inliers along the table frame's x and y (1st-99th percentile).
        inliers: number of RANSAC inliers in the sample; fraction: their share of the sample.
    """

    normal: np.ndarray
    offset: float
    sigma: float
    min_height: float
    T_b1_t: np.ndarray
    outline: np.ndarray
    extent: np.ndarray
    inliers: int
    fraction: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed heights (m) of ``points`` (N, 3) above the plane."""
        return points @ self.normal + self.offset

    def to_table(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) ``points`` (N, 3, b1) in the table frame (x, y on the plane, z = height)."""
        R, t = self.T_b1_t[:3, :3], self.T_b1_t[:3, 3]
        return (points - t) @ R

    @property
    def coefficients(self) -> np.ndarray:
        """(4,) ``[a, b, c, d]`` with ``a x + b y + c z + d = 0`` and (a, b, c) the upward unit normal."""
        return np.r_[self.normal, self.offset]


def check_metric(points: np.ndarray, source: str) -> None:
    """Raise InputError when the cloud is obviously not in metres (millimetres, or a tiny crop)."""
    step = max(1, len(points) // 50_000)
    lo, hi = np.percentile(points[::step], [2, 98], axis=0)
    ext = float(np.max(hi - lo))
    if ext > MAX_SCENE_EXTENT:
        raise InputError(Problem(source, "points", f"the cloud spans {ext:.4g} units: not a metric table-top scene "
                                 "(millimetres? an unscaled reconstruction?)",
                                 "give a cloud in metres in frame b1 (bijcr calibrate writes scene_b1.ply); "
                                 "a cloud in millimetres must be divided by 1000"))
    if ext < MIN_SCENE_EXTENT:
        raise InputError(Problem(source, "points", f"the cloud spans only {ext:.3g} units: too small for a metric "
                                 "table-top scene", "give a cloud in metres in frame b1 that includes the table"))


def _main_component(uv: np.ndarray, cell: float = 0.02) -> np.ndarray:
    """(M,) bool: the inliers (M, 2 in the plane) of the largest connected patch of the plane.

    Stray inliers far away (a coplanar shelf, a wrong far point) would blow the table's outline up.
    """
    import cv2

    lo = uv.min(0)
    ij = np.floor((uv - lo) / cell).astype(np.int64)
    shape = ij.max(0) + 1
    if shape[0] * shape[1] > 4_000_000:  # absurd extents: leave the check to the caller
        return np.ones(len(uv), bool)
    grid = np.zeros((shape[1], shape[0]), np.uint8)
    grid[ij[:, 1], ij[:, 0]] = 1
    grid = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    n, comp, stats, _ = cv2.connectedComponentsWithStats(grid, connectivity=8)
    if n <= 2:
        return np.ones(len(uv), bool)
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return comp[ij[:, 1], ij[:, 0]] == best


def fit_table(points: np.ndarray, params: SegmentParams, source: str = "points", seed: int = 0) -> TablePlane:
    """Find the table in ``points`` (N, 3, b1 metres).

    RANSAC (Open3D ``segment_plane``) on an evenly spread subset. Up to three planes are extracted in
    turn (each with at least a third of the biggest one's inliers); the table is the first roughly
    horizontal one (in b1) that passes within 20 cm of b1's origin, where the primary arm stands, else the
    first roughly horizontal one (not a wall), else the biggest. The plane is refined by least squares on its inliers and its
    normal turned up along b1's z (the arm's base stands on the table); for a plane that is not roughly
    horizontal in b1, towards the side with more points within 30 cm (where the objects are).
    """
    sample = uniform_sample(points, params.plane_sample, seed)
    fit = fit_plane(sample, params.plane_threshold, up=np.array([0.0, 0.0, 1.0]), cos_level=COS_HORIZONTAL,
                    near=NEAR_B1, seed=seed)
    min_inliers = max(50, int(0.05 * len(sample)))
    if fit is None or fit.support < min_inliers:
        got = 0 if fit is None else fit.support
        raise InputError(Problem(source, "points", f"no table plane found (best plane holds {got} of "
                                 f"{len(sample)} sampled points, need {min_inliers})",
                                 "give the whole scene including the table top (not a crop of the objects), "
                                 "in metres; or raise plane_threshold for a very noisy cloud"))
    n, d, sigma, inliers = fit.normal, fit.offset, fit.sigma, fit.inliers
    if abs(n[2]) > 0.5:
        # b1 is the primary arm's base frame, its z axis up from the table the arm stands on
        flip = n[2] < 0
    else:  # an unusual mounting: the side with more points near the plane (objects stand on it)
        h = sample @ n + d
        above = int(np.count_nonzero((h > 0.01) & (h < 0.3)))
        below = int(np.count_nonzero((h < -0.01) & (h > -0.3)))
        flip = below > above
    if flip:
        n, d = -n, -d
    min_h = params.min_height if params.min_height is not None else float(np.clip(3.5 * sigma, MIN_BAND, MAX_BAND))

    # table frame: z = n, x = b1's x projected onto the plane (or y when x is nearly normal to it)
    ax = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = ax - (ax @ n) * n
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    c = inliers.mean(0)
    c = c - (c @ n + d) * n
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, n], 1)
    T[:3, 3] = c
    uv = (inliers - c) @ T[:3, :2]
    main = _main_component(uv)
    uv = uv[main]
    c2 = inliers[main].mean(0)
    T[:3, 3] = c2 - (c2 @ n + d) * n
    uv = (inliers[main] - T[:3, 3]) @ T[:3, :2]
    lo, hi = np.percentile(uv, [1, 99], axis=0)
    extent = hi - lo
    if float(extent.max()) > MAX_TABLE_EXTENT:
        raise InputError(Problem(source, "points", f"the table plane is {extent.max():.3g} m across: not a metric "
                                 "cloud (millimetres? unscaled reconstruction?) or not a table-top scene",
                                 "give the cloud in metres in frame b1, as bijcr calibrate writes it"))
    if float(extent.min()) < MIN_TABLE_EXTENT:
        raise InputError(Problem(source, "points", f"no table found: the best plane is only {extent[0]:.2f} x "
                                 f"{extent[1]:.2f} m (a table is at least {MIN_TABLE_EXTENT} m both ways)",
                                 "include the table top around the objects in the cloud, in metres"))
    import cv2

    hull = cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    return TablePlane(n, d, sigma, min_h, T, hull, extent, len(inliers), len(inliers) / len(sample))


def on_table_mask(table: TablePlane, points_t: np.ndarray, margin: float, cell: float = 0.01) -> np.ndarray:
    """(N,) bool: points (N, 3) in the table frame whose x-y lie inside the table outline grown by ``margin``.

    The outline's convex hull is rasterised once (OpenCV ``fillConvexPoly``) and grown by ``margin``
    (``dilate``); each point is then a single grid look-up, which keeps this O(N) for 2M points.
    """
    import cv2

    hull = table.outline
    lo = hull.min(0) - margin - 2 * cell
    hi = hull.max(0) + margin + 2 * cell
    shape = np.ceil((hi - lo) / cell).astype(int) + 1
    grid = np.zeros((shape[1], shape[0]), np.uint8)
    cv2.fillConvexPoly(grid, np.round((hull - lo) / cell).astype(np.int32), 1)
    r = int(np.ceil(margin / cell))
    if r > 0:
        grid = cv2.dilate(grid, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    ij = np.floor((points_t[:, :2] - lo) / cell).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < shape[0]) & (ij[:, 1] < shape[1])
    out = np.zeros(len(points_t), bool)
    out[ok] = grid[ij[ok, 1], ij[ok, 0]] > 0
    return out
