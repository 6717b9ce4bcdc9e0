"""`bijcr view`: a run folder read into layers (missing parts absent, broken files named), the carried
object of a replay, and the page served, rendered in headless Chromium and stopped by its timeout and
by Ctrl-C."""

import json
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bimanual_app.cli import main as bijcr
from bimanual_app.io_utils import InputError
from bimanual_app.viewer import PhaseSpan, hold_intervals, load_run, object_pose, object_track

ROOT = Path(__file__).resolve().parents[1]
SIGMA_MM = [3.0, 4.0, 2.0]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """The task fixture's work folder (calibration, cloud, segments, grasps) with a planned hand-over, a
    run.json naming the scene and a T_b1_b2 uncertainty: the layout `bijcr run` writes."""
    from bimanual_app.robots import load_robot
    from tests._task_fixtures import make_task_workdir

    scene, work = make_task_workdir(tmp_path_factory.mktemp("view"), load_robot("piper"))
    assert bijcr(["task", "handover", str(scene), "--work", str(work), "--out", str(work / "tasks" / "handover"),
                  "--no-record", "--quiet"]) == 0
    (work / "run.json").write_text(json.dumps({"format": 1, "scene": str(scene)}))
    cal_path = work / "calibration" / "calibration.json"
    cal = json.loads(cal_path.read_text())
    cal["uncertainty"] = {"T_b1_b2": {"translation_mm": SIGMA_MM, "rotation_axes_deg": [0.1, 0.1, 0.1]}}
    cal_path.write_text(json.dumps(cal))
    return work


def _copy(run_dir, dst, parts=("calibration", "segments", "grasps", "tasks")):
    dst.mkdir()
    for p in parts:
        shutil.copytree(run_dir / p, dst / p)
    return dst


# ------------------------------------------------------------------------------------------ reading

def test_every_layer_is_read(run_dir):
    from bimanual_app.scene import load_scene

    layers = load_run(run_dir)
    assert layers.cloud is not None and layers.cloud.object_ids() == [0, 1]
    assert len(layers.cloud.labels) == len(layers.cloud.points)
    np.testing.assert_allclose(layers.sigma_b1_b2_m, np.array(SIGMA_MM) * 1e-3)
    # every capture view of both arms, the camera placed by the calibration's chain
    scene = load_scene(layers.scene_dir)
    assert len(layers.cameras) == len(scene.primary) + len(scene.secondary)
    v = next(c for c in layers.cameras if c.arm == "secondary")
    i = scene.secondary.images.index(v.image)
    np.testing.assert_allclose(v.T_b1_c, layers.T_b1_b2 @ scene.secondary.T_b_e[i] @ layers.T_e_c["secondary"])
    assert any("no intrinsics" in n for n in layers.notes)  # the fixture scene has no camera block
    # grasps: the hand-over of object 0, the pair of object 1
    assert layers.grasps[0].handover is not None and layers.grasps[0].T_move is not None
    assert len(layers.grasps[1].joint) == 1 and not layers.grasps[1].single
    # the hand-over plan, its phases on the plan's clock
    (task,) = layers.tasks
    assert task.name == "handover" and task.object_id == 0 and task.success
    assert [p.name for p in task.phases][:3] == ["reach", "approach", "grasp"]
    assert task.phases[-1].t1 == pytest.approx(task.duration, abs=0.01)
    assert not any(n.startswith(("cloud", "segments", "grasps", "tasks", "uncertainty")) for n in layers.notes)


def test_missing_parts_are_absent_layers_with_notes(run_dir, tmp_path):
    bare = _copy(run_dir, tmp_path / "bare", parts=("calibration",))
    layers = load_run(bare)
    assert layers.cloud is not None and layers.cloud.labels is None
    assert layers.cameras == [] and layers.grasps == {} and layers.tasks == []
    for what in ("segments:", "grasps:", "tasks:", "cameras:"):
        assert any(n.startswith(what) for n in layers.notes), (what, layers.notes)
    # a task that produced no plan (it failed before planning) is a note, not an error
    failed = _copy(run_dir, tmp_path / "failed")
    (failed / "tasks" / "handover" / "plan.npz").unlink()
    layers = load_run(failed)
    assert layers.tasks == [] and any(n.startswith("task handover: no plan.npz") for n in layers.notes)
    # the scene given explicitly when the run does not name it
    layers = load_run(bare, scene=run_dir.parent / "scene")
    assert len(layers.cameras) > 0


def _corrupt_calibration(d):
    (d / "calibration" / "calibration.json").write_text("{not json")
    return "calibration.json", ""


def _bad_transform(d):
    p = d / "calibration" / "calibration.json"
    cal = json.loads(p.read_text())
    cal["T_b1_b2"] = [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    p.write_text(json.dumps(cal))
    return "calibration.json", "T_b1_b2"


def _short_labels(d):
    np.savez(d / "segments" / "segments.npz", labels=np.zeros(10, np.int32))
    return "segments.npz", "labels"


def _corrupt_grasps(d):
    p = d / "grasps" / "grasps.json"
    g = json.loads(p.read_text())
    del g["objects"][1]["joint_grasps"][0]["secondary"]["T_b1_g"]
    p.write_text(json.dumps(g))
    return "grasps.json", "objects[1].joint_grasps[0].secondary"


def _corrupt_plan(d):
    (d / "tasks" / "handover" / "plan.npz").write_bytes(b"PK\x03\x04 not a zip")
    return "plan.npz", ""


def _corrupt_task(d):
    (d / "tasks" / "handover" / "task.json").write_text("[1, 2")
    return "task.json", ""


@pytest.mark.parametrize("break_it", [_corrupt_calibration, _bad_transform, _short_labels, _corrupt_grasps,
                                      _corrupt_plan, _corrupt_task])
def test_unreadable_file_is_a_named_error(run_dir, tmp_path, break_it):
    d = _copy(run_dir, tmp_path / "run")
    fname, field = break_it(d)
    with pytest.raises(InputError) as e:
        load_run(d)
    (p,) = e.value.problems
    assert Path(p.file).name == fname and p.field == field and p.fix


def test_not_a_run_folder_is_named(tmp_path, capsys):
    assert bijcr(["view", str(tmp_path), "--timeout", "1"]) == 1
    err = capsys.readouterr().err
    assert "not a run folder" in err and "bijcr run" in err


def test_unknown_task_is_named(run_dir, capsys):
    assert bijcr(["view", str(run_dir), "--task", "juggle", "--timeout", "1"]) == 1
    err = capsys.readouterr().err
    assert "--task" in err and "juggle" in err and "handover" in err


def test_without_viser_the_command_names_the_extra(run_dir, monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "viser" else real(name, *a))
    assert bijcr(["view", str(run_dir), "--timeout", "1"]) == 1
    err = capsys.readouterr().err
    assert "viser" in err and "pip install -e .[view]" in err


def test_bijcr_run_names_the_view_command_and_the_scene(run_dir, tmp_path, capsys):
    """`bijcr run` (every stage skipped here) prints the view command, names it in report.html and leaves
    run.json, from which the viewer finds the scene."""
    scene = run_dir.parent / "scene"
    out = tmp_path / "out"
    skip = [a for st in ("calibrate", "segment", "grasp", "joint-grasp", "handover") for a in ("--skip", st)]
    assert bijcr(["run", str(scene), "--out", str(out), *skip]) == 0
    assert f"bijcr view {out}" in capsys.readouterr().out
    assert f"bijcr view {out}" in (out / "report.html").read_text()
    assert Path(json.loads((out / "run.json").read_text())["scene"]) == scene.resolve()
    # with the run's results beside it, the viewer finds the capture cameras through run.json
    for part in ("calibration", "segments"):
        shutil.copytree(run_dir / part, out / part)
    assert len(load_run(out).cameras) > 0


# ------------------------------------------------------------------------------------- the replay

def _translation(x):
    T = np.eye(4)
    T[:3, 3] = x
    return T


def test_carried_object_follows_its_holder_through_a_hand_over():
    # primary grasps at t=1 and moves +x at 1 m/s; the secondary closes at t=3 and moves +y at 1 m/s from
    # t=4, when the primary lets go
    phases = [PhaseSpan("approach", 0, 0.5, ("primary",)), PhaseSpan("grasp", 0.5, 1, ("primary",)),
              PhaseSpan("transfer", 1, 2, ("primary",)), PhaseSpan("receive-grasp", 2, 3, ("secondary",)),
              PhaseSpan("release", 4, 5, ("primary",)), PhaseSpan("hold", 5, 6, ("secondary",))]
    pose = {"primary": lambda t: _translation([t, 0, 0]), "secondary": lambda t: _translation([5, max(t - 4, 0), 0])}
    pose_fn = lambda arm, t: pose[arm](t)  # noqa: E731
    assert hold_intervals(phases) == {"primary": [(1, 4)], "secondary": [(3, float("inf"))]}
    track = object_track(phases, pose_fn)
    assert [(h.arm, h.t0, h.t1) for h in track] == [("primary", 1, 4), ("secondary", 4, float("inf"))]
    at = lambda t: object_pose(track, pose_fn, t)[:3, 3]  # noqa: E731
    np.testing.assert_allclose(at(0.7), [0, 0, 0])  # still on the table
    np.testing.assert_allclose(at(2.5), [1.5, 0, 0])  # carried by the primary
    np.testing.assert_allclose(at(4.0), [3, 0, 0])  # handed over where the primary held it
    np.testing.assert_allclose(at(5.5), [3, 1.5, 0])  # then carried by the secondary
    # nobody holds it: it never moves
    assert object_track([PhaseSpan("reach", 0, 1, ("primary",))], pose_fn) == []


def test_replayed_object_reaches_the_transfer_pose(run_dir):
    from bimanual_app.robots import load_robot
    from bimanual_app.viewer._motion import gripper_poses

    layers = load_run(run_dir)
    (task,) = layers.tasks
    robot = load_robot("piper")

    def pose_fn(arm, t):
        return gripper_poses(robot, layers.T_b1_base(arm), task.trajectories[arm].sample(t)[0])

    track = object_track(task.phases, pose_fn)
    assert [h.arm for h in track] == ["primary", "secondary"]
    info = json.loads((run_dir / "tasks" / "handover" / "task.json").read_text())["plan"]["info"]
    # the object's centre (the segment's centroid) carried by the plan's own joint angles ends where the
    # hand-over put it
    c = layers.cloud.points[layers.cloud.labels == 0].mean(axis=0)
    release = next(p for p in task.phases if p.name == "release")
    T = object_pose(track, pose_fn, release.t0)
    target = np.asarray(info["T_move"])[:3, :3] @ c + np.asarray(info["T_move"])[:3, 3]
    assert np.linalg.norm(T[:3, :3] @ c + T[:3, 3] - target) < 0.01


def test_replay_panel_moves_the_arms_and_the_object(run_dir):
    """The replay panel in a live viser scene (no browser): choosing the task, the slider, play."""
    import viser

    from bimanual_app.viewer import build_scene

    layers = load_run(run_dir)
    server = viser.ViserServer(host="127.0.0.1", port=_free_port(), verbose=False)
    try:
        player = build_scene(server, layers)
        assert player.choice.options[0] == "start configuration" and "handover" in player.choice.options
        node = player.objects["handover"]
        assert not node.visible and player.slider.disabled
        player.choice.value = "handover"
        assert node.visible and not player.slider.disabled
        task = player.tasks["handover"]
        assert player.slider.max == pytest.approx(task.duration, abs=0.01)
        transfer = next(p for p in task.phases if p.name == "transfer")
        player.slider.value = round(transfer.t1, 2)  # the object carried to the transfer pose
        info = json.loads((run_dir / "tasks" / "handover" / "task.json").read_text())["plan"]["info"]
        np.testing.assert_allclose(node.position, np.asarray(info["T_move"])[:3, 3], atol=0.01)
        assert "transfer" in player.phase_md.content
        q_before = player.arms["secondary"].urdf._urdf.cfg.copy()
        player.toggle()  # play: wall time advances the plan
        player.tick(1.5)
        assert player.slider.value == pytest.approx(round(transfer.t1, 2) + 1.5, abs=0.02)
        assert np.abs(player.arms["secondary"].urdf._urdf.cfg - q_before).max() > 1e-3  # receive-reach moves it
        player.choice.value = "start configuration"
        assert not node.visible and not player.playing
    finally:
        server.stop()


# ------------------------------------------------------------------------------------- the server

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(run_dir, *extra):
    """Start `bijcr view` in a subprocess; returns (process, url) once it prints the URL."""
    cmd = [sys.executable, "-m", "bimanual_app.cli", "view", str(run_dir), "--port", str(_free_port()), *extra]
    p = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    lines = []
    while time.monotonic() - t0 < 180:
        line = p.stdout.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"serving .* at (http://127\.0\.0\.1:\d+)", "".join(lines))
        if m and "Ctrl-C stops" in line:  # the last line it prints once the page is ready
            return p, m.group(1), lines
    p.kill()
    raise AssertionError("bijcr view did not start:\n" + "".join(lines) + p.stderr.read())


def _shot(url: str, path: Path, profile: Path) -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "chromium is missing: `make test` installs it (tools/setup_test_deps.sh)"
    # viser draws with WebGL: SwiftShader gives headless Chromium a software GPU
    flags = ["--headless", "--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
             "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={profile}", "--window-size=1200,800", "--virtual-time-budget=15000"]
    subprocess.run([chromium, *flags, f"--screenshot={path}", url], capture_output=True, timeout=180)


def test_page_renders_in_headless_chromium_and_ctrl_c_stops_it(run_dir, tmp_path):
    from PIL import Image

    from bimanual_app.viewer._draw import segment_colors

    # the grasps, cameras and arms hidden: a gripper mesh may cover an object from this viewpoint, and the primary
    # arm's shaded blue-grey is too near object 0's blue for the colour test below
    p, url, lines = _start(run_dir, "--timeout", "600", "--hide", "grasps", "--hide", "cameras", "--hide", "arms")
    try:
        out = "".join(lines)
        port = int(url.rsplit(":", 1)[1])
        assert "listening on 127.0.0.1 only" in out and f"ssh -L {port}:127.0.0.1:{port}" in out
        # on a loaded machine the page can be captured before the server's scene has arrived over the
        # websocket (the virtual time budget runs on the browser's clock, not the server's): shoot again then
        for attempt in range(3):
            shot = tmp_path / f"view{attempt}.png"
            _shot(url, shot, tmp_path / f"profile{attempt}")
            assert shot.exists(), "chromium wrote no screenshot"
            img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
            h, w = img.shape[:2]
            scene = img[int(h * 0.3):, : int(w * 0.7)]  # below the browser's notices, left of the GUI panel
            if scene.std() > 20:
                break
        assert scene.std() > 20, "the 3D view is blank"
        # the segments are drawn: pixels of both objects' colours and of the grey table. The renderer lightens
        # small points towards the white background (more or less with the load on the machine), so a pixel
        # counts when it lies on the line from white to the colour, at least a quarter of the way
        white = np.array([255.0, 255.0, 255.0])
        # (with the cloud hidden: 0, 5 and about 330 such pixels, the last from the labels' grey anti-aliasing)
        for colour, least in zip(segment_colors(np.array([0, 1, -1])), (300, 300, 5000)):
            d = colour.astype(float) - white
            t = (scene - white) @ d / (d @ d)
            off = np.linalg.norm(scene - (white + t[..., None] * d), axis=2)
            near = (t > 0.25) & (t < 1.15) & (off < 15)
            assert near.sum() > least, f"too few pixels of colour {colour} (or lighter) in the view: {near.sum()}"
        p.send_signal(signal.SIGINT)  # Ctrl-C
        assert p.wait(timeout=60) == 130
        assert "interrupted" in p.stderr.read()
        with socket.socket() as s:  # the port is free again
            assert s.connect_ex(("127.0.0.1", port)) != 0
    finally:
        if p.poll() is None:
            p.kill()


def test_server_stops_on_its_own_after_timeout(run_dir):
    p, url, _ = _start(run_dir, "--timeout", "2")
    try:
        assert p.wait(timeout=60) == 0
        assert "bijcr view: stopped" in p.stdout.read()
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", int(url.rsplit(":", 1)[1]))) != 0
    finally:
        if p.poll() is None:
            p.kill()
