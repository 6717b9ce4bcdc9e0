"""`bijcr reach`: end to end on a small scene with a calibration, and the bad-input messages."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _motion_fixtures import write_reach_scene
from PIL import Image

from bimanual_app.cli import main


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("reach")
    return write_reach_scene(root)[0]


def test_reach_writes_a_validated_trajectory_and_a_preview(scene_dir, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["reach", str(scene_dir), "--arm", "primary", "--to", "0.35,0.15,0.08", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    data = json.loads((out / "trajectory_primary.json").read_text())
    assert data["success"] and data["validation"]["ok"] and data["frame"] == "b1"
    assert data["validation"]["max_step_m"] <= 0.01 + 1e-12
    q = np.array(data["arms"]["primary"]["q"])
    t = np.array(data["arms"]["primary"]["times"])
    assert q.shape == (len(t), 6) and t[0] == 0 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(data["T_b1_b2"], json.loads((scene_dir / "calibration" / "calibration.json").read_text())["T_b1_b2"])
    # the end state reaches the target (position only)
    from bimanual_app.robots import load_robot

    tcp = load_robot("piper").fk_link(q[-1], "gripper_tcp")[:3, 3]
    assert np.linalg.norm(tcp - [0.35, 0.15, 0.08]) < 2e-4
    img = np.asarray(Image.open(out / "preview_primary.png"))
    assert img.shape == (480, 640, 3) and img.std() > 10  # a picture, not a blank
    assert (out / "joints_primary.png").is_file()
    assert not list(out.glob(".*tmp*"))  # atomic writes leave no temporaries


def test_reach_secondary_with_pose(scene_dir, tmp_path):
    # the secondary base sits at (0.6, 0.02) facing the primary; a top-down pose 0.25 m in front of it and
    # 0.2 m to its right (beside the box), the gripper's x axis pointing back at that base
    rc = main(["reach", str(scene_dir), "--arm", "secondary", "--to", "0.35,0.22,0.08,0,3.14159265,2.4669",
               "--out", str(tmp_path), "--no-preview"])
    assert rc == 0
    data = json.loads((tmp_path / "trajectory_secondary.json").read_text())
    assert data["moving_arm"] == "secondary" and "primary" in data["hold"]
    from bimanual_app.robots import load_robot

    T_b2_g = load_robot("piper").fk_link(np.array(data["arms"]["secondary"]["q"][-1]), "gripper_tcp")
    T_b1_g = np.array(data["T_b1_b2"]) @ T_b2_g
    np.testing.assert_allclose(T_b1_g[:3, 3], [0.35, 0.22, 0.08], atol=2e-4)
    assert T_b1_g[2, 2] < -0.999  # pointing down


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--to", "1.6,0,0.1"], "out of reach"),
        (["--to", "0.3,0,0.1", "--from", "0,0,0,0,0,5"], "joint limits violated"),
        (["--to", "0.3,abc,0.1"], "cannot read"),
        (["--to", "0.3,0.1"], "cannot read"),
        (["--to", "0.32,0.0,0.1", "--from", "0,1.71,-1.26,0,1.2,0"], "start configuration is not valid"),
    ],
)
def test_reach_bad_input(scene_dir, tmp_path, capsys, extra, message):
    rc = main(["reach", str(scene_dir), "--out", str(tmp_path), "--no-preview"] + extra)
    err = capsys.readouterr().err
    assert rc == 1 and message in err, err
    assert not list(tmp_path.glob("trajectory_*.json"))


def test_reach_needs_a_calibration(tmp_path, capsys):
    scene, _ = write_reach_scene(tmp_path, calibration=False)
    rc = main(["reach", str(scene), "--to", "0.3,0,0.1"])
    err = capsys.readouterr().err
    assert rc == 1 and "bijcr calibrate" in err
    # ground truth allowed on request; the cloud must still come from somewhere non-empty
    empty = tmp_path / "empty.ply"
    empty.write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n")
    rc = main(["reach", str(scene), "--to", "0.3,0,0.1", "--use-ground-truth", "--cloud", str(empty)])
    err = capsys.readouterr().err
    assert rc == 1 and "no points" in err
    rc = main(["reach", str(scene), "--to", "0.3,0,0.1", "--calibration", str(tmp_path / "nope.json")])
    assert rc == 1 and "not found" in capsys.readouterr().err


def test_reach_refuses_a_calibration_of_another_scene(scene_dir, tmp_path, capsys):
    """The same check as `bijcr task`: a calibration made for another scene is refused, naming both."""
    data = json.loads((scene_dir / "calibration" / "calibration.json").read_text())
    foreign = tmp_path / "other" / "calibration.json"
    foreign.parent.mkdir()
    foreign.write_text(json.dumps(dict(data, scene="another-scene")))
    (foreign.parent / "scene_b1.ply").write_bytes((scene_dir / "calibration" / "scene_b1.ply").read_bytes())
    rc = main(["reach", str(scene_dir), "--to", "0.3,0,0.1", "--calibration", str(foreign),
               "--out", str(tmp_path / "o"), "--no-preview"])
    err = capsys.readouterr().err
    assert rc == 1 and "'another-scene'" in err and "calibrate this scene" in err, err
    assert not (tmp_path / "o").exists()
