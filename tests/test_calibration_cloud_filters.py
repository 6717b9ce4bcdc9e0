"""The metric cloud's self filters: each wrist camera's view of its own gripper, and points other views see
through (a misregistered view's phantom surface), on point maps rendered here from known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from bimanual_app.transforms import make_T
from calibration._fusion import confirmed_points, free_space_outliers, pointmap_intrinsics, view_votes
from calibration._selfmask import wrist_rig_pixels

H, W, F = 48, 64, 50.0


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(4,4) T_w_c of a camera at ``eye`` looking at ``target`` (z forward, y down)."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=1), eye)


def render_plane(T_w_c: np.ndarray, height: float = 0.0) -> np.ndarray:
    """(H,W,3) points in w where the pixel rays hit the plane z = height (NaN where they miss)."""
    cols, rows = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays_c = np.stack([(cols - W / 2) / F, (rows - H / 2) / F, np.ones_like(cols)], axis=-1)
    rays_w = rays_c @ T_w_c[:3, :3].T
    o = T_w_c[:3, 3]
    s = (height - o[2]) / rays_w[..., 2]
    P = o + s[..., None] * rays_w
    P[~(s > 0)] = np.nan
    return P


def views(n: int = 8, radius: float = 0.5, up: float = 0.45) -> np.ndarray:
    ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.stack([look_at(np.array([radius * np.cos(a), radius * np.sin(a), up]), np.zeros(3)) for a in ang])


def test_pointmap_intrinsics_recovers_the_pinhole():
    T = views(1)[0]
    P = render_plane(T)
    Pc = (P - T[:3, 3]) @ T[:3, :3]
    K = pointmap_intrinsics(Pc, np.all(np.isfinite(Pc), axis=-1))
    assert np.allclose(K, [F, F, W / 2, H / 2], atol=1e-6)


def test_wrist_rig_pixels_finds_the_fingers_and_nothing_else():
    T = views(8)
    maps = np.stack([render_plane(t) for t in T])
    # the fingers: a patch at the bottom of every image, 12 cm in front of the camera (camera frame)
    rig = np.zeros((H, W), bool)
    rig[40:, 20:44] = True
    cols, rows = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    finger_c = np.stack([(cols - W / 2) / F, (rows - H / 2) / F, np.ones_like(cols)], -1) * 0.12
    for v, t in enumerate(T):
        noise = 1 + 0.01 * np.random.default_rng(v).standard_normal((H, W, 1))  # 1 % depth noise
        maps[v][rig] = (finger_c[rig] * noise[rig]) @ t[:3, :3].T + t[:3, 3]
    found = wrist_rig_pixels(maps, T)
    assert found.shape == (H, W)
    assert found[rig].all()
    assert not found[~rig].any()
    # too few views to tell the rig from the scene
    assert not wrist_rig_pixels(maps[:2], T[:2]).any()
    with pytest.raises(ValueError, match="T_w_c"):
        wrist_rig_pixels(maps, T[:3])


def test_free_space_drops_a_misregistered_layer_and_keeps_the_table():
    T = views(8)
    maps = np.stack([render_plane(t) for t in T])
    ghost = render_plane(T[0], height=0.04)  # view 0's table 4 cm too high: a phantom layer
    maps[0] = ghost
    out = free_space_outliers(maps, T)
    assert out.shape == maps.shape[:3]
    seen = np.all(np.isfinite(maps), axis=-1)
    # most of the phantom layer goes (its rim is seen by no other view)
    assert out[0][seen[0]].mean() > 0.8
    # the consistent views keep (nearly) all of their table
    assert out[1:][seen[1:]].mean() < 0.01


def test_free_space_keeps_a_real_object_seen_by_all_views():
    T = views(8)
    maps = np.stack([render_plane(t) for t in T])
    box = np.zeros((len(T), H, W), bool)
    # a tall thin post at the origin: pixels whose table point lies within 3 cm of it show the post instead
    for v, t in enumerate(T):
        P = maps[v]
        r = np.linalg.norm(P[..., :2], axis=-1)
        hit = r < 0.03
        o = t[:3, 3]
        d = P[hit] - o
        # move the hit along its ray to the post's side facing the camera (radius 3 cm cylinder, crude)
        s = 1.0 - 0.03 / np.maximum(np.linalg.norm(d[:, :2], axis=1), 1e-9)
        P[hit] = o + d * np.clip(s, 0.5, 1.0)[:, None]
        box[v] = hit
    out = free_space_outliers(maps, T)
    assert out[box].mean() < 0.05


def test_confirmed_points_are_the_ones_other_views_saw_there_too():
    T = views(8)
    maps = np.stack([render_plane(t) for t in T])
    # view 0: a floating blob 3 cm over the table (other views see the table through it) and a patch pushed
    # 10 % of its depth along its rays, under the table: the other views cannot see it (no vote either way)
    blob = np.zeros((H, W), bool)
    blob[20:28, 28:36] = True
    o = T[0][:3, 3]
    d = maps[0][blob] - o
    maps[0][blob] = o + d * ((0.03 - o[2]) / d[:, 2])[:, None]
    pushed = np.zeros((H, W), bool)
    pushed[8:14, 10:20] = True
    maps[0][pushed] = o + (maps[0][pushed] - o) * 1.10
    votes = view_votes(maps, T)
    against, support, confirm, ok = votes
    assert against.shape == support.shape == confirm.shape == ok.shape == maps.shape[:3]
    out = confirmed_points(votes)
    seen_by_others = confirm[0] >= 2
    assert not out[0][blob].any() and (against[0][blob] >= 1).mean() > 0.5  # seen through, never confirmed
    assert not out[0][pushed].any() and against[0][pushed].max() == 0  # not seen through, not confirmed either
    table = ok[0] & ~blob & ~pushed & seen_by_others
    assert table.sum() > 0.3 * H * W and out[0][table].all()  # the table where other views saw it
    assert out[1:][ok[1:]].mean() > 0.7
    # the same counts as the see-through test's own
    assert np.array_equal(free_space_outliers(maps, T, votes=votes), free_space_outliers(maps, T))
    assert np.array_equal(confirmed_points(votes, min_views=99), np.zeros_like(out))


def test_free_space_stands_down_when_maps_do_not_fit_a_pinhole_or_disagree_wholesale():
    T = views(8)
    maps = np.stack([render_plane(t) for t in T])
    # a map resampled with a warp is no pinhole image: its intrinsics are not trusted (it does not vote)
    warped = maps[1].copy()
    warped[:, :, :] = maps[1][:, ::-1, :][:, np.argsort(np.random.default_rng(0).random(W)), :][:, ::-1, :]
    Pc = (warped - T[1][:3, 3]) @ T[1][:3, :3]
    assert np.all(np.isnan(pointmap_intrinsics(Pc, np.all(np.isfinite(Pc), axis=-1))))
    # half the views registered 6 cm above the other half (maps and poses together): the two halves see
    # through each other's table, the filter would drop a third of all points, so it drops none
    shifted, smaps = T.copy(), maps.copy()
    shifted[::2, 2, 3] += 0.06
    smaps[::2, ..., 2] += 0.06
    maps = smaps
    out = free_space_outliers(maps, shifted)
    assert not out.any()
    import calibration._fusion as fusion

    try:  # (without the stand-down it would have dropped more than a quarter of the points)
        fusion.MAX_DROP_FRACTION = 1.0
        seen = np.all(np.isfinite(maps), axis=-1)
        assert free_space_outliers(maps, shifted)[seen].mean() > 0.25
    finally:
        fusion.MAX_DROP_FRACTION = 0.25


def test_the_cloud_keeps_the_object_sides_other_views_confirm(synth_paper):
    """On a rendered capture the maps mark the steep sides of the objects unsure (low confidence); those
    other views saw too come back, and the cloud gains no stray points for them."""
    from scipy.spatial import cKDTree

    from bimanual_app.scene import load_scene
    from bimanual_app.scene.truth import ground_truth_cloud
    from calibration import calibrate, scene_cloud

    scene = load_scene(synth_paper)
    res = calibrate(scene)
    true_pts, _, true_ids = ground_truth_cloud(synth_paper, voxel=0.002)
    objects = true_pts[true_ids >= 0]

    def quality(points):  # (share of the true objects' surface within 5 mm, share of points 1 cm off it)
        covered = cKDTree(points).query(objects, k=1)[0] < 0.005
        stray = cKDTree(true_pts).query(points, k=1)[0] > 0.01
        return covered.mean(), stray.mean()

    plain, _, info_plain = scene_cloud(scene, res)  # the default: off
    both, _, info = scene_cloud(scene, res, confirm_unsure=True)
    assert "unsure_points_confirmed" not in info_plain and info["unsure_points_confirmed"] > 0
    assert len(both) == len(plain) + info["unsure_points_confirmed"] - (info["robot_points_removed"]
                                                                        - info_plain["robot_points_removed"])
    (cov0, stray0), (cov1, stray1) = quality(plain), quality(both)
    assert cov1 > cov0 + 0.1, (cov0, cov1)  # measured: 0.49 -> 0.68
    assert stray1 < stray0 + 0.002, (stray0, stray1)  # measured: 1.31 % -> 1.22 %


def test_calibrate_writes_the_unsure_flag_only_when_asked(synth_paper, tmp_path):
    from calibration import calibrate_stage
    from segmentation import read_cloud, read_unsure

    plain = calibrate_stage(synth_paper, tmp_path / "plain", figure=False)
    flagged = calibrate_stage(synth_paper, tmp_path / "flagged", figure=False, confirm_unsure=True)
    assert read_unsure(plain.files["scene_b1.ply"]) is None
    import json

    cloud_info = {k: json.loads((st.out / "calibration.json").read_text())["cloud"] for k, st in
                  (("plain", plain), ("flagged", flagged))}
    assert "unsure_points_confirmed" not in cloud_info["plain"] and cloud_info["flagged"]["unsure_points_confirmed"] > 0
    P = read_cloud(flagged.files["scene_b1.ply"])[0]
    U = read_unsure(flagged.files["scene_b1.ply"], len(P))
    assert U is not None and 0 < U.sum() < len(P)
    assert len(P) - U.sum() == len(read_cloud(plain.files["scene_b1.ply"])[0])  # the sure points are the same


def test_the_cli_flag_keeps_the_confirmed_points(synth_paper, tmp_path):
    from bimanual_app.cli import main
    from segmentation import read_cloud, read_unsure

    assert main(["calibrate", str(synth_paper), "--out", str(tmp_path / "c"), "--no-figure", "--quiet",
                 "--confirm-unsure"]) == 0
    ply = tmp_path / "c" / "scene_b1.ply"
    flags = read_unsure(ply, len(read_cloud(ply)[0]))
    assert flags is not None and flags.any()
