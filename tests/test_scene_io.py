"""Scene contract: loading, writing, and every validation rule with its error message."""

import os
import shutil

import numpy as np
import pytest

from bimanual_app.cli import main as cli_main
from bimanual_app.io_utils import InputError, atomic_path
from bimanual_app.scene import load_scene, validate_scene, write_scene
from tests._scene_fixtures import make_scene


@pytest.fixture()
def scene_dir(tmp_path):
    make_scene(tmp_path / "s", n=5)
    return tmp_path / "s"


def errors_of(path):
    scene, problems = validate_scene(path)
    errs = [p for p in problems if p.severity == "error"]
    assert (scene is None) == bool(errs)
    return errs


def only_error(path, *needles):
    errs = errors_of(path)
    text = "\n".join(str(e) for e in errs)
    for n in needles:
        assert n in text, f"{n!r} not in:\n{text}"
    return errs


def edit_csv(path, row, col, value):
    lines = path.read_text().splitlines()
    cells = lines[row].split(",")
    cells[col] = value
    lines[row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def test_roundtrip(scene_dir, tmp_path):
    s = load_scene(scene_dir)
    assert s.name == "fixture" and len(s.primary) == 5 and len(s.secondary) == 5
    assert s.reconstruction.pts3d.shape == (10, 12, 16, 3)
    assert s.ground_truth.scale == pytest.approx(0.7)
    out = write_scene(s, tmp_path / "copy")
    shutil.copytree(scene_dir / "primary" / "images", out / "primary" / "images")
    shutil.copytree(scene_dir / "secondary" / "images", out / "secondary" / "images")
    s2 = load_scene(out)
    assert np.allclose(s2.primary.T_b_e, s.primary.T_b_e, atol=1e-12)
    assert np.allclose(s2.reconstruction.T_w_c, s.reconstruction.T_w_c)
    assert np.allclose(s2.ground_truth.T_b1_b2, s.ground_truth.T_b1_b2)
    csv_rows, rec_rows = s.reconstruction.rows_for(2, s.secondary.images)
    assert list(csv_rows) == list(range(5)) and list(rec_rows) == list(range(5, 10))


def test_missing_files(tmp_path, scene_dir):
    (scene_dir / "scene.yaml").unlink()
    only_error(scene_dir, "scene.yaml", "file is missing")
    assert only_error(tmp_path / "nope", "is not a folder")


def test_missing_columns(scene_dir):
    p = scene_dir / "primary" / "ee_poses.csv"
    lines = p.read_text().splitlines()
    lines = [",".join(l.split(",")[:-1]) for l in lines]  # drop qw
    p.write_text("\n".join(lines) + "\n")
    only_error(scene_dir, "primary/ee_poses.csv", "header", "missing column(s) qw")


def test_quaternion_not_unit(scene_dir):
    edit_csv(scene_dir / "primary" / "ee_poses.csv", 2, 7, "0.2")
    only_error(scene_dir, "row 3", "quaternion is not unit", "normalise")


def test_millimetres(scene_dir):
    edit_csv(scene_dir / "secondary" / "ee_poses.csv", 1, 1, "310.0")
    only_error(scene_dir, "secondary/ee_poses.csv", "row 2", "millimetres", "divide x, y, z by 1000")


def test_non_finite_and_non_numeric(scene_dir):
    edit_csv(scene_dir / "primary" / "ee_poses.csv", 1, 2, "nan")
    edit_csv(scene_dir / "primary" / "ee_poses.csv", 3, 3, "abc")
    only_error(scene_dir, "non-finite", "'abc' is not a number")


def test_duplicate_image_keys(scene_dir):
    edit_csv(scene_dir / "primary" / "ee_poses.csv", 2, 0, "images/000.png")
    only_error(scene_dir, "duplicate image key 'images/000.png'", "row 3")


def test_rows_without_images_when_no_reconstruction(scene_dir):
    (scene_dir / "reconstruction.npz").unlink()
    (scene_dir / "primary" / "images" / "003.png").unlink()
    only_error(scene_dir, "1 row(s) have no image file", "images/003.png")


def test_images_optional_with_reconstruction(scene_dir):
    shutil.rmtree(scene_dir / "primary" / "images")
    assert errors_of(scene_dir) == []


def test_reconstruction_key_matches_no_row(scene_dir):
    d = dict(np.load(scene_dir / "reconstruction.npz"))
    d["image"] = d["image"].copy()
    d["image"][1] = "images/999.png"
    np.savez(scene_dir / "reconstruction.npz", **d)
    only_error(scene_dir, "reconstruction.npz", "'images/999.png'", "matches no row")


def test_reconstruction_shapes_and_values(scene_dir):
    d = dict(np.load(scene_dir / "reconstruction.npz"))
    bad = dict(d)
    bad["T_w_c"] = d["T_w_c"].copy()
    bad["T_w_c"][0, 0, 0] = np.inf
    np.savez(scene_dir / "reconstruction.npz", **bad)
    only_error(scene_dir, "T_w_c[0]", "non-finite")
    bad = dict(d)
    bad["conf"] = d["conf"][:, :5]
    np.savez(scene_dir / "reconstruction.npz", **bad)
    only_error(scene_dir, "conf", "(M, H, W)")
    bad = dict(d)
    del bad["arm"]
    np.savez(scene_dir / "reconstruction.npz", **bad)
    only_error(scene_dir, "[arm]", "required key is missing")
    bad = dict(d)
    bad["arm"] = d["arm"].copy()
    bad["arm"][0] = 3
    np.savez(scene_dir / "reconstruction.npz", **bad)
    only_error(scene_dir, "values [3]")
    (scene_dir / "reconstruction.npz").write_bytes(b"not a zip")
    only_error(scene_dir, "cannot be read")


def test_reconstruction_missing_one_arm_warns(scene_dir):
    d = dict(np.load(scene_dir / "reconstruction.npz"))
    keep = d["arm"] == 1
    d = {k: (v[keep] if k in ("arm", "image", "T_w_c", "pts3d", "conf") else v) for k, v in d.items()}
    np.savez(scene_dir / "reconstruction.npz", **d)
    scene, problems = validate_scene(scene_dir)
    assert scene is not None
    assert any("no image of the secondary arm" in str(p) and p.severity == "warning" for p in problems)


def test_joint_csv_needs_robot(scene_dir):
    p = scene_dir / "primary" / "ee_poses.csv"
    p.write_text("image,j1,j2,j3,j4,j5,j6\n" + "".join(f"images/{i:03d}.png,0,1.0,-0.5,0,0.3,0\n" for i in range(5)))
    y = scene_dir / "scene.yaml"
    y.write_text("\n".join(l for l in y.read_text().splitlines() if not l.startswith("robot")) + "\n")
    only_error(scene_dir, "scene.yaml", "[robot]", "joint angles")


def test_joint_angles_in_degrees(scene_dir):
    p = scene_dir / "primary" / "ee_poses.csv"
    p.write_text("image,j1,j2,j3,j4,j5,j6\n" + "".join(f"images/{i:03d}.png,0,90,-45,0,30,0\n" for i in range(5)))
    only_error(scene_dir, "degrees", "pi/180")


def test_scene_yaml_rules(scene_dir):
    y = scene_dir / "scene.yaml"
    y.write_text("format: 2\nname: x\ncamera: {width: 640, height: 480, fx: -1, fy: 600, cx: 320, cy: 240}\nrobt: piper\n")
    only_error(scene_dir, "format must be 1", "camera.fx")
    scene, problems = validate_scene(scene_dir)
    assert any("unknown key 'robt'" in str(p) for p in problems)
    y.write_text("format: 1\nname: [unclosed\n")
    only_error(scene_dir, "not valid YAML")


def test_ground_truth_rules(scene_dir):
    g = scene_dir / "ground_truth.yaml"
    g.write_text("T_e1_c1: [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\nT_e2_c2: [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\nscale: -1\n")
    only_error(scene_dir, "[T_e2_c2]", "not a rigid transform", "[T_b1_b2]", "required key is missing", "[scale]")


def test_check_cli(scene_dir, capsys):
    assert cli_main(["check", str(scene_dir)]) == 0
    out = capsys.readouterr().out
    assert "primary: 5 views" in out and "ground truth: present" in out and "OK" in out
    edit_csv(scene_dir / "primary" / "ee_poses.csv", 1, 1, "1200")
    assert cli_main(["check", str(scene_dir)]) == 1
    assert "millimetres" in capsys.readouterr().out


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.npz"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.npz"]


def test_load_scene_raises_input_error(scene_dir):
    edit_csv(scene_dir / "primary" / "ee_poses.csv", 1, 1, "1200")
    with pytest.raises(InputError) as e:
        load_scene(scene_dir)
    assert e.value.problems and e.value.problems[0].fix
