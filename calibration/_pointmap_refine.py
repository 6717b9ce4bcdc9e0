"""Point-map refinement of the pose-only solve (``CalibrationOptions.estimator="refine"``, the previous
default): make the views' point maps agree when each is placed by FK, the kinematic loop left out.

It trusts the kinematics and the maps completely, which holds on the emulator's rendered scenes and not on
real photographs or foundation-model-like maps; the default is the joint weighted estimator
(``calibration._joint``). Kept as an option for comparison (docs/calibration.md has both measured).

The joint solve uses only the camera *poses* of the reconstruction, and each of them carries its own
error (about 1.5 deg / 1 cm for a foundation model). The point maps carry much more: every view sees the
same table and objects. Placed by the kinematics, view ``i`` of arm ``a`` puts its camera-frame points
``p_c`` (reconstruction units) at

    x_b1 = T_b1_ba T_ba_e(i) T_ea_ca (scale * p_c)

where ``T_ba_e(i)`` is the arm's forward kinematics (millimetre-accurate) and only ``T_e1_c1``,
``T_e2_c2``, ``scale`` and ``T_b1_b2`` (19 numbers) are unknown. When they are right, every pair of views
lays the same surface in the same place; when they are off, views taken from different poses disagree
in a way that depends on the pose. This module finds the 19 numbers that minimise the point-to-plane
distance between overlapping views (an ICP whose only free parameters are the calibration's, so the
per-view pose error drops out: each view keeps its own depth and takes its pose from the arm).

Unlike a multiway registration with a free pose per view (which partial overlap and a dominant table
leave under-determined), the problem has 19 unknowns and tens of thousands of residuals.

Written with scipy (``least_squares`` with a soft-L1 loss, ``cKDTree`` correspondences) because the
parametrisation - every view's pose tied to the arm's kinematics through shared unknowns - is not one
that Open3D's or pycolmap's registration offers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bimanual_app.transforms import check_shape, make_T, so3_exp

from ._fusion import pointmap_intrinsics

__all__ = ["PointMapView", "RefineResult", "camera_frame_views", "refine_with_point_maps", "grid_normals"]

#: correspondence radii (m) of the successive ICP rounds: coarse to fine; the last is repeated (up to
#: MAX_FINE_ROUNDS times) until a round moves no point of the workspace by more than CONVERGED_M (any round
#: that moves less ends the refinement: the estimate has settled, e.g. point maps that already agree). Point-to-plane
#: pairs slide freely along the table, so what corrects the in-plane error is re-matching at object edges:
#: slow, round by round, after the coarse error is gone.
RADII = (0.03, 0.02, 0.012, 0.008)
MAX_FINE_ROUNDS = 4
CONVERGED_M = 2e-4
LEVER_M = 0.5  # a rotation change is judged by what it does this far away (the scale's likewise)
POINTS_PER_VIEW = 800  # sampled points per view that look for partners in every other view
PARTNERS_PER_ARM = 6  # each view is matched with the 4 nearest cameras of each arm (see _partner_views)
TARGETS_PER_VIEW = 6000  # points per view among which partners are looked for (point-to-plane needs no more)
MIN_NORMAL_COS = 0.8  # partners whose normals differ more (about 37 deg) are on different surfaces
ROBUST_KNEE_M = 0.003  # soft-L1 knee: residuals beyond 3 mm count less and less
MIN_RESIDUALS = 500
# a refinement that moves an output further than this is not a correction of the joint solve
MAX_ROT_CHANGE_DEG = 5.0
MAX_TRANS_CHANGE_M = 0.05
MAX_LOG_SCALE_CHANGE = 0.1


@dataclass(frozen=True)
class PointMapView:
    """One view's point map in its own camera frame.

    Attributes:
        arm: 1 (primary) or 2 (secondary).
        T_b_e: (4, 4) the arm's end-effector pose at this view (forward kinematics).
        points_c: (K, 3) points in the camera frame, reconstruction units.
        normals_c: (K, 3) unit normals in the camera frame (towards the camera).
        index: (H, W) int, the point of each pixel (-1: none), or None when the map is not a grid.
        intrinsics: (4,) ``fx, fy, cx, cy`` of the map's pixels (``_fusion.pointmap_intrinsics``), or None /
            NaN when a pinhole does not fit it. With both, partners are found by projection; otherwise
            by nearest neighbour.
    """

    arm: int
    T_b_e: np.ndarray
    points_c: np.ndarray
    normals_c: np.ndarray
    index: np.ndarray | None = None
    intrinsics: np.ndarray | None = None

    @property
    def projective(self) -> bool:
        return self.index is not None and self.intrinsics is not None and bool(np.all(np.isfinite(self.intrinsics)))


@dataclass
class RefineResult:
    """Refined calibration and how much the views' agreement improved.

    Attributes:
        T_e1_c1, T_e2_c2, T_b1_b2: (4, 4); scale: metric = scale * reconstruction units.
        accepted: False when the refinement was refused (``reason``); the inputs are then returned as given.
        rms_before_m, rms_after_m: RMS point-to-plane distance between overlapping views (m) on the final
            round's correspondences, at the joint solve and at the refined values.
        residuals_before_m, residuals_after_m: (R,) those distances (for plots).
        correspondences: number of point pairs in the final round; cross_arm: of them between the arms.
        rounds: per ICP round ``{"radius_m", "pairs", "rms_m", "moved_m"}`` (``moved_m``: how far the round's
            change moves the workspace, see ``_movement``).
        covariance: (19, 19) linearised covariance of the corrections (rotation vector and translation of
            ``T_e1_c1`` in c1, the same for ``T_e2_c2``, log scale, rotation vector and translation of
            ``T_b1_b2`` on the left in b1), from the last round's Jacobian and the robust spread of its
            residuals, as if they were independent (they are not: see :func:`uncertainty`).
    """

    T_e1_c1: np.ndarray
    T_e2_c2: np.ndarray
    scale: float
    T_b1_b2: np.ndarray
    accepted: bool
    reason: str = ""
    rms_before_m: float = float("nan")
    rms_after_m: float = float("nan")
    residuals_before_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residuals_after_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    correspondences: int = 0
    cross_arm: int = 0
    rounds: list = field(default_factory=list)
    covariance: np.ndarray | None = None


def grid_normals(points_c: np.ndarray) -> np.ndarray:
    """(H, W, 3) unit normals of an organised point map (H, W, 3) from its grid neighbours (central
    differences), oriented towards the camera; NaN where a neighbour is missing or at the border."""
    P = check_shape("points_c", np.asarray(points_c, dtype=np.float64), (None, None, 3))
    dx = np.full_like(P, np.nan)
    dy = np.full_like(P, np.nan)
    dx[:, 1:-1] = P[:, 2:] - P[:, :-2]
    dy[1:-1] = P[2:] - P[:-2]
    n = np.cross(dx, dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
        n = -n * np.sign(np.sum(n * P, axis=-1, keepdims=True))
    return n


def camera_frame_views(pts3d_w: np.ndarray, T_w_c: np.ndarray, keep: np.ndarray, arms: np.ndarray,
                       T_b_e: np.ndarray) -> list[PointMapView]:
    """The views of a reconstruction in their camera frames.

    Args:
        pts3d_w: (V, H, W, 3) point maps in the reconstruction frame; T_w_c: (V, 4, 4) their poses.
        keep: (V, H, W) bool, the pixels to use (confident, not the robot's own rig).
        arms: (V,) 1 or 2; T_b_e: (V, 4, 4) each view's end-effector pose in its arm's base.
    """
    P = check_shape("pts3d", np.asarray(pts3d_w), (None, None, None, 3))
    V = len(P)
    T = check_shape("T_w_c", np.asarray(T_w_c, dtype=np.float64), (V, 4, 4))
    keep = check_shape("keep", np.asarray(keep, dtype=bool), P.shape[:3])
    E = check_shape("T_b_e", np.asarray(T_b_e, dtype=np.float64), (V, 4, 4))
    out = []
    for v in range(V):
        Pc = (P[v].astype(np.float64) - T[v, :3, 3]) @ T[v, :3, :3]
        N = grid_normals(Pc)
        ok = keep[v] & np.all(np.isfinite(Pc), axis=-1) & np.all(np.isfinite(N), axis=-1) & (Pc[..., 2] > 0)
        index = np.full(ok.shape, -1, dtype=np.int64)
        index[ok] = np.arange(int(ok.sum()))
        finite = np.all(np.isfinite(Pc), axis=-1) & (np.nan_to_num(Pc[..., 2], nan=-1.0) > 0)
        out.append(PointMapView(int(arms[v]), E[v], Pc[ok], N[ok], index, pointmap_intrinsics(Pc, finite)))
    return out


def _unpack(x: np.ndarray, T_e1_c1, T_e2_c2, scale, T_b1_b2):
    """Corrections ``x`` (19,) -> the four outputs: hand-eyes corrected on the right (in the camera frame),
    the base on the left (in b1), the scale by a log factor."""
    T1 = T_e1_c1 @ make_T(so3_exp(x[0:3]), x[3:6])
    T2 = T_e2_c2 @ make_T(so3_exp(x[6:9]), x[9:12])
    Tb = make_T(so3_exp(x[13:16]), x[16:19]) @ T_b1_b2
    return T1, T2, float(scale * np.exp(x[12])), Tb


def _camera_poses(views, T1, T2, Tb) -> np.ndarray:
    """(V, 4, 4) each view's camera pose in b1 from the kinematics and the calibration."""
    return np.stack([(v.T_b_e @ T1) if v.arm == 1 else (Tb @ v.T_b_e @ T2) for v in views])


def _robot_column(P: np.ndarray, Tb: np.ndarray, radius: float = 0.15, above: float = 0.015) -> np.ndarray:
    """(N,) True near either base's vertical axis: the arms themselves, which move between views."""
    mask = np.zeros(len(P), dtype=bool)
    for T in (np.eye(4), Tb):
        local = (P - T[:3, 3]) @ T[:3, :3]
        mask |= (np.hypot(local[:, 0], local[:, 1]) < radius) & (local[:, 2] > above)
    return mask


def _partner_views(views, Tc: np.ndarray, per_arm: int = PARTNERS_PER_ARM) -> list[list[int]]:
    """For each view, the views it is matched with: the ``per_arm`` nearest cameras (by centre) of each
    arm. Near cameras overlap most; both arms are always among them (the pairs across the arms are what
    determine T_b1_b2). Every pair of views would cost twice as much and add views that barely overlap."""
    c = Tc[:, :3, 3]
    arm = np.array([v.arm for v in views])
    out = []
    for a in range(len(views)):
        d = np.linalg.norm(c - c[a], axis=1)
        d[a] = np.inf
        out.append(sorted(int(b) for m in (1, 2) for b in np.flatnonzero(arm == m)[np.argsort(d[arm == m])][:per_arm]
                          if b != a))
    return out


def _projective_correspondences(views, samples, Tc, scale, Tb, radius):
    """As :func:`_correspondences`, the partner of a sample being the point at the pixel where it projects
    in the other view (projective data association, as in KinectFusion's ICP): no search, as every view
    is an organised map with a fitted pinhole."""
    va, ia, vb, ib = [], [], [], []
    R, t = Tc[:, :3, :3], Tc[:, :3, 3]
    partners = _partner_views(views, Tc)
    for a, v in enumerate(views):
        s = samples[a]
        Pa = scale * v.points_c[s] @ R[a].T + t[a]
        Na = v.normals_c[s] @ R[a].T
        free = ~_robot_column(Pa, Tb)
        for b in partners[a]:
            u = views[b]
            c = (Pa - t[b]) @ R[b] / scale  # in camera b, its own units
            z = c[:, 2]
            front = free & (z > 1e-9)
            zs = np.where(front, z, 1.0)
            fx, fy, cx, cy = u.intrinsics
            col = np.round(fx * c[:, 0] / zs + cx)
            row = np.round(fy * c[:, 1] / zs + cy)
            H, W = u.index.shape
            inside = front & (col >= 0) & (col < W) & (row >= 0) & (row < H)
            j = np.full(len(s), -1, dtype=np.int64)
            j[inside] = u.index[row[inside].astype(np.int64), col[inside].astype(np.int64)]
            hit = np.flatnonzero(j >= 0)
            if not len(hit):
                continue
            Xb = scale * u.points_c[j[hit]] @ R[b].T + t[b]
            Nb = u.normals_c[j[hit]] @ R[b].T
            ok = (np.linalg.norm(Pa[hit] - Xb, axis=1) < radius) & (np.abs(np.sum(Na[hit] * Nb, axis=1)) >= MIN_NORMAL_COS)
            n = int(ok.sum())
            if n:
                va.append(np.full(n, a)), ia.append(s[hit[ok]]), vb.append(np.full(n, b)), ib.append(j[hit[ok]])
    return _gather(views, va, ia, vb, ib)


def _gather(views, va, ia, vb, ib):
    """``(va, pa, vb, pb, nb)`` from per-pair lists of view and point indices, or None when empty."""
    if not va:
        return None
    va, ia, vb, ib = (np.concatenate(z) for z in (va, ia, vb, ib))
    pa = np.empty((len(va), 3))
    pb = np.empty((len(vb), 3))
    nb = np.empty((len(vb), 3))
    for k, v in enumerate(views):
        m = va == k
        pa[m] = v.points_c[ia[m]]
        m = vb == k
        pb[m] = v.points_c[ib[m]]
        nb[m] = v.normals_c[ib[m]]
    return va, pa, vb, pb, nb


def _correspondences(views, samples, targets, Tc, scale, Tb, radius):
    """Point pairs between views within ``radius`` (m) with agreeing normals, at the current estimate:
    each view's ``samples`` (indices) look for their nearest partner among the ``targets`` of every other.

    Returns arrays ``(va, pa, vb, pb, nb)``: view and camera-frame point of each sample, view, point and
    normal of its nearest partner."""
    from scipy.spatial import cKDTree

    placed = [scale * v.points_c[g] @ T[:3, :3].T + T[:3, 3] for v, T, g in zip(views, Tc, targets)]
    trees = [cKDTree(p) for p in placed]
    partners = _partner_views(views, Tc)
    va, ia, vb, ib = [], [], [], []
    for a, v in enumerate(views):
        s = samples[a]
        Pa = scale * v.points_c[s] @ Tc[a, :3, :3].T + Tc[a, :3, 3]
        Na = v.normals_c[s] @ Tc[a, :3, :3].T
        free = ~_robot_column(Pa, Tb)
        for b in partners[a]:
            u = views[b]
            d, j = trees[b].query(Pa, distance_upper_bound=radius)
            ok = np.isfinite(d) & free
            if not ok.any():
                continue
            jj = targets[b][np.minimum(j, len(placed[b]) - 1)]
            Nb = u.normals_c[jj] @ Tc[b, :3, :3].T
            ok &= np.abs(np.sum(Na * Nb, axis=1)) >= MIN_NORMAL_COS
            n = int(ok.sum())
            if n:
                va.append(np.full(n, a)), ia.append(s[ok]), vb.append(np.full(n, b)), ib.append(jj[ok])
    return _gather(views, va, ia, vb, ib)


def _transform_grouped(R: np.ndarray, t: np.ndarray, p: np.ndarray, bounds: np.ndarray, s: float = 1.0) -> np.ndarray:
    """``s R[v] p + t[v]`` (or ``R[v] p`` when ``t`` is None) for points ``p`` (K, 3) sorted by view, view
    ``v`` owning rows ``bounds[v]:bounds[v+1]``: one small matmul per view, no (K, 3, 3) gather."""
    out = np.empty_like(p)
    for v in range(len(R)):
        a, b = bounds[v], bounds[v + 1]
        if b > a:
            out[a:b] = s * p[a:b] @ R[v].T + (0.0 if t is None else t[v])
    return out


class _Pairs:
    """Correspondences laid out for fast residuals: the samples sorted by their view, the partners by theirs."""

    def __init__(self, corr, n_views: int):
        va, pa, vb, pb, nb = corr
        oa = np.argsort(va, kind="stable")
        self.va, self.vb = va[oa], vb[oa]
        self.pa = pa[oa]
        ob = np.argsort(self.vb, kind="stable")
        self.ob = ob
        self.pb, self.nb = pb[oa][ob], nb[oa][ob]
        self.ba = np.searchsorted(self.va, np.arange(n_views + 1))
        self.bb = np.searchsorted(self.vb[ob], np.arange(n_views + 1))
        self.inv_ob = np.empty_like(ob)
        self.inv_ob[ob] = np.arange(len(ob))

    def __len__(self):
        return len(self.va)


def _geometry(x, views, start, pairs: _Pairs):
    """Everything the residuals and their Jacobian share: camera rotations and translations (V, 3, 3),
    (V, 3), the scale, and per pair (in the samples' order) ``X_a``, ``X_b``, ``N_b`` in b1."""
    T1, T2, s, Tb = _unpack(x, *start)
    Tc = _camera_poses(views, T1, T2, Tb)
    R, t = Tc[:, :3, :3], Tc[:, :3, 3]
    Xa = _transform_grouped(R, t, pairs.pa, pairs.ba, s)
    Xb = _transform_grouped(R, t, pairs.pb, pairs.bb, s)[pairs.inv_ob]
    Nb = _transform_grouped(R, None, pairs.nb, pairs.bb)[pairs.inv_ob]
    return R, t, s, Xa, Xb, Nb


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (K, 3) arrays (np.cross's generic broadcasting is 3x slower here)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _residuals(x, views, start, pairs: _Pairs) -> np.ndarray:
    """(P,) signed point-to-plane distances (m): sample ``X_a`` from the tangent plane of its partner."""
    _, _, _, Xa, Xb, Nb = _geometry(x, views, start, pairs)
    return np.sum((Xa - Xb) * Nb, axis=1)


def _jacobian(x, views, start, pairs: _Pairs) -> np.ndarray:
    """(P, 19) derivatives of :func:`_residuals`, analytic, for a perturbation of the current estimate (the
    hand-eyes' on the right, the base's on the left; exact at the start of a round, first-order away
    from it, which the trust region absorbs).

    Derived from ``X = R (s p) + t`` and ``N = R n``: a right rotation ``w`` of a view's hand-eye gives
    ``dX = -R (s p x w)``, ``dN = -R (n x w)``; a translation ``u`` gives ``dX = R u``; a left rotation of
    ``T_b1_b2`` gives ``dX = -X x w_b``, ``dN = -N x w_b`` for the secondary's views; the log-scale gives
    ``dX = X - t``. Checked against finite differences in the tests."""
    R, t, s, Xa, Xb, Nb = _geometry(x, views, start, pairs)
    arm = np.array([v.arm for v in views])
    Rt = np.swapaxes(R, 1, 2)
    nb_a = _transform_grouped(Rt, None, Nb, pairs.ba)  # N_b in camera a
    nb_b = pairs.nb[pairs.inv_ob]  # the partner's normal and point in its own camera b
    qb = s * pairs.pb[pairs.inv_ob]
    d_b = _transform_grouped(Rt, None, (Xa - Xb)[pairs.ob], pairs.bb)[pairs.inv_ob]
    # sample side: -(n_b in a) x (s p_a); partner side: -(d x n_b) + n_b x (s p_b) = n_b x (d + s p_b) in b
    rot_a = -_cross(nb_a, s * pairs.pa)
    rot_b = _cross(nb_b, d_b + qb)
    J = np.zeros((len(Xa), 19))
    am, bm = arm[pairs.va], arm[pairs.vb]
    for m, k0 in ((1, 0), (2, 6)):
        on_a, on_b = (am == m)[:, None].astype(np.float64), (bm == m)[:, None].astype(np.float64)
        J[:, k0:k0 + 3] = on_a * rot_a + on_b * rot_b
        J[:, k0 + 3:k0 + 6] = on_a * nb_a - on_b * nb_b
    J[:, 12] = np.sum(Nb * ((Xa - t[pairs.va]) - (Xb - t[pairs.vb])), axis=1)
    # the base moves the secondary's views: -N_b x X_a for a sample, N_b x X_a for a partner (they cancel
    # when both are the secondary's: a rigid motion of both views changes nothing)
    sign = (bm == 2).astype(np.float64) - (am == 2)
    J[:, 13:16] = sign[:, None] * _cross(Nb, Xa)
    J[:, 16:19] = -sign[:, None] * Nb
    return J


def _movement(dx: np.ndarray) -> float:
    """How far (m) a change of the corrections (19,) moves points of the workspace, at most."""
    rot = np.linalg.norm(dx[[0, 1, 2, 6, 7, 8, 13, 14, 15]].reshape(3, 3), axis=1)
    trans = np.linalg.norm(dx[[3, 4, 5, 9, 10, 11, 16, 17, 18]].reshape(3, 3), axis=1)
    return float(max((rot * LEVER_M + trans).max(), abs(dx[12]) * LEVER_M))


def refine_with_point_maps(views: list[PointMapView], T_e1_c1: np.ndarray, T_e2_c2: np.ndarray, scale: float,
                           T_b1_b2: np.ndarray, radii: tuple = RADII, points_per_view: int = POINTS_PER_VIEW,
                           max_fine_rounds: int = MAX_FINE_ROUNDS, seed: int = 0, progress=None) -> RefineResult:
    """Refine the joint solve so that the views' point maps, placed by the kinematics, agree.

    Args:
        views: the point maps (:func:`camera_frame_views`), at least 2 per arm.
        T_e1_c1, T_e2_c2, T_b1_b2: (4, 4) the joint solve's values; scale: its scale.
        radii: correspondence radius (m) of each ICP round; the last one is repeated up to
            ``max_fine_rounds`` times, until a round moves the workspace by less than ``CONVERGED_M``.
        points_per_view: sampled points of each view that look for partners.
        progress: optional callable(str) for one line per round.

    Returns:
        :class:`RefineResult`; refused (``accepted=False``, inputs unchanged) when the views overlap too
        little, the agreement does not improve, or an output would move further than a correction
        (``MAX_ROT_CHANGE_DEG``, ``MAX_TRANS_CHANGE_M``, ``MAX_LOG_SCALE_CHANGE``).
    """
    from scipy.optimize import least_squares

    initial = tuple(check_shape(n, np.asarray(T, dtype=np.float64), (4, 4)) for n, T in
                    (("T_e1_c1", T_e1_c1), ("T_e2_c2", T_e2_c2))) + (float(scale),) + (
        check_shape("T_b1_b2", np.asarray(T_b1_b2, dtype=np.float64), (4, 4)),)

    def refused(reason: str, **kw) -> RefineResult:
        return RefineResult(*initial, False, reason, **kw)

    per_arm = [sum(1 for v in views if v.arm == a) for a in (1, 2)]
    if min(per_arm) < 2:
        return refused(f"needs 2 or more point maps per arm, has {per_arm[0]} / {per_arm[1]}")
    rng = np.random.default_rng(seed)
    samples = [rng.choice(len(v.points_c), min(points_per_view, len(v.points_c)), replace=False)
               if len(v.points_c) else np.zeros(0, dtype=int) for v in views]
    targets = [rng.choice(len(v.points_c), min(TARGETS_PER_VIEW, len(v.points_c)), replace=False)
               if len(v.points_c) else np.zeros(0, dtype=int) for v in views]
    projective = all(v.projective for v in views)
    x_scale = np.r_[[0.01] * 3, [0.005] * 3, [0.01] * 3, [0.005] * 3, [0.01], [0.01] * 3, [0.01] * 3]
    zero = np.zeros(19)
    current, rounds, corr, sol = initial, [], None, None
    schedule = list(radii) + [radii[-1]] * max_fine_rounds
    for radius in schedule:
        T1, T2, s, Tb = current
        Tc = _camera_poses(views, T1, T2, Tb)
        corr = (_projective_correspondences(views, samples, Tc, s, Tb, radius) if projective
                else _correspondences(views, samples, targets, Tc, s, Tb, radius))
        n = 0 if corr is None else len(corr[0])
        if n < MIN_RESIDUALS:
            return refused(f"the point maps overlap too little: {n} point pairs within {radius * 1e3:.0f} mm "
                           f"(needs {MIN_RESIDUALS})", rounds=rounds)
        corr = _Pairs(corr, len(views))
        # each round solves for corrections of its own start, where the analytic Jacobian is exact
        sol = least_squares(_residuals, zero, jac=_jacobian, args=(views, current, corr), loss="soft_l1",
                            f_scale=ROBUST_KNEE_M, x_scale=x_scale, max_nfev=50, tr_solver="lsmr")
        moved = _movement(sol.x)
        current = _unpack(sol.x, *current)
        rounds.append({"radius_m": radius, "pairs": n, "rms_m": float(np.sqrt(np.mean(sol.fun ** 2))),
                       "moved_m": moved})
        if progress:
            progress(f"point-map refinement: {radius * 1e3:.0f} mm round, {n} point pairs, "
                     f"RMS {rounds[-1]['rms_m'] * 1e3:.2f} mm, moved {moved * 1e3:.2f} mm")
        if moved < CONVERGED_M:  # settled: finer radii would only re-select the same pairs
            break
    r0 = _residuals(zero, views, initial, corr)
    r1 = _residuals(zero, views, current, corr)
    va, vb = corr.va, corr.vb
    arm = np.array([v.arm for v in views])
    info = dict(rms_before_m=float(np.sqrt(np.mean(r0 ** 2))), rms_after_m=float(np.sqrt(np.mean(r1 ** 2))),
                residuals_before_m=r0, residuals_after_m=r1, correspondences=int(len(va)),
                cross_arm=int(np.sum(arm[va] != arm[vb])), rounds=rounds)
    # judged robustly (the median absolute distance), as the fit is: a few far pairs must not decide
    if np.median(np.abs(r1)) >= np.median(np.abs(r0)):
        return refused("the point maps agree no better after refinement", **info)
    rot, trans, dlog = _change(initial, current)
    if rot > MAX_ROT_CHANGE_DEG or trans > MAX_TRANS_CHANGE_M or abs(dlog) > MAX_LOG_SCALE_CHANGE:
        return refused(f"the refinement would move an output by {rot:.1f} deg / {trans * 1e3:.0f} mm / scale "
                       f"{(np.exp(dlog) - 1) * 100:+.1f} %, more than a correction of the joint solve", **info)
    if info["cross_arm"] == 0:
        return refused("no point pairs between the two arms' views: T_b1_b2 cannot be refined", **info)
    fun, jac = sol.fun, sol.jac
    sigma = 1.4826 * np.median(np.abs(fun - np.median(fun)))  # robust spread of the residuals (m)
    cov = sigma ** 2 * np.linalg.pinv(jac.T @ jac)
    return RefineResult(*current, True, "", covariance=cov, **info)


def _change(a: tuple, b: tuple) -> tuple[float, float, float]:
    """Largest rotation (deg) and translation (m) change between two ``(T_e1_c1, T_e2_c2, scale, T_b1_b2)``
    and the log-scale change."""
    from bimanual_app.transforms import rotation_angle_between

    Ts = [(a[0], b[0]), (a[1], b[1]), (a[3], b[3])]
    rot = max(float(np.degrees(rotation_angle_between(p[:3, :3], q[:3, :3]))) for p, q in Ts)
    trans = max(float(np.linalg.norm(p[:3, 3] - q[:3, 3])) for p, q in Ts)
    return rot, trans, float(np.log(b[2] / a[2]))
