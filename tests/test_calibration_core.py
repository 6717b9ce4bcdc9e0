"""Bi-JCR solver on arrays: exact recovery, Park–Martin, closed-form scale, refinement, SE(3) averaging,
analytic Jacobian, uncertainty, metric cloud."""

from __future__ import annotations

import numpy as np
import pytest
from _calib_fixtures import make_capture
from scipy.spatial.transform import Rotation

from bimanual_app.transforms import inv_T, make_T, rotation_angle_between, so3_exp
from calibration import CalibrationOptions, metric_cloud, solve_bijcr, solve_single_arm
from calibration import _absolute as absm
from calibration._closed_form import (
    average_base_from_world,
    base_from_world_per_view,
    pair_motions,
    park_martin_rotation,
    solve_translations_and_scale,
)
from calibration._evaluate import calibration_errors, paper_residuals


def _solve(cap, **kw):
    return solve_bijcr(cap.T_b1_e, cap.T_w_c1, cap.T_b2_e, cap.T_w_c2, **kw)


def _close(T, T_true, rot_tol=1e-7, trans_tol=1e-7):
    assert rotation_angle_between(T[:3, :3], T_true[:3, :3]) < rot_tol
    assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < trans_tol


@pytest.mark.parametrize("method", ["absolute", "paper-norefine", "paper"])
def test_exact_recovery_noise_free(method):
    cap = make_capture(seed=3, views=6, noise="none")
    r = _solve(cap, method=method)
    _close(r.T_e1_c1, cap.T_e1_c1)
    _close(r.T_e2_c2, cap.T_e2_c2)
    _close(r.T_b1_b2, cap.T_b1_b2)
    _close(r.T_b1_w, cap.T_b1_w)
    _close(r.T_b2_w, cap.T_b2_w)
    assert abs(r.scale / cap.scale - 1) < 1e-9
    assert r.residuals["rotation_rad"] < 1e-8 and r.residuals["translation_m"] < 1e-8
    assert r.views_dropped == {"primary": [], "secondary": []}


def test_single_arm_recovers_its_own_scale():
    cap = make_capture(seed=4, views=5, noise="none")
    s = solve_single_arm(cap.T_b2_e, cap.T_w_c2)
    _close(s["T_e_c"], cap.T_e2_c2)
    _close(s["T_b_w"], cap.T_b2_w)
    assert abs(s["scale"] / cap.scale - 1) < 1e-9


def test_park_martin_exact_and_small_angles_no_nan():
    rng = np.random.default_rng(0)
    R_X = Rotation.random(random_state=rng).as_matrix()
    b = rng.normal(scale=0.5, size=(10, 3))
    a = b @ R_X.T  # log(R_A) = R_X log(R_B)
    R, used = park_martin_rotation(a, b)
    assert used == 10 and rotation_angle_between(R, R_X) < 1e-10
    # near-pure translations: angles of 1e-9 rad; all pairs skipped by default -> a clear error, not NaN
    tiny = b / np.linalg.norm(b, axis=1, keepdims=True) * 1e-9
    with pytest.raises(ValueError, match="at least 2 pairs"):
        park_martin_rotation(tiny @ R_X.T, tiny)
    # forced to use them (min_angle 0), still a proper rotation, no NaN
    R0, _ = park_martin_rotation(tiny @ R_X.T, tiny, min_angle=0.0)
    assert np.all(np.isfinite(R0)) and abs(np.linalg.det(R0) - 1) < 1e-9
    # exact zero rotations mixed with real ones: the zero ones are ignored
    mix_a = np.vstack([a, np.zeros((5, 3))])
    mix_b = np.vstack([b, np.zeros((5, 3))])
    R1, used = park_martin_rotation(mix_a, mix_b)
    assert used == 10 and rotation_angle_between(R1, R_X) < 1e-10
    # rank-2 M (two axes only): still a proper rotation (the SVD form with the det fix)
    R2, _ = park_martin_rotation(a[:2], b[:2])
    assert abs(np.linalg.det(R2) - 1) < 1e-9 and rotation_angle_between(R2, R_X) < 1e-8


def test_park_martin_on_motions_with_pure_translation_pairs():
    cap = make_capture(seed=1, views=5, noise="none")
    E, C = cap.T_b1_e.copy(), cap.T_w_c1.copy()
    # add a view that only translates relative to view 0 (camera and flange)
    shift = make_T(np.eye(3), [0.05, 0.0, 0.0])
    E = np.concatenate([E, (E[0] @ shift)[None]])
    C_new = C[0] @ inv_T(cap.T_e1_c1) @ shift @ cap.T_e1_c1
    C = np.concatenate([C, C_new[None]])
    pm = pair_motions(E, C)
    assert np.all(np.isfinite(pm.a)) and np.all(np.isfinite(pm.b))
    R, _ = park_martin_rotation(pm.a, pm.b)
    assert rotation_angle_between(R, cap.T_e1_c1[:3, :3]) < 1e-9


def test_closed_form_translations_and_one_scale():
    cap = make_capture(seed=2, views=5, noise="none")
    pms = [pair_motions(cap.T_b1_e, cap.T_w_c1), pair_motions(cap.T_b2_e, cap.T_w_c2)]
    lin = solve_translations_and_scale(pms, [cap.T_e1_c1[:3, :3], cap.T_e2_c2[:3, :3]])
    assert abs(lin.scale / cap.scale - 1) < 1e-10
    assert np.allclose(lin.t_X[0], cap.T_e1_c1[:3, 3], atol=1e-10)
    assert np.allclose(lin.t_X[1], cap.T_e2_c2[:3, 3], atol=1e-10)
    assert lin.cov.shape == (7, 7)
    # the scale is linear in the data: reconstruction units twice as large -> scale halves
    C1, C2 = cap.T_w_c1.copy(), cap.T_w_c2.copy()
    C1[:, :3, 3] *= 2
    C2[:, :3, 3] *= 2
    pms2 = [pair_motions(cap.T_b1_e, C1), pair_motions(cap.T_b2_e, C2)]
    lin2 = solve_translations_and_scale(pms2, [cap.T_e1_c1[:3, :3], cap.T_e2_c2[:3, :3]])
    assert abs(lin2.scale / (cap.scale / 2) - 1) < 1e-10


def test_paper_refinement_lowers_the_loss():
    from calibration._paper_refine import paper_loss, refine_paper
    from calibration._solve import _closed_form

    cap = make_capture(seed=5, views=7, noise="paper")
    E, C = [cap.T_b1_e, cap.T_b2_e], [cap.T_w_c1, cap.T_w_c2]
    motions = [pair_motions(e, c) for e, c in zip(E, C)]
    st, _ = _closed_form(E, C, [np.arange(7)] * 2, motions, CalibrationOptions())
    X, s, info = refine_paper(motions, st.X, st.scale, alpha=0.5)
    l0 = paper_loss(motions, st.X, st.scale)
    l1 = paper_loss(motions, X, s)
    assert abs(info["loss_initial"] - l0) < 1e-9 and abs(info["loss_final"] - l1) < 1e-9
    assert l1 < l0  # the closed form is already close to this loss's minimum (an independent Powell search agrees)
    for x in X:  # rotations stay on SO(3)
        assert np.allclose(x[:3, :3].T @ x[:3, :3], np.eye(3), atol=1e-10)
    # from a poor start (3 deg, 2 cm, 10% off) it walks back to the same minimum
    bad = [make_T(so3_exp(np.array([0.03, -0.04, 0.02])) @ x[:3, :3], x[:3, 3] + [0.02, -0.01, 0.01]) for x in st.X]
    lb = paper_loss(motions, bad, 1.1 * st.scale)
    X2, s2, info2 = refine_paper(motions, bad, 1.1 * st.scale, alpha=0.5)
    assert info2["loss_final"] < 0.5 * lb
    assert abs(info2["loss_final"] - l1) < 0.02 * l1
    assert abs(s2 / s - 1) < 0.01


def test_absolute_refinement_lowers_its_cost_and_beats_the_closed_form_on_average():
    from calibration._solve import _closed_form

    better = 0
    for seed in range(4):
        cap = make_capture(seed=seed, views=8, noise="paper")
        E, C = [cap.T_b1_e, cap.T_b2_e], [cap.T_w_c1, cap.T_w_c2]
        motions = [pair_motions(e, c) for e, c in zip(E, C)]
        st0, _ = _closed_form(E, C, [np.arange(8)] * 2, motions, CalibrationOptions())
        sig = absm.estimate_noise(*absm.raw_residuals(E, C, st0), n_params=25)
        st1, _ = absm.refine_absolute(E, C, st0, sigma=sig, robust=False)
        c0 = np.sum(absm.whitened(E, C, st0, sig) ** 2)
        c1 = np.sum(absm.whitened(E, C, st1, sig) ** 2)
        assert c1 < c0
        e0 = calibration_errors(st0.X[0], st0.X[1], st0.scale, st0.W[0] @ inv_T(st0.W[1]), cap)
        e1 = calibration_errors(st1.X[0], st1.X[1], st1.scale, st1.W[0] @ inv_T(st1.W[1]), cap)
        better += e1["T_b1_b2"][1] < e0["T_b1_b2"][1]
    assert better >= 3


@pytest.mark.parametrize("pivot", [None, [0.05, -0.1, 0.9]], ids=["camera-centre", "pivot"])
def test_analytic_jacobian_matches_finite_differences(pivot):
    """With positions compared at the camera centre and at a pivot point of the camera frame."""
    from calibration._solve import _closed_form

    cap = make_capture(seed=6, views=5, noise="paper")
    E, C = [cap.T_b1_e, cap.T_b2_e], [cap.T_w_c1, cap.T_w_c2]
    st, _ = _closed_form(E, C, [np.arange(5)] * 2, [pair_motions(e, c) for e, c in zip(E, C)], CalibrationOptions())
    st = absm.AbsoluteState(st.X, st.W, st.scale, None if pivot is None else np.array(pivot))
    sig = (0.01, 0.004)
    x = np.random.default_rng(1).normal(scale=0.05, size=25)
    J = absm.jacobian(E, C, st, sig, x)
    h = 1e-6
    Jn = np.stack([(absm.whitened(E, C, st.perturbed(x + h * e), sig) - absm.whitened(E, C, st.perturbed(x - h * e), sig))
                   / (2 * h) for e in np.eye(25)], axis=1)
    assert np.abs(J - Jn).max() < 1e-6 * np.abs(Jn).max()


def test_se3_average_is_a_proper_rotation_mean():
    R = so3_exp(np.array([[0, 0, 0.6], [0, 0, -0.6], [0.6, 0, 0], [-0.6, 0, 0]]))
    T = make_T(R, np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 2.0, 0], [0, -2.0, 0]]))
    from bimanual_app.transforms import mean_T

    M = mean_T(T)
    assert np.allclose(M[:3, :3], np.eye(3), atol=1e-12) and np.allclose(M[:3, 3], 0)
    naive = T[:, :3, :3].mean(0)  # element-wise mean: not a rotation
    assert np.abs(naive.T @ naive - np.eye(3)).max() > 0.1
    # on noisy per-view estimates T_b_w(i) = T_b_e(i) X P_i(s)^-1 the average stays in SE(3)
    cap = make_capture(seed=7, views=8, noise="harsh")
    per_view = base_from_world_per_view(cap.T_b1_e, cap.T_e1_c1, cap.T_w_c1, cap.scale)
    A = average_base_from_world(cap.T_b1_e, cap.T_e1_c1, cap.T_w_c1, cap.scale)
    assert np.allclose(A[:3, :3].T @ A[:3, :3], np.eye(3), atol=1e-12) and np.linalg.det(A[:3, :3]) > 0
    ang = rotation_angle_between(per_view[:, :3, :3], A[None, :3, :3])
    assert ang.max() < np.deg2rad(10)
    assert rotation_angle_between(A[:3, :3], cap.T_b1_w[:3, :3]) < np.deg2rad(3)


def test_uncertainty_for_every_output_grows_with_noise():
    sig = {}
    for noise in ("low", "harsh"):
        cap = make_capture(seed=8, views=8, noise=noise)
        r = _solve(cap)
        u = r.uncertainty
        for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2", "T_b1_w", "T_b2_w"):
            assert u[key]["rotation_deg"] > 0 and u[key]["translation_norm_mm"] > 0
            assert len(u[key]["translation_mm"]) == 3
        assert u["scale"]["percent"] > 0
        sig[noise] = u
    for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2"):
        assert sig["harsh"][key]["rotation_deg"] > 2 * sig["low"][key]["rotation_deg"]
        assert sig["harsh"][key]["translation_norm_mm"] > 2 * sig["low"][key]["translation_norm_mm"]


def test_uncertainty_is_calibrated_roughly():
    """Over seeds, hand-eye errors divided by the reported sigma stay in a sane range (not over-/under-confident by 3x)."""
    z = []
    for seed in range(8):
        cap = make_capture(seed=seed, views=9, noise="paper")
        r = _solve(cap)
        for key, T_true in (("T_e1_c1", cap.T_e1_c1), ("T_e2_c2", cap.T_e2_c2)):
            T = getattr(r, key)
            z.append(np.linalg.norm(T[:3, 3] - T_true[:3, 3]) * 1000 / r.uncertainty[key]["translation_norm_mm"])
            z.append(np.rad2deg(rotation_angle_between(T[:3, :3], T_true[:3, :3])) / r.uncertainty[key]["rotation_deg"])
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 1 / 3 < rms < 3, rms


def test_jackknife_uncertainty_available():
    cap = make_capture(seed=9, views=6, noise="paper")
    r = _solve(cap, options=CalibrationOptions(uncertainty="jackknife"))
    assert r.uncertainty["estimator"] == "jackknife"
    for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2"):
        assert r.uncertainty[key]["rotation_deg"] > 0
    assert r.uncertainty["scale"]["percent"] > 0


def test_paper_residuals_with_true_motions():
    cap = make_capture(seed=10, views=5, noise="none")
    dr, dt = paper_residuals([cap.T_b1_e, cap.T_b2_e], [cap.T_e1_c1, cap.T_e2_c2], [cap.T_e1_c1, cap.T_e2_c2])
    assert dr < 1e-9 and dt < 1e-9
    bad = cap.T_e1_c1 @ make_T(so3_exp(np.array([0.0, 0.0, 0.05])), [0.01, 0, 0])
    dr, dt = paper_residuals([cap.T_b1_e], [bad], [cap.T_e1_c1])
    assert dr > 1e-3 and dt > 1e-3


def test_metric_cloud_exact_and_confidence_filtered():
    cap = make_capture(seed=11, views=4, noise="none", point_maps=True)
    r = _solve(cap)
    pts, cols, info = metric_cloud(cap.pts3d, r.T_b1_w, r.scale, cap.conf, cap.colors)
    keep = cap.conf > info["conf_threshold"]
    assert info["points"] == int(keep.sum()) < cap.conf.size
    assert np.abs(pts - cap.points_b1[keep]).max() < 1e-5  # float32 point maps
    assert cols.dtype == np.uint8 and np.array_equal(cols, cap.colors[keep])
    assert np.all(cap.conf[keep] > 1.0)  # the junk (conf < 0.5) is gone
    # explicit threshold, no conf
    pts2, _, info2 = metric_cloud(cap.pts3d, r.T_b1_w, r.scale, cap.conf, None, conf_threshold=5.0)
    assert info2["points"] == int((cap.conf > 5.0).sum())
    pts3, c3, info3 = metric_cloud(cap.pts3d, r.T_b1_w, r.scale)
    assert info3["points"] == cap.conf.size and c3 is None


def test_robot_self_filter_drops_the_arm_columns_only():
    from bimanual_app.transforms import make_T, so3_exp
    from calibration._api import robot_self_mask

    T_b1_b2 = make_T(so3_exp(np.array([0.0, 0.0, np.pi])), [0.6, 0.0, 0.02])
    pts = np.array([[0.05, 0.0, 0.30],    # primary arm column
                    [0.58, 0.03, 0.20],   # secondary arm column
                    [0.05, 0.0, 0.005],   # table next to the primary base
                    [0.35, 0.0, 0.05],    # an object between the arms
                    [0.60, 0.0, 0.03]])   # b2's own plate, below 1.5 cm over b2's plane
    m = robot_self_mask(pts, [np.eye(4), T_b1_b2], radius=0.15)
    assert m.tolist() == [True, True, False, False, False]
