"""The reach filter on the project's IK and collision world: grasp and pre-grasp reached, joint limits, far poses."""

import numpy as np
import pytest

from grasping import ArmReach, load_gripper, pregrasp_pose, rotate_about_approach


@pytest.fixture(scope="module")
def reach():
    from bimanual_app.robots import load_robot

    robot = load_robot("piper")
    return robot, ArmReach(robot, load_gripper("piper"))


def _tilted(roll_deg: float = 0.0) -> np.ndarray:
    """A grasp 30 cm out at 8 cm height, approaching 45 degrees down and outwards, turned ``roll`` about z.

    (Straight down with a vertical pre-grasp is out of the Piper's reach this close to the table: joint 5
    spans only +-70 degrees.)"""
    a = np.deg2rad(45.0)
    z = np.array([np.sin(a), 0.0, -np.cos(a)])
    y0 = np.array([0.0, 1.0, 0.0])
    r = np.deg2rad(roll_deg)
    y = np.cos(r) * y0 + np.sin(r) * np.cross(y0, z)
    T = np.eye(4)
    T[:3, :3] = np.stack([np.cross(y, z), y, z], axis=1)
    T[:3, 3] = [0.30, 0.05, 0.08]
    return T


def test_reachable_grasp_and_pregrasp(reach):
    robot, f = reach
    T = _tilted()
    far = T.copy()
    far[:3, 3] = [1.2, 0.0, 0.1]  # beyond the arm's reach
    res = f(np.stack([T, far]), np.array([0.05, 0.05]))
    assert res.ok.tolist() == [True, False] and "reach" in res.reason[1]
    T_used = rotate_about_approach(T) if res.flipped[0] else T
    assert np.allclose(robot.fk_link(res.q[0], robot.tcp_link), T_used, atol=1e-3)
    assert robot.within_limits(res.q[0]) and robot.within_limits(res.q_pre[0])
    pre = robot.fk_link(res.q_pre[0], robot.tcp_link)
    assert np.allclose(pre, pregrasp_pose(T_used, f.pregrasp), atol=1e-3)  # 9 cm back along the approach
    assert 0.08 <= f.pregrasp <= 0.10
    assert np.isnan(res.q[1]).all()


def test_wrist_limit_uses_the_turned_grasp(reach):
    """joint 6 spans +-120 degrees: of a grasp and the same grasp turned 180 degrees about z, the filter
    finds the one the wrist reaches (the gripper is symmetric)."""
    robot, f = reach
    oks = []
    for roll in range(0, 360, 45):
        T = _tilted(roll)
        res = f(T[None])
        oks.append(bool(res.ok[0]))
        if res.ok[0]:
            T_used = rotate_about_approach(T) if res.flipped[0] else T
            assert np.allclose(robot.fk_link(res.q[0], robot.tcp_link), T_used, atol=1e-3)
            assert np.allclose(rotate_about_approach(rotate_about_approach(T)), T)
    assert all(oks)


def test_follow_a_straight_lift_and_the_lifting_filter(reach):
    """``follow`` carries a reached grasp along a straight line (orientation kept) or says why not; the
    lifting filter keeps only grasps the arm can also lift."""
    from grasping import Arm
    from grasping._arms import LiftingReach, lifting_arm

    robot, f = reach
    T = _tilted()
    res = f(T[None])
    assert res.ok[0]
    T_used = rotate_about_approach(T) if res.flipped[0] else T
    assert f.follow(T_used, res.q[0], np.array([0.0, 0.0, 1.0]), 0.12) == ""
    # carried 40 cm further out it leaves the arm's reach (0.63 m)
    why = f.follow(T_used, res.q[0], np.array([1.0, 0.0, 0.0]), 0.40)
    assert why and "cm along" in why
    lift = LiftingReach(f, np.array([0.0, 0.0, 1.0]), 0.12)
    assert lift(T[None]).ok[0]
    out = LiftingReach(f, np.array([1.0, 0.0, 0.0]), 0.40)(T[None])
    assert not out.ok[0] and "cannot lift it 40 cm" in out.reason[0]
    assert lift.prior is f.prior or callable(lift.prior)  # the wrapped filter's prior stays available
    # a plain callable filter cannot follow a line: no lifting arm
    from grasping import callable_filter

    plain = Arm("primary", np.eye(4), callable_filter(lambda Ts: np.ones(len(Ts), dtype=bool)))
    assert lifting_arm(plain, np.array([0.0, 0.0, 1.0]), 0.12) is None
    assert isinstance(lifting_arm(Arm("primary", np.eye(4), f), np.array([0.0, 0.0, 1.0]), 0.12).reach, LiftingReach)


def test_an_approach_held_off_the_grasp_is_checked_where_it_ends(reach):
    """A push contact's approach ends held off the face (the task's standoff), then squeezes: the reach
    filter checks that pose too and the straight line from it to the pre-grasp, the task's own approach line;
    a held-off pose the arm cannot take rejects the grasp with that reason."""
    from grasping._reach import _approach_poses

    robot, f = reach
    T = _tilted()
    up = np.array([0.0, 0.0, 1.0])
    hold = -0.01 * T[:3, 2]  # 1 cm back along the approach
    poses, where = _approach_poses(T, f.pregrasp, up, hold)
    assert np.allclose(poses[0][:3, 3], T[:3, 3] + hold) and where[0] == "held off 10 mm"
    assert np.allclose(poses[-1], pregrasp_pose(T, f.pregrasp, up))  # the same pre-grasp
    steps = np.linalg.norm(np.diff([P[:3, 3] for P in poses], axis=0), axis=1)
    assert steps.max() <= 0.02 + 1e-12 and all(np.allclose(P[:3, :3], T[:3, :3]) for P in poses)
    res = f(T[None], np.array([0.05]), up[None], hold[None])
    assert res.ok[0]
    T_used = rotate_about_approach(T) if res.flipped[0] else T
    assert np.allclose(robot.fk_link(res.q[0], robot.tcp_link), T_used, atol=1e-3)  # q is still the grasp's
    res = f(T[None], np.array([0.05]), up[None], np.array([[0.6, 0.0, 0.0]]))  # "held off" beyond the reach
    assert not res.ok[0] and "held off 600 mm" in res.reason[0]


def test_push_contacts_carry_their_standoff_as_the_hold_off():
    """Each push contact's hold-off is the standoff out along the face's outward normal: against its squeeze."""
    from _grasp_fixtures import Obj, make_cloud

    from grasping import GripperCollider, estimate_support, object_geometry
    from grasping._collision import SceneOctree
    from grasping._push import PushParams, push_contacts

    P, L = make_cloud([Obj("box", (0.35, 0.0), (0.22, 0.12, 0.10), 0.0)], noise=0.0, seed=1)
    sup = estimate_support(P, L)
    geo = object_geometry(0, P[L == 0], sup, background=P[L < 0])
    g = load_gripper("piper")
    push = push_contacts(geo, sup, g, GripperCollider(g), SceneOctree(P[L < 0]))
    assert len(push)
    assert np.allclose(push.extra["hold_off"], -PushParams().standoff * push.extra["squeeze"])


def test_a_grasp_checked_again_is_remembered_not_solved_again():
    """The searches check many of the same grasps: a repeat (alone or among new grasps) gives the first
    check's outcome without new IK; another pre-grasp distance or opening is a new check."""
    from bimanual_app.robots import load_robot

    robot, gripper = load_robot("piper"), load_gripper("piper")

    def counted(f):
        calls = []
        solve_many = f.solver.solve_many
        f.solver.solve_many = lambda *a, **k: calls.append(len(a[0])) or solve_many(*a, **k)
        return calls

    T, far, new = _tilted(), _tilted(90.0), _tilted(45.0)
    far[:3, 3] = [1.2, 0.0, 0.1]
    fresh = ArmReach(robot, gripper)
    alone = counted(fresh)
    fresh(new[None], np.array([0.05]))  # the IK a new grasp costs
    f = ArmReach(robot, gripper)
    first = f(np.stack([T, far]), np.array([0.05, 0.05]))
    calls = counted(f)
    again = f(np.stack([far, T, new]), np.array([0.05, 0.05, 0.05]))
    assert calls == alone  # the repeats cost no IK
    assert again.ok[:2].tolist() == first.ok[::-1].tolist() and again.reason[0] == first.reason[1]
    assert np.array_equal(again.q[1], first.q[0]) and np.array_equal(again.q_pre[1], first.q_pre[0])
    n = len(calls)
    f(T[None], np.array([0.06]))  # another opening: checked anew
    assert len(calls) > n
    n = len(calls)
    f.with_pregrasp(0.08)(T[None], np.array([0.05]))  # another approach line
    assert len(calls) > n


def test_a_full_reach_cache_is_cleared_without_losing_the_grasps_it_held():
    """A batch mixing remembered grasps with new ones that overflow the cache: the cache is cleared, and the
    remembered grasps still get their outcome (they raised a KeyError once the push contacts were all
    checked: a ground-truth bench scene filled the 4096 entries mid-batch)."""
    from bimanual_app.robots import load_robot

    f = ArmReach(load_robot("piper"), load_gripper("piper"))
    f.REACH_CACHE = 2
    T, other, new = _tilted(), _tilted(90.0), _tilted(45.0)
    first = f(np.stack([T, other]), np.array([0.05, 0.05]))
    again = f(np.stack([T, new, other]), np.array([0.05, 0.05, 0.05]))  # 2 remembered + 1 new > 2
    assert again.ok[[0, 2]].tolist() == first.ok.tolist() and again.reason[2] == first.reason[1]
    assert np.array_equal(again.q[0], first.q[0], equal_nan=True)
    assert len(f._reach_cache) == 1  # cleared, then only the new grasp


def test_the_approach_screen_changes_no_outcome(reach):
    """Approaches with a pose no IK branch reaches are ruled out in one batch before the step-by-step solve
    (``IKSolver.screen``); the outcomes (and solutions) equal those of the step-by-step check alone."""
    robot, f = reach
    rng = np.random.default_rng(5)
    T = np.stack([_tilted(r) for r in rng.uniform(0, 360, 60)])
    T[:, :3, 3] += rng.normal(0.0, [0.12, 0.12, 0.05], (60, 3))  # many out of reach, some only on the way back
    screened = ArmReach(robot, load_gripper("piper"), _solver=f.solver)._check(T, np.full(60, 0.05), None, None)

    class Unscreened(ArmReach):
        def _screen_approaches(self, T, q, rt, ho):
            return [""] * len(T)

    plain = Unscreened(robot, load_gripper("piper"), _solver=f.solver)._check(T, np.full(60, 0.05), None, None)
    assert screened.ok.tolist() == plain.ok.tolist() and 5 <= screened.ok.sum() <= 55
    assert np.allclose(screened.q[screened.ok], plain.q[plain.ok]) and (screened.flipped == plain.flipped).all()
    assert any("pre-grasp" in r and "closed-form branch" in r for r in screened.reason)


def test_the_first_ik_cache_full_mid_batch_still_answers_every_pose(reach, monkeypatch):
    """A batch that overflows the remembered IK clears it and solves its own remembered poses again (it
    raised a KeyError for them when the cache was cleared under them)."""
    _, f = reach
    monkeypatch.setattr(type(f), "FIRST_IK_CACHE", 3)
    T, far, new = _tilted(), _tilted(90.0), _tilted(45.0)
    far[:3, 3] = [1.2, 0.0, 0.1]
    f._ik_cache.clear()
    first = f._first_ik(np.stack([T, far]))
    both = f._first_ik(np.stack([far, new, T, new]))  # 2 remembered + 1 new > 3: cleared mid-batch
    assert [r.success for r in both] == [first[1].success, both[1].success, first[0].success, both[1].success]
    assert np.array_equal(both[2].q, first[0].q)
    assert len(f._ik_cache) == 3


def test_a_pregrasp_nearer_the_scene_than_the_free_motion_margin_is_not_reached(reach):
    """The pre-grasp is where the task's free motion ends: a patch of points 8 mm in front of the fingertips
    there (inside the planner's 1 cm free-motion margin; the reach world leaves the gripper's own shapes to
    the sampler's swept check) rejects the grasp, one 3 cm in front does not, and without the goal check
    neither does."""
    robot, f = reach
    gripper = load_gripper("piper")
    T = _tilted()
    res = f(T[None], np.array([0.05]))
    assert res.ok[0]
    T_pre = robot.fk_link(res.q_pre[0], robot.tcp_link)  # the gripper where the free motion ends (b1 = b)
    xx, yy = np.meshgrid(np.linspace(-0.015, 0.015, 7), np.linspace(-0.045, 0.045, 19))

    def ahead(gap: float) -> np.ndarray:  # (133, 3) a 3 x 9 cm patch ``gap`` m in front of the fingertips
        return np.c_[xx.ravel(), yy.ravel(), np.full(xx.size, gap)] @ T_pre[:3, :3].T + T_pre[:3, 3]

    near = ArmReach(robot, gripper, _solver=f.solver).for_scene(ahead(0.008))
    out = near(T[None], np.array([0.05]))
    assert not out.ok[0]  # (its reason is the last branch's: the turned grasp's pre-grasp is out of reach)
    assert any("touches the scene map" in x for x in near.goal_problems(res.q_pre[0], 0.05))
    far = ArmReach(robot, gripper, _solver=f.solver).for_scene(ahead(0.03))
    assert far(T[None], np.array([0.05])).ok[0] and far.goal_problems(res.q_pre[0], 0.05) == []
    unchecked = ArmReach(robot, gripper, goal_margin=None, _solver=f.solver).for_scene(ahead(0.008))
    assert unchecked(T[None], np.array([0.05])).ok[0]


def test_the_goal_check_keeps_to_the_task_planners_free_motion_settings():
    """The reach filter's pre-grasp check mirrors the task planner's free motion (its margin and map)."""
    import inspect

    from bimanual_app.tasks._motion import MAP_RESOLUTION, TaskMotion

    f = inspect.signature(ArmReach.__init__).parameters
    assert f["goal_margin"].default == inspect.signature(TaskMotion.__init__).parameters["margin"].default
    assert f["goal_resolution"].default == MAP_RESOLUTION
