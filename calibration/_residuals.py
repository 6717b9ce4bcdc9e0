"""Residuals of a calibration: pairwise ``AX = XB`` (the paper's) and absolute per view."""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import rotation_angle, so3_log

from ._closed_form import PairMotions, scaled


def pair_residuals(pm: PairMotions, X: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """AX = XB residuals of each pair: rotation angle (rad) and translation norm (m) between ``A X`` and ``X B(s)``.

    Args:
        pm: one arm's pair motions (P pairs).
        X: (4, 4) hand-eye transform ``T_e_c``.
    Returns:
        ``(rot (P,), trans (P,))``.
    """
    R, t = X[:3, :3], X[:3, 3]
    RL = pm.R_A @ R
    tL = pm.R_A @ t + pm.t_A
    RR = R @ pm.R_B
    tR = scale * (pm.t_B @ R.T) + t
    return rotation_angle(np.swapaxes(RL, 1, 2) @ RR), np.linalg.norm(tL - tR, axis=1)


def view_residuals(T_b_e: np.ndarray, T_w_c: np.ndarray, X: np.ndarray, T_b_w: np.ndarray,
                   scale: float, pivot: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Absolute residuals per view between ``T_b_e X`` (kinematics) and ``T_b_w P(s)`` (reconstruction).

    Args:
        T_b_e: (N, 4, 4) end-effector poses; T_w_c: (N, 4, 4) reconstruction camera poses (unscaled).
        X: (4, 4) hand-eye ``T_e_c``; T_b_w: (4, 4); scale: metric = scale * reconstruction units.
        pivot: optional (3,) point in the camera frame (m) whose position is compared instead of the camera
            centre's (``_absolute.estimate_pivot``); None or zeros: the camera centre.

    Returns:
        ``(rot (N, 3) rotation vectors in the camera frame (rad), trans (N, 3) position differences of the
        pivot point (the camera centre by default) in the base (m))``.
    """
    C_kin = T_b_e @ X
    C_rec = T_b_w @ scaled(T_w_c, scale)
    rot = so3_log(np.swapaxes(C_kin[:, :3, :3], 1, 2) @ C_rec[:, :3, :3])
    trans = C_rec[:, :3, 3] - C_kin[:, :3, 3]
    if pivot is not None:
        trans = trans + (C_rec[:, :3, :3] - C_kin[:, :3, :3]) @ np.asarray(pivot, dtype=np.float64)
    return rot, trans
