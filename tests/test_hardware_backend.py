"""Piper backend against a simulated arm on python-can's virtual bus: motion, refusals, stops."""

import _thread
import signal
import threading
import time

import numpy as np
import pytest

from bimanual_app.hardware import (
    ApprovalError,
    ArmFault,
    BimanualHardware,
    ExecuteNotRequested,
    FeedbackTimeout,
    LimitViolation,
    PiperArm,
    SafetyLimits,
    TrackingError,
    WorkspaceBox,
    approve_plan,
)
from bimanual_app.hardware._piper import rad_to_sdk, sdk_to_rad
from tests._hw_fixtures import Q_READY, SimPiper, fast_config, line_trajectory, make_arm, new_channel

KEY = b"test-approval-key"
DQ = np.array([0.3, 0.2, -0.2, 0.3, 0.2, 0.5])


@pytest.fixture(scope="module")
def limits():
    return SafetyLimits.from_robot("piper", name="primary")


@pytest.fixture()
def sim_arm(limits):
    ch = new_channel()
    sim = SimPiper(ch, q0=Q_READY).start()
    arm = make_arm(ch, limits=limits)
    arm.connect()
    yield sim, arm
    arm.close()
    sim.close()


def test_units_round_trip():
    q = np.array([0.1, -2.5, 1e-4, 3.0, -0.7, 2.0])
    v = rad_to_sdk(q)
    assert all(isinstance(x, int) for x in v)
    assert v[0] == round(np.degrees(0.1) * 1000)
    np.testing.assert_allclose(sdk_to_rad(v), q, atol=np.radians(0.0005))


def test_approved_plan_runs_and_reaches_the_goal(sim_arm, tmp_path):
    sim, arm = sim_arm
    traj = line_trajectory(Q_READY, Q_READY + DQ, 0.8, gripper=(0.0, 0.04))
    appr = approve_plan({"primary": traj}, "pass", {"task": "test"}, key=KEY)
    rep = arm.execute(traj, appr, fast_config(), approval_key=KEY)
    np.testing.assert_allclose(sim.q, Q_READY + DQ, atol=0.01)
    np.testing.assert_allclose(rep.final_q["primary"], Q_READY + DQ, atol=0.01)
    assert rep.final_error_rad["primary"] <= 0.01
    ids = sim.ids_received()
    assert 0x471 in ids and 0x151 in ids and 0x155 in ids and 0x159 in ids
    assert ids.index(0x471) < ids.index(0x155), "motors enabled before the first joint command"
    # every joint command decoded by the simulated arm is inside the limits and the workspace
    cmds = np.array([q for _, q in sim.joint_cmds])
    assert not arm.limits.config_problems(cmds, "sent")
    assert sim.gripper_target == pytest.approx(0.04, abs=1e-5)
    assert not sim.estopped
    assert len(rep.trace["primary"]) == rep.cycles
    rep.plot(tmp_path / "execution.png")
    assert (tmp_path / "execution.png").stat().st_size > 1000


def test_plan_starting_slightly_off_the_measured_joints_runs(sim_arm):
    sim, arm = sim_arm
    start = Q_READY + np.array([0.03, -0.02, 0.0, 0.03, 0.0, -0.03])  # within start_tol_rad (0.05)
    traj = line_trajectory(start, start + DQ, 0.6)
    arm.execute(traj, approve_plan({"primary": traj}, "pass", key=KEY), fast_config(), approval_key=KEY)
    np.testing.assert_allclose(sim.q, start + DQ, atol=0.01)


def test_speed_ramps_up_from_slow(sim_arm):
    sim, arm = sim_arm
    traj = line_trajectory(Q_READY, Q_READY + np.array([0.6, 0, 0, 0, 0, 0]), 1.0)
    appr = approve_plan({"primary": traj}, "pass", key=KEY)
    cfg = fast_config(ramp_s=0.5, start_rate=0.2, speed_pct_start=10, speed_pct_max=80)
    seen = []
    from bimanual_app.hardware import execute_plan

    execute_plan({"primary": arm}, {"primary": traj}, appr, cfg, progress=seen.append, approval_key=KEY)
    pct = [c.speed_pct for c in seen]
    assert pct[0] <= 12 and max(pct) == 80
    assert all(b >= a for a, b in zip(pct, pct[1:])), "speed percentage never decreases during the ramp"
    # SDK frames carry the same ramp: 0x151 byte 2 is the speed percentage
    sent_pct = [f.data[2] for f in sim.frames if f.arbitration_id == 0x151]
    assert sent_pct[0] <= 12 and max(sent_pct) == 80
    # playback starts slow: plan time advances at the start rate, then at full rate
    rates = [c.rate for c in seen]
    assert rates[0] == pytest.approx(0.2, abs=0.05) and rates[-1] == pytest.approx(1.0)
    early = [c for c in seen if c.wall_s < 0.1]
    assert early[-1].plan_s < 0.05, "after 0.1 s of a 20 %-rate start, less than 0.05 s of plan has played"


def _assert_nothing_sent(sim):
    time.sleep(0.05)  # let the virtual bus deliver anything in flight
    assert sim.ids_received() == [], f"frames were sent: {[hex(i) for i in sim.ids_received()]}"
    np.testing.assert_allclose(sim.q, Q_READY, atol=1e-9)


def test_refuses_without_a_passing_approval(sim_arm, tmp_path):
    sim, arm = sim_arm
    from bimanual_app.hardware import execute_plan, load_approval, write_approval

    traj = line_trajectory(Q_READY, Q_READY + DQ)
    plan = {"primary": traj}
    with pytest.raises(ApprovalError, match="no preview approval"):
        execute_plan({"primary": arm}, plan, None, fast_config(), approval_key=KEY)
    with pytest.raises(ApprovalError, match="verdict is 'fail'"):
        execute_plan({"primary": arm}, plan, approve_plan(plan, "fail", key=KEY), fast_config(), approval_key=KEY)
    other = {"primary": line_trajectory(Q_READY, Q_READY - DQ)}
    with pytest.raises(ApprovalError, match="another plan"):
        execute_plan({"primary": arm}, plan, approve_plan(other, "pass", key=KEY), fast_config(), approval_key=KEY)
    # a failed verdict edited by hand to "pass": the signature no longer matches
    path = tmp_path / "approval.json"
    write_approval(path, approve_plan(plan, "fail", key=KEY))
    path.write_text(path.read_text().replace('"fail"', '"pass"'))
    assert load_approval(path).verdict == "pass"
    with pytest.raises(ApprovalError, match="signature"):
        execute_plan({"primary": arm}, plan, path, fast_config(), approval_key=KEY)
    # signed with another key (another machine)
    with pytest.raises(ApprovalError, match="signature"):
        execute_plan({"primary": arm}, plan, approve_plan(plan, "pass", key=b"other"), fast_config(), approval_key=KEY)
    _assert_nothing_sent(sim)


@pytest.mark.parametrize("case", ["joint", "velocity", "workspace", "start"])
def test_refuses_limit_violations_before_sending_anything(sim_arm, case):
    sim, arm = sim_arm
    from bimanual_app.hardware import execute_plan

    if case == "joint":  # joint 5 beyond +70 deg on the way
        traj = line_trajectory(Q_READY, Q_READY + np.array([0, 0, 0, 0, 1.0, 0]), 2.0)
        match = "joint 5"
    elif case == "velocity":  # 1 rad in 0.2 s: above the allowed 1.5 rad/s
        traj = line_trajectory(Q_READY, Q_READY + np.array([1.0, 0, 0, 0, 0, 0]), 0.2)
        match = "speed"
    elif case == "workspace":  # reach down through the table
        traj = line_trajectory(Q_READY, np.array([0.0, 1.9, -0.9, 0.0, 0.9, 0.0]), 3.0)
        match = "workspace box"
    else:  # plan starts elsewhere than the arm
        traj = line_trajectory(Q_READY + 0.2, Q_READY + DQ, 1.0)
        match = "starts"
    plan = {"primary": traj}
    with pytest.raises(LimitViolation, match=match):
        execute_plan({"primary": arm}, plan, approve_plan(plan, "pass", key=KEY), fast_config(), approval_key=KEY)
    _assert_nothing_sent(sim)


def test_workspace_box_is_configurable(limits):
    q_low = np.array([0.0, 1.9, -0.9, 0.0, 0.9, 0.0])
    assert limits.config_problems(q_low[None])
    wide = SafetyLimits.from_robot(limits.robot, workspace=WorkspaceBox((-1, -1, -0.5), (1, 1, 1)))
    assert not wide.config_problems(q_low[None])
    assert not SafetyLimits.from_robot(limits.robot, workspace=None).config_problems(q_low[None])


def test_refuses_without_the_execute_flag():
    ch = new_channel()
    with SimPiper(ch, q0=Q_READY) as sim:
        arm = PiperArm(ch, "primary", bustype="virtual", check_port=False)  # no execute="hardware"
        with pytest.raises(ExecuteNotRequested, match="execute"):
            arm.connect()
        assert not arm.connected
        _assert_nothing_sent(sim)


def test_feedback_timeout_mid_motion_stops_the_arm():
    ch = new_channel()
    # the arm answers for the first 30 joint commands (0.3 s at 100 Hz), then goes silent
    with SimPiper(ch, q0=Q_READY, silent_after_joint_cmds=30) as sim:
        arm = make_arm(ch)
        arm.connect()
        try:
            traj = line_trajectory(Q_READY, Q_READY + DQ, 1.5)
            plan = {"primary": traj}
            from bimanual_app.hardware import execute_plan

            t0 = time.monotonic()
            with pytest.raises(FeedbackTimeout) as ei:
                execute_plan({"primary": arm}, plan, approve_plan(plan, "pass", key=KEY),
                             fast_config(feedback_timeout_s=0.15), approval_key=KEY)
            elapsed = time.monotonic() - t0
        finally:
            arm.close()
        msg = str(ei.value)
        assert "[primary]" in msg and "feedback stopped" in msg and "stop sent to: primary" in msg
        assert ei.value.stopped == ("primary",)
        assert len(ei.value.report.trace["primary"]) >= 30, "the trace up to the failure is kept"
        assert elapsed < 1.5, "detected well before the plan would have ended"
        # the arm was left safe: quick stop received, no motion command after it, and it stopped moving
        t_stop = sim.estop_time()
        assert t_stop is not None and sim.estopped
        t_silent = sim.joint_cmds[29][0]
        assert 0.1 <= t_stop - t_silent < 0.5, "stop sent within the feedback timeout (+ scheduling slack)"
        time.sleep(0.05)
        assert sim.motion_frames_after(t_stop) == []
        q_stop = sim.q.copy()
        time.sleep(0.1)
        np.testing.assert_array_equal(sim.q, q_stop)


def test_tracking_error_stops_the_arm():
    ch = new_channel()
    with SimPiper(ch, q0=Q_READY, max_speed=0.2) as sim:  # a sluggish (blocked) arm
        arm = make_arm(ch)
        arm.connect()
        try:
            traj = line_trajectory(Q_READY, Q_READY + np.array([1.0, 0, 0, 0, 0, 0]), 1.5)
            plan = {"primary": traj}
            from bimanual_app.hardware import execute_plan

            with pytest.raises(TrackingError, match="from its recent setpoints"):
                execute_plan({"primary": arm}, plan, approve_plan(plan, "pass", key=KEY),
                             fast_config(tracking_tol_rad=0.1), approval_key=KEY)
        finally:
            arm.close()
        t_stop = sim.estop_time()
        assert t_stop is not None and sim.estopped and sim.motion_frames_after(t_stop) == []


def test_refuses_to_start_when_the_arm_reports_a_fault():
    ch = new_channel()
    with SimPiper(ch, q0=Q_READY) as sim:
        sim.estopped = True  # the arm's e-stop is active (status 0x01)
        arm = make_arm(ch)
        arm.connect()
        try:
            traj = line_trajectory(Q_READY, Q_READY + DQ)
            plan = {"primary": traj}
            from bimanual_app.hardware import execute_plan

            with pytest.raises(ArmFault, match="emergency stop"):
                execute_plan({"primary": arm}, plan, approve_plan(plan, "pass", key=KEY), fast_config(), approval_key=KEY)
        finally:
            arm.close()
        assert sim.ids_received() == []


@pytest.fixture()
def two_sims():
    chans = [new_channel("vprim"), new_channel("vsec")]
    sims = [SimPiper(c, q0=Q_READY).start() for c in chans]
    hw = BimanualHardware(make_arm(chans[0], "primary"), make_arm(chans[1], "secondary"))
    hw.connect()
    yield sims, hw
    hw.close()
    for s in sims:
        s.close()


def test_bimanual_plan_moves_both_arms(two_sims):
    (s1, s2), hw = two_sims
    plan = {"primary": line_trajectory(Q_READY, Q_READY + DQ, 0.6),
            "secondary": line_trajectory(Q_READY, Q_READY - 0.5 * DQ, 0.4)}
    rep = hw.execute(plan, approve_plan(plan, "pass", key=KEY), fast_config(), approval_key=KEY)
    np.testing.assert_allclose(s1.q, Q_READY + DQ, atol=0.01)
    np.testing.assert_allclose(s2.q, Q_READY - 0.5 * DQ, atol=0.01)
    assert set(rep.final_q) == {"primary", "secondary"}
    # an approval for the primary arm's part alone is not an approval of the bimanual plan
    with pytest.raises(ApprovalError):
        hw.execute(plan, approve_plan({"primary": plan["primary"]}, "pass", key=KEY), fast_config(), approval_key=KEY)


def test_ctrl_c_stops_both_arms(two_sims):
    (s1, s2), hw = two_sims
    plan = {"primary": line_trajectory(Q_READY, Q_READY + DQ, 1.5),
            "secondary": line_trajectory(Q_READY, Q_READY - DQ, 1.5)}

    def interrupt_at_cycle_20(info):
        if info.cycle == 20:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        hw.execute(plan, approve_plan(plan, "pass", key=KEY), fast_config(), progress=interrupt_at_cycle_20,
                   approval_key=KEY)
    for s in (s1, s2):
        t = s.estop_time()
        assert t is not None and s.estopped
        time.sleep(0.03)
        assert s.motion_frames_after(t) == []
        assert np.max(np.abs(s.q - Q_READY)) < 0.5, "stopped early in the motion"


def test_real_sigint_stops_the_arm(sim_arm):
    """A real SIGINT (KeyboardInterrupt raised in the main thread by the interpreter)."""
    sim, arm = sim_arm
    # Python's own Ctrl-C handler, also when the test runner was started with SIGINT ignored (a background
    # job of a non-interactive shell): then interrupt_main() would do nothing
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    traj = line_trajectory(Q_READY, Q_READY + DQ, 3.0)
    plan = {"primary": traj}
    from bimanual_app.hardware import execute_plan

    timer = threading.Timer(0.4, _thread.interrupt_main)
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            execute_plan({"primary": arm}, plan, approve_plan(plan, "pass", key=KEY), fast_config(), approval_key=KEY)
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, old)
    t_stop = sim.estop_time()
    assert t_stop is not None and sim.estopped and sim.motion_frames_after(t_stop) == []


def test_one_silent_arm_stops_both():
    chans = [new_channel("vprim"), new_channel("vsec")]
    s1 = SimPiper(chans[0], q0=Q_READY).start()
    s2 = SimPiper(chans[1], q0=Q_READY, silent_after_joint_cmds=20).start()
    hw = BimanualHardware(make_arm(chans[0], "primary"), make_arm(chans[1], "secondary"))
    try:
        hw.connect()
        plan = {"primary": line_trajectory(Q_READY, Q_READY + DQ, 1.0),
                "secondary": line_trajectory(Q_READY, Q_READY - DQ, 1.0)}
        with pytest.raises(FeedbackTimeout) as ei:
            hw.execute(plan, approve_plan(plan, "pass", key=KEY), fast_config(feedback_timeout_s=0.15), approval_key=KEY)
        assert ei.value.arm == "secondary" and set(ei.value.stopped) == {"primary", "secondary"}
        assert s1.estop_time() is not None and s2.estop_time() is not None
        assert s1.estopped and s2.estopped
    finally:
        hw.close()
        s1.close()
        s2.close()


def test_move_to_is_guarded(sim_arm):
    sim, arm = sim_arm
    goal = Q_READY + np.array([-0.2, 0.1, 0.1, 0.2, -0.1, 0.3])
    rep = arm.move_to(goal, speed=1.0, config=fast_config())
    np.testing.assert_allclose(sim.q, goal, atol=0.01)
    assert rep.final_error_rad["primary"] <= 0.01
    time.sleep(0.05)  # frames still in flight
    n = len(sim.frames)
    with pytest.raises(LimitViolation, match="joint 2"):
        arm.move_to(np.array([0.0, 3.5, -0.8, 0.0, 0.4, 0.0]), config=fast_config())
    time.sleep(0.03)
    assert len(sim.frames) == n, "nothing sent for a goal outside the limits"
