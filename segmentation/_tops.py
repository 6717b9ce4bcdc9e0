"""Split a region that holds two objects with flat tops at different heights side by side.

In a noisy foundation-model cloud the junction where a small box stands against a carton's side is a few
voxels whose normals blur into a convex crease; the contraction then joins the two (and a grasp planned
for the merged region's face can press the neighbour; cases: docs/segmentation.md). Their tops still tell
them apart: each is a flat, upward-facing plateau, at
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

Two tops within ``MIN_DROP`` of each other make one plateau; where another object's top bulges out of a
plateau's outline, joined to it along a short chord between two deep concave corners, the bulge is cut off
as a plateau of its own (``_bump``: e.g. a can only a few millimetres taller than the carton it stands against).
"""

from __future__ import annotations

import numpy as np

from ._params import SegmentParams

__all__ = ["split_by_tops", "object_sized"]

UP_COS = 0.9  # an upward-facing voxel: its normal within 26 degrees of the table normal
STEP = 0.004  # m: neighbouring plateau voxels differ in height by less than this
MIN_PLATEAU = 30  # voxels (5 mm: 7.5 cm^2, a 2.7 cm square)
MIN_TOP = 0.02  # m: a plateau this high above the table at least
MIN_DROP = 0.012  # m: plateaus of different objects differ in height by at least this
MAX_OVERLAP = 0.2  # share of the smaller plateau's footprint inside the other's
# One plateau over two objects whose tops are level (a can 3 mm taller than the carton it stands against):
# its footprint is the carton's rectangle with the can's disc bulging out of one side, joined along a short
# chord between two deep concave corners (``_bump``)
BUMP_DEPTH = 0.015  # m: both corners at least this deep (convexity defects of the footprint's outline)
BUMP_CUT = 0.08  # m: the chord between them at most this long (an object the gripper could hold)
BUMP_SIDES = (0.025, 0.12)  # m: the part cut off is at least / at most this wide (min-area rectangle)
BUMP_CELL = 0.005  # m: raster cell of the footprint outline
BUMP_REACH = 0.01  # m: such a piece takes the region's voxels at most this far outside its footprint


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


def _bump(xy: np.ndarray) -> np.ndarray | None:
    """(M,) bool: the points of a plateau footprint ``xy`` (M, 2) in a second object's top that bulges out
    of it (module constants ``BUMP_*``), or None. The footprint is rasterised and closed (OpenCV); its
    outline's two deepest convexity defects, each ``BUMP_DEPTH`` deep, are joined by a chord of at most
    ``BUMP_CUT``; cut there, the smaller piece must be ``BUMP_SIDES`` wide. The thresholds let a can's disc
    bulging out of a carton's top through and keep notches in a carton's noisy rim (shallower, or far apart)
    from being cut (measured cases: docs/segmentation.md)."""
    import cv2

    cell = BUMP_CELL
    lo = xy.min(axis=0) - 3 * cell
    ij = np.floor((xy - lo) / cell).astype(int)
    n_x, n_y = ij.max(axis=0) + 4
    img = np.zeros((n_y, n_x), np.uint8)
    img[ij[:, 1], ij[:, 0]] = 255
    img = cv2.morphologyEx(img, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    contours, _ = cv2.findContours(img, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    if len(c) < 8:
        return None
    hull = np.sort(cv2.convexHull(c, returnPoints=False), axis=0)  # convexityDefects wants them monotonous
    try:
        defects = cv2.convexityDefects(c, hull)
    except cv2.error:  # an outline that touches itself (a one-cell isthmus): no clean pair of corners
        return None
    if defects is None:
        return None
    d = defects[:, 0]
    deep = d[d[:, 3] / 256.0 * cell >= BUMP_DEPTH]
    if len(deep) < 2:
        return None
    deep = deep[np.argsort(-deep[:, 3])][:2]
    q1, q2 = (tuple(int(v) for v in c[k, 0]) for k in deep[:, 2])
    if np.hypot(q1[0] - q2[0], q1[1] - q2[1]) * cell > BUMP_CUT:
        return None
    cut = img.copy()
    cv2.line(cut, q1, q2, 0, 2)
    k, comp = cv2.connectedComponents(cut, connectivity=4)
    lab = comp[ij[:, 1], ij[:, 0]]
    sizes = np.bincount(lab[lab > 0], minlength=k)
    if (sizes > 0).sum() < 2:
        return None
    small = lab == np.argsort(-sizes)[1]
    # the points on the cut itself go to the side of the chord the piece lies on (its footprint reaches the
    # chord: the other object's wall below it is then nearer its footprint than the carton's)
    a, b = ((np.array(q, float) + 0.5) * cell + lo for q in (q1, q2))
    normal = np.array([a[1] - b[1], b[0] - a[0]])
    side = (xy - a) @ normal
    small |= (lab == 0) & (np.sign(side) == np.sign(np.mean(side[small])))
    (_, _), (w, h), _ = cv2.minAreaRect(xy[small].astype(np.float32))
    if min(w, h) < BUMP_SIDES[0] or max(w, h) > BUMP_SIDES[1]:
        return None
    return small


def object_sized(xy: np.ndarray, params: SegmentParams) -> bool:
    """Whether a piece split off a region (its voxels' x-y ``xy`` (M, 2)) is an object by the segmenter's own
    measures: ``min_object_voxels`` voxels, a footprint ``min_object_size`` long and 1.5 cm wide."""
    import cv2

    if len(xy) < params.min_object_voxels:
        return False
    (_, _), (w, h), _ = cv2.minAreaRect(xy.astype(np.float32))
    return max(w, h) >= params.min_object_size and min(w, h) >= 0.015


def split_by_tops(region: np.ndarray, xyz: np.ndarray, normals: np.ndarray, edges: np.ndarray,
                  params: SegmentParams) -> tuple[np.ndarray, int]:
    """Split regions holding side-by-side objects with flat tops at different heights (module docstring).

    ``region`` (V,) region id per voxel, ``xyz`` (V, 3) voxels in the table frame (z = height), ``normals``
    (V, 3) their normals (sign free), ``edges`` (E, 2) voxel neighbour pairs. Returns the new (V,) ids (new
    regions numbered after the existing ones) and the number of regions split off.
    """

    out = region.copy()
    next_id = int(region.max()) + 1 if len(region) else 0
    split = 0
    order = np.argsort(region, kind="stable")
    bounds = np.flatnonzero(np.diff(region[order])) + 1
    for idx in np.split(order, bounds):
        if len(idx) < 2 * params.min_object_voxels:
            continue
        tops = _plateaus(idx, xyz, normals, edges)
        level = set()  # pairs of plateaus cut from one level top (_bump): apart though at one height
        bumps = set()
        for i in range(len(tops) if "level_tops" not in params.skip else 0):
            small = _bump(xyz[tops[i], :2])
            if small is not None:
                level.add((i, len(tops)))
                bumps.add(len(tops))
                tops.append(tops[i][small])
                tops[i] = tops[i][~small]
        if len(tops) < 2:
            continue
        heights = np.array([float(np.median(xyz[t, 2])) for t in tops])
        hulls = [_hull(xyz[t, :2]) for t in tops]
        # keep one plateau per height level (the largest): fragments of one noisy top are not objects
        keep = []
        for i in np.argsort([-len(t) for t in tops]):
            if all(abs(heights[i] - heights[j]) >= MIN_DROP or (min(i, j), max(i, j)) in level for j in keep):
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
        # a piece cut off a level top takes only what lies within BUMP_REACH of its footprint (its top, its
        # wall); the rest of its plateau's region, even voxels above the plateau's median (a noisy top is a
        # layer 2 cm thick on the emulator's clouds), stays with the plateau's footprint
        cut = [j for j, i in enumerate(keep) if i in bumps]
        for j in cut:
            d[:, j] = np.where(d[:, j] <= BUMP_REACH, d[:, j], np.inf)
        d_flat = d.copy()
        above = xyz[idx, 2][:, None] > heights[keep][None, :] + STEP
        d = np.where(above, np.inf, d)
        owner = np.argmin(d, axis=1)
        lost = ~np.isfinite(d.min(axis=1))
        owner[lost] = np.argmin(np.abs(xyz[idx[lost], 2][:, None] - heights[keep][None, :]), axis=1)
        if cut:
            owner[lost] = np.argmin(d_flat[lost], axis=1)
        parts = [idx[owner == p] for p in range(len(keep))]
        if not all(object_sized(xyz[part, :2], params) for part in parts):
            continue
        for part in parts[1:]:
            out[part] = next_id
            next_id += 1
            split += 1
    return out, split
