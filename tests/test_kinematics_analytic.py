"""Closed-form IK branches (``bimanual_app.kinematics._analytic``): the Paden-Kahan subproblems on known
answers, the Piper's branches against forward kinematics, and IKSolver on them against the DLS seeds."""

from __future__ import annotations

import numpy as np
import pytest
from _motion_fixtures import piper, solver  # noqa: F401  (fixtures)
from scipy.spatial.transform import Rotation

from bimanual_app.kinematics._analytic import _rotate, ik_branches, sp1, sp2, sp3, wrist_chain


def _unit(rng, n=None):
    v = rng.normal(size=(3,) if n is None else (n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_subproblem_1_recovers_the_angle_and_falls_back_on_the_axis():
    rng = np.random.default_rng(0)
    w, r = _unit(rng), rng.normal(size=3)
    p = rng.normal(size=(50, 3))
    theta = rng.uniform(-np.pi, np.pi, 50)
    q = _rotate(w, r, theta, p)
    assert np.allclose(sp1(w, r, p, q, np.zeros(50)), theta, atol=1e-9)
    on_axis = np.tile(r + 0.3 * w, (2, 1))
    assert np.allclose(sp1(w, r, on_axis, q[:2], np.array([0.7, -0.2])), [0.7, -0.2])


def test_subproblem_2_finds_both_pairs_and_says_when_none_exists():
    rng = np.random.default_rng(1)
    w1, w2, r = _unit(rng), _unit(rng), rng.normal(size=3)
    p = r + rng.normal(size=(40, 3))
    t1, t2 = rng.uniform(-np.pi, np.pi, 40), rng.uniform(-np.pi, np.pi, 40)
    q = _rotate(w1, r, t1, _rotate(w2, r, t2, p))
    a1, a2, ok = sp2(w1, w2, r, p, q, np.zeros(40), np.zeros(40))
    assert ok.all()
    for k in range(2):  # each returned pair maps p onto q
        assert np.allclose(_rotate(w1, r, a1[:, k], _rotate(w2, r, a2[:, k], p)), q, atol=1e-9)
    err = np.minimum(np.abs(np.angle(np.exp(1j * (a1 - t1[:, None])))).min(axis=1), 1.0)
    assert err.max() < 1e-7  # the true pair is one of the two
    # q at another distance from r than p: no rotation about r takes p there
    _, _, ok = sp2(w1, w2, r, p[:1], r + 2.0 * (q[:1] - r), np.zeros(1), np.zeros(1))
    assert not ok.any()


def test_subproblem_3_puts_the_point_at_the_distance():
    rng = np.random.default_rng(2)
    w, r = _unit(rng), rng.normal(size=3)
    p, q = rng.normal(size=(30, 3)), rng.normal(size=(30, 3))
    theta = rng.uniform(-np.pi, np.pi, 30)
    delta = np.linalg.norm(_rotate(w, r, theta, p) - q, axis=1)
    t, ok = sp3(w, r, p, q, delta)
    assert ok.all()
    for k in range(2):
        assert np.allclose(np.linalg.norm(_rotate(w, r, t[:, k], p) - q, axis=1), delta, atol=1e-9)
    _, ok = sp3(w, r, p[:1], q[:1], np.array([100.0]))
    assert not ok.any()


def test_piper_chain_has_a_wrist_centre_and_a_seven_joint_arm_has_none(piper, solver):
    import os

    import pybullet_data

    from bimanual_app.kinematics import IKSolver
    from bimanual_app.robots import load_robot

    chain = solver.chain
    assert chain is not None and chain.wrist_gap < 2e-4  # the Piper's axes 4-6 meet to 0.09 mm
    assert np.allclose(chain.shoulder, [0.0, 0.0, 0.123], atol=1e-6)
    panda = load_robot(os.path.join(pybullet_data.getDataPath(), "franka_panda/panda.urdf"), ee_link="panda_hand")
    assert IKSolver(panda, table_size=500).chain is None
    # the flange (link6) has the same wrist centre: a chain for any frame fixed to the last link
    assert wrist_chain(IKSolver(piper, link="link6")._kin, piper.lower, piper.upper) is not None


def test_branches_reproduce_random_configurations(piper, solver):
    """For random configurations within the limits, some branch lies within the limits and within a few
    hundredths of a millimetre of the pose (the wrist's approximation), and on all but the poses near a
    singularity within 0.01 rad of the configuration itself."""
    q = piper.random_q(3000, rng=3)
    T = piper.fk_link(q, piper.tcp_link)
    Q, excess = ik_branches(solver.chain, T, q)
    ok = excess == 0
    assert np.isfinite(excess).all() and ok.any(axis=1).all()
    Tb = piper.fk_link(Q.reshape(-1, 6), piper.tcp_link).reshape(len(T), 8, 4, 4)
    pos_err = np.where(ok, np.linalg.norm(Tb[..., :3, 3] - T[:, None, :3, 3], axis=-1), np.inf).min(axis=1)
    assert np.percentile(pos_err, 99) < 2e-4 and pos_err.max() < 2e-3
    d = np.where(ok, np.abs(Q - q[:, None]).max(axis=2), np.inf).min(axis=1)
    assert np.mean(d < 0.01) > 0.9


def test_solver_on_the_branches_solves_every_reachable_pose_and_misses_nothing_the_seeds_find(piper):
    from bimanual_app.kinematics import IKSolver

    closed = IKSolver(piper)
    seeds = IKSolver(piper)
    seeds.chain = None  # the DLS seeds: current configuration, nearest table poses, random ones
    q = piper.random_q(600, rng=4)
    T = piper.fk_link(q, piper.tcp_link)
    rs = closed.solve_many(T, max_seeds=4)
    assert all(r.success for r in rs)
    for r in rs:
        assert piper.within_limits(r.q) and r.pos_error < 1e-4 and r.rot_error < 1e-3
    rng = np.random.default_rng(5)
    T[:, :3, 3] += rng.normal(0.0, 0.1, (len(T), 3))  # about half of these are out of reach
    a = np.array([r.success for r in closed.solve_many(T, max_seeds=8)])
    b = np.array([r.success for r in seeds.solve_many(T, max_seeds=16)])
    assert 0.2 < a.mean() < 0.8 and not (b & ~a).any()


def test_solutions_come_nearest_the_current_configuration_first(piper, solver):
    q = piper.random_q(50, rng=6)
    T = piper.fk_link(q, piper.tcp_link)
    for t, qk in zip(T, q):
        r = solver.solve(t, q_current=qk, n_solutions=4, max_seeds=8)
        assert r.success
        assert np.abs(r.q - qk).max() < 0.05 or np.abs(qk[4]) < 0.1  # the same, but near the wrist singularity
        d = np.linalg.norm(r.solutions - qk, axis=1)
        assert np.all(np.diff(d) >= 0)


def test_a_pose_near_the_shoulder_singularity_whose_branches_leave_the_limits_by_their_error_is_solved(
        piper, solver):
    """The wrist centre about a millimetre from axis 1: the closed form's joint 1 is 0.07 rad off, and the
    wrist's joints follow it beyond their limits, by less than the error the slack allows for there; one of
    these branches, clipped, polishes to a solution (joint 1 is nearly free there: not necessarily q's)."""
    q = np.array([-2.5407, 0.4346, -0.5693, -0.5858, 0.1443, -1.8619])
    T = piper.fk_link(q, piper.tcp_link)
    Q, excess = ik_branches(solver.chain, T[None], piper.neutral()[None])
    inside = excess[0] == 0
    assert inside.any() and (np.abs(Q[0, inside] - q).max(axis=1) > 0.05).all()  # not the solution itself
    r = solver.solve(T, q_current=piper.neutral(), max_seeds=8)
    assert r.success and piper.within_limits(r.q) and r.seeds >= 2  # the current configuration did not converge
    assert np.linalg.norm(piper.fk_link(r.q, piper.tcp_link)[:3, 3] - T[:3, 3]) < 1e-4
    assert r.rot_error < 1e-3


@pytest.mark.parametrize("where", ["wrist", "shoulder"])
def test_singular_poses_are_solved(piper, solver, where):
    """Joint 5 at zero (axes 4 and 6 aligned: only their sum sets the pose) and the wrist centre on axis 1
    (joint 1 free but for the orientation): the free angle starts at the current configuration's."""
    if where == "wrist":
        q = np.array([0.4, 1.2, -1.4, 0.6, 0.0, -0.3])
    else:  # the wrist centre straight above the shoulder, found by bisection on joint 2
        lo, hi = 0.2, 2.9
        chain = solver.chain

        def x_of(q2):
            T = piper.fk_link(np.array([0.0, q2, -1.6, 0.0, 0.5, 0.0]), piper.tcp_link)
            g = T @ chain.T_home_inv
            return (g[:3, :3] @ chain.wrist + g[:3, 3])[0]

        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.sign(x_of(mid)) == np.sign(x_of(lo)) else (lo, mid)
        q = np.array([0.3, 0.5 * (lo + hi), -1.6, 0.0, 0.5, 0.0])
    T = piper.fk_link(q, piper.tcp_link)
    r = solver.solve(T, q_current=q + 0.05, max_seeds=8)
    assert r.success and r.pos_error < 1e-4 and r.rot_error < 1e-3
    R = Rotation.from_matrix(piper.fk_link(r.q, piper.tcp_link)[:3, :3].T @ T[:3, :3])
    assert R.magnitude() < 1e-3


def test_a_target_outside_the_limits_or_beyond_reach_costs_no_branch(piper, solver):
    from bimanual_app.kinematics import IKSolver

    seeds = IKSolver(piper)
    seeds.chain = None
    for q5 in (1.4, 2.0):  # the wrist bent past joint 5's limit (1.22 rad): every branch leaves the limits
        T = piper.fk_link(np.array([0.0, 1.0, -1.2, 0.0, q5, 0.0]), piper.tcp_link)
        _, excess = ik_branches(solver.chain, T[None], piper.neutral()[None])
        assert (excess > 0).all() and np.isfinite(excess).any()
        r = solver.solve(T, max_seeds=8)
        assert not r.success and r.seeds == 1  # the current configuration only
        assert "every closed-form branch leaves them" in r.message
        assert not seeds.solve(T, max_seeds=16).success  # the DLS seeds find nothing either
    far = np.eye(4)
    far[:3, 3] = [0.0, 0.0, 0.123 + 0.55]  # within the table's reach, but the wrist centre cannot get there
    far[:3, :3] = Rotation.from_euler("y", np.pi).as_matrix()  # pointing down: the wrist centre 0.1 m higher
    r = solver.solve(far, max_seeds=8)
    assert not r.success and r.seeds == 1 and "wrist centre is beyond" in r.message


def test_a_screened_batch_gives_every_target_the_same_outcome_without_descending_the_hopeless_ones(piper, solver):
    """``screen=True``: targets none of whose branches lies within the limits fail at once; the others get
    the solution they get unscreened (the same seeds in the same order)."""
    rng = np.random.default_rng(17)
    q = piper.random_q(300, rng=6)
    T = piper.fk_link(q, piper.tcp_link)
    T[:, :3, 3] += rng.normal(0.0, 0.1, (len(T), 3))  # about half of these are out of reach
    q0 = piper.neutral()
    plain = solver.solve_many(T, q0, max_seeds=6)
    screened = solver.solve_many(T, q0, max_seeds=6, screen=True)
    ok = np.array([r.success for r in plain])
    assert 0.2 < ok.mean() < 0.8
    assert np.array_equal(ok, [r.success for r in screened])
    for a, b in zip(plain, screened):
        if a.success:
            np.testing.assert_allclose(a.q, b.q, atol=1e-9)
        elif b.seeds == 0 and a.seeds > 0:  # screened out: no descent at all (not just beyond the table's reach)
            assert "every closed-form branch leaves them" in b.message or "beyond the arm's reach" in b.message
    assert sum(r.seeds == 0 for r in screened) > sum(r.seeds == 0 for r in plain) + 20
