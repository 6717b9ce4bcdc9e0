"""Point-map refinement of the joint solve: make the views' point maps agree when each is placed by FK.

The joint solve uses only the camera *poses* of the reconstruction, and each of them carries its own
error (about 1.5 deg / 1 cm for a foundation model). The point maps carry much more: every view sees the
same table and objects. Placed by the kinematics, view ``i`` of arm ``a`` puts its camera-frame points
``p_c`` (reconstruction units) at

    x_b1 = T_b1_ba T_ba_e(i) T_ea_ca (scale * p_c)

where ``T_ba_e(i)`` is the arm's forward kinematics (millimetre-accurate) and only ``T_e1_c1``,
``T_e2_c2``, ``scale`` and ``T_b1_b2`` (19 numbers) are unknown. When they are right, every pair of views
lays the same surface in the same place; when they are off, views taken from different poses disagree
in a way that depends on the pose. A foundation model also gets each view's depth scale a little wrong,
so each view carries its own depth factor ``exp(kappa_v)`` on top of the shared scale.

This module holds the geometry of that residual family: the views in their camera frames, the point
pairs between overlapping views (projective association, or nearest neighbours), and the point-to-plane
residuals with their analytic Jacobian. ``calibration._joint`` weighs them against the kinematic loop
in one estimator.

Written with scipy (``least_squares`` with a soft-L1 loss, ``cKDTree`` correspondences) because the
parametrisation - every view's pose tied to the arm's kinematics through shared unknowns - is not one
that Open3D's or pycolmap's registration offers.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import check_shape, make_T, so3_exp

from ._fusion import pointmap_intrinsics

__all__ = ["PointMapView", "camera_frame_views", "grid_normals", "next_pixel_normals", "find_pairs", "MapPairs", "map_residuals",
           "map_jacobian", "view_camera_poses", "unpack_corrections"]

PARTNERS_PER_ARM = 6  # each view is matched with the 6 nearest cameras of each arm (see _partner_views)
#: normals: the plane of NORMAL_SAMPLES x NORMAL_SAMPLES grid points about +-NORMAL_WINDOW_RAD of view angle
#: wide (grid_normals)
NORMAL_SAMPLES = 7
NORMAL_WINDOW_RAD = 0.03
MIN_NORMAL_COS = 0.8  # partners whose normals differ more (about 37 deg) are on different surfaces


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


def grid_normals(points_c: np.ndarray, focal_px: float | None = None) -> np.ndarray:
    """(H, W, 3) unit normals of an organised point map (H, W, 3), oriented towards the camera; NaN where the
    window is not whole (a missing point, the border).

    Each normal is that of the plane fitted to a window of NORMAL_SAMPLES x NORMAL_SAMPLES grid points about
    +-NORMAL_WINDOW_RAD of view angle wide (grid step ``focal_px * NORMAL_WINDOW_RAD / (NORMAL_SAMPLES // 2)``
    pixels, at least 1; 1 without ``focal_px``): the derivatives along the rows and columns are the
    least-squares slopes over the window, the normal their cross product. From the next pixels alone, a
    model's 0.5 % depth noise tilts normals by 10-20 deg; on a table their spurious sideways parts pin
    point-to-plane pairs to their current partners, so the joint estimate creeps and its covariance takes
    that pinning for evidence (docs/calibration.md, "Normals").

    OpenCV's filters rather than a nearest-neighbour normal estimator (Open3D): the grid gives every window
    for free, and all windows of 16 maps cost a few milliseconds.
    """
    import cv2

    P = check_shape("points_c", np.asarray(points_c, dtype=np.float64), (None, None, 3))
    half = NORMAL_SAMPLES // 2
    step = max(1, int(round(focal_px * NORMAL_WINDOW_RAD / half))) if focal_px and np.isfinite(focal_px) else 1
    offs = np.arange(-half, half + 1, dtype=np.float64)
    size = 2 * half * step + 1
    ones, ku, kv = np.zeros((size, size)), np.zeros((size, size)), np.zeros((size, size))
    ones[::step, ::step] = 1.0
    ku[::step, ::step] = offs[None, :]  # column offset: correlation gives sum over the window of u p(u, v)
    kv[::step, ::step] = offs[:, None]
    ok = _finite3(P) & (np.nan_to_num(P[..., 2], nan=-1.0) > 0)
    Pz = np.where(ok[..., None], P, 0.0)

    def window_sum(a: np.ndarray, k: np.ndarray) -> np.ndarray:
        return cv2.filter2D(a, cv2.CV_64F, k, borderType=cv2.BORDER_CONSTANT)

    whole = ok & (window_sum(ok.astype(np.float64), ones) > NORMAL_SAMPLES ** 2 - 0.5)
    du = np.stack([window_sum(Pz[..., i], ku) for i in range(3)], -1)
    dv = np.stack([window_sum(Pz[..., i], kv) for i in range(3)], -1)
    n = _cross(du.reshape(-1, 3), dv.reshape(-1, 3)).reshape(P.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / np.sqrt(_dot3(n, n))[..., None]
        n = -n * np.sign(_dot3(n, P))[..., None]
    n[~whole] = np.nan
    return n


def next_pixel_normals(points_c: np.ndarray) -> np.ndarray:
    """(H, W, 3) unit normals of an organised point map (H, W, 3) from its next grid neighbours (central
    differences), oriented towards the camera; NaN where a neighbour is missing or at the border. What the
    previous point-map estimator (``estimator="refine"``) was built and tuned with; the joint estimate
    uses :func:`grid_normals`."""
    P = check_shape("points_c", np.asarray(points_c, dtype=np.float64), (None, None, 3))
    dx = np.full_like(P, np.nan)
    dy = np.full_like(P, np.nan)
    dx[:, 1:-1] = P[:, 2:] - P[:, :-2]
    dy[1:-1] = P[2:] - P[:-2]
    n = _cross(dx.reshape(-1, 3), dy.reshape(-1, 3)).reshape(P.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / np.sqrt(_dot3(n, n))[..., None]
        n = -n * np.sign(_dot3(n, P))[..., None]
    return n


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``sum(a * b, axis=-1)`` of (..., 3) arrays, summed in the same order, without a reduction over an axis
    of 3 (numpy's is slow there)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _finite3(a: np.ndarray) -> np.ndarray:
    """``np.all(np.isfinite(a), axis=-1)`` of a (..., 3) array."""
    return np.isfinite(a[..., 0]) & np.isfinite(a[..., 1]) & np.isfinite(a[..., 2])


def camera_frame_views(pts3d_w: np.ndarray, T_w_c: np.ndarray, keep: np.ndarray, arms: np.ndarray,
                       T_b_e: np.ndarray, normals: str = "window") -> list[PointMapView]:
    """The views of a reconstruction in their camera frames.

    Args:
        pts3d_w: (V, H, W, 3) point maps in the reconstruction frame; T_w_c: (V, 4, 4) their poses.
        keep: (V, H, W) bool, the pixels to use (confident, not the robot's own rig).
        arms: (V,) 1 or 2; T_b_e: (V, 4, 4) each view's end-effector pose in its arm's base.
        normals: "window" (:func:`grid_normals`) or "next pixels" (:func:`next_pixel_normals`).
    """
    if normals not in ("window", "next pixels"):
        raise ValueError(f"normals must be 'window' or 'next pixels', got {normals!r}")
    P = check_shape("pts3d", np.asarray(pts3d_w), (None, None, None, 3))
    V = len(P)
    T = check_shape("T_w_c", np.asarray(T_w_c, dtype=np.float64), (V, 4, 4))
    keep = check_shape("keep", np.asarray(keep, dtype=bool), P.shape[:3])
    E = check_shape("T_b_e", np.asarray(T_b_e, dtype=np.float64), (V, 4, 4))
    out = []
    for v in range(V):
        Pc = (P[v].astype(np.float64) - T[v, :3, 3]) @ T[v, :3, :3]
        finite = _finite3(Pc) & (np.nan_to_num(Pc[..., 2], nan=-1.0) > 0)
        K = pointmap_intrinsics(Pc, finite)
        N = grid_normals(Pc, 0.5 * float(K[0] + K[1])) if normals == "window" else next_pixel_normals(Pc)
        ok = keep[v] & finite & _finite3(N)
        index = np.full(ok.shape, -1, dtype=np.int64)
        index[ok] = np.arange(int(ok.sum()))
        out.append(PointMapView(int(arms[v]), E[v], Pc[ok], N[ok], index, K))
    return out


def unpack_corrections(x: np.ndarray, T_e1_c1, T_e2_c2, scale, T_b1_b2):
    """Corrections ``x`` (19,) -> the four outputs: hand-eyes corrected on the right (in the camera frame),
    the base on the left (in b1), the scale by a log factor."""
    T1 = T_e1_c1 @ make_T(so3_exp(x[0:3]), x[3:6])
    T2 = T_e2_c2 @ make_T(so3_exp(x[6:9]), x[9:12])
    Tb = make_T(so3_exp(x[13:16]), x[16:19]) @ T_b1_b2
    return T1, T2, float(scale * np.exp(x[12])), Tb


def view_camera_poses(views, T1, T2, Tb) -> np.ndarray:
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


class _Stacked:
    """Every view's points, normals and pixel index in flat arrays (view ``v`` at ``off[v]``), so that the partners
    of one view's samples in all its partner views are looked up in one go."""

    def __init__(self, views):
        self.off = np.r_[0, np.cumsum([len(v.points_c) for v in views])]
        self.points = np.concatenate([v.points_c for v in views])
        self.normals = np.concatenate([v.normals_c for v in views])
        if all(v.projective for v in views):
            shapes = np.array([v.index.shape for v in views])
            self.H, self.W = shapes[:, 0], shapes[:, 1]
            self.pix_off = np.r_[0, np.cumsum(self.H * self.W)]
            self.index = np.concatenate([v.index.ravel() for v in views])
            self.intrinsics = np.array([v.intrinsics for v in views], dtype=np.float64)


class StackedViews(tuple):
    """A fixed sequence of views whose flat arrays (``_Stacked``) are built once, on first use, and shared by
    every :func:`find_pairs` call on it (an estimate finds pairs a dozen times over the same views)."""

    @functools.cached_property
    def stacked(self) -> _Stacked:
        return _Stacked(self)


def _projective_partners(stack: _Stacked, B: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(..., K) indices into each partner view ``B`` (...)'s points of the partners of samples ``c`` (..., K, 3),
    placed in each partner's camera frame (its own units) (-1: none): the point at the pixel where each projects
    (projective data association, as in KinectFusion's ICP), no search, as every view is an organised map with a
    fitted pinhole."""
    z = c[..., 2]
    front = z > 1e-9
    zs = np.where(front, z, 1.0)
    fx, fy, cx, cy = (stack.intrinsics[B, i][..., None] for i in range(4))
    col, row = np.round(fx * c[..., 0] / zs + cx), np.round(fy * c[..., 1] / zs + cy)
    H, W = stack.H[B][..., None], stack.W[B][..., None]
    inside = front & (col >= 0) & (col < W) & (row >= 0) & (row < H)
    pix = stack.pix_off[B][..., None] + np.where(inside, row * W + col, 0).astype(np.int64)
    return np.where(inside, stack.index[pix], -1)


def _nearest_partners(trees, targets, b: int, Pa, radius):
    """As :func:`_projective_partners` for one partner view ``b``, by nearest neighbour among its placed target
    points."""
    if not len(targets[b]):  # a view without points has no partners to give
        return np.full(len(Pa), -1)
    d, j = trees[b].query(Pa, distance_upper_bound=radius)
    return np.where(np.isfinite(d), targets[b][np.minimum(j, len(targets[b]) - 1)], -1)


def _padded(rows: list) -> tuple[np.ndarray, np.ndarray]:
    """``(X (n, L) int, used (n, L) bool)``: int arrays of different lengths, padded with zeros to the longest."""
    L = max((len(r) for r in rows), default=0)
    X = np.zeros((len(rows), L), dtype=int)
    used = np.arange(L) < np.array([len(r) for r in rows])[:, None]
    X[used] = np.concatenate(rows) if rows else []
    return X, used


def find_pairs(views, samples, targets, Tc: np.ndarray, sv: np.ndarray, Tb: np.ndarray, radius: float):
    """Point pairs between overlapping views within ``radius`` (m) with agreeing normals, at the current
    estimate: each view's ``samples`` (indices) look for a partner in each of its partner views.

    Args:
        Tc: (V, 4, 4) camera poses in b1; sv: (V,) each view's metric scale (shared scale x depth factor);
        Tb: (4, 4) T_b1_b2 (to leave out the arms' columns).
    Returns:
        :class:`MapPairs` or None when no pair is found.
    """
    projective = all(v.projective for v in views)
    stack = views.stacked if isinstance(views, StackedViews) else _Stacked(views)
    trees = None
    if not projective:
        from scipy.spatial import cKDTree

        trees = [cKDTree(sv[k] * v.points_c[g] @ T[:3, :3].T + T[:3, 3]) for k, (v, T, g) in
                 enumerate(zip(views, Tc, targets))]
    R, t = Tc[:, :3, :3], Tc[:, :3, 3]
    B, has = _padded([np.asarray(p, dtype=int) for p in _partner_views(views, Tc)])  # (V, m) partners, sorted
    S, mine = _padded([np.asarray(x, dtype=int) for x in samples])  # (V, K) samples
    if not (has.any() and mine.any()):
        return None
    g_a = np.where(mine, stack.off[:len(views), None] + S, 0)
    Pa = sv[:, None, None] * stack.points[g_a] @ np.swapaxes(R, 1, 2) + t[:, None]  # (V, K, 3) in b1
    # the samples and their normals in each partner's camera frame (its own units): the partners' points
    # need not be moved
    c = (Pa[:, None] - t[B][:, :, None]) @ R[B] / sv[B][..., None, None]  # (V, m, K, 3)
    n = (stack.normals[g_a] @ np.swapaxes(R, 1, 2))[:, None] @ R[B]
    if projective:
        j = _projective_partners(stack, B, c)
    else:
        j = np.full(B.shape + S.shape[1:], -1)
        for a, i in zip(*np.nonzero(has)):
            j[a, i] = _nearest_partners(trees, targets, B[a, i], Pa[a], radius)
    free = ~_robot_column(Pa.reshape(-1, 3), Tb).reshape(Pa.shape[:2])
    a, i, k = np.nonzero((j >= 0) & has[:, :, None] & (mine & free)[:, None])  # by view, partner, sample
    b, g = B[a, i], stack.off[B[a, i]] + j[a, i, k]
    d = c[a, i, k] - stack.points[g]
    ok = (sv[b] * np.sqrt(_dot3(d, d)) < radius) & (np.abs(_dot3(n[a, i, k], stack.normals[g])) >= MIN_NORMAL_COS)
    if not ok.any():
        return None
    va, pa, vb, pb, nb = a[ok], stack.points[g_a[a, k][ok]], b[ok], stack.points[g[ok]], stack.normals[g[ok]]
    return MapPairs(va, pa, vb, pb, nb, len(views))


def _transform_grouped(R: np.ndarray, t: np.ndarray | None, p: np.ndarray, bounds: np.ndarray,
                       s: np.ndarray | None = None) -> np.ndarray:
    """``s[v] R[v] p + t[v]`` (or ``R[v] p`` when ``t`` is None) for points ``p`` (K, 3) sorted by view, view
    ``v`` owning rows ``bounds[v]:bounds[v+1]``: one small matmul per view, no (K, 3, 3) gather."""
    out = np.empty_like(p)
    for v in range(len(R)):
        a, b = bounds[v], bounds[v + 1]
        if b > a:
            out[a:b] = (1.0 if s is None else s[v]) * p[a:b] @ R[v].T + (0.0 if t is None else t[v])
    return out


class MapPairs:
    """Point pairs between views, laid out for fast residuals: the samples sorted by their view, the
    partners by theirs.

    Attributes:
        va, vb: (P,) view of each sample and of its partner; pa, pb: (P, 3) their camera-frame points;
        nb: (P, 3) the partner's camera-frame normal (samples' order for ``va``/``pa``, partners' for the rest).
    """

    def __init__(self, va, pa, vb, pb, nb, n_views: int):
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

    def design(self) -> np.ndarray:
        """(P, 13) the pairs' coefficients in the closed form of ``calibration._summary`` (samples' order),
        computed once: they depend on the pairs alone."""
        if getattr(self, "_design", None) is None:
            from ._summary import pair_design

            self._design = pair_design(self.pa, self.pb[self.inv_ob], self.nb[self.inv_ob])
        return self._design


def _geometry(x, kappa, views, start, pairs: MapPairs):
    """Everything the residuals and their Jacobian share: camera rotations and translations (V, 3, 3),
    (V, 3), each view's metric scale (V,), and per pair (in the samples' order) ``X_a``, ``X_b``, ``N_b`` in b1."""
    T1, T2, s, Tb = unpack_corrections(x, *start)
    Tc = view_camera_poses(views, T1, T2, Tb)
    R, t = Tc[:, :3, :3], Tc[:, :3, 3]
    sv = s * np.exp(kappa)
    Xa = _transform_grouped(R, t, pairs.pa, pairs.ba, sv)
    Xb = _transform_grouped(R, t, pairs.pb, pairs.bb, sv)[pairs.inv_ob]
    Nb = _transform_grouped(R, None, pairs.nb, pairs.bb)[pairs.inv_ob]
    return R, t, sv, Xa, Xb, Nb


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (K, 3) arrays (np.cross's generic broadcasting is 3x slower here)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def map_residuals(x, kappa, views, start, pairs: MapPairs) -> np.ndarray:
    """(P,) signed point-to-plane distances (m): sample ``X_a`` from the tangent plane of its partner.

    Args:
        x: (19,) corrections of ``start = (T_e1_c1, T_e2_c2, scale, T_b1_b2)`` (:func:`unpack_corrections`);
        kappa: (V,) each view's log depth factor.
    """
    _, _, _, Xa, Xb, Nb = _geometry(x, kappa, views, start, pairs)
    return _dot3(Xa - Xb, Nb)


def map_jacobian(x, kappa, views, start, pairs: MapPairs) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of :func:`map_residuals`: ``(P, 19)`` for the corrections and ``(P, V)`` for the depth
    factors; analytic, for a perturbation of the current estimate (the hand-eyes' on the right, the base's on
    the left; exact at ``x = 0``, first-order away from it, which the trust region absorbs).

    Derived from ``X = R (s_v p) + t`` and ``N = R n``: a right rotation ``w`` of a view's hand-eye gives
    ``dX = -R (s_v p x w)``, ``dN = -R (n x w)``; a translation ``u`` gives ``dX = R u``; a left rotation of
    ``T_b1_b2`` gives ``dX = -X x w_b``, ``dN = -N x w_b`` for the secondary's views; the log-scale and a
    view's own log depth factor give ``dX = X - t``. Checked against finite differences in the tests."""
    R, t, sv, Xa, Xb, Nb = _geometry(x, kappa, views, start, pairs)
    arm = np.array([v.arm for v in views])
    Rt = np.swapaxes(R, 1, 2)
    nb_a = _transform_grouped(Rt, None, Nb, pairs.ba)  # N_b in camera a
    nb_b = pairs.nb[pairs.inv_ob]  # the partner's normal and point in its own camera b
    qb = sv[pairs.vb][:, None] * pairs.pb[pairs.inv_ob]
    d_b = _transform_grouped(Rt, None, (Xa - Xb)[pairs.ob], pairs.bb)[pairs.inv_ob]
    # sample side: -(n_b in a) x (s p_a); partner side: -(d x n_b) + n_b x (s p_b) = n_b x (d + s p_b) in b
    rot_a = -_cross(nb_a, sv[pairs.va][:, None] * pairs.pa)
    rot_b = _cross(nb_b, d_b + qb)
    J = np.zeros((len(Xa), 19))
    am, bm = arm[pairs.va], arm[pairs.vb]
    for m, k0 in ((1, 0), (2, 6)):
        on_a, on_b = (am == m)[:, None].astype(np.float64), (bm == m)[:, None].astype(np.float64)
        J[:, k0:k0 + 3] = on_a * rot_a + on_b * rot_b
        J[:, k0 + 3:k0 + 6] = on_a * nb_a - on_b * nb_b
    da = _dot3(Nb, Xa - t[pairs.va])
    db = -_dot3(Nb, Xb - t[pairs.vb])
    J[:, 12] = da + db
    # the base moves the secondary's views: -N_b x X_a for a sample, N_b x X_a for a partner (they cancel
    # when both are the secondary's: a rigid motion of both views changes nothing)
    sign = (bm == 2).astype(np.float64) - (am == 2)
    J[:, 13:16] = sign[:, None] * _cross(Nb, Xa)
    J[:, 16:19] = -sign[:, None] * Nb
    Jk = np.zeros((len(Xa), len(views)))
    rows = np.arange(len(Xa))
    Jk[rows, pairs.va] += da
    Jk[rows, pairs.vb] += db
    return J, Jk
