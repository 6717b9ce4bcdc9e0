"""Joint refinement on absolute poses (past the paper).

For every view i of arm m: ``T_b_e(i) X_m = T_bm_w P_i(s)`` — the camera pose from the kinematics must equal
the camera pose from the reconstruction, scaled by the ONE shared scale and placed by the arm's
``T_b_w``. Unknowns: ``X_m``, ``T_bm_w`` for each arm and ``s`` (12 K + 1). Unlike the pairwise ``AX = XB``
form, every view enters once, so view errors are not correlated across residuals and the estimate is the
maximum-likelihood one under independent per-view noise.

Residuals are whitened by the expected noise of the inputs (rotation in rad, position in m) — given by
the caller, or estimated from the residuals themselves (variance components, re-estimated each pass) —
so no hand-picked rotation/translation weight is needed. The robust loss is scipy's ``soft_l1``
(pseudo-Huber) with ``f_scale`` in units of that noise: quadratic (maximum likelihood) for inliers, linear
growth for the rest, smooth and nearly convex so trust-region steps stay reliable; gross outlier views are
removed explicitly beforehand (``_outliers``), the robust loss handles what is left.

Positions are compared at a *pivot* point fixed in the camera frame (:func:`estimate_pivot`), not
necessarily at the camera centre. An image pins the view of the scene far better than the camera's pose:
turning the camera about a scene point it looks at (moving its centre on a sphere around that point)
changes the image least, so a reconstruction's pose errors lie mostly along that direction. The camera
centre's error is then ``l x dphi`` for a rotation error ``dphi`` about the point ``l`` (camera frame),
strongly correlated with the rotation error, while the position of ``l`` itself is well determined.
Whitening the centre's residual as independent of the rotation's would count one error twice and let the
positions (through ``T_b_w``'s rotation) pull the hand-eye rotations; the residual of the pivot's position
is close to independent of the rotation residual. The pivot is estimated once, after a first fit that
compares camera centres, by regressing the views' leave-one-out centre residuals on their rotation
residuals (re-estimating it from a fit that already compares pivot positions would confirm any pivot:
that fit shapes the centre residuals into ``l x r``), and used only when they show the coupling clearly
(an F test); with no coupling (errors about the camera centre) positions stay compared at the centre.

Parameters are local perturbations around the starting point: ``R = exp(dphi) R0``, ``t = t0 + dt``,
``s = s0 (1 + ds)``; the covariance in these coordinates is what ``_uncertainty`` propagates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from bimanual_app.transforms import make_T, skew, so3_exp, so3_log

from ._residuals import view_residuals

# median of a chi-square with 3 degrees of freedom: median(|r|^2) / 2.366 estimates sigma^2 per component
_CHI2_3_MEDIAN = 2.3660
SIGMA_FLOOR_ROT = 1.745e-4  # rad (0.01 deg): no camera pose is known better than the arm itself
SIGMA_FLOOR_TRANS = 1e-4    # m (0.1 mm)
#: metres of camera-position error that typically come with one radian of camera-rotation error in a
#: reconstruction of a table-top scene seen from 0.2-0.5 m (bimanual_app.synth's levels: 0.34-0.48 m);
#: used only when one of the two noises cannot be estimated (too few views)
PRIOR_LEVER = 0.4
MIN_REDUNDANCY = 3.0


@dataclass
class AbsoluteState:
    """A point of the absolute problem: per arm ``X`` (4, 4) and ``T_b_w`` (4, 4); shared ``scale``.

    ``pivot`` (3,) is part of the noise model, not an unknown: the point in the camera frame (m) whose
    position the residuals compare (zeros: the camera centre; None: the camera centre, not yet estimated,
    :func:`refine_absolute` estimates it; see :func:`estimate_pivot`).
    """

    X: list
    W: list
    scale: float
    pivot: np.ndarray | None = None

    def perturbed(self, x: np.ndarray) -> AbsoluteState:
        """Apply local coordinates ``x`` (12 K + 1,): per arm [dphi_X, dt_X, dphi_W, dt_W], then ds."""
        X, W = [], []
        for m in range(len(self.X)):
            d = x[12 * m:12 * m + 12]
            X.append(make_T(so3_exp(d[0:3]) @ self.X[m][:3, :3], self.X[m][:3, 3] + d[3:6]))
            W.append(make_T(so3_exp(d[6:9]) @ self.W[m][:3, :3], self.W[m][:3, 3] + d[9:12]))
        return AbsoluteState(X, W, self.scale * (1.0 + x[-1]), self.pivot)


def raw_residuals(T_b_e: list, T_w_c: list, st: AbsoluteState) -> tuple[list, list]:
    """Per arm (N_m, 3) rotation residuals (rad) and (N_m, 3) position residuals of the pivot point (m)."""
    rot, trans = [], []
    for E, P, X, W in zip(T_b_e, T_w_c, st.X, st.W):
        r, t = view_residuals(E, P, X, W, st.scale, st.pivot)
        rot.append(r)
        trans.append(t)
    return rot, trans


def estimate_noise(rot: list, trans: list, n_params: int = 0) -> tuple[float, float]:
    """Robust pooled noise (sigma_rot rad, sigma_trans m per component) from residual vectors.

    Median-based (insensitive to a few bad views), with a degrees-of-freedom correction for the
    parameters fitted to the same residuals.
    """
    r = np.concatenate(rot)
    t = np.concatenate(trans)
    m = 6 * len(r)
    dof = m / max(m - n_params, 1) if m > n_params else 1.0
    sr = np.sqrt(np.median(np.sum(r ** 2, axis=1)) / _CHI2_3_MEDIAN * dof)
    stt = np.sqrt(np.median(np.sum(t ** 2, axis=1)) / _CHI2_3_MEDIAN * dof)
    return max(float(sr), SIGMA_FLOOR_ROT), max(float(stt), SIGMA_FLOOR_TRANS)


def variance_components(T_b_e: list, T_w_c: list, st: AbsoluteState, sigma: tuple[float, float],
                        iterations: int = 3) -> tuple[float, float]:
    """Noise (rotation rad, position m) of a fitted state by variance-component estimation, robustly.

    Each residual component j of type c (rotation or position) has redundancy ``1 - h_jj`` (diagonal of the
    hat matrix): a view that pins parameters on its own leaves residuals far smaller than the noise, which
    a plain median of residuals would mistake for a quiet measurement. Per view and type,
    ``q = sum r_j^2 / sum (1 - h_jj)`` estimates that type's variance; the median over views (robust to a
    few bad views; Wilson-Hilferty median correction for ~3 dof) updates sigma_c, iterated because the hat
    matrix depends on the weights.
    """
    sig = np.array(sigma, dtype=np.float64)
    n_views = [len(e) for e in T_b_e]
    for _ in range(iterations):
        r = whitened(T_b_e, T_w_c, st, tuple(sig))
        J = jacobian(T_b_e, T_w_c, st, tuple(sig))
        A = np.linalg.pinv(J.T @ J)
        red = 1.0 - np.einsum("ij,jk,ik->i", J, A, J)
        q = [[], []]
        for _, _, sl in _view_blocks(n_views):
            rr, dd = r[sl] ** 2, red[sl]
            for c in range(2):
                den = dd[3 * c:3 * c + 3].sum()
                if den > 0.3:  # a view whose residuals of this type are almost fully absorbed says nothing
                    q[c].append(rr[3 * c:3 * c + 3].sum() / den)
        k = 3.0
        corr = (1 - 2 / (9 * k)) ** 3
        new = sig.copy()
        total = [sum(red[sl][3 * c:3 * c + 3].sum() for _, _, sl in _view_blocks(n_views)) for c in range(2)]
        for c in range(2):
            if q[c]:
                new[c] = sig[c] * np.sqrt(np.median(q[c]) / corr)
        # a type whose residuals the parameters almost fully absorb (very few views) cannot show its noise:
        # then it follows the other type through the usual ratio of a camera-pose error (PRIOR_LEVER)
        if total[1] < MIN_REDUNDANCY <= total[0]:
            new[1] = max(new[1], PRIOR_LEVER * new[0])
        elif total[0] < MIN_REDUNDANCY <= total[1]:
            new[0] = max(new[0], new[1] / PRIOR_LEVER)
        new = np.maximum(new, [SIGMA_FLOOR_ROT, SIGMA_FLOOR_TRANS])
        done = np.all(np.abs(np.log(new / sig)) < 0.02)
        sig = new
        if done:
            break
    return float(sig[0]), float(sig[1])


#: the pivot is used when the regression explains the centre residuals at this significance (F test)
PIVOT_SIGNIFICANCE = 1e-4
#: a pivot farther than this from the camera (m) is no scene point a wrist camera looks at: not used
MAX_PIVOT_M = 5.0
#: residual degrees of freedom (6 N - parameters) below which the pivot is not estimated: with fewer, the
#: three numbers of the regression would fit the little the parameters leave of the residuals
PIVOT_MIN_REDUNDANCY = 20
PIVOT_HUBER = 2.0  # Huber knee of the pivot regression, in robust spreads of a view's residual


def estimate_pivot(T_b_e: list, T_w_c: list, st: AbsoluteState, sigma: tuple[float, float] | None = None
                   ) -> np.ndarray:
    """The point (3,) in the camera frame (m) about which the views' pose errors turn, or zeros.

    Model per view: camera-centre residual ``t_c = l x r + u`` in the camera frame, ``r`` the rotation
    residual, ``u`` the pivot's own position error, independent of ``r`` (module docstring); ``l`` is fitted
    by :func:`pivot_regression` over all views. The regression uses each view's deleted residual (against
    the fit without that view, :func:`_deleted_residuals`): the fit's own residuals are shaped by the fit
    (``T_b_w``'s rotation moves a view's rotation and position residuals together; a view that pins
    parameters alone keeps little of its error), so they understate a real coupling and show some where
    there is none. ``l`` is returned only with at least ``PIVOT_MIN_REDUNDANCY`` residual degrees of
    freedom, when it explains the centre residuals significantly (``PIVOT_SIGNIFICANCE``) and lies within
    ``MAX_PIVOT_M``; otherwise zeros (the camera centre).

    Args:
        T_b_e, T_w_c: per arm (N_m, 4, 4) inputs; st: the fitted state (camera centres compared: its own
            pivot is not used); sigma: (rotation rad, position m) noise of that fit, None: estimated.
    """
    st0 = AbsoluteState(st.X, st.W, st.scale)
    n_par = 12 * len(st.X) + 1
    if 6 * sum(len(e) for e in T_b_e) - n_par < PIVOT_MIN_REDUNDANCY:
        return np.zeros(3)
    if sigma is None:
        sigma = estimate_noise(*raw_residuals(T_b_e, T_w_c, st0), n_params=n_par)
    ell, p, _ = pivot_regression(*_deleted_residuals(T_b_e, T_w_c, st0, sigma))
    if p > PIVOT_SIGNIFICANCE or np.linalg.norm(ell) > MAX_PIVOT_M:
        return np.zeros(3)
    return ell


def _deleted_residuals(T_b_e: list, T_w_c: list, st: AbsoluteState, sigma: tuple[float, float]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Each view's residual against the fit without it, to first order ``(I - H_ii)^-1 r_i`` (whitened, the
    eigenvalues of ``I - H_ii`` clipped at 0.05 as in :func:`_quad`): (N, 3) rotation (rad, camera frame)
    and (N, 3) position (m, rotated into the camera frame)."""
    n_views = [len(e) for e in T_b_e]
    r = whitened(T_b_e, T_w_c, st, sigma)
    J = jacobian(T_b_e, T_w_c, st, sigma)
    A = np.linalg.pinv(J.T @ J)
    d = np.zeros((sum(n_views), 6))
    for _, _, sl in _view_blocks(n_views):
        Ji = J[sl]
        w, V = np.linalg.eigh(np.eye(6) - Ji @ A @ Ji.T)
        d[sl.start // 6] = V @ ((V.T @ r[sl]) / np.maximum(w, 0.05))
    R_c = np.concatenate([(E @ X)[:, :3, :3] for E, X in zip(T_b_e, st.X)])
    return d[:, :3] * sigma[0], np.einsum("nji,nj->ni", R_c, d[:, 3:] * sigma[1])


def pivot_regression(r: np.ndarray, t: np.ndarray, iterations: int = 5) -> tuple[np.ndarray, float, float]:
    """Robust fit of ``t = l x r`` over views: rotation residuals r (N, 3) (rad, camera frame) and camera-centre
    residuals t (N, 3) (m, camera frame).

    Least squares reweighted per view: Huber on the fit's residual, and bounded leverage (Mallows): a
    view's rotation residual is the regressor, so a gross one would set ``l`` on its own however badly it
    fits; its weight times ``|r|^2`` is capped at ``(PIVOT_HUBER x typical |r|)^2``.

    Returns:
        ``(l (3,), p-value of the F test of l = 0 (3 and 3 N - 3 dof), fraction of sum |t|^2 explained)``,
        both with the final weights.
    """
    from scipy.special import fdtrc  # (scipy.stats would add 0.6 s to the CLI's start-up)

    n = len(r)
    A = -skew(r)  # l x r = -[r]x l
    lev = np.linalg.norm(r, axis=1) / max(float(np.sqrt(np.median(np.sum(r ** 2, axis=1)))), 1e-15)
    w_x = np.minimum(1.0, (PIVOT_HUBER / np.maximum(lev, 1e-12)) ** 2)
    w = w_x
    for _ in range(iterations):
        sw = np.sqrt(w)[:, None, None]
        ell = np.linalg.lstsq((sw * A).reshape(-1, 3), (sw[..., 0] * t).ravel(), rcond=None)[0]
        e = np.linalg.norm(t - A @ ell, axis=1)
        z = e / max(float(np.sqrt(np.median(e ** 2))), 1e-15)
        w = w_x * np.minimum(1.0, PIVOT_HUBER / np.maximum(z, 1e-12))
    rss0 = float(np.sum(w * np.sum(t ** 2, axis=1)))
    rss1 = float(np.sum(w * np.sum((t - A @ ell) ** 2, axis=1)))
    dof = 3 * n - 3
    F = (rss0 - rss1) / 3.0 / max(rss1 / dof, 1e-300)
    return ell, float(fdtrc(3, dof, max(F, 0.0))), (rss0 - rss1) / max(rss0, 1e-300)


def whitened(T_b_e: list, T_w_c: list, st: AbsoluteState, sigma: tuple[float, float]) -> np.ndarray:
    """Stacked residuals divided by the noise: (6 * sum N_m,)."""
    rot, trans = raw_residuals(T_b_e, T_w_c, st)
    return np.concatenate([np.concatenate([r / sigma[0], t / sigma[1]], axis=1).ravel() for r, t in zip(rot, trans)])


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian J_l(phi) (3, 3): exp(phi + d) = exp(J_l d) exp(phi) to first order."""
    th = float(np.linalg.norm(phi))
    S = skew(phi)
    if th < 1e-6:
        return np.eye(3) + 0.5 * S + S @ S / 6.0
    return np.eye(3) + (1 - np.cos(th)) / th ** 2 * S + (th - np.sin(th)) / th ** 3 * S @ S


def _right_jacobian_inv(r: np.ndarray) -> np.ndarray:
    """Inverse right Jacobians (N, 3, 3) of SO(3) at rotation vectors r (N, 3): log(exp(r) exp(d)) = r + Jr^-1 d."""
    th = np.linalg.norm(r, axis=1)
    S = skew(r)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0, 1.0 / ths ** 2 - (1 + np.cos(ths)) / (2 * ths * np.sin(np.where(small, 1.0, ths))))
    return np.eye(3) + 0.5 * S + c[:, None, None] * (S @ S)


def jacobian(T_b_e: list, T_w_c: list, base: AbsoluteState, sigma: tuple[float, float], x: np.ndarray | None = None) -> np.ndarray:
    """Analytic Jacobian (6 sum N_m, 12 K + 1) of ``whitened(base.perturbed(x))`` with respect to ``x``.

    Written out (rather than finite differences) because the solver calls it every iteration and the
    finite-difference version cost most of the solve time. Verified against finite differences in tests.
    """
    K = len(base.X)
    n = 12 * K + 1
    x = np.zeros(n) if x is None else x
    st = base.perturbed(x)
    piv = np.zeros(3) if st.pivot is None else st.pivot
    blocks = []
    for m, (E, P) in enumerate(zip(T_b_e, T_w_c)):
        N = len(E)
        X, W = st.X[m], st.W[m]
        R_E = E[:, :3, :3]
        R_kin = R_E @ X[:3, :3]
        R_rec = W[:3, :3] @ P[:, :3, :3]
        D = np.swapaxes(R_kin, 1, 2) @ R_rec
        r = so3_log(D)
        Jri = _right_jacobian_inv(r)
        d = x[12 * m:12 * m + 12]
        JlX, JlW = _left_jacobian(d[0:3]), _left_jacobian(d[6:9])
        J = np.zeros((N, 6, n))
        # rotation residual: log(D); dphi_W -> Jr^-1 R_rec^T ; dphi_X -> -Jr^-1 D^T R_X^T
        J[:, :3, 12 * m + 6:12 * m + 9] = Jri @ np.swapaxes(R_rec, 1, 2) @ JlW / sigma[0]
        J[:, :3, 12 * m:12 * m + 3] = -(Jri @ np.swapaxes(D, 1, 2) @ X[:3, :3].T) @ JlX / sigma[0]
        # position residual (pivot l): R_W s t_P + t_W + R_rec l - R_E t_X - t_E - R_kin l
        p_rec = (P[:, :3, 3] * st.scale) @ W[:3, :3].T
        J[:, 3:, 12 * m + 3:12 * m + 6] = -R_E / sigma[1]
        J[:, 3:, 12 * m + 9:12 * m + 12] = np.eye(3) / sigma[1]
        J[:, 3:, 12 * m + 6:12 * m + 9] = -skew(p_rec + R_rec @ piv) @ JlW / sigma[1]
        J[:, 3:, 12 * m:12 * m + 3] = R_E @ skew(X[:3, :3] @ piv) @ JlX / sigma[1]
        J[:, 3:, -1] = p_rec / (1.0 + x[-1]) / sigma[1]
        blocks.append(J.reshape(6 * N, n))
    return np.concatenate(blocks)


NULL_RTOL = 1e-12  # relative eigenvalue below which a direction of the normal matrix is undetermined
NULL_COMPONENT = 1e-3  # a parameter moves along an undetermined direction when its component exceeds this


def covariance(T_b_e: list, T_w_c: list, st: AbsoluteState, sigma: tuple[float, float]) -> tuple[np.ndarray, float, float]:
    """Linearised covariance (12 K + 1, 12 K + 1) of the local coordinates at ``st``.

    ``cov = (J^T J)^-1 * chi2 / dof`` (a-posteriori variance factor). Directions of the (column-scaled)
    normal matrix whose eigenvalue is below ``NULL_RTOL`` times the largest are not determined by the data
    (e.g. the camera offset along the only rotation axis): every parameter that moves along one gets an
    infinite variance (``inf`` on the diagonal, its off-diagonal terms 0), never the pseudo-inverse's
    small number. Returns ``(cov, condition number of J^T J after column scaling, variance factor)``.
    """
    J = jacobian(T_b_e, T_w_c, st, sigma)
    r = whitened(T_b_e, T_w_c, st, sigma)
    m, n = J.shape
    vf = float(r @ r) / (m - n) if m > n else 1.0
    cov, cond = normal_covariance(J.T @ J)
    return cov * vf, cond, vf


def normal_covariance(H: np.ndarray) -> tuple[np.ndarray, float]:
    """``(H^-1 (n, n), condition number)`` of a normal matrix ``H`` (n, n), column-scaled, with every parameter
    that moves along an undetermined direction (eigenvalue below ``NULL_RTOL`` of the largest) given an
    infinite variance (``inf`` on the diagonal, its off-diagonal terms 0), never the pseudo-inverse's small
    number."""
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    ev, V = np.linalg.eigh(H / d[:, None] / d[None, :])
    cond = float(ev[-1] / max(ev[0], 1e-300))
    null = ev < NULL_RTOL * ev[-1]
    inv = np.where(null, 0.0, 1.0 / np.where(null, 1.0, ev))
    cov = (V * inv) @ V.T / d[:, None] / d[None, :]
    free = np.any(np.abs(V[:, null]) > NULL_COMPONENT, axis=1)
    cov[free, :] = 0.0
    cov[:, free] = 0.0
    cov[free, free] = np.inf
    return cov, cond


def refine_absolute(T_b_e: list, T_w_c: list, start: AbsoluteState, sigma: tuple[float, float] | None = None,
                    robust: bool = True, f_scale: float = 2.5, max_passes: int = 3) -> tuple[AbsoluteState, dict]:
    """Solve the absolute problem from ``start``.

    Args:
        T_b_e, T_w_c: per arm (N_m, 4, 4) inputs of the views to use.
        start: initial state (closed-form solution).
        sigma: expected (rotation rad, position m) noise of a view; None: estimated from the residuals,
            re-estimated after each pass until it settles.
        robust: soft_l1 loss (else plain least squares).
        f_scale: robust-loss knee in units of sigma.

    Returns:
        ``(state, info)``, info with ``sigma``, ``cost``, ``nfev``, ``passes``. With the noise estimated and
        the start's pivot None, the pivot is estimated after the first pass (:func:`estimate_pivot`, from
        that fit of the camera centres) and kept for the passes after it; otherwise the start's is kept.
    """
    n = 12 * len(start.X) + 1
    st = start
    est = sigma is None
    if est:
        sigma = estimate_noise(*raw_residuals(T_b_e, T_w_c, st), n_params=n)
    info = {"nfev": 0, "passes": 0}
    extra = 0  # one more pass when a pivot was found after the first
    while info["passes"] < max_passes + extra:
        sig = sigma

        def fun(x, st=st, sig=sig):
            return whitened(T_b_e, T_w_c, st.perturbed(x), sig)

        def jac(x, st=st, sig=sig):
            return jacobian(T_b_e, T_w_c, st, sig, x)

        res = least_squares(fun, np.zeros(n), jac=jac, method="trf", loss="soft_l1" if robust else "linear",
                            f_scale=f_scale, x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=100)
        st = st.perturbed(res.x)
        info["nfev"] += int(res.nfev)
        info["passes"] += 1
        info["cost"] = float(res.cost)
        if not est:
            break
        moved = 0.0
        if st.pivot is None:
            st = AbsoluteState(st.X, st.W, st.scale, estimate_pivot(T_b_e, T_w_c, st, sig))
            moved = float(np.linalg.norm(st.pivot))
            extra = int(moved > 0)
        new = variance_components(T_b_e, T_w_c, st, sigma)
        change = max(abs(np.log(new[0] / sigma[0])), abs(np.log(new[1] / sigma[1])), moved * new[0] / new[1])
        sigma = new
        if change < 0.1:
            break
    info["sigma"] = sigma
    return st, info




def _view_blocks(n_views: list[int]):
    start = 0
    for m, n in enumerate(n_views):
        for i in range(n):
            yield m, i, slice(start + 6 * i, start + 6 * i + 6)
        start += 6 * n


def _quad(S: np.ndarray, r: np.ndarray, floor: float = 0.05) -> float:
    """r^T S^-1 r with S's eigenvalues clipped from below (views that pin parameters alone have S ~ 0)."""
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    w = np.maximum(w, floor)
    y = V.T @ r
    return float(np.sum(y * y / w))


def studentized_scores(T_b_e: list, T_w_c: list, st: AbsoluteState, sigma: tuple[float, float]) -> tuple[list, float]:
    """Leverage-corrected (internally studentized) residual of every view.

    For view i with whitened residual ``r_i`` (6,) and hat-matrix block ``H_ii = J_i (J^T J)^-1 J_i^T``,
    ``z_i^2 = r_i^T (I - H_ii)^-1 r_i`` is chi-square(6) under the noise model: without the correction a
    view that pins parameters on its own (few views per arm) looks too good and the others too bad. The
    noise is rescaled by ``kappa``, the median over views of ``|r_i|^2 / tr(I - H_ii)`` (robust to a few bad
    views, see :func:`_noise_scale2`).

    Returns:
        ``(per arm (N_m,) scores sqrt(z^2 / kappa^2), kappa)`` where ``kappa`` is the noise rescale factor.
    """
    r = whitened(T_b_e, T_w_c, st, sigma)
    J = jacobian(T_b_e, T_w_c, st, sigma)
    A = np.linalg.pinv(J.T @ J)
    n_views = [len(e) for e in T_b_e]
    z2 = [[] for _ in n_views]
    q = []
    for m, _, sl in _view_blocks(n_views):
        Ji = J[sl]
        S = np.eye(6) - Ji @ A @ Ji.T
        z2[m].append(_quad(S, r[sl]))
        q.append(float(r[sl] @ r[sl]) / max(np.trace(S), 0.3))  # E|r_i|^2 = kappa^2 tr(I - H_ii)
    kappa2 = max(_noise_scale2(np.array(q)), 1e-12)
    return [np.sqrt(np.array(z) / kappa2) for z in z2], float(np.sqrt(kappa2))


def _noise_scale2(q: np.ndarray) -> float:
    """Robust kappa^2 from per-view estimates ``q_i = |r_i|^2 / tr(I - H_ii)`` (each ~ kappa^2 chi2_k / k).

    The median of chi2_k / k is below 1 (0.85 for k = 4.5): divided out for k = 4.5, a typical residual
    dof of a view in these problems (6 minus its share of the parameters)."""
    k = 4.5
    med_ratio = 1 - 2 / (9 * k)  # Wilson-Hilferty: median(chi2_k) / k ~ (1 - 2 / (9k))^3
    return float(np.median(q)) / med_ratio ** 3


def deleted_score(T_b_e: list, T_w_c: list, st: AbsoluteState, sigma: tuple[float, float], E_v: np.ndarray,
                  C_v: np.ndarray, arm: int) -> float:
    """How far one held-out view is from a fit that did not use it, in sigmas (prediction error included).

    ``d^2 = r_v^T (I + J_v C J_v^T)^-1 r_v / kappa^2`` with ``C = (J^T J)^-1`` of the fit's own views and
    ``kappa`` their studentized noise rescale: chi-square(6) for a view that follows the noise model.
    """
    J = jacobian(T_b_e, T_w_c, st, sigma)
    C = np.linalg.pinv(J.T @ J)
    r = whitened(T_b_e, T_w_c, st, sigma)
    m, n = J.shape
    kappa = float(np.sqrt(max(float(r @ r) / max(m - n, 1), 1e-12)))  # the fit's own views: clean, so the plain estimate
    E1 = [np.zeros((0, 4, 4))] * len(T_b_e)
    C1 = [np.zeros((0, 4, 4))] * len(T_b_e)
    E1[arm], C1[arm] = E_v[None], C_v[None]
    rv = whitened(E1, C1, st, sigma)
    Jv = jacobian(E1, C1, st, sigma)
    return float(np.sqrt(_quad(np.eye(6) + Jv @ C @ Jv.T, rv, floor=1.0) / kappa ** 2))


__all__ = ["AbsoluteState", "refine_absolute", "estimate_pivot", "covariance", "estimate_noise", "raw_residuals",
           "studentized_scores", "deleted_score"]
