"""Planning: time parametrisation, dense validation, OMPL paths for one arm and both, reach queries."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _motion_fixtures import BOX_CENTER, BOX_HALF, T_B1_B2, down_pose, table_cloud, tabletop_configs

from bimanual_app.io_utils import write_json
from bimanual_app.planning import BimanualSetup, JointSpace, default_ready, parametrize, plan_path, validate_samples
from bimanual_app.robots import load_robot


@pytest.fixture(scope="module")
def piper():
    return load_robot("piper")


@pytest.fixture(scope="module")
def setup(piper):
    return BimanualSetup(piper, T_B1_B2, table_cloud()[0])


def _polyline_distance(W: np.ndarray, q: np.ndarray) -> float:
    best = np.inf
    for a, b in zip(W[:-1], W[1:]):
        t = np.clip(np.dot(q - a, b - a) / max(np.dot(b - a, b - a), 1e-18), 0, 1)
        best = min(best, float(np.linalg.norm(a + t * (b - a) - q)))
    return best


@pytest.mark.parametrize("stop", [False, True])
def test_parametrize_respects_limits(stop):
    rng = np.random.default_rng(0)
    W = np.cumsum(rng.normal(scale=0.5, size=(5, 6)), axis=0)
    vmax, amax = rng.uniform(1, 3, 6), rng.uniform(2, 5, 6)
    tr = parametrize(W, vmax, amax, stop_at_waypoints=stop)
    t = np.linspace(0, tr.duration, 4001)
    q, qd = tr.sample(t)
    np.testing.assert_allclose(q[0], W[0], atol=1e-12)
    np.testing.assert_allclose(q[-1], W[-1], atol=1e-12)
    np.testing.assert_allclose(qd[[0, -1]], 0, atol=1e-12)
    assert np.all(np.abs(qd) <= vmax * (1 + 1e-9))
    acc = np.diff(qd, axis=0) / np.diff(t)[:, None]
    assert np.all(np.abs(acc) <= amax * (1 + 1e-6))
    vel_fd = np.diff(q, axis=0) / np.diff(t)[:, None]  # positions integrate the velocities
    # (trapezoid rule: exact except across a blend boundary, where it errs by at most amax dt / 4)
    np.testing.assert_allclose(vel_fd, 0.5 * (qd[1:] + qd[:-1]), atol=amax.max() * (t[1] - t[0]) / 4 + 1e-9)
    # at least one joint runs at its velocity or acceleration limit somewhere (time-optimal per segment)
    assert np.max(np.abs(qd) / vmax) > 0.999 or np.max(np.abs(acc) / amax) > 0.999
    if stop:  # every waypoint is reached (at rest)
        for w in W:
            assert np.min(np.linalg.norm(q - w, axis=1)) < 1e-3
    else:  # outside the blends the trajectory lies on the validated polyline
        tb = tr.breakpoints()
        for m in range(len(tr.t0) - 1):
            mid = 0.5 * (tr.t0[m] + tr.blend[m] / 2 + tr.t0[m + 1] - tr.blend[m + 1] / 2)
            assert _polyline_distance(W, tr.sample([mid])[0][0]) < 1e-9
        assert len(tb) >= 2


def test_parametrize_short_move_is_triangular():
    tr = parametrize(np.array([[0.0, 0.0], [0.1, 0.0]]), np.array([3.0, 3.0]), np.array([5.0, 5.0]))
    assert tr.duration == pytest.approx(2 * np.sqrt(0.1 / 5.0), rel=1e-6)


def test_validate_samples_finds_problems(piper, setup):
    q0 = default_ready(piper)
    space = setup.space(["primary"], {"primary": q0, "secondary": q0})
    q_box = setup.ik("primary", down_pose(BOX_CENTER + np.array([0, 0, BOX_HALF[2] - 0.06]))).q
    times = np.linspace(0, 4.0, 41)
    Q = q0 + np.linspace(0, 1, 41)[:, None] * (q_box - q0)
    rep = validate_samples(space, times, Q)
    assert not rep.ok and any("not valid" in p for p in rep.problems)
    assert rep.max_step <= setup.world.margin + 1e-12
    fast = validate_samples(space, times * 0.01, Q)
    assert any("velocity" in p for p in fast.problems)
    Q2 = Q.copy()
    Q2[5, 5] = 3.0
    assert any("outside" in p for p in validate_samples(space, times, Q2).problems)


def test_plan_path_fails_fast_on_bad_start_and_goal(piper, setup):
    q0 = default_ready(piper)
    space = setup.space(["primary"], {"primary": q0, "secondary": q0})
    q_box = setup.ik("primary", down_pose(BOX_CENTER + np.array([0, 0, BOX_HALF[2] - 0.06]))).q
    res = plan_path(space, q_box, q0[None])
    assert not res.success and res.reason == "start" and "scene map" in res.message and res.plan_time < 0.1
    res = plan_path(space, q0, q_box[None])
    assert not res.success and res.reason == "goal"
    res = plan_path(space, q0, (q0 + 10.0)[None])
    assert not res.success and "outside" in res.message


def test_plan_around_the_box(piper, setup):
    """Start on one side of the box, goal on the other, low over the table: the straight move hits it."""
    q0 = default_ready(piper)
    q_now = {"primary": q0, "secondary": q0}
    a = setup.ik("primary", down_pose([0.32, -0.16, 0.05])).q
    b = setup.ik("primary", down_pose([0.32, 0.16, 0.05])).q
    space = setup.space(["primary"], q_now)
    assert not space.valid_batch(space.interpolate(a, b, 0.01)).all()
    plan = setup.plan_configurations(["primary"], {"primary": a}, [{"primary": b}], q_now, seed=3)
    assert plan.success, plan.message
    assert plan.method == "rrtconnect" and plan.validation.ok
    tr = plan.trajectories["primary"]
    np.testing.assert_allclose(tr.q[0], a, atol=1e-9)
    np.testing.assert_allclose(tr.q[-1], b, atol=1e-9)
    assert plan.validation.max_step <= setup.world.margin + 1e-12
    assert plan.validation.max_vel_ratio <= 1 + 1e-6 and plan.validation.max_acc_ratio <= 1 + 1e-3
    # the same samples pass an independent validation with a finer collision step
    from bimanual_app.planning._motion import _Scaled

    assert validate_samples(_Scaled(space, setup.speed), tr.times, tr.q, step=0.005).ok
    assert np.all(np.abs(np.diff(tr.q, axis=0) / np.diff(tr.times)[:, None]) <= piper.velocity_limits * setup.speed + 1e-9)


def test_plan_reach_and_json(piper, setup, tmp_path):
    q0 = default_ready(piper)
    rng = np.random.default_rng(4)
    goal = tabletop_configs(piper, setup.world, 1, rng, q_other=q0)[0]
    T = piper.fk_link(goal, "gripper_tcp")
    plan = setup.plan_reach("primary", T, {"primary": q0, "secondary": q0}, seed=1)
    assert plan.success, plan.message
    end = piper.fk_link(plan.trajectories["primary"].q[-1], "gripper_tcp")
    assert np.linalg.norm(end[:3, 3] - T[:3, 3]) < 2e-4
    write_json(tmp_path / "t.json", plan.to_json())
    data = json.loads((tmp_path / "t.json").read_text())
    assert data["success"] and data["validation"]["ok"]
    assert len(data["arms"]["primary"]["times"]) == len(data["arms"]["primary"]["q"])
    assert "secondary" in data["hold"]
    # the hardware layer's reader takes the planner's trajectory as is
    from bimanual_app.hardware import as_trajectory

    jt = as_trajectory(plan.trajectories["primary"])
    assert jt.q.shape[1] == 6
    # out of reach and a start in collision give reasons, no trajectory
    far = np.eye(4)
    far[:3, 3] = [2.0, 0, 0.1]
    bad = setup.plan_reach("primary", far, {"primary": q0, "secondary": q0}, position_only=True)
    assert not bad.success and bad.reason == "reach" and not bad.trajectories


def test_both_arms_twelve_dof(piper, setup):
    q0 = default_ready(piper)
    rng = np.random.default_rng(7)
    g1 = tabletop_configs(piper, setup.world, 1, rng, q_other=q0)[0]
    g2 = tabletop_configs(piper, setup.world, 1, rng, arm="secondary", q_other=g1, T_b1_b=T_B1_B2)[0]
    assert setup.world.valid(g1, g2)
    plan = setup.plan_configurations(["primary", "secondary"], {"primary": q0, "secondary": q0},
                                     [{"primary": g1, "secondary": g2}], seed=2)
    assert plan.success, plan.message
    assert plan.waypoints.shape[1] == 12 and not plan.hold
    t1, t2 = plan.trajectories["primary"], plan.trajectories["secondary"]
    np.testing.assert_array_equal(t1.times, t2.times)
    np.testing.assert_allclose(t2.q[-1], g2, atol=1e-9)
    assert setup.world.valid_batch(t1.q, t2.q).all()


def test_never_returns_an_unvalidated_trajectory(piper, setup, monkeypatch):
    import bimanual_app.planning._motion as motion
    from bimanual_app.planning import ValidationReport

    monkeypatch.setattr(motion, "validate_samples", lambda *a, **k: ValidationReport(False, ["forced failure"]))
    q0 = default_ready(piper)
    goal = tabletop_configs(piper, setup.world, 1, np.random.default_rng(5), q_other=q0)[0]
    plan = setup.plan_configurations(["primary"], {"primary": q0}, [{"primary": goal}], {"secondary": q0})
    assert not plan.success and plan.reason == "validation" and not plan.trajectories
    assert "forced failure" in plan.message


def test_a_path_refused_by_the_dense_validation_is_planned_again_with_denser_edge_checks(piper, setup, monkeypatch):
    """The validation checks the timed trajectory at other states than the planner checked its edges at; a path
    it refuses is planned once more with the edges checked a quarter margin apart, and that plan is kept."""
    import bimanual_app.planning._motion as motion
    from bimanual_app.planning import ValidationReport

    steps = []

    def recording(*a, **k):
        steps.append(k.get("step"))
        return plan_path(*a, **k)

    def strict(space, times, Q, **k):  # refuses whatever came from the coarse edge check
        return validate_samples(space, times, Q, **k) if steps[-1] is not None else ValidationReport(False, ["dip"])

    monkeypatch.setattr(motion, "plan_path", recording)
    monkeypatch.setattr(motion, "validate_samples", strict)
    q0 = default_ready(piper)
    goal = tabletop_configs(piper, setup.world, 1, np.random.default_rng(5), q_other=q0)[0]
    plan = setup.plan_configurations(["primary"], {"primary": q0}, [{"primary": goal}], {"secondary": q0}, seed=1)
    assert plan.success and plan.validation.ok, plan.message
    assert steps == [None, pytest.approx(setup.world.margin * motion.FINE_EDGE_STEP)]
    assert "plan_fine" in plan.timings
    steps.clear()
    monkeypatch.setattr(motion, "validate_samples", lambda *a, **k: ValidationReport(False, ["dip"]))
    plan = setup.plan_configurations(["primary"], {"primary": q0}, [{"primary": goal}], {"secondary": q0}, seed=1)
    assert not plan.success and plan.reason == "validation" and "dip" in plan.message and len(steps) == 2


def test_joint_space_requires_the_held_arm(setup):
    with pytest.raises(ValueError, match="secondary"):
        JointSpace(setup.world, ["primary"], {})


def test_setup_check_reports_limits_and_collisions(piper, setup):
    q0 = default_ready(piper)
    assert setup.check({"primary": q0, "secondary": q0}) == []
    bad = q0.copy()
    bad[0] = 3.0
    assert any("joint1" in p and "outside" in p for p in setup.check({"primary": q0, "secondary": bad}))
    q_box = setup.ik("primary", down_pose(BOX_CENTER + np.array([0, 0, BOX_HALF[2] - 0.06]))).q
    assert any("scene map" in p for p in setup.check({"primary": q_box, "secondary": q0}))


def test_ompl_plans_alike_whatever_ran_before(piper, setup):
    """OMPL is seeded per query from its inputs: the same query gives the same path after other queries
    (one process running every stage plans as a fresh one does)."""
    q0 = default_ready(piper)
    q_now = {"primary": q0, "secondary": q0}
    a = setup.ik("primary", down_pose([0.32, -0.16, 0.05])).q
    b = setup.ik("primary", down_pose([0.32, 0.16, 0.05])).q
    space = setup.space(["primary"], q_now)
    first = plan_path(space, a, b[None], timeout=2.0, seed=3)
    other = plan_path(space, b, a[None], timeout=2.0, seed=5)  # OMPL draws random numbers in between
    again = plan_path(space, a, b[None], timeout=2.0, seed=3)
    assert first.method == other.method == again.method == "rrtconnect"
    np.testing.assert_array_equal(first.path, again.path)
