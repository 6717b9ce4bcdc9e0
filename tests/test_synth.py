"""Synthetic captures: contract validity, exact geometry with noise none, outliers, reproducibility, CLI."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from PIL import Image
from scipy.spatial import cKDTree

from bimanual_app.cli import main as cli_main
from bimanual_app.io_utils import InputError
from bimanual_app.scene import load_scene, validate_scene
from bimanual_app.synth import NOISE_LEVELS, ground_truth_cloud, make_synthetic_scene
from bimanual_app.synth._camera import look_at, projection_matrix, view_matrix
from bimanual_app.synth._emulator import perturb_poses
from bimanual_app.synth._layout import sample_hand_eye
from bimanual_app.transforms import apply_T, inv_T, rotation_angle, rotation_angle_between
from tests._synth_fixtures import pointmaps_in_b1, reported_T_b1_c, true_T_b1_c, umeyama


def test_projection_matrix_renders_opencv_pixels():
    """A rendered rectangle covers exactly the pixels whose centres project inside it (u = fx X/Z + cx)."""
    import pybullet as p

    cid = p.connect(p.DIRECT)
    try:
        W, H, fx, fy, cx, cy = 64, 48, 50.0, 55.0, 30.2, 24.7
        # a box face at Z = 1 (camera frame = world frame), edges at fractional pixel positions
        u0, u1, v0, v1 = 10.3, 41.6, 7.4, 33.2
        x0, x1, y0, y1 = (u0 - cx) / fx, (u1 - cx) / fx, (v0 - cy) / fy, (v1 - cy) / fy
        vs = p.createVisualShape(p.GEOM_BOX, halfExtents=[(x1 - x0) / 2, (y1 - y0) / 2, 0.05], physicsClientId=cid)
        p.createMultiBody(0, -1, vs, basePosition=[(x0 + x1) / 2, (y0 + y1) / 2, 1.05], physicsClientId=cid)
        _, _, _, zbuf, seg = p.getCameraImage(W, H, view_matrix(np.eye(4)), projection_matrix(W, H, fx, fy, cx, cy, 0.1, 5.0),
                                              renderer=p.ER_TINY_RENDERER, physicsClientId=cid)
    finally:
        p.disconnect(cid)
    seg = np.reshape(seg, (H, W)) >= 0
    vv, uu = np.mgrid[0:H, 0:W]
    want = (uu > u0) & (uu < u1) & (vv > v0) & (vv < v1)
    assert np.array_equal(seg, want)


def test_look_at_points_the_optical_axis_at_the_target():
    T = look_at(np.array([0.3, -0.2, 0.4]), np.array([0.1, 0.1, 0.0]), roll=0.4)
    z = T[:3, 2]
    d = np.array([0.1, 0.1, 0.0]) - T[:3, 3]
    assert np.allclose(z, d / np.linalg.norm(d))
    assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)


def test_hand_eye_mounts_are_plausible():
    rng = np.random.default_rng(0)
    for _ in range(50):
        T = sample_hand_eye(rng)
        off_axis = np.linalg.norm(T[:2, 3])
        tilt = np.degrees(np.arccos(T[2, 2]))  # optical axis vs the approach axis (flange z)
        assert 0.045 < off_axis < 0.085 and 0.02 < T[2, 3] < 0.07
        assert tilt < 18.0


def test_perturbation_magnitudes_match_the_levels():
    rng = np.random.default_rng(1)
    T = np.repeat(np.eye(4)[None], 4000, axis=0)
    for name in ("low", "paper", "harsh"):
        lvl = NOISE_LEVELS[name]
        Tr, re, te = perturb_poses(T, lvl, np.zeros(len(T), bool), rng)
        assert np.sqrt(np.mean(np.degrees(rotation_angle(Tr[:, :3, :3])) ** 2)) == pytest.approx(lvl.rot_deg, rel=0.05)
        assert np.sqrt(np.mean(np.sum(Tr[:, :3, 3] ** 2, 1))) == pytest.approx(lvl.trans_m, rel=0.05)
    out = np.ones(len(T), bool)
    Tr, re, te = perturb_poses(T, NOISE_LEVELS["none"], out, rng)
    ang = np.degrees(rotation_angle(Tr[:, :3, :3]))
    assert ang.min() >= 10.0 - 1e-9 and ang.max() <= 40.0 + 1e-9
    assert te.min() >= 0.1 - 1e-12 and te.max() <= 0.3 + 1e-12


def test_synth_scene_passes_the_contract_checks(synth_none):
    scene, problems = validate_scene(synth_none)
    assert scene is not None, [str(p) for p in problems]
    assert not [p for p in problems if p.severity == "error"]
    assert scene.robot == "piper" and scene.ee_link == "link6"
    assert (scene.camera.width, scene.camera.height) == (640, 480)
    for arm in scene.arms:
        assert len(arm) == 3
        for i, key in enumerate(arm.images):
            img = np.asarray(Image.open(synth_none / arm.name / key))
            assert img.shape == (480, 640, 3) and img.dtype == np.uint8
            mask = np.asarray(Image.open(synth_none / arm.name / "masks" / f"{i:03d}.png"))
            assert mask.shape == (480, 640) and mask.dtype == np.uint8
    rec = scene.reconstruction
    assert rec.model == "synthetic" and rec.pts3d.shape == (6, 120, 160, 3) and rec.pts3d.dtype == np.float32
    assert rec.conf.shape == (6, 120, 160) and rec.colors.shape == (6, 120, 160, 3)
    assert (synth_none / "preview.png").stat().st_size > 10_000
    gt = scene.ground_truth
    kinds = [o["kind"] for o in gt.objects]
    assert kinds[0] == "large_box" and kinds[1] == "small_box" and len(kinds) == 3
    assert gt.objects[0]["needs_two_hands"] and max(gt.objects[0]["size"][:2]) >= 0.3
    assert gt.objects[1]["fits_gripper"] and min(gt.objects[1]["size"][:2]) <= 0.06
    # half of three objects touch: at least two objects name a neighbour
    assert sum(bool(o["touching"]) for o in gt.objects) >= 2
    # bases 0.5-0.7 m apart, facing each other
    assert 0.49 < np.linalg.norm(gt.T_b1_b2[:3, 3]) < 0.71
    assert np.degrees(rotation_angle(gt.T_b1_b2[:3, :3])) > 160


def test_views_are_distinct_and_look_at_the_table(synth_none):
    scene = load_scene(synth_none)
    data = yaml.safe_load((synth_none / "ground_truth.yaml").read_text())
    T_cams = true_T_b1_c(scene)
    for arm in scene.arms:
        R = arm.T_b_e[:, :3, :3]
        ang = np.degrees(rotation_angle_between(R[:, None], R[None, :]))
        assert ang[~np.eye(len(R), dtype=bool)].min() > 15.0
        assert data["viewpoints"][arm.name]["min_pair_rotation_deg"] > 15.0
        assert np.linalg.norm(arm.T_b_e[:, :3, 3], axis=1).max() < 0.65  # within the Piper's reach
    # every camera is above the table and looks down at it
    assert np.all(T_cams[:, 2, 3] > 0.1) and np.all(T_cams[:, 2, 2] < -0.4)


def test_noise_none_poses_are_one_similarity_of_the_truth(synth_none):
    """The Done-when check: T_w_c equals T_b_e @ T_e_c (secondary via T_b1_b2) up to one similarity, to 1e-6."""
    scene = load_scene(synth_none)
    T_true = true_T_b1_c(scene)
    T_w_c = scene.reconstruction.T_w_c
    s, R, t = umeyama(T_true[:, :3, 3], T_w_c[:, :3, 3])
    # metric = scale * w units: the similarity's scale is 1 / scale
    assert s == pytest.approx(1.0 / scene.ground_truth.scale, rel=1e-9)
    centres = s * T_true[:, :3, 3] @ R.T + t
    assert np.abs(centres - T_w_c[:, :3, 3]).max() < 1e-6
    assert np.abs(R @ T_true[:, :3, :3] - T_w_c[:, :3, :3]).max() < 1e-6
    # and the ground truth's own frame agrees
    assert np.abs(reported_T_b1_c(scene) - T_true).max() < 1e-9


def test_noise_none_point_maps_land_on_the_true_geometry(synth_none):
    scene = load_scene(synth_none)
    gt = scene.ground_truth
    P = pointmaps_in_b1(scene)
    conf = scene.reconstruction.conf
    pts, cols, labels = ground_truth_cloud(synth_none)
    assert pts.dtype == np.float64 and cols.dtype == np.uint8 and labels.dtype == np.int32
    assert set(np.unique(labels)) <= set(range(-1, len(gt.objects)))
    tree = cKDTree(pts)
    # confident point-map points that see no robot (robot pixels are 0 in the ground-truth depth)
    M, h, w, _ = P.shape
    keep = []
    for m, (a, key) in enumerate(zip(scene.reconstruction.arm, scene.reconstruction.image)):
        arm = scene.arms[int(a) - 1]
        stem = key.split("/")[-1].split(".")[0]
        d = np.asarray(Image.open(synth_none / arm.name / "depth" / f"{stem}.png"))  # stride 2: 240 x 320
        static = d.reshape(h, 2, w, 2).min(axis=(1, 3)) > 0
        keep.append(static & (conf[m] >= 5.0) & (np.linalg.norm(P[m] - apply_T(true_T_b1_c(scene)[m], np.zeros(3)), axis=-1) < 1.0))
    keep = np.array(keep)
    assert keep.mean() > 0.3
    dist, _ = tree.query(P[keep])
    assert np.median(dist) < 1.0e-3 and np.percentile(dist, 95) < 2.5e-3
    # the table top is the plane z = 0 of b1: confident table points lie on it (no noise: sub-millimetre)
    # (on the table's footprint, away from the secondary's base plate, whose sides reach up to 3 cm)
    T_b1_t, size = np.array(gt.extras["table"]["T_b1_t"]), np.array(gt.extras["table"]["size"])
    on_top = np.all(np.abs(apply_T(inv_T(T_b1_t), pts)[:, :2]) < size[:2] / 2, axis=1)
    table = on_top & (np.abs(pts[:, 2]) < 0.01) & (np.linalg.norm(pts[:, :2] - gt.T_b1_b2[:2, 3], axis=1) > 0.13)
    assert np.abs(pts[table & (labels == -1), 2]).max() < 5e-4


def test_masks_agree_with_the_objects(synth_none):
    scene = load_scene(synth_none)
    pts, _, labels = ground_truth_cloud(synth_none)
    for o in scene.ground_truth.objects:
        k = o["id"]
        mine = pts[labels == k]
        assert len(mine) > 200, f"object {k} is barely visible"
        local = apply_T(inv_T(o["T_b1_o"]), mine)
        inside = np.all(np.abs(local) <= o["size"] / 2 + 2e-3, axis=1)
        assert inside.mean() > 0.99
    # points labelled table lie outside every object's box (or on its bottom face)
    tab = pts[labels == -1]
    for o in scene.ground_truth.objects:
        local = apply_T(inv_T(o["T_b1_o"]), tab)
        inside = np.all(np.abs(local) < o["size"] / 2 - 3e-3, axis=1)
        assert inside.mean() < 1e-3


def test_point_maps_follow_the_reported_poses(synth_outliers):
    """Each point map, taken back through its *reported* pose, re-projects onto its pixel grid."""
    scene = load_scene(synth_outliers)
    rec = scene.reconstruction
    K = scene.camera.K
    scale = scene.ground_truth.scale
    M, h, w, _ = rec.pts3d.shape
    u = (np.arange(w) + 0.5) * 640 / w - 0.5
    v = (np.arange(h) + 0.5) * 480 / h - 0.5
    for m in range(M):
        Pc = apply_T(inv_T(rec.T_w_c[m]), rec.pts3d[m].astype(np.float64)) * scale
        assert np.all(Pc[..., 2] > 0.01)
        uu = Pc[..., 0] / Pc[..., 2] * K[0, 0] + K[0, 2]
        vv = Pc[..., 1] / Pc[..., 2] * K[1, 1] + K[1, 2]
        # (float32 storage with 16 mantissa bits: a few hundredths of a pixel)
        assert np.abs(uu - u[None, :]).max() < 0.1 and np.abs(vv - v[:, None]).max() < 0.1


def test_outliers_perturb_exactly_the_chosen_views(synth_outliers):
    scene = load_scene(synth_outliers)
    extras = scene.ground_truth.extras
    T_true = true_T_b1_c(scene)
    T_rep = reported_T_b1_c(scene)
    rot = np.degrees(rotation_angle_between(T_true[:, :3, :3], T_rep[:, :3, :3]))
    trans = np.linalg.norm(T_true[:, :3, 3] - T_rep[:, :3, 3], axis=1)
    rec = scene.reconstruction
    names = ("primary", "secondary")
    for m, (a, key) in enumerate(zip(rec.arm, rec.image)):
        arm = names[int(a) - 1]
        if key in extras["outlier_views"][arm]:
            assert 10.0 - 1e-6 <= rot[m] <= 40.0 + 1e-6 and 0.1 - 1e-9 <= trans[m] <= 0.3 + 1e-9
        else:
            assert rot[m] < 7.0 and trans[m] < 0.05
        i = scene.arms[int(a) - 1].images.index(key)
        assert rot[m] == pytest.approx(extras["pose_errors"][arm]["rot_deg"][i], abs=1e-3)
    assert [len(extras["outlier_views"][n]) for n in names] == [1, 1]
    # the outlier's point map is consistent with its wrong pose, so it misses the true geometry
    pts, _, _ = ground_truth_cloud(synth_outliers)
    tree = cKDTree(pts)
    P = pointmaps_in_b1(scene)
    errs = []
    for m in range(len(rec)):
        good = rec.conf[m] >= 5.0
        errs.append(np.median(tree.query(P[m][good])[0]))
    out = np.array([key in extras["outlier_views"][names[int(a) - 1]] for a, key in zip(rec.arm, rec.image)])
    assert min(np.array(errs)[out]) > 3 * max(np.array(errs)[~out])


def test_seed_reproducible_and_render_independent(synth_none, tmp_path):
    """Same seed through the CLI without rendering: identical poses, ground truth and reconstruction poses."""
    fast = tmp_path / "fast"
    assert cli_main(["synth", str(fast), "--seed", "11", "--views", "3", "--objects", "3", "--noise", "none",
                     "--no-render", "--quiet"]) == 0
    assert cli_main(["check", str(fast)]) == 0
    for name in ("primary/ee_poses.csv", "secondary/ee_poses.csv", "scene.yaml"):
        assert (fast / name).read_text() == (synth_none / name).read_text().replace("name: none", "name: fast")
    a, b = load_scene(fast), load_scene(synth_none)
    assert np.array_equal(a.reconstruction.T_w_c, b.reconstruction.T_w_c)
    assert a.reconstruction.pts3d is None and not (fast / "primary" / "images").exists()
    ga = yaml.safe_load((fast / "ground_truth.yaml").read_text())
    gb = yaml.safe_load((synth_none / "ground_truth.yaml").read_text())
    for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2", "scale", "objects", "T_w_b1", "pose_errors"):
        assert ga[key] == gb[key]
    with pytest.raises(InputError):
        ground_truth_cloud(fast)


def test_other_seed_other_scene(synth_none, synth_outliers):
    a, b = load_scene(synth_none).ground_truth, load_scene(synth_outliers).ground_truth
    assert not np.allclose(a.T_b1_b2, b.T_b1_b2) and not np.allclose(a.T_e1_c1, b.T_e1_c1)


def test_joint_angle_csv_and_overwrite(tmp_path):
    """as_joints writes j1..j6 whose forward kinematics are the capture's poses; overwrite replaces a synth folder."""
    path = tmp_path / "j"
    path.mkdir()
    (path / "ground_truth.yaml").write_text("synthetic: {seed: 0}\n")
    (path / "stale.txt").write_text("old run")
    make_synthetic_scene(path, seed=3, views=3, objects=1, noise="low", render=False, as_joints=True,
                         overwrite=True, progress=False, preview=False)
    assert not (path / "stale.txt").exists()
    header = (path / "primary" / "ee_poses.csv").read_text().splitlines()[0]
    assert header == "image,j1,j2,j3,j4,j5,j6"
    scene = load_scene(path)
    gt = scene.ground_truth
    T_true = np.array([T @ gt.T_e1_c1 for T in scene.primary.T_b_e])
    T_rep = reported_T_b1_c(scene)[:3]
    assert np.degrees(rotation_angle_between(T_true[:, :3, :3], T_rep[:, :3, :3])).max() < 3.0
    assert np.abs(T_true[:, :3, 3] - T_rep[:, :3, 3]).max() < 0.02
    assert not list(tmp_path.glob(".*tmp-*")) and not list(tmp_path.glob(".*old-*")), "staging folders left behind"


def test_cli_refuses_bad_arguments_and_foreign_folders(tmp_path, capsys):
    other = tmp_path / "user"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert cli_main(["synth", str(other), "--no-render", "--quiet"]) == 1  # exists: refused
    assert cli_main(["synth", str(other), "--no-render", "--quiet", "--overwrite"]) == 1  # not a synth scene
    assert (other / "notes.txt").read_text() == "mine"
    assert cli_main(["synth", str(tmp_path / "bad"), "--views", "1", "--outliers", "0.9", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "exists and is not empty" in err and "not made by bijcr synth" in err
    assert "views" in err and "outlier" in err
    assert not (tmp_path / "bad").exists() and not list(tmp_path.glob(".*tmp-*"))


# ------------------------------------------------------------------ point-map error models (--map-noise)

def test_fm_depth_error_has_the_documented_parts():
    from bimanual_app.synth import MAP_NOISES, MapNoise
    from bimanual_app.synth._emulator import map_depth_error

    fm = MAP_NOISES["fm"]
    rng = np.random.default_rng(0)
    h, w = 60, 80
    y, x = np.meshgrid(np.linspace(-1, 1, h), np.linspace(-1, 1, w), indexing="ij")
    B = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], -1).reshape(-1, 6)
    scales, warps, rest, lag1 = [], [], [], []
    for _ in range(200):
        e, s = map_depth_error(fm, h, w, rng)
        assert e.shape == (h, w)
        scales.append(s)
        coef, *_ = np.linalg.lstsq(B, (e - s).ravel(), rcond=None)
        fit = (B @ coef).reshape(h, w)
        warps.append(np.sqrt(np.mean((fit - fit.mean()) ** 2)))
        r = (e - s) - fit
        rest.append(r.std())
        lag1.append(np.corrcoef(r[:, :-1].ravel(), r[:, 1:].ravel())[0, 1])
    assert np.std(scales) == pytest.approx(0.01, rel=0.15)          # per-view depth scale, 1 % sigma
    assert np.median(warps) == pytest.approx(0.005, rel=0.15)       # quadratic warp, RMS 0.5 %
    assert np.median(rest) == pytest.approx(0.003, rel=0.2)         # correlated noise, 0.3 %
    assert np.median(lag1) > 0.8                                    # neighbours correlated
    white = MapNoise("white", 0.0, 0.0, 0.001, 0.0)
    e, s = map_depth_error(white, h, w, rng)
    assert s == 0.0 and e.std() == pytest.approx(0.001, rel=0.1)
    assert abs(np.corrcoef(e[:, :-1].ravel(), e[:, 1:].ravel())[0, 1]) < 0.1


def test_fm_map_noise_scales_each_views_depth_along_its_reported_pose(synth_none, tmp_path):
    """Same seed with --map-noise fm: the same poses; every map point stays on its cell's ray of the reported
    camera, its depth off by the view's recorded depth scale error plus a smooth per-pixel part."""
    fm_path = make_synthetic_scene(tmp_path / "fm", seed=11, views=3, objects=3, noise="none", render=True,
                                   progress=False, preview=False, map_noise="fm")
    a, b = load_scene(synth_none), load_scene(fm_path)
    ra, rb = a.reconstruction, b.reconstruction
    assert np.array_equal(ra.T_w_c, rb.T_w_c) and np.array_equal(ra.conf, rb.conf)
    meta = yaml.safe_load((fm_path / "ground_truth.yaml").read_text())
    assert meta["synthetic"]["map_noise"] == "fm" and meta["noise"]["map_noise"]["depth_scale_rel_sigma"] == 0.01
    assert "map_errors" not in yaml.safe_load((synth_none / "ground_truth.yaml").read_text())
    s_err = np.concatenate([meta["map_errors"][arm]["depth_scale_rel"] for arm in ("primary", "secondary")])
    med, rms = [], []
    for k in range(len(ra)):
        T_c_w = inv_T(ra.T_w_c[k])
        pa = apply_T(T_c_w, ra.pts3d[k].reshape(-1, 3).astype(np.float64))
        pb = apply_T(T_c_w, rb.pts3d[k].reshape(-1, 3).astype(np.float64))
        ok = ra.conf[k].ravel() >= 5
        da, db = pa[ok] / np.linalg.norm(pa[ok], axis=1, keepdims=True), pb[ok] / np.linalg.norm(pb[ok], axis=1, keepdims=True)
        assert np.max(np.linalg.norm(da - db, axis=1)) < 1e-4  # same rays: the depth alone changed
        e = pb[ok, 2] / pa[ok, 2] - 1.0
        med.append(np.median(e))
        rms.append(np.sqrt(np.mean((e - s_err[k]) ** 2)))
    assert np.std(s_err) > 0.002
    assert np.corrcoef(med, s_err)[0, 1] > 0.8
    assert np.median(np.abs(np.array(med) - s_err)) < 0.005
    assert 0.001 < np.median(rms) < 0.015  # the warp and correlated noise: about 0.6 % RMS


def test_unknown_map_noise_is_refused(tmp_path):
    with pytest.raises(InputError) as e:
        make_synthetic_scene(tmp_path / "x", seed=0, views=3, objects=1, render=False, map_noise="dust3r")
    assert "map_noise" in str(e.value) and "fm" in str(e.value)


def test_viewpoints_draw_past_the_budget_only_while_too_few_are_feasible():
    """A budget too small for N feasible views is extended (up to EXTRA_CANDIDATES times) instead of failing;
    a budget that suffices draws no more; an impossible N still raises with the counts."""
    from bimanual_app.robots import load_robot
    from bimanual_app.synth._layout import sample_base_pose
    from bimanual_app.synth._viewpoints import EXTRA_CANDIDATES, plan_views
    from bimanual_app.synth._world import SynthWorld

    rng = np.random.default_rng(3)
    with SynthWorld(load_robot("piper"), sample_base_pose(rng), rng) as world:
        for a in range(2):
            world.set_hand_eye(a, sample_hand_eye(rng))
        centre = np.array([0.3, 0.0, 0.0])
        views, st = plan_views(world, 0, 2, np.random.default_rng(0), centre, max_candidates=10)
        assert len(views) == 2 and 10 < st["candidates"] <= 10 * EXTRA_CANDIDATES
        _, st_big = plan_views(world, 0, 2, np.random.default_rng(0), centre, max_candidates=60)
        assert st_big["candidates"] <= 60 and st_big["visible"] >= 2
        with pytest.raises(RuntimeError, match="of 50 viewpoints"):
            plan_views(world, 0, 50, np.random.default_rng(0), centre, max_candidates=3)
