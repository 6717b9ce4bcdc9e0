"""Preview approvals and trajectories: hashing, signing, files, dry-run validation (no hardware)."""

import json
import os
import stat

import numpy as np
import pytest

from bimanual_app.hardware import (
    ApprovalError,
    JointTrajectory,
    LimitViolation,
    SafetyLimits,
    approve_plan,
    as_trajectory,
    check_approval,
    joint_move,
    load_approval,
    load_plan,
    save_plan,
    trajectory_hash,
    validate_plan,
    write_approval,
)
from bimanual_app.io_utils import InputError
from tests._hw_fixtures import Q_READY, line_trajectory

KEY = b"k1"


def _plan():
    return {"primary": line_trajectory(Q_READY, Q_READY + 0.2, 1.0, gripper=(0.0, 0.03)),
            "secondary": line_trajectory(Q_READY, Q_READY - 0.2, 1.0)}


def test_hash_is_stable_across_a_json_round_trip_and_changes_with_the_plan(tmp_path):
    plan = _plan()
    h = trajectory_hash(plan)
    # JSON round trip (what a task.json would hold)
    as_json = json.loads(json.dumps({k: {"times": v.times.tolist(), "q": v.q.tolist(),
                                         "gripper": None if v.gripper is None else v.gripper.tolist()}
                                     for k, v in plan.items()}))
    assert trajectory_hash({k: as_trajectory(v) for k, v in as_json.items()}) == h
    # npz round trip
    save_plan(tmp_path / "plan.npz", plan)
    assert trajectory_hash(load_plan(tmp_path / "plan.npz")) == h
    # any change: one joint by 1e-6 rad, a time stamp, the gripper, an arm name
    q = plan["primary"].q.copy()
    q[10, 3] += 1e-6
    assert trajectory_hash({**plan, "primary": JointTrajectory(plan["primary"].times, q, plan["primary"].gripper)}) != h
    t = plan["secondary"].times.copy()
    t[-1] += 0.01
    assert trajectory_hash({**plan, "secondary": JointTrajectory(t, plan["secondary"].q)}) != h
    assert trajectory_hash({**plan, "primary": JointTrajectory(plan["primary"].times, plan["primary"].q)}) != h
    assert trajectory_hash({"secondary": plan["primary"], "primary": plan["secondary"]}) != h


def test_approval_record_round_trip_and_checks(tmp_path):
    plan = _plan()
    rec = approve_plan(plan, "pass", {"task": "handover", "lift_m": 0.11}, key=KEY)
    path = tmp_path / "approval.json"
    write_approval(path, rec)
    back = load_approval(path)
    assert back == rec and back.signature.startswith("hmac-sha256:")
    assert check_approval(path, plan, key=KEY).passed
    assert back.duration_s == pytest.approx(1.0)
    for edit in ('"lift_m": 0.11', '"task": "handover"'):
        assert edit in path.read_text()
    tampered = path.read_text().replace('"lift_m": 0.11', '"lift_m": 0.5')
    path.write_text(tampered)
    with pytest.raises(ApprovalError, match="signature"):
        check_approval(path, plan, key=KEY)
    with pytest.raises(ApprovalError, match="missing"):
        check_approval(tmp_path / "nope.json", plan, key=KEY)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ApprovalError, match="not valid JSON"):
        check_approval(tmp_path / "bad.json", plan, key=KEY)
    with pytest.raises(ValueError):
        approve_plan(plan, "maybe", key=KEY)


def test_default_key_file_is_private_and_reused(tmp_path, monkeypatch):
    monkeypatch.delenv("BIJCR_APPROVAL_KEY", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    plan = _plan()
    rec = approve_plan(plan, "pass")
    key_file = tmp_path / "cfg" / "bijcr" / "approval.key"
    assert key_file.is_file()
    assert stat.S_IMODE(os.stat(key_file).st_mode) == 0o600
    assert check_approval(rec, plan).passed  # same key read back
    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "another machine")
    with pytest.raises(ApprovalError, match="signature"):
        check_approval(rec, plan)


def test_trajectory_input_checks():
    with pytest.raises(InputError, match="increase strictly"):
        JointTrajectory([0.0, 0.5, 0.5], np.zeros((3, 6)))
    with pytest.raises(ValueError, match="shape"):
        JointTrajectory([0.0, 1.0], np.zeros((3, 6)))
    with pytest.raises(InputError, match="NaN"):
        JointTrajectory([0.0, 1.0], np.array([[0.0] * 6, [np.nan] + [0.0] * 5]))
    with pytest.raises(InputError, match="cannot read"):
        as_trajectory({"q": np.zeros((2, 6))})
    tr = JointTrajectory([1.0, 2.0, 3.0], [[0.0] * 6, [1.0] * 6, [3.0] * 6])
    assert tr.times[0] == 0.0 and tr.duration == 2.0
    q, g = tr.sample(1.5)
    np.testing.assert_allclose(q, 2.0)
    assert g is None
    np.testing.assert_allclose(tr.sample(99)[0], 3.0)


def test_joint_move_respects_speed_and_acceleration():
    lim = SafetyLimits.from_robot("piper")
    q0, q1 = Q_READY, Q_READY + np.array([1.0, -0.3, 0.2, 0.0, 0.5, -1.2])
    v, a = lim.velocity * 0.5, np.full(6, 2.0)
    tr = joint_move(q0, q1, v, a, dt=0.005)
    np.testing.assert_allclose(tr.q[0], q0)
    np.testing.assert_allclose(tr.q[-1], q1)
    vel = tr.velocities()
    assert np.all(np.abs(vel) <= v * 1.001)
    acc = np.diff(vel, axis=0) / 0.005
    assert np.all(np.abs(acc) <= a * 1.02)
    assert np.max(np.abs(vel[:, 5])) > 0.95 * v[5], "the slowest joint sets the duration: it reaches its speed limit"


def test_validate_plan_is_the_dry_run():
    lim = {n: SafetyLimits.from_robot("piper", name=n) for n in ("primary", "secondary")}
    plan = _plan()
    lines = validate_plan(plan, approve_plan(plan, "pass", key=KEY), lim, approval_key=KEY)
    assert "verdict pass" in lines[0] and any("gripper commanded" in s for s in lines)
    bad = {**plan, "secondary": line_trajectory(Q_READY, Q_READY + np.array([0, 0, 0, 0, 1.5, 0]), 3.0)}
    with pytest.raises(LimitViolation, match="joint 5"):
        validate_plan(bad, approve_plan(bad, "pass", key=KEY), lim, approval_key=KEY)
    with pytest.raises(ApprovalError):
        validate_plan(plan, None, lim, approval_key=KEY)
