"""Two-arm joint grasps (balanced, opposite sides, grippers apart) and hand-overs (fingers apart)."""

from dataclasses import replace

import numpy as np
import pytest
from _grasp_fixtures import Obj, accept_all_arms, facing_T_b1_b2, make_cloud

from grasping import GripperCollider, PlanParams, grippers_distance, load_gripper, plan_grasps, scene_cloud

T12 = facing_T_b1_b2(0.6)


@pytest.fixture(scope="module")
def large_plan():
    objs = [Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.1),  # 0: needs two arms (wider than the stroke)
            Obj("box", (0.3, 0.27), (0.30, 0.04, 0.05), 0.0)]  # 1: a long bar: pinch it at both ends
    P, L = make_cloud(objs, table_size=(0.8, 0.8))
    return plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12,
                       params=PlanParams(handover=False, retry_factor=1))


def _centres(op, pair):
    p_ag, s_ag = op.pair_grasps(pair)
    out = []
    for ag, i in ((p_ag, pair.i_primary), (s_ag, pair.i_secondary)):
        g = ag.grasps
        out.append(g.extra["contact"][i] if "contact" in g.extra else g.T_b1_g[i, :3, 3] - g.T_b1_g[i, :3, 2] * g.depth[i])
    return out


def test_push_pair_balanced_on_opposite_faces(large_plan):
    op = large_plan.objects[0]
    assert op.mode == "joint" and op.joint, op.notes
    g = load_gripper()
    col = GripperCollider(g)
    for pair in op.joint:
        assert pair.kind == "push"
        p_ag, s_ag = op.pair_grasps(pair)
        sq1, sq2 = p_ag.grasps.extra["squeeze"][pair.i_primary], s_ag.grasps.extra["squeeze"][pair.i_secondary]
        assert sq1 @ sq2 < -0.99  # squeezing towards each other
        c1, c2 = _centres(op, pair)
        mid = 0.5 * (c1 + c2)
        d = (c2 - c1)[:2] / np.linalg.norm((c2 - c1)[:2])
        lateral = np.linalg.norm((mid - op.geometry.centre)[:2] - ((mid - op.geometry.centre)[:2] @ d) * d)
        assert lateral < 0.01 and pair.imbalance <= 0.25  # the squeeze line passes by the centre
        assert abs(c1[2] - c2[2]) <= 0.015  # at one height
        assert c1[2] > op.geometry.centre[2] - 1e-3  # at or above the centre: it hangs below the squeeze
        assert grippers_distance(col, p_ag.grasps.T_b1_g[pair.i_primary], p_ag.grasps.width[pair.i_primary],
                                 s_ag.grasps.T_b1_g[pair.i_secondary], s_ag.grasps.width[pair.i_secondary]) > 0.02


def test_pinch_pair_at_both_ends_of_a_long_bar(large_plan):
    op = large_plan.objects[1]
    assert op.mode == "joint"  # 30 cm long
    pinch = [p for p in op.joint if p.kind == "pinch"]
    assert pinch, op.stats.get("joint_pinch")
    g = load_gripper()
    col = GripperCollider(g)
    axis = op.geometry.T_b1_box[:3, 0]
    for pair in pinch:
        c1, c2 = _centres(op, pair)
        s1, s2 = (c1 - op.geometry.centre) @ axis, (c2 - op.geometry.centre) @ axis
        assert s1 * s2 < 0  # opposite sides of the centre
        assert abs(s1 + s2) <= 0.25 * 0.5 * abs(s1 - s2) + 1e-9  # balanced
        p_ag, s_ag = op.pair_grasps(pair)
        assert grippers_distance(col, p_ag.grasps.T_b1_g[pair.i_primary], p_ag.grasps.width[pair.i_primary],
                                 s_ag.grasps.T_b1_g[pair.i_secondary], s_ag.grasps.width[pair.i_secondary]) > 0.02


def test_handover_fingers_apart():
    P, L = make_cloud([Obj("cylinder", (0.3, 0.2), (0.05, 0.05, 0.11))])
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12,
                       params=PlanParams(retry_factor=1))
    op = plan.objects[0]
    h = op.handover
    assert op.mode == "single" and h is not None, op.notes
    g = load_gripper()
    col = GripperCollider(g)
    # the giver holds the object where it picked it: its grasp moved with the object
    G_pick = h.givers.grasps.T_b1_g[h.giver_index]
    moved = h.T_move @ G_pick
    flipped = moved @ np.diag([-1.0, -1.0, 1.0, 1.0])
    assert np.allclose(h.giver_T_b1_g, moved, atol=1e-9) or np.allclose(h.giver_T_b1_g, flipped, atol=1e-9)
    # the transfer pose is up in the air, between the bases
    assert h.centre[2] > 0.15 and 0.1 < h.centre[0] < 0.5
    # the two grippers (giver closed on the object, receiver closed too) keep apart
    assert h.gap >= 0.015 - 1e-6
    assert grippers_distance(col, h.giver_T_b1_g, h.giver_width, h.receiver["T_b1_g"], h.receiver["contact_width"]) >= 0.0149
    # the receiver grasps the moved object: its contact centre lies inside the object's moved box
    R = h.receiver["T_b1_g"]
    c = R[:3, 3] - R[:3, 2] * h.receiver["depth"]
    rel = h.T_move[:3, :3].T @ (c - h.centre)
    box = op.geometry.T_b1_box[:3, :3].T @ rel
    assert np.all(np.abs(box) <= op.geometry.extent / 2 + 0.005)



def test_handover_alternatives_differ_from_the_best_and_are_written():
    """Besides the best hand-over, the grasping stage keeps alternatives (another giver grasp or a transfer
    pose at least 4 cm / 30 degrees away), each as feasible as the first, and writes them to grasps.json."""
    from grasping import plan_to_dict
    from grasping._handover import _distinct

    P, L = make_cloud([Obj("cylinder", (0.3, 0.2), (0.05, 0.05, 0.11))])
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=PlanParams(retry_factor=1))
    op = plan.objects[0]
    alts = op.handover_alternatives
    assert op.handover is not None and 1 <= len(alts) <= plan.params.handover_params.alternatives - 1
    col = GripperCollider(load_gripper())
    for k, h in enumerate(alts):
        assert _distinct(h, [op.handover, *alts[:k]])
        assert h.gap >= plan.params.handover_params.gap - 1e-6
        assert grippers_distance(col, h.giver_T_b1_g, h.giver_width, h.receiver["T_b1_g"],
                                 h.receiver["contact_width"]) >= plan.params.handover_params.gap - 1e-4
        assert h.centre[2] - op.geometry.centre[2] >= plan.params.handover_params.min_rise - 1e-6
    o = plan_to_dict(plan)["objects"][0]
    assert o["handover"] is not None and len(o["handover_alternatives"]) == len(alts)
    assert np.allclose(o["handover_alternatives"][0]["T_move"], alts[0].T_move)

def test_handover_giver_leaves_the_receiver_room():
    """The giver is not the best single-arm pick (centred, deep): of the pick grasps, the first giver tried
    is one that leaves the most free-space receiver grasps clear of its fingers."""
    from grasping._handover import _clear_receivers, release_width

    P, L = make_cloud([Obj("box", (0.3, 0.2), (0.05, 0.06, 0.07), 0.3)])
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=PlanParams(retry_factor=1))
    op = plan.objects[0]
    assert op.handover is not None, op.notes
    col = GripperCollider(load_gripper())
    gap = plan.params.handover_params.gap
    # the giver lets go opening its release width (it may have picked wider)
    picks = op.giver_picks  # the picks, then the shallow holds sampled for the giver
    assert len(picks) >= len(op.grasps) and np.allclose(picks.T_b1_g[: len(op.grasps)], op.grasps.T_b1_g)
    w_rel = release_width(picks.width, picks.contact_width, plan.params.handover_params)
    assert np.all(w_rel <= picks.width + 1e-12)
    n = np.array([len(_clear_receivers(col, picks.T_b1_g[i], w_rel[i], picks.contact_width[i],
                                       op.free_grasps, gap)) for i in range(len(picks))])
    givers = op.handover.givers
    assert len(givers) and np.all(n[givers.index] > 0)
    cap = plan.params.handover_params.enough_clear
    assert min(n[givers.index[0]], cap) == min(n.max(), cap)
    assert op.handover.tried["clear_receivers"] > 0
    # the receiver's grasp is one of those the giver leaves clear
    gi = givers.index[op.handover.giver_index]
    assert op.handover.receiver["index"] in _clear_receivers(col, picks.T_b1_g[gi], w_rel[gi], picks.contact_width[gi],
                                                             op.free_grasps, gap)
    # and the object rises at least min_rise above where it lay
    assert op.handover.centre[2] - op.geometry.centre[2] >= plan.params.handover_params.min_rise - 1e-6


def test_handover_giver_may_hold_the_object_shallow(monkeypatch):
    """The picks go as deep as the fingers fit. Held shallower (the same sampler at ``shallow_depths`` of the
    finger length), a can leaves the receiver more grasps clear of the giver's fingers; when the picks give
    no hand-over, the search is run again with those shallow holds among the givers."""
    import grasping._plan as gplan
    from grasping import HandoverParams, SceneOctree, estimate_support, sample_grasps
    from grasping._handover import _clear_receivers, release_width

    P, L = make_cloud([Obj("cylinder", (0.3, 0.2), (0.05, 0.05, 0.10))])
    hp = HandoverParams()
    params = PlanParams(retry_factor=1)
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=params)
    op = plan.objects[0]
    assert op.handover is not None and len(op.giver_picks) == len(op.grasps)  # found with the picks alone
    flen = load_gripper().finger_length
    shallow, _ = sample_grasps(op.geometry, estimate_support(P, L), load_gripper(), GripperCollider(load_gripper()),
                               SceneOctree(P[L < 0], params.octree_resolution),
                               replace(params.sampler, depths=hp.shallow_depths))
    assert len(shallow) and np.all(shallow.depth <= max(hp.shallow_depths) * flen + 1e-9)
    assert op.grasps.depth.max() > max(hp.shallow_depths) * flen  # the picks: deeper where they fit
    col = GripperCollider(load_gripper())

    def clear_from_above(gs):
        w_rel = release_width(gs.width, gs.contact_width, hp)
        return max(len(_clear_receivers(col, gs.T_b1_g[i], w_rel[i], gs.contact_width[i], op.free_grasps, hp.gap))
                   for i in np.flatnonzero(gs.T_b1_g[:, 2, 2] < -0.9))  # held from above

    assert clear_from_above(shallow) > clear_from_above(op.grasps)

    # where the picks give no hand-over (here: the first search is made to find none), the search runs again
    # with the shallow holds as the givers
    real, calls = gplan.plan_handovers, []

    def none_first(geo, support, givers, *args, **kw):
        found, stats = real(geo, support, givers, *args, **kw)
        calls.append(givers.grasps.depth.copy())
        return (found if len(calls) > 1 else []), stats

    monkeypatch.setattr(gplan, "plan_handovers", none_first)
    plan2 = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=params)
    op2 = plan2.objects[0]
    n_shallow = op2.stats["handover"]["shallow_picks"]
    assert len(calls) == 2 and n_shallow > 0 and len(op2.giver_picks) == len(op2.grasps) + n_shallow
    assert np.all(calls[1] <= max(hp.shallow_depths) * flen + 1e-9)  # the givers of the second search: shallow
    h = op2.handover
    assert h is not None and h.givers.grasps.depth[h.giver_index] <= max(hp.shallow_depths) * flen + 1e-9
    gi = h.givers.index[h.giver_index]  # points past the picks, at the shallow hold it is
    assert gi >= len(op2.grasps) and np.allclose(op2.giver_picks.T_b1_g[gi][:3, 3], h.givers.grasps.T_b1_g[h.giver_index][:3, 3])
    from grasping import plan_to_dict

    assert plan_to_dict(plan2)["objects"][0]["handover"]["giver"]["grasp_rank"] is None  # not one of the picks


def test_handover_grasps_are_drawn_again_when_no_draw_gave_one(monkeypatch):
    """When neither the picks nor the shallow holds give a hand-over, both grasp sets are drawn again with
    other seeds and searched; a hand-over from that draw points at its own giver; with none found, the plan
    keeps the first draws and says that it tried."""
    import grasping._plan as gplan
    from grasping import HandoverParams, plan_to_dict

    P, L = make_cloud([Obj("cylinder", (0.3, 0.2), (0.05, 0.05, 0.10))])
    params = PlanParams(retry_factor=1, handover_givers=("primary",))  # the primary's draws only
    real, calls = gplan.plan_handovers, []

    def none_until(n):
        def search(geo, support, givers, free, *args, **kw):
            found, stats = real(geo, support, givers, free, *args, **kw)
            calls.append((givers.grasps.T_b1_g.copy(), free.T_b1_g.copy()))
            return (found if len(calls) > n else []), stats
        return search

    monkeypatch.setattr(gplan, "plan_handovers", none_until(2))  # the picks, then the shallow holds: none
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=params)
    op = plan.objects[0]
    assert len(calls) == 3 and op.stats["handover"]["redraw"] == 1
    assert not np.array_equal(calls[2][1], calls[0][1])  # the receivers drawn again
    assert not any(np.array_equal(calls[2][0], c[0]) for c in calls[:2])  # and the givers
    h = op.handover
    assert h is not None and np.array_equal(op.free_grasps.T_b1_g, calls[2][1])
    gi = h.givers.index[h.giver_index]  # past the picks, at the redrawn giver it is
    assert gi >= len(op.grasps) and np.allclose(op.giver_picks.T_b1_g[gi], h.givers.grasps.T_b1_g[h.giver_index])
    assert plan_to_dict(plan)["objects"][0]["handover"]["giver"]["grasp_rank"] is None  # not one of the picks

    calls.clear()
    monkeypatch.setattr(gplan, "plan_handovers", none_until(99))
    op = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=params).objects[0]
    assert op.handover is None and len(calls) == 2 + HandoverParams().redraws
    assert op.stats["handover"]["redraws_tried"] == HandoverParams().redraws
    assert np.array_equal(op.free_grasps.T_b1_g, calls[0][1])  # the first draw kept


def test_handover_grasps_are_drawn_again_only_where_no_object_has_a_hand_over():
    from types import SimpleNamespace

    from grasping._plan import NO_HANDOVER, ObjectPlan, _redraw_where_none

    calls = []
    by_primary = SimpleNamespace(giver_arm="primary")
    found = ObjectPlan(0, None, "single", handover=by_primary)
    none = ObjectPlan(1, None, "single", notes=[NO_HANDOVER], redraws={"primary": lambda: calls.append(1) or [by_primary]})
    _redraw_where_none([found, none])
    assert not calls and none.handover is None  # the scene has one: no draws
    found.handover = None
    _redraw_where_none([found, none])
    assert calls == [1] and none.handover is by_primary and NO_HANDOVER not in none.notes
    assert "handover_redraw" in none.timings


def test_handover_redraws_go_giver_by_giver():
    """A hand-over from the secondary does not stop the primary's draws (the primary gives by preference):
    one found replaces it, none found keeps it; the secondary draws again only where no object has any."""
    from types import SimpleNamespace

    from grasping._plan import ObjectPlan, _redraw_where_none

    calls = []
    by_primary, by_secondary = SimpleNamespace(giver_arm="primary"), SimpleNamespace(giver_arm="secondary")

    def draw(name, result):
        return lambda: calls.append(name) or result

    a = ObjectPlan(0, None, "single", handover=by_secondary, redraws={"primary": draw("a1", [])})
    b = ObjectPlan(1, None, "single", redraws={"primary": draw("b1", []), "secondary": draw("b2", [by_secondary])})
    _redraw_where_none([a, b])
    assert calls == ["a1", "b1"] and a.handover is by_secondary and b.handover is None
    calls.clear()
    a.redraws["primary"] = draw("a1", [by_primary])
    _redraw_where_none([a, b])
    assert calls == ["a1", "b1"] and a.handover is by_primary  # found by the primary's draw: replaces the other
    calls.clear()
    a.handover, a.redraws = None, {}
    _redraw_where_none([a, b])
    assert calls == ["b1", "b2"] and b.handover is by_secondary


def test_handover_transfer_pose_keeps_the_object_clear_of_the_scene():
    """A tall box stands right where the transfer pose would be by preference (above the middle of the
    line between the bases): the hand-over moves the object elsewhere, clear of it by the clearance."""
    from scipy.spatial import cKDTree

    P, L = make_cloud([Obj("cylinder", (0.3, 0.2), (0.05, 0.05, 0.11)),
                       Obj("box", (0.3, 0.0), (0.12, 0.12, 0.30), 0.0)], table_size=(0.8, 0.8))
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=PlanParams(retry_factor=1),
                       objects=[0])
    op = plan.objects[0]
    h = op.handover
    assert h is not None, op.notes
    assert h.tried["object_in_scene"] > 0  # the preferred poses were refused
    moved = P[L == 0] @ h.T_move[:3, :3].T + h.T_move[:3, 3]
    d, _ = cKDTree(P[L != 0]).query(moved)
    assert d.min() >= plan.params.handover_params.object_clearance - 0.005  # (the check uses the closed geometry)


def test_push_contacts_can_be_reached_from_straight_above():
    """Each push contact has three ways in (along the face normal, back along its approach, straight down
    from above), each kept only where its sweep is free; an arm that can come in only from above still
    gets contacts, and the way it used is the one recorded."""
    from grasping import Arm, ReachResult, reachable_grasps

    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.1)], table_size=(0.8, 0.8))
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12,
                       params=PlanParams(handover=False, retry_factor=1))
    op = plan.objects[0]
    push = op.push
    R = push.extra["retreats"]
    assert R.shape == (len(push), 3, 3)
    up = np.array([0.0, 0.0, 1.0])
    finite = np.isfinite(R[:, 2]).all(axis=1)
    assert finite.any() and np.allclose(R[finite, 2], up)

    def from_above_only(T_b_g, width=None, retreat=None, hold_off=None):
        n = len(T_b_g)
        ok = np.zeros(n, bool) if retreat is None else np.asarray(retreat)[:, 2] > 0.99
        return ReachResult(ok, np.zeros((n, 6)), np.zeros((n, 6)), np.zeros(n, bool), [""] * n)

    ag = reachable_grasps(push, Arm("primary", np.eye(4), from_above_only), max_tries=len(push), want=5)
    assert len(ag) >= 5  # (checked in batches of 8)
    assert np.allclose(ag.grasps.extra["retreat"], up)


def test_catch_probability_and_the_calibration_uncertainty_it_uses():
    from grasping import b2b_sigma
    from grasping._handover import catch_probability

    p = catch_probability(np.array([0.0, 0.005, 0.0196, 0.05]), 0.01)
    assert p[0] == 0.0 and 0.35 < p[1] < 0.40 and abs(p[2] - 0.95) < 0.002 and p[3] > 0.999
    assert np.all(np.diff(p) > 0)
    cal = {"uncertainty": {"T_b1_b2": {"translation_mm": [3.0, 4.0, 12.0], "rotation_axes_deg": [1.0, 1.0, 1.0]}}}
    st, sr = b2b_sigma(cal)
    assert abs(st - np.sqrt((9 + 16 + 144) / 3) * 1e-3) < 1e-12 and abs(sr - np.deg2rad(1.0)) < 1e-12
    assert b2b_sigma({}) is None and b2b_sigma({"uncertainty": {"T_b1_b2": {"translation_mm": "x"}}}) is None


def test_handover_receiver_closes_across_the_side_that_leaves_it_most_margin():
    """A 3 x 5.5 x 6 cm box: the receiver may close across 3 cm (2 cm of opening to spare on each side) or
    5.5 cm (under 1 cm): with the calibration error it is far likelier to catch across the narrow side."""
    P, L = make_cloud([Obj("box", (0.3, 0.1), (0.03, 0.055, 0.06), 0.0)])
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=PlanParams(retry_factor=1))
    h = plan.objects[0].handover
    assert h is not None, plan.objects[0].notes
    assert h.receiver["contact_width"] < 0.04 and h.margin > 0.015 and h.catch > 0.9
    assert abs(h.margin - 0.5 * (h.receiver["width"] - h.receiver["contact_width"])) < 1e-9
    p = plan.params.handover_params
    d = np.linalg.norm(h.receiver["T_b1_g"][:3, 3] - T12[:3, 3])
    assert abs(h.sigma - np.hypot(p.b2b_sigma_m, p.b2b_sigma_rad * d)) < 1e-9


def test_spread_order_puts_other_places_before_near_copies():
    from grasping._joint import spread_order

    # best first: a cluster of three within 1 cm on face A, one 5 cm away on A, one on face B
    P = np.array([[0.0, 0.0, 0.0], [0.005, 0.0, 0.0], [0.0, 0.008, 0.0], [0.05, 0.0, 0.0], [0.0, 0.0, 0.0]])
    faces = np.array([[0, 1], [0, 1], [0, 1], [0, 1], [1, -1]])
    assert spread_order(P, faces, 0.03).tolist() == [0, 3, 4, 1, 2]
    assert spread_order(P, faces, 0.0).tolist() == [0, 1, 2, 3, 4]


def test_joint_pairs_list_other_places_before_near_copies(large_plan):
    """After the best push pair come pairs whose contacts are elsewhere on the faces (when the arms reach
    such contacts), before near copies of pairs already listed."""
    op = large_plan.objects[0]
    pairs = [p for p in op.joint if p.kind == "push"]
    assert len(pairs) >= 2

    def contacts(pair):
        a, b = op.pair_grasps(pair)
        return a.grasps.extra["contact"][pair.i_primary], b.grasps.extra["contact"][pair.i_secondary]

    (a0, b0), (a1, b1) = contacts(pairs[0]), contacts(pairs[1])
    assert max(np.linalg.norm(a1 - a0), np.linalg.norm(b1 - b0)) >= 0.03, "the second pair holds where the first does"
    assert pairs[0].score == max(p.score for p in pairs)


def test_push_contacts_are_clear_of_the_scene_where_the_task_moves_them():
    """The task's straight moves end at the push contact (the approach) and ``press`` past it (the squeeze),
    checked against its map (the scene without what lies within 1.5 cm of the object) with its contact
    margin: every push contact is clear of that map at both, beside a neighbour 2 cm from one face."""
    from grasping import PushParams, SceneOctree, estimate_support, object_geometry, push_contacts

    objs = [Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.0),
            Obj("box", (0.3 + 0.08 + 0.02 + 0.02, 0.05), (0.04, 0.04, 0.06), 0.0)]  # 2 cm off the +x face
    P, L = make_cloud(objs, table_size=(0.8, 0.8))
    sup = estimate_support(P, L)
    geo = object_geometry(0, P[L == 0], sup, background=P[L < 0])
    g = load_gripper()
    col = GripperCollider(g)
    others = SceneOctree(P[L != 0], PlanParams().octree_resolution)
    pp = PushParams()
    push = push_contacts(geo, sup, g, col, others, pp)
    assert len(push) > 20
    pressed = push.T_b1_g.copy()
    pressed[:, :3, 3] += pp.press * push.extra["squeeze"]
    # the task's map for its moves in contact: the scene without what lies within its cut radius of the
    # object, at its resolution, with its contact margin
    import inspect

    from scipy.spatial import cKDTree

    from bimanual_app.tasks._motion import CONTACT_MARGIN, MAP_RESOLUTION, TaskMotion

    cut_radius = inspect.signature(TaskMotion.__init__).parameters["cut_radius"].default
    rest = P[L != 0]
    cut = SceneOctree(rest[cKDTree(P[L == 0]).query(rest)[0] > cut_radius], MAP_RESOLUTION)
    for T in (push.T_b1_g, pressed):
        assert not col.collides(cut, T, push.width, swept=False, margin=CONTACT_MARGIN).any()


def _push_faces(P, L):
    """Push contacts on object 0 of the cloud: (contacts, stats, the box's axes)."""
    from grasping import PushParams, SceneOctree, estimate_support, object_geometry, push_contacts

    sup = estimate_support(P, L)
    geo = object_geometry(0, P[L == 0], sup, background=P[L < 0])
    g = load_gripper()
    stats: dict = {}
    push = push_contacts(geo, sup, g, GripperCollider(g), SceneOctree(P[L != 0], PlanParams().octree_resolution),
                         PushParams(), stats)
    return push, stats, geo


def test_a_face_only_filled_in_is_pushed_only_where_the_scene_beyond_it_was_seen():
    """A carton seen over part of its length ends, in the cloud, where the views end: the face there was
    never seen and nothing was seen beyond it, so no push lands on it (the real box goes on). A far face
    hidden from the cameras by the box itself, with the table seen beyond it, is still pushed."""
    box = Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.0)
    P, L = make_cloud([box], table_size=(0.8, 0.8))
    # the views end at y = -0.05: nothing of the box or of the table beyond it was seen
    cut = P[:, 1] > -0.05
    push, stats, geo = _push_faces(P[cut], L[cut])
    assert stats["unseen_beyond"] == 1
    out = -np.sign(push.extra["squeeze"][:, 1])  # the pushed face's outward normal along y
    assert len(push) and not np.any((out < 0) & (np.abs(push.extra["squeeze"][:, 1]) > 0.9))
    # the box's -y face (y = -0.16) not seen, the table beyond it seen: pushed from the completed face
    hidden = (L == 0) & (P[:, 1] < -0.16 + 0.004)
    push, stats, _ = _push_faces(P[~hidden], L[~hidden])
    assert stats["unseen_beyond"] == 0
    assert np.any(push.extra["squeeze"][:, 1] > 0.9)  # pressing the hidden face towards +y


def test_open_ends_name_the_end_the_views_stopped_at():
    """The end of a carton where the views stopped (no point of its face, nothing seen beyond it) is open; a far
    face hidden by the box itself, with the table seen beyond it, is not."""
    from grasping import PushParams, SceneOctree, estimate_support, object_geometry
    from grasping._push import open_ends

    box = Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.0)
    P, L = make_cloud([box], table_size=(0.8, 0.8))

    def ends(keep):
        sup = estimate_support(P[keep], L[keep])
        geo = object_geometry(0, P[keep & (L == 0)], sup, background=P[keep & (L < 0)])
        return open_ends(geo, SceneOctree(P[keep & (L != 0)], PlanParams().octree_resolution), PushParams())

    cut = ends(P[:, 1] > -0.05)  # the views end at y = -0.05
    assert len(cut) == 1 and cut[0][1] < -0.99
    hidden = (L == 0) & (P[:, 1] < -0.16 + 0.004)  # the -y face unseen, the table beyond it seen
    assert ends(~hidden) == []
    assert ends(np.ones(len(P), bool)) == []


def test_a_squeeze_of_a_carton_cut_short_is_balanced_about_where_its_centre_may_be():
    """A carton seen over part of its length (its far end out of view) has its seen box's centre short of the
    real one: a squeeze across it may be balanced about any place of the centre up to ``open_end_shift`` of
    the seen length towards the open end, and about none beyond; 0 keeps the seen centre only."""
    from grasping._joint import _nearest_centre

    c, span = np.zeros(3), np.array([0.0, -0.05, 0.0])
    assert np.allclose(_nearest_centre(c, span, np.array([0.1, -0.03, 0.0])), [0.0, -0.03, 0.0])
    assert np.allclose(_nearest_centre(c, span, np.array([0.1, -0.09, 0.0])), [0.0, -0.05, 0.0])
    assert np.allclose(_nearest_centre(c, span, np.array([0.1, 0.02, 0.0])), c)  # never away from the open end
    assert np.allclose(_nearest_centre(c, None, np.array([0.1, -0.03, 0.0])), c)

    box = Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.0)
    P, L = make_cloud([box], table_size=(0.8, 0.8))
    cut = P[:, 1] > -0.05  # seen from y = -0.05 to 0.16: the seen box's centre at y = 0.055
    plans = {}
    for shift in (0.0, 0.25):
        params = PlanParams(handover=False, retry_factor=1, open_end_shift=shift)
        plans[shift] = plan_grasps(scene_cloud(P[cut], L[cut]), arms=accept_all_arms(T12), T_b1_b2=T12,
                                   params=params).objects[0]
    seen_y = plans[0.0].geometry.centre[1]
    assert 0.04 < seen_y < 0.07
    # the user is told which end was not seen (the grasp stage's problems list it when no pair is found)
    assert any("-1.00) in b1 was not seen" in n for n in plans[0.25].notes), plans[0.25].notes
    assert plans[0.25].stats["joint_push"]["balanced"] > plans[0.0].stats["joint_push"]["balanced"]
    for shift, op in plans.items():
        lowest = seen_y - shift * plans[0.0].geometry.extent[0]  # the farthest the centre may be towards -y
        for pair in op.joint:
            mid = 0.5 * sum(_centres(op, pair))
            off = max(0.0, lowest - mid[1], mid[1] - seen_y)  # from the nearest place the centre may be
            assert off <= 0.25 * 0.5 * pair.separation + 1e-6


def test_steep_push_contacts_lean_about_the_face_normal():
    """A steep gripper (fingers hanging beside the face) also comes leaned about the face normal: its
    approach turned along the face, the pad still flat on it. An arm beside the face rather than in front
    of it carries such a contact up; the plain tilts and swivels all keep the approach in the vertical
    plane of the face normal there."""
    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.0)], table_size=(0.8, 0.8))
    push, _, geo = _push_faces(P, L)
    n = -push.extra["squeeze"]  # outward face normals
    z = push.T_b1_g[:, :3, 2]
    up = np.array([0.0, 0.0, 1.0])
    t = np.cross(up, n)
    steep = -(z @ up) > np.cos(np.deg2rad(45))
    along_face = np.abs(np.einsum("ij,ij->i", z, t))
    assert np.any(steep & (along_face > np.sin(np.deg2rad(20))))


def test_push_contacts_pressed_past_a_short_face_stay_off_the_top():
    """A carton's face in the cloud misses its last millimetres (the real face is ``face_shortfall``
    further out), so the task's squeeze drives the fingers ``press + face_shortfall`` into the real box.
    No gripper part of a kept push contact is then on the box's top face; on a low carton some contacts
    (steep fingers with their tips high on the face) are refused for it and counted."""
    from grasping import PushParams

    box = Obj("box", (0.3, 0.0), (0.16, 0.32, 0.06), 0.0)
    P, L = make_cloud([box], table_size=(0.8, 0.8))
    push, stats, geo = _push_faces(P, L)
    assert stats["on_top_edge"] > 0 and len(push) > 20
    pp = PushParams()
    deep = push.T_b1_g.copy()
    deep[:, :3, 3] += (pp.press + pp.face_shortfall) * push.extra["squeeze"]
    g = load_gripper()
    from grasping import SceneOctree

    top = P[(L == 0) & (P[:, 2] > 0.06 - 1e-6)]
    # the top inside the faces (a finger beside the face, pressed in, may pass over its very edge)
    inner = top[(np.abs(top[:, 0] - 0.3) < 0.08 - 0.008) & (np.abs(top[:, 1]) < 0.16 - 0.008)]
    assert not GripperCollider(g).collides(SceneOctree(inner, 0.002), deep, push.width, swept=False).any()


def test_push_contacts_clear_of_the_top_at_the_tasks_squeeze_depth_come_first():
    """The task squeezes ``squeeze_margin`` deeper than ``press`` (its ``PUSH_PRESS_MARGIN``); a steep finger
    pressing high on a low carton's face then lies on its top edge once the real face is further out. Such
    contacts are kept (an arm may reach nothing else) but come after those clear of the top that deep
    (``extra["clears_top"]``), whose reach is checked first; a pair with one of them comes after every pair
    without (``_joint._push_terms``' tier)."""
    from bimanual_app.tasks._planners import PUSH_PRESS_MARGIN
    from grasping import PushParams, SceneOctree
    from grasping._joint import _push_terms

    pp = PushParams()
    assert pp.squeeze_margin == PUSH_PRESS_MARGIN  # the depth the task squeezes to
    box = Obj("box", (0.3, 0.0), (0.16, 0.32, 0.06), 0.0)
    P, L = make_cloud([box], table_size=(0.8, 0.8))
    push, _, _ = _push_faces(P, L)
    clears = push.extra["clears_top"]
    assert clears.any() and not clears.all()
    first_not = int(np.argmin(clears))
    assert clears[:first_not].all() and not clears[first_not:].any()  # the clear ones first, then the rest
    # those not clear: pressed that deep, some gripper part is on the top face inside the faces
    deep = push.T_b1_g.copy()
    deep[:, :3, 3] += (pp.press + pp.squeeze_margin + pp.face_shortfall) * push.extra["squeeze"]
    top = P[(L == 0) & (P[:, 2] > 0.06 - 1e-6)]
    inner = top[(np.abs(top[:, 0] - 0.3) < 0.08 - 0.008) & (np.abs(top[:, 1]) < 0.16 - 0.008)]
    g = load_gripper()
    hit = GripperCollider(g).collides(SceneOctree(inner, 0.002), deep, push.width, swept=False)
    assert not hit[clears].any() and hit[~clears].mean() > 0.5

    class _Arm:  # ArmGrasps' fields _push_terms reads
        def __init__(self, gs):
            self.grasps = gs

    face = push.extra["face"]
    i = int(np.flatnonzero(clears & (face[:, 0] == 0) & (face[:, 1] > 0))[0])
    j_ok = np.flatnonzero(clears & (face[:, 0] == 0) & (face[:, 1] < 0))
    j_bad = np.flatnonzero(~clears & (face[:, 0] == 0) & (face[:, 1] < 0))
    assert len(j_ok) and len(j_bad)
    c = push.extra["contact"]
    up = np.array([0.0, 0.0, 1.0])

    def tier(j):
        d = (c[j] - c[i]) * np.array([1.0, 1.0, 0.0])
        sep = float(np.linalg.norm(d))
        out = _push_terms(_Arm(push), _Arm(push), i, j, c, c, up, d, sep, np.zeros(3), 1.0)
        return None if out is None else out[2]

    tiers_ok = {tier(j) for j in j_ok} - {None}
    tiers_bad = {tier(j) for j in j_bad} - {None}
    assert tiers_ok and tiers_bad and max(tiers_ok) < 2 <= min(tiers_bad)


class _PriorReach:
    """A reach filter that accepts every grasp and predicts reach by the distance from a point (a ``prior``
    without ``prior_min``, so the hand-over ranks with its generic fallback)."""

    def __init__(self, centre):
        from grasping import callable_filter

        self.centre = np.asarray(centre, dtype=float)
        self._accept = callable_filter(lambda T: np.ones(len(T), dtype=bool))

    def __call__(self, T_b_g, width=None, retreat=None, hold_off=None):
        return self._accept(T_b_g, width, retreat, hold_off)

    def prior(self, T_b_g):
        return 0.4 * np.linalg.norm(np.asarray(T_b_g)[:, :3, 3] - self.centre, axis=1)


def test_handover_ranking_scored_lazily_keeps_the_order_of_scoring_everything(monkeypatch):
    """The hand-over's transfer poses are scored chunk by chunk, in order of the giver's prior (a bound on
    their cost); the candidates come out in the same order whatever the chunk, the order of scoring all of
    them first (a chunk larger than every pose), sorted by cost bin and preference, and the search finds the
    same hand-over."""
    import grasping._handover as gh
    from grasping import Arm

    P, L = make_cloud([Obj("cylinder", (0.3, 0.2), (0.05, 0.05, 0.11)),
                       Obj("box", (0.3, 0.0), (0.12, 0.12, 0.30), 0.0)], table_size=(0.8, 0.8))
    arms = {"primary": Arm("primary", np.eye(4), _PriorReach([0.3, 0.15, 0.2])),
            "secondary": Arm("secondary", T12, _PriorReach([0.35, 0.05, 0.25]))}
    real = gh._ranked_transfers

    def handover(chunk, record=None):
        monkeypatch.setattr(gh, "RANK_CHUNK", chunk)
        if record is not None:  # every candidate, in the order yielded (the search then reads them from the list)
            def recorded(*args, **kw):
                items = list(real(*args, **kw))
                record.extend((gh._cost_key(c[0], c[1]), c[2], c[3].tobytes()) for c in items)
                return iter(items)

            monkeypatch.setattr(gh, "_ranked_transfers", recorded)
        plan = plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12, params=PlanParams(retry_factor=1), objects=[0])
        monkeypatch.setattr(gh, "_ranked_transfers", real)
        h = plan.objects[0].handover
        assert h is not None, plan.objects[0].notes
        return h.giver_index, h.T_move.tobytes()

    orders = {chunk: [] for chunk in (10 ** 9, 1, 7)}
    found = {chunk: handover(chunk, orders[chunk]) for chunk in orders}
    keys = [k for k, _, _ in orders[10 ** 9]]
    assert len(keys) > 20 and keys == sorted(keys) and len({k[0] for k in keys}) > 1  # several cost bins
    assert orders[1] == orders[7] == orders[10 ** 9]
    assert found[1] == found[7] == found[10 ** 9] == handover(1)  # read lazily by the search, too


@pytest.mark.parametrize("tries, found", [(30, False), (None, True)])
def test_push_contacts_an_arm_reaches_in_few_places_are_all_checked(tries, found):
    """An arm pushing the face of a large box a hand's width from its base reaches it only steeply tilted and
    high up (a few of a face's ~500 contacts, ranked low by the score). Every contact is checked for reach by
    default (``push_tries_per_face=None``), so the pair is found; with the first 30 of each face it is not."""
    from grasping import Arm, callable_filter

    def steep_and_high(T):  # tilted 55 degrees down, fingertips in the top part of the face
        tilt = np.degrees(np.arcsin(np.clip(-T[:, 2, 2], -1, 1)))
        return (np.abs(tilt - 55.0) < 1.0) & (T[:, 2, 3] > 0.08)

    f = callable_filter(steep_and_high)
    arms = {"primary": Arm("primary", np.eye(4), f), "secondary": Arm("secondary", T12, f)}
    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.1)], table_size=(0.8, 0.8))
    plan = plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12,
                       params=PlanParams(handover=False, retry_factor=1, push_tries_per_face=tries))
    op = plan.objects[0]
    assert op.mode == "joint"
    assert bool(op.joint) == found, op.notes


def test_aimed_swivels_point_the_approach_away_from_each_base():
    """A push approach aimed at a face from a base points horizontally straight away from that base; a base
    on the face's far side (more than ``max_angle`` off its normal) gets none, and a swivel already tried is
    not added again."""
    from grasping._push import aimed_swivels

    up = np.array([0.0, 0.0, 1.0])
    n = np.array([-1.0, 0.0, 0.0])  # the face looks back at the primary's base
    t = np.cross(up, n)
    contact = np.array([0.22, 0.06, 0.05])
    bases = np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 0.0]])
    sws = aimed_swivels(n, t, contact, bases, np.deg2rad(35.0))
    assert len(sws) == 1
    z_h = -(np.cos(sws[0]) * n + np.sin(sws[0]) * t)
    aim = (contact - bases[0])[:2] / np.linalg.norm((contact - bases[0])[:2])
    assert np.allclose(z_h[:2], aim, atol=1e-9) and abs(z_h[2]) < 1e-12
    assert aimed_swivels(n, t, contact, bases, np.deg2rad(35.0), known=(sws[0] + 0.01,)) == []


@pytest.mark.parametrize("aim_max, found", [(0.0, False), (np.deg2rad(35.0), True)])
def test_a_box_off_the_line_between_the_bases_is_squeezed_with_aimed_approaches(aim_max, found):
    """Arms that reach a face only with the approach pointing straight away from their base (as a Piper
    does a hand's width from its base), on a box 6 cm off the line between the bases: the faces' normals
    are 15 degrees off those directions, so the pair is found only with the approaches aimed away from
    each base, turned opposite ways (the squeeze stays along the faces' normals)."""
    from grasping import Arm, PushParams, callable_filter

    def radial(T):  # T_b_g (N, 4, 4) in the arm's base frame
        zh, ph = T[:, :2, 2], T[:, :2, 3]
        cos = np.einsum("nk,nk->n", zh, ph) / np.linalg.norm(zh, axis=1) / np.linalg.norm(ph, axis=1)
        tilt = np.degrees(np.arcsin(np.clip(-T[:, 2, 2], -1, 1)))
        return (cos > np.cos(np.deg2rad(3.0))) & (tilt > 30) & (tilt < 70)

    f = callable_filter(radial)
    arms = {"primary": Arm("primary", np.eye(4), f), "secondary": Arm("secondary", T12, f)}
    P, L = make_cloud([Obj("box", (0.3, 0.06), (0.16, 0.32, 0.10), 0.0)], table_size=(0.8, 0.8))
    plan = plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12,
                       params=PlanParams(handover=False, retry_factor=1, push=PushParams(aim_max=aim_max)))
    op = plan.objects[0]
    assert bool(op.joint) == found, op.notes
    for pair in op.joint:
        p_ag, s_ag = op.pair_grasps(pair)
        sq1, sq2 = p_ag.grasps.extra["squeeze"][pair.i_primary], s_ag.grasps.extra["squeeze"][pair.i_secondary]
        assert sq1 @ sq2 < -0.99


def test_push_pairs_off_the_face_middle_where_the_arms_reach_only_there():
    """Push contacts are also placed off each face's middle (``PushParams.laterals``): arms that reach a
    large box's end faces only towards one of their edges still get a pair, the two contacts across from
    each other (on one squeeze line); with contacts at the middle only they get none."""
    from grasping import Arm, PushParams, callable_filter

    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.16, 0.32, 0.10), 0.0)], table_size=(0.8, 0.8))

    def near_edge(T_b1_b):  # the reach of an arm that gets to x > 0.32 in b1 only (the predicate sees T_b_g)
        return callable_filter(lambda T_b_g: (T_b1_b @ T_b_g)[:, 0, 3] > 0.32 - 1e-9)

    arms = {"primary": Arm("primary", np.eye(4), near_edge(np.eye(4))),
            "secondary": Arm("secondary", T12, near_edge(T12))}

    def plan(push):
        return plan_grasps(scene_cloud(P, L), arms=arms, T_b1_b2=T12,
                           params=PlanParams(handover=False, retry_factor=1, push=push)).objects[0]

    op = plan(PushParams())
    assert op.mode == "joint" and op.joint, op.notes
    for pair in op.joint:
        c1, c2 = _centres(op, pair)
        assert c1[0] > 0.32 and c2[0] > 0.32
        assert abs(abs(c1[1]) - 0.16) < 0.01 and abs(abs(c2[1]) - 0.16) < 0.01 and c1[1] * c2[1] < 0  # both ends
        assert abs(c1[0] - c2[0]) <= 0.02  # across from each other: one squeeze line
    assert not plan(PushParams(laterals=(0.0,))).joint


def test_hand_over_fallbacks_left_out_by_name(monkeypatch, tmp_path):
    """``grasp_stage(leave_out=...)`` (what bench/tasks.py --leave-out measures) switches the hand-over search's
    fallbacks off by name: no shallow holds after a search that found none, no redraws; unknown names are
    refused naming the field."""
    import grasping._plan as gplan
    from bimanual_app.io_utils import InputError
    from grasping import HANDOVER_FALLBACKS, HandoverParams, grasp_stage
    from grasping._handover import without_fallbacks

    hp = HandoverParams()
    off = without_fallbacks(hp, tuple(HANDOVER_FALLBACKS))
    assert hp.shallow_depths and hp.redraws > 0 and off.shallow_depths == () and off.redraws == 0
    assert without_fallbacks(hp, ("make-way",)) == hp  # a planner fallback: not the search's
    P, L = make_cloud([Obj("cylinder", (0.3, 0.2), (0.05, 0.05, 0.10))])
    real, calls = gplan.plan_handovers, []

    def none_found(geo, support, givers, *args, **kw):
        calls.append(len(givers.grasps))
        return [], real(geo, support, givers, *args, **kw)[1]

    monkeypatch.setattr(gplan, "plan_handovers", none_found)
    params = PlanParams(retry_factor=1)
    plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=params)
    n_with = len(calls)
    calls.clear()
    params = replace(params, handover_params=without_fallbacks(params.handover_params, ("shallow-holds",)))
    plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=params)
    assert n_with > len(calls) >= 1  # the shallow holds' search (and its redraw's) left out
    with pytest.raises(InputError, match=r"leave_out.*unknown hand-over fallback.*shallow-holds"):
        grasp_stage(tmp_path / "none", tmp_path / "none.npz", tmp_path / "out", leave_out=("shallow_holds",))
