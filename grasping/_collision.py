"""Collision checks of the gripper's real geometry (coal shapes from the URDF) against the scene map.

The scene map is a coal octree built from the metric cloud (``coal.makeOctree``). A grasp is checked
with its *approach sweep*: each gripper shape is replaced by the volume it sweeps while the gripper moves
in along its approach axis from the pre-grasp (``approach`` metres back) to the grasp. For a box whose
axes include the approach axis that volume is a longer box; for any other shape it is the convex hull
(``coal.Convex.convexHull``) of its bounding box at both ends. So a grasp whose fingers would pass
through a neighbour on the way in is rejected, not only one whose final pose overlaps it.
"""

from __future__ import annotations

import numpy as np

from ._gripper import GripperModel

__all__ = ["SceneOctree", "GripperCollider", "grippers_collide", "grippers_distance", "points_in_gripper"]


class SceneOctree:
    """A coal octree of points (N, 3) at ``resolution`` metres (empty point sets give a map that never collides)."""

    def __init__(self, points: np.ndarray, resolution: float = 0.004):
        import coal

        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.points = P
        self.resolution = float(resolution)
        self.octree = coal.makeOctree(P, self.resolution) if len(P) else None


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

    def _placements(self, T_b_g: np.ndarray, width: np.ndarray, swept: bool) -> np.ndarray:
        T = self.gripper.shape_poses(T_b_g, width)  # (N, S, 4, 4)
        if swept:
            off = np.stack([o for _, o in self.swept])  # (S, 3) in shape frames
            T = T.copy()
            T[..., :3, 3] += np.einsum("nsij,sj->nsi", T[..., :3, :3], off)
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
        T = self._placements(T_b_g, width, swept)
        geoms = [g for g, _ in self.swept] if swept else [s.geometry for s in self.gripper.shapes]
        req, res = coal.CollisionRequest(), coal.CollisionResult()
        req.security_margin = float(margin)
        ident = coal.Transform3s()
        idx = range(n) if active is None else np.nonzero(active)[0]
        for i in idx:
            for k, g in enumerate(geoms):
                res.clear()
                if coal.collide(g, coal.Transform3s(T[i, k, :3, :3], T[i, k, :3, 3]), scene.octree, ident, req, res):
                    hit[i] = True
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


def grippers_collide(collider: GripperCollider, T_b_g1: np.ndarray, w1: float, T_b_g2: np.ndarray, w2: float,
                     margin: float = 0.0, swept1: bool = False, swept2: bool = False) -> bool:
    """True when two grippers (poses (4, 4) in one frame, openings w1, w2) come within ``margin`` of each
    other; ``swept1`` / ``swept2`` use that gripper's approach (or retreat) sweep instead of its pose."""
    import coal

    geoms = [g for g, _ in collider.swept], [s.geometry for s in collider.gripper.shapes]
    A = collider._placements(np.asarray(T_b_g1)[None], np.array([w1]), swept1)[0]
    B = collider._placements(np.asarray(T_b_g2)[None], np.array([w2]), swept2)[0]
    ga = geoms[0] if swept1 else geoms[1]
    gb = geoms[0] if swept2 else geoms[1]
    req, res = coal.CollisionRequest(), coal.CollisionResult()
    req.security_margin = float(margin)
    for sa, Ta in zip(ga, A):
        ta = coal.Transform3s(Ta[:3, :3], Ta[:3, 3])
        for sb, Tb in zip(gb, B):
            res.clear()
            if coal.collide(sa, ta, sb, coal.Transform3s(Tb[:3, :3], Tb[:3, 3]), req, res):
                return True
    return False


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
