"""IK: damped least squares with several seeds, joint limits, closest solution first."""

from __future__ import annotations

import os

import numpy as np
import pytest
from _motion_fixtures import piper, solver  # noqa: F401  (fixtures)

from bimanual_app.kinematics import IKSolver, solve_ik
from bimanual_app.robots import load_robot
from bimanual_app.transforms import rotation_angle_between


def test_ik_reaches_fk_targets(piper, solver):
    """Targets from FK of random configurations: >= 99% solved (the bench measures 1,000), accurate, in limits."""
    Q = piper.random_q(200, rng=11)
    T = piper.fk_link(Q, "gripper_tcp")
    ok = 0
    for i in range(len(Q)):
        res = solver.solve(T[i])
        if not res.success:
            continue
        ok += 1
        assert piper.within_limits(res.q)
        T_got = piper.fk_link(res.q, "gripper_tcp")
        assert np.linalg.norm(T_got[:3, 3] - T[i, :3, 3]) < 1.1e-4
        assert rotation_angle_between(T_got[:3, :3], T[i, :3, :3]) < 1.1e-3
        assert res.pos_error < 1e-4 and res.rot_error < 1e-3
    assert ok >= 198


def test_ik_solutions_closest_first(piper, solver):
    q_true = np.array([0.4, 1.2, -1.0, 0.5, 0.6, -0.3])
    T = piper.fk_link(q_true, "gripper_tcp")
    near = q_true + 0.05
    res = solver.solve(T, q_current=near, n_solutions=4, max_seeds=16)
    assert res.success
    d = np.linalg.norm(res.solutions - near, axis=1)
    assert np.all(np.diff(d) >= 0)
    np.testing.assert_allclose(res.q, q_true, atol=2e-3)  # the nearby branch, not another one
    assert res.solutions.shape[1] == 6 and np.all(piper.within_limits(res.solutions))


def test_ik_respects_joint_limits_when_the_unconstrained_solution_does_not(piper, solver):
    """Targets whose solutions sit on a joint limit are still found, never outside the limits."""
    q = piper.random_q(30, rng=5)
    q[:, 2] = piper.upper[2]  # elbow at its limit
    q[:, 1] = piper.lower[1] + 0.3
    T = piper.fk_link(q, "gripper_tcp")
    for i in range(len(q)):
        res = solver.solve(T[i], q_current=piper.neutral())
        if res.success:
            assert np.all(res.q <= piper.upper + 1e-12) and np.all(res.q >= piper.lower - 1e-12)
    assert sum(solver.solve(T[i]).success for i in range(len(q))) >= 28


def test_position_only_and_ee_link(piper):
    q = np.array([0.3, 1.0, -0.8, 0.2, 0.5, 0.1])
    p = piper.fk_link(q, "gripper_tcp")[:3, 3]
    T = np.eye(4)
    T[:3, 3] = p
    res = solve_ik(piper, T, position_only=True)
    assert res.success
    assert np.linalg.norm(piper.fk_link(res.q, "gripper_tcp")[:3, 3] - p) < 1e-4
    flange = IKSolver(piper, link="link6")
    res = flange.solve(piper.fk(q))
    assert res.success and np.allclose(piper.fk(res.q), piper.fk(q), atol=2e-4)


def test_given_seeds_replace_the_table_and_are_tried_in_order(piper, solver):
    """A caller's own starts: the first that converges gives the answer (its branch), the table is not used."""
    q_a = np.array([0.4, 1.2, -1.0, 0.5, 0.6, -0.3])
    T = piper.fk_link(q_a, "gripper_tcp")
    far = piper.lower + 0.05  # a start far from every branch of this pose
    res = solver.solve(T, q_current=far, seeds=np.stack([far, q_a + 0.02]), max_seeds=3)
    assert res.success and res.seeds <= 3
    np.testing.assert_allclose(res.q, q_a, atol=2e-3)
    # only the given seeds: one that cannot converge and nothing else fails rather than falling back on the table
    res = solver.solve(T, q_current=far, seeds=far[None], max_seeds=16)
    assert res.seeds == 2
    assert not res.success or np.linalg.norm(res.q - far) < np.linalg.norm(q_a - far)
    with pytest.raises(ValueError, match="seeds"):
        solver.solve(T, seeds=np.zeros((2, 5)))


def test_capture_planner_uses_the_one_ik_and_accepts_only_near_misses(piper):
    """The synthetic capture's flange IK: the project's IKSolver from the planner's starts; a start that
    stops short of the IK tolerance still counts within 5 mm / 2 degrees, and nothing beyond."""
    from bimanual_app.synth._viewpoints import IK_ACCEPT, _flange_ik

    flange = IKSolver(piper, link=piper.ee_link, max_iter=80)
    q = np.array([0.3, 1.0, -0.8, 0.2, 0.5, 0.1])
    T = piper.fk(q)
    starts = np.stack([piper.neutral(), q + 0.1])
    q_got, pe, re = _flange_ik(flange, T, starts)
    assert q_got is not None and pe < 1e-4 and re < 1e-3
    np.testing.assert_allclose(piper.fk(q_got), T, atol=2e-4)
    T_far = T.copy()
    T_far[:3, 3] *= 3.0  # out of reach
    q_got, pe, re = _flange_ik(flange, T_far, starts)
    assert q_got is None and (pe > IK_ACCEPT[0] or re > IK_ACCEPT[1])


def test_unreachable_fails_fast_with_a_reason(solver):
    T = np.eye(4)
    T[:3, 3] = [1.5, 0.0, 0.2]
    res = solver.solve(T)
    assert not res.success and res.q is None and res.iterations == 0
    assert "reaches about" in res.message
    T[:3, 3] = [0.0, 0.0, 0.0]  # inside the base column: in range but no solution
    res = solver.solve(T, max_seeds=4)
    assert not res.success and "no IK solution" in res.message


def test_bad_input(solver):
    with pytest.raises(ValueError):
        solver.solve(np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="q_current"):
        solver.solve(np.eye(4), q_current=np.zeros(5))


def test_ik_other_robot_panda():
    import pybullet_data

    panda = load_robot(os.path.join(pybullet_data.getDataPath(), "franka_panda/panda.urdf"), ee_link="panda_hand")
    s = IKSolver(panda, table_size=2000)
    Q = panda.random_q(20, rng=2)
    T = panda.fk(Q)
    ok = [s.solve(T[i]).success for i in range(20)]
    assert sum(ok) >= 19
