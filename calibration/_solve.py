"""The Bi-JCR solver on arrays: input checks, outliers, degeneracy, closed form, refinement, uncertainty.

``solve_bijcr`` is the pure-array entry point (no files); ``solve_single_arm`` solves one arm with its own
scale (the "each arm alone" baseline, and a plain hand-eye calibration from a reconstruction).
"""

from __future__ import annotations

import itertools
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import check_shape, inv_T, make_T

from . import _absolute as absm
from ._closed_form import (
    PairMotions,
    average_base_from_world,
    pair_motions,
    park_martin_rotation,
    solve_translations_and_scale,
)
from ._degeneracy import MIN_VIEWS, Finding, analyse_capture
from ._outliers import angle_screen, effective_threshold, worst_view
from ._residuals import pair_residuals, view_residuals
from ._uncertainty import from_covariance, from_samples

METHODS = ("absolute", "paper", "paper-norefine")
#: chosen by measurement (docs/bench/calibration.md): the absolute-pose refinement is more accurate than
#: the paper's pairwise refinement at every noise level and view count tested.
DEFAULT_METHOD = "absolute"
ARM_NAMES = ("primary", "secondary")
COND_ERROR = 1e12  # condition number of the (column-scaled) normal matrix beyond which nothing is determined


class DegenerateCaptureError(InputError):
    """The capture does not determine the calibration (why and which extra pose would fix it are in ``problems``)."""


@dataclass
class CalibrationOptions:
    """Switches and settings of the solver (defaults are what the benchmark measured best).

    Attributes:
        alpha: rotation weight of the paper's loss (the paper does not give its value).
        pairs: "all" pairs ``i < j`` (default) or "consecutive" (the paper's printed form).
        min_pair_angle_deg: pairs rotating less are skipped in the Park–Martin rotation solve.
        refine_iterations: L-BFGS iterations of the paper's refinement.
        reject_outliers: find and drop badly registered views; None = method default (on for "absolute",
            off for the paper's methods, which are reproduced faithfully).
        robust: robust (soft_l1) loss in the absolute refinement.
        robust_scale: knee of the robust loss, in units of the view noise.
        noise_rot_deg, noise_trans_mm: expected noise of one view's camera pose (both, or neither: then it
            is estimated from the residuals).
        outlier_threshold: combined residual (in noise sigmas) above which a view is an outlier.
        outlier_min_rot_deg, outlier_min_trans_mm: a view is never called an outlier below these residuals.
        max_outlier_fraction: never drop more than this fraction of an arm's views.
        on_degenerate: "raise" (DegenerateCaptureError) or "warn" (solve anyway, warnings in the result).
        uncertainty: "jacobian", "jackknife" or "none".
        point_maps: with :func:`calibration.calibrate` on a scene whose reconstruction has point maps,
            refine the joint solve so that the views' point maps, placed by the kinematics, agree
            (``calibration._pointmaps``), and build the cloud from the views placed by the kinematics.
            Arrays-only :func:`solve_bijcr` has no point maps and ignores it.
        estimator: how the point maps are used: "joint" (default: one weighted estimate of the kinematic
            loop and the point maps with per-view depth factors, noise levels from the data and a held-out
            check against the pose-only solve, ``calibration._joint``) or "refine" (the previous estimator:
            an ICP of the 19 calibration numbers with every view placed by the kinematics and the loop left
            out, ``calibration._pointmap_refine``; docs/calibration.md has both measured).
    """

    alpha: float = 0.5
    pairs: str = "all"
    min_pair_angle_deg: float = 1.0
    refine_iterations: int = 100
    reject_outliers: bool | None = None
    robust: bool = True
    robust_scale: float = 2.5
    noise_rot_deg: float | None = None
    noise_trans_mm: float | None = None
    outlier_threshold: float = 5.0
    outlier_min_rot_deg: float = 0.5
    outlier_min_trans_mm: float = 5.0
    max_outlier_fraction: float = 0.34
    on_degenerate: str = "raise"
    uncertainty: str = "jacobian"
    point_maps: bool = True
    estimator: str = "joint"

    def __post_init__(self):
        if self.pairs not in ("all", "consecutive"):
            raise ValueError(f"pairs must be 'all' or 'consecutive', got {self.pairs!r}")
        if self.on_degenerate not in ("raise", "warn"):
            raise ValueError(f"on_degenerate must be 'raise' or 'warn', got {self.on_degenerate!r}")
        if self.estimator not in ("refine", "joint"):
            raise ValueError(f"estimator must be 'refine' or 'joint', got {self.estimator!r}")
        if self.uncertainty not in ("jacobian", "jackknife", "none"):
            raise ValueError(f"uncertainty must be 'jacobian', 'jackknife' or 'none', got {self.uncertainty!r}")
        if (self.noise_rot_deg is None) != (self.noise_trans_mm is None):
            raise ValueError("give both noise_rot_deg and noise_trans_mm, or neither (then the noise is estimated)")
        if not 0.0 <= self.alpha <= 1.0:
            raise ValueError(f"alpha must be in [0, 1], got {self.alpha}")


@dataclass
class CalibrationResult:
    """Everything Bi-JCR recovers (frames as in the contract; metres, radians).

    Attributes:
        method: solver used (one of :data:`METHODS`).
        scale: metric = scale * reconstruction units.
        T_e1_c1, T_e2_c2: (4, 4) hand-eye transforms (camera in end effector).
        T_b1_w, T_b2_w: (4, 4) scaled reconstruction frame in each base (``x_b = T_b_w (scale * x_w)``).
        T_b1_b2: (4, 4) secondary base in the primary base.
        views_used: per arm name, the row indices (into the solver's input arrays) used.
        views_dropped: per arm name, ``{"index", "image", "reason"}`` for each dropped view.
        images: per arm name, the image keys of the input rows (or None).
        residuals: mean AX=XB residuals over the pairs used (contract keys ``rotation_rad``,
            ``translation_m``) plus per-arm, consecutive-pair and absolute breakdowns.
        uncertainty: 1-sigma uncertainty of each output (see ``_uncertainty``).
        noise: per-view noise used to weight the absolute problem (estimated or given): rotation, and
            position of the pivot point ``pivot_m`` (camera frame; zeros = the camera centre), about which the
            views' pose errors were found to turn (``_absolute.estimate_pivot``).
        warnings: human-readable warnings (degeneracy, dropped views, ...).
        info: timings and solver details.
        diagnostics: arrays for the figures that do not go to calibration.json (the point-map refinement's
            per-pair distances before and after).
    """

    method: str
    scale: float
    T_e1_c1: np.ndarray
    T_e2_c2: np.ndarray
    T_b1_w: np.ndarray
    T_b2_w: np.ndarray
    T_b1_b2: np.ndarray
    views_used: dict
    views_dropped: dict
    images: dict | None
    residuals: dict
    uncertainty: dict
    noise: dict
    warnings: list = field(default_factory=list)
    info: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict, repr=False)

    @property
    def hand_eye(self) -> tuple[np.ndarray, np.ndarray]:
        return self.T_e1_c1, self.T_e2_c2

    def to_json(self, scene_name: str = "") -> dict:
        """calibration.json content: the contract keys plus extras (uncertainty, views, method, warnings)."""
        return {
            "format": 1,
            "scene": scene_name,
            "scale": self.scale,
            "T_e1_c1": self.T_e1_c1, "T_e2_c2": self.T_e2_c2,
            "T_b1_w": self.T_b1_w, "T_b2_w": self.T_b2_w, "T_b1_b2": self.T_b1_b2,
            "views_used": {k: len(v) for k, v in self.views_used.items()},
            "residuals": self.residuals,
            "method": self.method,
            "uncertainty": self.uncertainty,
            "views": {k: {"used": [self._key(k, i) for i in v], "dropped": self.views_dropped.get(k, [])}
                      for k, v in self.views_used.items()},
            "noise": self.noise,
            "warnings": self.warnings,
            "info": self.info,
        }

    def _key(self, arm: str, i: int):
        return self.images[arm][i] if self.images and arm in self.images else int(i)


# ----------------------------------------------------------------------------------------------- inputs

def _check_arm(name: str, E, C, sources: dict, images: list | None) -> tuple[np.ndarray, np.ndarray]:
    m = 1 if name == "primary" else 2
    kE, kC = f"T_b{m}_e", f"T_w_c{m}"
    fE, fC = sources.get(kE, kE), sources.get(kC, kC)
    problems = []
    try:
        E = check_shape(kE, np.asarray(E, dtype=np.float64), (None, 4, 4))
    except ValueError as e:
        raise InputError(Problem(fE, kE, str(e), "pass one 4x4 end-effector pose per view, shape (N, 4, 4)")) from None
    try:
        C = check_shape(kC, np.asarray(C, dtype=np.float64), (None, 4, 4))
    except ValueError as e:
        raise InputError(Problem(fC, kC, str(e), "pass one 4x4 camera pose per view, shape (N, 4, 4)")) from None
    if len(E) != len(C):
        raise InputError(Problem(fC, kC, f"{len(C)} camera poses for {len(E)} end-effector poses of the {name} arm",
                                 "give the camera pose of the same image for every end-effector pose: match rows by image "
                                 "key (Reconstruction.rows_for)"))
    for f, k, T in ((fE, kE, E), (fC, kC, C)):
        for i in range(len(T)):
            where = f"{k}[{i}]" + (f" ({images[i]})" if images else "")
            R = T[i, :3, :3]
            if not np.all(np.isfinite(T[i])):
                problems.append(Problem(f, where, "contains NaN or inf", "drop this view or re-measure it"))
            elif not np.allclose(T[i, 3], [0, 0, 0, 1], atol=1e-6):
                problems.append(Problem(f, where, "bottom row is not 0 0 0 1", "pass homogeneous rigid transforms"))
            elif np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) <= 0:
                problems.append(Problem(f, where, f"rotation is not orthonormal (max |R^T R - I| = "
                                        f"{np.abs(R.T @ R - np.eye(3)).max():.1e}, det {np.linalg.det(R):.3f})",
                                        "re-orthonormalise it (bimanual_app.transforms.project_to_SO3) or check the "
                                        "quaternion order (qx, qy, qz, qw)"))
    if problems:
        raise InputError(problems)
    if len(E) < MIN_VIEWS:
        raise InputError(Problem(fC, kC, f"only {len(E)} usable view(s) of the {name} arm; at least {MIN_VIEWS} are needed",
                                 f"capture more {name} views (6 or more, wrist tilted 20-40 deg about different axes) "
                                 "and re-run 'bijcr reconstruct'"))
    return E, C


def _handle_findings(findings: list[Finding], opts: CalibrationOptions, warnings: list, seen: set) -> None:
    errors = []
    for f in findings:
        if (f.arm, f.code, f.severity) in seen:
            continue
        seen.add((f.arm, f.code, f.severity))
        if f.severity == "error" and opts.on_degenerate == "raise":
            errors.append(Problem("capture", f"{f.arm} arm: {f.code}", f.message, f.fix))
        else:
            warnings.append(f"{f.arm} arm: {f.message} -> fix: {f.fix}")
    if errors:
        raise DegenerateCaptureError(errors)


# ---------------------------------------------------------------------------------------------- stages

def _closed_form(E, C, kept, motions, opts) -> tuple[absm.AbsoluteState, dict]:
    pms = [pm.subset(k) for pm, k in zip(motions, kept)]
    R_X = []
    for m, pm in enumerate(pms):
        try:
            R_X.append(park_martin_rotation(pm.a, pm.b, np.deg2rad(opts.min_pair_angle_deg))[0])
        except ValueError as e:
            raise DegenerateCaptureError(Problem("capture", f"{ARM_NAMES[m] if len(pms) == 2 else 'arm'}: rotation",
                                                 str(e), "add views rotated 20-40 deg about different axes")) from e
    lin = solve_translations_and_scale(pms, R_X)
    if not np.isfinite(lin.scale) or lin.scale <= 0:
        raise DegenerateCaptureError(Problem("capture", "scale", f"the scale came out as {lin.scale:.3g} (must be > 0): "
                                             "the camera motions do not match the robot motions",
                                             "check that each image key is paired with its own pose and that both arms "
                                             "moved the camera by 10 cm or more"))
    X = [make_T(R, t) for R, t in zip(R_X, lin.t_X)]
    W = [average_base_from_world(E[m][k], X[m], C[m][k], lin.scale) for m, k in enumerate(kept)]
    return absm.AbsoluteState(X, W, lin.scale), {"scale_closed_form": lin.scale, "linear_rms_m": lin.rms}


SMALL_CAPTURE = 6  # views per arm at or below which the start is also tried without each single view


def _robust_start(E, C, kept, motions, opts) -> tuple[absm.AbsoluteState, dict, list]:
    """Closed-form start that one bad view cannot capture.

    With few views (or when the closed form on all views fails), a single badly registered view is a large
    share of the pairs and can drag the closed form far enough that the robust fit starts in the wrong
    basin. Then the closed forms leaving out one view per arm (all combinations, at most 7 x 7) are tried
    too, and the start whose residuals over ALL views have the least median (LMedS: a minority of bad views
    cannot pull it) is kept. Returns ``(start, info, left_out)``: per arm the view that start left out, or None.
    """
    try:
        st, info = _closed_form(E, C, kept, motions, opts)
        if min(len(k) for k in kept) > SMALL_CAPTURE:
            return st, info, [None] * len(kept)
        cands = [(st, info)]
        combos = [(None,) * len(kept)]
    except DegenerateCaptureError as err:
        first_error, cands, combos = err, [], []
    # every combination of leaving out nothing or one view per arm (the arms share the scale, so a bad view
    # in each arm must be left out together)
    options = [[None] + (list(k) if len(k) - 1 >= MIN_VIEWS else []) for k in kept]
    for combo in itertools.product(*options):
        if all(v is None for v in combo):
            continue
        k2 = [k if v is None else k[k != v] for k, v in zip(kept, combo)]
        try:
            cands.append(_closed_form(E, C, k2, motions, opts))
            combos.append(combo)
        except DegenerateCaptureError:
            continue
    if not cands:
        raise first_error
    Es, Cs = _sub(E, C, kept)
    med = []
    for st, _ in cands:
        # each candidate's T_b_w comes from its own views; its residuals are judged on all views
        rot, trans = absm.raw_residuals(Es, Cs, st)
        med.append((np.median(np.linalg.norm(np.concatenate(rot), axis=1)),
                    np.median(np.linalg.norm(np.concatenate(trans), axis=1))))
    med = np.array(med) + 1e-15
    score = med[:, 0] / med[:, 0].min() + med[:, 1] / med[:, 1].min()
    best = int(np.argmin(score))
    sigma_all = None
    if combos and all(v is None for v in combos[0]):  # the closed form on all views succeeded
        rot, trans = absm.raw_residuals(Es, Cs, cands[0][0])
        sigma_all = absm.estimate_noise(rot, trans, n_params=12 * len(kept) + 1)
    gain = None
    if combos and all(v is None for v in combos[0]):
        gain = float(np.max(med[0] / med[best]))  # how much leaving views out shrinks the median residual
    st, info = cands[best]
    info = dict(info, start_candidates=len(cands), sigma_all=sigma_all, start_gain=gain)
    return st, info, list(combos[best])


def _sub(E, C, kept):
    return [e[k] for e, k in zip(E, kept)], [c[k] for c, k in zip(C, kept)]


class _Views:
    """The views each arm still uses (``kept``) and the ones dropped so far, with the reason for each."""

    def __init__(self, N: list[int], images: list | None):
        self.N = N
        self.kept = [np.arange(n) for n in N]
        self.dropped: list[list[dict]] = [[] for _ in N]
        self.images = images

    def drop(self, m: int, v: int, reason: str) -> None:
        self.kept[m] = self.kept[m][self.kept[m] != v]
        self.dropped[m].append({"index": int(v), "image": self.images[m][v] if self.images else None,
                                "reason": reason})


def _screen_angles(all_motions: list, views: _Views, opts: CalibrationOptions) -> None:
    """Stage 1: drop views whose end-effector and camera rotation angles disagree (no fit needed)."""
    for m in range(len(views.N)):
        idx_views = views.kept[m].copy()
        score, flag = angle_screen(all_motions[m], idx_views)
        budget = max(min(int(np.floor(opts.max_outlier_fraction * views.N[m])), len(idx_views) - MIN_VIEWS), 0)
        for idx in np.argsort(-score)[:budget]:
            if flag[idx]:
                views.drop(m, int(idx_views[idx]), f"end-effector and camera rotation angles disagree by "
                                                   f"{score[idx]:.1f} deg (median over its pairs)")


def _test_left_out(E, C, views: _Views, st, left_out: list, given_sigma, opts: CalibrationOptions):
    """Test each view the least-median start left out against a fit without it; drop it if it is an outlier.

    With few views a robust fit over all of them can spread one bad view's error over the good ones, so the
    left-out view is judged against the start fitted without it. Returns the state to continue from.
    """
    if not any(v is not None for v in left_out):
        return st
    own = [k if v is None else k[k != v] for k, v in zip(views.kept, left_out)]
    Eo, Co = _sub(E, C, own)
    st_own, own_info = absm.refine_absolute(Eo, Co, st, sigma=given_sigma, robust=False)
    for m, v in enumerate(left_out):
        if v is None:
            continue
        d = absm.deleted_score(Eo, Co, st_own, own_info["sigma"], E[m][v], C[m][v], m)
        rot, trans = view_residuals(E[m][v:v + 1], C[m][v:v + 1], st_own.X[m], st_own.W[m], st_own.scale)
        r, t = float(np.linalg.norm(rot)), float(np.linalg.norm(trans))
        # conservative: the degrees of freedom of this arm's own views (with 3 of them the prediction
        # of a fourth is the weakest link, and a good view must not be dropped from so few)
        thr = effective_threshold(opts.outlier_threshold, 6 * len(own[m]) - 12)
        if d > thr and (r > np.deg2rad(opts.outlier_min_rot_deg) or t > opts.outlier_min_trans_mm / 1000):
            views.drop(m, v, f"residual {np.rad2deg(r):.1f} deg / {1000 * t:.0f} mm ({d:.1f} sigma, prediction "
                             "error included) against a fit of the other views (least-median start)")
            st = st_own
    return st


def _drop_worst_views(E, C, views: _Views, st, given_sigma, opts: CalibrationOptions):
    """Stage 2: robust absolute fits, dropping the worst view while it is an outlier. Returns ``(st, abs_info)``."""
    K = len(E)
    while True:
        Es, Cs = _sub(E, C, views.kept)
        st, abs_info = absm.refine_absolute(Es, Cs, st, sigma=given_sigma, robust=True, f_scale=opts.robust_scale)
        sig = abs_info["sigma"]
        scores, _ = absm.studentized_scores(Es, Cs, st, sig)
        rot, trans = absm.raw_residuals(Es, Cs, st)
        res = [np.stack([np.linalg.norm(r, axis=1), np.linalg.norm(t, axis=1)], axis=1) for r, t in zip(rot, trans)]
        thr = effective_threshold(opts.outlier_threshold, 6 * sum(len(k) for k in views.kept) - (12 * K + 1))
        w = worst_view(scores, res, views.kept, views.N, thr, np.deg2rad(opts.outlier_min_rot_deg),
                       opts.outlier_min_trans_mm / 1000, MIN_VIEWS, opts.max_outlier_fraction)
        if w is None:
            return st, abs_info
        m, v, d = w
        rot, trans = view_residuals(E[m][v:v + 1], C[m][v:v + 1], st.X[m], st.W[m], st.scale)
        views.drop(m, v, f"residual {np.rad2deg(np.linalg.norm(rot)):.1f} deg / "
                         f"{1000 * np.linalg.norm(trans):.0f} mm ({d:.1f} sigma) against the robust fit of the other views")


def _refine(method: str, Es, Cs, pms, st, abs_info: dict, reject: bool, given_sigma, opts: CalibrationOptions,
            info: dict):
    """The method's refinement on the kept views. Returns ``(st, sigma)``; sigma is None when not estimated."""
    if method == "absolute":
        if not reject or not opts.robust:
            st, abs_info = absm.refine_absolute(Es, Cs, st, sigma=given_sigma, robust=opts.robust,
                                                f_scale=opts.robust_scale)
        info.update({"absolute_nfev": abs_info["nfev"], "absolute_passes": abs_info["passes"]})
        return st, abs_info["sigma"]
    if method == "paper":
        from ._paper_refine import refine_paper

        X, s, pinfo = refine_paper(pms, st.X, st.scale, alpha=opts.alpha, max_iter=opts.refine_iterations)
        W = [average_base_from_world(e, x, c, s) for e, x, c in zip(Es, X, Cs)]
        info.update(pinfo)
        return absm.AbsoluteState(X, W, s), given_sigma
    return st, given_sigma


def _uncertainty_of(E, C, views: _Views, names, method, opts: CalibrationOptions, st, sigma, info: dict,
                    warnings: list, seen: set) -> dict:
    """1-sigma uncertainty of every output (``opts.uncertainty``); flags an ill-conditioned problem."""
    if opts.uncertainty == "none":
        return {}
    K = len(E)
    Es, Cs = _sub(E, C, views.kept)
    cov, cond, vf = absm.covariance(Es, Cs, st, sigma)
    info.update({"condition_number": cond, "variance_factor": vf})
    if cond > COND_ERROR:
        _handle_findings([Finding("both", "error", "ill_conditioned",
                                  f"the calibration is not determined by these views (condition number {cond:.1e})",
                                  "add views rotated 20-40 deg about different axes and moved 10-20 cm apart")],
                         opts, warnings, seen)
    he_names = ("T_e1_c1", "T_e2_c2") if K == 2 else ("T_e_c",)
    if opts.uncertainty == "jacobian":
        unc = from_covariance(st, cov, he_names)
        unc["estimator"] = "jacobian"
    else:
        unc = _jackknife(E, C, views.kept, names, method, opts, st, he_names)
        unc["estimator"] = "jackknife"
    unc["note"] = "1-sigma"
    return unc


def _result_warnings(views: _Views, names, unc: dict, opts: CalibrationOptions, warnings: list) -> None:
    """Append the warnings about dropped views and a poorly determined scale."""
    for m, dropped in enumerate(views.dropped):
        if dropped:
            warnings.append(f"{names[m]} arm: dropped {len(dropped)} outlier view(s): "
                            + ", ".join(str(d["image"] if d["image"] is not None else d["index"]) for d in dropped))
    if opts.uncertainty != "none" and "scale" in unc and unc["scale"]["percent"] > 10:
        warnings.append(f"the scale is poorly determined (+-{unc['scale']['percent']:.0f}%): add views that move the "
                        "cameras 10-20 cm apart")


def _start(E, C, views: _Views, motions, reject: bool, given_sigma, opts: CalibrationOptions):
    """The start of the refinement: the least-median closed form (its left-out views tested) when outliers are
    rejected, else the closed form on all views. Returns ``(st, info)``."""
    if not reject:
        return _closed_form(E, C, views.kept, motions, opts)
    st, info, left_out = _robust_start(E, C, views.kept, motions, opts)
    return _test_left_out(E, C, views, st, left_out, given_sigma, opts), info


def _solve(E: list, C: list, names: tuple, method: str, opts: CalibrationOptions, images: list | None) -> dict:
    """Core over K arms (1 or 2) sharing one scale. Returns a dict of everything the result needs."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    t0 = time.perf_counter()
    K = len(E)
    warnings: list[str] = []
    seen: set = set()
    consecutive = opts.pairs == "consecutive"
    motions = [pair_motions(e, c, consecutive=consecutive) for e, c in zip(E, C)]
    views = _Views([len(e) for e in E], images)
    reject = opts.reject_outliers if opts.reject_outliers is not None else method == "absolute"
    given_sigma = None if opts.noise_rot_deg is None else (np.deg2rad(opts.noise_rot_deg), opts.noise_trans_mm / 1000)

    def check_capture():
        _handle_findings(analyse_capture({names[m]: E[m][views.kept[m]] for m in range(K)}), opts, warnings, seen)

    if reject:
        _screen_angles(motions if not consecutive else [pair_motions(e, c) for e, c in zip(E, C)], views, opts)
    check_capture()
    st, info = _start(E, C, views, motions, reject, given_sigma, opts)
    t_closed = time.perf_counter() - t0
    abs_info: dict = {}
    if reject:
        st, abs_info = _drop_worst_views(E, C, views, st, given_sigma, opts)
        check_capture()
        if method != "absolute":  # the paper's methods restart from the closed form on the kept views
            st, info = _closed_form(E, C, views.kept, motions, opts)
    Es, Cs = _sub(E, C, views.kept)
    pms = [pm.subset(k) for pm, k in zip(motions, views.kept)]
    st, sigma = _refine(method, Es, Cs, pms, st, abs_info, reject, given_sigma, opts, info)
    if sigma is None:
        sigma = absm.estimate_noise(*absm.raw_residuals(Es, Cs, st), n_params=12 * K + 1)
    t_solve = time.perf_counter() - t0
    unc = _uncertainty_of(E, C, views, names, method, opts, st, sigma, info, warnings, seen)
    res = _residual_summary(E, C, views.kept, pms, st, names)
    noise = {"rotation_deg": float(np.rad2deg(sigma[0])), "translation_mm": float(sigma[1] * 1000),
             "pivot_m": [0.0, 0.0, 0.0] if st.pivot is None else [float(v) for v in st.pivot],
             "source": "given" if given_sigma is not None else "estimated from the residuals"}
    _result_warnings(views, names, unc, opts, warnings)
    info.update({"time_closed_form_s": t_closed, "time_solve_s": t_solve, "time_total_s": time.perf_counter() - t0})
    return {"state": st, "kept": views.kept, "dropped": views.dropped, "residuals": res, "uncertainty": unc,
            "noise": noise, "warnings": warnings, "info": info}


def _jackknife(E, C, kept, names, method, opts, st, he_names) -> dict:
    sub_opts = CalibrationOptions(**{**asdict(opts), "reject_outliers": False, "uncertainty": "none",
                                     "on_degenerate": "warn"})
    samples = []
    for m in range(len(E)):
        for v in kept[m]:
            k2 = [k if mm != m else k[k != v] for mm, k in enumerate(kept)]
            try:
                r = _solve([e[k] for e, k in zip(E, k2)], [c[k] for c, k in zip(C, k2)], names, method, sub_opts, None)
            except (InputError, ValueError):
                continue
            s = r["state"]
            d = {he_names[mm]: s.X[mm] for mm in range(len(E))}
            d["scale"] = s.scale
            if len(E) == 2:
                d["T_b1_b2"] = s.W[0] @ inv_T(s.W[1])
            samples.append(d)
    ref = {he_names[mm]: st.X[mm] for mm in range(len(E))}
    ref["scale"] = st.scale
    if len(E) == 2:
        ref["T_b1_b2"] = st.W[0] @ inv_T(st.W[1])
    return from_samples(ref, samples)


def _residual_summary(E, C, kept, pms: list[PairMotions], st, names) -> dict:
    rot, tr, per_arm = [], [], {}
    for m, pm in enumerate(pms):
        r, t = pair_residuals(pm, st.X[m], st.scale)
        rot.append(r)
        tr.append(t)
        cons = pair_motions(E[m][kept[m]], C[m][kept[m]], consecutive=True)
        rc, tc = pair_residuals(cons, st.X[m], st.scale)
        vr, vt = view_residuals(E[m][kept[m]], C[m][kept[m]], st.X[m], st.W[m], st.scale)
        per_arm[names[m]] = {
            "rotation_rad": float(r.mean()), "translation_m": float(t.mean()), "pairs": int(len(r)),
            "consecutive_rotation_rad": float(rc.mean()), "consecutive_translation_m": float(tc.mean()),
            "absolute_rms_rotation_deg": float(np.rad2deg(np.sqrt(np.mean(np.sum(vr ** 2, 1))))),
            "absolute_rms_translation_mm": float(1000 * np.sqrt(np.mean(np.sum(vt ** 2, 1)))),
        }
    r, t = np.concatenate(rot), np.concatenate(tr)
    return {"rotation_rad": float(r.mean()), "translation_m": float(t.mean()), "per_arm": per_arm,
            "note": "mean AX=XB residuals over all pairs of the views used"}


# ------------------------------------------------------------------------------------------------ API

def solve_bijcr(T_b1_e: np.ndarray, T_w_c1: np.ndarray, T_b2_e: np.ndarray, T_w_c2: np.ndarray,
                method: str = DEFAULT_METHOD, options: CalibrationOptions | None = None,
                images: tuple[list[str], list[str]] | None = None, sources: dict | None = None) -> CalibrationResult:
    """Bi-JCR on arrays: both hand-eye transforms, the shared scale, both ``T_b_w`` and ``T_b1_b2``.

    Args:
        T_b1_e: (N1, 4, 4) primary end-effector poses in b1 (metres).
        T_w_c1: (N1, 4, 4) primary camera poses in the reconstruction frame w (its own scale), same rows.
        T_b2_e: (N2, 4, 4) secondary end-effector poses in b2.
        T_w_c2: (N2, 4, 4) secondary camera poses in w.
        method: "absolute" (default), "paper" or "paper-norefine".
        options: :class:`CalibrationOptions`.
        images: optional image keys of the rows of each arm (used in messages and the report).
        sources: optional ``{"T_b1_e": "primary/ee_poses.csv", ...}`` file names for error messages.

    Raises:
        InputError: bad arrays (shape, mismatched rows, non-finite, non-orthonormal, < 3 views).
        DegenerateCaptureError: the views do not determine the calibration (with ``on_degenerate="raise"``).
    """
    opts = options or CalibrationOptions()
    sources = sources or {}
    im = list(images) if images is not None else [None, None]
    E1, C1 = _check_arm("primary", T_b1_e, T_w_c1, sources, im[0])
    E2, C2 = _check_arm("secondary", T_b2_e, T_w_c2, sources, im[1])
    r = _solve([E1, E2], [C1, C2], ARM_NAMES, method, opts, images)
    st = r["state"]
    return CalibrationResult(
        method=method, scale=float(st.scale), T_e1_c1=st.X[0], T_e2_c2=st.X[1], T_b1_w=st.W[0], T_b2_w=st.W[1],
        T_b1_b2=st.W[0] @ inv_T(st.W[1]),
        views_used={n: [int(v) for v in k] for n, k in zip(ARM_NAMES, r["kept"])},
        views_dropped={n: d for n, d in zip(ARM_NAMES, r["dropped"])},
        images={n: list(i) for n, i in zip(ARM_NAMES, images)} if images is not None else None,
        residuals=r["residuals"], uncertainty=r["uncertainty"], noise=r["noise"], warnings=r["warnings"],
        info=r["info"])


def solve_single_arm(T_b_e: np.ndarray, T_w_c: np.ndarray, method: str = DEFAULT_METHOD,
                     options: CalibrationOptions | None = None) -> dict:
    """One arm alone, with its own scale: ``{"T_e_c", "scale", "T_b_w", "uncertainty", "residuals", ...}``.

    Args:
        T_b_e: (N, 4, 4) end-effector poses; T_w_c: (N, 4, 4) camera poses in w, same rows.
    """
    opts = options or CalibrationOptions()
    E, C = _check_arm("primary", T_b_e, T_w_c, {"T_b1_e": "T_b_e", "T_w_c1": "T_w_c"}, None)
    r = _solve([E], [C], ("arm",), method, opts, None)
    st = r["state"]
    return {"T_e_c": st.X[0], "scale": float(st.scale), "T_b_w": st.W[0], "views_used": [int(v) for v in r["kept"][0]],
            "views_dropped": r["dropped"][0], "uncertainty": r["uncertainty"], "residuals": r["residuals"],
            "warnings": r["warnings"], "info": r["info"]}
