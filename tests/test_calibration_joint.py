"""The joint weighted estimator (calibration._joint, _estimate, _guard; ``CalibrationOptions(estimator="joint")``):
analytic map Jacobian with per-view depth factors, the held-out downdate, and that exact poses keep their
exact answer when the maps are noisy; on a rendered scene at the paper's noise it must beat the pose-only
solve on the hand-eyes and be preferred by its held-out check."""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import rotation_angle_between


def test_joint_estimate_beats_the_pose_only_solve_and_says_why(synth_paper):
    from bimanual_app.scene import load_scene
    from calibration import CalibrationOptions, calibrate, scene_cloud

    scene = load_scene(synth_paper)
    plain = calibrate(scene, options=CalibrationOptions(point_maps=False))
    lines = []
    res = calibrate(scene, options=CalibrationOptions(estimator="joint"), progress=lines.append)
    pm = res.info["point_maps"]
    assert pm["accepted"], pm["reason"]
    assert pm["held_out_cost"]["joint"] < pm["held_out_cost"]["pose_only"]
    assert len([x for x in lines if " mm round, " in x]) == len(pm["rounds"]) and "joint estimate" in lines[0]
    assert pm["noise"]["loop_rotation_deg"] > 0 and pm["noise"]["map_mm_median"] > 0
    gt = scene.ground_truth
    for T, T0, T_true in ((res.T_e1_c1, plain.T_e1_c1, gt.T_e1_c1), (res.T_e2_c2, plain.T_e2_c2, gt.T_e2_c2)):
        e = np.degrees(rotation_angle_between(T[:3, :3], T_true[:3, :3]))
        e0 = np.degrees(rotation_angle_between(T0[:3, :3], T_true[:3, :3]))
        assert e < e0 and e < 0.5, (e, e0)
    assert abs(res.scale / gt.scale - 1) < abs(plain.scale / gt.scale - 1)
    assert "joint weighted estimate" in res.uncertainty["estimator"]
    assert scene_cloud(scene, res)[2]["views_placed_by"] == "kinematics"


def test_joint_estimate_needs_two_views_per_arm():
    from calibration._estimate import estimate_jointly
    from calibration._joint import JointState
    from tests._calib_fixtures import flat_views

    views = flat_views()
    E = np.tile(np.eye(4), (3, 1, 1))
    st = JointState(np.eye(4), np.eye(4), 1.0, np.eye(4), np.eye(4), np.zeros(3))
    r = estimate_jointly(views, np.array([1, 1, 2]), E, E, st, (0.01, 0.01))
    assert not r.accepted and "2 or more point maps per arm" in r.reason and "2 / 1" in r.reason


def test_analytic_jacobian_matches_finite_differences():
    from calibration._pointmaps import map_jacobian, map_residuals
    from tests._calib_fixtures import random_pair_problem

    views, start, pairs = random_pair_problem()
    kappa = np.random.default_rng(5).normal(scale=0.02, size=6)
    J, Jk = map_jacobian(np.zeros(19), kappa, views, start, pairs)
    h = 1e-6

    def f(x):
        return map_residuals(x[:19], kappa + x[19:], views, start, pairs)

    Jn = np.stack([(f(h * e) - f(-h * e)) / (2 * h) for e in np.eye(25)], axis=1)
    assert np.abs(Jn).max() > 0.1
    assert np.allclose(np.concatenate([J, Jk], axis=1), Jn, atol=1e-7)


def test_held_out_downdate_equals_refitting_without_the_view():
    """On a linear problem the one-step downdate is exact: the held-out predictions equal a refit."""
    from calibration._guard import held_out_cost

    rng = np.random.default_rng(4)
    J = rng.normal(size=(60, 4))
    y = J @ rng.normal(size=4) + rng.normal(scale=0.3, size=60)
    view = np.repeat(np.arange(6), 10)
    x = np.linalg.lstsq(J, y, rcond=None)[0]
    r = J @ x - y
    got, shift = held_out_cost(J, r, view, [(np.ones(60, bool), np.arange(4))], f_scale=1e3)
    want = []
    for v in range(6):
        keep = view != v
        xv = np.linalg.lstsq(J[keep], y[keep], rcond=None)[0]
        want.append(np.sum((J[~keep] @ xv - y[~keep]) ** 2))
        assert np.allclose(shift[v], xv - x)
    assert np.allclose(got, want, rtol=1e-5)


def test_exact_poses_with_noisy_maps_lean_on_the_poses(synth_none):
    """Exact poses, point maps with 0.1 % depth noise: the joint estimate stays at the (exact) pose-only
    answer within a fraction of a millimetre."""
    from bimanual_app.scene import load_scene
    from calibration import CalibrationOptions, calibrate

    scene = load_scene(synth_none)
    rec = scene.reconstruction
    rng = np.random.default_rng(7)
    T = rec.T_w_c
    pc = np.einsum("vji,vhwj->vhwi", T[:, :3, :3], rec.pts3d - T[:, None, None, :3, 3])
    pc *= 1 + rng.normal(scale=0.001, size=pc.shape[:3] + (1,))
    rec.pts3d = (np.einsum("vij,vhwj->vhwi", T[:, :3, :3], pc) + T[:, None, None, :3, 3]).astype(rec.pts3d.dtype)
    plain = calibrate(scene, options=CalibrationOptions(point_maps=False))
    res = calibrate(scene, options=CalibrationOptions(estimator="joint"))
    gt = scene.ground_truth
    for T_res, T_plain, T_true in ((res.T_e1_c1, plain.T_e1_c1, gt.T_e1_c1), (res.T_e2_c2, plain.T_e2_c2, gt.T_e2_c2)):
        e_res = np.linalg.norm(T_res[:3, 3] - T_true[:3, 3])
        e_plain = np.linalg.norm(T_plain[:3, 3] - T_true[:3, 3])
        assert e_res < max(1.2 * e_plain, 5e-4), (e_res, e_plain)
    # the loop's scatter is far under its floor: the held-out check measures it on its own scale, on which the
    # maps' pull is no gain, and the exact poses stand
    pm = res.info["point_maps"]
    assert not pm["accepted"] and np.allclose(res.T_e1_c1, plain.T_e1_c1, atol=1e-9), pm["reason"]


def test_the_held_out_check_measures_a_floored_loop_on_its_own_scale():
    from calibration._absolute import SIGMA_FLOOR_ROT, SIGMA_FLOOR_TRANS
    from calibration._estimate import _guard_loop_sigma
    from calibration._terms import CostTerm

    groups = np.tile([0, 0, 0, 1, 1, 1], 4)
    raw = np.where(groups == 0, 2e-6, 3e-7)  # rad, m: exact poses, numerically
    term = CostTerm("kinematic loop", lambda th: raw, None, groups, np.array([SIGMA_FLOOR_ROT, SIGMA_FLOOR_TRANS]))
    assert np.allclose(_guard_loop_sigma(term, 3), [2e-6, 3e-7])
    term.sigma = np.array([0.01, SIGMA_FLOOR_TRANS])  # rotation noisy (not floored): its level stays
    assert np.allclose(_guard_loop_sigma(term, 3), [0.01, 3e-7])
    term.residuals = lambda th: np.zeros(len(groups))  # no scatter at all: a thousandth of the floor
    assert np.allclose(_guard_loop_sigma(term, 3), [0.01, 1e-3 * SIGMA_FLOOR_TRANS])




def test_a_view_whose_depth_is_far_off_is_named_and_left_out(synth_paper):
    from bimanual_app.scene import load_scene
    from calibration import CalibrationOptions, calibrate

    scene = load_scene(synth_paper)
    opts = CalibrationOptions(estimator="joint")
    base = calibrate(scene, options=opts)
    rec = scene.reconstruction
    j = 2
    T = rec.T_w_c[j]
    pc = (rec.pts3d[j] - T[:3, 3]) @ T[:3, :3]
    rec.pts3d[j] = ((1.3 * pc) @ T[:3, :3].T + T[:3, 3]).astype(rec.pts3d.dtype)
    res = calibrate(scene, options=opts)
    key = str(rec.image[j])
    assert any(key in w and "contradicts its own pose" in w for w in res.warnings), res.warnings
    assert res.info["point_maps"]["dropped_views"] == [j]
    for a, b in ((res.T_e1_c1, base.T_e1_c1), (res.T_e2_c2, base.T_e2_c2), (res.T_b1_b2, base.T_b1_b2)):
        assert np.degrees(rotation_angle_between(a[:3, :3], b[:3, :3])) < 0.3
        assert np.linalg.norm(a[:3, 3] - b[:3, 3]) < 0.005


def test_closed_form_pair_summaries_equal_projecting_every_distance():
    """The map term's summaries and their Jacobian (``calibration._summary``, 13 numbers per ordered view pair)
    equal the weighted projections ``Q^T (w r)`` of the point-to-plane distances and of their analytic
    Jacobian, away from the start too."""
    from calibration._pointmaps import map_jacobian, map_residuals, unpack_corrections, view_camera_poses
    from calibration._summary import pair_summary, view_twists
    from tests._calib_fixtures import random_pair_problem

    views, start, pairs = random_pair_problem()
    rng = np.random.default_rng(6)
    V, P = len(views), len(pairs)
    lo, hi = np.minimum(pairs.va, pairs.vb), np.maximum(pairs.va, pairs.vb)
    blocks = [(idx, np.linalg.qr(rng.normal(size=(len(idx), 8)))[0])
              for key in np.unique(lo * V + hi) if len(idx := np.flatnonzero(lo * V + hi == key)) >= 8]
    w = rng.uniform(0.5, 2.0, P)
    S = np.zeros((8 * len(blocks), P))
    for k, (idx, Q) in enumerate(blocks):
        S[8 * k:8 * k + 8, idx] = Q.T
    summary = pair_summary(blocks, pairs.va, pairs.vb, pairs.design(), w)
    arms = np.array([v.arm for v in views])
    for x in (np.zeros(19), rng.normal(scale=0.05, size=19)):
        kappa = rng.normal(scale=0.02, size=V)
        T1, T2, s, Tb = unpack_corrections(x, *start)
        Tc = view_camera_poses(views, T1, T2, Tb)
        R, t, sv = Tc[:, :3, :3], Tc[:, :3, 3], s * np.exp(kappa)
        want = S @ (w * map_residuals(x, kappa, views, start, pairs))
        assert np.abs(want).max() > 1e-2
        assert np.allclose(summary.values(R, t, sv), want, atol=1e-10)
        J, Jk = map_jacobian(x, kappa, views, start, pairs)
        got = summary.jacobian(R, t, sv, *view_twists(R, t, arms, 19 + V, 19))
        assert np.allclose(got, S @ (w[:, None] * np.concatenate([J, Jk], axis=1)), atol=1e-10)


def test_orthonormal_basis_is_numpys_qr():
    from calibration._joint import _orthonormal_basis

    G = np.random.default_rng(2).normal(size=(40, 8)) * np.logspace(-3, 1, 8)
    Q = _orthonormal_basis(G)
    assert Q.shape == (40, 8)
    assert np.allclose(Q, np.linalg.qr(G)[0], atol=1e-12) and np.allclose(Q.T @ Q, np.eye(8), atol=1e-12)


def _linear_problem_with_a_depth_prior(seed: int, V: int = 6, sigma0: float = 3e-3):
    """A linear whitened problem shaped like the joint estimator's: data rows that inform the calibration
    well and the depth factors weakly, then the prior's rows (one per view, the two arms' means)."""
    from calibration import _joint as jm

    rng = np.random.default_rng(seed)
    n = jm.N_CAL + V
    Jd = rng.normal(size=(120, n))
    Jd[:, jm.N_CAL:] *= 0.05  # the maps barely tell the depth factors
    arms = np.array([1] * (V // 2) + [2] * (V - V // 2))
    D = np.vstack([np.eye(V), [(arms == a) / np.sum(arms == a) for a in (1, 2)]])
    Jp = np.zeros((V + 2, n))
    Jp[:, jm.N_CAL:] = D / np.r_[np.full(V, sigma0), [jm.MEAN_KAPPA_SIGMA] * 2][:, None]
    return Jd, Jp, np.vstack([Jd, Jp])


def test_prior_share_is_the_calibrations_spread_from_depth_factors_the_prior_does_not_know():
    """Exact data, true depth factors spread 3x wider than the prior: the calibration's error is then all
    the prior's doing, which the delete-one-view jackknife cannot see; _prior_share predicts its covariance."""
    from calibration import _joint as jm
    from calibration._absolute import normal_covariance
    from calibration._estimate import _prior_share

    V, sigma0, spread = 6, 3e-3, 9e-3
    Jd, Jp, J = _linear_problem_with_a_depth_prior(0, V, sigma0)
    rng = np.random.default_rng(1)
    errs = []
    for _ in range(4000):
        theta = np.r_[rng.normal(size=jm.N_CAL) * 0.01, rng.normal(size=V) * spread]
        y = np.r_[Jd @ theta, np.zeros(V + 2)]  # the prior says zero
        errs.append(np.linalg.lstsq(J, y, rcond=None)[0][:jm.N_CAL] - theta[:jm.N_CAL])
    emp = np.cov(np.array(errs).T)
    pred = _prior_share(normal_covariance(J.T @ J)[0], Jp, spread ** 2)
    sd_emp, sd_pred = np.sqrt(np.diag(emp)), np.sqrt(np.diag(pred))
    assert np.all(sd_pred > 0)
    np.testing.assert_allclose(sd_pred, sd_emp, rtol=0.08)


def test_prior_variance_factor_measures_how_far_the_depth_factors_spread():
    """The fitted factors' spread against the prior's: about (spread / sigma0)^2 = 9 when the maps pin the
    factors (one pass of variance components: lower when the prior dominates them), and never below 1."""
    from calibration import _joint as jm
    from calibration._estimate import _prior_variance_factor

    V, sigma0 = 40, 3e-3
    Jd, Jp, J = _linear_problem_with_a_depth_prior(2, V, sigma0)
    Jd[:, jm.N_CAL:] *= 3000.0  # here the maps pin the factors: the prior barely pulls them
    J = np.vstack([Jd, Jp])
    rng = np.random.default_rng(3)
    for spread, lo, hi in ((9e-3, 5.0, 14.0), (1e-4, 1.0, 1.0)):
        theta = np.r_[rng.normal(size=jm.N_CAL) * 0.01, rng.normal(size=V) * spread]
        y = np.r_[Jd @ theta + rng.normal(size=len(Jd)), np.zeros(V + 2)]  # whitened data: unit noise
        est = np.linalg.lstsq(J, y, rcond=None)[0]
        r = J @ est - y
        f = _prior_variance_factor(J, r, V + 2)
        assert lo <= f <= hi, (spread, f)


def test_depth_prior_rises_to_the_spread_the_maps_show(synth_paper, tmp_path):
    """Maps whose views each get the depth scale a little wrong (fm-like: 1 % per view) raise the depth
    factors' prior above its floor and the estimate is solved again; the emulator's maps, exact in each
    camera's frame, leave it at the floor. Both runs say so in their rounds."""
    from bimanual_app.scene import load_scene
    from bimanual_app.synth import make_synthetic_scene
    from calibration import CalibrationOptions, calibrate
    from calibration import _joint as jm

    fm = make_synthetic_scene(tmp_path / "fm", seed=3, views=6, objects=2, noise="paper", render=True,
                              pointmap_size=(80, 60), progress=False, preview=False, map_noise="fm")
    levels = {}
    for name, path in (("emulator", synth_paper), ("fm", fm)):
        lines = []
        pm = calibrate(load_scene(path), options=CalibrationOptions(estimator="joint"), progress=lines.append).info["point_maps"]
        levels[name] = pm["noise"]["depth_factor_sigma"]
        assert pm["rounds"][0]["depth_prior"] == jm.KAPPA_SIGMA
        assert pm["rounds"][-1]["depth_prior"] == levels[name]
        assert jm.KAPPA_SIGMA <= levels[name] <= jm.KAPPA_CAP
        assert (levels[name] > jm.KAPPA_SIGMA) == any("solving again" in x for x in lines)
    assert levels["fm"] > 2 * jm.KAPPA_SIGMA, levels
    # the emulator's maps: a spread a little over the prior's (about 0.11 %) is not significant, no second solve
    assert levels["emulator"] == jm.KAPPA_SIGMA, levels


def test_point_map_figure_draws_each_fit_of_the_joint_estimate_as_its_own_line():
    from calibration._plot import _fits

    rounds = [{"radius_m": r, "rms_m": 1e-3, "depth_prior": p} for p in (1e-3, 3e-3) for r in (0.03, 0.02, 0.008)]
    fits = _fits(rounds)
    assert [len(f) for f in fits] == [3, 3] and [f[0]["depth_prior"] for f in fits] == [1e-3, 3e-3]
    assert len(_fits([{"radius_m": 0.03, "rms_m": 1e-3}, {"radius_m": 0.02, "rms_m": 1e-3}])) == 1  # the refinement's
