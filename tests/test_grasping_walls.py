"""A carton seen only from above (wrist cameras looking down): it stands on the table when the table is hidden
under it, its side walls are completed (unseen, solid), and push contacts then find its faces; a plate
held above the table, with the table seen under it, is left as it is."""

import numpy as np
from _grasp_fixtures import Obj, make_cloud

from grasping import estimate_support, object_geometry
from grasping._objects import hides_table

BOX = Obj("box", (0.3, 0.0), (0.30, 0.18, 0.10), 0.2)


def _top_only(P, L, top):
    """The object's points on its top face only (the sides unseen)."""
    keep = (L < 0) | (P[:, 2] > top - 0.004)
    return P[keep], L[keep]


def test_a_carton_seen_only_from_above_stands_on_the_table_with_walls():
    P, L = _top_only(*make_cloud([BOX], table_size=(0.8, 0.8)), top=0.10)
    sup = estimate_support(P, L)
    floating = object_geometry(0, P[L == 0], sup)
    assert floating.extent[2] < 0.02  # without the table's evidence: only a slab at the top
    geo = object_geometry(0, P[L == 0], sup, background=P[L < 0])
    assert abs(geo.extent[2] - 0.10) < 0.006 and abs(geo.centre[2] - 0.05) < 0.004
    walls = geo.points[~geo.observed]
    assert len(walls) > 500
    # the completed walls are the box's sides, from near the table to its top, with outward normals
    rel = (walls - geo.centre) @ geo.T_b1_box[:3, :3]
    on_side = np.abs(np.abs(rel[:, :2]) - geo.extent[:2] / 2).min(axis=1) < 0.006
    assert on_side.mean() > 0.95 and walls[:, 2].min() < 0.01 and walls[:, 2].max() > 0.08  # (near the top edge the top face is close enough)
    n_rel = geo.normals[~geo.observed] @ geo.T_b1_box[:3, :3]
    assert np.all(np.einsum("ij,ij->i", n_rel[:, :2], rel[:, :2]) > 0)


def test_a_plate_held_above_the_table_is_not_grounded():
    P, L = _top_only(*make_cloud([BOX], table_size=(0.8, 0.8)), top=0.10)
    # the table under the footprint is seen too: the object does not hide it
    under = np.stack(np.meshgrid(np.arange(0.16, 0.44, 0.006), np.arange(-0.08, 0.08, 0.006)), -1).reshape(-1, 2)
    P = np.vstack([P, np.c_[under, np.zeros(len(under))]])
    L = np.r_[L, np.full(len(under), -1)]
    sup = estimate_support(P, L)
    geo = object_geometry(0, P[L == 0], sup, background=P[L < 0])
    assert geo.extent[2] < 0.02 and geo.observed.all()
    Q = P[L == 0]
    u, v = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    assert not hides_table(P[L < 0], sup, u, v, (0.15, 0.45), (-0.09, 0.09))
    assert hides_table(P[(L < 0) & ~((np.abs(P[:, 0] - 0.3) < 0.15) & (np.abs(P[:, 1]) < 0.09))], sup, u, v,
                       (Q[:, 0].min(), Q[:, 0].max()), (Q[:, 1].min(), Q[:, 1].max()))


def test_a_small_box_seen_only_from_above_stands_on_the_table_unless_it_rests_on_another_object():
    """A 5 cm box seen from above only (its sides hidden by the views, the table hidden under it) reaches
    down to the table; a piece of the same size seen on top of a carton rests on the carton."""
    small = Obj("box", (0.3, 0.0), (0.05, 0.04, 0.05))
    P, L = _top_only(*make_cloud([small], table_size=(0.8, 0.8)), top=0.05)
    sup = estimate_support(P, L)
    geo = object_geometry(0, P[L == 0], sup, background=P[L < 0])
    assert abs(geo.extent[2] - 0.05) < 0.006 and abs(geo.centre[2] - 0.025) < 0.004
    carton = Obj("box", (0.3, 0.0), (0.12, 0.10, 0.10))
    Pc, Lc = make_cloud([carton], table_size=(0.8, 0.8))
    piece = Pc[(Lc == 0) & (Pc[:, 2] > 0.097) & (np.abs(Pc[:, 0] - 0.3) < 0.025) & (np.abs(Pc[:, 1]) < 0.02)]
    piece = piece + [0.0, 0.0, 0.02]  # 2 cm above the carton's top: a piece held on it
    sup = estimate_support(Pc, Lc)
    geo = object_geometry(1, piece, sup, background=Pc[Lc < 0], others=Pc[Lc == 0])
    assert geo.extent[2] < 0.02  # not a column through the carton down to the table
    u, v = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    rng_u, rng_v = (piece[:, 0].min(), piece[:, 0].max()), (piece[:, 1].min(), piece[:, 1].max())
    assert hides_table(Pc[Lc < 0], sup, u, v, rng_u, rng_v)  # the table is hidden there ...
    assert not hides_table(Pc[Lc < 0], sup, u, v, rng_u, rng_v, others=Pc[Lc == 0], bottom=0.118)  # ... by the carton


def test_givers_that_hold_deeper_are_likelier_to_hold():
    from grasping._handover import HandoverParams, giver_hold_probability

    p = giver_hold_probability(np.array([0.0, 0.006, 0.02, 0.04]), HandoverParams())
    assert np.all(np.diff(p) > 0) and p[0] < 0.5 and p[-1] > 0.99


def test_push_pairs_are_found_on_a_carton_seen_only_from_above():
    from _grasp_fixtures import accept_all_arms, facing_T_b1_b2

    from grasping import PlanParams, plan_grasps, scene_cloud

    T12 = facing_T_b1_b2(0.6)
    P, L = _top_only(*make_cloud([BOX], table_size=(0.8, 0.8)), top=0.10)
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12,
                       params=PlanParams(handover=False, retry_factor=1))
    op = plan.objects[0]
    assert op.mode == "joint" and op.joint, op.notes
    assert op.joint[0].kind == "push"


def test_a_small_box_with_no_grasp_on_its_seen_top_gets_its_walls_and_grasps():
    """A 4.5 cm box seen only from above: no antipodal pair among its top points, so no grasp; it is a box
    standing on the table, so its side walls are filled in under its top's outline (unseen) and the sampler
    closes on them. A box whose sides were seen keeps its seen points only (no note, no unseen walls)."""
    from _grasp_fixtures import accept_all_arms, facing_T_b1_b2

    from grasping import PlanParams, plan_grasps, scene_cloud

    T12 = facing_T_b1_b2(0.6)
    params = PlanParams(handover=False)
    small = Obj("box", (0.3, 0.0), (0.045, 0.04, 0.05))
    P, L = _top_only(*make_cloud([small], table_size=(0.8, 0.8)), top=0.05)
    op = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=params).objects[0]
    assert op.shape == "box" and op.mode == "single" and len(op.grasps) > 0, op.notes
    assert any("side walls" in n for n in op.notes)
    assert (~op.geometry.observed).sum() > 50
    # the grasps close across the box, on the filled-in walls: contact width within a few mm of a side
    assert np.all(np.min(np.abs(op.grasps.contact_width[:, None] - np.array([0.045, 0.04])), axis=1) < 0.006)
    P, L = make_cloud([small], table_size=(0.8, 0.8))
    op = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(T12), T_b1_b2=T12, params=params).objects[0]
    assert op.mode == "single" and not any("side walls" in n for n in op.notes)
