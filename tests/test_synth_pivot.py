"""The emulator's pose errors that turn about a point ahead of the camera (``pose_pivot_m``, issue 21).

A real reconstruction's pose errors mostly turn each camera about a scene point it looks at, so the
camera centre errs by about ``l x dphi``. With ``pose_pivot_m = l`` the emulator makes such errors; with the
default (0) every number is the one the camera-centre model gave before the option existed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from bimanual_app.cli import main as cli_main
from bimanual_app.io_utils import InputError
from bimanual_app.scene import load_scene
from bimanual_app.synth import NOISE_LEVELS, make_synthetic_scene
from bimanual_app.synth._emulator import perturb_poses
from bimanual_app.transforms import make_T, rotation_angle, so3_exp
from tests._synth_fixtures import reported_T_b1_c, true_T_b1_c


def _true_poses(n: int, seed: int = 0) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    return make_T(Rotation.random(n, random_state=rng).as_matrix(), rng.normal(scale=0.3, size=(n, 3)))


def test_default_level_draws_and_returns_what_the_camera_centre_model_did():
    """Without a pivot: the same random draws, reported rotation R exp(w) and centre c + dt, bit for bit."""
    T = _true_poses(50)
    lvl = NOISE_LEVELS["paper"]
    assert lvl.pivot_m == 0.0
    out = np.zeros(50, bool)
    out[[3, 17]] = True
    got = perturb_poses(T, lvl, out, np.random.default_rng(7))
    rng = np.random.default_rng(7)  # the draws of the camera-centre model, in its order
    w = rng.normal(scale=np.deg2rad(lvl.rot_deg) / np.sqrt(3.0), size=(50, 3))
    dt = rng.normal(scale=lvl.trans_m / np.sqrt(3.0), size=(50, 3))
    v = rng.normal(size=(2, 3))
    w[out] = v / np.linalg.norm(v, axis=1, keepdims=True) * np.deg2rad(rng.uniform(10.0, 40.0, 2))[:, None]
    v = rng.normal(size=(2, 3))
    dt[out] = v / np.linalg.norm(v, axis=1, keepdims=True) * rng.uniform(0.10, 0.30, 2)[:, None]
    want = make_T(T[:, :3, :3] @ so3_exp(w), T[:, :3, 3] + dt)
    assert np.array_equal(got[0], want)
    assert np.array_equal(got[1], np.linalg.norm(w, axis=1)) and np.array_equal(got[2], np.linalg.norm(dt, axis=1))


@pytest.mark.parametrize("ell", [0.5, 1.0])
def test_pivot_errors_turn_about_the_point_ahead_and_move_the_centre_by_l_dphi(ell):
    """Rotation errors only (no centre noise of their own): the point ``ell`` ahead on the optical axis stays
    where it was, the centre moves by ``|(R - R') (0, 0, ell)|`` = ``ell x`` the rotation error's part across
    the axis, and the RMS centre error is ``ell x`` the RMS rotation error x sqrt(2/3) (small angles)."""
    n = 4000
    T = _true_poses(n, seed=1)
    lvl = replace(NOISE_LEVELS["paper"], trans_m=0.0, pivot_m=ell)
    Tr, rot, centre = perturb_poses(T, lvl, np.zeros(n, bool), np.random.default_rng(2))
    base = perturb_poses(T, replace(lvl, pivot_m=0.0), np.zeros(n, bool), np.random.default_rng(2))[0]
    assert np.array_equal(Tr[:, :3, :3], base[:, :3, :3]), "the pivot changes where the camera is, not how it turns"
    p_true = T[:, :3, 3] + ell * T[:, :3, 2]
    p_rep = Tr[:, :3, 3] + ell * Tr[:, :3, 2]
    assert np.abs(p_rep - p_true).max() < 1e-12
    moved = np.linalg.norm(Tr[:, :3, 3] - T[:, :3, 3], axis=1)
    assert np.allclose(centre, moved, atol=1e-12)
    dR = np.einsum("nji,njk->nik", T[:, :3, :3], Tr[:, :3, :3])  # the error in the camera frame
    across = np.sqrt(dR[:, 0, 2] ** 2 + dR[:, 1, 2] ** 2)  # sin of how far the optical axis turned
    assert np.allclose(moved, ell * np.sqrt(across ** 2 + (1.0 - dR[:, 2, 2]) ** 2), atol=1e-12)
    assert np.all(moved <= ell * rot + 1e-12)
    rms_rot = np.sqrt(np.mean(rotation_angle(dR) ** 2))
    assert np.sqrt(np.mean(moved ** 2)) == pytest.approx(ell * rms_rot * np.sqrt(2.0 / 3.0), rel=0.02)


def test_pivot_adds_to_the_levels_centre_noise_and_spares_outliers():
    """With centre noise: the centre error is the level's offset plus the turn's move (same draws); outlier
    views keep their gross error exactly as without a pivot."""
    n = 40
    T = _true_poses(n, seed=3)
    out = np.zeros(n, bool)
    out[5] = True
    lvl = NOISE_LEVELS["harsh"]
    a = perturb_poses(T, lvl, out, np.random.default_rng(4))
    b = perturb_poses(T, replace(lvl, pivot_m=1.2), out, np.random.default_rng(4))
    assert np.array_equal(a[0][:, :3, :3], b[0][:, :3, :3]) and np.array_equal(a[1], b[1])
    assert np.array_equal(a[0][5], b[0][5])
    turn = (T[:, :3, :3] - a[0][:, :3, :3]) @ np.array([0.0, 0.0, 1.2])
    ok = ~out
    assert np.allclose(b[0][ok, :3, 3] - a[0][ok, :3, 3], turn[ok], atol=1e-12)


def test_scene_with_a_pivot_differs_from_the_default_only_in_the_camera_centres(tmp_path):
    """Same seed, poses-only: ``pose_pivot_m=0`` is the default scene file for file; with 1 m the reported
    rotations are the default's, each camera's point 1 m ahead is where the default's noise put it, the
    centre errors are about 1 m x the rotation errors, and the ground truth records the pivot."""
    kw = dict(seed=5, views=6, objects=2, noise="paper", render=False, progress=False, preview=False)
    d = make_synthetic_scene(tmp_path / "d", **kw)
    z = make_synthetic_scene(tmp_path / "z", pose_pivot_m=0.0, **kw, name="d")
    for f in ("scene.yaml", "ground_truth.yaml", "primary/ee_poses.csv", "secondary/ee_poses.csv",
              "reconstruction.npz"):
        assert (d / f).read_bytes() == (z / f).read_bytes(), f
    p = make_synthetic_scene(tmp_path / "p", pose_pivot_m=1.0, **kw)
    sd, sp = load_scene(d), load_scene(p)
    Td, Tp, Tt = reported_T_b1_c(sd), reported_T_b1_c(sp), true_T_b1_c(sp)
    assert np.allclose(Td[:, :3, :3], Tp[:, :3, :3], atol=1e-9)
    ahead = np.array([0.0, 0.0, 1.0, 1.0])
    assert np.allclose((Tp @ ahead)[:, :3] - Tt[:, :3, 3] - Tt[:, :3, 2], Td[:, :3, 3] - Tt[:, :3, 3], atol=1e-9)
    gt = yaml.safe_load((p / "ground_truth.yaml").read_text())
    assert gt["noise"]["pose_pivot_m"] == 1.0 and gt["synthetic"]["pose_pivot_m"] == 1.0
    assert "pose_pivot_m" not in yaml.safe_load((d / "ground_truth.yaml").read_text())["noise"]
    rot = np.deg2rad(np.concatenate([gt["pose_errors"][a]["rot_deg"] for a in ("primary", "secondary")]))
    centre = np.linalg.norm(Tp[:, :3, 3] - Tt[:, :3, 3], axis=1)
    assert np.all(centre <= 1.0 * rot + 0.05)  # the turn's move, plus the level's centre noise (10 mm RMS)
    # what the pivot adds to each centre is the 1 m lever's chord: at most the rotation error x 1 m, and on
    # average pi/4 of it over random axes (the chord shrinks as the axis nears the optical axis)
    turn = np.linalg.norm(Tp[:, :3, 3] - Td[:, :3, 3], axis=1)
    assert np.all(turn <= 1.0 * rot + 1e-9) and turn.sum() > 0.5 * rot.sum()


def test_cli_option_and_bad_pivot(tmp_path, capsys):
    path = tmp_path / "c"
    assert cli_main(["synth", str(path), "--seed", "2", "--views", "3", "--objects", "1", "--no-render",
                     "--quiet", "--pose-pivot-m", "0.8"]) == 0
    assert yaml.safe_load((path / "ground_truth.yaml").read_text())["noise"]["pose_pivot_m"] == 0.8
    with pytest.raises(InputError, match="pose_pivot_m"):
        make_synthetic_scene(tmp_path / "bad", seed=0, views=3, objects=1, render=False, pose_pivot_m=-1.0)
