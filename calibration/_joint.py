"""One weighted estimator: the kinematic loop and the point maps in one robust least-squares problem.

Unknowns ``theta`` (25 + V), corrections of a :class:`JointState`: ``T_e1_c1`` and ``T_e2_c2`` (on the
right, in the camera frame), the log of the shared scale, ``T_b1_b2`` (on the left, in b1), ``T_b1_w`` (on
the left) and one log depth factor ``kappa_v`` per view (a foundation model gets each view's depth scale a
little wrong). ``T_b2_w = T_b1_b2^-1 T_b1_w``.

Cost terms (``calibration._terms``), each whitened by noise levels estimated from the data:

- **kinematic loop**: per view, the camera pose from the kinematics ``T_b_e X`` against the
  reconstruction's ``T_b_w P(s)`` (rotation in rad, position in m); one noise level per type, by
  variance components (``sum r^2 / sum (1 - h_jj)``);
- **point maps**: point-to-plane distances between overlapping views placed by the kinematics
  (``calibration._pointmaps``), each divided by its view's own noise (robust spread), then summarised per
  pair of views into the 8 numbers a pair can tell (:func:`map_term`), whose noise level is estimated by
  variance components over the pairs: correlated errors (a view's depth warp) show up there, where a
  count of raw distances would take them for independent evidence;
- **depth factors**: the prior ``kappa_v ~ N(0, sigma)``, each arm's mean held at zero; ``sigma`` is
  KAPPA_SIGMA, or the fitted factors' spread up to KAPPA_CAP when they show more.

Exact poses with noisy maps: the loop's residuals are tiny, its weight is high, the maps barely move the
answer. Noisy poses with maps that agree: the loop's weight is low, the maps decide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import inv_T, make_T, so3_exp

from ._absolute import SIGMA_FLOOR_ROT, SIGMA_FLOOR_TRANS
from ._pointmaps import _cross, _dot3, unpack_corrections, view_camera_poses
from ._summary import pair_summary, view_twists
from ._terms import CostTerm

__all__ = ["JointState", "N_CAL", "perturb", "pose_term", "map_term", "depth_prior_term", "view_map_noise"]

N_CAL = 25  # calibration unknowns in theta before the per-view depth factors
MAP_SIGMA_FLOOR = 2e-4  # m: no point map agrees better than this
#: the per-view depth factors' prior: its level where the maps show no wider spread (the floor), and the
#: most the data may raise it to. The estimate is solved at the floor; when the fitted factors spread
#: significantly wider (the prior rows' variance factor, a chi-square test), it is solved again from the
#: start with the prior at that spread, at most KAPPA_CAP (estimate._depth_level). Iterated freely
#: (variance components), the factors' spread absorbs hand-eye and scale errors (a camera moved along its
#: optical axis looks like a depth factor), hand-eye translations several times worse. No fixed level
#: serves maps with and without per-view depth-scale errors: the measurements are in docs/calibration.md
#: ("The depth factors' prior, measured (issue 21)").
KAPPA_SIGMA = 1e-3
KAPPA_CAP = 3e-3
MEAN_KAPPA_SIGMA = 1e-4  # each arm's mean depth factor: held at zero (see depth_prior_term)
#: point-to-plane distances are weighted (Huber, knee HUBER_K of the view's noise) at each round's start
#: and left out beyond TRIM of it: the pair summaries are plain least squares, so robustness is per point
HUBER_K = 2.5
TRIM = 10.0


@dataclass(frozen=True)
class JointState:
    """A point of the joint problem (frames as in the contract).

    Attributes:
        T_e1_c1, T_e2_c2, T_b1_b2, T_b1_w: (4, 4); scale: metric = scale x reconstruction units;
        kappa: (V,) each view's log depth factor.
    """

    T_e1_c1: np.ndarray
    T_e2_c2: np.ndarray
    scale: float
    T_b1_b2: np.ndarray
    T_b1_w: np.ndarray
    kappa: np.ndarray

    @property
    def calibration(self) -> tuple:
        """``(T_e1_c1, T_e2_c2, scale, T_b1_b2)``: the start of the point-map corrections."""
        return self.T_e1_c1, self.T_e2_c2, self.scale, self.T_b1_b2


def perturb(st: JointState, theta: np.ndarray) -> JointState:
    """``st`` moved by ``theta`` (25 + V,)."""
    T1, T2, s, Tb = unpack_corrections(theta[:19], *st.calibration)
    W1 = make_T(so3_exp(theta[19:22]), theta[22:25]) @ st.T_b1_w
    return JointState(T1, T2, s, Tb, W1, st.kappa + theta[N_CAL:])


def _perturbed(st: JointState, thetas: np.ndarray) -> tuple:
    """``st`` moved by each row of ``thetas`` (S, 25 + V) as :func:`perturb` does, all rows at once (one rotation
    exponential for all): ``(T_e1_c1, T_e2_c2, T_b1_b2, T_b1_w)`` (S, 4, 4) each and the scales (S,)."""
    th = np.atleast_2d(thetas)
    R = so3_exp(th[:, [0, 1, 2, 6, 7, 8, 13, 14, 15, 19, 20, 21]].reshape(-1, 4, 3))  # (S, 4, 3, 3)
    D = make_T(R, th[:, [3, 4, 5, 9, 10, 11, 16, 17, 18, 22, 23, 24]].reshape(-1, 4, 3))
    return (st.T_e1_c1 @ D[:, 0], st.T_e2_c2 @ D[:, 1], D[:, 2] @ st.T_b1_b2, D[:, 3] @ st.T_b1_w,
            st.scale * np.exp(th[:, 12]))


def _pose_residuals(st: JointState, thetas: np.ndarray, arms: np.ndarray, E: np.ndarray, P: np.ndarray,
                    pivot: np.ndarray | None = None) -> np.ndarray:
    """(S, 6 V) for ``st`` moved by each row of ``thetas`` (S, 25 + V), per view [rotation (rad, camera frame),
    position (m, base frame)] of the kinematic loop, views in input order. All in one batch.

    ``pivot`` (3,): the point of the camera frame (m) whose positions are compared (the pose-only solve's
    noise model, ``_absolute.estimate_pivot``); None compares the camera centres."""
    from bimanual_app.transforms import so3_log

    T1, T2, Tb, W1, s = _perturbed(st, thetas)
    one = (arms == 1)[None, :, None, None]
    X = np.where(one, T1[:, None], T2[:, None])  # (S, V, 4, 4)
    W = np.where(one, W1[:, None], (inv_T(Tb) @ W1)[:, None])
    Ckin = E[None] @ X
    Rrec = W[..., :3, :3] @ P[None, :, :3, :3]
    trec = np.einsum("svij,svj->svi", W[..., :3, :3], s[:, None, None] * P[None, :, :3, 3]) + W[..., :3, 3]
    rot = so3_log(np.swapaxes(Ckin[..., :3, :3], -1, -2) @ Rrec)
    trans = trec - Ckin[..., :3, 3]
    if pivot is not None:
        trans = trans + (Rrec - Ckin[..., :3, :3]) @ np.asarray(pivot, dtype=np.float64)
    return np.concatenate([rot, trans], axis=-1).reshape(len(s), -1)


def pose_term(st: JointState, arms: np.ndarray, E: np.ndarray, P: np.ndarray, sigma: tuple[float, float],
              pivot: np.ndarray | None = None) -> CostTerm:
    """The kinematic loop of every view.

    Args:
        arms: (V,) 1 or 2; E: (V, 4, 4) end-effector poses ``T_b_e``; P: (V, 4, 4) reconstruction poses ``T_w_c``.
        sigma: (rotation rad, position m) starting noise levels.
        pivot: (3,) camera-frame point (m) whose positions are compared, or None for the camera centres.
    """
    V = len(arms)
    n = N_CAL + V
    steps = 1e-7 * np.eye(n)[:N_CAL]

    def res(theta):
        return _pose_residuals(st, theta, arms, E, P, pivot)[0]

    def jac(theta):  # 25 columns by forward differences, all in one batch: 6 V residuals are cheap
        R = _pose_residuals(st, theta + np.vstack([np.zeros(n), steps]), arms, E, P, pivot)
        J = np.zeros((6 * V, n))
        J[:, :N_CAL] = ((R[1:] - R[0]) / 1e-7).T
        return J

    groups = np.tile([0, 0, 0, 1, 1, 1], V)
    return CostTerm("kinematic loop", res, jac, groups, np.array(sigma, dtype=np.float64), _update_pose,
                    np.repeat(np.arange(V), 6))


def _update_pose(term: CostTerm, raw: np.ndarray, red: np.ndarray) -> np.ndarray:
    """Variance components per type, each residual's square capped at (3 sigma)^2 (a few bad views must
    not inflate the level); a type the parameters absorb almost fully keeps its level."""
    new = term.sigma.copy()
    for g, floor in ((0, SIGMA_FLOOR_ROT), (1, SIGMA_FLOOR_TRANS)):
        m = term.groups == g
        den = red[m].sum()
        if den > 3.0:
            r2 = np.minimum(raw[m] ** 2, 9.0 * term.sigma[g] ** 2)
            new[g] = max(float(np.sqrt(r2.sum() / den)), floor)
    return new


def _relative_motion_basis(Xa, nb, ta, tb, Xb, a_is_lo) -> np.ndarray:
    """(K, 8) derivatives of point-to-plane residuals with respect to what a pair of views can tell: a rigid
    motion (rotation, translation) of the lower-numbered view and the two views' log depth factors."""
    sign = np.where(a_is_lo, 1.0, -1.0)[:, None]
    G = np.empty((len(Xa), 8))
    G[:, 0:3] = sign * _cross(Xa, nb)
    G[:, 3:6] = sign * nb
    da, db = _dot3(nb, Xa - ta), -_dot3(nb, Xb - tb)
    G[:, 6] = np.where(a_is_lo, da, db)
    G[:, 7] = np.where(a_is_lo, db, da)
    return G


def _orthonormal_basis(G: np.ndarray) -> np.ndarray:
    """(K, 8) the Q of the QR decomposition of ``G`` (K, 8), as ``np.linalg.qr`` gives it, by LAPACK directly
    (numpy's wrapper costs as much as the decomposition at this size, and a term makes hundreds)."""
    from scipy.linalg import lapack

    qr, tau, _, _ = lapack.dgeqrf(G)
    return lapack.dorgqr(qr, tau)[0]


def map_term(st: JointState, views: list, pairs, sigma_v: np.ndarray, sigma_pair: float) -> CostTerm:
    """The point maps, summarised per pair of views.

    The point-to-plane distances of one pair of views only tell the pair's relative placement and depth
    factors (8 numbers), and they share the pair's depth warp, so they are far from independent. Each
    pair's distances, divided by the sample view's own noise ``sigma_v`` (robust spread) and Huber-weighted
    (gross ones left out), are projected onto an orthonormal basis of those 8 directions (QR of their derivatives at the
    round's start): 8 numbers per pair that keep everything the distances say about the unknowns. If the
    distances were independent, each would have unit variance; ``sigma_pair`` (variance components over
    the pairs) measures how far they are from that, correlation included.

    Args:
        views: the :class:`calibration._pointmaps.PointMapView` list; pairs: their ``MapPairs`` at ``st``.
        sigma_v: (V,) each view's point-to-plane noise (m); sigma_pair: the pair summaries' noise level.
    """
    from ._pointmaps import _geometry

    V = len(views)
    _, t, _, Xa, Xb, Nb = _geometry(np.zeros(19), st.kappa, views, st.calibration, pairs)
    raw0 = _dot3(Xa - Xb, Nb)
    w = 1.0 / np.asarray(sigma_v, dtype=np.float64)[pairs.va]
    lo, hi = np.minimum(pairs.va, pairs.vb), np.maximum(pairs.va, pairs.vb)
    z = np.abs(raw0) * w
    ok = z < TRIM
    w = w * np.sqrt(np.minimum(1.0, HUBER_K / np.maximum(z, 1e-12)))  # Huber weights at the round's start
    G = _relative_motion_basis(Xa, Nb, t[pairs.va], t[pairs.vb], Xb, pairs.va == lo) * w[:, None]
    rows = np.flatnonzero(ok)
    rows = rows[np.argsort((lo * V + hi)[rows], kind="stable")]  # by view pair, each pair's rows in order
    _, first, count = np.unique((lo * V + hi)[rows], return_index=True, return_counts=True)
    blocks = [(idx, _orthonormal_basis(G[idx])) for idx in (rows[f:f + c] for f, c in zip(first, count)) if len(idx) >= 30]
    summary = pair_summary(blocks, pairs.va, pairs.vb, pairs.design(), w)
    arms = np.array([v.arm for v in views])

    def cameras(theta):
        T1, T2, s, Tb = unpack_corrections(theta[:19], *st.calibration)
        Tc = view_camera_poses(views, T1, T2, Tb)
        return Tc[:, :3, :3], Tc[:, :3, 3], s * np.exp(st.kappa + theta[N_CAL:])

    def res(theta):  # = S (w * map_residuals), S the blocks' Q^T, in closed form (calibration._summary)
        return summary.values(*cameras(theta))

    def jac(theta):
        R, t, s = cameras(theta)
        return summary.jacobian(R, t, s, *view_twists(R, t, arms, N_CAL + V, N_CAL))

    who = np.concatenate([np.tile([[idx[0]]], (Q.shape[1], 1)) for idx, Q in blocks]).ravel() if blocks else np.zeros(0, int)

    m = len(who)
    return CostTerm("point maps", res, jac, np.zeros(m, dtype=int), np.array([sigma_pair], dtype=np.float64),
                    _update_pair_noise, np.stack([lo[who], hi[who]], axis=1) if m else np.zeros((0, 2), int),
                    {"sigma_view_m": np.asarray(sigma_v, dtype=np.float64), "pairs": pairs, "blocks": len(blocks),
                     "points": int(sum(len(i) for i, _ in blocks)), "raw": raw0})


def view_map_noise(raw: np.ndarray, va: np.ndarray, V: int) -> np.ndarray:
    """(V,) each view's point-to-plane noise: the robust spread (1.4826 MAD) of the residuals it samples."""
    sig = np.full(V, np.nan)
    for v in range(V):
        r = raw[va == v]
        if len(r) >= 10:
            sig[v] = 1.4826 * np.median(np.abs(r - np.median(r)))
    fallback = np.nanmedian(sig) if np.isfinite(sig).any() else MAP_SIGMA_FLOOR
    return np.maximum(np.where(np.isfinite(sig), sig, fallback), MAP_SIGMA_FLOOR)


def _update_pair_noise(term: CostTerm, raw: np.ndarray, red: np.ndarray) -> np.ndarray:
    """Variance components of the pair summaries (squares capped at (3 sigma)^2), and the views' own
    noise re-measured for the next round."""
    pairs = term.info["pairs"]
    term.info["sigma_view_m"] = view_map_noise(term.info["raw"], pairs.va, len(term.info["sigma_view_m"]))
    den = red.sum()
    if den < 3.0:
        return term.sigma
    r2 = np.minimum(raw ** 2, 9.0 * term.sigma[0] ** 2)
    return np.array([max(float(np.sqrt(r2.sum() / den)), 1e-3)])


def depth_prior_term(st: JointState, sigma: float, arms: np.ndarray) -> CostTerm:
    """The prior of the per-view log depth factors: each view's ``kappa_v ~ N(0, sigma)`` (group 0), and each arm's mean factor held at zero (group 1, ``MEAN_KAPPA_SIGMA``): a
    hand-eye translation along the optical axis moves every view of that arm nearly as a common depth
    factor would, so only the spread within an arm is the maps' own."""
    V = len(st.kappa)
    A = np.zeros((2, V))
    for i, a in enumerate((1, 2)):
        m = arms == a
        A[i, m] = 1.0 / max(int(m.sum()), 1)
    D = np.vstack([np.eye(V), A])

    def res(theta):
        return D @ (st.kappa + theta[N_CAL:])

    def jac(theta):
        J = np.zeros((V + 2, N_CAL + V))
        J[:, N_CAL:] = D
        return J

    return CostTerm("depth factors", res, jac, np.r_[np.zeros(V, dtype=int), [1, 1]],
                    np.array([sigma, MEAN_KAPPA_SIGMA], dtype=np.float64), _update_prior,
                    np.r_[np.arange(V), [-1, -1]])


def _update_prior(term: CostTerm, raw: np.ndarray, red: np.ndarray) -> np.ndarray:
    """The prior's levels are fixed (see KAPPA_SIGMA)."""
    return term.sigma


