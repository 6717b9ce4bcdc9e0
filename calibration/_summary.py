"""Point-map pair summaries in closed form: a fixed linear summary of the point-to-plane distances between
two views depends on the calibration only through the two views' relative placement, so it is evaluated
from 13 numbers per ordered pair of views instead of from every point.

A distance between a sample ``p_a`` of view ``a`` and its partner ``p_b`` (normal ``n_b``, both in their own
camera frames, reconstruction units) with the views at ``(R_a, t_a, s_a)``, ``(R_b, t_b, s_b)`` in b1 is

    r = n_b . R_b^T (s_a R_a p_a + t_a - t_b) - s_b n_b . p_b = A(p_a, p_b, n_b) . z

with ``z = [s_a vec(M), c, s_b]`` (13,), ``M = R_b^T R_a``, ``c = R_b^T (t_a - t_b)``: linear in ``z``, with
coefficients ``A = [vec(n_b p_a^T), n_b, -n_b . p_b]`` that never change. A weighted projection
``Q^T (w r)`` of one ordered pair's distances is therefore ``K z`` with ``K = Q^T (w A)`` (8, 13) formed once
per term: the same numbers as projecting the distances themselves (up to rounding), at a cost that does
not grow with the number of point pairs. Its derivatives follow from those of ``z`` under a small motion
of each camera (a twist on the right, :func:`view_twists`).
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import skew

__all__ = ["PairSummary", "pair_design", "pair_summary", "view_twists"]

#: hat(w)_ij = sum_k _HAT[i, j, k] w_k (the derivative of vec(M hat(w)) and vec(hat(w) M) in w)
_HAT = np.zeros((3, 3, 3))
_HAT[2, 1, 0], _HAT[1, 2, 0] = 1.0, -1.0
_HAT[0, 2, 1], _HAT[2, 0, 1] = 1.0, -1.0
_HAT[1, 0, 2], _HAT[0, 1, 2] = 1.0, -1.0


class PairSummary:
    """``K`` (D, R, 13) of the D ordered view pairs ``(a[d], b[d])`` and the output rows block ``block[d]`` (of
    ``n_blocks``, R rows each) they add to: ``out[block] += K z(a, b)``."""

    def __init__(self, K: np.ndarray, a: np.ndarray, b: np.ndarray, block: np.ndarray, n_blocks: int):
        self.K, self.a, self.b, self.block, self.n_blocks = K, a, b, block, n_blocks

    def relative(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``M (D, 3, 3)``, ``c (D, 3)`` of every ordered pair from the cameras ``R (V, 3, 3)``, ``t (V, 3)`` in b1."""
        Rb_t = np.swapaxes(R[self.b], 1, 2)
        return Rb_t @ R[self.a], np.einsum("dij,dj->di", Rb_t, t[self.a] - t[self.b])

    def values(self, R: np.ndarray, t: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(n_blocks R,) the summaries with the cameras at ``R, t`` and per-view metric scales ``s`` (V,)."""
        M, c = self.relative(R, t)
        z = np.concatenate([s[self.a, None] * M.reshape(-1, 9), c, s[self.b, None]], axis=1)
        return self._gather(np.einsum("drj,dj->dr", self.K, z))

    def jacobian(self, R: np.ndarray, t: np.ndarray, s: np.ndarray, twist: np.ndarray,
                 log_s: np.ndarray) -> np.ndarray:
        """(n_blocks R, n) derivatives of :meth:`values` with respect to n parameters that move each camera by
        ``twist`` (V, 6, n) (rotation, translation, on the right: ``T_b1_c exp(twist)``) and change each view's log
        metric scale by ``log_s`` (V, n)."""
        M, c = self.relative(R, t)
        D = len(self.a)
        sa, sb = s[self.a], s[self.b]
        # z's derivatives (D, 13, 14) with respect to each pair's [w_a, u_a, w_b, u_b, log s_a, log s_b]:
        # M = R_b^T R_a: dM = M hat(w_a) - hat(w_b) M; c = R_b^T (t_a - t_b): dc = M u_a - u_b + hat(c) w_b
        L = np.zeros((D, 13, 14))
        L[:, :9, 0:3] = sa[:, None, None] * np.einsum("dil,ljk->dijk", M, _HAT).reshape(D, 9, 3)
        L[:, :9, 6:9] = -sa[:, None, None] * np.einsum("ilk,dlj->dijk", _HAT, M).reshape(D, 9, 3)
        L[:, :9, 12] = sa[:, None] * M.reshape(D, 9)
        L[:, 9:12, 3:6] = M
        L[:, 9:12, 9:12] = -np.eye(3)
        L[:, 9:12, 6:9] = skew(c)
        L[:, 12, 13] = sb
        # ... and those with respect to the n parameters (D, 14, n)
        P = np.concatenate([twist[self.a], twist[self.b], log_s[self.a][:, None], log_s[self.b][:, None]], axis=1)
        return self._gather((self.K @ L) @ P)

    def _gather(self, per_pair: np.ndarray) -> np.ndarray:
        out = np.zeros((self.n_blocks,) + per_pair.shape[1:])
        np.add.at(out, self.block, per_pair)
        return out.reshape((-1,) + per_pair.shape[2:])


def pair_design(pa: np.ndarray, pb: np.ndarray, nb: np.ndarray) -> np.ndarray:
    """(P, 13) each distance's coefficients ``A = [vec(n_b p_a^T), n_b, -n_b . p_b]`` from the samples ``pa``, their
    partners ``pb`` and the partners' normals ``nb`` (P, 3), each in its own camera frame."""
    return np.concatenate([(nb[:, :, None] * pa[:, None, :]).reshape(-1, 9), nb,
                           -(nb[:, 0] * pb[:, 0] + nb[:, 1] * pb[:, 1] + nb[:, 2] * pb[:, 2])[:, None]], axis=1)


def pair_summary(blocks: list, va: np.ndarray, vb: np.ndarray, design: np.ndarray, w: np.ndarray) -> PairSummary:
    """The closed form of the summaries ``Q_k^T (w r)[idx_k]`` of ``blocks`` ``[(idx_k, Q_k (len(idx_k), R))]``.

    Args:
        va, vb: (P,) each distance's sample and partner view; design: (P, 13) their :func:`pair_design`;
        w: (P,) each distance's weight.
    """
    R = blocks[0][1].shape[1] if blocks else 8
    if not blocks:
        return PairSummary(np.zeros((0, R, 13)), np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), 0)
    i = np.concatenate([idx for idx, _ in blocks])
    Q = np.concatenate([Q for _, Q in blocks]) * w[i, None]
    blk = np.repeat(np.arange(len(blocks)), [len(idx) for idx, _ in blocks])
    # one ordered pair = the run of rows with the same block and sample view (blocks list their rows sorted)
    order = np.lexsort((va[i], blk))
    i, Q, blk = i[order], Q[order], blk[order]
    A = design[i]
    first = np.flatnonzero(np.r_[True, (blk[1:] != blk[:-1]) | (va[i][1:] != va[i][:-1])])
    K = np.stack([Q[f:e].T @ A[f:e] for f, e in zip(first, np.r_[first[1:], len(i)])])
    return PairSummary(K, va[i[first]], vb[i[first]], blk[first], len(blocks))


def view_twists(R: np.ndarray, t: np.ndarray, arms: np.ndarray, n: int, kappa_at: int) -> tuple[np.ndarray, np.ndarray]:
    """``twist (V, 6, n)``, ``log_s (V, n)`` of the point-map corrections (``calibration._pointmaps``): the hand-eye
    of arm 1 (columns 0-5) and of arm 2 (6-11) on the right, in the camera frame; the log scale (12); T_b1_b2
    on the left, in b1 (13-18), which moves arm 2's cameras by ``(R^T w, R^T (w x t))``; each view's log depth
    factor (``kappa_at + v``). ``R (V, 3, 3)``, ``t (V, 3)``: the cameras in b1."""
    V = len(arms)
    tw = np.zeros((V, 6, n))
    log_s = np.zeros((V, n))
    eye = np.eye(3)
    for v in range(V):
        k0 = 0 if arms[v] == 1 else 6
        tw[v, :3, k0:k0 + 3] = eye
        tw[v, 3:, k0 + 3:k0 + 6] = eye
        if arms[v] == 2:
            Rt = R[v].T
            tw[v, :3, 13:16] = Rt
            tw[v, 3:, 13:16] = -Rt @ skew(t[v])  # R^T (w x t) = -R^T hat(t) w
            tw[v, 3:, 16:19] = Rt
    log_s[:, 12] = 1.0
    log_s[np.arange(V), kappa_at + np.arange(V)] = 1.0
    return tw, log_s
