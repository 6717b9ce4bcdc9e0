"""Plane-sweep densification and point-map grid conventions, on rendered views with known poses."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from _recon_fixtures import camera_poses, make_world, ray_cast

from bimanual_app.reconstruction._dense import (
    DenseOptions,
    _mean_of_top,
    choose_sources,
    consistency_counts,
    fit_plane,
    plane_sweep,
    sweep_planes,
)
from bimanual_app.reconstruction._pointmap import (
    box_to_model,
    grid_pixels,
    intrinsics_from_box,
    intrinsics_in_box,
    pixels_to_cells,
    sample_nearest,
)
from bimanual_app.scene import CameraIntrinsics
from bimanual_app.transforms import apply_T, inv_T

W, H = 256, 192
K = CameraIntrinsics(W, H, 0.9 * W, 0.9 * W, (W - 1) / 2, (H - 1) / 2).K


@pytest.fixture(scope="module")
def views():
    world = make_world(0)
    poses = camera_poses(3, seed=0)
    Ts = np.concatenate([poses["primary"], poses["secondary"]])
    imgs, depths = [], []
    for T in Ts:
        img, P = ray_cast(T, K, W, H, world["boxes"], world["table_tex"])
        imgs.append(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255)
        depths.append(apply_T(inv_T(T), P.reshape(-1, 3))[:, 2].reshape(H, W))
    return Ts, imgs, depths


def test_plane_sweep_along_the_table_normal_recovers_depth(views):
    Ts, imgs, depths = views
    heights = np.linspace(-0.01, 0.12, 48)
    nb = [[1, 2], [0, 2], [0, 1]]
    ds = []
    for i in range(3):
        n_c, c = sweep_planes(np.array([0.0, 0.0, 1.0]), 0.0, heights, Ts[i])
        d, s = plane_sweep(imgs[i], K, Ts[i], [(imgs[j], K, Ts[j]) for j in nb[i]], n_c, c, DenseOptions())
        assert np.all(s[d > 0] >= DenseOptions().min_score) and np.all(s[d == 0] == -1)
        ds.append(d)
    ok = ds[0] > 0
    rel = np.abs(ds[0][ok] - depths[0][ok]) / depths[0][ok]
    assert ok.mean() > 0.4 and np.median(rel) < 0.003
    # the multi-view consistency check keeps the right depths and drops most wrong ones
    keep = consistency_counts(ds, [K] * 3, Ts[:3], nb, rel_tol=0.01)[0] >= 1
    rel_kept = np.abs(ds[0][keep] - depths[0][keep]) / depths[0][keep]
    assert keep.mean() > 0.3 and np.mean(rel_kept < 0.02) > 0.95 > np.mean(rel < 0.02)


def test_consistency_rejects_depths_the_other_views_contradict(views):
    Ts, imgs, depths = views
    noisy = [depths[0] * (1 + 0.2 * (np.random.default_rng(0).random((H, W)) > 0.5)), depths[1], depths[2]]
    counts = consistency_counts(noisy, [K] * 3, Ts[:3], [[1, 2], [0, 2], [0, 1]], rel_tol=0.01)
    wrong = noisy[0] != depths[0]
    assert np.mean(counts[0][wrong] == 0) > 0.95
    assert np.mean(counts[0][~wrong] >= 1) > 0.6  # right depths seen by another view agree


def test_fit_plane_and_sources():
    rng = np.random.default_rng(0)
    table = np.c_[rng.uniform(-1, 1, (400, 2)), rng.normal(0, 0.002, 400)]
    boxes = rng.uniform(-0.2, 0.2, (100, 3)) + [0, 0, 0.3]
    n, d, frac = fit_plane(np.r_[table, boxes], centres=np.array([[0, 0, -2.0]]), threshold=0.01)
    assert abs(abs(n[2]) - 1) < 1e-3 and n[2] < 0  # oriented towards the camera below
    assert 0.75 < frac < 0.85
    obs = [np.arange(0, 50), np.arange(10, 60), np.arange(45, 100), np.arange(200, 210)]
    src = choose_sources(obs, k=2, min_shared=8)
    assert src[0] == [1] and src[1] == [0, 2] and src[3] in ([0], [1], [2])


def test_mean_of_top_matches_sorting():
    rng = np.random.default_rng(1)
    for S in range(1, 6):
        a = [rng.random((4, 5)).astype(np.float32) for _ in range(S)]
        top = max(1, (S + 1) // 2)
        np.testing.assert_allclose(_mean_of_top(a, top), np.sort(np.stack(a), 0)[S - top:].mean(0), rtol=1e-6)


def test_grid_convention_and_boxes():
    g = grid_pixels((640, 480), (160, 120))
    np.testing.assert_allclose(g[0, 0], [1.5, 1.5])      # centre of the first 4x4 block
    np.testing.assert_allclose(g[-1, -1], [637.5, 477.5])
    cells = pixels_to_cells(g.reshape(-1, 2), (640, 480), (160, 120))
    np.testing.assert_array_equal(cells.reshape(120, 160, 2)[..., 0], np.tile(np.arange(160), (120, 1)))
    # a model grid covering a crop box: intrinsics there and back, pixel mapping consistent with them
    K0 = np.array([[600.0, 0, 319.5], [0, 610.0, 239.5], [0, 0, 1]])
    box, msize = np.array([80.0, -20.0, 560.0, 500.0]), (224, 224)
    Km = intrinsics_in_box(K0, box, msize)
    np.testing.assert_allclose(intrinsics_from_box(Km, box, msize), K0, atol=1e-9)
    X = np.array([0.1, -0.05, 1.0])
    p0, pm = (K0 @ X)[:2] / X[2], (Km @ X)[:2] / X[2]
    np.testing.assert_allclose(box_to_model(p0[None], box, msize)[0], pm, atol=1e-9)
    vals, inside = sample_nearest(np.arange(12.0).reshape(3, 4, 1), np.array([[0.4, 0.4], [3.4, 2.4], [4.6, 0], [1, 1]]),
                                  valid_size=(4, 2))
    assert inside.tolist() == [True, False, False, True] and vals[:, 0].tolist() == [0, 0, 0, 5]


def test_kinematic_check_flags_wrongly_registered_views():
    from bimanual_app.reconstruction._kinematic import inconsistent_views, motion_angle_errors
    from bimanual_app.transforms import make_T, random_T, so3_exp

    rng = np.random.default_rng(3)
    T_b_e = random_T(rng, 7, trans_scale=0.2)
    X = random_T(rng, trans_scale=0.05)
    T_w_b = random_T(rng, trans_scale=1.0)
    T_w_c = T_w_b @ T_b_e @ X
    T_w_c[:, :3, 3] *= 3.0  # the reconstruction's own scale: irrelevant to the check
    noisy = T_w_c @ make_T(so3_exp(rng.normal(0, np.deg2rad(0.3), (7, 3))), np.zeros((7, 3)))
    assert np.max(motion_angle_errors(T_b_e, T_w_c)) < 1e-6
    assert not inconsistent_views(T_b_e, noisy).any()
    wrong = noisy.copy()
    wrong[2] = wrong[2] @ make_T(so3_exp(np.array([0.0, 0.6, 0.3])), np.zeros(3))  # ~38 deg off
    wrong[5] = wrong[5] @ make_T(so3_exp(np.array([1.2, 0.0, 0.0])), np.zeros(3))
    assert np.flatnonzero(inconsistent_views(T_b_e, wrong)).tolist() == [2, 5]
    assert not inconsistent_views(T_b_e[:2], wrong[:2]).any()  # too few views to judge
