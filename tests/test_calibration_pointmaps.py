"""Point-map refinement of the joint solve (``estimator="refine"``, calibration._pointmap_refine): on a rendered scene at the paper's
noise it must bring the views' point maps, placed by the kinematics, onto the true surfaces; it must be
refused, leaving the joint solve as it was, when the point maps cannot support it."""

from __future__ import annotations

import json

import numpy as np

from bimanual_app.transforms import inv_T, make_T, rotation_angle_between, so3_exp
from calibration import CalibrationOptions as _Options

REFINE = _Options(estimator="refine")  # the previous point-map estimator, tested as it was


def _cloud_error_mm(path, points: np.ndarray) -> float:
    """Median distance (mm) of the cloud's points to the true surfaces (points further than 5 cm excluded:
    background the true cloud does not hold)."""
    from scipy.spatial import cKDTree

    from bimanual_app.scene import ground_truth_cloud

    true_pts, _, _ = ground_truth_cloud(path)
    d = cKDTree(true_pts).query(points)[0]
    return float(np.median(d[d < 0.05]) * 1e3)


def test_refinement_brings_the_cloud_onto_the_true_surfaces(synth_paper):
    from bimanual_app.scene import load_scene
    from calibration import CalibrationOptions, calibrate, scene_cloud

    scene = load_scene(synth_paper)
    plain = calibrate(scene, options=CalibrationOptions(point_maps=False))
    lines = []
    refined = calibrate(scene, options=REFINE, progress=lines.append)
    pm = refined.info["point_maps"]
    assert pm["accepted"], pm["reason"]
    assert pm["median_after_mm"] < pm["median_before_mm"]
    assert len(lines) == len(pm["rounds"]) and "point-map refinement" in lines[0]
    p_plain, _, i_plain = scene_cloud(scene, plain)
    p_ref, _, i_ref = scene_cloud(scene, refined)
    assert i_plain["views_placed_by"] == "reconstruction" and i_ref["views_placed_by"] == "kinematics"
    e_plain, e_ref = _cloud_error_mm(synth_paper, p_plain), _cloud_error_mm(synth_paper, p_ref)
    assert e_ref < 2.5 and e_ref < 0.3 * e_plain, (e_plain, e_ref)
    gt = scene.ground_truth
    for T, T_true in ((refined.T_e1_c1, gt.T_e1_c1), (refined.T_e2_c2, gt.T_e2_c2)):
        assert np.degrees(rotation_angle_between(T[:3, :3], T_true[:3, :3])) < 0.6
        assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 0.004
    assert abs(refined.scale / gt.scale - 1) < 0.005
    # T_b1_w follows the refined values: the kinematic cameras and the reconstruction's agree through it
    from calibration._api import _views_of, kinematic_camera_poses
    from calibration._closed_form import scaled

    rows, arms, E = _views_of(scene, refined)
    C_rec = refined.T_b1_w @ scaled(scene.reconstruction.T_w_c[rows], refined.scale)
    off = np.linalg.norm(C_rec[:, :3, 3] - kinematic_camera_poses(refined, arms, E)[:, :3, 3], axis=1)
    assert np.median(off) < 0.02
    assert np.allclose(refined.T_b2_w, inv_T(refined.T_b1_b2) @ refined.T_b1_w)
    assert "point-map refinement" in refined.uncertainty["estimator"]
    assert pm["joint_solve"]["scale"] == plain.scale


def test_unusable_point_maps_leave_the_joint_solve_as_it_was(synth_paper):
    from bimanual_app.scene import load_scene
    from calibration import CalibrationOptions, calibrate, scene_cloud

    scene = load_scene(synth_paper)
    plain = calibrate(scene, options=CalibrationOptions(point_maps=False))
    rec = scene.reconstruction
    rng = np.random.default_rng(0)
    # every view's map scrambled: the surfaces of different views no longer overlap
    P = rec.pts3d.reshape(len(rec.pts3d), -1, 3)
    rec.pts3d = np.stack([p[rng.permutation(len(p))] for p in P]).reshape(rec.pts3d.shape)
    rec.pts3d += rng.normal(scale=0.2, size=rec.pts3d.shape).astype(rec.pts3d.dtype)
    res = calibrate(scene, options=REFINE)
    pm = res.info["point_maps"]
    assert not pm["accepted"] and pm["reason"]
    assert any("point-map refinement not applied" in w for w in res.warnings)
    for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2", "T_b1_w"):
        assert np.array_equal(getattr(res, key), getattr(plain, key)), key
    assert res.scale == plain.scale
    assert scene_cloud(scene, res)[2]["views_placed_by"] == "reconstruction"


def test_refinement_needs_two_views_per_arm():
    from calibration._pointmap_refine import refine_with_point_maps
    from tests._calib_fixtures import flat_views

    views = flat_views()
    r = refine_with_point_maps(views, np.eye(4), np.eye(4), 1.0, np.eye(4))
    assert not r.accepted and "2 or more point maps per arm" in r.reason and "2 / 1" in r.reason


def test_kinematic_anchor_moves_each_map_with_its_camera():
    from types import SimpleNamespace

    from calibration._api import _kinematic_anchor, kinematic_camera_poses

    rng = np.random.default_rng(2)
    res = SimpleNamespace(T_e1_c1=make_T(so3_exp([0.1, 0.2, 0.3]), [0.05, 0.0, 0.04]),
                          T_e2_c2=make_T(so3_exp([0.0, -0.2, 0.1]), [0.06, 0.01, 0.03]),
                          T_b1_b2=make_T(so3_exp([0.0, 0.0, 3.0]), [0.7, 0.0, 0.0]),
                          T_b1_w=make_T(so3_exp([0.4, -0.3, 1.0]), [0.2, -0.1, 0.3]), scale=0.8)
    arms = np.array([1, 2])
    E = np.stack([make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3) * 0.3) for _ in range(2)])
    T_w_c = np.stack([make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3)) for _ in range(2)])
    pc = rng.uniform(0.1, 0.6, (2, 4, 5, 3))  # camera-frame points, w units
    pw = np.einsum("vij,vhwj->vhwi", T_w_c[:, :3, :3], pc) + T_w_c[:, None, None, :3, 3]
    moved, C_w = _kinematic_anchor(pw, T_w_c, res, arms, E)
    back = np.einsum("vji,vhwj->vhwi", C_w[:, :3, :3], moved - C_w[:, None, None, :3, 3])
    assert np.allclose(back, pc)  # same map in its own camera frame
    C_b1 = res.T_b1_w @ np.stack([make_T(C[:3, :3], C[:3, 3] * res.scale) for C in C_w])
    assert np.allclose(C_b1, kinematic_camera_poses(res, arms, E))


def test_cli_writes_the_refinement_and_can_skip_it(synth_paper, tmp_path, capsys):
    from bimanual_app.cli import main

    assert main(["calibrate", str(synth_paper), "--out", str(tmp_path / "on"), "--estimator", "refine"]) == 0
    out = capsys.readouterr().out
    assert "point-map refinement: overlapping views" in out
    cal = json.loads((tmp_path / "on" / "calibration.json").read_text())
    assert cal["info"]["point_maps"]["accepted"] and cal["cloud"]["views_placed_by"] == "kinematics"
    assert (tmp_path / "on" / "point_maps.png").stat().st_size > 10_000
    assert main(["calibrate", str(synth_paper), "--out", str(tmp_path / "off"), "--no-point-maps"]) == 0
    cal = json.loads((tmp_path / "off" / "calibration.json").read_text())
    assert "point_maps" not in cal["info"] and cal["cloud"]["views_placed_by"] == "reconstruction"
    assert not (tmp_path / "off" / "point_maps.png").exists()


def test_analytic_jacobian_matches_finite_differences():
    from calibration._pointmap_refine import _jacobian, _residuals
    from tests._calib_fixtures import random_pair_problem

    views, start, pairs = random_pair_problem()
    J = _jacobian(np.zeros(19), views, start, pairs)
    h = 1e-6
    Jn = np.stack([(_residuals(h * e, views, start, pairs) - _residuals(-h * e, views, start, pairs)) / (2 * h)
                   for e in np.eye(19)], axis=1)
    assert np.abs(Jn).max() > 0.1
    assert np.allclose(J, Jn, atol=1e-7)


def test_maps_a_pinhole_does_not_fit_are_matched_by_nearest_neighbour(synth_paper, monkeypatch):
    import calibration._pointmaps as pm
    from bimanual_app.scene import load_scene
    from calibration import CalibrationOptions, calibrate, scene_cloud

    scene = load_scene(synth_paper)
    plain = calibrate(scene, options=CalibrationOptions(point_maps=False))
    monkeypatch.setattr(pm, "pointmap_intrinsics", lambda P, ok: np.full(4, np.nan))
    used = []
    real = pm._nearest_partners
    monkeypatch.setattr(pm, "_nearest_partners", lambda *a, **k: used.append(1) or real(*a, **k))
    res = calibrate(scene, options=REFINE)
    assert used and res.info["point_maps"]["accepted"], res.info["point_maps"]["reason"]
    e_plain = _cloud_error_mm(synth_paper, scene_cloud(scene, plain)[0])
    e_ref = _cloud_error_mm(synth_paper, scene_cloud(scene, res)[0])
    assert e_ref < 0.3 * e_plain, (e_plain, e_ref)


def test_exact_capture_keeps_its_exact_calibration(synth_none):
    """Noise-free: the joint solve is exact and the point maps already agree; whatever the refinement
    concludes, the result stays at the truth (a refinement must not pull an exact answer off)."""
    from bimanual_app.scene import load_scene
    from calibration import calibrate

    scene = load_scene(synth_none)
    res = calibrate(scene, options=REFINE)
    pm = res.info["point_maps"]
    assert pm["accepted"] or pm["reason"]
    gt = scene.ground_truth
    for T, T_true in ((res.T_e1_c1, gt.T_e1_c1), (res.T_e2_c2, gt.T_e2_c2), (res.T_b1_b2, gt.T_b1_b2)):
        assert np.degrees(rotation_angle_between(T[:3, :3], T_true[:3, :3])) < 0.05
        assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 0.001
    assert abs(res.scale / gt.scale - 1) < 0.001


def test_find_pairs_with_samples_of_different_lengths_equals_a_plain_loop():
    """find_pairs looks up every view's samples in all its partners at once (padded arrays); with views of
    different sizes (one with no samples) it gives the pairs a plain loop over the view pairs gives."""
    from scipy.spatial import cKDTree

    from calibration._pointmaps import MIN_NORMAL_COS, PointMapView, _partner_views, _robot_column, find_pairs

    rng = np.random.default_rng(3)
    views = []
    for v, n in enumerate((300, 120, 0, 250, 80, 200)):
        pts = rng.uniform(-0.15, 0.15, (n, 3)) + [0, 0, 0.5]
        nrm = np.tile([0.0, 0.0, -1.0], (n, 1)) + rng.normal(scale=0.2, size=(n, 3))
        views.append(PointMapView(1 if v < 3 else 2, np.eye(4), pts, nrm / np.linalg.norm(nrm, axis=1, keepdims=True)))
    Tc = np.stack([make_T(so3_exp(rng.normal(scale=0.05, size=3)), rng.normal(scale=0.01, size=3) + [0.6, 0, 0])
                   for _ in views])
    sv, Tb, radius = np.full(6, 1.1), make_T(so3_exp([0, 0, 3.0]), [1.5, 0, 0]), 0.02
    samples = [rng.choice(len(v.points_c), min(60, len(v.points_c)), replace=False) for v in views]
    targets = [np.arange(len(v.points_c)) for v in views]
    got = find_pairs(views, samples, targets, Tc, sv, Tb, radius)
    place = [sv[k] * v.points_c @ T[:3, :3].T + T[:3, 3] for k, (v, T) in enumerate(zip(views, Tc))]
    want = []
    for a, partners in enumerate(_partner_views(views, Tc)):
        Pa = place[a][samples[a]]
        for b in partners:
            if not len(place[b]) or not len(Pa):
                continue
            d, j = cKDTree(place[b]).query(Pa, distance_upper_bound=radius)
            Na, Nb = views[a].normals_c[samples[a]] @ Tc[a, :3, :3].T, views[b].normals_c[np.minimum(j, len(place[b]) - 1)] @ Tc[b, :3, :3].T
            ok = np.isfinite(d) & ~_robot_column(Pa, Tb) & (np.abs(np.sum(Na * Nb, axis=1)) >= MIN_NORMAL_COS)
            want += [(a, int(s), b, int(jj)) for s, jj in zip(samples[a][ok], j[ok])]
    assert len(want) > 50
    pa_rows = {tuple(p) for p in got.pa}
    assert len(got) == len(want) and sorted(np.bincount(got.va, minlength=6)) == sorted(
        np.bincount([w[0] for w in want], minlength=6))
    assert all(tuple(views[a].points_c[s]) in pa_rows for a, s, _, _ in want)
