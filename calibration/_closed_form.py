"""Closed-form stages of Bi-JCR (paper, "Solving for Initial Calibration Solution"): pure array kernels.

- :func:`pair_motions`: relative motions ``A = T_b_e(i)^-1 T_b_e(j)``, ``B = T_w_c(i)^-1 T_w_c(j)`` over all
  pairs ``i < j`` (the paper uses consecutive pairs only; all pairs use every view's information).
- :func:`park_martin_rotation`: ``M = sum log(R_B) log(R_A)^T``, ``R_X = (M^T M)^-1/2 M^T``, evaluated via
  the SVD of ``M^T`` (identical for a well-posed ``M``, and still a proper rotation when ``M`` is rank 2).
- :func:`solve_translations_and_scale`: every arm's hand-eye translation and the ONE shared scale from a
  single linear least-squares problem (the paper's SRP, stacked over arms; no search over the scale).
- :func:`base_from_world_per_view` / :func:`average_base_from_world`: ``T_b_w`` per view in the absolute
  form ``T_b_e(i) X P_i(s)^-1`` and its proper SE(3) average (the paper's eq. for this average mixes a
  relative motion with an absolute pose; the absolute form is what the method needs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import inv_T, make_T, mean_T, so3_log


@dataclass
class PairMotions:
    """Relative motions of one arm over view pairs.

    Attributes:
        i, j: (P,) view indices of each pair (i < j).
        R_A, t_A: (P, 3, 3), (P, 3) end-effector motion ``T_b_e(i)^-1 T_b_e(j)`` (metres).
        R_B, t_B: (P, 3, 3), (P, 3) camera motion ``T_w_c(i)^-1 T_w_c(j)`` (reconstruction units: metric = s * t_B).
        a, b: (P, 3) rotation vectors ``log(R_A)``, ``log(R_B)`` (quaternion-based log: no NaN at small angles).
    """

    i: np.ndarray
    j: np.ndarray
    R_A: np.ndarray
    t_A: np.ndarray
    R_B: np.ndarray
    t_B: np.ndarray
    a: np.ndarray
    b: np.ndarray

    def __len__(self) -> int:
        return len(self.i)

    def subset(self, views: np.ndarray) -> PairMotions:
        """The pairs whose two views are both in ``views`` ((K,) indices)."""
        keep = np.isin(self.i, views) & np.isin(self.j, views)
        return PairMotions(*(getattr(self, k)[keep] for k in ("i", "j", "R_A", "t_A", "R_B", "t_B", "a", "b")))


def pair_motions(T_b_e: np.ndarray, T_w_c: np.ndarray, consecutive: bool = False) -> PairMotions:
    """Relative motions of one arm over all pairs ``i < j`` (or consecutive pairs only).

    Args:
        T_b_e: (N, 4, 4) end-effector poses in the arm's base.
        T_w_c: (N, 4, 4) camera poses in the reconstruction frame (unscaled).
    """
    n = len(T_b_e)
    if consecutive:
        i, j = np.arange(n - 1), np.arange(1, n)
    else:
        i, j = np.triu_indices(n, 1)
    A = inv_T(T_b_e[i]) @ T_b_e[j]
    B = inv_T(T_w_c[i]) @ T_w_c[j]
    return PairMotions(i, j, A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3],
                       so3_log(A[:, :3, :3]), so3_log(B[:, :3, :3]))


def park_martin_rotation(a: np.ndarray, b: np.ndarray, min_angle: float = np.deg2rad(1.0),
                         weights: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Park–Martin hand-eye rotation from rotation vectors of paired motions.

    Solves ``log(R_A) = R_X log(R_B)`` in the least-squares sense: with ``M = sum b a^T``,
    ``R_X = (M^T M)^-1/2 M^T``. Computed as ``U diag(1, 1, det) V^T`` from the SVD ``M^T = U S V^T``,
    which equals the formula when ``M`` has full rank and stays a proper rotation (no NaN, no reflection)
    when it does not. Pairs whose rotation is below ``min_angle`` (rad) on either side carry no usable
    axis and are skipped.

    Args:
        a: (P, 3) ``log(R_A)`` (end-effector motions).
        b: (P, 3) ``log(R_B)`` (camera motions).
        weights: optional (P,) non-negative pair weights.

    Returns:
        ``(R_X (3, 3), number of pairs used)``.
    """
    keep = (np.linalg.norm(a, axis=1) >= min_angle) & (np.linalg.norm(b, axis=1) >= min_angle)
    w = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=np.float64)
    keep &= w > 0
    if keep.sum() < 2:
        raise ValueError(f"Park-Martin needs at least 2 pairs rotating more than {np.rad2deg(min_angle):.2f} deg, "
                         f"got {int(keep.sum())}")
    Mt = (w[keep, None] * a[keep]).T @ b[keep]  # M^T = sum a b^T
    U, _, Vt = np.linalg.svd(Mt)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return U @ np.diag([1.0, 1.0, d]) @ Vt, int(keep.sum())


@dataclass
class LinearSolution:
    """Result of the stacked translation + scale least squares.

    Attributes:
        t_X: list of (3,) hand-eye translations (metres), one per arm.
        scale: the shared scale (metric = scale * reconstruction units).
        cov: (3K+1, 3K+1) covariance of ``[t_X..., scale]`` from the residual variance (unweighted LS).
        rms: root-mean-square residual (metres).
    """

    t_X: list
    scale: float
    cov: np.ndarray
    rms: float


def solve_translations_and_scale(motions: list[PairMotions], R_X: list[np.ndarray],
                                 weights: list[np.ndarray] | None = None) -> LinearSolution:
    """All arms' hand-eye translations and one shared scale from ONE linear least-squares problem.

    For every pair of arm m: ``R_A t_X + t_A = R_X (s t_B) + t_X``, i.e.
    ``(R_A - I) t_Xm - s R_Xm t_B = -t_A``; unknowns ``[t_X1, ..., t_XK, s]`` (3K + 1).

    Args:
        motions: K arms' pair motions.
        R_X: K (3, 3) hand-eye rotations.
        weights: optional K arrays (P_m,) of pair weights.
    """
    K = len(motions)
    rows, rhs = [], []
    for m, (pm, R) in enumerate(zip(motions, R_X)):
        P = len(pm)
        blk = np.zeros((P, 3, 3 * K + 1))
        blk[:, :, 3 * m:3 * m + 3] = pm.R_A - np.eye(3)
        blk[:, :, -1] = -(pm.t_B @ R.T)
        r = -pm.t_A
        if weights is not None:
            w = np.sqrt(np.asarray(weights[m], dtype=np.float64))[:, None]
            blk = blk * w[..., None]
            r = r * w
        rows.append(blk.reshape(3 * P, 3 * K + 1))
        rhs.append(r.reshape(3 * P))
    A = np.concatenate(rows)
    y = np.concatenate(rhs)
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = A @ x - y
    dof = max(len(y) - len(x), 1)
    sigma2 = float(res @ res) / dof
    cov = np.linalg.pinv(A.T @ A) * sigma2
    return LinearSolution([x[3 * m:3 * m + 3] for m in range(K)], float(x[-1]), cov,
                          float(np.sqrt(np.mean(res ** 2))) if len(res) else 0.0)


def scaled(T_w_c: np.ndarray, scale: float) -> np.ndarray:
    """``P(s)``: camera poses ``(..., 4, 4)`` with the translation multiplied by ``scale``."""
    P = np.array(T_w_c, dtype=np.float64, copy=True)
    P[..., :3, 3] *= scale
    return P


def base_from_world_per_view(T_b_e: np.ndarray, X: np.ndarray, T_w_c: np.ndarray, scale: float) -> np.ndarray:
    """(N, 4, 4) per-view estimates ``T_b_w(i) = T_b_e(i) X P_i(scale)^-1`` (absolute-pose form)."""
    return T_b_e @ X @ inv_T(scaled(T_w_c, scale))


def average_base_from_world(T_b_e: np.ndarray, X: np.ndarray, T_w_c: np.ndarray, scale: float,
                            weights: np.ndarray | None = None) -> np.ndarray:
    """``T_b_w`` (4, 4): proper SE(3) average (rotation mean on SO(3), translation mean) of the per-view estimates."""
    return mean_T(base_from_world_per_view(T_b_e, X, T_w_c, scale), weights)


def hand_eye(R_X: np.ndarray, t_X: np.ndarray) -> np.ndarray:
    """(4, 4) from rotation (3, 3) and translation (3,)."""
    return make_T(R_X, t_X)
