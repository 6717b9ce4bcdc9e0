"""The joint weighted estimate (``calibration._joint``) from the pose-only solve: rounds of point pairs from
coarse to fine, each a robust solve of all cost terms with noise levels re-estimated from its residuals,
then the held-out check (``calibration._guard``) against the pose-only estimate."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from . import _joint as jm
from ._absolute import SIGMA_FLOOR_ROT, SIGMA_FLOOR_TRANS, normal_covariance
from ._correction import beyond_correction, correction_limits
from ._guard import held_out_cost, jackknife_covariance
from ._pointmaps import StackedViews, find_pairs, map_residuals, view_camera_poses
from ._terms import CostTerm, redundancy, solve_terms, stack, update_terms

__all__ = ["JointFit", "estimate_jointly"]

#: correspondence radii (m) of the successive rounds, coarse to fine; the last is repeated (up to
#: MAX_FINE_ROUNDS more) until a round moves the workspace by less than CONVERGED_M. Point-to-plane pairs
#: slide along the table, so the in-plane error goes by re-matching at object edges, round by round.
RADII = (0.03, 0.02, 0.012, 0.008)
MAX_FINE_ROUNDS = 4
CONVERGED_M = 2e-4
LEVER_M = 0.5  # a rotation change is judged by what it does this far away (the scale's likewise)
POINTS_PER_VIEW = 800  # sampled points per view that look for partners
TARGETS_PER_VIEW = 6000  # points per view among which partners are looked for by nearest neighbour
MIN_PAIRS = 500
F_SCALE = 2.5  # robust knee, in noise sigmas (as the pose-only solve)
PAIR_SIGMA0 = 3.0  # starting noise of the pair summaries (1 if the distances were independent)
#: the depth factors spread wider than their prior only when a chi-square test of their rows says so at this
#: level (a variance factor measured from about 16 views is uncertain by about a third)
DEPTH_TEST_P = 0.05
#: a view whose map meets the others' this much less than the median view, placed by the reconstruction's
#: own poses, contradicts its own pose (see contradicting_views)
BAD_MATCH_RATIO = 0.25
CONTRADICTION_RADIUS_M = 0.02


@dataclass
class JointFit:
    """The joint estimate and the evidence for it.

    Attributes:
        state: the estimate (:class:`calibration._joint.JointState`), or the start when ``accepted`` is False.
        accepted: the joint estimate passed every check and the held-out test preferred it.
        reason: why not, when not accepted.
        covariance: (25 + V, 25 + V) of the corrections at ``state`` (from the weighted problem).
        noise: the estimated noise levels (rotation rad, position m, per-view map m, F, sigma_kappa).
        held_out: ``{"joint": total, "pose_only": total, "gain": mean, "gain_se": its standard error}``:
            held-out costs, and the per-view gain of the joint estimate over the pose-only one.
        residuals_before_m, residuals_after_m: point-to-plane distances of the final pairs at the start and
            at the estimate; rounds: per round ``{"radius_m", "pairs", "rms_m", "moved_m"}``.
        dropped_views: indices of views left out of the point-map term (their map contradicts their pose).
    """

    state: object
    accepted: bool
    reason: str = ""
    covariance: np.ndarray | None = None
    noise: dict = field(default_factory=dict)
    held_out: dict = field(default_factory=dict)
    residuals_before_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residuals_after_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pairs: int = 0
    cross_arm: int = 0
    rounds: list = field(default_factory=list)
    dropped_views: list = field(default_factory=list)


def _sample(views, n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.choice(len(v.points_c), min(n, len(v.points_c)), replace=False) if len(v.points_c)
            else np.zeros(0, dtype=int) for v in views]


def _pairs_at(views, st, samples, targets, radius, active):
    Tc = view_camera_poses(views, st.T_e1_c1, st.T_e2_c2, st.T_b1_b2)
    use = [s if active[k] else s[:0] for k, s in enumerate(samples)]
    pairs = find_pairs(views, use, targets, Tc, st.scale * np.exp(st.kappa), st.T_b1_b2, radius)
    if pairs is not None and not active.all():
        keep = active[pairs.vb] & active[pairs.va]
        if not keep.all():
            from ._pointmaps import MapPairs

            pairs = MapPairs(pairs.va[keep], pairs.pa[keep], pairs.vb[keep], pairs.pb[pairs.inv_ob][keep],
                             pairs.nb[pairs.inv_ob][keep], len(views))
    return pairs


def _movement(theta: np.ndarray) -> float:
    """How far (m) a change of the calibration corrections moves points of the workspace, at most."""
    rot = np.linalg.norm(theta[[0, 1, 2, 6, 7, 8, 13, 14, 15]].reshape(3, 3), axis=1)
    trans = np.linalg.norm(theta[[3, 4, 5, 9, 10, 11, 16, 17, 18]].reshape(3, 3), axis=1)
    return float(max((rot * LEVER_M + trans).max(), abs(theta[12]) * LEVER_M))


def _x_scale(V: int) -> np.ndarray:
    return np.r_[[0.01] * 3, [0.005] * 3, [0.01] * 3, [0.005] * 3, [0.01], [0.01] * 3, [0.01] * 3,
                 [0.01] * 3, [0.01] * 3, [0.01] * V]


def _terms(st, views, pairs, arms, E, P, noise) -> list[CostTerm]:
    """The cost terms at ``st``: kinematic loop, point maps, depth-factor prior."""
    return [jm.pose_term(st, arms, E, P, noise["pose"], noise.get("pivot")),
            jm.map_term(st, views, pairs, noise["map"], noise["pair"]),
            jm.depth_prior_term(st, noise["kappa"], arms)]


def _record(noise: dict, terms: list[CostTerm]) -> None:
    pose, maps, prior = terms
    noise["pose"] = tuple(float(s) for s in pose.sigma)
    noise["pair"] = float(maps.sigma[0])
    noise["map"] = np.asarray(maps.info["sigma_view_m"], dtype=np.float64)
    noise["kappa"] = float(prior.sigma[0])


def _initial_map_noise(st, views, pairs) -> np.ndarray:
    """(V,) per-view map noise of the residuals at the start."""
    raw = map_residuals(np.zeros(19), st.kappa, views, st.calibration, pairs)
    return jm.view_map_noise(raw, pairs.va, len(views))


def _round(st, views, pairs, arms, E, P, noise, passes: int):
    """One round: solve all terms, re-estimate their noise, repeat until the levels settle."""
    V = len(views)
    theta = np.zeros(jm.N_CAL + V)
    moved = 0.0
    for _ in range(passes):
        terms = _terms(st, views, pairs, arms, E, P, noise)
        sol = solve_terms(terms, theta, _x_scale(V), F_SCALE)
        moved += _movement(sol.x)
        st = jm.perturb(st, sol.x)
        terms = _terms(st, views, pairs, arms, E, P, noise)
        _, J = stack(terms, theta)
        change = update_terms(terms, theta, J)
        _record(noise, terms)
        if change < 0.1:
            break
    return st, moved


def contradicting_views(views, P: np.ndarray, start, samples, targets) -> np.ndarray:
    """(V,) bool: views whose point map contradicts its own pose. Placed where the reconstruction's own poses
    ``P`` (V, 4, 4) put them (``T_b1_w P(s)``), the views' maps must meet each other (a reconstruction makes
    its maps and poses together); a view that finds partners for fewer than BAD_MATCH_RATIO of the median
    view's share of its samples (within CONTRADICTION_RADIUS_M) has a map that does not fit its pose (its
    depth far off, a wrong image)."""
    from ._closed_form import scaled

    V = len(views)
    Tc = start.T_b1_w @ scaled(np.asarray(P, dtype=np.float64), start.scale)
    pairs = find_pairs(views, samples, targets, Tc, np.full(V, start.scale), start.T_b1_b2, CONTRADICTION_RADIUS_M)
    if pairs is None:
        return np.zeros(V, dtype=bool)
    rate = np.bincount(pairs.va, minlength=V) / np.maximum([len(x) for x in samples], 1)
    return rate < BAD_MATCH_RATIO * np.median(rate)


def _view_rows(terms: list[CostTerm]) -> np.ndarray:
    """(M, 2) the view(s) each stacked residual belongs to (-1: none)."""
    pose, maps, prior = terms
    return np.concatenate([np.stack([pose.views, np.full(len(pose.views), -1)], 1), maps.views,
                           np.full((len(prior.groups), 2), -1)])


def _guard_loop_sigma(loop_pose: CostTerm, n: int) -> np.ndarray:
    """(2,) the kinematic loop's noise levels (rotation, position) for the held-out check: the fit's, except
    where the fit's level sits at its floor (``SIGMA_FLOOR_*``: no pose is weighted as better known than the
    arm): there the data are more exact than the floor, and the check measures them on their own scale, the
    pose-only estimate's loop scatter (RMS, at least 1e-3 of the floor). With exact poses a joint estimate
    that the maps pulled a few hundredths of a millimetre off then predicts the held-out loop worse, and the
    poses stand; with any real pose noise the floor does not bind and nothing changes."""
    sig = np.asarray(loop_pose.sigma, dtype=np.float64).copy()
    raw = loop_pose.residuals(np.zeros(n))
    for g, floor in ((0, SIGMA_FLOOR_ROT), (1, SIGMA_FLOOR_TRANS)):
        m = loop_pose.groups == g
        if m.any() and sig[g] <= floor * (1.0 + 1e-9):
            sig[g] = max(float(np.sqrt(np.mean(raw[m] ** 2))), 1e-3 * floor)
    return sig


def _held_out(terms_joint, terms_pose, V: int) -> tuple[dict, np.ndarray]:
    """Held-out cost of the joint estimate and of the pose-only one (same residuals, same weights; the loop's
    weights where its level is floored: ``_guard_loop_sigma``):
    ``({"joint": total, "pose_only": total, "gain": mean per-view gain, "gain_se": its standard error},
    the joint estimate's shifts without each view (V, n))``; a view's gain is the pose-only estimate's
    held-out cost there minus the joint one's."""
    theta = np.zeros(jm.N_CAL + V)
    sig = _guard_loop_sigma(terms_pose[0], len(theta))
    floored = sig != np.asarray(terms_pose[0].sigma)  # only the floored levels change, in both estimates' terms
    terms_joint, terms_pose = ([replace(t[0], sigma=np.where(floored, sig, t[0].sigma)), *t[1:]]
                               for t in (terms_joint, terms_pose))
    costs = {}
    n_pose = len(terms_joint[0].groups)
    shifts = None
    for name, terms in (("joint", terms_joint), ("pose_only", terms_pose)):
        r, J = stack(terms, theta)
        rows = _view_rows(terms)
        all_rows = np.ones(len(r), dtype=bool)
        if name == "joint":
            blocks = [(all_rows, np.arange(jm.N_CAL + V))]
        else:
            loop = np.zeros(len(r), dtype=bool)
            loop[:n_pose] = True
            blocks = [(loop, np.arange(jm.N_CAL)), (~loop, np.arange(jm.N_CAL, jm.N_CAL + V))]
        costs[name], shift = held_out_cost(J, r, rows, blocks, F_SCALE)
        if name == "joint":
            shifts = shift
    gain = costs["pose_only"] - costs["joint"]
    se = float(np.std(gain, ddof=1) / np.sqrt(len(gain))) if len(gain) > 1 else float("inf")
    return {"joint": float(costs["joint"].sum()), "pose_only": float(costs["pose_only"].sum()),
            "gain": float(gain.mean()), "gain_se": se}, shifts


def _fit_depth_only(st, views, pairs, arms, E, P, noise):
    """The pose-only calibration with its depth factors fitted to the maps (calibration fixed)."""
    V = len(views)
    terms = _terms(st, views, pairs, arms, E, P, noise)
    from scipy.optimize import least_squares

    cols = np.arange(jm.N_CAL, jm.N_CAL + V)

    def f(k):
        th = np.zeros(jm.N_CAL + V)
        th[cols] = k
        return stack(terms[1:], th, jac=False)[0]

    def jac(k):
        th = np.zeros(jm.N_CAL + V)
        th[cols] = k
        return stack(terms[1:], th)[1][:, cols]

    sol = least_squares(f, np.zeros(V), jac=jac, loss="soft_l1", f_scale=F_SCALE, x_scale=0.01, max_nfev=30)
    th = np.zeros(jm.N_CAL + V)
    th[cols] = sol.x
    return jm.perturb(st, th)


def estimate_jointly(views: list, arms: np.ndarray, E: np.ndarray, P: np.ndarray, start, pose_noise: tuple,
                     progress=None, pivot: np.ndarray | None = None, limits: dict | None = None) -> JointFit:
    """The joint weighted estimate from the pose-only ``start`` (:class:`JointState`, kappa zero).

    Args:
        views: (V) point maps in their camera frames (``_pointmaps.camera_frame_views``), one per view.
        arms: (V,) 1 or 2; E: (V, 4, 4) ``T_b_e``; P: (V, 4, 4) the reconstruction's ``T_w_c``.
        pose_noise: the pose-only solve's (rotation rad, position m) noise per view.
        progress: optional callable(str), one line per round.
        pivot: (3,) the pose-only solve's pivot (camera frame, m): the loop compares that point's positions,
            as the pose-only noise model does; None or zeros: the camera centres.
        limits: how far the estimate may move each output from ``start`` and still be a correction of it
            (``_correction.correction_limits`` of the pose-only solve's uncertainty); None: the fixed floors.
    """
    from threadpoolctl import threadpool_limits

    # its dense matrices are small (25 + V columns): BLAS threads cost more to start and synchronise than
    # they give (many times more on a busy machine)
    with threadpool_limits(limits=1, user_api="blas"):
        return _estimate(views, arms, E, P, start, pose_noise, progress, pivot, limits)


def _estimate(views, arms, E, P, start, pose_noise, progress, pivot=None, limits=None) -> JointFit:
    if min(int(np.sum(arms == 1)), int(np.sum(arms == 2))) < 2:
        return JointFit(start, False, f"needs 2 or more point maps per arm, has {int(np.sum(arms == 1))} / "
                                      f"{int(np.sum(arms == 2))}")
    views = StackedViews(views)  # the views' flat arrays are built once for every pair search below
    samples, targets = _sample(views, POINTS_PER_VIEW), _sample(views, TARGETS_PER_VIEW, 1)
    active = ~contradicting_views(views, P, start, samples, targets)
    pivot = None if pivot is None or not np.any(pivot) else np.asarray(pivot, dtype=np.float64)

    def fit_at(level: float, rounds: list):
        noise = {"pose": tuple(pose_noise), "kappa": level, "pair": PAIR_SIGMA0, "pivot": pivot}
        return _fit_rounds(views, arms, E, P, start, noise, samples, targets, active, rounds, progress)

    rounds = []
    st, pairs, noise = fit_at(jm.KAPPA_SIGMA, rounds)
    if st is None:  # pairs: why not
        return JointFit(start, False, pairs, rounds=rounds)
    level = _depth_level(st, views, pairs, arms, E, P, noise)
    if level > jm.KAPPA_SIGMA:
        # the factors spread wider than the prior allows: solved again from the start with the prior at the
        # level they show (at most KAPPA_CAP)
        if progress:
            progress(f"joint estimate: the depth factors spread {level * 100:.2f} % (prior {jm.KAPPA_SIGMA * 100:.2f} %): "
                     f"solving again with that prior")
        again = fit_at(level, rounds)
        if again[0] is not None:
            st, pairs, noise = again
    return _conclude(start, st, views, pairs, arms, E, P, noise, rounds, active, limits)


def _fit_rounds(views, arms, E, P, start, noise, samples, targets, active, rounds: list, progress):
    """The rounds of point pairs from the coarsest radius to convergence, from ``start`` with the noise levels
    ``noise`` (updated in place; each round appended to ``rounds``). Returns ``(state, pairs, noise)``, or
    ``(None, reason, noise)`` when the maps overlap too little."""
    st, pairs = start, None
    schedule = list(RADII) + [RADII[-1]] * MAX_FINE_ROUNDS
    for k, radius in enumerate(schedule):
        pairs = _pairs_at(views, st, samples, targets, radius, active)
        n = 0 if pairs is None else len(pairs)
        if n < MIN_PAIRS:
            return None, (f"the point maps overlap too little: {n} point pairs within {radius * 1e3:.0f} mm "
                          f"(needs {MIN_PAIRS})"), noise
        if "map" not in noise:
            noise["map"] = _initial_map_noise(st, views, pairs)
        st, moved = _round(st, views, pairs, arms, E, P, noise, passes=2 if k >= len(RADII) - 1 else 1)
        after = map_residuals(np.zeros(19), st.kappa, views, st.calibration, pairs)
        rounds.append({"radius_m": radius, "pairs": n, "rms_m": float(np.sqrt(np.mean(after ** 2))), "moved_m": moved,
                       "pair_noise": noise["pair"], "depth_prior": noise["kappa"]})
        if progress:
            progress(f"joint estimate: {radius * 1e3:.0f} mm round, {n} point pairs, moved {moved * 1e3:.2f} mm, "
                     f"loop noise {np.degrees(noise['pose'][0]):.2f} deg / {noise['pose'][1] * 1e3:.1f} mm, "
                     f"maps {np.median(noise['map']) * 1e3:.2f} mm, pair summaries x {noise['pair']:.1f}")
        if k >= len(RADII) - 1 and moved < CONVERGED_M:
            break
    return st, pairs, noise


def _depth_level(st, views, pairs, arms, E, P, noise) -> float:
    """The depth factors' prior level the data show at ``st``: the prior's level times the root of its rows'
    variance factor, at most KAPPA_CAP; the prior's own level unless the factors spread significantly wider
    (their rows' sum of squares above the chi-square quantile ``1 - DEPTH_TEST_P`` of their redundancy)."""
    from scipy.special import chdtri

    r, J = stack(_terms(st, views, pairs, arms, E, P, noise), np.zeros(jm.N_CAL + len(views)))
    ss, dof = _prior_rows(J, r, len(views) + 2)
    if dof <= 0.0 or ss <= chdtri(dof, DEPTH_TEST_P):
        return float(noise["kappa"])
    return float(min(noise["kappa"] * np.sqrt(ss / dof), jm.KAPPA_CAP))


def _conclude(start, st, views, pairs, arms, E, P, noise, rounds, active, limits=None) -> JointFit:
    """Checks, held-out test and covariance of the final estimate."""
    V = len(views)
    zero = np.zeros(19)
    r0 = map_residuals(zero, np.zeros(V), views, start.calibration, pairs)
    r1 = map_residuals(zero, st.kappa, views, st.calibration, pairs)
    arm = np.array([v.arm for v in views])
    fit = JointFit(start, False, noise=_noise_report(noise), residuals_before_m=r0, residuals_after_m=r1,
                   pairs=len(pairs), cross_arm=int(np.sum(arm[pairs.va] != arm[pairs.vb])), rounds=rounds,
                   dropped_views=[int(v) for v in np.flatnonzero(~active)])
    fit.reason = beyond_correction(_outputs(start), _outputs(st), limits or correction_limits(None),
                                   "the joint estimate") or ""
    if fit.reason:
        return fit
    if fit.cross_arm == 0:
        fit.reason = "no point pairs between the two arms' views: T_b1_b2 cannot be refined"
        return fit
    terms = _terms(st, views, pairs, arms, E, P, noise)
    pose_st = _fit_depth_only(start, views, pairs, arms, E, P, noise)
    fit.held_out, shifts = _held_out(terms, _terms(pose_st, views, pairs, arms, E, P, noise), V)
    r, J = stack(terms, np.zeros(jm.N_CAL + V))
    f = _prior_variance_factor(J, r, V + 2)
    fit.noise["depth_factor_spread"] = float(noise["kappa"] * np.sqrt(f))
    fit.covariance = _covariance(J, shifts, V + 2, float(terms[2].sigma[0]) ** 2 * f)
    ho = fit.held_out
    if ho["gain"] <= ho["gain_se"]:
        # the one-standard-error rule: the simpler estimate stands unless the richer one predicts the views
        # left out in turn better by more than the spread of that gain over the views allows to be chance
        fit.reason = (f"views left out in turn are not predicted clearly better by the joint estimate (held-out "
                      f"cost {ho['joint']:.1f} against {ho['pose_only']:.1f} for the pose-only solve; gain per view "
                      f"{ho['gain']:.1f} +- {ho['gain_se']:.1f}, not more than one standard error)")
        return fit
    fit.state, fit.accepted = st, True
    return fit


def _covariance(J: np.ndarray, shifts: np.ndarray, n_prior: int, kappa_var: float) -> np.ndarray:
    """(25 + V, 25 + V) covariance of the corrections: the delete-one-view jackknife's for the calibration
    (views are the independent units; the normal matrix counts a view's correlated residuals as independent
    evidence) plus the depth-factor prior's share (:func:`_prior_share`), the normal matrix's for the depth
    factors, and ``inf`` where the data determine nothing. J: (M, 25 + V) whitened, the prior's ``n_prior``
    rows last; shifts: (V, 25 + V) the estimate's shifts without each view; kappa_var: the depth factors'
    actual variance."""
    C = normal_covariance(J.T @ J)[0]
    jack = jackknife_covariance(shifts[:, :jm.N_CAL]) + _prior_share(C, J[len(J) - n_prior:], kappa_var)
    finite = np.isfinite(np.diag(C)[:jm.N_CAL])
    blk = C[:jm.N_CAL, :jm.N_CAL]
    blk[np.ix_(finite, finite)] = jack[np.ix_(finite, finite)]
    C[:jm.N_CAL, :jm.N_CAL] = blk
    return C


def _prior_rows(J: np.ndarray, r: np.ndarray, n_prior: int) -> tuple[float, float]:
    """``(sum r^2, sum (1 - h_jj))`` over the per-view depth-factor rows: J (M, n) and r (M,) whitened, the
    prior's ``n_prior`` rows last (one per view, then the two arms' means)."""
    rows = slice(len(r) - n_prior, len(r) - 2)
    return float(np.sum(r[rows] ** 2)), float(np.sum(redundancy(J)[0][rows]))


def _prior_variance_factor(J: np.ndarray, r: np.ndarray, n_prior: int) -> float:
    """The per-view depth-factor rows' a-posteriori variance factor, at least 1: how much wider the fitted
    factors spread than the prior says (``sum r^2 / sum (1 - h_jj)`` over those rows, :func:`_prior_rows`)."""
    ss, dof = _prior_rows(J, r, n_prior)
    return max(1.0, ss / max(dof, 1e-9))


def _prior_share(C: np.ndarray, Jp: np.ndarray, kappa_var: float) -> np.ndarray:
    """(25, 25) the calibration's covariance from the depth-factor prior's errors.

    The prior's whitened rows ``Jp`` (V + 2, 25 + V) (one per view, then the two arms' means) belong to no
    view, so the jackknife cannot see their errors. Their pseudo-observation is zero; the truth is each
    view's actual depth factor, of variance ``kappa_var`` (the prior's level times the variance factor of
    :func:`_prior_variance_factor`). For row errors ``e = Jp[:, kappa] kappa`` the estimate moves by
    ``-C Jp^T e`` (``C`` (25 + V, 25 + V) the normal matrix's inverse), hence ``kappa_var G G^T`` with
    ``G = C Jp^T Jp[:, kappa]``."""
    G = np.where(np.isfinite(C), C, 0.0) @ Jp.T @ Jp[:, jm.N_CAL:]
    return kappa_var * (G @ G.T)[:jm.N_CAL, :jm.N_CAL]


def _noise_report(noise: dict) -> dict:
    return {"loop_rotation_deg": float(np.degrees(noise["pose"][0])), "loop_position_mm": noise["pose"][1] * 1e3,
            "map_mm_median": float(np.median(noise["map"]) * 1e3), "map_mm_per_view": (noise["map"] * 1e3).tolist(),
            "pair_summary_noise": noise["pair"], "depth_factor_sigma": noise["kappa"]}


def _outputs(st) -> dict:
    """The outputs of a :class:`calibration._joint.JointState` that ``beyond_correction`` judges."""
    return {"T_e1_c1": st.T_e1_c1, "T_e2_c2": st.T_e2_c2, "T_b1_b2": st.T_b1_b2, "scale": st.scale}
