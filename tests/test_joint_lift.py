"""The joint lift's object motion chosen inside both arms' reach (bimanual_app.kinematics._lift)."""

from __future__ import annotations

import numpy as np
import pytest

from bimanual_app.kinematics._lift import (
    LIFT_COSTS,
    LIFT_PATHS,
    LiftArm,
    along,
    arms_ik,
    lift_candidates,
    lift_costs,
    object_motion,
    rank_lifts,
)
from grasping._joint import LIFT_STAGES

UP = np.array([0.0, 0.0, 1.0])
CENTRE = np.array([0.31, 0.01, 0.06])


def test_candidates_are_rigid_motions_about_the_centre_straight_up_first():
    c = lift_candidates(CENTRE, UP, 0.15, 0.105, radius=0.08, n_heights=4, n_rings=2, n_dirs=8,
                        yaws=(0.0, 0.3, -0.3))
    n = 4 * (1 + 2 * 8) * 3
    assert len(c) == n and c.T_end.shape == (n, 4, 4) and c.shift.shape == (n, 3)
    straight = np.eye(4)
    straight[:3, 3] = 0.15 * UP
    assert np.allclose(c.T_end[0], straight)
    R = c.T_end[:, :3, :3]
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    # the centre goes where height and shift say, whatever the turn; the turn is about up
    moved = (R @ CENTRE) + c.T_end[:, :3, 3]
    assert np.allclose(moved, CENTRE + c.height[:, None] * UP + c.shift)
    assert np.allclose(R @ UP, UP)
    assert np.allclose(c.shift @ UP, 0.0)
    assert c.height.max() == pytest.approx(0.15) and c.height.min() == pytest.approx(0.105)
    assert np.linalg.norm(c.shift, axis=1).max() == pytest.approx(0.08)
    with pytest.raises(ValueError, match="lift_min"):
        lift_candidates(CENTRE, UP, 0.10, 0.12)
    with pytest.raises(ValueError, match="centre"):
        lift_candidates(CENTRE[:2], UP, 0.15, 0.105)


def test_object_motion_starts_still_and_ends_at_the_candidate():
    c = lift_candidates(CENTRE, UP, 0.15, 0.105, yaws=(0.0, 0.4))
    i = int(np.flatnonzero((c.yaw > 0) & (np.linalg.norm(c.shift, axis=1) > 0.05))[0])
    T = object_motion(c, i)
    assert np.allclose(T[0], np.eye(4)) and np.allclose(T[-1], c.T_end[i])
    rise = T[:, :3, 3] @ UP
    assert np.all(np.diff(rise) > 0)  # never down
    step = np.linalg.norm(np.diff((T[:, :3, :3] @ CENTRE) + T[:, :3, 3], axis=0), axis=1)
    assert step.max() < 0.02  # waypoints about 1 cm apart (the straight-move checker's spacing)
    half = len(T) // 2 + 1
    assert np.allclose(T[half:, :3, :3], T[-1, :3, :3])  # the turn is done over the first half
    # the stages the IK search follows lie on this very path
    s = np.linspace(0.0, 1.0, len(T))
    for k in (0, 3, len(T) // 2, len(T) - 1):
        assert np.allclose(along(c, s[k])[i], T[k])
    assert np.allclose(along(c, 1.0), c.T_end)


def test_lift_paths_differ_only_in_where_along_the_rise_the_object_moves_sideways():
    c = lift_candidates(CENTRE, UP, 0.15, 0.105, yaws=(0.0, 0.4))
    i = int(np.flatnonzero((c.yaw > 0) & (np.linalg.norm(c.shift, axis=1) > 0.05))[0])
    assert np.allclose(object_motion(c, i, path=LIFT_PATHS[0]), object_motion(c, i))  # the default is the first
    for name, start, end in LIFT_PATHS:
        T = object_motion(c, i, path=(name, start, end))
        assert np.allclose(T[0], np.eye(4)) and np.allclose(T[-1], c.T_end[i])
        assert np.all(np.diff(T[:, :3, 3] @ UP) > 0)  # the rise is linear whatever the path
        s = np.linspace(0.0, 1.0, len(T))
        before, after = s <= start + 1e-9, s >= end - 1e-9
        assert np.allclose(T[before, :3, :3], np.eye(3))  # not turned yet
        horizontal = T[before, :3, 3] - np.outer(T[before, :3, 3] @ UP, UP)
        assert np.allclose(horizontal, 0.0)  # nor shifted: straight up
        assert np.allclose(T[after, :3, :3], c.T_end[i, :3, :3])  # turned all the way
    rise_first = object_motion(c, i, path=LIFT_PATHS[1])
    assert np.allclose(rise_first[: len(rise_first) // 2, :3, :3], np.eye(3))  # rises half way before moving


def test_a_lift_that_would_sweep_the_object_into_a_low_neighbour_rises_first():
    """A shifted lift end pose whose usual path (sideways over the first half of the rise) would carry the object
    into a 4 cm neighbour beside it is taken along the path that rises half way first, and its name says so."""
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion
    from bimanual_app.tasks._planners import _clear_lift_path
    from tests._task_fixtures import FIX_T_B1_B2, box_surface_points, table_points

    obj = box_surface_points([0.30, 0.0, 0.04], [0.04, 0.04, 0.08], 1500, visible_only=False)
    low = box_surface_points([0.345, 0.0, 0.02], [0.03, 0.08, 0.04], 1500, seed=2)  # 1.5 cm off its +x face
    motion = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([table_points(), obj, low]), obj, obj,
                        cut_radius=0.0005)
    c = lift_candidates(obj.mean(axis=0), UP, 0.15, 0.105, radius=0.08, n_heights=1, yaws=(0.0,))
    towards = int(np.argmax(c.shift[:, 0]))  # 8 cm towards the neighbour
    assert motion.object_clear(object_motion(c, towards))  # the usual path meets it
    T, how, problem = _clear_lift_path(motion, c, towards, UP)
    assert problem == "" and how.endswith(LIFT_PATHS[1][0])
    assert np.allclose(T, object_motion(c, towards, path=LIFT_PATHS[1]))
    straight = int(np.flatnonzero(np.linalg.norm(c.shift, axis=1) == 0)[0])
    T, how, problem = _clear_lift_path(motion, c, straight, UP)  # straight up: one path, its plain name
    assert problem == "" and how == "up 15.0 cm"
    blocked = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([table_points(), obj, low + [0, 0, 0.11]]),
                         obj, obj, cut_radius=0.0005)  # the neighbour raised over the end pose: every path meets it
    T, how, problem = _clear_lift_path(blocked, c, towards, UP)
    assert T is None and "meets the scene" in problem


def _ramp_reach(T, x0):
    """A fake arm's reach: gripper targets rise at most 2 cm above the object's grasp height, plus twice
    what they moved towards -x from ``x0`` (lifting is only possible nearer the base)."""
    return T[:, 2, 3] - 0.06 <= 0.02 + 2.0 * (x0 - T[:, 0, 3]) + 1e-9


def _fake_arm(x0: float):
    """A LiftArm with :func:`_ramp_reach` (q = the target's x, y)."""

    def solve(T, seeds):
        assert seeds.shape == (len(T), 2)
        return T[:, :2, 3].copy(), _ramp_reach(T, x0)

    return LiftArm(solve, lambda Q: np.tile(np.eye(6)[:, :2], (len(Q), 1, 1)), np.full(2, -1.0), np.full(2, 1.0),
                   np.zeros(2))


def _grasps_beside_centre() -> dict:
    """Both grippers (4, 4) 5 cm either side of CENTRE along y, frames aligned with b1."""
    S = {"primary": np.eye(4), "secondary": np.eye(4)}
    S["primary"][:3, 3] = CENTRE + [0.0, 0.05, 0.0]
    S["secondary"][:3, 3] = CENTRE - [0.0, 0.05, 0.0]
    return S


def test_ranking_keeps_what_both_arms_reach_with_named_costs():
    """An end pose the arms reach only after a shift towards them is found; the straight-up lift is not
    among the ranked; every cost is a named (N,) term."""
    c = lift_candidates(CENTRE, UP, 0.15, 0.105, radius=0.08, yaws=(0.0,))
    S = _grasps_beside_centre()
    arms = {"primary": _fake_arm(CENTRE[0]), "secondary": _fake_arm(CENTRE[0] - 0.01)}
    ik = arms_ik(arms, S, c)
    costs = lift_costs(c, ik, arms)
    assert list(costs) == [t.name for t in LIFT_COSTS]
    assert {"joint-limit margin", "singularity", "shift", "turn", "height given up"} <= set(costs)
    assert all(v.shape == (len(c),) and np.all(np.isfinite(v)) for v in costs.values())
    order = rank_lifts(c, ik, costs)
    assert len(order) and 0 not in order
    # only the shifts that bring the object within reach: up 10.5 cm needs 4.75 (primary) / 5.25 cm
    # (secondary) towards -x, up 15 cm 7 cm
    assert np.all(c.shift[order, 0] <= -0.0525 + 1e-9)
    assert np.all(c.height[order] <= 0.02 + 2 * (-c.shift[order, 0] - 0.01) + 1e-9)
    total = np.sum(list(costs.values()), axis=0)
    assert np.all(np.diff(total[order]) >= 0)
    # the full lift, 8 cm towards the bases (the shift costs less than the height it would give up)
    assert c.height[order[0]] == pytest.approx(0.15) and np.allclose(c.shift[order[0]], [-0.08, 0.0, 0.0])
    assert costs["shift"][order[0]] > 0 and costs["height given up"][order[0]] == 0 and costs["turn"][order[0]] == 0


def test_the_highest_lift_both_arms_reach_goes_first_even_with_less_joint_room():
    """The task needs the object 10 cm up, held; a lift planned just past that leaves nothing for the object
    to sag in the grippers. Here every lift is reached, but the higher the lift the nearer a joint comes to
    its limit: the full lift still ranks first, and the lower ones stay behind it as fallbacks."""
    c = lift_candidates(CENTRE, UP, 0.15, 0.105, radius=0.08, yaws=(0.0,))

    def solve(T, seeds):  # joint 0 follows the height: 0.63 rad at 10.5 cm up, 0.9 rad (0.1 from its limit) at 15
        return np.c_[(T[:, 2, 3] - CENTRE[2]) * 6.0, T[:, 1, 3]], np.ones(len(T), bool)

    arm = LiftArm(solve, lambda Q: np.tile(np.eye(6)[:, :2], (len(Q), 1, 1)), np.full(2, -1.0), np.full(2, 1.0),
                  np.zeros(2))
    S = _grasps_beside_centre()
    arms = {"primary": arm, "secondary": arm}
    ik = arms_ik(arms, S, c)
    costs = lift_costs(c, ik, arms)
    assert costs["joint-limit margin"][np.argmax(c.height)] > costs["joint-limit margin"][np.argmin(c.height)]
    order = rank_lifts(c, ik, costs)
    assert c.height[order[0]] == pytest.approx(0.15)
    assert np.all(np.diff(c.height[order]) <= 1e-12)  # by height first, every height kept
    assert len(order) == len(c)


def test_arms_ik_checks_shapes():
    c = lift_candidates(CENTRE, UP, 0.15, 0.105)
    bad = LiftArm(lambda T, q: (np.zeros((3, 2)), np.ones(3, bool)), None, np.zeros(2), np.ones(2), np.zeros(2))
    with pytest.raises(ValueError, match="primary solver returned shapes"):
        arms_ik({"primary": bad}, {"primary": np.eye(4)}, c)
    with pytest.raises(ValueError, match="S\\[primary\\]"):
        arms_ik({"primary": _fake_arm(1.0)}, {"primary": np.eye(3)}, c)


# A push pair over a long object, both grasps from above and tilted towards the other arm (each arm at the
# edge of its joint limits with that orientation): straight up, the primary leaves its reach below 10 cm.
S_PRIMARY = np.array([[-0.912651, 0.07168, 0.402406, 0.324513], [-0.012872, 0.978974, -0.203577, 0.168883],
                      [-0.408538, -0.190975, -0.892539, 0.066173], [0.0, 0.0, 0.0, 1.0]])
S_SECONDARY = np.array([[0.912651, -0.07168, -0.402406, 0.301415], [0.012872, -0.978974, 0.203577, -0.146586],
                        [-0.408538, -0.190975, -0.892539, 0.066173], [0.0, 0.0, 0.0, 1.0]])
Q_PRIMARY = np.array([0.744938, 1.783398, -1.101409, -0.575733, 0.888172, 1.125773])
Q_SECONDARY = np.array([0.885924, 1.884314, -1.166554, -0.592357, 0.852766, 1.140558])
T_B1_B2 = np.array([[-0.98827, -0.15272, 0.0, 0.644906], [0.15272, -0.98827, 0.0, 0.034104],
                    [0.0, 0.0, 1.0, 0.018958], [0.0, 0.0, 0.0, 1.0]])


def test_a_lift_both_arms_follow_is_found_where_straight_up_is_out_of_reach():
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import PlanFailure, TaskMotion
    from bimanual_app.tasks._planners import LIFT, LIFT_MIN, LIFT_RADIUS, _lift_arms

    robot = load_robot("piper")
    table = np.stack(np.meshgrid(np.linspace(0.0, 0.7, 50), np.linspace(-0.4, 0.4, 50), [0.0]), -1).reshape(-1, 3)
    obj = np.stack(np.meshgrid([0.30, 0.32], np.linspace(-0.15, 0.17, 20), np.linspace(0.0, 0.1, 6)),
                   -1).reshape(-1, 3)
    motion = TaskMotion(robot, T_B1_B2, table, obj, up=UP)
    S = {"primary": S_PRIMARY, "secondary": S_SECONDARY}
    q = {"primary": Q_PRIMARY, "secondary": Q_SECONDARY}
    for a in S:  # the start is where the arms hold the object
        assert np.allclose(motion.tcp_pose(a, q[a]), S[a], atol=1e-4)
    straight = lift_candidates(obj.mean(axis=0), UP, LIFT_MIN, LIFT_MIN, n_heights=1, n_rings=0, yaws=(0.0,))
    with pytest.raises(PlanFailure, match="primary gripper leaves its reach"):
        motion.cartesian({a: object_motion(straight, 0) @ S[a] for a in S}, q)
    c = lift_candidates(obj.mean(axis=0), UP, LIFT, LIFT_MIN, radius=LIFT_RADIUS)
    arms = _lift_arms(motion, q)
    ik = arms_ik(arms, S, c)
    assert not ik["primary"][1][(c.yaw == 0) & (np.linalg.norm(c.shift, axis=1) == 0)].any()
    order = rank_lifts(c, ik, lift_costs(c, ik, arms))
    assert len(order)
    followed = None
    for i in order[:6]:
        try:
            tr = motion.cartesian({a: object_motion(c, i) @ S[a] for a in S}, q)
        except PlanFailure:
            continue
        followed = i
        break
    assert followed is not None
    assert c.height[followed] >= LIFT_MIN - 1e-9
    for a in S:  # the grippers end where the object's motion takes their grasps
        assert np.allclose(motion.tcp_pose(a, tr[a].q[-1]), c.T_end[followed] @ S[a], atol=2e-3)


class _Result:
    def __init__(self, ok, q):
        self.success, self.q = ok, q


class _FakeSolver:
    """``solve_many`` with :func:`_ramp_reach` (targets in the arm's base frame); counts calls."""

    def __init__(self, x0):
        self.x0, self.calls = x0, 0
        self.lower, self.upper = np.full(6, -3.0), np.full(6, 3.0)

    def solve_many(self, T, q, max_seeds=1):
        self.calls += 1
        return [_Result(ok, qi) for ok, qi in zip(_ramp_reach(T, self.x0), q)]


def _grasps(arm, x, y):
    from types import SimpleNamespace

    T = np.tile(np.eye(4), (1, 1, 1))
    T[0, :3, 3] = [x, y, 0.06]
    return SimpleNamespace(arm=arm, index=np.array([0]), grasps=SimpleNamespace(T_b1_g=T), q=np.zeros((1, 6)))


def test_pair_lift_needs_one_end_pose_both_arms_reach_and_solves_each_grasp_once():
    from grasping._joint import PairLift

    p, s = _FakeSolver(CENTRE[0]), _FakeSolver(CENTRE[0])
    lift = PairLift({"primary": (p, np.eye(4)), "secondary": (s, np.eye(4))}, CENTRE, UP)
    # both grasps at the object's x: only a lift shifted 4.25 cm or more towards -x is followed
    assert lift(_grasps("primary", CENTRE[0], 0.05), 0, _grasps("secondary", CENTRE[0], -0.05), 0)
    assert lift(_grasps("primary", CENTRE[0], 0.05), 0, _grasps("secondary", CENTRE[0], -0.05), 0)
    assert p.calls == s.calls and p.calls >= 1  # the lift's stages, once per grasp (cached)
    calls = p.calls
    # the secondary's grasp 5 cm further out: no shift within the radius brings both within reach
    assert not lift(_grasps("primary", CENTRE[0], 0.05), 0, _grasps("secondary", CENTRE[0] + 0.05, -0.05), 0)
    assert p.calls == calls  # the primary's grasp again: cached
    ends = lift._candidates().T_end
    assert ends.shape[1:] == (4, 4) and np.allclose(ends[:, 2, 3], 0.105)  # the least lift only


def test_grasp_stage_lists_the_pairs_the_arms_can_lift_first(monkeypatch):
    """With a lift check, pairs both arms cannot lift the object from follow every pair they can, flagged."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from _grasp_fixtures import Obj, accept_all_arms, facing_T_b1_b2, make_cloud

    import grasping._plan as gplan
    from grasping import PlanParams, plan_grasps, scene_cloud

    T12 = facing_T_b1_b2(0.6)
    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.1)], table_size=(0.8, 0.8))
    seen = []

    def fake(primary, i, secondary, j):  # liftable: the primary's contact on the +y half of the face
        ok = bool(primary.grasps.extra["contact"][i][1] > 0.0)
        seen.append(ok)
        return ok

    monkeypatch.setattr(gplan.PairLift, "for_arms", classmethod(lambda cls, arms, centre, up, **kw: fake))
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12,
                       params=PlanParams(handover=False, retry_factor=1))
    op = plan.objects[0]
    assert True in seen and False in seen  # the check ran on pairs of both sorts
    flags = [p.liftable for p in op.joint]
    assert flags == sorted(flags, reverse=True) and flags[0]
    for pair in op.joint:
        p_ag, _ = op.pair_grasps(pair)
        assert pair.liftable == bool(p_ag.grasps.extra["contact"][pair.i_primary][1] > 0.0)
    assert op.stats["joint_push"]["liftable"] == seen.count(True)


def _down_grasp(x, y, z):
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # approach straight down
    T[:3, 3] = [x, y, z]
    return T


def test_lift_clear_keeps_the_lifts_whose_gripper_misses_the_scene():
    """A plate 3 cm wide hangs 3 cm over a gripper holding the object from above: lifting straight up runs
    the gripper into it; lifts shifted far enough sideways pass it, and each one kept is clear at every stage."""
    from grasping import GripperCollider, SceneOctree, lift_clear, load_gripper

    gripper = load_gripper("piper")
    collider = GripperCollider(gripper, 0.0)
    T = _down_grasp(*CENTRE)
    top = float((T @ np.r_[0.0, 0.0, -0.18, 1.0])[2])  # over the flange (13.6 cm behind the fingertips)
    xx, yy = np.meshgrid(np.linspace(-0.015, 0.015, 7), np.linspace(-0.15, 0.15, 61))
    plate = np.c_[CENTRE[0] + xx.ravel(), CENTRE[1] + yy.ravel(), np.full(xx.size, top + 0.03)]
    scene = SceneOctree(plate, 0.005)
    c = lift_candidates(CENTRE, UP, 0.105, 0.105, radius=0.08, n_heights=1)
    ok = lift_clear(collider, scene, c, T, 0.04, 0.003)
    assert ok.shape == (len(c),) and ok.any() and not ok.all()
    assert not collider.collides(scene, T[None], np.array([0.04]), swept=False, margin=0.003)[0]  # clear at rest
    assert not ok[0]  # straight up
    assert np.all(np.abs(c.shift[ok, 0]) > 0.03)  # only well to either side of the plate
    for i in np.flatnonzero(ok):  # clear, margin included, at every stage the check names
        for s in LIFT_STAGES:
            Ts = along(c, s)[i] @ T
            assert not collider.collides(scene, Ts[None], np.array([0.04]), swept=False, margin=0.003)[0]
    only = lift_clear(collider, scene, c, T, 0.04, 0.003, ok=~ok)  # only the lifts asked about are checked
    assert not only.any()
    assert lift_clear(collider, SceneOctree(np.zeros((0, 3))), c, T, 0.04, 0.003).all()  # an empty scene


def test_pair_lift_with_a_scene_needs_a_lift_both_grippers_pass():
    from grasping import GripperCollider, SceneOctree, load_gripper
    from grasping._joint import PairLift

    p, s = _FakeSolver(CENTRE[0]), _FakeSolver(CENTRE[0])
    solvers = {"primary": (p, np.eye(4)), "secondary": (s, np.eye(4))}
    a, b = _grasps("primary", CENTRE[0], 0.05), _grasps("secondary", CENTRE[0], -0.05)
    for g in (a, b):
        g.grasps.T_b1_g[0][:3, :3] = np.diag([1.0, -1.0, -1.0])
        g.grasps.width = np.array([0.04])
    assert PairLift(solvers, CENTRE, UP)(a, 0, b, 0)  # IK only: a lift towards -x
    # a wall of points on the -x side, where every lift both arms follow goes
    yy, zz = np.meshgrid(np.linspace(-0.2, 0.2, 81), np.linspace(0.0, 0.4, 81))
    wall = np.c_[np.full(yy.size, CENTRE[0] - 0.06), yy.ravel(), zz.ravel()]
    collider = GripperCollider(load_gripper("piper"), 0.0)
    blocked = PairLift(solvers, CENTRE, UP, collider=collider, scene=SceneOctree(wall, 0.005))
    assert not blocked(a, 0, b, 0)
    far = PairLift(solvers, CENTRE, UP, collider=collider, scene=SceneOctree(wall - [0.4, 0.0, 0.0], 0.005))
    assert far(a, 0, b, 0)
