"""`bijcr task ... --execute hardware` against simulated Piper arms on python-can's virtual bus: a link that
stops answering mid-motion stops both arms and gives a clear failed result; no arms, no plan; hardware
and ground-truth evaluation do not mix."""

import json

import pytest

from bimanual_app.cli import main
from bimanual_app.robots import load_robot
from tests._hw_fixtures import SimPiper, new_channel
from tests._task_fixtures import make_task_workdir


@pytest.fixture(scope="module")
def fixture_dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("taskhw")
    return make_task_workdir(root, load_robot("piper"))


def _hw_args(scene, work, out, c1, c2):
    return ["task", "handover", str(scene), "--work", str(work), "--out", str(out), "--execute", "hardware",
            "--can-interface", "virtual", "--can-primary", c1, "--can-secondary", c2, "--no-record", "--quiet"]


def test_link_failing_mid_motion_stops_both_arms(fixture_dirs, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    scene, work = fixture_dirs
    c1, c2 = new_channel(), new_channel()
    out = tmp_path / "o"
    with SimPiper(c1, silent_after_joint_cmds=30) as a, SimPiper(c2) as b:
        rc = main(_hw_args(scene, work, out, c1, c2))
        stop_a, stop_b = a.estop_time(), b.estop_time()
        moved = len(a.joint_cmds)
    assert rc == 1
    assert stop_a is not None and stop_b is not None  # the stop went to both arms
    assert moved >= 30  # it did start moving: the failure is mid-motion
    rec = json.loads((out / "task.json").read_text())
    assert rec["success"] is False and rec["failed_stage"] == "hardware"
    assert rec["hardware"]["ok"] is False and set(rec["hardware"]["stopped"]) == {"primary", "secondary"}
    assert "joint feedback stopped" in rec["reason"]
    assert rec["approval"]["verdict"] == "pass"  # the preview passed; the hardware is what failed
    assert "hardware run failed" in capsys.readouterr().err


def test_no_arms_on_the_bus_nothing_is_planned(fixture_dirs, tmp_path):
    scene, work = fixture_dirs
    out = tmp_path / "o"
    assert main(_hw_args(scene, work, out, new_channel(), new_channel())) == 1
    rec = json.loads((out / "task.json").read_text())
    assert rec["failed_stage"] == "hardware" and "cannot connect to the arms" in rec["reason"]
    assert rec["plans"] == [] and not (out / "plan.npz").exists()


def test_hardware_and_truth_objects_do_not_mix(fixture_dirs, tmp_path, capsys):
    scene, work = fixture_dirs
    args = _hw_args(scene, work, tmp_path / "o", "a", "b") + ["--truth-objects"]
    assert main(args) == 1
    assert "--truth-objects is an evaluation" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
