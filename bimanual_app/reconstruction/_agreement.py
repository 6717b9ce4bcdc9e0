"""Kinematic agreement of a reconstruction: how well its camera motions match the robot's (pure functions).

For two views i, j of one arm the end-effector motion ``A = T_b_e(i)^-1 T_b_e(j)`` and the camera motion
``B = T_w_c(i)^-1 T_w_c(j)`` satisfy ``A X = X B(s)`` for the hand-eye ``X`` and the reconstruction's
scale ``s``. Fitting ``X`` and ``s`` in closed form (Park-Martin rotation, then the linear least squares
for the translation and the scale: calibration's own closed-form kernels) and measuring what is left
over the view pairs scores a reconstruction by what the calibration needs from it, independently of its
frame and scale: a model whose camera motions are more accurate leaves smaller residuals. The robot's own
pose noise sets a floor that is the same for every reconstruction of one capture, so the scores rank
reconstructions of the same capture; they are not comparable across captures.

- rotation residual of a pair: the angle between ``R_A R_X`` and ``R_X R_B`` (deg);
- translation residual: ``|R_A t_X + t_A - R_X s t_B - t_X|``, its median over the pairs divided by the
  median end-effector displacement ``|t_A|`` (relative: no unit, no scale);
- per arm the medians over all pairs ``i < j`` (robust to one bad view); both arms: the mean of the arms';
- the combined score ``rot_deg / ROT_UNIT_DEG + trans_rel / TRANS_UNIT``: one degree counts like 2 % of the
  motion (a 1 deg error of a camera 1 m from the scene moves what it sees by 17 mm, about 2 % of a
  typical 0.5-1 m wrist motion). Lower is better.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape, rotation_angle_between

__all__ = ["ROT_UNIT_DEG", "TRANS_UNIT", "NEAR_TIE", "arm_agreement", "motion_agreement", "choose_attempt"]

ROT_UNIT_DEG = 1.0
TRANS_UNIT = 0.02
NEAR_TIE = 0.05  # scores within 5 % of the best count as a tie: more points decide


def arm_agreement(T_b_e: np.ndarray, T_w_c: np.ndarray) -> dict:
    """Agreement of one arm's camera motions with its end-effector motions, after the closed-form fit.

    Args:
        T_b_e: (N, 4, 4) end-effector poses in the arm's base (metres).
        T_w_c: (N, 4, 4) camera-to-world poses of the same views (reconstruction frame and units).

    Returns ``{"views": N, "pairs": P, "rot_deg": median rotation residual, "trans_rel": median
    translation residual / median |t_A|, "trans_mm": median translation residual (mm), "scale": s}``;
    ``rot_deg`` and ``trans_rel`` are NaN when the fit is impossible (fewer than 3 views, or fewer than
    two pairs rotating over 1 deg).
    """
    from calibration._closed_form import pair_motions, park_martin_rotation, solve_translations_and_scale

    check_shape("T_b_e", T_b_e, (None, 4, 4))
    check_shape("T_w_c", T_w_c, (len(T_b_e), 4, 4))
    n = len(T_b_e)
    out = {"views": n, "pairs": n * (n - 1) // 2, "rot_deg": float("nan"), "trans_rel": float("nan"),
           "trans_mm": float("nan"), "scale": float("nan")}
    if n < 3:
        return out
    pm = pair_motions(np.asarray(T_b_e, np.float64), np.asarray(T_w_c, np.float64))
    try:
        R_X, _ = park_martin_rotation(pm.a, pm.b)
    except ValueError:  # no two pairs rotate enough to fix an axis
        return out
    lin = solve_translations_and_scale([pm], [R_X])
    t_X, s = lin.t_X[0], lin.scale
    rot = np.rad2deg(rotation_angle_between(pm.R_A @ R_X, R_X @ pm.R_B))
    res = np.linalg.norm(pm.R_A @ t_X + pm.t_A - s * (pm.t_B @ R_X.T) - t_X, axis=1)
    motion = float(np.median(np.linalg.norm(pm.t_A, axis=1)))
    out.update(rot_deg=float(np.median(rot)), trans_mm=1e3 * float(np.median(res)), scale=float(s),
               trans_rel=float(np.median(res)) / motion if motion > 0 else float("nan"))
    return out


def motion_agreement(arms: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict:
    """Agreement of a reconstruction with both arms' kinematics.

    Args:
        arms: per arm name ``(T_b_e (N, 4, 4), T_w_c (N, 4, 4))`` of its registered views.

    Returns ``{"rot_deg", "trans_rel", "score", "arms": {name: arm_agreement(...)}}``; ``rot_deg`` and
    ``trans_rel`` are the means over the arms, ``score`` (lower is better) combines them (module
    docstring); all NaN-free only when every arm could be fitted, else ``score`` is inf.
    """
    per = {name: arm_agreement(T_b_e, T_w_c) for name, (T_b_e, T_w_c) in arms.items()}
    rot = float(np.mean([p["rot_deg"] for p in per.values()])) if per else float("nan")
    tr = float(np.mean([p["trans_rel"] for p in per.values()])) if per else float("nan")
    score = rot / ROT_UNIT_DEG + tr / TRANS_UNIT
    return {"rot_deg": rot, "trans_rel": tr, "score": float(score) if np.isfinite(score) else float("inf"),
            "arms": per}



def choose_attempt(usable: list[bool], views: list[int], points: list[int], scores: list[float],
                   near_tie: float = NEAR_TIE) -> int:
    """Index of the reconstruction attempt to keep.

    Among the usable attempts (every arm has enough views), those that register the most views; among
    them, the one whose camera motions agree best with the robot's (lowest ``score``,
    :func:`motion_agreement`); scores within ``near_tie`` (relative) of the best tie, and the tie goes to
    more points, then the earlier attempt. Views come first because every registered view is data the
    calibration uses, and a model that misses views leaves out the hard ones, so its agreement over the
    remaining pairs is not comparable (measured: docs/reconstruction.md, "Choosing the attempt").
    Without any usable attempt, or without any finite score, views and points decide alone.

    Args:
        usable, views, points, scores: one entry per attempt (A,).
    """
    n = len(usable)
    if not (len(views) == len(points) == len(scores) == n) or n == 0:
        raise ValueError(f"choose_attempt: need equally long, non-empty lists, got {n}, {len(views)}, "
                         f"{len(points)}, {len(scores)}")
    idx = [i for i in range(n) if usable[i]] or list(range(n))
    most = max(views[i] for i in idx)
    idx = [i for i in idx if views[i] == most]
    finite = [i for i in idx if np.isfinite(scores[i])]
    if finite:
        best = min(scores[i] for i in finite)
        idx = [i for i in finite if scores[i] <= best * (1.0 + near_tie) + 1e-12]
    return max(idx, key=lambda i: (points[i], -i))
