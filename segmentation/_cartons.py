"""A carton is a box under its top: what a carton's region holds beyond its top is a neighbour.

A cylinder standing against a carton's side can end up in the carton's region: the contraction joins its
lower part at the junction (noisy normals blur the crease), and its upper part then lies within the
carton's footprint and is attached as a part of it (``_parts``). A box's walls stand under the outline of
its top and nothing of it rises above its top, so the region's voxels more than ``OUT_TOL`` outside the
rectangle of its top plateau, or more than ``ABOVE_TOL`` above the plateau, are not the carton. Where they
form an object-sized piece (voxels within ``PIECE_GAP`` of each other; the segmenter's own size measures, as
``_tops.object_sized``, as ``split_by_tops`` uses them) whose sides do not face along the carton's axes, the piece becomes a region of
its own; smaller remains stay (a wall strip, noise). Four more tests keep a carton whole:

- the walls under the unseen part of a carton's top lie outside the rectangle of the seen part, but they
  face along its axes (``WALL_SHARE`` of their side voxels within ``WALL_DEG``); a cylinder's sides face
  every way;
- the unseen part of a top seen in fragments continues the plateau: upward-facing voxels at its height
  (within ``STEP``) next to it (within ``PIECE_GAP``);
- most of the piece lies outside the rectangle: a sheet above the carton's top, inside its outline, is a
  second copy of the top (a view registered a few centimetres off), not a neighbour;
- the piece rises to within ``ABOVE_TOL`` of the carton's top: a lower neighbour whose top is seen is split
  by that top already (``split_by_tops``), so what this rule is for is a neighbour whose top is level with
  the carton's or unseen above it; a low piece is a sheet of the table or noise (the segmentation bench's
  emulator clouds, 8-14 mm of table noise, hold such pieces).

A region is a carton when its largest flat top plateau (``_tops._plateaus``) is at least ``CARTON_WIDTH``
wide and fills its minimum-area rectangle (OpenCV) to ``FILL``: a disc fills pi/4 of its square, a duck's or
a bunny's back is not flat. A carton whose top the cameras saw only in part (a corner hidden behind a
neighbour) fills less, and is still told from a disc by a corner of its own: two adjacent sides of the
rectangle each lined with plateau voxels over ``EDGE_COVER`` of their length (:func:`_seen_corner`: within
``EDGE_BAND`` of the side's own edge, the 99th percentile of the voxels across it, so that a few noisy voxels
past the edge do not move it). A disc 8 cm or more across lines each side of its square over three quarters
of it at most (a chord 1.3 cm deep); a carton's seen side is lined nearly all along.

A can whose top is level with the carton's (within the plateaus' ``STEP``) is part of the carton's plateau,
and its disc then stretches the plateau's rectangle over the can. The rectangle is therefore the carton's
*core* (:func:`_core_rectangle`): slabs of the plateau across one of its axes that are occupied over less
than ``NARROW`` of the plateau's typical width, at one end of that axis while the other end is as wide as the
middle, are not the carton's top (a box's top is as wide at its ends as in its middle; a disc is narrow at
both); they are cut off and the rectangle of the rest is taken. What was cut is outside the rectangle like any
neighbour's piece, and it does not count as the top continuing (a top seen in fragments is another plateau,
not a narrow end of this one), but a piece holding a cut end must show a side of its own (``SIDE_SHARE`` of
its voxels facing sideways): a level can's top comes with its side, the end of a carton's top that the
cameras saw only in part does not.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._params import SegmentParams
from ._tops import STEP, UP_COS, _plateaus, object_sized

__all__ = ["split_carton_neighbours"]

CARTON_WIDTH = 0.08  # m: the top plateau's rectangle is at least this wide (as _parts.CORE_MIN_WIDTH)
FILL = 0.85  # the plateau's convex hull fills at least this share of its rectangle
OUT_TOL = 0.01  # m: voxels this far outside the rectangle are not the carton (its rim's noise is less) ...
ABOVE_TOL = 0.02  # m: ... nor voxels this far above its top (a noisy top is a layer up to 2 cm thick)
PIECE_GAP = 0.015  # m: voxels of one piece lie within this of each other (3 voxels)
WALL_DEG = 20.0  # a side voxel faces along an axis of the rectangle when its normal is within this of it ...
WALL_SHARE = 0.7  # ... and a piece is the carton's own wall when this share of its side voxels does
NARROW = 0.5  # an end slab of the top plateau occupied over less than this share of its median width is no carton's
SLAB = 0.005  # m: the slabs' thickness along the axis (one voxel)
SIDE_SHARE = 0.25  # a piece holding a cut end is a neighbour only with this share of side voxels (its own side)
EDGE_BAND = 0.01  # m: plateau voxels this near a side's edge line that side (two voxels) ...
EDGE_COVER = 0.9  # ... and two adjacent sides lined over this share of their length are a seen corner


class _Top(NamedTuple):
    """A carton's top: its plateau's minimum-area rectangle in x-y and its height (table frame)."""

    centre: np.ndarray  # (2,)
    R: np.ndarray  # (2, 2), columns: the rectangle's axes
    half: np.ndarray  # (2,) half sizes along them
    height: float  # the plateau's median height (m)
    voxels: np.ndarray  # (P,) the plateau's voxel indices (its core, without the narrow ends cut off)
    cut: np.ndarray  # (C,) the voxels of the plateau's narrow ends, cut off (a level neighbour's top)


def _narrow_ends(local: np.ndarray) -> np.ndarray:
    """(P,) bool: the points ``local`` (P, 2) (in their rectangle's axes) in the end slabs, along either axis, whose
    occupied width is under ``NARROW`` of the median slab's, at an end whose opposite end is not narrow (a box
    with a neighbour's top against one side; a disc, narrow at both ends, keeps them)."""
    cut = np.zeros(len(local), bool)
    for ax in (0, 1):
        slab = np.floor((local[:, ax] - local[:, ax].min()) / SLAB).astype(int)
        n = int(slab.max()) + 1
        lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
        np.minimum.at(lo, slab, local[:, 1 - ax])
        np.maximum.at(hi, slab, local[:, 1 - ax])
        width = np.where(np.isfinite(lo), hi - lo, 0.0)
        narrow = width < NARROW * np.median(width[width > 0])
        if narrow.all():
            continue
        k_lo, k_hi = int(np.argmin(narrow)), int(np.argmin(narrow[::-1]))  # narrow slabs at each end
        if k_lo and not k_hi:
            cut |= slab < k_lo
        elif k_hi and not k_lo:
            cut |= slab >= n - k_hi
    return cut


def _core_rectangle(xy: np.ndarray) -> tuple[tuple, np.ndarray]:
    """The minimum-area rectangle (OpenCV's ``((cx, cy), (w, h), angle)``) of the points ``xy`` (P, 2) without their
    narrow ends (:func:`_narrow_ends`, in the axes of the rectangle of them all), and (P,) bool: the points cut."""
    import cv2

    rect = cv2.minAreaRect(xy.astype(np.float32))
    a = np.deg2rad(rect[2])
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    cut = _narrow_ends((xy - rect[0]) @ R)
    if (~cut).sum() < 3:
        return rect, np.zeros(len(xy), bool)
    return cv2.minAreaRect(xy[~cut].astype(np.float32)), cut


def _seen_corner(local: np.ndarray, half: np.ndarray) -> bool:
    """Whether two adjacent sides of a rectangle (half sizes ``half`` (2,)) are each lined with the points
    ``local`` (P, 2) (in the rectangle's axes, from its centre) over ``EDGE_COVER`` of their length (module
    docstring)."""
    lined = {}
    for ax in (0, 1):
        n = max(1, int(np.ceil(2 * half[1 - ax] / SLAB)))
        for sign in (1.0, -1.0):
            across = sign * local[:, ax]
            on = across >= np.percentile(across, 99) - EDGE_BAND
            k = np.clip(((local[on, 1 - ax] + half[1 - ax]) / SLAB).astype(int), 0, n - 1)
            lined[ax, sign] = len(np.unique(k)) / n >= EDGE_COVER
    return any(lined[0, s0] and lined[1, s1] for s0 in (1.0, -1.0) for s1 in (1.0, -1.0))


def _top_rectangle(idx: np.ndarray, xyz: np.ndarray, normals: np.ndarray, edges: np.ndarray) -> _Top | None:
    """The top of a carton region (voxel indices ``idx``), or None when the region is not a carton."""
    import cv2

    tops = _plateaus(idx, xyz, normals, edges)
    if not tops:
        return None
    top = max(tops, key=len)
    ((cx, cy), (w, h), angle), cut = _core_rectangle(xyz[top, :2])
    xy = xyz[top[~cut], :2].astype(np.float32)
    if min(w, h) < CARTON_WIDTH:
        return None
    a = np.deg2rad(angle)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    if (cv2.contourArea(cv2.convexHull(xy)) < FILL * w * h
            and not _seen_corner((xy - np.array([cx, cy])) @ R, np.array([w, h]) / 2)):
        return None
    return _Top(np.array([cx, cy]), R, np.array([w, h]) / 2, float(np.median(xyz[top, 2])), top[~cut], top[cut])


def _outside(xy: np.ndarray, top: _Top) -> np.ndarray:
    """(M,) distance (m) of points ``xy`` (M, 2) outside the top's rectangle (0 inside)."""
    local = np.abs((xy - top.centre) @ top.R)
    return np.linalg.norm(np.maximum(local - top.half, 0.0), axis=1)


def _pieces(points: np.ndarray, gap: float) -> list[np.ndarray]:
    """Index arrays of the groups of ``points`` (M, 3) joined by steps under ``gap`` (scipy)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(points).query_pairs(gap, output_type="ndarray")
    n = len(points)
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


def _continues_top(piece: np.ndarray, xyz: np.ndarray, normals: np.ndarray, top: _Top) -> bool:
    """Whether a piece (voxel indices) holds upward-facing voxels at the top plateau's height next to it."""
    from scipy.spatial import cKDTree

    flat = piece[(np.abs(normals[piece, 2]) >= UP_COS) & (np.abs(xyz[piece, 2] - top.height) < STEP)]
    flat = flat[~np.isin(flat, top.cut)]  # a narrow end cut off the plateau is a level neighbour's top
    if not len(flat):
        return False
    d, _ = cKDTree(xyz[top.voxels]).query(xyz[flat], distance_upper_bound=PIECE_GAP)
    return bool(np.isfinite(d).any())


def _separate(piece: np.ndarray, xyz: np.ndarray, normals: np.ndarray, top: _Top, params: SegmentParams) -> bool:
    """Whether a piece (voxel indices) outside a carton's top is an object of its own (module docstring)."""
    if np.isin(piece, top.cut).any() and np.mean(np.abs(normals[piece, 2]) < 0.7) < SIDE_SHARE:
        return False  # a narrow end of the top with no side of its own: the carton's top, partly seen
    return (object_sized(xyz[piece, :2], params) and np.mean(_outside(xyz[piece, :2], top) > 0) >= 0.5
            and xyz[piece, 2].max() >= top.height - ABOVE_TOL and not _carton_wall(normals[piece], top.R)
            and not _continues_top(piece, xyz, normals, top))


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
        top = _top_rectangle(idx, xyz, normals, edges)
        if top is None:
            continue
        far = idx[(_outside(xyz[idx, :2], top) > OUT_TOL) | (xyz[idx, 2] > top.height + ABOVE_TOL)]
        if len(far) < params.min_object_voxels:
            continue
        for piece in _pieces(xyz[far], PIECE_GAP):
            if _separate(far[piece], xyz, normals, top, params):
                out[far[piece]] = next_id
                next_id += 1
                split += 1
    return out, split
