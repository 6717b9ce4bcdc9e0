"""Kinematic consistency of registered views: a scale- and calibration-free check of camera poses.

For two views i, j of one arm, the end-effector motion ``A = T_b_e(i)^-1 T_b_e(j)`` and the camera
motion ``B = T_w_c(i)^-1 T_w_c(j)`` satisfy ``A X = X B`` for the unknown hand-eye ``X``, so
``R_B = X^T R_A X``: both rotate by the same angle. A view that SfM registered wrongly (repetitive
texture matched across different faces, a symmetric object) breaks this for every pair it is in, by
tens of degrees, while correct views agree within the pose noise (a fraction of a degree). No scale,
no hand-eye estimate and no threshold on the reconstruction's units are needed.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape, inv_T, rotation_angle

__all__ = ["motion_angle_errors", "inconsistent_views"]


def motion_angle_errors(T_b_e: np.ndarray, T_w_c: np.ndarray) -> np.ndarray:
    """(N, N) |angle(R_A_ij) - angle(R_B_ij)| in degrees for all view pairs of one arm (0 on the diagonal).

    Args:
        T_b_e: (N, 4, 4) end-effector poses; T_w_c: (N, 4, 4) camera poses of the same views.
    """
    check_shape("T_b_e", T_b_e, (None, 4, 4))
    check_shape("T_w_c", T_w_c, (len(T_b_e), 4, 4))
    A = inv_T(T_b_e)[:, None] @ T_b_e[None]
    B = inv_T(T_w_c)[:, None] @ T_w_c[None]
    return np.rad2deg(np.abs(rotation_angle(A[..., :3, :3]) - rotation_angle(B[..., :3, :3])))


def inconsistent_views(T_b_e: np.ndarray, T_w_c: np.ndarray, tol_deg: float = 5.0) -> np.ndarray:
    """(N,) bool: views whose rotations disagree with the arm's kinematics.

    Repeatedly drops the view with the largest median disagreement with the remaining views while that
    median exceeds ``tol_deg`` (medians: a bad view must not condemn the good ones it is paired with).
    Needs 3 views to decide anything; fewer are all kept.
    """
    E = motion_angle_errors(T_b_e, T_w_c)
    bad = np.zeros(len(E), bool)
    while (~bad).sum() >= 3:
        keep = np.flatnonzero(~bad)
        sub = E[np.ix_(keep, keep)]
        med = np.array([np.median(np.delete(sub[k], k)) for k in range(len(keep))])
        worst = int(np.argmax(med))
        if med[worst] <= tol_deg:
            break
        bad[keep[worst]] = True
    return bad
