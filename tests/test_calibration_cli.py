"""Scene-level API and ``bijcr calibrate`` end to end on tiny scene folders (write_scene), outputs, bad scenes."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from _calib_fixtures import make_capture, make_scene, write_capture_scene
from scipy.spatial.transform import Rotation

from bimanual_app.cli import main
from bimanual_app.io_utils import InputError
from bimanual_app.scene import load_scene, write_scene
from bimanual_app.transforms import T_from_xyz_quat, make_T, rotation_angle_between
from calibration import calibrate, scene_cloud


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    cap = make_capture(seed=21, views=5, noise="none", point_maps=True)
    root = write_capture_scene(cap, tmp_path_factory.mktemp("scene") / "tiny", name="tiny")
    return cap, root


def test_cli_end_to_end(tiny_scene, tmp_path, capsys):
    cap, root = tiny_scene
    out = tmp_path / "calib"
    assert main(["calibrate", str(root), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "EVALUATION against ground_truth.yaml (not used by the solver)" in text and "+-" in text
    data = json.loads((out / "calibration.json").read_text())
    for key in ("format", "scene", "scale", "T_e1_c1", "T_e2_c2", "T_b1_w", "T_b2_w", "T_b1_b2", "views_used",
                "residuals", "uncertainty", "method", "warnings", "views"):
        assert key in data, key
    assert data["format"] == 1 and data["scene"] == "tiny" and data["method"] == "absolute"
    assert data["views_used"] == {"primary": 5, "secondary": 5}
    assert set(data["residuals"]) >= {"rotation_rad", "translation_m"}
    assert abs(data["scale"] / cap.scale - 1) < 1e-6
    for key, T_true in (("T_e1_c1", cap.T_e1_c1), ("T_e2_c2", cap.T_e2_c2), ("T_b1_b2", cap.T_b1_b2)):
        T = np.array(data[key])
        assert rotation_angle_between(T[:3, :3], T_true[:3, :3]) < 1e-6
        assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 1e-6
        assert {"rotation_deg", "translation_mm"} <= set(data["uncertainty"][key])
    assert "percent" in data["uncertainty"]["scale"]
    assert data["views"]["primary"]["used"][0] == "images/000.png"
    # metric coloured cloud, read back with Open3D
    import open3d as o3d

    pcd = o3d.io.read_point_cloud(str(out / "scene_b1.ply"))
    pts, cols = np.asarray(pcd.points), np.asarray(pcd.colors)
    keep = cap.conf > data["cloud"]["conf_threshold"]
    # every written point is a confident input point in b1 with its colour; the self filters (a wrist
    # camera's rig, points other views see through) may drop a few of this random fixture's points
    from scipy.spatial import cKDTree

    expected, exp_cols = cap.points_b1[keep], cap.colors[keep]
    assert len(cols) == len(pts) and 0.99 * len(expected) <= len(pts) <= len(expected)
    rig = sum(data["cloud"].get("wrist_rig_pixels", {}).values()) * 5  # pixels x views per arm
    assert len(expected) - len(pts) <= data["cloud"]["seen_through_removed"] + rig  # every drop is accounted for
    d, idx = cKDTree(expected).query(pts)
    assert d.max() < 1e-4
    assert np.allclose(cols * 255, exp_cols[idx], atol=0.5)
    # the depth views the cloud came from (checked on a rendered scene in tests/test_calibration_views.py)
    from bimanual_app.views import load_views

    views = load_views(out / "views.npz")
    assert len(views) == 10 and views.depth.shape[1:] == cap.conf.shape[1:]
    # picture
    from PIL import Image

    im = Image.open(out / "calibration.png")
    assert im.size[0] > 800 and im.size[1] > 400
    # ROS exports agree with the calibration
    ros = yaml.safe_load((out / "ros" / "static_transforms.yaml").read_text())
    by_child = {t["child"]: t for t in ros["transforms"]}
    t = by_child["primary_camera_optical_frame"]
    T = T_from_xyz_quat([t["translation"][k] for k in "xyz"], [t["rotation"][k] for k in "xyzw"])
    assert np.allclose(T, cap.T_e1_c1, atol=1e-6) and t["parent"] == "primary_ee_link"
    t = by_child["secondary_base_link"]
    T = T_from_xyz_quat([t["translation"][k] for k in "xyz"], [t["rotation"][k] for k in "xyzw"])
    assert np.allclose(T, cap.T_b1_b2, atol=1e-6)
    urdf = ET.parse(out / "ros" / "bijcr_calibration.urdf").getroot()
    joints = {j.find("child").get("link"): j for j in urdf.findall("joint")}
    o = joints["secondary_camera_optical_frame"].find("origin")
    R = Rotation.from_euler("xyz", [float(v) for v in o.get("rpy").split()]).as_matrix()
    assert np.allclose(make_T(R, [float(v) for v in o.get("xyz").split()]), cap.T_e2_c2, atol=1e-6)
    for launch in ("static_transforms.launch.xml", "static_transforms.launch"):
        nodes = ET.parse(out / "ros" / launch).getroot().findall("node")
        assert len(nodes) == 3 and all(n.get("pkg") == "tf2_ros" for n in nodes)
    # no temporary files left behind
    assert not [p for p in out.rglob("*") if ".tmp-" in p.name]


def test_cli_paper_method_and_options(tiny_scene, tmp_path):
    _, root = tiny_scene
    out = tmp_path / "paper"
    assert main(["calibrate", str(root), "--out", str(out), "--method", "paper-norefine", "--no-figure",
                 "--uncertainty", "none", "--quiet"]) == 0
    data = json.loads((out / "calibration.json").read_text())
    assert data["method"] == "paper-norefine" and data["uncertainty"] == {}
    assert not (out / "calibration.png").exists()


def test_scene_without_reconstruction_names_the_command(tmp_path, capsys):
    cap = make_capture(seed=22, views=4, noise="none")
    scene = make_scene(cap, "norec")
    scene.reconstruction = None
    root = write_scene(scene, tmp_path / "norec")
    for arm in ("primary", "secondary"):  # images exist: a valid scene, just not reconstructed yet
        (root / arm / "images").mkdir()
        for k in range(4):
            (root / arm / "images" / f"{k:03d}.png").write_bytes(b"")
    assert main(["calibrate", str(root), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "reconstruction.npz" in err and "bijcr reconstruct SCENE" in err
    assert not (tmp_path / "o" / "calibration.json").exists()


def test_reconstruction_missing_one_arm(tmp_path, capsys):
    cap = make_capture(seed=23, views=4, noise="none")
    scene = make_scene(cap, "onearm")
    rec = scene.reconstruction
    keep = rec.arm == 1
    rec.arm, rec.image, rec.T_w_c = rec.arm[keep], rec.image[keep], rec.T_w_c[keep]
    root = write_scene(scene, tmp_path / "onearm")
    assert main(["calibrate", str(root), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "none of the secondary arm's images" in err and "bijcr reconstruct" in err


def test_partly_registered_arm_is_reported(tmp_path):
    cap = make_capture(seed=24, views=6, noise="none")
    scene = make_scene(cap, "partial")
    rec = scene.reconstruction
    keep = ~((rec.arm == 2) & (rec.image == "images/004.png"))
    rec.arm, rec.image, rec.T_w_c = rec.arm[keep], rec.image[keep], rec.T_w_c[keep]
    r = calibrate(scene)
    assert r.views_used["secondary"] == [0, 1, 2, 3, 5]  # CSV rows
    assert any("not registered" in w and "images/004.png" in w for w in r.warnings)
    assert np.linalg.norm(r.T_b1_b2[:3, 3] - cap.T_b1_b2[:3, 3]) < 1e-6


def test_mismatched_image_keys(tmp_path, capsys):
    cap = make_capture(seed=25, views=4, noise="none")
    scene = make_scene(cap, "keys")
    scene.reconstruction.image = np.array([k.replace("images/", "img/") for k in scene.reconstruction.image])
    with pytest.raises(InputError) as e:  # in-memory scene: the calibration checks the keys itself
        calibrate(scene)
    p = e.value.problems[0]
    assert p.file == "reconstruction.npz" and "match no row" in p.message and "ee_poses.csv" in p.fix
    root = write_scene(scene, tmp_path / "keys")  # on disk: the scene loader reports it
    assert main(["calibrate", str(root), "--out", str(tmp_path / "o")]) == 1
    assert "matches no row" in capsys.readouterr().err


def test_degenerate_scene_cli_message(tmp_path, capsys):
    cap = make_capture(seed=26, views=5, noise="none")
    n = 5
    E = np.stack([cap.T_b1_e[0] @ make_T(Rotation.from_rotvec([0, 0, 0.3 * k]).as_matrix(), [0.02 * k, 0, 0])
                  for k in range(n)])
    P = np.linalg.inv(cap.T_b1_w) @ E @ cap.T_e1_c1
    P[:, :3, 3] /= cap.scale
    cap.T_b1_e, cap.T_w_c1 = E, P
    root = write_capture_scene(cap, tmp_path / "degen")
    assert main(["calibrate", str(root), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "one axis" in err and "fix:" in err
    assert main(["calibrate", str(root), "--out", str(tmp_path / "o"), "--allow-degenerate", "--no-figure"]) == 0
    assert "warning:" in capsys.readouterr().out


def test_writes_are_atomic(tiny_scene, tmp_path, monkeypatch):
    from calibration import _files, write_outputs

    cap, root = tiny_scene
    scene = load_scene(root)
    result = calibrate(scene)
    out = tmp_path / "atomic"
    write_outputs(out, scene, result, figure=False)
    before = (out / "calibration.json").read_bytes()
    ply_before = (out / "scene_b1.ply").read_bytes()

    def boom(tmp):
        assert Path(tmp).exists() and Path(tmp).stat().st_size > 0  # the content was written to the temp name
        raise OSError("disk full")

    monkeypatch.setattr(_files, "readable", boom)
    result.scale *= 2  # a different result: would change both files
    with pytest.raises(OSError, match="disk full"):
        write_outputs(out, scene, result, figure=False)
    assert (out / "calibration.json").read_bytes() == before  # old file intact, never half-written
    assert (out / "scene_b1.ply").read_bytes() == ply_before
    assert not [p for p in out.rglob("*") if ".tmp-" in p.name]
    monkeypatch.undo()
    # scene_cloud uses only the views the calibration kept
    pts, _, info = scene_cloud(scene, result)
    assert info["points"] == len(pts) > 0


def test_scale_is_compared_with_the_ground_truth_only_for_the_synthetic_reconstruction():
    from types import SimpleNamespace

    from calibration.cli import evaluation_lines

    I = np.eye(4)
    res = SimpleNamespace(T_e1_c1=I, T_e2_c2=I, T_b1_b2=I, scale=2.0)
    gt = SimpleNamespace(T_e1_c1=I, T_e2_c2=I, T_b1_b2=I, scale=1.0)
    assert "  scale: 100.000%" in evaluation_lines(res, gt, "synthetic")
    lines = evaluation_lines(res, gt, "colmap")
    assert any("scale: not compared" in ln and "'colmap'" in ln for ln in lines)
    assert not any("%" in ln for ln in lines)


def test_undeterminable_offset_is_reported_unbounded(tmp_path, capsys):
    """Rotations about one axis leave the camera offset along it free: its sigma has no bound (not millimetres)."""
    cap = make_capture(seed=26, views=5, noise="low")
    E = np.stack([cap.T_b1_e[0] @ make_T(Rotation.from_rotvec([0, 0, 0.3 * k]).as_matrix(), [0.02 * k, 0, 0])
                  for k in range(5)])
    P = np.linalg.inv(cap.T_b1_w) @ E @ cap.T_e1_c1
    P[:, :3, 3] /= cap.scale
    cap.T_b1_e, cap.T_w_c1 = E, P
    root = write_capture_scene(cap, tmp_path / "degen")
    out = tmp_path / "o"
    assert main(["calibrate", str(root), "--out", str(out), "--allow-degenerate", "--no-figure"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("T_e1_c1"))
    assert "unbounded" in line, line
    u = json.loads((out / "calibration.json").read_text())["uncertainty"]
    sig = u["T_e1_c1"]["translation_mm"]
    assert np.isinf(sig[2]) and np.isfinite(sig[0]) and np.isfinite(sig[1])  # along the rotation axis only
    assert np.all(np.isfinite(u["T_e2_c2"]["translation_mm"]))  # the other arm's motions determine its offset
    assert np.isinf(u["T_b1_b2"]["translation_norm_mm"])


@pytest.mark.parametrize("views, still", [((2, 5), False), (5, True)])
def test_check_runs_the_checks_calibrate_runs(tmp_path, capsys, views, still):
    """`bijcr check` refuses what `bijcr calibrate` refuses (too few views; an arm that does not move)."""
    cap = make_capture(seed=27, views=views, noise="none")
    if still:  # the primary never moves: every view from the same pose
        cap.T_b1_e = np.stack([cap.T_b1_e[0]] * len(cap.T_b1_e))
        cap.T_w_c1 = np.stack([cap.T_w_c1[0]] * len(cap.T_w_c1))
    root = write_capture_scene(cap, tmp_path / "s")
    assert main(["calibrate", str(root), "--out", str(tmp_path / "o")]) == 1
    capsys.readouterr()
    assert main(["check", str(root)]) == 1
    out = capsys.readouterr().out
    assert "OK" not in out.splitlines()
    assert ("at least 3" in out) if not still else ("rotates at most" in out)
    assert "bijcr calibrate" in out and "fix:" in out


def test_paper_method_without_torch_names_the_extra(tiny_scene, tmp_path, capsys, monkeypatch):
    """torch is the optional extra [paper]: without it, --method paper stops at once and says how to get it."""
    import sys

    _, root = tiny_scene
    monkeypatch.setitem(sys.modules, "torch", None)  # `import torch` raises ImportError
    assert main(["calibrate", str(root), "--out", str(tmp_path / "o"), "--method", "paper"]) == 1
    err = capsys.readouterr().err
    assert "pip install -e .[paper]" in err and "--method" in err
    assert not (tmp_path / "o").exists()


def test_a_known_command_builds_only_its_own_parser(capsys):
    """``bijcr calibrate ...`` imports and builds the calibrate command alone (start-up time); without a known
    command the parser lists them all."""
    from bimanual_app.cli import build_parser

    def commands(parser):
        return list(next(a for a in parser._actions if a.dest == "command").choices)

    assert commands(build_parser("calibrate")) == ["calibrate"]
    assert "calibrate" in commands(build_parser()) and len(commands(build_parser())) > 1
    with pytest.raises(SystemExit):
        main(["no-such-command"])
    assert "calibrate" in capsys.readouterr().err
