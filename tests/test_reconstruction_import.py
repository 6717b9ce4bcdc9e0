"""Importers of DUSt3R / MASt3R / VGGT / Ray Diffusion exports, on fixture files in the documented layout.

The fixture files are written by the exporters' own ``pack`` functions from emulated model outputs of a
rendered scene: in the model's own world frame (a similarity of the true one), in a shuffled image
order, on the model's resized / cropped / padded images. The importer must undo all of it.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from _recon_fixtures import (
    ARMS,
    expected_points,
    expected_T_w_c,
    load_tool,
    render_scene,
    similarity,
    write_model_export,
)

from bimanual_app.cli import main as bijcr
from bimanual_app.io_utils import InputError
from bimanual_app.reconstruction import build_reconstruction, import_export, load_export, reconstruct
from bimanual_app.scene import load_scene
from bimanual_app.transforms import rotation_angle_between

ORDER = [4, 1, 5, 0, 3, 2]  # shuffled: secondary and primary interleaved
MODEL_SCALE = 3.7           # similarity() scales the world by this


@pytest.fixture(scope="module")
def scene3(tmp_path_factory):
    root = tmp_path_factory.mktemp("imp") / "scene"
    gt = render_scene(root, views_per_arm=3)
    return root, gt, load_scene(root), similarity()


def _check_poses(rec, gt, S):
    assert rec.arm.tolist() == [1, 1, 1, 2, 2, 2]  # back in CSV order
    assert rec.image.tolist() == [f"images/{k:03d}.png" for k in range(3)] * 2
    for a, k, T in zip(rec.arm, rec.image, rec.T_w_c):
        E = expected_T_w_c(gt, S, ARMS[a - 1], k)
        assert rotation_angle_between(E[:3, :3], T[:3, :3]) < 1e-6
        assert np.linalg.norm(E[:3, 3] - T[:3, 3]) < 1e-6


def _point_errors_mm(rec, gt, S) -> np.ndarray:
    out = []
    for j, (a, k) in enumerate(zip(rec.arm, rec.image)):
        P = expected_points(gt, S, ARMS[a - 1], k, (160, 120))
        ok = rec.conf[j] > 0
        out.append(np.linalg.norm(rec.pts3d[j][ok] - P[ok], axis=-1) / MODEL_SCALE * 1000)
    return np.concatenate(out)


@pytest.mark.parametrize("model", ["dust3r", "mast3r", "vggt"])
def test_point_map_models(scene3, tmp_path, model):
    root, gt, scene, S = scene3
    f = write_model_export(tmp_path / f"{model}.npz", model, root, gt, S, ORDER)
    rec, info = import_export(scene, f, model)
    assert rec.model == model
    _check_poses(rec, gt, S)
    assert rec.pts3d.shape == (6, 120, 160, 3) and rec.colors.shape == (6, 120, 160, 3)
    e = _point_errors_mm(rec, gt, S)
    # nearest model pixel: sub-millimetre typically; a wrong crop offset or scale would be centimetres
    assert np.median(e) < 1.5 and np.percentile(e, 95) < 6
    # intrinsics mapped back from model pixels to the original image
    # (DUSt3R/MASt3R have one focal for both axes; their resize rounds each axis apart: 0.2 % allowed)
    np.testing.assert_allclose(rec.extras["K"], np.broadcast_to(gt["K"], (6, 3, 3)), rtol=2e-3, atol=1e-6)


def test_dust3r_224_crop_leaves_the_sides_unseen(scene3, tmp_path):
    """DUSt3R at 224 crops the centre square: map cells left and right of it get confidence 0."""
    root, gt, scene, S = scene3
    common = load_tool("export_common")
    box, size = common.dust3r_crop_box(320, 240, 224)
    assert size == (224, 224) and 0 < box[0] < 40
    f = write_model_export(tmp_path / "d.npz", "dust3r", root, gt, S, ORDER, dust3r_size=224)
    rec, _ = import_export(scene, f, "dust3r")
    x_cells = (np.arange(160) + 0.5) * 2  # pixel-edge x of each map column in the 320-wide image
    outside = (x_cells < box[0]) | (x_cells > box[2])
    assert np.all(rec.conf[:, :, outside] == 0)
    assert np.all(rec.conf[:, :, ~outside & (x_cells > box[0] + 3) & (x_cells < box[2] - 3)] > 0)
    assert np.all(np.isfinite(rec.pts3d))


def test_export_without_the_models_project_names_the_environment():
    """An export script run outside the model's Python environment exits with one line saying which."""
    common = load_tool("export_common")

    def run():
        import dust3r_not_installed_here  # noqa: F401

    with pytest.raises(SystemExit) as e:
        common.run_in_model_env(run, "DUSt3R")
    assert "DUSt3R's Python environment" in str(e.value) and "--repo" in str(e.value)
    assert common.run_in_model_env(lambda: 7, "DUSt3R") == 7


def test_vggt_pad_mode_box_reaches_beyond_the_image(scene3, tmp_path):
    root, gt, scene, S = scene3
    tool = load_tool("export_vggt")
    boxes, sizes = tool.crop_boxes([(320, 240)], "pad")
    assert sizes[0] == (518, 518) and boxes[0][1] < 0 and boxes[0][3] > 240
    f = write_model_export(tmp_path / "v.npz", "vggt", root, gt, S, ORDER, vggt_mode="pad")
    rec, _ = import_export(scene, f, "vggt")
    _check_poses(rec, gt, S)
    e = _point_errors_mm(rec, gt, S)
    assert np.median(e) < 1.5


def test_raydiffusion_poses_only(scene3, tmp_path):
    root, gt, scene, S = scene3
    f = write_model_export(tmp_path / "r.npz", "raydiffusion", root, gt, S, ORDER)
    rec, info = import_export(scene, f, "raydiffusion")
    _check_poses(rec, gt, S)
    assert rec.pts3d is None and rec.conf is None and not info["point_maps"]


def test_wrong_pose_convention_is_caught_by_these_checks(scene3, tmp_path):
    """Negative control: storing VGGT's extrinsics as camera-to-world (a classic mistake) moves the cameras."""
    root, gt, scene, S = scene3
    f = write_model_export(tmp_path / "v.npz", "vggt", root, gt, S, ORDER)
    data = dict(np.load(f))
    E = data["extrinsic"]
    wrong = np.concatenate([E[:, :3, :3].transpose(0, 2, 1), -np.einsum("nji,nj->ni", E[:, :3, :3], E[:, :3, 3])[..., None]], 2)
    wrong_file = tmp_path / "wrong.npz"
    np.savez(wrong_file, **{**data, "extrinsic": wrong})  # camera-to-world where world-to-camera belongs
    rec, _ = import_export(scene, wrong_file, "vggt")
    with pytest.raises(AssertionError):
        _check_poses(rec, gt, S)
    # the stage's kinematic check (relative rotation angles) cannot see this mistake: inverting every pose
    # keeps each relative rotation's angle (R_i R_j^T is conjugate to R_i^T R_j); hence these tests
    rec, info = build_reconstruction(scene, "vggt", input=wrong_file, log=lambda s: None)
    assert info["inconsistent"] == []
    # a single view rotated wrongly, though, is flagged (reported for importers, not dropped)
    bad = dict(np.load(f))
    bad["extrinsic"] = bad["extrinsic"].copy()
    R = cv2.Rodrigues(np.array([0.0, 0.7, 0.0]))[0]
    bad["extrinsic"][2, :, :3] = R @ bad["extrinsic"][2, :, :3]
    bad_file = tmp_path / "bad.npz"
    np.savez(bad_file, **bad)
    rec, info = build_reconstruction(scene, "vggt", input=bad_file, log=lambda s: None)
    assert info["inconsistent"] == [f"{data['image'][2]}"]


def test_bad_exports_are_explained(scene3, tmp_path):
    root, gt, scene, S = scene3
    f = write_model_export(tmp_path / "d.npz", "dust3r", root, gt, S, ORDER)
    data = dict(np.load(f))
    with pytest.raises(InputError, match="written for 'dust3r'.*--backend dust3r"):
        import_export(scene, f, "vggt")
    bad = tmp_path / "nokey.npz"
    np.savez(bad, **{k: v for k, v in data.items() if k != "crop_box"})
    with pytest.raises(InputError, match=r"\[crop_box\].*missing"):
        load_export(bad, "dust3r")
    bare = tmp_path / "bare.npz"
    np.savez(bare, **{**data, "image": np.array([n.split("/")[-1] for n in data["image"]])})
    with pytest.raises(InputError, match="matches 2 rows"):
        import_export(scene, bare, "dust3r")
    alien = tmp_path / "alien.npz"
    names = data["image"].copy()
    names[0] = "primary/images/999.png"
    np.savez(alien, **{**data, "image": names})
    with pytest.raises(InputError, match="999.png' matches no row"):
        import_export(scene, alien, "dust3r")
    with pytest.raises(InputError, match="missing"):
        load_export(tmp_path / "nothing.npz", "dust3r")
    # absolute paths that end with <arm>/<key> are fine
    abs_file = tmp_path / "abs.npz"
    np.savez(abs_file, **{**data, "image": np.array([str(root / n) for n in data["image"]])})
    rec, _ = import_export(scene, abs_file, "dust3r")
    _check_poses(rec, gt, S)


def test_too_few_views_of_an_arm_in_the_export(scene3, tmp_path):
    root, gt, scene, S = scene3
    f = write_model_export(tmp_path / "d.npz", "raydiffusion", root, gt, S, [0, 1, 2, 3, 4])  # secondary 2 of 3
    work = tmp_path / "scene"
    import shutil

    shutil.copytree(root, work)
    with pytest.raises(InputError, match=r"raydiffusion registered only 2 of 3 secondary views.*secondary/images/002.png"):
        reconstruct(work, backend="raydiffusion", input=f, plot=False, log=lambda s: None)
    assert not (work / "reconstruction.npz").exists()


def test_cli_force_keeps_a_backup_and_writes_atomically(scene3, tmp_path, monkeypatch, capsys):
    import shutil

    root, gt, scene, S = scene3
    work = tmp_path / "scene"
    shutil.copytree(root, work)
    f = write_model_export(tmp_path / "v.npz", "vggt", root, gt, S, ORDER)
    assert bijcr(["reconstruct", str(work), "--backend", "vggt", "--input", str(f), "--no-plot"]) == 0
    out = capsys.readouterr().out
    assert "primary: 3/3 views registered" in out and "secondary: 3/3" in out
    first = (work / "reconstruction.npz").read_bytes()
    # without --force: refused, untouched
    assert bijcr(["reconstruct", str(work), "--backend", "vggt", "--input", str(f)]) == 1
    assert "--force" in capsys.readouterr().err
    assert (work / "reconstruction.npz").read_bytes() == first
    # importer without --input: says which tool makes the file
    assert bijcr(["reconstruct", str(work), "--backend", "mast3r", "--force"]) == 1
    assert "tools/export_mast3r.py" in capsys.readouterr().err
    # a crash while writing leaves the old file in place and no partial file
    import bimanual_app.scene.write as writer

    def boom(fobj, **arrays):
        fobj.write(b"PK partial")
        raise OSError("disk full")

    r_file = write_model_export(tmp_path / "r.npz", "raydiffusion", root, gt, S, ORDER)
    monkeypatch.setattr(writer.np, "savez_compressed", boom)
    with pytest.raises(OSError):
        reconstruct(work, backend="raydiffusion", input=r_file, force=True, plot=False, log=lambda s: None)
    monkeypatch.undo()
    assert (work / "reconstruction.npz").read_bytes() == first
    assert not [p for p in work.iterdir() if p.name.startswith(".reconstruction")]
    # with --force: replaced, previous kept
    for p in work.glob("reconstruction.bak-*.npz"):
        p.unlink()
    assert bijcr(["reconstruct", str(work), "--backend", "raydiffusion", "--input", str(tmp_path / "r.npz"), "--force",
                  "--no-plot"]) == 0
    backups = list(work.glob("reconstruction.bak-*.npz"))
    assert len(backups) == 1 and backups[0].read_bytes() == first
    assert load_scene(work).reconstruction.model == "raydiffusion"


def test_force_replaces_a_broken_reconstruction(scene3, tmp_path):
    """A corrupt reconstruction.npz makes the scene unloadable; --force still rebuilds it (and keeps the old bytes)."""
    import shutil

    root, gt, scene, S = scene3
    work = tmp_path / "scene"
    shutil.copytree(root, work)
    (work / "reconstruction.npz").write_bytes(b"garbage")
    f = write_model_export(tmp_path / "r.npz", "raydiffusion", root, gt, S, ORDER)
    with pytest.raises(InputError, match="--force"):
        reconstruct(work, backend="raydiffusion", input=f, plot=False, log=lambda s: None)
    res = reconstruct(work, backend="raydiffusion", input=f, force=True, plot=False, log=lambda s: None)
    assert res.backup.read_bytes() == b"garbage"
    assert load_scene(work).reconstruction.model == "raydiffusion"
