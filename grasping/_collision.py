"""Collision checks of the gripper's real geometry (coal shapes from the URDF) against the scene map.

The scene map is a coal octree built from the metric cloud (``coal.makeOctree``). A grasp is checked
with its *approach sweep*: each gripper shape is replaced by the volume it sweeps while the gripper moves
in along its approach axis from the pre-grasp (``approach`` metres back) to the grasp. For a box whose
axes include the approach axis that volume is a longer box; for any other shape it is the convex hull
(``coal.Convex.convexHull``) of its bounding box at both ends. So a grasp whose fingers would pass
through a neighbour on the way in is rejected, not only one whose final pose overlaps it.

Broad phases keep coal's exact tests for the pairs that can touch (bounding spheres against a grid of
occupied cells for the scene, against each other for two grippers); ``PointClearance`` answers whether
rigidly moved copies of an object's points keep a clearance from the scene (the hand-over's transfer poses).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._gripper import GripperModel

__all__ = ["SceneOctree", "GripperCollider", "grippers_collide", "grippers_collide_many", "grippers_distance",
           "points_in_gripper", "place_grippers", "PlacedGrippers"]


class SceneOctree:
    """A coal octree of points (N, 3) at ``resolution`` metres (empty point sets give a map that never collides).
    ``octree``: one already built of these points at this resolution (a task's ``SceneMap``), used as it is."""

    def __init__(self, points: np.ndarray, resolution: float = 0.004, octree=None):
        import coal

        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.points = P
        self.resolution = float(resolution)
        if octree is None and len(P):
            octree = coal.makeOctree(P, self.resolution)
        self.octree = octree if len(P) else None
        self._counts = None  # (origin, cell, prefix sums of occupied cells), built on the first query

    GRID_CELL = 0.01  # m, the broad phase's cells (coarser for scenes so large that the grid would pass MAX_CELLS)
    MAX_CELLS = 2_000_000

    def maybe_near(self, centres: np.ndarray, halves: np.ndarray) -> np.ndarray:
        """(M,) bool: some point may lie within the world-axis boxes of half-sizes ``halves`` (M, 3) around
        ``centres`` (M, 3); False only where none does.

        A dense grid of occupied cells with 3D prefix sums counts the occupied cells a query box touches in
        constant time (vectorised over the queries): a cheap broad phase before coal's octree."""
        c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
        r = np.asarray(halves, dtype=np.float64).reshape(-1, 3)
        if not len(self.points):
            return np.zeros(len(c), dtype=bool)
        if self._counts is None:
            P = self.points
            span = np.ptp(P, axis=0) + 2 * self.GRID_CELL
            cell = max(self.GRID_CELL, float(np.prod(span) / self.MAX_CELLS) ** (1 / 3))
            origin = P.min(axis=0) - cell
            idx = np.floor((P - origin) / cell).astype(np.int64)
            occ = np.zeros(tuple(idx.max(axis=0) + 2), dtype=np.int32)
            occ[tuple(idx.T)] = 1
            S = np.zeros(tuple(np.array(occ.shape) + 1), dtype=np.int32)
            S[1:, 1:, 1:] = occ.cumsum(0, dtype=np.int32).cumsum(1, dtype=np.int32).cumsum(2, dtype=np.int32)
            self._counts = (origin, cell, S)
        origin, cell, S = self._counts
        dims = np.array(S.shape) - 1
        lo = np.clip(np.floor((c - r - origin) / cell).astype(np.int64), 0, dims - 1)
        hi = np.clip(np.floor((c + r - origin) / cell).astype(np.int64), 0, dims - 1) + 1
        empty = np.any((c + r - origin) < 0, axis=1) | np.any((c - r - origin) >= dims * cell, axis=1)
        x0, y0, z0 = lo.T
        x1, y1, z1 = hi.T
        n = (S[x1, y1, z1] - S[x0, y1, z1] - S[x1, y0, z1] - S[x1, y1, z0]
             + S[x0, y0, z1] + S[x0, y1, z0] + S[x1, y0, z0] - S[x0, y0, z0])
        return (n > 0) & ~empty


def _box_sweep(shape, sweep_local: np.ndarray):
    """(coal shape, offset (3,)) for a shape swept by the local vector ``sweep_local``, or None if not a box along an axis."""
    import coal

    if not isinstance(shape, coal.Box):
        return None
    s = np.abs(sweep_local)
    k = int(np.argmax(s))
    if np.linalg.norm(np.delete(s, k)) > 1e-9 * max(1.0, s[k]):
        return None
    half = np.asarray(shape.halfSide, dtype=np.float64).copy()
    size = 2 * half
    size[k] += s[k]
    return coal.Box(*size), 0.5 * sweep_local


def _hull_sweep(aabb: np.ndarray, sweep_local: np.ndarray):
    import coal

    lo, hi = aabb
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    v = coal.StdVec_Vec3s()
    for p in np.vstack([c, c + sweep_local]):
        v.append(p)
    return coal.Convex.convexHull(v, False, ""), np.zeros(3)


def _local_aabb(geometry) -> np.ndarray:
    """(2, 3) min and max corner of a coal shape's box in its own frame."""
    geometry.computeLocalAABB()
    bb = geometry.aabb_local
    return np.array([np.asarray(bb.min_, dtype=np.float64), np.asarray(bb.max_, dtype=np.float64)])


class GripperCollider:
    """Checks grasps against a scene octree, with or without the approach sweep.

    Args:
        gripper: the gripper model.
        approach: length (m) of the approach sweep (the pre-grasp distance).
    """

    def __init__(self, gripper: GripperModel, approach: float = 0.09):
        self.gripper = gripper
        self.approach = float(approach)
        self.swept = []  # per shape: (coal geometry, offset in the shape's frame)
        for s in gripper.shapes:
            R = s.T_g_s0[:3, :3]
            sweep_local = R.T @ np.array([0.0, 0.0, -self.approach])
            sw = _box_sweep(s.geometry, sweep_local) if self.approach > 0 else (s.geometry, np.zeros(3))
            self.swept.append(sw if sw is not None else _hull_sweep(s.aabb_local, sweep_local))
        self.sweep_offsets = np.stack([o for _, o in self.swept])  # (S, 3) in the shapes' frames
        # local boxes (S, 2, 3) of the shapes and of their sweeps (offset included), for broad phases
        self.local_aabbs = np.stack([_local_aabb(s.geometry) for s in gripper.shapes])
        self.swept_local_aabbs = np.stack([_local_aabb(g) for g, _ in self.swept])  # placed with the offset

    def _placements(self, T_b_g: np.ndarray, width: np.ndarray, swept: bool) -> np.ndarray:
        T = self.gripper.shape_poses(T_b_g, width)  # (N, S, 4, 4)
        if swept:
            T[..., :3, 3] += np.einsum("nsij,sj->nsi", T[..., :3, :3], self.sweep_offsets)
        return T

    def collides(self, scene: SceneOctree, T_b_g: np.ndarray, width: np.ndarray, swept: bool = True,
                 margin: float = 0.0, active: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool: grasps ``T_b_g`` (N, 4, 4) at opening ``width`` (N,) touch the scene (within ``margin``)."""
        import coal

        T_b_g = np.asarray(T_b_g, dtype=np.float64).reshape(-1, 4, 4)
        n = len(T_b_g)
        hit = np.zeros(n, dtype=bool)
        if scene.octree is None or n == 0:
            return hit
        idx = np.arange(n) if active is None else np.nonzero(active)[0]
        T = self._placements(T_b_g[idx], np.broadcast_to(np.asarray(width, dtype=np.float64), (n,))[idx], swept)
        geoms = [g for g, _ in self.swept] if swept else [s.geometry for s in self.gripper.shapes]
        # broad phase: a shape can touch an occupied octree cell within the margin only when some point lies
        # within its world-axis box grown by the margin and a cell (the point is inside that cell)
        centres, halves = _world_boxes(self, T, swept)
        reach = halves + (float(margin) + scene.resolution + 1e-9)
        near = scene.maybe_near(centres.reshape(-1, 3), reach.reshape(-1, 3)).reshape(len(idx), -1)
        req, res = coal.CollisionRequest(), coal.CollisionResult()
        req.security_margin = float(margin)
        ident = coal.Transform3s()
        order = list(range(len(geoms)))  # the shape that hit last is tried first: neighbours hit alike
        for j, i in enumerate(idx):
            for n, k in enumerate(order):
                if not near[j, k]:
                    continue
                res.clear()
                if coal.collide(geoms[k], coal.Transform3s(T[j, k, :3, :3], T[j, k, :3, 3]), scene.octree, ident, req, res):
                    hit[i] = True
                    order.insert(0, order.pop(n))
                    break
        return hit

    def clearance(self, scene: SceneOctree, T_b_g: np.ndarray, width: np.ndarray,
                  levels: tuple[float, ...] = (0.005, 0.01, 0.02, 0.03)) -> np.ndarray:
        """(N,) the largest of ``levels`` (m) by which the (swept) gripper clears the scene; 0 when none."""
        T_b_g = np.asarray(T_b_g, dtype=np.float64).reshape(-1, 4, 4)
        out = np.zeros(len(T_b_g))
        alive = np.ones(len(T_b_g), dtype=bool)
        for lv in sorted(levels):
            ok = alive & ~self.collides(scene, T_b_g, width, swept=True, margin=lv, active=alive)
            out[ok] = lv
            alive = ok
            if not alive.any():
                break
        return out


def _oriented_boxes(collider: GripperCollider, T: np.ndarray, swept: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (N, S, 3), axes (N, S, 3, 3) (columns) and half-sizes (S, 3) of each shape's box (swept or not)
    placed at ``T`` (N, S, 4, 4)."""
    boxes = collider.swept_local_aabbs if swept else collider.local_aabbs  # (S, 2, 3)
    c_loc = 0.5 * (boxes[:, 0] + boxes[:, 1])
    return (np.einsum("nsij,sj->nsi", T[..., :3, :3], c_loc) + T[..., :3, 3], T[..., :3, :3],
            0.5 * (boxes[:, 1] - boxes[:, 0]))


def _world_boxes(collider: GripperCollider, T: np.ndarray, swept: bool) -> tuple[np.ndarray, np.ndarray]:
    """Centres (N, S, 3) and half-sizes (N, S, 3) of the world-axis boxes around each shape's box (swept or
    not) placed at ``T`` (N, S, 4, 4): a thin finger tilted 45 degrees spans half the cube of its sphere."""
    c, R, h = _oriented_boxes(collider, T, swept)
    return c, np.einsum("nsij,sj->nsi", np.abs(R), h)


def obb_overlap(c1: np.ndarray, R1: np.ndarray, h1: np.ndarray, c2: np.ndarray, R2: np.ndarray,
                h2: np.ndarray) -> np.ndarray:
    """(P,) bool: pairs of oriented boxes (centres (P, 3), axes as columns (P, 3, 3), half-sizes (P, 3)) that
    overlap: no separating axis among the 15 of the separating-axis theorem (both boxes' axes and their
    cross products). Written out because it runs on thousands of pairs at once, where coal takes one pair
    per call; a broad phase here (coal decides), so a small tolerance errs towards overlap."""
    R = np.swapaxes(R1, 1, 2) @ R2  # box 2's axes in box 1's frame
    t = np.einsum("pji,pj->pi", R1, c2 - c1)  # box 2's centre in box 1's frame
    A = np.abs(R) + 1e-9  # the tolerance also keeps parallel edges' cross products from a false separation
    sep = (np.abs(t) > h1 + np.einsum("pij,pj->pi", A, h2)).any(axis=1)  # box 1's axes
    sep |= (np.abs(np.einsum("pi,pij->pj", t, R)) > np.einsum("pi,pij->pj", h1, A) + h2).any(axis=1)  # box 2's
    for i in range(3):  # box 1's axis i x box 2's axis j
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            ra = h1[:, i1] * A[:, i2, j] + h1[:, i2] * A[:, i1, j]
            rb = h2[:, j1] * A[:, i, j2] + h2[:, j2] * A[:, i, j1]
            sep |= np.abs(t[:, i2] * R[:, i1, j] - t[:, i1] * R[:, i2, j]) > ra + rb
    return ~sep


class PlacedGrippers(NamedTuple):
    """K grippers placed for ``grippers_collide_many`` (``place_grippers``): every shape's pose (K, S, 4, 4) and
    its box's centre (K, S, 3) and half-sizes (S, 3); the box's circumscribed sphere is the first broad phase."""

    T: np.ndarray
    box_c: np.ndarray
    box_h: np.ndarray
    swept: bool

    @property
    def radius(self) -> np.ndarray:
        """(S,) each shape's bounding-sphere radius: its box's half diagonal."""
        return np.linalg.norm(self.box_h, axis=1)

    def take(self, idx) -> PlacedGrippers:
        """The grippers ``idx`` of these."""
        return PlacedGrippers(self.T[idx], self.box_c[idx], self.box_h, self.swept)


def place_grippers(collider: GripperCollider, T_b_g: np.ndarray, w: np.ndarray, swept: bool = False) -> PlacedGrippers:
    """Grippers at poses ``T_b_g`` (K, 4, 4), openings ``w`` (K,) (their approach sweeps when ``swept``), placed
    once for many ``grippers_collide_many`` calls against them."""
    T_b_g = np.asarray(T_b_g, dtype=np.float64).reshape(-1, 4, 4)
    T = collider._placements(T_b_g, np.broadcast_to(np.asarray(w, dtype=np.float64), (len(T_b_g),)), swept)
    box_c, _, box_h = _oriented_boxes(collider, T, swept)
    return PlacedGrippers(T, box_c, box_h, swept)


def grippers_collide_many(collider: GripperCollider, T_b_g1: np.ndarray, w1: float, T_b_g2: np.ndarray | None,
                          w2: np.ndarray | None, margin: float = 0.0, swept1: bool = False, swept2: bool = False,
                          placed2: PlacedGrippers | None = None) -> np.ndarray:
    """(K,) bool: one gripper (pose (4, 4), opening ``w1``) comes within ``margin`` of each of K others (poses
    (K, 4, 4) in the same frame, openings ``w2`` (K,); or ``placed2``, ``place_grippers`` of them, instead);
    ``swept1`` / ``swept2`` use that gripper's approach (or retreat) sweep instead of its pose.

    A broad phase on bounding spheres (all K x S x S shape pairs at once in numpy), then on the shapes' boxes,
    leaves coal's exact test to the pairs that may touch within ``margin``: the answer is coal's."""
    import coal

    B = placed2 if placed2 is not None else place_grippers(collider, T_b_g2, w2, swept2)
    swept2 = B.swept
    K = len(B.T)
    A = place_grippers(collider, np.asarray(T_b_g1, dtype=np.float64)[None], np.array([float(w1)]), swept1)
    gap = (np.linalg.norm(B.box_c[:, None, :, :] - A.box_c[0][None, :, None, :], axis=-1) - A.radius[None, :, None]
           - B.radius[None, None, :])
    near = gap <= margin + 1e-9  # (K, Sa, Sb): pairs the exact test must see
    hit = np.zeros(K, dtype=bool)
    if not near.any():
        return hit
    # then the shapes' oriented boxes (A's grown by the margin), on the pairs whose spheres came near
    k, a, b = np.nonzero(near)
    near[k, a, b] = obb_overlap(A.box_c[0, a], A.T[0, a, :3, :3], A.box_h[a] + margin + 1e-9,
                                B.box_c[k, b], B.T[k, b, :3, :3], B.box_h[b])
    if not near.any():
        return hit
    ga = [g for g, _ in collider.swept] if swept1 else [s.geometry for s in collider.gripper.shapes]
    gb = [g for g, _ in collider.swept] if swept2 else [s.geometry for s in collider.gripper.shapes]
    ta = [coal.Transform3s(Ta[:3, :3], Ta[:3, 3]) for Ta in A.T[0]]
    req, res = coal.CollisionRequest(), coal.CollisionResult()
    req.security_margin = float(margin)
    for k, a, b in zip(*np.nonzero(near)):
        if hit[k]:
            continue
        res.clear()
        Tb = B.T[k, b]
        if coal.collide(ga[a], ta[a], gb[b], coal.Transform3s(Tb[:3, :3], Tb[:3, 3]), req, res):
            hit[k] = True
    return hit


def grippers_collide(collider: GripperCollider, T_b_g1: np.ndarray, w1: float, T_b_g2: np.ndarray, w2: float,
                     margin: float = 0.0, swept1: bool = False, swept2: bool = False) -> bool:
    """True when two grippers (poses (4, 4) in one frame, openings w1, w2) come within ``margin`` of each
    other; ``swept1`` / ``swept2`` use that gripper's approach (or retreat) sweep instead of its pose."""
    return bool(grippers_collide_many(collider, T_b_g1, w1, np.asarray(T_b_g2)[None], np.array([float(w2)]),
                                      margin, swept1, swept2)[0])


def grippers_distance(collider: GripperCollider, T_b_g1: np.ndarray, w1: float, T_b_g2: np.ndarray, w2: float) -> float:
    """Smallest distance (m) between two grippers' shapes (coal; negative when they overlap)."""
    import coal

    A = collider._placements(np.asarray(T_b_g1)[None], np.array([w1]), False)[0]
    B = collider._placements(np.asarray(T_b_g2)[None], np.array([w2]), False)[0]
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    best = np.inf
    for sa, Ta in zip(collider.gripper.shapes, A):
        ta = coal.Transform3s(Ta[:3, :3], Ta[:3, 3])
        for sb, Tb in zip(collider.gripper.shapes, B):
            res.clear()
            best = min(best, float(coal.distance(sa.geometry, ta, sb.geometry, coal.Transform3s(Tb[:3, :3], Tb[:3, 3]), req, res)))
    return best


def points_in_gripper(gripper: GripperModel, T_b_g: np.ndarray, width: float, P: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """(M,) bool: points P (M, 3) inside any gripper shape's bounding box (inflated by ``margin``) at ``width``."""
    T = gripper.shape_poses(np.asarray(T_b_g)[None], np.array([width]))[0]
    inside = np.zeros(len(P), dtype=bool)
    for s, Ts in zip(gripper.shapes, T):
        loc = (P - Ts[:3, 3]) @ Ts[:3, :3]
        lo, hi = s.aabb_local
        inside |= np.all((loc >= lo - margin) & (loc <= hi + margin), axis=1)
    return inside


class PointClearance:
    """Whether rigidly moved copies of a point set keep ``clearance`` (m) from fixed points (N, 3).

    Exact: a point is too close when a fixed point lies within ``clearance`` of it (scipy ``cKDTree``). For the
    query points inside ``region`` ((lo (3,), hi (3,)); default: the fixed points' box) a grid of cells a
    quarter of the clearance wide decides most of them without the tree: a point whose cell or a neighbour
    of it (3 x 3 x 3) holds a fixed point is too close (two cell diagonals are under the clearance); a point
    more than four cells from every such cell is clear (farther than four cell widths). Only the points in
    between, and those outside the region, go to the tree. Built once per point set, it answers thousands
    of moves.
    """

    MAX_CELLS = 4_000_000

    def __init__(self, points: np.ndarray, clearance: float, region: tuple[np.ndarray, np.ndarray] | None = None):
        from scipy.ndimage import binary_dilation
        from scipy.spatial import cKDTree

        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        c = self.clearance = float(clearance)
        self.points = P
        if region is None:
            region = (P.min(axis=0), P.max(axis=0)) if len(P) else (np.zeros(3), np.zeros(3))
        self.lo, self.hi = (np.asarray(r, dtype=np.float64).reshape(3) for r in region)
        # only fixed points within the clearance of the region can be near a query point inside it
        box_lo, box_hi = self.lo - c, self.hi + c
        near_box = P[np.all((P >= box_lo) & (P <= box_hi), axis=1)]
        self.cell = max(c / 4, float(np.prod(box_hi - box_lo) / self.MAX_CELLS) ** (1 / 3), 1e-6)
        # cells (Chebyshev) within which a fixed point is surely within the clearance: (k + 1) diagonals < c
        self.sure = int(np.floor(c / (self.cell * np.sqrt(3.0)) - 1e-9)) - 1
        reach = int(np.ceil(c / self.cell))  # cells a too-close fixed point can be away, along each axis
        self.origin = box_lo
        self.shape = np.floor((box_hi - box_lo) / self.cell).astype(np.int64) + 1
        occ = np.zeros(tuple(self.shape), dtype=bool)
        idx = np.minimum(np.floor((near_box - box_lo) / self.cell).astype(np.int64), self.shape - 1)
        occ[tuple(idx.T)] = True
        cube = np.ones((3, 3, 3), dtype=bool)
        self.too_close = (binary_dilation(occ, structure=cube, iterations=self.sure) if self.sure > 0 else occ) \
            if self.sure >= 0 else np.zeros_like(occ)
        self.near = binary_dilation(occ, structure=cube, iterations=reach)
        self.tree = cKDTree(near_box)
        self._tree_all = None  # for query points outside the region (built when first needed)

    def clear(self, points: np.ndarray) -> np.ndarray:
        """(M,) bool: each of M point sets ``points`` (M, K, 3) keeps the clearance from every fixed point."""
        Q = np.asarray(points, dtype=np.float64)
        M = Q.shape[0]
        flat = Q.reshape(-1, 3)
        K = len(flat) // max(M, 1)
        owner = np.repeat(np.arange(M), K)
        inside = np.all((flat >= self.lo) & (flat <= self.hi), axis=1)
        idx = np.floor((flat[inside] - self.origin) / self.cell).astype(np.int64)
        idx = tuple(np.minimum(idx, self.shape - 1).T)
        hit = np.zeros(len(flat), dtype=bool)
        hit[inside] = self.too_close[idx]
        bad = np.bincount(owner[hit], minlength=M) > 0
        ask = ~inside  # the points the grid cannot decide: outside the region, or in its band
        ask[inside] = self.near[idx] & ~hit[inside]
        ask = np.nonzero(ask & ~bad[owner])[0]  # a move already too close needs no more answers
        if len(ask) and (~inside[ask]).any() and self._tree_all is None:
            from scipy.spatial import cKDTree

            self._tree_all = cKDTree(self.points)
        # the tree in rounds of 1, 2, 4, ... points per move, in a fixed shuffled order of the set's points: a
        # move too close somewhere is usually found so within a few points, and then asks no more
        rank = np.random.default_rng(0).permutation(K)[ask % K] if K else ask
        lo = 0
        while len(ask):
            now = rank < 2 * lo + 1
            for sel, tree in ((now & inside[ask], self.tree), (now & ~inside[ask], self._tree_all)):
                if sel.any():
                    d, _ = tree.query(flat[ask[sel]], k=1, distance_upper_bound=self.clearance)
                    bad |= np.bincount(owner[ask[sel]][np.isfinite(d)], minlength=M) > 0
            keep = ~now & ~bad[owner[ask]]
            ask, rank, lo = ask[keep], rank[keep], 2 * lo + 1
        return ~bad
