"""Choosing a reconstruction by how well its camera motions agree with the robot's (kinematic agreement)."""

from __future__ import annotations

import numpy as np
import pytest
from _recon_fixtures import render_scene

from bimanual_app.reconstruction import ColmapOptions, build_reconstruction, reconstruct
from bimanual_app.reconstruction._agreement import arm_agreement, choose_attempt, motion_agreement
from bimanual_app.scene import load_scene
from bimanual_app.transforms import inv_T, make_T, random_T, so3_exp


def _arm(rng, n=8, scale=0.3):
    """End-effector poses and exactly consistent camera poses (frame w, units = metres / scale)."""
    X = random_T(rng, trans_scale=0.05)
    T_b_w = random_T(rng, trans_scale=0.5)
    T_b_e = random_T(rng, n, trans_scale=0.4)
    T_w_c = inv_T(T_b_w) @ T_b_e @ X
    T_w_c[:, :3, 3] /= scale
    return T_b_e, T_w_c


def _perturb(rng, T_w_c, rot_deg, trans):
    """Camera poses with a random rotation about the centre (RMS rot_deg) and centre offset (RMS trans, w units)."""
    n = len(T_w_c)
    w = rng.normal(scale=np.deg2rad(rot_deg) / np.sqrt(3), size=(n, 3))
    out = T_w_c.copy()
    out[:, :3, :3] = T_w_c[:, :3, :3] @ so3_exp(w)
    out[:, :3, 3] += rng.normal(scale=trans / np.sqrt(3), size=(n, 3))
    return out


def test_exact_motions_agree_and_recover_the_scale():
    rng = np.random.default_rng(0)
    T_b_e, T_w_c = _arm(rng, scale=0.3)
    a = arm_agreement(T_b_e, T_w_c)
    assert a["rot_deg"] < 1e-6 and a["trans_rel"] < 1e-9 and a["trans_mm"] < 1e-6
    assert a["scale"] == pytest.approx(0.3, rel=1e-9)
    assert a["views"] == 8 and a["pairs"] == 28


def test_noisier_camera_poses_score_worse_whatever_the_frame_and_scale():
    rng = np.random.default_rng(1)
    arms = {"primary": _arm(rng, scale=2.0), "secondary": _arm(rng, scale=2.0)}
    noisy = {k: (E, _perturb(rng, C, 0.3, 0.002)) for k, (E, C) in arms.items()}
    noisier = {k: (E, _perturb(rng, C, 1.5, 0.010)) for k, (E, C) in arms.items()}
    good, bad = motion_agreement(noisy), motion_agreement(noisier)
    assert 0 < good["score"] < bad["score"]
    assert good["rot_deg"] < bad["rot_deg"] and good["trans_rel"] < bad["trans_rel"]
    assert set(good["arms"]) == {"primary", "secondary"}
    # another frame and scale of the same reconstruction: the same agreement
    S = make_T(so3_exp(np.array([0.3, -1.0, 2.0])), np.array([1.0, 2.0, -3.0]))
    moved = {}
    for k, (E, C) in noisy.items():
        C2 = S @ C
        C2[:, :3, 3] *= 7.0
        moved[k] = (E, C2)
    assert motion_agreement(moved)["score"] == pytest.approx(good["score"], rel=1e-6)


def test_too_few_views_are_not_scored():
    rng = np.random.default_rng(2)
    T_b_e, T_w_c = _arm(rng, n=2)
    a = arm_agreement(T_b_e, T_w_c)
    assert np.isnan(a["rot_deg"]) and np.isnan(a["trans_rel"])
    assert motion_agreement({"primary": (T_b_e, T_w_c)})["score"] == np.inf


def test_choice_goes_by_views_then_agreement_then_points():
    # the best-agreeing attempt wins over one with more points when both register every view
    assert choose_attempt([True, True], [18, 18], [4412, 796], [1.3, 0.9]) == 1
    # an unusable attempt never wins while a usable one exists
    assert choose_attempt([False, True], [18, 16], [900, 500], [0.5, 1.0]) == 1
    # more registered views win over a better agreement on fewer views
    assert choose_attempt([True, True], [8, 13], [260, 871], [0.3, 0.6]) == 1
    # near-ties (within 5 %): more points
    assert choose_attempt([True, True, True], [18, 18, 18], [5000, 700, 800], [0.93, 0.90, 0.94]) == 0
    assert choose_attempt([True, True], [18, 18], [700, 800], [0.90, 0.99]) == 0  # 10 % apart: no tie
    # nothing scored: views, then points (the ladder's old rule)
    assert choose_attempt([True, True], [17, 18], [9000, 100], [np.inf, np.inf]) == 1
    assert choose_attempt([True, True], [18, 18], [100, 9000], [np.inf, np.inf]) == 1
    assert choose_attempt([False, False], [4, 5], [10, 5], [np.inf, np.inf]) == 1
    with pytest.raises(ValueError):
        choose_attempt([], [], [], [])


def test_colmap_keeps_the_attempt_its_agreement_prefers(tmp_path, monkeypatch):
    """With the denser features forced (thin-model threshold), both attempts register every view; a rigged
    agreement that prefers the first attempt keeps it although the second has more points."""
    from bimanual_app.reconstruction import _api

    root = tmp_path / "s"
    render_scene(root, views_per_arm=4, seed=0)
    real = _api._agreement
    calls = []

    def rigged(scene):
        agree = real(scene)

        def f(names, T):
            out = agree(names, T)
            calls.append(out["score"])
            out["score"] = float(len(calls))  # first scored attempt best
            return out
        return f

    monkeypatch.setattr(_api, "_agreement", rigged)
    opts = ColmapOptions(points_per_view=100000, reseeds=0)
    rec, info = build_reconstruction(load_scene(root), dense=False, colmap_options=opts, log=lambda s: None)
    scored = [a for a in info["attempts"] if a["agreement"]]
    assert len(scored) >= 2 and len(calls) == len(scored)
    assert info["chosen"] == scored[0]["name"] == "sift/default"
    assert max(a["points"] for a in scored) > scored[0]["points"]
    # the real agreement of a clean render is small: COLMAP's motions match the exact kinematics
    assert all(0 <= s < 0.5 for s in calls)
    ex = rec.extras
    assert ex["attempts"].tolist() == [a["name"] for a in info["attempts"]]
    assert ex["attempts"][int(ex["attempt_chosen"])] == "sift/default"
    assert ex["attempt_agreement"].shape == (len(info["attempts"]), 3)
    assert ex["attempt_views"].shape == (len(info["attempts"]), 2)


def test_agreement_is_written_and_read_back(tmp_path):
    root = tmp_path / "s"
    render_scene(root, views_per_arm=4, seed=0)
    res = reconstruct(root, dense=False, colmap_options=ColmapOptions(points_per_view=10), plot=False,
                      log=lambda s: None)
    ex = load_scene(root).reconstruction.extras
    k = int(ex["attempt_chosen"])
    assert ex["attempts"][k] == res.info["chosen"]
    rot, rel, score = ex["attempt_agreement"][k]
    assert 0 <= rot < 0.5 and 0 <= rel < 0.02 and score == pytest.approx(rot + rel / 0.02)
    assert ex["attempt_views"][k].tolist() == [4, 4]


def test_importers_record_their_agreement_and_it_sees_inverted_poses(tmp_path):
    """An importer's one model is scored too; storing VGGT's world-to-camera extrinsics as camera-to-world
    (every pose inverted) keeps every relative rotation angle, so the rotation-angle check cannot see it,
    but the camera motions no longer agree with the robot's after the hand-eye fit."""
    from _recon_fixtures import similarity, write_model_export

    root = tmp_path / "s"
    gt = render_scene(root, views_per_arm=4)
    scene = load_scene(root)
    f = write_model_export(tmp_path / "v.npz", "vggt", root, gt, similarity(), [5, 1, 6, 0, 3, 7, 2, 4])
    rec, info = build_reconstruction(scene, "vggt", input=f, log=lambda s: None)
    good = info["agreement"]
    assert good["rot_deg"] < 0.01 and good["trans_rel"] < 1e-3
    assert rec.extras["attempts"].tolist() == ["vggt"] and int(rec.extras["attempt_chosen"]) == 0
    assert rec.extras["attempt_agreement"][0, 2] == pytest.approx(good["score"])
    data = dict(np.load(f))
    E = data["extrinsic"]
    Rt = E[:, :3, :3].transpose(0, 2, 1)
    data["extrinsic"] = np.concatenate([Rt, -np.einsum("nij,nj->ni", Rt, E[:, :3, 3])[..., None]], 2)
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, **data)
    _, info_w = build_reconstruction(scene, "vggt", input=wrong, log=lambda s: None)
    assert info_w["inconsistent"] == []  # the rotation-angle check is blind to it
    assert info_w["agreement"]["score"] > 20 * good["score"] + 1.0
