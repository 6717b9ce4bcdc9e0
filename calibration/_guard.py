"""The held-out check that decides between the joint estimate and the pose-only one.

Each view is left out in turn: its kinematic-loop residuals and every point-map residual it takes part in
are removed, the estimate is updated without them (one Gauss-Newton downdate of the normal equations,
exact for a linear problem: ``(H - J_v^T J_v) d = J_v^T r_v - J^T r``, the gradient of the rows kept), and the removed residuals are
predicted from the updated estimate. A view's held-out score is the robust cost of those predictions,
whitened by the joint problem's noise levels. The pose-only estimate is scored the same way on the same
residuals, its calibration re-fitted from the kinematic loop alone and its depth factors from the maps
alone. The estimate with the lower total predicts data it did not see better.
"""

from __future__ import annotations

import numpy as np

from ._terms import robust_cost

__all__ = ["held_out_cost", "jackknife_covariance"]


def held_out_cost(J: np.ndarray, r: np.ndarray, view_of_row: np.ndarray, fitted_by: list[tuple[np.ndarray, np.ndarray]],
                  f_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``(cost (V,), shift (V, n))``: the held-out cost of each view and how far the estimate moves without it
    (the delete-one-view jackknife's replicates, see :func:`jackknife_covariance`).

    Args:
        J: (M, n) whitened Jacobian of all residuals at the estimate; r: (M,) whitened residuals there.
        view_of_row: (M,) the view each residual belongs to (-1: none, e.g. a prior; a point pair between
            views a and b appears in both a's and b's blocks: pass it twice via ``rows_of_view`` semantics
            by giving a (M, 2) array).
        fitted_by: how the estimator fits its parameters: a list of ``(rows (bool M,), cols (int k,))``
            blocks, each set of parameters fitted from its rows alone (the joint estimate: one block with
            every row and column; the pose-only one: the calibration from the loop, the depth factors from
            the maps).
        f_scale: the robust knee (whitened units).
    """
    vo = np.asarray(view_of_row).reshape(len(r), -1)
    V = int(vo.max()) + 1
    out = np.zeros(V)
    shift = np.zeros((V, J.shape[1]))
    # each block's normal matrix and gradient over all its rows, once; a view's rows are taken out of them
    blocks = [(rows, cols, J[np.ix_(rows, cols)], r[rows]) for rows, cols in fitted_by]
    blocks = [(rows, cols, Jb, rb, Jb.T @ Jb, Jb.T @ rb) for rows, cols, Jb, rb in blocks]
    for v in range(V):
        mine = np.any(vo == v, axis=1)
        pred = r[mine].copy()
        for rows, cols, Jb, rb, Hb, gb in blocks:
            held = mine[rows]
            if not held.any():
                continue
            Jh, rh = Jb[held], rb[held]
            H = Hb - Jh.T @ Jh
            g = gb - Jh.T @ rh
            d = np.linalg.lstsq(H, -g, rcond=1e-12)[0]
            pred += J[np.ix_(mine, cols)] @ d
            shift[v, cols] += d
        out[v] = float(np.sum(robust_cost(pred, f_scale)))
    return out, shift


def jackknife_covariance(shift: np.ndarray) -> np.ndarray:
    """(n, n) delete-one-view jackknife covariance ``(V - 1) / V sum (d_v - mean d)(d_v - mean d)^T`` from the
    estimate's shifts without each view (V, n). The views are the independent units: errors shared by the
    residuals of one view (its depth warp, its pose error) are counted once, which the normal matrix of
    residuals assumed independent cannot do."""
    V = len(shift)
    dev = shift - shift.mean(axis=0)
    return (V - 1) / V * dev.T @ dev
