"""Errors against ground truth: for evaluation only (CLI report, benchmark). The solver never calls this."""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import inv_T, rotation_angle_between


def transform_error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(rotation error deg, translation error mm) of a (4, 4) estimate."""
    return (float(np.rad2deg(rotation_angle_between(T[:3, :3], T_true[:3, :3]))),
            float(1000 * np.linalg.norm(T[:3, 3] - T_true[:3, 3])))


def calibration_errors(T_e1_c1, T_e2_c2, scale, T_b1_b2, gt) -> dict:
    """Errors of a calibration against a :class:`bimanual_app.scene.GroundTruth` (or anything with the same
    attributes). Keys: ``T_e1_c1``/``T_e2_c2``/``T_b1_b2`` -> (deg, mm), ``scale_percent`` (None without a true scale)."""
    out = {"T_e1_c1": transform_error(T_e1_c1, gt.T_e1_c1), "T_e2_c2": transform_error(T_e2_c2, gt.T_e2_c2),
           "T_b1_b2": transform_error(T_b1_b2, gt.T_b1_b2)}
    out["scale_percent"] = None if gt.scale is None else float(100 * abs(scale / gt.scale - 1))
    return out


def paper_residuals(T_b_e: list, X_est: list, X_true: list, consecutive: bool = True) -> tuple[float, float]:
    """The paper's evaluation residuals: ``A X - X B_true`` with the TRUE camera motions on the right-hand side.

    ``B_true = X_true^-1 A X_true`` (camera motion implied by the exact hand-eye transform). Returns the mean
    rotation angle (rad) and translation norm (m) over the motions of all arms (consecutive pairs, as in
    the paper's table).
    """
    rot, tr = [], []
    for E, X, Xt in zip(T_b_e, X_est, X_true):
        n = len(E)
        i, j = (np.arange(n - 1), np.arange(1, n)) if consecutive else np.triu_indices(n, 1)
        A = inv_T(E[i]) @ E[j]
        B = inv_T(Xt) @ A @ Xt
        L, R = A @ X, X @ B
        rot.append(rotation_angle_between(L[:, :3, :3], R[:, :3, :3]))
        tr.append(np.linalg.norm(L[:, :3, 3] - R[:, :3, 3], axis=1))
    return float(np.mean(np.concatenate(rot))), float(np.mean(np.concatenate(tr)))
