"""The capture's depth views in b1 (``views.npz`` beside calibration.json): where each wrist camera was and how
far it saw along each pixel, so that later stages can tell the space a camera saw through (free) from the
space no camera saw into (unknown).

``bijcr calibrate`` writes it from the point maps the metric cloud is made of (the same views, placed the same
way, the same pixels kept). Keys (docs/scene-format.md, "Project extensions"):

| key | shape, dtype | meaning |
| --- | --- | --- |
| ``T_b1_c`` | (V, 4, 4) float64 | each view's camera pose in b1 (metres) |
| ``K`` | (V, 4) float64 | its pinhole ``fx, fy, cx, cy`` in depth-map pixels (NaN: not a pinhole map) |
| ``depth`` | (V, H, W) float32 | z-depth (m) of the surface seen at each pixel; NaN where nothing was kept |
| ``arm`` | (V,) int64 | 1 primary, 2 secondary |
| ``disagreement`` | () float64, optional | how far (m) the views see past the cloud's own points, 95th percentile (0 when absent) |

The views of one capture disagree: a real reconstruction's views, each placed with its own error, see
centimetres past surfaces that other views put in the cloud (the real capture in shecar_desk: 23 % of the cloud's
points at 5 mm, 5 % at 3 cm; the task bench's synthetic captures: 0.4-1.2 mm at the 95th percentile). A test of
free space (``seen_free``) is only as sharp as that: its users take ``disagreement`` as the least tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import check_shape

__all__ = ["DepthViews", "seen_free", "see_past", "views_disagreement", "write_views", "load_views", "VIEWS_FILE",
           "filter3", "pinhole_pixels"]

VIEWS_FILE = "views.npz"


@dataclass(frozen=True)
class DepthViews:
    """V depth views in b1: ``T_b1_c`` (V, 4, 4), ``K`` (V, 4), ``depth`` (V, H, W) metres (NaN: no surface
    kept), ``arm`` (V,); ``disagreement`` (m): how far they see past their own cloud (:func:`views_disagreement`;
    0 for exact views)."""

    T_b1_c: np.ndarray
    K: np.ndarray
    depth: np.ndarray
    arm: np.ndarray
    disagreement: float = 0.0

    def __post_init__(self):
        for name, shape in _field_shapes(len(self.T_b1_c)):
            check_shape(name, getattr(self, name), shape)
        if not _is_distance(self.disagreement):
            raise ValueError(f"disagreement must be a finite distance >= 0 (m), not {self.disagreement}")

    def __len__(self) -> int:
        return len(self.T_b1_c)

    def tolerance(self, tol: float) -> float:
        """The least distance (m) past a point at which these views prove it free: ``tol``, or their own
        ``disagreement`` where larger (nearer than that, a view seeing past a point proves nothing)."""
        return max(float(tol), float(self.disagreement))


def _field_shapes(V: int) -> tuple:
    """(field, shape) of the arrays of V views (``check_shape`` patterns)."""
    return ("T_b1_c", (V, 4, 4)), ("K", (V, 4)), ("depth", (V, None, None)), ("arm", (V,))


def _is_distance(x: float) -> bool:
    return bool(np.isfinite(x) and x >= 0)


def seen_free(points_b1: np.ndarray, views: DepthViews, tol: float = 0.01) -> np.ndarray:
    """(K,) bool: some view saw past each point of ``points_b1`` (K, 3): it projects into that view's map, in
    front of the camera, and every surface the view kept within one pixel of it lies more than ``tol`` m
    farther along the view's axis. A pixel without a kept surface says nothing (background, a robot, a
    dropped point); neither does a point behind a surface (occluded) or within ``tol`` of it."""
    return see_past(points_b1, views) > tol


def see_past(points_b1: np.ndarray, views: DepthViews) -> np.ndarray:
    """(K,) float: how far (m) the farthest-seeing view saw past each point of ``points_b1`` (K, 3): over the
    views it projects into, in front of the camera, the largest depth of the nearest surface kept within one
    pixel of it, less its own depth (negative: behind a surface; -inf: no view kept a surface there)."""
    P = check_shape("points_b1", np.asarray(points_b1, dtype=np.float64), (None, 3))
    past = np.full(len(P), -np.inf)
    V, H, W = views.depth.shape
    # the nearest kept surface around each pixel, -inf where a neighbour kept none: a point next to an
    # object's silhouette is compared with the object, and a pixel beside a hole proves nothing
    near = filter3(views.depth.astype(np.float64), np.minimum)  # NaN (no surface) propagates
    near = np.where(np.isnan(near), -np.inf, near).reshape(V, -1)
    for v in range(V):
        if not np.all(np.isfinite(views.K[v])):
            continue
        T = views.T_b1_c[v]
        pix, z = pinhole_pixels(P, np.ascontiguousarray(T[:3, :3]), T[:3, 3], views.K[v], H, W)
        seen = np.nonzero(pix >= 0)[0]
        past[seen] = np.maximum(past[seen], near[v][pix[seen]] - z[seen])
    return past


def views_disagreement(points_b1: np.ndarray, views: DepthViews, q: float = 95.0, max_points: int = 30000,
                       seed: int = 0) -> float:
    """How far (m) the ``views`` see past the cloud they made, ``points_b1`` (K, 3): the ``q``-th percentile of
    :func:`see_past` over the points some view kept a surface for (at most ``max_points`` of them, drawn with
    ``seed``); 0 when none. Every point of the cloud is a surface some view saw, so a view seeing past it is the
    views' own disagreement (each view placed with its own error), not free space."""
    P = check_shape("points_b1", np.asarray(points_b1, dtype=np.float64), (None, 3))
    if len(P) > max_points:
        P = P[np.random.default_rng(seed).choice(len(P), max_points, replace=False)]
    past = see_past(P, views)
    past = past[np.isfinite(past)]
    return max(0.0, float(np.percentile(past, q))) if len(past) else 0.0


def filter3(Z: np.ndarray, reduce) -> np.ndarray:
    """The 3x3 minimum or maximum (``reduce``: ``np.minimum`` / ``np.maximum``) of each (H, W) slice of
    ``Z`` (V, H, W), edges repeated: ``scipy.ndimage``'s ``minimum_filter`` / ``maximum_filter`` with
    ``size=3, mode="nearest"``, the same values (a minimum or maximum is exact). Written with numpy because
    ``scipy.ndimage``'s import costs a command's start-up more than the filtering itself."""
    H, W = Z.shape[1:]
    Zp = np.pad(Z, ((0, 0), (1, 1), (1, 1)), mode="edge")
    out = Zp[:, 1:H + 1, 1:W + 1].copy()
    for dy in range(3):
        for dx in range(3):
            if dy != 1 or dx != 1:
                reduce(out, Zp[:, dy:dy + H, dx:dx + W], out=out)
    return out


def pinhole_pixels(X: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray, H: int, W: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``(pixel (N,) int64, depth (N,))`` of points X (N, 3) in a view with pose (R (3, 3), t (3,)) and
    pinhole ``K`` (4,) = fx, fy, cx, cy: the flat index ``row * W + col`` of the nearest pixel, -1 where
    the point is behind the camera or outside the (H, W) map."""
    c = (X - t) @ R
    z = c[:, 2]
    front = z > 1e-9
    zs = np.where(front, z, 1.0)
    col = np.round(K[0] * c[:, 0] / zs + K[2])
    row = np.round(K[1] * c[:, 1] / zs + K[3])
    seen = front & (col >= 0) & (col < W) & (row >= 0) & (row < H)
    return np.where(seen, row * W + col, -1.0).astype(np.int64), z


def write_views(path: str | Path, views: DepthViews) -> Path:
    """Write ``views`` to ``path`` (.npz), complete or not at all (a temporary name, then renamed)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, T_b1_c=views.T_b1_c, K=views.K, depth=views.depth.astype(np.float32), arm=views.arm,
                        disagreement=np.float64(views.disagreement))
    tmp.replace(path)
    return path


def load_views(path: str | Path) -> DepthViews:
    """Read a views.npz (raises InputError naming the file and the field)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as e:  # missing file, zip / format errors of several kinds
        raise InputError(Problem(str(path), "", f"cannot read as .npz: {e}", "re-run `bijcr calibrate`")) from None
    missing = [k for k in ("T_b1_c", "K", "depth", "arm") if k not in data]
    if missing:
        raise InputError(Problem(str(path), missing[0], "missing", "re-run `bijcr calibrate` (it writes views.npz)"))
    try:  # views.npz written before ``disagreement`` existed: exact views as far as anyone knows
        disagreement = float(np.asarray(data.get("disagreement", 0.0), dtype=np.float64).reshape(()))
    except (TypeError, ValueError) as e:
        raise InputError(Problem(str(path), "disagreement", f"not one number: {e}", "re-run `bijcr calibrate`")) from None
    if not _is_distance(disagreement):
        raise InputError(Problem(str(path), "disagreement", f"{disagreement} is not a distance >= 0 (m)",
                                 "re-run `bijcr calibrate`"))
    for name, shape in _field_shapes(len(data["T_b1_c"]) if np.ndim(data["T_b1_c"]) else 0):
        try:
            check_shape(name, data[name], shape)
        except ValueError as e:
            raise InputError(Problem(str(path), name, str(e), "re-run `bijcr calibrate`")) from None
    return DepthViews(data["T_b1_c"].astype(np.float64), data["K"].astype(np.float64),
                      data["depth"].astype(np.float32), data["arm"].astype(np.int64), disagreement)
