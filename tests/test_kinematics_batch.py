"""Batched IK (``bimanual_app.kinematics._dls``): its pieces against Pinocchio, and many targets at once
against one at a time (the one-lane path runs on Pinocchio's own kinematics)."""

from __future__ import annotations

import numpy as np
import pytest
from _motion_fixtures import piper, solver  # noqa: F401  (fixtures)

from bimanual_app.kinematics._dls import descend, log6


def _targets(piper, n: int, seed: int) -> np.ndarray:
    """FK targets of random configurations, half of them moved up to ~20 cm (some out of reach)."""
    rng = np.random.default_rng(seed)
    T = piper.fk_link(piper.random_q(n, rng=rng), piper.tcp_link)
    T[n // 2:, :3, 3] += rng.normal(0.0, 0.1, (n - n // 2, 3))
    return T


def test_pose_and_local_jacobian_match_pinocchio(solver):
    import pinocchio as pin

    Q = solver.robot.random_q(50, rng=3)
    Tf, J = solver._kin(Q)
    data = solver.model.createData()
    for q, T, Jk in zip(Q, Tf, J):
        pin.computeJointJacobians(solver.model, data, q)
        M = pin.updateFramePlacement(solver.model, data, solver.fid)
        assert np.allclose(T, M.homogeneous, atol=1e-12)
        assert np.allclose(Jk, pin.getFrameJacobian(solver.model, data, solver.fid, pin.LOCAL), atol=1e-12)


def test_log6_matches_pinocchio_including_half_turns():
    import pinocchio as pin

    rng = np.random.default_rng(5)
    Ts = [pin.SE3.Random().homogeneous for _ in range(200)]
    for angle in (0.0, 1e-7, 1e-3, np.pi - 1e-2, np.pi - 1e-4, np.pi):  # small and near-half-turn rotations
        for _ in range(10):
            a = rng.normal(size=3)
            a /= np.linalg.norm(a)
            T = np.eye(4)
            T[:3, :3] = pin.exp3(angle * a)
            T[:3, 3] = rng.normal(0, 0.3, 3)
            Ts.append(T)
    Ts = np.stack(Ts)
    got = log6(Ts)
    want = np.stack([pin.log6(pin.SE3(T[:3, :3].copy(), T[:3, 3].copy())).vector for T in Ts])
    assert np.allclose(got, want, atol=1e-6)  # near pi both recover the axis from the symmetric part
    assert np.allclose(got[:200], want[:200], atol=1e-10)


@pytest.mark.parametrize("position_only", [False, True])
def test_batched_descent_matches_one_lane_descent(piper, solver, position_only):
    """Every lane of the numpy iteration follows the one-lane Pinocchio iteration: same end, errors, steps."""
    import pinocchio as pin

    T = _targets(piper, 40, seed=7)
    Q0 = piper.random_q(40, rng=8)
    Q, ep, er, it = descend(solver._kin, Q0, T, solver.lower, solver.upper, position_only, solver.tol_pos,
                            solver.tol_rot, solver.max_iter, solver.damping, solver.far_damping, solver.max_step)
    agree = 0
    for k in range(len(T)):
        goal = T[k, :3, 3].copy() if position_only else pin.SE3(T[k, :3, :3].copy(), T[k, :3, 3].copy())
        q1, ep1, er1, it1 = solver._descend_one(Q0[k].copy(), goal, position_only)
        agree += it1 == it[k] and np.abs(q1 - Q[k]).max() < 1e-8 and abs(ep1 - ep[k]) < 1e-9
    # rounding differs in the last bits; a lane on the edge of the stagnation test may stop one step apart
    assert agree >= 38


def test_solve_many_equals_solving_one_by_one(piper, solver):
    T = _targets(piper, 80, seed=11)
    many = solver.solve_many(T, max_seeds=6)  # 80 targets x 5 seeds: the numpy lanes
    one = [solver.solve(t, max_seeds=6) for t in T]  # a few lanes each: the Pinocchio path
    assert sum(r.success for r in one) >= 40
    for a, b in zip(many, one):
        assert a.success == b.success
        if a.success:
            assert np.abs(a.q - b.q).max() < 1e-6
            assert a.seeds == b.seeds
            assert piper.within_limits(a.q)


def test_solve_many_with_several_solutions_and_own_seeds(piper, solver):
    T = _targets(piper, 40, seed=13)[:20]
    q_cur = piper.random_q(20, rng=14)
    many = solver.solve_many(T, q_cur, max_seeds=6, n_solutions=3)
    for t, q, a in zip(T, q_cur, many):
        b = solver.solve(t, q_current=q, max_seeds=6, n_solutions=3)
        assert a.success == b.success and a.solutions.shape == b.solutions.shape
        assert np.allclose(a.solutions, b.solutions, atol=1e-6)


def test_screen_rules_out_only_targets_no_solve_reaches(piper, solver):
    """``screen`` rules a target out only where no solve (from the current configuration, its closed-form
    branches or the descent from the target's own configuration) finds a solution, and with the message
    the failed solve gives; it rules out most of the unreachable ones."""
    T = _targets(piper, 120, seed=21)
    q_cur = piper.random_q(120, rng=22)
    why = solver.screen(T, q_cur)
    solved = [solver.solve(t, q_current=q, max_seeds=8) for t, q in zip(T, q_cur)]
    assert all(r.success for r in solved[:60]) and not any(why[:60])  # FK targets: nothing ruled out
    for w, r in zip(why, solved):
        if w:
            assert not r.success and r.message == w
    failed = sum(not r.success for r in solved)
    assert failed >= 20 and sum(bool(w) for w in why) >= 0.8 * failed


def test_solve_many_rejects_bad_shapes(solver):
    with pytest.raises(ValueError):
        solver.solve_many(np.tile(np.eye(4), (3, 1, 1)), q_current=np.zeros((2, 6)))
    bad = np.tile(np.eye(4), (2, 1, 1))
    bad[1, 0, 3] = np.nan
    with pytest.raises(ValueError):
        solver.solve_many(bad)


def test_descent_finished_lane_by_lane_equals_the_batch(piper, solver):
    """The slow lanes handed to the one-lane iteration part-way end where the batch would have taken them."""
    import pinocchio as pin

    T = _targets(piper, 30, seed=17)
    Q0 = piper.random_q(30, rng=18)
    args = (solver.lower, solver.upper, False, solver.tol_pos, solver.tol_rot, solver.max_iter, solver.damping,
            solver.far_damping, solver.max_step)
    Qa, epa, _, ita = descend(solver._kin, Q0, T, *args)
    handed = []

    def tail(lane, q, first, history):
        handed.append(lane)
        goal = pin.SE3(T[lane, :3, :3].copy(), T[lane, :3, 3].copy())
        return solver._descend_one(q.copy(), goal, False, first, history.tolist())

    Qb, epb, _, itb = descend(solver._kin, Q0, T, *args, tail=tail, tail_lanes=10)
    assert len(handed) > 0
    assert np.allclose(Qa, Qb, atol=1e-8) and np.array_equal(ita, itb) and np.allclose(epa, epb, atol=1e-10)
