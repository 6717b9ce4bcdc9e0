"""Region clean-up after contraction: attach parts that cannot stand on their own, drop noise.

Convexity alone cuts objects that have concave junctions of their own: a mug's handle, its inside, a
duck's head, a bunny's ears. Such parts share a physical trait that separate objects lack: they do not
stand on the table (nor on top of another object), and/or they lie inside another region's footprint.
A region S adjacent to a bigger region N is attached to N when

    S's bottom is below N's top (S is not stacked on N), and
    S does not reach the table, or at least 90% of S lies inside N's footprint (convex hull in x-y).

Among the parts that do not reach the table, thin ones (under 3 cm wide) join N when they hang off its side
below its top (a handle) or, at least a fifth of N's size, rise above N's top from its upper part (a bunny's
ears beside its head: split off at the concave junction, a grasp of the body alone would close its
fingers on the ears).

A part that touches no region at all (the cloud misses the concave junction: a duck's neck) but rests on
one that reaches the table, at most 1.5 cm above its top and inside its footprint, joins it unless it is an
object standing on it (rule ``resting_parts``).

A part may have more voxels than the region that holds it up (cameras looking down see a duck's head better
than its body, a carton's top face better than its walls): a region that does not reach the table may join one
that does whatever their sizes (rule ``held_parts``); otherwise the smaller region joins the larger.

Colour keeps apart two regions whose flat junction is a change of print (two objects flush side by side), but
a printed band also cuts one top in two: a piece that does not reach the table, whose top is level with a
neighbour's, which meets that neighbour's top along its whole width there, and whose top and the neighbour's
together fill one box's rectangle or one can's circle, is the rest of that top whatever its colour (rule
``cut_tops``). A separate object's top seen between others meets a neighbour's at a tangent, which leaves
notches beside the junction, and one whose sides are seen reaches the table.

A touching neighbour that stands on the table beside N is left alone; a box stacked on N is left alone.
Tiny regions (fewer than ``min_object_voxels``) join the neighbour with the best affinity when they rise
above the table band, and are dropped otherwise.
"""

from __future__ import annotations

import numpy as np

from ._graph import RegionGraph
from ._params import SegmentParams

STACK_TOL = 0.01  # S may stand on N when its bottom is within 1 cm of N's top, or above it
THIN = 0.03  # a part hanging off N outside its footprint must be narrower than this (a handle)
FLOAT_RISE = 0.015  # ... or, rising above N, its lowest voxels this far above N's ...
FLOAT_SHARE = 0.2  # ... and at least this share of N's size (a bunny's ears: 0.38 of its body; the top of a
# can seen above a carton beside it, its lower part hidden: 0.02)
REST_GAP = 0.015  # a floating part's bottom at most this far above the top of the region it rests on
TIGHT_MARGIN = 0.005
HULL_MARGIN = 0.01  # "inside N's footprint": within N's x-y convex hull grown by 1 cm (N's walls, noise)
CORE_RADIUS = 0.01  # N's footprint for that test: its core, without slivers under 2 cm wide (see core_hull) ...
CORE_MIN_WIDTH = 0.08  # ... for regions at least this wide (cartons); smaller ones keep their plain hull
CUT_SPAN = 0.9  # a top cut in two: the piece meets the neighbour's top along this share of its width there ...
CUT_BAND = 0.01  # ... top voxels: within this of the region's top; ...
CUT_GAP = 0.008  # ... meeting: top voxels of the two within this of each other in x-y (1.5 voxels)
PLATEAU_COS = 0.9  # ... top voxels facing up: |normal z| at least this (within 26 deg of vertical); and
TOP_FILL_RECT = 0.9  # ... both tops together fill this share of their minimum-area rectangle (a box's top) ...
TOP_FILL_DISC = 0.6  # ... or of their enclosing circle (a can's). Two tops met at a tangent fill less: two
# equal discs 0.5 of their circle (0.79 of their rectangle), a can beside a 5 cm box 0.53 (0.75), a can beside a
# carton under 0.87 of its rectangle; a whole can's top, ragged in a pipeline cloud, fills 0.66-0.84


def _inside_hull(hull_xy: np.ndarray, xy: np.ndarray, margin: float, cell: float = 0.002) -> np.ndarray:
    """(M,) bool: points ``xy`` (M, 2) inside the convex polygon ``hull_xy`` (K, 2) grown by ``margin``.

    Rasterised (OpenCV ``fillConvexPoly`` + ``dilate``) at ``cell``: one grid look-up per point.
    """
    import cv2

    if len(hull_xy) < 3:
        return np.zeros(len(xy), bool)
    lo = hull_xy.min(0) - margin - 2 * cell
    shape = np.ceil((hull_xy.max(0) + margin + 2 * cell - lo) / cell).astype(int) + 1
    grid = np.zeros((shape[1], shape[0]), np.uint8)
    cv2.fillConvexPoly(grid, np.round((hull_xy - lo) / cell).astype(np.int32), 1)
    r = int(np.ceil(margin / cell))
    if r > 0:
        grid = cv2.dilate(grid, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < shape[0]) & (ij[:, 1] < shape[1])
    out = np.zeros(len(xy), bool)
    out[ok] = grid[ij[ok, 1], ij[ok, 0]] > 0
    return out


def core_hull(xy: np.ndarray, cell: float = 0.004, radius: float = CORE_RADIUS) -> np.ndarray:
    """(K, 2) convex hull of the *core* of a footprint ``xy`` (M, 2): its raster (``cell``), holes filled,
    opened by a disc of ``radius`` (OpenCV), so that slivers narrower than 2 x ``radius`` do not count.
    Falls back to the plain hull when the opening leaves nothing.

    The contraction leaves a few voxels of a touching neighbour's side in a region; the plain hull then
    spans the gap to them and covers the neighbour, which the footprint test below took for a part of the
    region (a cylinder standing against a carton's side would be merged into the carton)."""
    import cv2
    from scipy import ndimage

    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    plain = cv2.convexHull(xy.astype(np.float32)).reshape(-1, 2).astype(np.float64) if len(xy) >= 3 else xy
    if len(xy) < 3:
        return plain
    r = int(np.ceil(radius / cell))
    lo = xy.min(0) - (r + 2) * cell
    ij = np.floor((xy - lo) / cell).astype(int)
    shape = ij.max(0) + r + 3
    grid = np.zeros((shape[1], shape[0]), np.uint8)
    grid[ij[:, 1], ij[:, 0]] = 1
    grid = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    grid = ndimage.binary_fill_holes(grid).astype(np.uint8)
    core = cv2.morphologyEx(grid, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    yx = np.argwhere(core > 0)
    if len(yx) < 3:
        return plain
    pts = (yx[:, ::-1] + 0.5) * cell + lo
    return cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2).astype(np.float64)


class _Stats:
    def __init__(self, xyz: np.ndarray, voxels_of: dict[int, np.ndarray]):
        import cv2

        self.bottom, self.top, self.hull, self.xy, self.width = {}, {}, {}, {}, {}
        for r, idx in voxels_of.items():
            z = xyz[idx, 2]
            self.bottom[r] = float(np.percentile(z, 1))
            self.top[r] = float(np.percentile(z, 98))
            xy = xyz[idx, :2]
            self.xy[r] = xy
            self.width[r] = float(min(cv2.minAreaRect(xy.astype(np.float32))[1])) if len(xy) >= 3 else 0.0
            # a large region's footprint is its core (a neighbour's stray voxels do not stretch it); a small
            # object's is its plain hull (opening it would cut off the head of a duck, a mug's rim)
            self.hull[r] = core_hull(xy) if self.width[r] >= CORE_MIN_WIDTH else (
                cv2.convexHull(xy.astype(np.float32)).reshape(-1, 2).astype(np.float64) if len(xy) >= 3 else xy)


def reaches_table(bottom: float, top: float) -> bool:
    """True when a region's lowest visible voxels are near the table (its base is seen or implied)."""
    return bottom <= max(0.015, 0.3 * top)


def looks_different(G: RegionGraph, S: int, N: int) -> bool:
    """The masks say S and N are different instances, or their colours differ across a flat junction."""
    if G.masks is not None and G.mask_agreement(S, N) < -0.5:
        return True
    w, _, wf = G.adj[S][N]
    return G.hist is not None and wf / max(w, 1e-9) * G.colour_penalty(S, N) >= 0.5


def is_object_on(G: RegionGraph, S: int, N: int, st: _Stats, params: SegmentParams) -> bool:
    """S (whose bottom is at N's top) is an object standing on N, not a part of N's top.

    It must rise above N by at least ``min_object_height`` (a flat piece of N's top face is N's print),
    and, when colours are known, its colours must differ from N's (a duck's head sits on its body).
    """
    if st.top[S] - st.bottom[S] < params.min_object_height:
        return False
    return G.hist is None or G.colour_penalty(S, N) >= 0.5


def _top_band(xyz: np.ndarray, normals: np.ndarray, top: float) -> np.ndarray:
    """(k, 2) x-y of the voxels within ``CUT_BAND`` of ``top`` that face up (a plateau, not a wall's rim)."""
    keep = (xyz[:, 2] >= top - CUT_BAND) & (np.abs(normals[:, 2]) >= PLATEAU_COS)
    return xyz[keep, :2]


def cut_top(S_xyz: np.ndarray, S_normals: np.ndarray, N_xyz: np.ndarray, N_normals: np.ndarray, s_bottom: float,
            s_top: float, n_top: float) -> bool:
    """Whether region S (voxels ``S_xyz`` (m, 3) and normals (m, 3), table frame) is a piece of neighbour N's
    top cut off by its print (rule ``cut_tops``, module docstring): S does not reach the table, its top is
    level with N's (within ``STACK_TOL``), the upward-facing top voxels of S within ``CUT_GAP`` of N's
    (``N_xyz``, ``N_normals`` (n, 3)) span at least ``CUT_SPAN`` of S's top along the line they follow (S is
    no wider than where it meets N: a cut, not a tangent), and both tops together are one box's or one can's
    (:func:`one_primitive_top`)."""
    from scipy.spatial import cKDTree

    if reaches_table(s_bottom, s_top) or abs(s_top - n_top) > STACK_TOL:
        return False
    s_xy, n_xy = _top_band(S_xyz, S_normals, s_top), _top_band(N_xyz, N_normals, n_top)
    if len(s_xy) < 3 or len(n_xy) < 3:
        return False
    d, _ = cKDTree(n_xy).query(s_xy, distance_upper_bound=CUT_GAP)
    meet = s_xy[np.isfinite(d)]
    if len(meet) < 2:
        return False
    axis = np.linalg.svd(meet - meet.mean(0), full_matrices=False)[2][0]
    if np.ptp(meet @ axis) + CUT_GAP < CUT_SPAN * (np.ptp(s_xy @ axis) + CUT_GAP):
        return False  # S is wider than where it meets N: a tangent, not a cut
    return one_primitive_top(np.vstack([s_xy, n_xy]))


def one_primitive_top(xy: np.ndarray, cell: float = 0.005) -> bool:
    """Whether a top's footprint ``xy`` (M, 2) is one box's or one can's: its raster (``cell``, closed, holes
    filled) fills at least ``TOP_FILL_RECT`` of its minimum-area rectangle or ``TOP_FILL_DISC`` of its minimum
    enclosing circle (both grown by half a cell: the raster's cells are squares around the points). Two tops
    that meet at a tangent (a can beside a carton) leave the notches between them empty."""
    import cv2
    from scipy import ndimage

    lo = xy.min(0) - 2 * cell
    ij = np.floor((xy - lo) / cell).astype(int)
    grid = np.zeros(tuple(ij.max(0)[::-1] + 3), np.uint8)
    grid[ij[:, 1], ij[:, 0]] = 1
    grid = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))  # a ragged top's missing cells
    area = float(ndimage.binary_fill_holes(grid).sum()) * cell * cell
    pts = xy.astype(np.float32)
    w, h = cv2.minAreaRect(pts)[1]
    r = cv2.minEnclosingCircle(pts)[1]
    return (area >= TOP_FILL_RECT * (w + cell) * (h + cell)
            or area >= TOP_FILL_DISC * np.pi * (r + cell / 2) ** 2)


def _grounds(N: int, S: int, st: _Stats, params: SegmentParams) -> bool:
    """N reaches the table and S does not (rule ``held_parts``): S may join N though it has more voxels (a duck's
    head seen better than its body by cameras looking down; a carton's top face, its walls hidden)."""
    return ("held_parts" not in params.skip and reaches_table(st.bottom[N], st.top[N])
            and not reaches_table(st.bottom[S], st.top[S]))


def _groups(G: RegionGraph, patch_of_voxel: np.ndarray) -> dict[int, np.ndarray]:
    lab = np.array([G.find(i) for i in range(len(G.parent))])[patch_of_voxel]
    order = np.argsort(lab, kind="stable")
    bounds = np.flatnonzero(np.diff(lab[order])) + 1
    return {int(lab[g[0]]): g for g in np.split(order, bounds)}


def _resting_on(G: RegionGraph, S: int, big: dict, st: _Stats, params: SegmentParams) -> int | None:
    """The region a floating region S rests on across a gap in the cloud, or None (the rule ``resting_parts``
    of attach_parts): S does not reach the table, and N, which does, has its top at most ``REST_GAP`` below
    S's bottom (or overlaps it by ``STACK_TOL``) and holds 90% of S inside its footprint; not when S is an
    object standing on N (:func:`is_object_on`). The region graph links only touching voxels, and where the
    cloud misses a concave junction (a duck's neck, seen from above by wrist cameras) the part above has no
    neighbour."""
    if "resting_parts" in params.skip or reaches_table(st.bottom[S], st.top[S]):
        return None
    best, share = None, 0.0
    for N in big:
        if N == S or not reaches_table(st.bottom[N], st.top[N]):
            continue
        if not -STACK_TOL <= st.bottom[S] - st.top[N] <= REST_GAP:
            continue
        inside = float(np.mean(_inside_hull(st.hull[N], st.xy[S], HULL_MARGIN)))
        if inside >= 0.9 and inside > share:
            best, share = N, inside
    if best is None or is_object_on(G, S, best, st, params):
        return None
    return best


def attach_parts(G: RegionGraph, patch_of_voxel: np.ndarray, xyz: np.ndarray, params: SegmentParams,
                 max_rounds: int = 200, normals: np.ndarray | None = None) -> int:
    """Merge tiny regions and dependent parts of ``G`` in place; returns the number of merges.

    ``patch_of_voxel`` (V,) maps voxels to patches (the graph's initial nodes); ``xyz`` (V, 3) are the
    voxels in the table frame (z = height); ``normals`` (V, 3) their normals (sign free), for the rule
    ``cut_tops`` (without them it does not run).
    """
    cuts = normals is not None and "cut_tops" not in params.skip
    merges = 0
    # 1. tiny regions, smallest first, into their best neighbour (one pass; sizes are kept by G)
    groups = _groups(G, patch_of_voxel)
    top = {r: float(xyz[idx, 2].max()) for r, idx in groups.items()}
    for S in sorted(groups, key=lambda r: len(groups[r])):
        r = G.find(S)
        if r != S or G.nvox[S] >= params.min_object_voxels or top[S] < params.min_object_height:
            continue
        nbrs = [n for n in G.adj[S] if G.alive[n]]
        if nbrs:
            G.merge(S, max(nbrs, key=lambda n: G.affinity(S, n)))
            merges += 1
    # 2. parts that cannot stand alone, one merge per round (stats change with each merge)
    for _ in range(max_rounds):
        groups = _groups(G, patch_of_voxel)
        big = {r: g for r, g in groups.items() if len(g) >= params.min_object_voxels}
        st = _Stats(xyz, big)
        did = False
        for S in sorted(big, key=lambda r: len(big[r])):
            nS = len(big[S])
            cands = []
            for N in G.adj[S]:
                if N not in big or (len(big[N]) <= nS and not _grounds(N, S, st, params)):
                    continue
                if cuts and cut_top(xyz[big[S]], normals[big[S]], xyz[big[N]], normals[big[N]], st.bottom[S],
                                    st.top[S], st.top[N]):
                    cands.append(N)  # a piece of N's top that its print cut off
                    continue
                if looks_different(G, S, N):
                    continue
                if st.bottom[S] >= st.top[N] - STACK_TOL and is_object_on(G, S, N, st, params):
                    continue
                overlap = float(np.mean(_inside_hull(st.hull[N], st.xy[S], HULL_MARGIN)))
                if overlap >= 0.9:
                    cands.append(N)  # within N's footprint: N's inside, N's print, a part on top
                elif overlap >= 0.5 and np.mean(_inside_hull(st.hull[N], st.xy[S], TIGHT_MARGIN)) >= 0.5:
                    cands.append(N)  # half inside N's footprint: two convex objects cannot interpenetrate
                elif (not reaches_table(st.bottom[S], st.top[S]) and st.width[S] < THIN
                      and st.top[S] <= st.top[N] + STACK_TOL / 2):
                    cands.append(N)  # hangs off N's side, thin, not above it (a handle)
                elif ("bunny_ears" not in params.skip
                      and not reaches_table(st.bottom[S], st.top[S]) and st.width[S] < THIN
                      and st.bottom[S] >= st.bottom[N] + FLOAT_RISE and st.top[S] > st.top[N] + STACK_TOL / 2
                      and nS >= FLOAT_SHARE * len(big[N])):
                    cands.append(N)  # thin, held up beside N's upper part, rising above it (a bunny's ears)
            # a neighbour (the best-linked one), else the region S rests on across a gap (no junction)
            target = max(cands, key=lambda n: G.affinity(S, n)) if cands else _resting_on(G, S, big, st, params)
            if target is not None:
                G.merge(S, target)
                merges += 1
                did = True
                break
        if not did:
            break
    return merges


def dissolve_slivers(region: np.ndarray, xyz: np.ndarray, width: float, min_voxels: int) -> np.ndarray:
    """Hand the voxels of sliver regions to the nearest voxel of another region.

    Where two objects meet in a concave valley, the voxels along the valley are concave to both sides
    and can end up as a region of their own: tall or long, but only about a centimetre wide in x-y.
    Regions whose footprint (OpenCV minimum-area rectangle of the x-y) is narrower than ``width`` are
    split voxel by voxel between their neighbours (nearest kept voxel, KD-tree). ``region`` (V,) region
    ids, ``xyz`` (V, 3) table frame; returns the new (V,) ids.
    """
    import cv2
    from scipy.spatial import cKDTree

    R = int(region.max()) + 1
    order = np.argsort(region, kind="stable")
    bounds = np.flatnonzero(np.diff(region[order])) + 1
    sliver = np.zeros(R, bool)
    for g in np.split(order, bounds):
        if len(g) < 3:
            continue
        (_, _), (w, h), _ = cv2.minAreaRect(xyz[g, :2].astype(np.float32))
        sliver[region[g[0]]] = min(w, h) < width
    counts = np.bincount(region, minlength=R)
    donors = ~sliver[region] & (counts[region] >= min_voxels)
    move = sliver[region]
    if not move.any() or not donors.any():
        return region
    tree = cKDTree(xyz[donors])
    d, j = tree.query(xyz[move], k=1, distance_upper_bound=4 * width, workers=-1)
    out = region.copy()
    ok = np.isfinite(d)
    idx = np.flatnonzero(move)
    out[idx[ok]] = region[np.flatnonzero(donors)[j[ok]]]
    return out
