"""Single-arm antipodal grasp sampling in the spirit of grasp pose detection (ten Pas et al., IJRR 2017).

1. Contact pairs: from a random surface point p1 a ray goes into the object along its inward normal; the
   farthest surface point p2 near the ray whose normal is (anti)parallel to it within the friction cone
   closes the pair (and the nearest such point too, when it differs: a pinch across one wall of a ring
   or a mug). The closing axis y = (p2 - p1)/|p2 - p1| must lie inside the friction cone of both
   normals (half-angle atan(mu)).
2. Hand frames: approach directions z perpendicular to y, spread over the half circle that does not come
   from below the table (the most top-down one first), and -- given the arms' capability maps -- half of
   them drawn from the directions the arms reach the object with; x = y x z.
3. Closing region: the object points between the fingers (the fingers' x span, their z span, and at most
   the gripper's full opening along y) give the contact width; the frame is re-centred between them, the
   opening is the contact width plus clearance on each side, and enough points must be there.
4. Depth: the contact centre is placed as deep between the fingers as the collision check allows (the
   deepest first, as GPD pushes the hand forward until contact), down to the fingertips' plane.
5. Collision: the swept fingers and palm (from the pre-grasp in) against the object's own points (a fine
   coal octree) and against the rest of the scene map (coal octree with a margin), see ``_collision``.
6. Score: antipodality, contact along the fingers, centring on the object, clearance from the rest of
   the scene, approach from above or the side (``_score``); grasps whose finger contacts fall outside a
   (wider) friction cone are dropped.

All steps are vectorised over candidates with numpy; only the coal calls loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._collision import GripperCollider, SceneOctree
from ._gripper import GripperModel
from ._objects import ObjectGeometry, Support

__all__ = ["SamplerParams", "GraspSet", "sample_grasps", "rotate_about_approach"]


@dataclass(frozen=True)
class SamplerParams:
    """Parameters of the antipodal sampler (metres, radians).

    n_candidates: hand frames sampled (contact pairs x approach directions).
    n_approach: approach directions per contact pair.
    friction: friction coefficient mu assumed for contact pairs and the antipodal score; the friction
        cone's half-angle is atan(mu).
    reject_friction: grasps whose finger contacts lie outside this (wider) cone are dropped: normals of
        a noisy or curved surface scatter, the score ranks what the wider cone lets through.
    ray_radius: how close to the ray from p1 a point counts as on it.
    min_width: narrowest contact width the fingers can resolve.
    clearance: wanted free space between each finger and the object when open; ``min_clearance`` is the least accepted.
    wide_clearance: where the swept gripper stays free of the scene that far open (capped by the stroke), it
        opens that far past the object on each side instead (else halfway there): the object's place in the
        cloud is off by the calibration's error (5-15 mm on the bench's pipeline clouds), and the coupled
        fingers centre it as they close. 0 turns it off.
    scene_margin: least distance between the swept gripper and the rest of the scene (table, neighbours).
    own_resolution: voxel size of the object's own octree (below ``min_clearance``).
    min_points: object points needed in the closing region.
    depths: contact-centre depths behind the fingertips, as fractions of the finger length, deepest first.
    approach: pre-grasp distance back along the approach (the collision sweep's length).
    max_keep: best grasps kept per object after scoring.
    full_circle: approach from every direction around the closing axis, from below too (an object held in
        the air, for a hand-over); otherwise only from above or the side. Also drops the score's preference
        for approaching from above (every direction is as good in the air).
    """

    n_candidates: int = 500
    n_approach: int = 8
    friction: float = 0.5
    reject_friction: float = 1.0
    ray_radius: float = 0.004
    min_width: float = 0.006
    clearance: float = 0.010
    wide_clearance: float = 0.020
    min_clearance: float = 0.003
    scene_margin: float = 0.003  # the task planner's contact margin (see PlanParams.octree_resolution)
    own_resolution: float = 0.002
    min_points: int = 8
    depths: tuple[float, ...] = (0.85, 0.7, 0.55, 0.4, 0.25, 0.12, 0.0)
    approach: float = 0.09
    max_keep: int = 60
    full_circle: bool = False
    seed: int = 0

    @property
    def cone_cos(self) -> float:
        return float(np.cos(np.arctan(self.friction)))

    @property
    def reject_cos(self) -> float:
        return float(np.cos(np.arctan(self.reject_friction)))

    def max_contact_width(self, gripper: GripperModel) -> float:
        """Widest contact width the gripper takes with the least clearance on both sides (m)."""
        return gripper.max_width - 2 * self.min_clearance


@dataclass
class GraspSet:
    """Grasps of one object, as arrays (N grasps), best first once scored.

    Attributes:
        object_id: the object's label.
        T_b1_g: (N, 4, 4) gripper poses in b1 (contract frame g).
        width: (N,) opening (m) to approach with: the contact width plus clearance on both sides.
        contact_width: (N,) the object's width between the contacts (m); the fingers close to it.
        depth: (N,) how far the contact centre lies behind the fingertips (m).
        score: (N,) in [0, 1].
        terms: name -> (N,) score terms in [0, 1].
        kind: ``"pinch"`` (antipodal) or ``"push"`` (fingertips pressing a face, for joint lifts).
        extra: name -> (N, ...) other per-grasp arrays (``face`` of push contacts).
    """

    object_id: int
    T_b1_g: np.ndarray
    width: np.ndarray
    contact_width: np.ndarray
    depth: np.ndarray
    score: np.ndarray
    terms: dict = field(default_factory=dict)
    kind: str = "pinch"
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.T_b1_g)

    def take(self, idx) -> GraspSet:
        idx = np.asarray(idx, dtype=int).reshape(-1)
        return GraspSet(self.object_id, self.T_b1_g[idx], self.width[idx], self.contact_width[idx], self.depth[idx],
                        self.score[idx], {k: v[idx] for k, v in self.terms.items()}, self.kind,
                        {k: v[idx] for k, v in self.extra.items()})

    @staticmethod
    def concat(sets: list[GraspSet]) -> GraspSet:
        """One set holding the grasps of ``sets`` (same object and kind), in order."""
        sets = [s for s in sets if len(s)] or sets[:1]
        s0 = sets[0]
        cat = lambda f: np.concatenate([f(s) for s in sets])  # noqa: E731
        return GraspSet(s0.object_id, cat(lambda s: s.T_b1_g), cat(lambda s: s.width), cat(lambda s: s.contact_width),
                        cat(lambda s: s.depth), cat(lambda s: s.score),
                        {k: cat(lambda s, k=k: s.terms[k]) for k in s0.terms}, s0.kind,
                        {k: cat(lambda s, k=k: s.extra[k]) for k in s0.extra})

    @staticmethod
    def empty(object_id: int, kind: str = "pinch") -> GraspSet:
        z = np.zeros(0)
        return GraspSet(object_id, np.zeros((0, 4, 4)), z, z.copy(), z.copy(), z.copy(), {}, kind)

    def transformed(self, T: np.ndarray) -> GraspSet:
        """The same grasps on the object moved rigidly by ``T`` (4, 4) (applied in b1)."""
        out = self.take(np.arange(len(self)))
        out.T_b1_g = np.asarray(T) @ self.T_b1_g
        return out


def rotate_about_approach(T_b_g: np.ndarray) -> np.ndarray:
    """The same physical grasps (..., 4, 4) with the gripper turned 180 degrees about its approach axis z.

    A symmetric parallel gripper grasps identically either way; the arm may reach only one of them.
    """
    F = np.diag([-1.0, -1.0, 1.0, 1.0])
    return np.asarray(T_b_g) @ F


def _contact_pairs(P: np.ndarray, N: np.ndarray, seeds: np.ndarray, p: SamplerParams, max_cw: float,
                   rows: int = 128):
    """For seed indices (S,): partner indices (2S,) (-1 when none) and closing axes (2S, 3): the farthest
    partners of all seeds, then the nearest ones. ``rows`` seeds at a time (the (S, M) arrays stay in cache)."""
    parts = [_contact_pairs_rows(P, N, seeds[a:a + rows], p, max_cw) for a in range(0, len(seeds), rows)]
    if not parts:
        return np.zeros(0, dtype=int), np.zeros((0, 3))
    half = [len(j) // 2 for j, _ in parts]  # each part: its seeds' farthest partners, then their nearest
    j = np.concatenate([j[:h] for (j, _), h in zip(parts, half)] + [j[h:] for (j, _), h in zip(parts, half)])
    y = np.concatenate([y[:h] for (_, y), h in zip(parts, half)] + [y[h:] for (_, y), h in zip(parts, half)])
    return j, y


def _contact_pairs_rows(P: np.ndarray, N: np.ndarray, seeds: np.ndarray, p: SamplerParams, max_cw: float):
    """``_contact_pairs`` for a few seeds."""
    cos_c = p.cone_cos
    d = -N[seeds]  # (S, 3) into the object
    Ps = P[seeds]
    # t = (p_j - p_s) . d and |p_j - p_s|^2 through matrix products: no (S, M, 3) temporaries
    t = d @ P.T - np.einsum("sk,sk->s", Ps, d)[:, None]  # (S, M)
    sq = np.einsum("mk,mk->m", P, P)[None, :] - 2.0 * (Ps @ P.T) + np.einsum("sk,sk->s", Ps, Ps)[:, None]
    perp2 = sq - t * t
    align = np.abs(d @ N.T)  # (S, M) |n_j . d|
    ok = (t >= p.min_width) & (t <= max_cw) & (perp2 <= p.ray_radius ** 2) & (align >= cos_c)
    # the farthest partner (a pinch across the whole object) and the nearest one (across one wall of a
    # hollow or ring-shaped object); for a convex object they are the same exit point
    rows = np.arange(len(seeds))
    j_far = np.argmax(np.where(ok, t, -np.inf), axis=1)
    j_near = np.argmin(np.where(ok, t, np.inf), axis=1)
    has = ok[rows, j_far]
    out_j, out_y = [], []
    for j, extra in ((j_far, np.ones(len(seeds), bool)), (j_near, t[rows, j_near] < t[rows, j_far] - 2 * p.min_width)):
        y = P[j] - P[seeds]
        y /= np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-12)
        in_cone = (np.abs(np.einsum("sk,sk->s", N[seeds], y)) >= cos_c) & (np.abs(np.einsum("sk,sk->s", N[j], y)) >= cos_c)
        out_j.append(np.where(has & extra & in_cone, j, -1))
        out_y.append(y)
    return np.concatenate(out_j), np.concatenate(out_y)


def _frames(y: np.ndarray, up: np.ndarray, n_approach: int, rng: np.random.Generator, full_circle: bool = False,
            hints: np.ndarray | None = None) -> np.ndarray:
    """Rotations (S, K, 3, 3) with columns x, y, z: approach z perpendicular to y, never from below (unless
    ``full_circle``). With ``hints`` (H, 3) (directions the arms reach the object with), half of the K
    approaches are hints projected perpendicular to y, the rest spread as usual."""
    S = len(y)
    a = -up[None, :] - (y @ -up)[:, None] * y  # the most top-down direction perpendicular to y
    na = np.linalg.norm(a, axis=1)
    # y vertical: every perpendicular direction is horizontal; take any
    alt = np.cross(y, np.where(np.abs(y[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])))
    a = np.where(na[:, None] > 1e-3, a, alt)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(y, a)
    if n_approach == 1:
        th = np.zeros((S, 1))
    elif full_circle:
        th = np.linspace(-np.pi, np.pi, n_approach, endpoint=False)[None] + rng.uniform(0, 2 * np.pi / n_approach, (S, 1))
        th[:, 0] = 0.0
    else:
        base = np.linspace(-np.pi / 2, np.pi / 2, n_approach)
        jitter = rng.uniform(-0.5, 0.5, size=(S, n_approach)) * (np.pi / (n_approach - 1))
        th = np.clip(base[None] + jitter, -np.pi / 2, np.pi / 2)
        th[:, 0] = 0.0  # always try the most top-down approach
    z = np.cos(th)[..., None] * a[:, None, :] + np.sin(th)[..., None] * b[:, None, :]
    if hints is not None and len(hints) and n_approach > 1:
        k = n_approach // 2
        h = hints[rng.integers(0, len(hints), size=(S, k))]  # (S, k, 3)
        hp = h - np.einsum("skj,sj->sk", h, y)[..., None] * y[:, None, :]
        nh = np.linalg.norm(hp, axis=-1)
        ok = nh > 0.5  # not along the closing axis
        if not full_circle:
            ok &= (hp @ up) <= 0.1 * nh  # not from below
        hp = hp / np.maximum(nh, 1e-9)[..., None]
        z[:, n_approach - k:] = np.where(ok[..., None], hp, z[:, n_approach - k:])
    Y = np.broadcast_to(y[:, None, :], z.shape)
    x = np.cross(Y, z)
    return np.stack([x, Y, z], axis=-1)


def _seed_pairs(P: np.ndarray, N: np.ndarray, rng: np.random.Generator, params: SamplerParams, max_cw: float,
                n_pairs: int) -> tuple[list, list, list, int]:
    """Antipodal contact pairs seeded from the points in a random order: lists of chunks of (first point,
    partner point, closing axis (., 3)) and how many seeds were tried.

    Several times the pairs wanted are tried (many rays find no antipodal partner), in chunks to cap memory.
    """
    M = len(P)
    order = rng.permutation(M)
    pairs_i, pairs_j, axes = [], [], []
    chunk = max(32, min(3 * n_pairs, int(2e6 // max(M, 1))))
    pos = 0
    while pos < len(order) and sum(len(a) for a in pairs_i) < n_pairs and pos < 8 * n_pairs:
        s = order[pos: pos + chunk]
        pos += len(s)
        j, y = _contact_pairs(P, N, s, params, max_cw)
        ok = j >= 0
        s = np.concatenate([s, s])
        pairs_i.append(s[ok])
        pairs_j.append(j[ok])
        axes.append(y[ok])
    return pairs_i, pairs_j, axes, pos


def _window_points(P: np.ndarray, R: np.ndarray, C: np.ndarray, gripper: GripperModel, params: SamplerParams,
                   chunk: int = 128) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The object points (M, 3) that may fall in a candidate's closing region at one of ``params.depths``, for
    the candidate frames R (n, 3, 3) at contact centres C (n, 3): ``(candidate (K,), y (K,), z (K,))`` with y,
    z the point in the candidate's frame centred on the contact centre (float32), candidates in order.

    Within the fingers' x span and the stroke, and within the z span of every depth's region; a third of the
    pairs or fewer, computed a chunk of candidates at a time (the dense (n, M, 3) array was 70 MB)."""
    fx, fz = gripper.finger_x, gripper.finger_z
    dl = [f * gripper.finger_length for f in params.depths]
    z_lo, z_hi = fz[0] + min(dl) - 1e-4, fz[1] + max(dl) + 1e-4  # padded: each depth's own test follows
    P32 = P.astype(np.float32)[None]
    rows, ys, zs = [], [], []
    for a in range(0, len(R), chunk):
        R32 = R[a:a + chunk].astype(np.float32)
        L = np.matmul(P32, R32) - np.matmul(C[a:a + chunk].astype(np.float32)[:, None, :], R32)
        keep = ((L[..., 0] >= fx[0]) & (L[..., 0] <= fx[1]) & (np.abs(L[..., 1]) <= gripper.max_width / 2)
                & (L[..., 2] >= z_lo) & (L[..., 2] <= z_hi))
        r, m = np.nonzero(keep)
        rows.append(r + a)
        ys.append(L[r, m, 1])
        zs.append(L[r, m, 2])
    return np.concatenate(rows), np.concatenate(ys), np.concatenate(zs)


def _closing_region(window: tuple[np.ndarray, np.ndarray, np.ndarray], todo: np.ndarray, R: np.ndarray,
                    C: np.ndarray, dlt: float, gripper: GripperModel, params: SamplerParams,
                    max_cw: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """The candidates among ``todo`` (n,) bool whose closing region, pushed in by ``dlt``, holds enough of the
    object within the stroke (``window``: ``_window_points``): ``(indices (k,), T_b1_g (k, 4, 4) centred on it,
    opening (k,), contact width (k,))``."""
    fz = gripper.finger_z
    rows, y, z = window
    sel = todo[rows]
    rows, y, zl = rows[sel], y[sel], z[sel] - dlt  # closing region at this depth: z_g = z - dlt in finger_z
    reg = (zl >= fz[0]) & (zl <= fz[1])
    rows, y = rows[reg], y[reg]
    n = len(todo)
    cnt = np.bincount(rows, minlength=n)
    ymin, ymax = np.full(n, np.inf, dtype=np.float32), np.full(n, -np.inf, dtype=np.float32)
    if len(rows):  # per candidate (rows sorted): the extent of its points across the closing axis
        starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
        ymin[rows[starts]] = np.minimum.reduceat(y, starts)
        ymax[rows[starts]] = np.maximum.reduceat(y, starts)
    idx = np.nonzero(todo & (cnt >= params.min_points))[0]
    cw = ymax[idx] - ymin[idx]
    ok = (cw >= params.min_width) & (cw <= max_cw)
    idx = idx[ok]
    if len(idx) == 0:
        return idx, None, None, None
    shift = 0.5 * (ymin[idx] + ymax[idx])
    w = np.minimum(cw[ok] + 2 * params.clearance, gripper.max_width)
    Rk = R[idx]
    o = C[idx] + Rk[:, :, 1] * shift[:, None] + Rk[:, :, 2] * dlt
    T = np.zeros((len(idx), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = Rk, o, 1.0
    return idx, T, w, cw[ok]


def _push_in(P: np.ndarray, R: np.ndarray, C: np.ndarray, gripper: GripperModel, collider: GripperCollider,
             own: SceneOctree, others: SceneOctree, params: SamplerParams, max_cw: float) -> tuple[np.ndarray, ...]:
    """Each candidate frame (R (n, 3, 3) at contact centre C (n, 3)) pushed in to the first of ``params.depths``
    where its closing region holds the object and the swept gripper is free.

    Returns ``(chosen depth index (n,) or -1, T_b1_g (n, 4, 4), opening (n,), contact width (n,), depth (n,),
    any closing region held (n,) bool)``.
    """
    n = len(R)
    window = _window_points(P, R, C, gripper, params)
    chosen = np.full(n, -1)
    T_best = np.zeros((n, 4, 4))
    width = np.zeros(n)
    cwidth = np.zeros(n)
    depth = np.zeros(n)
    region_any = np.zeros(n, dtype=bool)
    for k, frac in enumerate(params.depths):
        todo = chosen < 0
        if not todo.any():
            break
        dlt = frac * gripper.finger_length
        idx, T, w, cw = _closing_region(window, todo, R, C, dlt, gripper, params, max_cw)
        region_any[idx] = True
        if len(idx) == 0:
            continue
        # the swept fingers and palm against the rest of the scene (table, neighbours), with a margin (most
        # candidates that fail, fail here: asked first) ...
        free = ~collider.collides(others, T, w, swept=True, margin=params.scene_margin)
        # ... and against the object's own points (a fine octree: at most its resolution of inflation, less
        # than the least clearance)
        free[free] = ~collider.collides(own, T[free], w[free], swept=True)
        good = idx[free]
        chosen[good] = k
        T_best[good] = T[free]
        width[good] = w[free]
        cwidth[good] = cw[free]
        depth[good] = dlt
    return chosen, T_best, width, cwidth, depth, region_any


def sample_grasps(geo: ObjectGeometry, support: Support, gripper: GripperModel, collider: GripperCollider,
                  others: SceneOctree, params: SamplerParams = SamplerParams(),
                  rng: np.random.Generator | None = None, approach_hints: np.ndarray | None = None
                  ) -> tuple[GraspSet, dict]:
    """Collision-free antipodal grasps of one object, scored and sorted best first.

    Args:
        geo: the object's points, normals and box.
        support: the table plane.
        gripper, collider: the gripper and its collision checker.
        others: octree of the scene map without this object (table, neighbours): the swept fingers and palm
            must stay ``params.scene_margin`` clear of it (the object's own points get a finer octree here).
        approach_hints: (H, 3) approach directions the arms are known to reach the object with (from their
            capability maps): half of each contact pair's approaches are drawn from them.
    Returns:
        (grasps, stats) with stats counting candidates at each stage.
    """
    from ._score import score_grasps

    rng = np.random.default_rng(params.seed if rng is None else rng)
    P, N = geo.points, geo.normals
    own = SceneOctree(P, params.own_resolution)
    M = len(P)
    max_cw = params.max_contact_width(gripper)
    stats = {"points": int(M), "pairs_tried": 0, "pairs": 0, "candidates": 0, "closing_region_ok": 0,
             "collision_free": 0, "antipodal_ok": 0, "kept": 0}
    if M < 3:
        return GraspSet.empty(geo.id), stats
    n_pairs = int(np.ceil(params.n_candidates / params.n_approach))
    pairs_i, pairs_j, axes, stats["pairs_tried"] = _seed_pairs(P, N, rng, params, max_cw, n_pairs)
    if not pairs_i or sum(len(a) for a in pairs_i) == 0:
        return GraspSet.empty(geo.id), stats
    pi = np.concatenate(pairs_i)[:n_pairs]
    pj = np.concatenate(pairs_j)[:n_pairs]
    Y = np.concatenate(axes)[:n_pairs]
    stats["pairs"] = int(len(pi))
    C = 0.5 * (P[pi] + P[pj])  # (S, 3)
    R = _frames(Y, support.up, params.n_approach, rng, params.full_circle, approach_hints).reshape(-1, 3, 3)  # (S*K, 3, 3)
    C = np.repeat(C, params.n_approach, axis=0)
    stats["candidates"] = int(len(R))
    chosen, T_best, width, cwidth, depth, region_any = _push_in(P, R, C, gripper, collider, own, others, params,
                                                                 max_cw)
    stats["closing_region_ok"] = int(region_any.sum())
    keep = np.nonzero(chosen >= 0)[0]
    stats["collision_free"] = int(len(keep))
    if len(keep) == 0:
        return GraspSet.empty(geo.id), stats
    gs = GraspSet(geo.id, T_best[keep], width[keep], cwidth[keep], depth[keep], np.zeros(len(keep)))
    gs = score_grasps(gs, geo, support, gripper, collider, others, params)
    gs = _open_towards_unseen(gs, gripper, collider, own, others, params)
    gs = _open_wider(gs, gripper, collider, own, others, params)
    # the fingers' actual contact bands must face each other (median normal within ``reject_friction``'s
    # cone of the closing axis): the pair that seeded a candidate may not be what the fingers touch once
    # the frame is centred and pushed in
    gs = gs.take(np.nonzero(gs.extra["contact_cos"] >= params.reject_cos)[0])
    stats["antipodal_ok"] = int(len(gs))
    gs = _dedupe(gs, params.max_keep)
    stats["kept"] = int(len(gs))
    return gs, stats


def _open_towards_unseen(gs: GraspSet, gripper: GripperModel, collider: GripperCollider, own: SceneOctree,
                         others: SceneOctree, params: SamplerParams) -> GraspSet:
    """Grasps with one finger's side unseen (its face only filled in by completion, whose extent is a guess):
    open fully, keeping the seen side's clearance, so the unseen side gets all the spare stroke; kept as
    they were when that wider gripper would collide."""
    seen = gs.extra.get("seen")
    if seen is None:
        return gs
    one = np.nonzero(seen[:, 0] ^ seen[:, 1])[0]
    if len(one) == 0:
        return gs
    extra = gripper.max_width - gs.width[one]
    one, extra = one[extra > 1e-4], extra[extra > 1e-4]
    if len(one) == 0:
        return gs
    sign = np.where(seen[one, 0], 1.0, -1.0)  # the +y finger's side unseen when the -y side was seen
    T = gs.T_b1_g[one].copy()
    T[:, :3, 3] += (0.5 * extra * sign)[:, None] * T[:, :3, 1]
    w = np.full(len(one), gripper.max_width)
    free = ~collider.collides(own, T, w, swept=True)
    free[free] = ~collider.collides(others, T[free], w[free], swept=True, margin=params.scene_margin)
    gs.T_b1_g[one[free]] = T[free]
    gs.width[one[free]] = w[free]
    return gs


def _open_wider(gs: GraspSet, gripper: GripperModel, collider: GripperCollider, own: SceneOctree,
                others: SceneOctree, params: SamplerParams) -> GraspSet:
    """Grasps opened ``wide_clearance`` past the object on each side (capped by the stroke), else halfway
    between that and ``clearance``, where the swept gripper stays clear of the object and the scene at that
    opening; the others keep their width. The frame does not move (the contacts stay centred)."""
    if params.wide_clearance <= params.clearance or len(gs) == 0:
        return gs
    for c in (params.wide_clearance, 0.5 * (params.wide_clearance + params.clearance)):
        w = np.minimum(gs.contact_width + 2 * c, gripper.max_width)
        todo = np.nonzero(w > gs.width + 1e-4)[0]
        if len(todo) == 0:
            continue
        free = ~collider.collides(own, gs.T_b1_g[todo], w[todo], swept=True)
        free[free] = ~collider.collides(others, gs.T_b1_g[todo[free]], w[todo[free]], swept=True,
                                        margin=params.scene_margin)
        gs.width[todo[free]] = w[todo[free]]
    return gs

def _dedupe(gs: GraspSet, max_keep: int, pos_tol: float = 0.004, ang_tol: float = np.deg2rad(8)) -> GraspSet:
    """Best-first, drop grasps within ``pos_tol`` and ``ang_tol`` of a better one (same or flipped about z).

    The relation is symmetric, so each kept grasp marks every grasp near it at once (one vectorised test per
    kept grasp instead of one Python test per pair)."""
    order = np.argsort(-gs.score)
    kept: list[int] = []
    cos_t = np.cos(ang_tol)
    P, Z, Y = gs.T_b1_g[:, :3, 3], gs.T_b1_g[:, :3, 2], gs.T_b1_g[:, :3, 1]
    near = np.zeros(len(gs), dtype=bool)
    for i in order:
        if near[i]:
            continue
        kept.append(int(i))
        if len(kept) >= max_keep:
            break
        near |= (np.linalg.norm(P - P[i], axis=1) < pos_tol) & (Z @ Z[i] > cos_t) & (np.abs(Y @ Y[i]) > cos_t)
    return gs.take(kept)
