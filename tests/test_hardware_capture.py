"""`bijcr capture` against a simulated Piper on the virtual bus and a camera stand-in serving image files."""

import csv
import time

import numpy as np
import pytest
from PIL import Image

from bimanual_app.cli import main as cli_main
from bimanual_app.hardware import ImageFolderCamera, load_poses, plan_capture
from bimanual_app.hardware._camera import OpenCVCamera, open_camera
from bimanual_app.io_utils import InputError
from bimanual_app.scene import load_scene
from tests._hw_fixtures import Q_READY, SimPiper, new_channel

POSES = np.array([Q_READY + [0.10, 0.0, 0.0, 0.0, 0.0, 0.2],
                  Q_READY + [-0.10, 0.05, 0.0, 0.1, 0.0, -0.2],
                  Q_READY + [0.0, -0.05, 0.05, -0.1, 0.1, 0.0]])


def _poses_yaml(path, poses=POSES, extra=""):
    rows = "\n".join(f"  - {{name: p{i}, q: [{', '.join(f'{v:.6f}' for v in q)}]}}" for i, q in enumerate(poses))
    path.write_text(f"format: 1\nrobot: piper\nspeed: 1.0\nsettle_s: 0.1\n{extra}poses:\n{rows}\n")
    return path


def _images(folder, n, seed=0):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    arrays = []
    for i in range(n):
        a = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
        Image.fromarray(a).save(folder / f"frame_{i:02d}.png")
        arrays.append(a)
    return arrays


def _args(poses, out, ch, cam, arm="primary", execute=True, feedback_timeout="1.0"):
    # the simulated arm shares this process (and, on CI, two cores) with the capture: a 1 s feedback limit
    # keeps a scheduling hiccup from reading as a dead link; the timeout itself is tested in
    # test_hardware_backend.py and below
    a = ["capture", "--arm", arm, "--poses", str(poses), "--out", str(out), "--can", ch,
         "--can-interface", "virtual", "--camera", str(cam), "--feedback-timeout", feedback_timeout]
    return a + (["--execute", "hardware"] if execute else [])


def _read_csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def test_dry_run_checks_and_prints_the_plan_without_touching_anything(tmp_path, capsys):
    poses = _poses_yaml(tmp_path / "poses.yaml")
    ch = new_channel()
    with SimPiper(ch, q0=Q_READY) as sim:
        rc = cli_main(_args(poses, tmp_path / "scene", ch, tmp_path / "nocam", execute=False))
        time.sleep(0.05)
        assert sim.ids_received() == []
    out = capsys.readouterr().out
    assert rc == 0
    assert "capture plan: 3 poses for the primary arm" in out and "dry run: nothing was connected or moved" in out
    assert not (tmp_path / "scene").exists()


def test_capture_both_arms_writes_a_valid_scene(tmp_path, capsys):
    poses = _poses_yaml(tmp_path / "poses.yaml")
    scene = tmp_path / "scene"
    cams = {}
    for arm, seed in (("primary", 1), ("secondary", 2)):
        cams[arm] = _images(tmp_path / f"cam_{arm}", 3, seed)
        ch = new_channel()
        with SimPiper(ch, q0=Q_READY, noise_rad=2e-5, seed=seed) as sim:
            rc = cli_main(_args(poses, scene, ch, tmp_path / f"cam_{arm}", arm))
            assert rc == 0, capsys.readouterr().err
            assert not sim.estopped
            # every joint command the arm received was within the limits of the plan's moves
            cmds = np.array([q for _, q in sim.joint_cmds])
            assert np.all(np.abs(cmds - Q_READY).max(axis=1) < 0.25)
        header, rows = _read_csv(scene / arm / "ee_poses.csv")
        assert header == ["image", "j1", "j2", "j3", "j4", "j5", "j6"]
        assert [r[0] for r in rows] == ["images/000.png", "images/001.png", "images/002.png"]
        q = np.array([[float(v) for v in r[1:]] for r in rows])
        np.testing.assert_allclose(q, POSES, atol=0.006)  # measured (settled) joints, radians
        for i, a in enumerate(cams[arm]):
            np.testing.assert_array_equal(np.asarray(Image.open(scene / arm / f"images/{i:03d}.png")), a)
        assert (scene / arm / "capture_overview.png").is_file()
    out = capsys.readouterr().out
    assert "both arms captured" in out
    s = load_scene(scene)
    assert s.robot == "piper" and len(s.primary) == 3 and len(s.secondary) == 3
    assert s.primary.joints is not None and s.primary.T_b_e.shape == (3, 4, 4)
    assert not [p for p in scene.rglob(".*")], "no staging folder left behind"


def test_refuses_to_overwrite_an_existing_capture(tmp_path, capsys):
    poses = _poses_yaml(tmp_path / "poses.yaml")
    scene = tmp_path / "scene"
    (scene / "primary").mkdir(parents=True)
    (scene / "primary" / "ee_poses.csv").write_text("keep me\n")
    (scene / "scene.yaml").write_text("format: 1\nname: x\nrobot: ur5\n")
    ch = new_channel()
    with SimPiper(ch, q0=Q_READY) as sim:
        rc = cli_main(_args(poses, scene, ch, tmp_path))
        time.sleep(0.05)
        assert sim.ids_received() == []
    err = capsys.readouterr().err
    assert rc == 1 and "refusing to overwrite" in err and "robot 'ur5'" in err
    assert (scene / "primary" / "ee_poses.csv").read_text() == "keep me\n"
    assert (scene / "scene.yaml").read_text() == "format: 1\nname: x\nrobot: ur5\n"


def test_arm_that_stops_answering_mid_capture_is_stopped_and_nothing_is_written(tmp_path, capsys):
    poses = _poses_yaml(tmp_path / "poses.yaml")
    _images(tmp_path / "cam", 3)
    scene = tmp_path / "scene"
    ch = new_channel()
    # about 100 joint commands: the first pose is reached and captured, the arm goes silent on the way
    with SimPiper(ch, q0=Q_READY, silent_after_joint_cmds=130) as sim:
        rc = cli_main(_args(poses, scene, ch, tmp_path / "cam", feedback_timeout="0.25"))
        t_stop = sim.estop_time()
        assert t_stop is not None and sim.estopped
        time.sleep(0.03)
        assert sim.motion_frames_after(t_stop) == []
    err = capsys.readouterr().err
    assert rc == 1
    assert "feedback stopped" in err and "stop sent to: primary" in err and "nothing was written" in err
    assert not (scene / "primary").exists() and not (scene / "scene.yaml").exists()
    assert not [p for p in scene.iterdir() if p.name.startswith(".")]


class _InterruptingCamera(ImageFolderCamera):
    """Ctrl-C pressed while the second frame is being taken."""

    def grab(self):
        if self._i == 1:
            raise KeyboardInterrupt
        return super().grab()


def test_ctrl_c_during_capture_stops_the_arm(tmp_path, monkeypatch):
    import bimanual_app.hardware._camera as camera_mod

    poses = _poses_yaml(tmp_path / "poses.yaml")
    _images(tmp_path / "cam", 3)
    monkeypatch.setattr(camera_mod, "ImageFolderCamera", _InterruptingCamera)
    scene = tmp_path / "scene"
    ch = new_channel()
    with SimPiper(ch, q0=Q_READY) as sim:
        rc = cli_main(_args(poses, scene, ch, tmp_path / "cam"))
        assert sim.estop_time() is not None and sim.estopped
    assert rc == 130
    assert not (scene / "primary").exists()
    assert not [p for p in scene.iterdir() if p.name.startswith(".")]


def test_poses_file_problems_name_file_field_and_fix(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: 1\nspeed: 3\ncolour: red\nposes:\n  - [0, 1, 2]\n  - {name: a, q: [0, 1.2, -0.8, 0, 0.4, 0], x: 1}\n")
    with pytest.raises(InputError) as ei:
        load_poses(bad)
    text = str(ei.value)
    for part in ("[speed]", "[colour]", "[poses[0]]", "must be 6 joint values", "[poses[1]]", "unknown key"):
        assert part in text
    assert all(p.fix for p in ei.value.problems)
    # degrees are accepted when said so
    deg = tmp_path / "deg.yaml"
    deg.write_text("format: 1\nunits: deg\nposes:\n  - [0, 68.75, -45.84, 0, 22.92, 0]\n")
    np.testing.assert_allclose(load_poses(deg).q[0], Q_READY, atol=1e-3)
    # a pose outside the joint limits / through the table: refused by the plan, before any hardware
    out_of = _poses_yaml(tmp_path / "limits.yaml", np.array([Q_READY, [0.0, 1.9, -0.9, 0.0, 0.9, 0.0],
                                                            Q_READY + [0, 0, 0, 0, 1.0, 0]]))
    with pytest.raises(InputError) as ei:
        plan_capture(out_of, tmp_path / "s", "primary")
    text = str(ei.value)
    assert "poses[1] (p1)" in text and "workspace box" in text
    assert "poses[2] (p2)" in text and "joint 5" in text


def test_camera_sources(tmp_path):
    arrays = _images(tmp_path / "cam", 2)
    cam = open_camera(str(tmp_path / "cam"))
    assert isinstance(cam, ImageFolderCamera)
    cam.open()
    np.testing.assert_array_equal(cam.grab()[..., ::-1], arrays[0])  # BGR, like OpenCV
    cam.grab()
    from bimanual_app.hardware._camera import CameraError

    with pytest.raises(CameraError, match="all 2 images"):
        cam.grab()
    assert isinstance(open_camera("0"), OpenCVCamera) and open_camera("0").source == 0
    with pytest.raises(CameraError, match="cannot open"):
        OpenCVCamera(str(tmp_path / "no_such_device")).open()


def test_missing_can_interface_is_a_clear_error(tmp_path, capsys):
    poses = _poses_yaml(tmp_path / "poses.yaml")
    _images(tmp_path / "cam", 3)
    rc = cli_main(["capture", "--poses", str(poses), "--out", str(tmp_path / "scene"), "--can", "can_nosuch",
                   "--camera", str(tmp_path / "cam"), "--execute", "hardware"])
    err = capsys.readouterr().err
    assert rc == 1 and "can_nosuch" in err and "does not exist" in err and "ip link set can_nosuch up" in err
    assert not (tmp_path / "scene" / "primary").exists()


def test_feedback_timeout_out_of_range_is_refused_before_connecting(tmp_path, capsys):
    poses = _poses_yaml(tmp_path / "poses.yaml")
    args = _args(poses, tmp_path / "scene", "vnone", tmp_path / "cam")
    args[args.index("--feedback-timeout") + 1] = "5"
    assert cli_main(args) == 1
    err = capsys.readouterr().err
    assert "--feedback-timeout" in err and "feedback_timeout_s" in err and "[0.02, 1.0]" in err
    assert not (tmp_path / "scene").exists()
