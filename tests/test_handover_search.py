"""Hand-over search: transfer poses solved for a (giver, receiver) pair, named cost terms, receiver hold."""

import numpy as np
import pytest
from _grasp_fixtures import Obj, facing_T_b1_b2, make_cloud
from scipy.spatial.transform import Rotation

from grasping._handover_pairs import PAIR_COST_TERMS, PairParams, pair_costs, pair_moves, wahba_rotations

UP = np.array([0.0, 0.0, 1.0])


def test_wahba_recovers_a_rotation_from_three_vector_pairs():
    R = Rotation.from_euler("xyz", [[0.3, -1.1, 2.0], [2.9, 0.2, -0.4]]).as_matrix()
    src = np.array([[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]] * 2)
    dst = np.einsum("nij,nvj->nvi", R, src)
    out = wahba_rotations(src, dst, np.array([1.0, 1.0, 0.2]))
    assert np.allclose(out, R, atol=1e-9)
    assert np.allclose(np.linalg.det(out), 1.0)
    with pytest.raises(ValueError, match=r"\(N, V, 3\)"):
        wahba_rotations(src[:, :2], dst, np.ones(3))


def test_wahba_returns_a_proper_rotation_for_a_reflected_target():
    src = np.eye(3)[None]
    dst = np.diag([1.0, 1.0, -1.0])[None]  # a reflection: the best proper rotation is not it
    out = wahba_rotations(src, dst, np.ones(3))
    assert np.allclose(out[0] @ out[0].T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(out[0]), 1.0)


def test_pair_moves_point_each_approach_away_from_its_own_base():
    """A giver approaching from above and a receiver from the side (perpendicular): at a transfer pose
    between the bases the giver can still come from above (giver tilt pi/2) while the receiver comes in
    horizontally from the secondary's side -- both exactly, and the object's centre lands on the target."""
    centre = np.array([0.2, 0.3, 0.03])
    a_g = np.array([0.0, 0.0, -1.0])  # the giver's approach: straight down where the object lies
    a_r = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # two receivers, both horizontal
    o1, o2 = np.zeros(3), np.array([0.6, 0.0, 0.0])
    targets = np.array([[0.3, 0.0, 0.2], [0.3, 0.1, 0.25]])
    p = PairParams(giver_tilts=(np.pi / 2,), receiver_tilts=(0.0,))
    moves, which = pair_moves(centre, UP, a_g, a_r, targets, o1, o2, p)
    assert moves.shape == (2, 2, 1, 1, 4, 4) and which.shape == (2, 2, 1, 1)
    for r in range(2):
        for t in range(2):
            M = moves[r, t, 0, 0]
            assert np.allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-9)
            assert np.allclose(M[:3, :3] @ centre + M[:3, 3], targets[t])
            assert np.allclose(M[:3, :3] @ a_g, -UP, atol=1e-9)  # the giver still from above
            away = targets[t] - o2
            away[2] = 0.0
            assert np.allclose(M[:3, :3] @ a_r[r], away / np.linalg.norm(away), atol=1e-9)
            assert which[r, t, 0, 0] == r


def test_pair_moves_keep_the_object_upright_when_the_approaches_are_opposite():
    """Opposite approaches leave the turn about them free; the weak pull on up settles it: upright."""
    centre = np.array([0.3, 0.2, 0.04])
    a_g = np.array([1.0, 0.0, 0.0])
    a_r = np.array([[-1.0, 0.0, 0.0]])
    o1, o2 = np.zeros(3), np.array([0.6, 0.0, 0.0])
    targets = np.array([[0.3, 0.0, 0.2]])
    moves, _ = pair_moves(centre, UP, a_g, a_r, targets, o1, o2, PairParams(giver_tilts=(0.0,), receiver_tilts=(0.0,)))
    M = moves.reshape(4, 4)
    assert np.allclose(M[:3, :3] @ a_g, [1.0, 0, 0], atol=1e-9) and np.allclose(M[:3, :3] @ UP, UP, atol=1e-9)


def test_pair_costs_weigh_named_terms_and_refuse_unknown_ones():
    terms = {"giver_reach": np.array([0.01, 0.05]), "receiver_reach": np.array([0.02, 0.0]),
             "receiver_grasp": np.array([0.5, 0.0]), "receiver_hold": np.array([0.5, 0.0])}
    w = PAIR_COST_TERMS
    expect = [0.01 * w["giver_reach"] + 0.02 * w["receiver_reach"] + 0.5 * w["receiver_grasp"] + 0.5 * w["receiver_hold"],
              0.05 * w["giver_reach"]]
    assert np.allclose(pair_costs(terms), expect)
    with pytest.raises(ValueError, match="without a weight"):
        pair_costs({"giver_reach": np.zeros(2), "elbow_room": np.zeros(2)})


class _Cone:
    """A reach filter (with a prior, as ``ArmReach`` has) accepting grasps whose approach (z of g, base frame)
    is within ``max_deg`` of the direction away from the base, tilted down by ``tilt_deg`` (lo, hi); on the
    table (below 12 cm) every grasp."""

    def __init__(self, max_deg, tilt_deg, table=True):
        from grasping import callable_filter

        self.max_deg, self.tilt_deg, self.table = max_deg, tilt_deg, table
        self.filter = callable_filter(self.ok)

    def ok(self, T):
        z = T[:, :3, 2]
        away = T[:, :3, 3] * np.array([1.0, 1.0, 0.0])
        away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-9)
        tilt = np.radians(np.clip(np.degrees(np.arcsin(np.clip(-z[:, 2], -1, 1))), *self.tilt_deg))
        want = np.cos(tilt)[:, None] * away - np.sin(tilt)[:, None] * UP
        ang = np.degrees(np.arccos(np.clip((z * want).sum(axis=1), -1, 1)))
        low = T[:, 2, 3] < 0.12
        return (low & self.table) | (~low & (ang < self.max_deg))

    def __call__(self, T, width=None, retreat=None, hold_off=None):
        return self.filter(T, width, retreat, hold_off)

    def prior(self, T):
        return np.where(self.ok(np.asarray(T).reshape(-1, 4, 4)), 0.0, np.inf)


def test_plan_handovers_finds_poses_where_each_arm_reaches_only_from_its_own_side():
    """The giver reaches only grasps coming in level from its own side, the receiver only ones tilted
    35-45 degrees down from its own side (narrow cones about the directions away from each base): the
    pair search solves the object's turn for such pairs, and the hand-over found has both grippers there."""
    from grasping import Arm, PlanParams, plan_grasps, scene_cloud

    T12 = facing_T_b1_b2(0.6)
    P, L = make_cloud([Obj("box", (0.3, 0.2), (0.05, 0.05, 0.08), 0.3)], table_size=(0.8, 0.8))
    giver, receiver = _Cone(10.0, (0.0, 5.0)), _Cone(8.0, (35.0, 45.0))
    arms = {"primary": Arm("primary", np.eye(4), giver), "secondary": Arm("secondary", T12, receiver)}
    plan = plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12, params=PlanParams(retry_factor=1))
    op = plan.objects[0]
    h = op.handover
    assert h is not None, (op.notes, op.stats.get("handover"))
    assert op.stats["handover"]["paired_poses"] > 0
    assert receiver.ok((np.linalg.inv(T12) @ h.receiver["T_b1_g"])[None])[0]
    assert giver.ok(h.giver_T_b1_g[None])[0]
    assert np.allclose(h.T_move[:3, :3] @ op.geometry.centre + h.T_move[:3, 3], h.centre)


def test_a_receiver_whose_gripper_meets_the_scene_at_the_transfer_pose_is_skipped():
    """At the transfer pose the receiver's open gripper, swept from its pre-grasp, keeps the task planner's
    contact margin from the rest of the scene (the pick's own checks leave the gripper against the map to the
    sampler, which samples the receivers in free space): a cluster of points floating where the hand-over
    above puts the receiver's palm makes the search skip that receiver and count it."""
    from grasping import Arm, PlanParams, plan_grasps, scene_cloud

    T12 = facing_T_b1_b2(0.6)
    P, L = make_cloud([Obj("box", (0.3, 0.2), (0.05, 0.05, 0.08), 0.3)], table_size=(0.8, 0.8))
    arms = {"primary": Arm("primary", np.eye(4), _Cone(10.0, (0.0, 5.0))),
            "secondary": Arm("secondary", T12, _Cone(8.0, (35.0, 45.0)))}
    params = PlanParams(retry_factor=1)
    op = plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12, params=params).objects[0]
    assert op.stats["handover"]["receiver_in_scene"] == 0
    R = op.handover.receiver["T_b1_g"]
    palm = R[:3, :3] @ np.array([0.0, 0.0, -0.07]) + R[:3, 3]
    blob = palm + np.random.default_rng(0).uniform(-0.01, 0.01, (200, 3))  # label -1: no object, in the air
    op2 = plan_grasps(scene_cloud(np.vstack([P, blob]), np.r_[L, np.full(len(blob), -1)]), arms=arms, T_b1_b2=T12,
                      params=params).objects[0]
    assert op2.stats["handover"]["receiver_in_scene"] > 0
    if op2.handover is not None:  # another receiver, or another transfer pose: its gripper clear of the blob
        from grasping import load_gripper
        from grasping._collision import points_in_gripper

        R2, w2 = op2.handover.receiver["T_b1_g"], op2.handover.receiver["width"]
        for back in np.linspace(0.0, 0.06, 7):  # at the grasp and on the way in from the pre-grasp
            T = R2.copy()
            T[:3, 3] -= back * R2[:3, 2]
            assert not points_in_gripper(load_gripper(), T, w2, blob).any()


class _GoalBlocked(_Cone):
    """A ``_Cone`` whose every configuration comes within the free-motion margin of the scene
    (``ArmReach.goal_problems``): its pre-grasps pass (the filter's own check), its free motions' goals not."""

    def goal_problems(self, q, width):
        return ["gripper_base touches the scene map"]


def test_a_transfer_the_givers_free_motion_cannot_end_at_is_skipped():
    """The carry's free motion ends with the giver at the transfer pose: where that configuration is within
    the planner's free-motion margin of the scene (``goal_problems``), the transfer pose is skipped and
    counted; the same arms without that check find the hand-over of the test above."""
    from grasping import Arm, PlanParams, plan_grasps, scene_cloud

    T12 = facing_T_b1_b2(0.6)
    P, L = make_cloud([Obj("box", (0.3, 0.2), (0.05, 0.05, 0.08), 0.3)], table_size=(0.8, 0.8))
    arms = {"primary": Arm("primary", np.eye(4), _GoalBlocked(10.0, (0.0, 5.0))),
            "secondary": Arm("secondary", T12, _GoalBlocked(8.0, (35.0, 45.0)))}
    op = plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12, params=PlanParams(retry_factor=1)).objects[0]
    assert op.handover is None  # (nor with the secondary giving: its goals are blocked too)
    st = op.stats["handover"]
    assert st["giver_goal_blocked"] > 0 and st["giver_reached"] == 0


def test_the_secondary_gives_where_the_primary_reaches_no_pick():
    """The primary reaches nothing on the table, only grasps in the air tilted 35-45 degrees down from its
    own side; the secondary reaches every grasp on the table and level ones from its side in the air: the
    secondary picks and gives, the primary receives, and grasps.json says which arm does what. With the
    primary as the only giver (``handover_givers``) there is no hand-over."""
    from grasping import Arm, PlanParams, plan_grasps, plan_to_dict, scene_cloud
    from grasping._plan import NO_HANDOVER

    T12 = facing_T_b1_b2(0.6)
    P, L = make_cloud([Obj("box", (0.3, 0.2), (0.05, 0.05, 0.08), 0.3)], table_size=(0.8, 0.8))
    giver, receiver = _Cone(10.0, (0.0, 5.0)), _Cone(8.0, (35.0, 45.0), table=False)
    arms = {"primary": Arm("primary", np.eye(4), receiver), "secondary": Arm("secondary", T12, giver)}
    plan = plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12, params=PlanParams(retry_factor=1))
    op = plan.objects[0]
    assert len(op.reach["primary"]) == 0 and len(op.reach["secondary"]) > 0
    h = op.handover
    assert h is not None, (op.notes, op.stats.get("handover"))
    assert h.giver_arm == "secondary" and h.receiver_arm == "primary" and op.stats["handover"]["giver_arm"] == "secondary"
    assert giver.ok((np.linalg.inv(T12) @ h.giver_T_b1_g)[None])[0]
    assert receiver.ok(h.receiver["T_b1_g"][None])[0]
    d = plan_to_dict(plan)["objects"][0]["handover"]
    assert d["giver"]["arm"] == "secondary" and d["receiver"]["arm"] == "primary"
    with pytest.raises(ValueError, match="handover_givers"):
        PlanParams(handover_givers=("primary", "left"))
    only_primary = PlanParams(retry_factor=1, handover_givers=("primary",))
    op1 = plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12, params=only_primary).objects[0]
    assert op1.handover is None and NO_HANDOVER not in op1.notes  # not searched: the primary reaches no pick


def test_transfer_places_run_from_the_givers_base():
    """A place ``f`` of the way along the line between the bases is measured from the giver's base: with the
    secondary giving, the places mirror those of the primary giving, and the line points the other way."""
    from types import SimpleNamespace

    from grasping import Arm, HandoverParams
    from grasping._handover import _roles, _transfer_targets

    T12 = facing_T_b1_b2(0.6)
    arms = {"primary": Arm("primary", np.eye(4), None), "secondary": Arm("secondary", T12, None)}
    geo = SimpleNamespace(centre=np.array([0.2, 0.3, 0.03]))
    support = SimpleNamespace(up=UP, height=-0.01)
    p = HandoverParams(fractions=(0.25,), offsets=(0.0,), heights=(0.2,), towards_object=())
    from_1, line_1 = _transfer_targets(geo, support, _roles(arms, "primary", None), p)
    from_2, line_2 = _transfer_targets(geo, support, _roles(arms, "secondary", None), p)
    assert np.allclose(from_1, [[0.15, 0.0, 0.19]]) and np.allclose(from_2, [[0.45, 0.0, 0.19]])
    assert np.allclose(line_1, [1.0, 0.0, 0.0]) and np.allclose(line_2, -line_1)


def test_receiver_order_prefers_pads_on_the_object():
    """Among receivers the secondary is as likely to reach and to catch, one whose contact lies deeper
    behind its fingertips (pads on the object, not on its edge) is checked first."""
    from grasping import Arm, HandoverParams, callable_filter
    from grasping._antipodal import GraspSet
    from grasping._handover import _receiver_order, _roles

    n = 3
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = 0.3
    free = GraspSet(0, T, np.full(n, 0.07), np.full(n, 0.05), np.array([0.0, 0.02, 0.004]), np.full(n, 0.6))
    every = callable_filter(lambda T: np.ones(len(T), bool))
    arms = {"primary": Arm("primary", np.eye(4), every), "secondary": Arm("secondary", facing_T_b1_b2(0.6), every)}
    order, catch, margin = _receiver_order(_roles(arms, "primary", None), T, free, np.arange(n), HandoverParams())
    assert list(order) == [1, 2, 0]
    assert np.allclose(margin, 0.01)


def test_alternatives_try_another_giver_grasp_first(monkeypatch):
    """A pick that does not hold the object fails every hand-over starting with it: after the first
    hand-over, the alternatives with a giver grasp not used yet come before other transfer poses of a used one."""
    import grasping._handover as gh

    def fake(giver_index, x):
        centre = np.array([x, 0.0, 0.2])
        T = np.eye(4)
        T[:3, 3] = centre
        return gh.Handover(T, centre, giver_index, np.eye(4), np.zeros(6), 0.05, {}, 0.02, 0.5)

    def search(order):
        def _search(*args):
            yield from (fake(g, 0.1 * k) for k, g in enumerate(order))
        return _search

    arms = {a: gh.Arm(a, np.eye(4), None) for a in ("primary", "secondary")}
    args = (None, None, [1, 1, 1], [1], arms, None, None)  # three givers
    monkeypatch.setattr(gh, "_search", search([0, 0, 1, 0, 2]))
    found, _ = gh.plan_handovers(*args, params=gh.HandoverParams(alternatives=3))
    assert [h.giver_index for h in found] == [0, 1, 2]
    monkeypatch.setattr(gh, "_search", search([0, 0, 0, 1]))
    found, _ = gh.plan_handovers(*args, params=gh.HandoverParams(alternatives=3))
    assert [h.giver_index for h in found] == [0, 1, 0]  # only two givers: then another pose of the first
    one_giver = (None, None, [1], *args[3:])  # no other giver to wait for: the search stops at n
    monkeypatch.setattr(gh, "_search", search([0, 0, 0, 1]))
    found, _ = gh.plan_handovers(*one_giver, params=gh.HandoverParams(alternatives=3))
    assert [h.giver_index for h in found] == [0, 0, 0]


def _givers(n: int):
    from grasping._antipodal import GraspSet
    from grasping._arms import ArmGrasps

    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = np.arange(n) * 0.01
    g = GraspSet(0, T, np.full(n, 0.05), np.full(n, 0.04), np.zeros(n), np.linspace(1.0, 0.5, n))
    q = np.tile(np.arange(n, dtype=float)[:, None], (1, 6))
    return ArmGrasps("primary", g, np.arange(10, 10 + n), q, q + 100.0, T.copy(), tried=n)


def test_picks_against_the_waiting_receiver_go_last_in_order():
    """The task's first move takes the giver to its pre-grasp with the receiver still at rest: picks whose
    arm meets it there (at the pre-grasp or the grasp) are tried after the others, each part in its order."""
    from grasping._handover import waiting_receiver_last

    givers, clear = _givers(5), [np.array([k]) for k in range(5)]
    rest = np.full(6, -1.0)
    calls = []

    def check(q1, w1, q2, w2):  # (primary, secondary): pick 1 meets it at its pre-grasp, pick 3 at its grasp
        calls.append((q1[0], q2[0], w2))
        bad = q1[0] in (101.0, 3.0)
        return (not bad, "primary gripper_base / secondary link8 collide" if bad else "")

    out, clear2, moved = waiting_receiver_last(givers, clear, rest, check, "primary")
    assert moved == 2
    assert out.index.tolist() == [10, 12, 14, 11, 13]
    assert [c[0] for c in clear2] == [0, 2, 4, 1, 3]
    assert np.allclose(out.q[:, 0], [0, 2, 4, 1, 3]) and np.allclose(out.q_pre[:, 0], [100, 102, 104, 101, 103])
    assert np.allclose(out.grasps.T_b1_g[:, 0, 3], [0.0, 0.02, 0.04, 0.01, 0.03])
    assert all(c[1] == -1.0 and c[2] == 0.0 for c in calls)  # against the receiver at rest, closed
    # the secondary giving: its configuration goes second in the check
    seen = []
    waiting_receiver_last(givers, clear, rest, lambda q1, w1, q2, w2: (seen.append(q2[0]) or True, ""), "secondary")
    assert set(seen) <= {float(k) for k in range(5)} | {100.0 + k for k in range(5)}


def test_the_grasp_stage_puts_a_pick_against_the_waiting_secondary_last():
    """On the Piper with the real arm-against-arm check: a pick whose configuration reaches over to the waiting
    secondary's shoulder goes after one clear of it."""
    from bimanual_app.robots import load_robot
    from grasping import load_gripper
    from grasping._arms import TwoArmCheck
    from grasping._handover import waiting_receiver_last

    robot = load_robot("piper")
    T_b1_b2 = facing_T_b1_b2(0.6)
    check = TwoArmCheck(robot, load_gripper("piper"), T_b1_b2)
    rest = robot.neutral()
    givers, clear = _givers(2), [np.array([0]), np.array([1])]
    reach_over = np.array([0.0, 2.6, -2.3, -1.5, 0.1, -1.3])  # the primary's link5 meets the secondary's link2
    near_home = robot.neutral()
    assert "secondary link2" in check(reach_over, 0.05, rest, 0.0)[1] and check(near_home, 0.05, rest, 0.0)[0]
    givers.q[:] = [reach_over, near_home]
    givers.q_pre[:] = [reach_over, near_home]
    out, _, moved = waiting_receiver_last(givers, clear, rest, check)
    assert moved == 1 and out.index.tolist() == [11, 10]
