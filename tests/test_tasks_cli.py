"""`bijcr task` end to end on a small scene built in code (calibration = ground truth, cloud, segments and
grasps.json in the stages' formats): both tasks plan, pass the physics preview and write everything;
a calibration from another scene, an unknown object, a foreign output folder are refused; an object
with no feasible grasp and a planner that finds no path in time give a clear failed result."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bimanual_app.cli import main
from bimanual_app.hardware import ApprovalError, check_approval, load_approval, load_plan
from bimanual_app.robots import load_robot
from tests._task_fixtures import make_task_workdir


@pytest.fixture(scope="module")
def fixture_dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("taskfx")
    scene, work = make_task_workdir(root, load_robot("piper"))
    return scene, work


def _run(args):
    return main(["task", *map(str, args), "--frame-size", "160x120", "--quiet"])


@pytest.mark.parametrize("task, extra", [("handover", []), ("joint-grasp", ["--truth-objects"])])
def test_task_end_to_end(fixture_dirs, tmp_path, task, extra, monkeypatch):
    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    scene, work = fixture_dirs
    out = tmp_path / task
    assert _run([task, scene, "--work", work, "--out", out, *extra]) == 0
    rec = json.loads((out / "task.json").read_text())
    assert rec["success"] is True and rec["task"] == task
    assert rec["object"] == (0 if task == "handover" else 1) and "best-scoring" in rec["object_reason"]
    check = rec["preview"]["checks"]["hold"]
    assert check["ok"] and check["held_s"] >= 2.0 and check["max_rise_m"] >= 0.10
    assert rec["preview"]["world"] == ("ground truth" if extra else "estimate")
    assert rec["preview"]["contacts"] == []
    names = [p["phase"] for p in rec["plans"]]
    track = rec["preview"]["object_track"]  # where the object was after each phase
    assert [e["phase"] for e in track] == names and track[0]["on_table"] and max(e["rise_m"] for e in track) >= 0.10
    if task == "handover":
        assert track[-1]["held_by"] == ["secondary"] and "primary" in track[names.index("grasp")]["held_by"]
    if task == "handover":
        assert names[:3] == ["reach", "approach", "grasp"] and "release" in names and names[-1] == "hold"
        assert "secondary only" in check["detail"]
    else:
        assert names[:4] == ["reach", "approach", "close", "lift"] and "hold" in names
    assert all(p["duration_s"] > 0 and p["n_waypoints"] >= 2 for p in rec["plans"])
    assert {"plan", "preview", "total"} <= set(rec["timings_s"])
    # outputs: animation, one key frame per phase (+ start), the plan and its signed passing approval
    assert (out / "preview.gif").stat().st_size > 1000
    assert len(list(out.glob("*.png"))) == len(names) + 1
    plan = load_plan(out / "plan.npz")
    appr = check_approval(load_approval(out / "approval.json"), plan)  # raises unless valid for this plan
    assert appr.verdict == "pass" and rec["approval"]["plan_sha256"] == appr.plan_sha256
    # every arm trajectory is within the joint and (validated) velocity limits
    robot = load_robot("piper")
    for tr in plan.values():
        assert np.all(tr.q >= robot.lower - 1e-6) and np.all(tr.q <= robot.upper + 1e-6)
        assert np.all(np.abs(tr.velocities()) <= robot.velocity_limits + 1e-6)
    assert not list(out.parent.glob(f".{out.name}.tmp-*"))  # staging folder gone


def _copy_work(work, tmp_path):
    w = tmp_path / "work"
    shutil.copytree(work, w)
    return w


def test_refuses_a_calibration_of_another_scene(fixture_dirs, tmp_path, capsys):
    scene, work = fixture_dirs
    w = _copy_work(work, tmp_path)
    cal_path = w / "calibration" / "calibration.json"
    cal = json.loads(cal_path.read_text())
    cal["scene"] = "kitchen_monday"
    cal_path.write_text(json.dumps(cal))
    out = tmp_path / "out"
    assert _run(["handover", scene, "--work", w, "--out", out]) == 1
    err = capsys.readouterr().err
    assert "for scene 'kitchen_monday', not 'fixture'" in err and "calibration.json" in err
    assert not out.exists()
    # same name, but the transforms of another capture: the camera poses it implies do not fit the views
    cal["scene"] = "fixture"
    T = np.array(cal["T_b1_w"])
    T[:3, 3] += [0.3, 0.0, 0.0]
    cal["T_b1_w"] = T.tolist()
    cal_path.write_text(json.dumps(cal))
    assert _run(["handover", scene, "--work", w, "--out", out]) == 1
    assert "does not fit this scene's views" in capsys.readouterr().err and not out.exists()
    # more views used than the scene has
    cal = json.loads((work / "calibration" / "calibration.json").read_text())
    cal["views_used"] = {"primary": 9, "secondary": 5}
    cal_path.write_text(json.dumps(cal))
    assert _run(["handover", scene, "--work", w, "--out", out]) == 1
    assert "uses 9 views but primary/ee_poses.csv has 5 rows" in capsys.readouterr().err


def test_bad_object_and_foreign_output_folder_are_refused(fixture_dirs, tmp_path, capsys):
    scene, work = fixture_dirs
    assert _run(["handover", scene, "--work", work, "--out", tmp_path / "o", "--object", "7"]) == 1
    assert "no object 7 in the segments (objects: 0, 1)" in capsys.readouterr().err
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    assert _run(["handover", scene, "--work", work, "--out", foreign]) == 1
    assert "not a task result" in capsys.readouterr().err
    assert (foreign / "notes.txt").read_text() == "keep me" and len(list(foreign.iterdir())) == 1


def test_unreachable_object_gives_a_clear_failed_result(fixture_dirs, tmp_path, capsys):
    scene, work = fixture_dirs
    out = tmp_path / "o"
    # object 1 (the bar) has no hand-over in grasps.json: nothing reaches it for that task
    assert _run(["handover", scene, "--work", work, "--out", out, "--object", "1"]) == 1
    rec = json.loads((out / "task.json").read_text())
    assert rec["success"] is False and rec["failed_stage"] == "grasp"
    assert "object 1 has no reachable hand-over" in rec["reason"]
    assert not (out / "preview.gif").exists() and not (out / "approval.json").exists()
    assert "object 1 has no reachable hand-over" in capsys.readouterr().err


def test_no_plan_in_time_fails_cleanly_and_replaces_an_old_result(fixture_dirs, tmp_path, monkeypatch):
    from bimanual_app.planning import BimanualSetup, MotionPlan

    scene, work = fixture_dirs
    out = tmp_path / "o"
    out.mkdir()
    (out / "task.json").write_text("{}")  # an earlier result: replaced as a whole
    (out / "preview.gif").write_bytes(b"old")

    def no_path(self, arms, q_start, goals, q_now=None, timeout=2.0, seed=None):
        assert timeout == 0.5
        return MotionPlan(False, "RRTConnect found no path", reason="search")

    monkeypatch.setattr(BimanualSetup, "plan_configurations", no_path)
    assert _run(["joint-grasp", scene, "--work", work, "--out", out, "--plan-time", "0.5"]) == 1
    rec = json.loads((out / "task.json").read_text())
    assert rec["success"] is False and rec["failed_stage"] == "plan"
    assert "no path found within the 0.5 s limit" in rec["reason"]
    assert not (out / "preview.gif").exists()  # the stale animation of the old run is gone



def test_push_pair_squeezes_lifts_and_lets_go_before_retreating(tmp_path, monkeypatch):
    """A carton too wide for one gripper, planned through the real grasp stage: a push pair squeezes it,
    lifts, holds and places it, then undoes the squeeze (release) before retreating; the preview in the
    true world holds it. The true carton is 4 mm larger on every side than its points say (a segment
    misses the last millimetres of each edge): the approach stops short of the faces and the squeeze
    presses from the fingertips, not from the gripper's origin, so the fingers neither land on its top nor
    dig into it."""
    import open3d as o3d

    from bimanual_app.io_utils import write_json
    from bimanual_app.transforms import make_T
    from tests._task_fixtures import _scene_folder, box_surface_points

    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    box = {"centre": [0.30, 0.0, 0.05], "size": [0.16, 0.26, 0.10], "mass": 0.8}
    truth = [{"id": 0, "kind": "box", "shape": "box", "T_b1_o": make_T(np.eye(3), box["centre"]),
              "size": [box["size"][0] + 0.008, box["size"][1] + 0.008, box["size"][2]], "mass": box["mass"]}]
    scene = tmp_path / "scene"
    _, cal = _scene_folder(scene, name="carton", objects=truth)
    rng = np.random.default_rng(0)
    table = np.stack([rng.uniform(-0.15, 0.75, 8000), rng.uniform(-0.45, 0.45, 8000), rng.normal(0, 7e-4, 8000)], 1)
    c, sz = np.asarray(box["centre"]), np.asarray(box["size"])
    table = table[~np.all(np.abs(table[:, :2] - c[:2]) < sz[:2] / 2 + 0.003, axis=1)]
    obj = box_surface_points(box["centre"], box["size"], 4000, seed=1, noise=7e-4)
    work = tmp_path / "work"
    (work / "calibration").mkdir(parents=True)
    write_json(work / "calibration" / "calibration.json", cal)
    o3d.io.write_point_cloud(str(work / "calibration" / "scene_b1.ply"),
                             o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.vstack([table, obj]))))
    (work / "segments").mkdir()
    np.savez(work / "segments" / "segments.npz",
             labels=np.r_[np.full(len(table), -1), np.zeros(len(obj), int)].astype(np.int32))
    out = tmp_path / "push"
    assert _run(["joint-grasp", scene, "--work", work, "--out", out, "--truth-objects"]) == 0
    rec = json.loads((out / "task.json").read_text())
    assert rec["success"] is True, rec["reason"]
    names = [p["phase"] for p in rec["plans"]]
    assert names == ["reach", "approach", "squeeze", "lift", "hold", "place", "release", "retreat"]
    assert rec["preview"]["checks"]["hold"]["max_rise_m"] >= 0.10
    # the approach ends PUSH_STANDOFF (>= 5 mm) short of the contact, the squeeze at least ``press`` past it
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._planners import PUSH_STANDOFF

    assert PUSH_STANDOFF >= 0.005
    robot = load_robot("piper")
    plan = np.load(out / "plan.npz")
    ends = np.cumsum([p["duration_s"] for p in rec["plans"]])
    for arm, g in rec["plan"]["info"]["grasps"].items():
        T_b1_b = np.eye(4) if arm == "primary" else np.asarray(cal["T_b1_b2"])
        times, q = plan[f"{arm}/times"], plan[f"{arm}/q"]
        at = [T_b1_b @ robot.fk_link(q[np.argmin(np.abs(times - ends[k]))], robot.tcp_link) for k in (1, 2)]
        contact = np.asarray(g["T_b1_g"])[:3, 3]
        assert abs(np.linalg.norm(at[0][:3, 3] - contact) - PUSH_STANDOFF) < 0.002, arm
        assert np.linalg.norm(at[1][:3, 3] - contact) >= g["press"] - 0.002, arm


def _with_alternative(work, tmp_path):
    """A copy of the fixture's work folder whose object 0 also has a second, slightly worse hand-over."""
    w = _copy_work(work, tmp_path)
    path = w / "grasps" / "grasps.json"
    g = json.loads(path.read_text())
    alt = json.loads(json.dumps(g["objects"][0]["handover"]))
    alt["score"] = 0.6
    g["objects"][0]["handover_alternatives"] = [alt]
    path.write_text(json.dumps(g))
    return w


def _handover_failing_previews(monkeypatch, scene, w, tmp_path, fails) -> tuple[dict, list]:
    """The hand-over run (exit code 0 expected) with the preview on the reconstruction failing the plans for
    which ``fails(plan, k)`` (k: the preview's number) is true and run for real on the others; returns
    task.json and, per preview, whether it was on the ground truth."""
    from bimanual_app.tasks import _preview

    real, calls = _preview.preview_plan, []

    def preview(plan, *a, **kw):
        calls.append(kw.get("truth", False))
        if fails(plan, len(calls) - 1):
            return _preview.PreviewResult(False, "hold: the object slipped out (test)")
        return real(plan, *a, **kw)

    monkeypatch.setattr(_preview, "preview_plan", preview)
    out = tmp_path / "o"
    assert _run(["handover", scene, "--work", w, "--out", out]) == 0
    return json.loads((out / "task.json").read_text()), calls


def test_a_failed_preview_moves_on_to_the_next_candidate(fixture_dirs, tmp_path, monkeypatch):
    """The first plan's preview (on the reconstruction) drops the object: the task plans and previews the
    next candidate, which passes; task.json lists both previews and the plan is the second candidate's."""
    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    scene, work = fixture_dirs
    w = _with_alternative(work, tmp_path)
    rec, calls = _handover_failing_previews(monkeypatch, scene, w, tmp_path, lambda plan, k: k == 0)
    assert rec["success"] is True and calls == [False, False]
    assert [p["success"] for p in rec["previews_tried"]] == [False, True]
    assert rec["previews_tried"][0]["reason"] == "hold: the object slipped out (test)"
    assert rec["plan"]["info"]["candidate_rank"] == 1
    assert load_approval(tmp_path / "o" / "approval.json").verdict == "pass"


def test_when_every_preview_fails_the_first_is_reported_and_not_approved(fixture_dirs, tmp_path, monkeypatch):
    from bimanual_app.tasks import _preview

    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    scene, work = fixture_dirs
    w = _with_alternative(work, tmp_path)
    monkeypatch.setattr(_preview, "preview_plan",
                        lambda plan, *a, **kw: _preview.PreviewResult(False, f"hold: dropped ({len(plan.phases)} phases)"))
    _without_redraw(monkeypatch)  # the candidates of grasps.json only (the redraw: its own test below)
    out = tmp_path / "o"
    assert _run(["handover", scene, "--work", w, "--out", out]) == 1
    rec = json.loads((out / "task.json").read_text())
    assert rec["success"] is False and rec["failed_stage"] == "preview"
    assert "2 plans previewed, none passed" in rec["reason"] and len(rec["previews_tried"]) == 2
    assert rec["plan"]["info"]["candidate_rank"] == 0  # the first failed one is what is reported
    plan = load_plan(out / "plan.npz")
    assert load_approval(out / "approval.json").verdict == "fail"
    with pytest.raises(ApprovalError, match="verdict is 'fail'"):
        check_approval(load_approval(out / "approval.json"), plan)  # the hardware refuses a failed preview


def test_ctrl_c_while_a_task_writes_leaves_the_old_result_whole(fixture_dirs, tmp_path, monkeypatch):
    """Ctrl-C after the task has written part of its result (the plan) into its staging folder: the
    interrupt goes through (exit 130), the earlier result in OUT stays as it was, and no staging folder or
    partial file is left beside it."""
    import bimanual_app.tasks._run as task_run

    scene, work = fixture_dirs
    out = tmp_path / "o"
    out.mkdir()
    (out / "task.json").write_text('{"earlier": true}')
    real_report = task_run._report_plan

    def report_then_interrupt(*args, **kwargs):
        real_report(*args, **kwargs)  # plan.npz is written into the staging folder
        raise KeyboardInterrupt

    monkeypatch.setattr(task_run, "_report_plan", report_then_interrupt)
    assert main(["task", "joint-grasp", str(scene), "--work", str(work), "--out", str(out), "--quiet"]) == 130
    assert sorted(p.name for p in out.iterdir()) == ["task.json"]
    assert json.loads((out / "task.json").read_text()) == {"earlier": True}
    assert [p.name for p in tmp_path.iterdir()] == ["o"]  # no .o.tmp-* staging folder


def _two_objects_with_handovers(work, tmp_path, n_first: int):
    """A copy of the fixture's work folder in which object 0 has ``n_first`` hand-overs and object 1 one."""
    w = _copy_work(work, tmp_path)
    path = w / "grasps" / "grasps.json"
    g = json.loads(path.read_text())
    h = g["objects"][0]["handover"]
    g["objects"][0]["handover_alternatives"] = [dict(h, score=0.7 - 0.05 * (k + 1)) for k in range(n_first - 1)]
    g["objects"][1]["handover"] = dict(h, score=0.3)
    path.write_text(json.dumps(g))
    return w


def _without_redraw(monkeypatch) -> None:
    """The task without its "preview-redraw" fallback (no search again after every preview failed)."""
    from bimanual_app.tasks import _run as run_module

    monkeypatch.setattr(run_module, "_redraw", lambda *a, **kw: None)


def test_when_every_preview_fails_the_hand_overs_are_drawn_again_without_those_picks(fixture_dirs, tmp_path,
                                                                                    monkeypatch):
    """Every candidate of grasps.json fails its preview: the grasp stage's search runs again on the object
    without the refused picks; a redrawn hand-over whose preview passes is the task's plan."""
    from grasping._handover import refused as near_refused

    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    scene, work = fixture_dirs
    w = _with_alternative(work, tmp_path)
    rec, _ = _handover_failing_previews(monkeypatch, scene, w, tmp_path,
                                        lambda plan, k: not plan.info["source"].startswith("redrawn "))
    assert rec["success"] is True and rec["redrawn"][0]["object"] == 0 and rec["redrawn"][0]["found"] >= 1
    assert rec["redrawn"][0]["refused_picks"] == 2 and rec["previews_tried"][-1]["success"]
    assert rec["plan"]["info"]["source"].startswith("redrawn objects[0].")
    assert "preview-redraw" in rec["plan"]["info"]["fallbacks"]
    g = json.loads((Path(w) / "grasps" / "grasps.json").read_text())["objects"][0]
    refused = np.stack([h["giver"]["pick"]["T_b1_g"] for h in [g["handover"], *g["handover_alternatives"]]])
    pick = np.asarray(rec["plan"]["info"]["grasps"]["pick"]["T_b1_g"])
    assert not near_refused(pick[None], refused)[0]  # another pick than the two that failed
    assert load_approval(tmp_path / "o" / "approval.json").verdict == "pass"


def test_a_redraw_that_cannot_run_leaves_the_task_failed_as_before(fixture_dirs, tmp_path, monkeypatch):
    """The redraw's grasp search refuses its inputs: the task ends with its first failed preview, as without
    the redraw, and task.json says why the redraw did not run."""
    import grasping
    from bimanual_app.io_utils import InputError, Problem
    from bimanual_app.tasks import _preview

    def refuse(cloud, *a, **kw):
        raise InputError(Problem(str(cloud), "views", "unreadable (test)", "re-run bijcr calibrate"))

    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    monkeypatch.setattr(grasping, "redraw_handovers", refuse)
    monkeypatch.setattr(_preview, "preview_plan", lambda *a, **kw: _preview.PreviewResult(False, "hold: dropped"))
    scene, work = fixture_dirs
    out = tmp_path / "o"
    assert _run(["handover", scene, "--work", _with_alternative(work, tmp_path), "--out", out]) == 1
    rec = json.loads((out / "task.json").read_text())
    assert rec["failed_stage"] == "preview" and "2 plans previewed, none passed" in rec["reason"]
    assert "unreadable (test)" in rec["redrawn"][0]["error"] and "found" not in rec["redrawn"][0]


def _previews_in_order(fixture_dirs, tmp_path, monkeypatch, object_1_plans: bool) -> list:
    """The (object, candidate) previewed, in order, when every preview fails; plans are object 0's first
    candidate's (the geometry is beside the point), and object 1's fail to plan unless ``object_1_plans``."""
    from bimanual_app.tasks import _preview
    from bimanual_app.tasks import _run as run_module
    from bimanual_app.tasks._motion import PlanFailure

    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    scene, work = fixture_dirs
    w = _two_objects_with_handovers(work, tmp_path, 3)
    real, first = run_module._plan_candidate, {}

    def plan_candidate(opts, motion_o, c, k, *a):
        if c.object_id == 1 and not object_1_plans:
            raise PlanFailure("plan", "no path (test)")
        first.setdefault("args", (opts, motion_o, c, 0, *a))
        return real(*first["args"])

    monkeypatch.setattr(run_module, "_plan_candidate", plan_candidate)
    monkeypatch.setattr(_preview, "preview_plan", lambda *a, **kw: _preview.PreviewResult(False, "hold: dropped"))
    _without_redraw(monkeypatch)  # the budget among grasps.json's candidates
    out = tmp_path / "o"
    assert _run(["handover", scene, "--work", w, "--out", out]) == 1
    rec = json.loads((out / "task.json").read_text())
    return [(p["object"], p["candidate_rank"]) for p in rec["previews_tried"]]


def test_two_failed_previews_of_one_object_leave_the_last_to_the_next_object(fixture_dirs, tmp_path, monkeypatch):
    """An object's previews fail together when its estimated body fails them: after two, the last of the
    three previews goes to the next object rather than to a third grasp of the same object."""
    assert _previews_in_order(fixture_dirs, tmp_path, monkeypatch, True) == [(0, 0), (0, 1), (1, 0)]


def test_the_preview_left_by_an_object_that_plans_nothing_goes_back(fixture_dirs, tmp_path, monkeypatch):
    """When the next object plans nothing, the preview it was left goes back to the first object's third."""
    assert _previews_in_order(fixture_dirs, tmp_path, monkeypatch, False) == [(0, 0), (0, 1), (0, 2)]


def test_a_failed_preview_says_where_the_object_was_lost():
    from bimanual_app.simulation import HoldSample
    from bimanual_app.tasks import last_loss
    from bimanual_app.tasks._preview import phase_state, where_lost

    def at(phase, rise, held):
        return phase_state(phase, HoldSample(0.0, rise, frozenset(held), frozenset(held), rise < 0.01))

    lost = [at("grasp", 0.0, {"primary"}), at("lift", 0.12, {"primary"}), at("receive-grasp", 0.12, {"primary", "secondary"}),
            at("release", 0.0, set()), at("hold", 0.0, set())]
    assert where_lost(lost) == " (held by the primary and secondary after receive-grasp; by no arm after release, 0.0 cm up)"
    assert where_lost([at("grasp", 0.0, set()), at("lift", 0.0, set())]) == " (no arm held it after any phase)"
    assert where_lost(lost[:3]) == "" and where_lost([]) == "" and last_loss(lost[:3]) is None
    assert last_loss(lost) == {"held_after": "receive-grasp", "by": ["primary", "secondary"], "lost_after": "release",
                               "rise_m": 0.0}
    assert last_loss([at("grasp", 0.0, set())])["held_after"] is None
    assert lost[0] == {"phase": "grasp", "rise_m": 0.0, "held_by": ["primary"], "touched_by": ["primary"], "on_table": True}
