"""Straight moves on one IK branch (bimanual_app.kinematics.follow_poses, the task planner's Cartesian moves): the
rule itself on a made-up one-joint arm."""

import numpy as np
import pytest

from bimanual_app.kinematics import MAX_JOINT_JUMP, WAYPOINT_STEP, IKResult, follow_poses, line_poses
from bimanual_app.transforms import make_T


def _x_line(n: int, dx: float = WAYPOINT_STEP) -> np.ndarray:
    return np.stack([make_T(np.eye(3), [i * dx, 0.0, 0.0]) for i in range(n)])


def _one_joint(f, reach: float = np.inf):
    """A solve function of a made-up one-joint arm whose joint is ``f(x)`` at the pose's x (m); beyond ``reach``
    it fails."""
    def solve(T, q_seed, n_solutions, max_seeds):
        x = float(T[0, 3])
        if x > reach + 1e-12:
            return IKResult(False, None, np.zeros((0, 1)), 1.0, 0.0, 0, max_seeds, "out of reach")
        q = np.array([f(x)])
        return IKResult(True, q, q[None], 0.0, 0.0, 1, 1, "")

    return solve


def test_a_slow_joint_follows_the_line_step_by_step():
    solve = _one_joint(lambda x: 2.0 * x)
    Q, fail = follow_poses({"a": solve}, {"a": _x_line(6)}, {"a": np.zeros(1)})
    assert fail is None
    np.testing.assert_allclose(Q["a"][:, 0], 2.0 * np.arange(6) * WAYPOINT_STEP)


def test_fast_but_continuous_motion_is_split_until_it_is_followed():
    # a wrist near its singularity: 0.6 rad over one 1 cm step, smooth (a steep ramp): the splits shrink the jump
    solve = _one_joint(lambda x: 0.6 * np.clip((x - 0.01) / 0.01, 0.0, 1.0))
    Q, fail = follow_poses({"a": solve}, {"a": _x_line(4)}, {"a": np.zeros(1)})
    assert fail is None
    assert len(Q["a"]) > 4  # the steep step came back in sub-steps
    assert np.max(np.abs(np.diff(Q["a"][:, 0]))) <= MAX_JOINT_JUMP / 2 + 1e-12


def test_a_switch_to_another_branch_is_refused_however_split():
    # the joint jumps by 1 rad at x = 1.5 cm, a step of its own at every split: another IK branch
    solve = _one_joint(lambda x: 0.0 if x < 0.015 else 1.0)
    Q, fail = follow_poses({"a": solve}, {"a": _x_line(4)}, {"a": np.zeros(1)})
    assert fail is not None and fail.kind == "branch" and fail.index == 2
    assert fail.jump == pytest.approx(1.0)
    assert fail.step == pytest.approx(WAYPOINT_STEP / 8)
    assert len(Q["a"]) == 2  # the waypoints up to the failed step


def test_a_jump_asks_for_more_solutions_and_keeps_the_nearest():
    # two branches (q and q + 1): the first answer of a seed far from its branch is the other one; asked for
    # several solutions (n_solutions > 1) the solver returns the nearest
    def branches(x, q_seed):
        return 2.0 * x + (1.0 if q_seed[0] > 0.5 else 0.0) if x < 0.025 else 2.0 * x + 1.0

    calls = []

    def solve(T, q_seed, n_solutions, max_seeds):
        calls.append(n_solutions)
        x = float(T[0, 3])
        q = np.array([2.0 * x if n_solutions > 1 else branches(x, q_seed)])
        return IKResult(True, q, q[None], 0.0, 0.0, 1, 1, "")

    Q, fail = follow_poses({"a": solve}, {"a": _x_line(5)}, {"a": np.zeros(1)})
    assert fail is None
    np.testing.assert_allclose(Q["a"][:, 0], 2.0 * np.arange(5) * WAYPOINT_STEP)
    assert max(calls) > 1


def test_a_pose_out_of_reach_names_the_arm_and_the_waypoint():
    ok = _one_joint(lambda x: x)
    short = _one_joint(lambda x: x, reach=0.025)
    Q, fail = follow_poses({"p": ok, "s": short}, {"p": _x_line(5), "s": _x_line(5)},
                           {"p": np.zeros(1), "s": np.zeros(1)})
    assert fail is not None and fail.kind == "reach"
    assert (fail.arm, fail.index) == ("s", 3)
    assert fail.T[0, 3] == pytest.approx(0.03)
    assert len(Q["p"]) == len(Q["s"]) == 3


def test_arms_moving_together_split_every_arms_step():
    slow = _one_joint(lambda x: x)
    steep = _one_joint(lambda x: 0.6 * np.clip((x - 0.01) / 0.01, 0.0, 1.0))
    Q, fail = follow_poses({"p": slow, "s": steep}, {"p": _x_line(4), "s": _x_line(4)},
                           {"p": np.zeros(1), "s": np.zeros(1)})
    assert fail is None
    assert len(Q["p"]) == len(Q["s"]) > 4


def test_poses_of_different_lengths_are_refused():
    solve = _one_joint(lambda x: x)
    with pytest.raises(ValueError, match="same number"):
        follow_poses({"p": solve, "s": solve}, {"p": _x_line(3), "s": _x_line(4)}, {"p": np.zeros(1), "s": np.zeros(1)})


def test_line_poses_keep_the_waypoint_spacing_and_both_ends():
    T0 = make_T(np.eye(3), [0.3, 0.0, 0.2])
    T1 = make_T(np.eye(3), [0.3, 0.0, 0.29])
    P = line_poses(T0, T1)
    assert len(P) == 10
    np.testing.assert_allclose(P[0], T0)
    np.testing.assert_allclose(P[-1], T1)
    assert np.allclose(np.diff(P[:, 2, 3]), 0.01)


def test_the_planner_follows_a_straight_line_on_the_piper_and_names_where_it_leaves_the_reach():
    """TaskMotion.ik_path on follow_poses: a 9 cm line from a comfortable pose is followed (every waypoint's FK
    on the line), and a line out past the arm's reach fails with the waypoint and the pose."""
    from _task_fixtures import FIX_T_B1_B2, box_surface_points, table_points

    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import PlanFailure, TaskMotion

    robot = load_robot("piper")
    obj = box_surface_points([0.3, 0.0, 0.03], [0.05, 0.05, 0.06])
    motion = TaskMotion(robot, FIX_T_B1_B2, np.vstack([table_points(), obj]), obj, obj)
    q = robot.neutral()
    T = robot.fk_link(q[None], robot.tcp_link)[0]
    T_end = T.copy()
    T_end[:3, 3] += [0.0, 0.0, 0.09]
    poses = line_poses(T, T_end)
    Q = motion.ik_path({"primary": poses}, {"primary": q})["primary"]
    assert len(Q) >= len(poses)
    P = robot.fk_link(Q, robot.tcp_link)[:, :3, 3]
    d = np.cross(P - T[:3, 3], [0.0, 0.0, 1.0])
    assert np.abs(d).max() < 1e-3  # on the vertical line
    assert np.linalg.norm(P[-1] - T_end[:3, 3]) < 1e-3
    far = T.copy()
    far[:3, 3] = [0.95, 0.0, T[2, 3]]
    with pytest.raises(PlanFailure, match="leaves its reach"):
        motion.ik_path({"primary": line_poses(T, far)}, {"primary": q})


def _x_pose_of(x_of_q, y_of_q=lambda q: 0.0 * q):
    """Forward kinematics of the made-up one-joint arm: (N, 1) joints -> (N, 4, 4) poses at x_of_q, y_of_q."""
    def fk(Q):
        q = np.asarray(Q, dtype=np.float64)[:, 0]
        return np.stack([make_T(np.eye(3), [x_of_q(v), y_of_q(v), 0.0]) for v in q])
    return fk


def test_a_jump_no_split_shrinks_passes_when_the_joint_line_stays_on_the_move():
    # a wrist within a fraction of a millimetre of its singularity: 2.5 rad over 0.1 mm at x = 1.5 cm, finer
    # than the finest split; the joint moving straight between the two solutions keeps the gripper on the line
    x0, dx, turn = 0.015, 1e-4, 2.5
    solve = _one_joint(lambda x: turn * np.clip((x - x0) / dx, 0.0, 1.0))
    fk = _x_pose_of(lambda q: x0 + q / turn * dx)
    Q, fail = follow_poses({"a": solve}, {"a": _x_line(4)}, {"a": np.zeros(1)})
    assert fail is not None and fail.kind == "branch"  # without the arm's kinematics: refused as before
    Q, fail = follow_poses({"a": solve}, {"a": _x_line(4)}, {"a": np.zeros(1)}, fk={"a": fk})
    assert fail is None
    assert Q["a"][-1, 0] == pytest.approx(turn)
    assert np.max(np.abs(np.diff(Q["a"][:, 0]))) <= 0.02 + 1e-12  # the jump came back as joint-line samples


def test_a_branch_switch_whose_joint_line_leaves_the_move_is_still_refused():
    # the same jump, but halfway between the two solutions the gripper is 5 cm off the line: another branch
    x0, dx, turn = 0.015, 1e-4, 2.5
    solve = _one_joint(lambda x: turn * np.clip((x - x0) / dx, 0.0, 1.0))
    fk = _x_pose_of(lambda q: x0 + q / turn * dx, lambda q: 0.05 * np.sin(np.pi * q / turn))
    Q, fail = follow_poses({"a": solve}, {"a": _x_line(4)}, {"a": np.zeros(1)}, fk={"a": fk})
    assert fail is not None and fail.kind == "branch" and fail.index == 2
