"""Finding views the reconstruction registered badly (past the paper).

Two tests, both on quantities the solver already has:

1. :func:`angle_screen` — a scale-free, calibration-free invariant: for a correct pair, the end-effector
   and camera motions rotate by the SAME angle (``A = X B X^-1``). A badly registered view breaks this for
   all of its pairs, a good view only for its pairs with bad views, so the per-view MEDIAN discrepancy
   singles out bad views before anything is fitted.
2. :func:`worst_view` — after a robust fit, each view's absolute residual (rotation and position), corrected
   for its leverage and in units of the robustly estimated noise (``_absolute.studentized_scores``), is
   compared with a chi(6) threshold; the worst offender is dropped and the fit repeated (one at a time, so
   one bad view cannot mask or drag down good ones).
"""

from __future__ import annotations

import numpy as np

from ._closed_form import PairMotions


def angle_screen(pm: PairMotions, views: np.ndarray, floor_deg: float = 3.0, k: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Per-view median |angle(A) - angle(B)| over its pairs and which views exceed the threshold.

    Args:
        pm: pair motions of one arm (all pairs among its views).
        views: (K,) view indices in use.
        floor_deg: never flag below this discrepancy (deg).
        k: threshold in robust standard deviations of the pair discrepancies.

    Returns:
        ``(score_deg (K,), flagged (K,) bool)``.
    """
    sub = pm.subset(views)
    e = np.rad2deg(np.abs(np.linalg.norm(sub.a, axis=1) - np.linalg.norm(sub.b, axis=1)))
    score = np.array([np.median(e[(sub.i == v) | (sub.j == v)]) if np.any((sub.i == v) | (sub.j == v)) else 0.0
                      for v in views])
    # robust scale from the pairs that do not touch the worst view: with few views, a large share of all
    # pairs involves one bad view, which would inflate a plain median
    worst = views[int(np.argmax(score))] if len(views) else -1
    clean = e[(sub.i != worst) & (sub.j != worst)]
    if len(clean) < 6:  # too few to estimate a scale from (4 views): the plain median, conservative
        clean = e
    sigma = 1.4826 * np.median(clean) if len(clean) else 0.0
    thr = max(floor_deg, k * sigma)
    return score, score > thr


def effective_threshold(threshold: float, dof: int) -> float:
    """The score threshold when the noise itself was estimated from ``dof`` residual degrees of freedom.

    ``threshold`` is meant for a known noise (a chi(6) score); with an estimated noise the score follows
    ``sqrt(6 F(6, dof))`` (the outlier test's t-like correction), so the same false-alarm probability needs a
    higher bar when few views are left to estimate the noise (dof 11: 8.3 instead of 5.0; dof 95: 5.3).
    """
    from scipy.special import chdtr, fdtri  # (scipy.stats would add 0.6 s to the CLI's start-up)

    if dof <= 0:
        return float("inf")
    return float(np.sqrt(6 * fdtri(6, dof, chdtr(6, threshold ** 2))))


def worst_view(scores: list[np.ndarray], residuals: list[np.ndarray], kept: list[np.ndarray], n_total: list[int],
               threshold: float, min_rot: float, min_trans: float, min_views: int = 3,
               max_fraction: float = 0.34) -> tuple[int, int, float] | None:
    """The view to drop next, or None.

    Args:
        scores: per arm (K_m,) studentized residual of each view in sigmas (chi with 6 dof under the model).
        residuals: per arm (K_m, 2) rotation (rad) and position (m) residual norms.
        kept: per arm (K_m,) view indices the scores belong to.
        n_total: per arm number of views before any was dropped.
        threshold: score above which a view is an outlier.
        min_rot, min_trans: absolute residuals (rad, m) a view must also exceed (never drop a view for
            residuals below what any real capture has).
        min_views, max_fraction: never leave fewer views, or drop more than this fraction, of an arm.

    Returns:
        ``(arm index, view index, score)`` of the worst droppable outlier.
    """
    best = None
    for m, (sc, res, kv) in enumerate(zip(scores, residuals, kept)):
        if len(kv) - 1 < min_views or (n_total[m] - len(kv) + 1) > max_fraction * n_total[m]:
            continue
        big = (res[:, 0] > min_rot) | (res[:, 1] > min_trans)
        d = np.where(big, sc, 0.0)
        k = int(np.argmax(d))
        if d[k] > threshold and (best is None or d[k] > best[2]):
            best = (m, int(kv[k]), float(d[k]))
    return best
