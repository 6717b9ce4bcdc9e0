"""Give a neighbour back the piece of its wall that a small box's region took.

A small box wedged against a can or a carton: the few voxels of the neighbour's side next to the box's edge
have normals blurred by the noise, and the contraction joins them to the box (a strip of the neighbour's
side, possibly taller than the box; the box's segment then looks longer than it is and its grasps collide
with the neighbour; cases: docs/segmentation.md). The box's flat top tells where the box is: its sides
stand within the top's footprint (x-y), and what lies clearly outside it, on the neighbour's footprint,
is the neighbour's.

For each region with a flat top (:func:`._tops._plateaus`, the largest, with its edge voxels at its height, facing up)
that is the region's top (at most ``MAX_ABOVE`` of its voxels rise ``ABOVE`` it: not a cup's inside bottom)
and covers at least ``MIN_TOP_SHARE`` of the region's own footprint (a box, a can: not a duck): its voxels
more than ``MARGIN`` outside the top's footprint, or rising above the top, that lie within
``NEAR`` of the footprint of an adjacent, larger object region (one sharing a voxel edge with them), in
connected pieces that touch that region, go to it; at most ``MAX_SHED`` of the region. Only small regions
(the top at most ``MAX_TOP`` long) give: a large region whose top is seen only in part (a carton), or whose
top is not its whole footprint (a torus's ring-shaped crown), would otherwise give its own sides away.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from ._params import SegmentParams
from ._tops import STEP, _hull, _hull_distance, _plateaus

__all__ = ["shed_neighbour_walls"]

MARGIN = 0.008  # m outside the top's footprint (a box's own sides stand within the cloud noise, 2-3 mm)
NEAR = 0.004  # m: within (or this near) the neighbour's footprint
MIN_TOP_SHARE = 0.5  # the top's footprint area over the region's
MAX_SHED = 0.4  # share of the region's voxels it may give away
MAX_TOP = 0.09  # m: the top's longer side at most (a small box, a can: what one gripper takes)
ABOVE = 2 * STEP  # m: a voxel this far above the top rises above it (a box's sides do not)
MAX_ABOVE = 0.25  # share of the region's voxels that may rise above its top (else the plateau is not its top)
TOP_EDGE = 0.012  # m: the top's edge voxels lie this near the plateau ...
EDGE_COS = 0.5  # ... with normals within 60 degrees of up (blurred by the corner; a wall beside it: level)


def _area(hull: np.ndarray) -> float:
    import cv2

    return float(cv2.contourArea(hull.astype(np.float32).reshape(-1, 1, 2))) if len(hull) >= 3 else 0.0


def _box_top(idx: np.ndarray, xyz: np.ndarray, normals: np.ndarray, edges: np.ndarray,
             region_hull: Callable[[], np.ndarray]) -> tuple[float, np.ndarray] | None:
    """(height, (K, 2) footprint hull) of the flat top of the region with voxels ``idx`` when it is the region's
    top, covers ``MIN_TOP_SHARE`` of its footprint (``region_hull()``, asked only when needed) and is at most
    ``MAX_TOP`` long; else None."""
    import cv2

    tops = _plateaus(idx, xyz, normals, edges)
    if not tops:
        return None
    top_vox = max(tops, key=len)
    h = float(np.median(xyz[top_vox, 2]))
    z = xyz[idx, 2]
    if np.mean(z > h + ABOVE) > MAX_ABOVE:
        return None  # not the region's top: a cup's inside bottom, a part low down
    # the top's full outline: the voxels at its height near the plateau (whose edge voxels, their
    # normals blurred by the corner, it leaves out)
    near_top = ((np.abs(z - h) < STEP) & (np.abs(normals[idx, 2]) >= EDGE_COS)
                & (_hull_distance(_hull(xyz[top_vox, :2]), xyz[idx, :2]) < TOP_EDGE))
    top_hull = _hull(xyz[idx[near_top], :2])
    if _area(top_hull) < MIN_TOP_SHARE * max(_area(region_hull()), 1e-12):
        return None
    (_, _), (w, l), _ = cv2.minAreaRect(top_hull.astype(np.float32))
    if max(w, l) > MAX_TOP:
        return None  # a carton's region: its sides beyond a partly seen top are its own
    return h, top_hull


def _larger_neighbours(r: int, idx: np.ndarray, region: np.ndarray, ca: np.ndarray, cb: np.ndarray,
                       is_obj: np.ndarray, nvox: np.ndarray) -> list[int]:
    """Object regions sharing a voxel edge with region ``r`` (voxels ``idx``) and larger than it."""
    mine = np.zeros(len(region), bool)
    mine[idx] = True
    nb = np.unique(np.concatenate([region[cb[mine[ca]]], region[ca[mine[cb]]]]))
    return [int(n) for n in nb if n != r and is_obj[n] and nvox[n] > len(idx)]


def _touching_pieces(cand_vox: np.ndarray, cand_owner: np.ndarray, nb: list[int], region: np.ndarray,
                     a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(C,) bool: candidates in connected pieces that touch the neighbour most of the piece lies by; the piece's
    owner (``cand_owner``, index into ``nb``) is set to that neighbour."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    local = np.full(len(region), -1)
    local[cand_vox] = np.arange(len(cand_vox))
    la, lb = local[a], local[b]
    inner = (la >= 0) & (lb >= 0)
    g = coo_matrix((np.ones(int(inner.sum())), (la[inner], lb[inner])), shape=(len(cand_vox),) * 2)
    _, piece = connected_components(g, directed=False)
    give = np.zeros(len(cand_vox), bool)
    for p in np.unique(piece):
        sel = piece == p
        n = nb[int(np.bincount(cand_owner[sel]).argmax())]
        pv = cand_vox[sel]
        pm = np.zeros(len(region), bool)
        pm[pv] = True
        touches = np.any(pm[a] & (region[b] == n)) or np.any(pm[b] & (region[a] == n))
        if touches:
            give[sel] = True
            cand_owner[sel] = nb.index(n)
    return give


def shed_neighbour_walls(region: np.ndarray, xyz: np.ndarray, normals: np.ndarray, edges: np.ndarray,
                         params: SegmentParams, min_top: float = 0.0) -> tuple[np.ndarray, int]:
    """Move pieces of neighbours' walls out of box-topped regions (module docstring).

    ``region`` (V,) region id per voxel, ``xyz`` (V, 3) voxels in the table frame (z = height), ``normals``
    (V, 3) their normals (sign free), ``edges`` (E, 2) voxel neighbour pairs; ``min_top``: a neighbour is an
    object when its highest voxel is at least this high (and it has ``params.min_object_voxels``). Returns
    the new (V,) ids and the number of voxels moved.
    """
    region = np.asarray(region)
    out = region.copy()
    R = int(region.max()) + 1 if len(region) else 0
    nvox = np.bincount(region, minlength=R)
    top = np.full(R, -np.inf)
    np.maximum.at(top, region, xyz[:, 2])
    is_obj = (nvox >= params.min_object_voxels) & (top >= min_top)
    a, b = edges[:, 0], edges[:, 1]
    cross = region[a] != region[b]
    ca, cb = a[cross], b[cross]
    hulls: dict[int, np.ndarray] = {}

    def hull_of(r: int) -> np.ndarray:
        if r not in hulls:
            hulls[r] = _hull(xyz[region == r, :2])
        return hulls[r]

    moved = 0
    order = np.argsort(region, kind="stable")
    bounds = np.flatnonzero(np.diff(region[order])) + 1
    for idx in np.split(order, bounds):
        r = int(region[idx[0]])
        if not is_obj[r]:
            continue
        box = _box_top(idx, xyz, normals, edges, partial(hull_of, r))
        if box is None:
            continue
        h, top_hull = box
        outside = idx[(_hull_distance(top_hull, xyz[idx, :2]) > MARGIN) | (xyz[idx, 2] > h + ABOVE)]
        if not len(outside):
            continue
        nb = _larger_neighbours(r, idx, region, ca, cb, is_obj, nvox)
        if not nb:
            continue
        d = np.stack([_hull_distance(hull_of(n), xyz[outside, :2]) for n in nb], axis=1)  # (k, N)
        owner = np.argmin(d, axis=1)
        cand = d[np.arange(len(outside)), owner] <= NEAR
        if not cand.any():
            continue
        cand_vox, cand_owner = outside[cand], owner[cand]
        give = _touching_pieces(cand_vox, cand_owner, nb, region, a, b)
        if not give.any() or give.sum() > MAX_SHED * len(idx):
            continue
        out[cand_vox[give]] = np.array(nb)[cand_owner[give]]
        moved += int(give.sum())
    return out, moved
