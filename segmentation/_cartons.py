"""A carton is a box under its top: what a carton's region holds beyond its top is a neighbour.

A cylinder standing against a carton's side can end up in the carton's region: the contraction joins its
lower part at the junction (noisy normals blur the crease), and its upper part then lies within the
carton's footprint and is attached as a part of it (``_parts``). A box's walls stand under the outline of
its top and nothing of it rises above its top, so the region's voxels more than ``OUT_TOL`` outside the
rectangle of its top plateau, or more than ``ABOVE_TOL`` above the plateau, are not the carton. Where they
form an object-sized piece (voxels within ``PIECE_GAP`` of each other; the segmenter's own size measures, as
``split_by_tops`` uses them) whose sides do not face along the carton's axes, the piece becomes a region of
its own; smaller remains stay (a wall strip, noise). The last test keeps a carton whose top was seen only in
part whole: the walls under the unseen part of its top lie outside the rectangle of the seen part, but they
face along its axes (``WALL_SHARE`` of their side voxels within ``WALL_DEG``); a cylinder's sides face every
way.

A region is a carton when its largest flat top plateau (``_tops._plateaus``) is at least ``CARTON_WIDTH``
wide and fills its minimum-area rectangle (OpenCV) to ``FILL``: a disc fills pi/4 of its square, a duck's or
a bunny's back is not flat.
"""

from __future__ import annotations

import numpy as np

from ._params import SegmentParams
from ._tops import _plateaus

__all__ = ["split_carton_neighbours"]

CARTON_WIDTH = 0.08  # m: the top plateau's rectangle is at least this wide (as _parts.CORE_MIN_WIDTH)
FILL = 0.85  # the plateau's convex hull fills at least this share of its rectangle
OUT_TOL = 0.01  # m: voxels this far outside the rectangle are not the carton (its rim's noise is less) ...
ABOVE_TOL = 0.02  # m: ... nor voxels this far above its top (a noisy top is a layer up to 2 cm thick)
PIECE_GAP = 0.015  # m: voxels of one piece lie within this of each other (3 voxels)
WALL_DEG = 20.0  # a side voxel faces along an axis of the rectangle when its normal is within this of it ...
WALL_SHARE = 0.7  # ... and a piece is the carton's own wall when this share of its side voxels does


def _top_rectangle(idx: np.ndarray, xyz: np.ndarray, normals: np.ndarray, edges: np.ndarray):
    """``(centre (2,), R (2, 2) columns = the rectangle's axes, half sizes (2,), height)`` of a carton region's
    top plateau (its x-y rectangle, its median height), or None when the region (voxel indices ``idx``) is
    not a carton."""
    import cv2

    tops = _plateaus(idx, xyz, normals, edges)
    if not tops:
        return None
    top = max(tops, key=len)
    xy = xyz[top, :2].astype(np.float32)
    (cx, cy), (w, h), angle = cv2.minAreaRect(xy)
    if min(w, h) < CARTON_WIDTH or cv2.contourArea(cv2.convexHull(xy)) < FILL * w * h:
        return None
    a = np.deg2rad(angle)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return np.array([cx, cy]), R, np.array([w, h]) / 2, float(np.median(xyz[top, 2]))


def _outside(xy: np.ndarray, rect) -> np.ndarray:
    """(M,) distance (m) of points ``xy`` (M, 2) outside a rectangle (0 inside)."""
    c, R, half, _ = rect
    local = np.abs((xy - c) @ R)
    return np.linalg.norm(np.maximum(local - half, 0.0), axis=1)


def _pieces(xy: np.ndarray, gap: float) -> list[np.ndarray]:
    """Index arrays of the groups of points ``xy`` (M, 3) joined by steps under ``gap`` (scipy)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(xy).query_pairs(gap, output_type="ndarray")
    n = len(xy)
    _, lab = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
                                  directed=False)
    return [np.flatnonzero(lab == k) for k in np.unique(lab)]


def _carton_wall(normals: np.ndarray, R: np.ndarray) -> bool:
    """Whether a piece's side voxels (``normals`` (M, 3)) face along the rectangle's axes ``R`` (2, 2)."""
    n = normals[np.abs(normals[:, 2]) < 0.7, :2]
    if not len(n):
        return False
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    along = np.max(np.abs(n @ R), axis=1) >= np.cos(np.deg2rad(WALL_DEG))
    return bool(np.mean(along) >= WALL_SHARE)


def _object_sized(xy: np.ndarray, params: SegmentParams) -> bool:
    import cv2

    if len(xy) < params.min_object_voxels:
        return False
    (_, _), (w, h), _ = cv2.minAreaRect(xy.astype(np.float32))
    return max(w, h) >= params.min_object_size and min(w, h) >= 0.015


def split_carton_neighbours(region: np.ndarray, xyz: np.ndarray, normals: np.ndarray, edges: np.ndarray,
                            params: SegmentParams) -> tuple[np.ndarray, int]:
    """Give the object-sized pieces of carton regions that lie outside their top's rectangle regions of
    their own (module docstring). ``region`` (V,) region ids, ``xyz`` (V, 3) voxels in the table frame,
    ``normals`` (V, 3), ``edges`` (E, 2) voxel neighbour pairs. Returns the new (V,) ids (new regions
    numbered after the existing ones) and the number of pieces split off."""
    out = region.copy()
    next_id = int(region.max()) + 1 if len(region) else 0
    split = 0
    order = np.argsort(region, kind="stable")
    for idx in np.split(order, np.flatnonzero(np.diff(region[order])) + 1):
        if len(idx) < 2 * params.min_object_voxels:
            continue
        rect = _top_rectangle(idx, xyz, normals, edges)
        if rect is None:
            continue
        far = idx[(_outside(xyz[idx, :2], rect) > OUT_TOL) | (xyz[idx, 2] > rect[3] + ABOVE_TOL)]
        if len(far) < params.min_object_voxels:
            continue
        for piece in _pieces(xyz[far], PIECE_GAP):
            if _object_sized(xyz[far[piece], :2], params) and not _carton_wall(normals[far[piece]], rect[1]):
                out[far[piece]] = next_id
                next_id += 1
                split += 1
    return out, split
