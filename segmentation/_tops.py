"""Split a region that holds two objects with flat tops at different heights side by side.

In a noisy foundation-model cloud the junction where a small box stands against a carton's side is a few
voxels whose normals blur into a convex crease; the contraction then joins the two (on the task bench a
4 cm box and a 13 cm can were each merged into a carton this way, and the pushes meant for the carton's
face pressed the neighbour). Their tops still tell them apart: each is a flat, upward-facing plateau, at
its own height, over its own footprint. Parts of one object do not look like that: a mug's inside bottom
lies within its rim's footprint, a duck's or a bunny's back is not flat, and two touching boxes of the same
height give one plateau.

For each region: the plateaus are connected sets of upward-facing voxels (normal within ``UP_COS`` of the
table normal) whose neighbours differ in height by under ``STEP`` (flat), at least ``MIN_PLATEAU`` voxels
and ``MIN_TOP`` above the table. When two or more plateaus lie at least ``MIN_DROP`` apart in height and
their footprints (x-y convex hulls) overlap by at most ``MAX_OVERLAP`` of the smaller one, every voxel of the
region goes to the plateau whose footprint it lies deepest inside (or nearest to) in x-y, never to a plateau it
rises above by more than ``STEP``. The split is kept when every part is an object by the
segmenter's own measures (voxels, footprint size).
"""

from __future__ import annotations

import numpy as np

from ._params import SegmentParams

__all__ = ["split_by_tops"]

UP_COS = 0.9  # an upward-facing voxel: its normal within 26 degrees of the table normal
STEP = 0.004  # m: neighbouring plateau voxels differ in height by less than this
MIN_PLATEAU = 30  # voxels (5 mm: 7.5 cm^2, a 2.7 cm square)
MIN_TOP = 0.02  # m: a plateau this high above the table at least
MIN_DROP = 0.012  # m: plateaus of different objects differ in height by at least this
MAX_OVERLAP = 0.2  # share of the smaller plateau's footprint inside the other's


def _hull(xy: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.convexHull(xy.astype(np.float32)).reshape(-1, 2).astype(np.float64)


def _hull_distance(hull: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(M,) signed distance (m) of points ``xy`` (M, 2) to a convex polygon ``hull`` (K, 2): negative inside."""
    import cv2

    h = hull.astype(np.float32).reshape(-1, 1, 2)
    return np.array([-cv2.pointPolygonTest(h, (float(x), float(y)), True) for x, y in xy])


def _plateaus(idx: np.ndarray, xyz: np.ndarray, normals: np.ndarray, edges: np.ndarray) -> list[np.ndarray]:
    """Flat upward-facing plateaus (voxel index arrays) among the voxels ``idx`` of one region."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    up = idx[(np.abs(normals[idx, 2]) >= UP_COS) & (xyz[idx, 2] >= MIN_TOP)]
    if len(up) < MIN_PLATEAU:
        return []
    local = np.full(len(xyz), -1)
    local[up] = np.arange(len(up))
    a, b = local[edges[:, 0]], local[edges[:, 1]]
    ok = (a >= 0) & (b >= 0)
    a, b = a[ok], b[ok]
    flat = np.abs(xyz[up[a], 2] - xyz[up[b], 2]) < STEP
    n = len(up)
    g = coo_matrix((np.ones(int(flat.sum())), (a[flat], b[flat])), shape=(n, n))
    k, lab = connected_components(g, directed=False)
    sizes = np.bincount(lab, minlength=k)
    return [up[lab == c] for c in np.flatnonzero(sizes >= MIN_PLATEAU)]


def split_by_tops(region: np.ndarray, xyz: np.ndarray, normals: np.ndarray, edges: np.ndarray,
                  params: SegmentParams) -> tuple[np.ndarray, int]:
    """Split regions holding side-by-side objects with flat tops at different heights (module docstring).

    ``region`` (V,) region id per voxel, ``xyz`` (V, 3) voxels in the table frame (z = height), ``normals``
    (V, 3) their normals (sign free), ``edges`` (E, 2) voxel neighbour pairs. Returns the new (V,) ids (new
    regions numbered after the existing ones) and the number of regions split off.
    """
    import cv2

    out = region.copy()
    next_id = int(region.max()) + 1 if len(region) else 0
    split = 0
    order = np.argsort(region, kind="stable")
    bounds = np.flatnonzero(np.diff(region[order])) + 1
    for idx in np.split(order, bounds):
        if len(idx) < 2 * params.min_object_voxels:
            continue
        tops = _plateaus(idx, xyz, normals, edges)
        if len(tops) < 2:
            continue
        heights = np.array([float(np.median(xyz[t, 2])) for t in tops])
        hulls = [_hull(xyz[t, :2]) for t in tops]
        # keep one plateau per height level (the largest): fragments of one noisy top are not objects
        keep = []
        for i in np.argsort([-len(t) for t in tops]):
            if all(abs(heights[i] - heights[j]) >= MIN_DROP for j in keep):
                keep.append(int(i))
        if len(keep) < 2:
            continue
        apart = all(np.mean(_hull_distance(hulls[j], xyz[tops[i], :2]) < 0) <= MAX_OVERLAP
                    for i in keep for j in keep if i != j)
        if not apart:
            continue  # one footprint inside another: a mug's bottom under its rim, a part on top
        # each voxel to the plateau it lies deepest inside (or nearest to) in x-y, among those it does not
        # rise above; a voxel above every plateau (a speck of noise) to the one nearest in height
        d = np.stack([_hull_distance(hulls[i], xyz[idx, :2]) for i in keep], axis=1)  # (n, P)
        above = xyz[idx, 2][:, None] > heights[keep][None, :] + STEP
        d = np.where(above, np.inf, d)
        owner = np.argmin(d, axis=1)
        lost = ~np.isfinite(d.min(axis=1))
        owner[lost] = np.argmin(np.abs(xyz[idx[lost], 2][:, None] - heights[keep][None, :]), axis=1)
        parts = [idx[owner == p] for p in range(len(keep))]
        ok = True
        for part in parts:
            if len(part) < params.min_object_voxels:
                ok = False
                break
            (_, _), (w, h), _ = cv2.minAreaRect(xyz[part, :2].astype(np.float32))
            if max(w, h) < params.min_object_size or min(w, h) < 0.015:
                ok = False
                break
        if not ok:
            continue
        for part in parts[1:]:
            out[part] = next_id
            next_id += 1
            split += 1
    return out, split
