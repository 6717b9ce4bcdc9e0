"""Point-map refinement of the pose-only solve (``CalibrationOptions.estimator="refine"``, the previous
default): make the views' point maps agree when each is placed by FK, the kinematic loop left out.

It trusts the kinematics and the maps completely, which holds on the emulator's rendered scenes and not on
real photographs or foundation-model-like maps; the default is the joint weighted estimator
(``calibration._joint``). Kept as an option for comparison (docs/calibration.md has both measured).

Placed by the kinematics, every view lays its point map in b1 through ``T_e1_c1``, ``T_e2_c2``, ``scale``
and ``T_b1_b2`` (19 numbers); when they are right, overlapping views lay the same surface in the same place.
This module finds the 19 numbers that minimise the point-to-plane distance between overlapping views (an
ICP whose only free parameters are the calibration's, so the per-view pose error drops out: each view keeps
its own depth and takes its pose from the arm). Unlike a multiway registration with a free pose per view
(which partial overlap and a dominant table leave under-determined), the problem has 19 unknowns and tens
of thousands of residuals. The views, their point pairs and the residuals with their Jacobian are
``calibration._pointmaps``'s (shared with the joint estimator), the per-view depth factors held at 1.

Written with scipy (``least_squares`` with a soft-L1 loss, ``cKDTree`` correspondences) because the
parametrisation - every view's pose tied to the arm's kinematics through shared unknowns - is not one
that Open3D's or pycolmap's registration offers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bimanual_app.transforms import check_shape

from ._absolute import normal_covariance
from ._correction import beyond_correction, correction_limits
from ._pointmaps import (
    MapPairs,
    PointMapView,
    camera_frame_views,
    find_pairs,
    grid_normals,
    map_jacobian,
    map_residuals,
    unpack_corrections,
    view_camera_poses,
)

__all__ = ["PointMapView", "RefineResult", "camera_frame_views", "refine_with_point_maps", "grid_normals"]

#: correspondence radii (m) of the successive ICP rounds: coarse to fine; the last is repeated (up to
#: MAX_FINE_ROUNDS times) until a round moves no point of the workspace by more than CONVERGED_M (any round
#: that moves less ends the refinement: the estimate has settled, e.g. point maps that already agree). Point-to-plane
#: pairs slide freely along the table, so what corrects the in-plane error is re-matching at object edges:
#: slow, round by round, after the coarse error is gone.
RADII = (0.03, 0.02, 0.012, 0.008)
MAX_FINE_ROUNDS = 4
CONVERGED_M = 2e-4
LEVER_M = 0.5  # a rotation change is judged by what it does this far away (the scale's likewise)
POINTS_PER_VIEW = 800  # sampled points per view that look for partners in every other view
TARGETS_PER_VIEW = 6000  # points per view among which partners are looked for (point-to-plane needs no more)
ROBUST_KNEE_M = 0.003  # soft-L1 knee: residuals beyond 3 mm count less and less
MIN_RESIDUALS = 500
_OUTPUTS = ("T_e1_c1", "T_e2_c2", "scale", "T_b1_b2")  # the order of the estimate's tuples


@dataclass
class RefineResult:
    """Refined calibration and how much the views' agreement improved.

    Attributes:
        T_e1_c1, T_e2_c2, T_b1_b2: (4, 4); scale: metric = scale * reconstruction units.
        accepted: False when the refinement was refused (``reason``); the inputs are then returned as given.
        rms_before_m, rms_after_m: RMS point-to-plane distance between overlapping views (m) on the final
            round's correspondences, at the joint solve and at the refined values.
        residuals_before_m, residuals_after_m: (R,) those distances (for plots).
        correspondences: number of point pairs in the final round; cross_arm: of them between the arms.
        rounds: per ICP round ``{"radius_m", "pairs", "rms_m", "moved_m"}`` (``moved_m``: how far the round's
            change moves the workspace, see ``_movement``).
        covariance: (19, 19) linearised covariance of the corrections (rotation vector and translation of
            ``T_e1_c1`` in c1, the same for ``T_e2_c2``, log scale, rotation vector and translation of
            ``T_b1_b2`` on the left in b1), from the last round's Jacobian and the robust spread of its
            residuals, as if they were independent (they are not: see :func:`uncertainty`).
    """

    T_e1_c1: np.ndarray
    T_e2_c2: np.ndarray
    scale: float
    T_b1_b2: np.ndarray
    accepted: bool
    reason: str = ""
    rms_before_m: float = float("nan")
    rms_after_m: float = float("nan")
    residuals_before_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residuals_after_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    correspondences: int = 0
    cross_arm: int = 0
    rounds: list = field(default_factory=list)
    covariance: np.ndarray | None = None


def _residuals(x, views, start, pairs: MapPairs) -> np.ndarray:
    """(P,) point-to-plane distances (m) (:func:`calibration._pointmaps.map_residuals`), the views' depth
    factors held at 1: this estimator trusts the maps' depths."""
    return map_residuals(x, np.zeros(len(views)), views, start, pairs)


def _jacobian(x, views, start, pairs: MapPairs) -> np.ndarray:
    """(P, 19) analytic derivatives of :func:`_residuals` (:func:`calibration._pointmaps.map_jacobian`)."""
    return map_jacobian(x, np.zeros(len(views)), views, start, pairs)[0]


def _movement(dx: np.ndarray) -> float:
    """How far (m) a change of the corrections (19,) moves points of the workspace, at most."""
    rot = np.linalg.norm(dx[[0, 1, 2, 6, 7, 8, 13, 14, 15]].reshape(3, 3), axis=1)
    trans = np.linalg.norm(dx[[3, 4, 5, 9, 10, 11, 16, 17, 18]].reshape(3, 3), axis=1)
    return float(max((rot * LEVER_M + trans).max(), abs(dx[12]) * LEVER_M))


def refine_with_point_maps(views: list[PointMapView], T_e1_c1: np.ndarray, T_e2_c2: np.ndarray, scale: float,
                           T_b1_b2: np.ndarray, radii: tuple = RADII, points_per_view: int = POINTS_PER_VIEW,
                           max_fine_rounds: int = MAX_FINE_ROUNDS, seed: int = 0, progress=None) -> RefineResult:
    """Refine the joint solve so that the views' point maps, placed by the kinematics, agree.

    Args:
        views: the point maps (:func:`camera_frame_views`), at least 2 per arm.
        T_e1_c1, T_e2_c2, T_b1_b2: (4, 4) the joint solve's values; scale: its scale.
        radii: correspondence radius (m) of each ICP round; the last one is repeated up to
            ``max_fine_rounds`` times, until a round moves the workspace by less than ``CONVERGED_M``.
        points_per_view: sampled points of each view that look for partners.
        progress: optional callable(str) for one line per round.

    Returns:
        :class:`RefineResult`; refused (``accepted=False``, inputs unchanged) when the views overlap too little,
        the agreement does not improve, or an output moves beyond ``_correction``'s fixed limits (no held-out
        check stands behind this estimate, so a large move is never let through).
    """
    from scipy.optimize import least_squares

    initial = tuple(check_shape(n, np.asarray(T, dtype=np.float64), (4, 4)) for n, T in
                    (("T_e1_c1", T_e1_c1), ("T_e2_c2", T_e2_c2))) + (float(scale),) + (
        check_shape("T_b1_b2", np.asarray(T_b1_b2, dtype=np.float64), (4, 4)),)

    def refused(reason: str, **kw) -> RefineResult:
        return RefineResult(*initial, False, reason, **kw)

    per_arm = [sum(1 for v in views if v.arm == a) for a in (1, 2)]
    if min(per_arm) < 2:
        return refused(f"needs 2 or more point maps per arm, has {per_arm[0]} / {per_arm[1]}")
    rng = np.random.default_rng(seed)
    samples = [rng.choice(len(v.points_c), min(points_per_view, len(v.points_c)), replace=False)
               if len(v.points_c) else np.zeros(0, dtype=int) for v in views]
    targets = [rng.choice(len(v.points_c), min(TARGETS_PER_VIEW, len(v.points_c)), replace=False)
               if len(v.points_c) else np.zeros(0, dtype=int) for v in views]
    x_scale = np.r_[[0.01] * 3, [0.005] * 3, [0.01] * 3, [0.005] * 3, [0.01], [0.01] * 3, [0.01] * 3]
    zero = np.zeros(19)
    current, rounds, corr, sol = initial, [], None, None
    schedule = list(radii) + [radii[-1]] * max_fine_rounds
    for radius in schedule:
        T1, T2, s, Tb = current
        Tc = view_camera_poses(views, T1, T2, Tb)
        corr = find_pairs(views, samples, targets, Tc, np.full(len(views), s), Tb, radius)
        n = 0 if corr is None else len(corr)
        if n < MIN_RESIDUALS:
            return refused(f"the point maps overlap too little: {n} point pairs within {radius * 1e3:.0f} mm "
                           f"(needs {MIN_RESIDUALS})", rounds=rounds)
        # each round solves for corrections of its own start, where the analytic Jacobian is exact
        sol = least_squares(_residuals, zero, jac=_jacobian, args=(views, current, corr), loss="soft_l1",
                            f_scale=ROBUST_KNEE_M, x_scale=x_scale, max_nfev=50, tr_solver="lsmr")
        moved = _movement(sol.x)
        current = unpack_corrections(sol.x, *current)
        rounds.append({"radius_m": radius, "pairs": n, "rms_m": float(np.sqrt(np.mean(sol.fun ** 2))),
                       "moved_m": moved})
        if progress:
            progress(f"point-map refinement: {radius * 1e3:.0f} mm round, {n} point pairs, "
                     f"RMS {rounds[-1]['rms_m'] * 1e3:.2f} mm, moved {moved * 1e3:.2f} mm")
        if moved < CONVERGED_M:  # settled: finer radii would only re-select the same pairs
            break
    r0 = _residuals(zero, views, initial, corr)
    r1 = _residuals(zero, views, current, corr)
    va, vb = corr.va, corr.vb
    arm = np.array([v.arm for v in views])
    info = dict(rms_before_m=float(np.sqrt(np.mean(r0 ** 2))), rms_after_m=float(np.sqrt(np.mean(r1 ** 2))),
                residuals_before_m=r0, residuals_after_m=r1, correspondences=int(len(va)),
                cross_arm=int(np.sum(arm[va] != arm[vb])), rounds=rounds)
    # judged robustly (the median absolute distance), as the fit is: a few far pairs must not decide
    if np.median(np.abs(r1)) >= np.median(np.abs(r0)):
        return refused("the point maps agree no better after refinement", **info)
    why = beyond_correction(dict(zip(_OUTPUTS, initial)), dict(zip(_OUTPUTS, current)), correction_limits(None),
                            "the refinement")
    if why:
        return refused(why, **info)
    if info["cross_arm"] == 0:
        return refused("no point pairs between the two arms' views: T_b1_b2 cannot be refined", **info)
    fun, jac = sol.fun, sol.jac
    sigma = 1.4826 * np.median(np.abs(fun - np.median(fun)))  # robust spread of the residuals (m)
    # undetermined directions get an infinite variance, as in the pose-only solve (not pinv's small number)
    cov = sigma ** 2 * normal_covariance(jac.T @ jac)[0]
    return RefineResult(*current, True, "", covariance=cov, **info)
