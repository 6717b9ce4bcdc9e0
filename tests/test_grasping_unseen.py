"""The space around an object that no camera saw into is solid for its grasps (``unseen_space``)."""

import numpy as np
from _grasp_fixtures import Obj, accept_all_arms, make_cloud

from grasping import PlanParams, estimate_support, plan_grasps, scene_cloud
from grasping._objects import unseen_space

CENTRE = (0.3, 0.0)
DIAMETER = 0.05


def _half_seen_cylinder():
    """A 5 cm cylinder seen from -y only: its far half (y > 0) and the table in its shadow (y in 0..8 cm
    beside it) were never seen."""
    P, L = make_cloud([Obj("cylinder", CENTRE, (DIAMETER, DIAMETER, 0.08), 0.0)], table_size=(0.5, 0.5))
    far = (L == 0) & (P[:, 1] > CENTRE[1])
    shadow = (L < 0) & (P[:, 1] > CENTRE[1]) & (P[:, 1] < CENTRE[1] + 0.08) & (np.abs(P[:, 0] - CENTRE[0]) < 0.045)
    keep = ~far & ~shadow
    return P[keep], L[keep]


def test_unseen_space_fills_the_unseen_half_and_nothing_around_a_seen_object():
    P, L = _half_seen_cylinder()
    sup = estimate_support(P, L)
    U = unseen_space(P[L == 0], P[L < 0], P[L > 0], sup)
    assert len(U) and np.all(sup.elevation(U) > 0) and np.all(sup.elevation(U) <= 0.081)
    # the cylinder's unseen half: (nearly) every spot of its footprint is under an unseen column
    g = np.linspace(-DIAMETER / 2, DIAMETER / 2, 21)
    X, Y = np.meshgrid(g, g)
    inside = (X ** 2 + Y ** 2 < (DIAMETER / 2 - 0.003) ** 2) & (Y > 0.004)
    spots = np.stack([X[inside] + CENTRE[0], Y[inside] + CENTRE[1]], axis=1)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(U[:, :2]).query(spots)
    assert np.mean(d < 0.005) > 0.9
    assert np.all(U[:, 1] > CENTRE[1] - 0.01)  # not on the seen side, where the table was seen
    # the same cylinder seen all round: the table was seen everywhere around it
    P2, L2 = make_cloud([Obj("cylinder", CENTRE, (DIAMETER, DIAMETER, 0.08), 0.0)], table_size=(0.5, 0.5))
    assert len(unseen_space(P2[L2 == 0], P2[L2 < 0], P2[L2 > 0], estimate_support(P2, L2))) == 0


def test_grasps_of_a_half_seen_cylinder_do_not_close_across_the_seen_shell(monkeypatch):
    """Seen from one side the cylinder is a 2.5 cm deep shell: a grasp closing across that depth puts a
    finger into its unseen half. Completed as a cylinder (``complete_cylinder``, the default), every grasp
    closes on its whole 5 cm. Without that completion, such grasps exist when the unseen space is ignored,
    and none is kept when it is solid (``unseen_radius``); grasps closing across the seen 5 cm width remain."""
    import grasping._objects as objects

    P, L = _half_seen_cylinder()

    def across_depth(params):
        plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(), params=params)
        gs = plan.objects[0].grasps
        assert gs is not None and len(gs), plan.objects[0].notes
        closing = gs.T_b1_g[:, :3, 1]
        return int(np.sum(np.abs(closing[:, 1]) > 0.9)), gs

    _, gs = across_depth(PlanParams(handover=False))
    assert np.all(gs.contact_width > DIAMETER - 0.005)  # on the whole cylinder, not across the shell
    monkeypatch.setattr(objects, "complete_cylinder", lambda geo, support, bottom=0.0: geo)
    n_ignored, _ = across_depth(PlanParams(handover=False))
    n_solid, gs_solid = across_depth(PlanParams(handover=False, unseen_radius=0.05))
    assert n_ignored > 0
    assert n_solid == 0 and len(gs_solid) > 0


def _cylinder_normals(P):
    n = np.zeros_like(P)
    d = P[:, :2] - np.asarray(CENTRE)
    r = np.linalg.norm(d, axis=1)
    side = r > DIAMETER / 2 - 0.002
    n[side, :2] = d[side] / r[side, None]
    n[~side, 2] = 1.0
    return n


def test_only_the_directions_whose_side_was_not_seen_are_filled():
    """With the object's normals, the unseen table is filled only where its side was not seen: a cylinder
    seen all round whose shadow on the table no camera saw gets nothing (the shadow is not more of it);
    the half-seen one still gets its far half."""
    P, L = make_cloud([Obj("cylinder", CENTRE, (DIAMETER, DIAMETER, 0.08), 0.0)], table_size=(0.5, 0.5))
    shadow = (L < 0) & (P[:, 1] > CENTRE[1]) & (P[:, 1] < CENTRE[1] + 0.08) & (np.abs(P[:, 0] - CENTRE[0]) < 0.045)
    P, L = P[~shadow], L[~shadow]
    sup = estimate_support(P, L)
    obj = P[L == 0]
    assert len(unseen_space(obj, P[L < 0], P[L > 0], sup)) > 0  # without normals: the shadow is filled
    assert len(unseen_space(obj, P[L < 0], P[L > 0], sup, normals=_cylinder_normals(obj))) == 0
    P2, L2 = _half_seen_cylinder()
    obj2 = P2[L2 == 0]
    U = unseen_space(obj2, P2[L2 < 0], P2[L2 > 0], estimate_support(P2, L2), normals=_cylinder_normals(obj2))
    assert len(U) and np.all(U[:, 1] > CENTRE[1] - 0.005)


def _cylinder_views(azimuths_deg):
    from _views_fixtures import render, ring_of_cameras

    return render(ring_of_cameras((CENTRE[0], CENTRE[1], 0.04), azimuths_deg),
                  [(CENTRE, DIAMETER / 2, 0.08)], table_half=0.25)


def test_carving_finds_the_far_half_no_camera_saw_and_nothing_around_a_seen_object():
    """Cameras on the -y side only: the cells no camera saw past lie beside the cylinder's far (+y) half,
    within the radius, above the table; with cameras all round only its inside, which no camera sees either."""
    from grasping._unseen import carved_unseen

    P, L = _half_seen_cylinder()
    sup = estimate_support(P, L)
    U = carved_unseen(P[L == 0], P[L != 0], sup, _cylinder_views([-150, -120, -90, -60, -30]))
    assert len(U) > 50
    r = np.linalg.norm(U[:, :2] - np.asarray(CENTRE), axis=1)
    assert np.all(r < DIAMETER / 2 + 0.03 + 0.005) and np.all(sup.elevation(U) >= 0.01)
    # outside the cylinder on the seen side, nothing but a cell's width at its silhouette (the cylinder's
    # inside is unseen too, and harmless: no finger goes there)
    outside_seen = (r > DIAMETER / 2 + 0.012) & (U[:, 1] < CENTRE[1] - 0.01)
    assert not outside_seen.any(), U[outside_seen]
    # the unseen half itself (beyond the seen points' skin) is in it: its centre line, 2 cm behind the axis
    from scipy.spatial import cKDTree

    behind = np.array([[CENTRE[0], CENTRE[1] + 0.02, z] for z in (0.02, 0.04, 0.06)])
    assert np.all(cKDTree(U).query(behind)[0] < 0.005)
    P2, L2 = make_cloud([Obj("cylinder", CENTRE, (DIAMETER, DIAMETER, 0.08), 0.0)], table_size=(0.5, 0.5))
    all_round = _cylinder_views(list(range(-180, 180, 45)))
    U2 = carved_unseen(P2[L2 == 0], P2[L2 != 0], estimate_support(P2, L2), all_round)
    assert np.all(np.linalg.norm(U2[:, :2] - np.asarray(CENTRE), axis=1) < DIAMETER / 2)  # its inside only


def test_carving_trusts_a_view_seeing_past_a_cell_only_beyond_the_views_own_disagreement():
    """Views that see 3 cm past each other's surfaces (a real capture's) prove a cell free only when they see
    more than that past it: the ring of cells just outside the cylinder stays unseen, those farther out do not."""
    from dataclasses import replace

    from grasping._unseen import carved_unseen

    P2, L2 = make_cloud([Obj("cylinder", CENTRE, (DIAMETER, DIAMETER, 0.08), 0.0)], table_size=(0.5, 0.5))
    sup = estimate_support(P2, L2)
    all_round = _cylinder_views(list(range(-180, 180, 45)))
    sharp = carved_unseen(P2[L2 == 0], P2[L2 != 0], sup, all_round)
    blunt = carved_unseen(P2[L2 == 0], P2[L2 != 0], sup, replace(all_round, disagreement=0.03))
    r = np.linalg.norm(blunt[:, :2] - np.asarray(CENTRE), axis=1)
    assert len(blunt) > len(sharp) + 50 and np.any(r > DIAMETER / 2 + 0.015)
    assert np.all(r < DIAMETER / 2 + 0.03 + 0.005)  # still within the carving's radius


def test_a_handover_keeps_its_fingers_out_of_what_no_camera_saw():
    """A box seen only by cameras on its -y side: the air behind it (+y) may hold more of it. With the capture's
    depth views on the cloud, the hand-over's pick and receiver are drawn with those cells solid
    (``_clear_of_unseen``): neither swept gripper meets them, though some of the plain picks do."""
    from _grasp_fixtures import facing_T_b1_b2
    from _views_fixtures import render, ring_of_cameras
    from test_handover_search import _Cone

    from grasping import Arm
    from grasping._collision import GripperCollider, SceneOctree

    T12 = facing_T_b1_b2(0.6)
    box = ((0.3, 0.2), (0.05, 0.05, 0.08), 0.3)
    P, L = make_cloud([Obj("box", *box)], table_size=(0.8, 0.8))
    arms = {"primary": Arm("primary", np.eye(4), _Cone(10.0, (0.0, 5.0))),
            "secondary": Arm("secondary", T12, _Cone(8.0, (35.0, 45.0)))}
    cloud = scene_cloud(P, L)
    cloud.views = render(ring_of_cameras((0.3, 0.2, 0.04), [-150, -120, -90, -60, -30]), [], table_half=0.4,
                         boxes=[box])
    plan = plan_grasps(cloud, arms=arms, T_b1_b2=T12, params=PlanParams(retry_factor=1))
    op = plan.objects[0]
    c, s_ = np.cos(box[2]), np.sin(box[2])
    local = (op.carved[:, :2] - box[0]) @ np.array([[c, -s_], [s_, c]])
    outside = np.any(np.abs(local) > 0.025, axis=1)  # (inside: the box's own unseen core)
    assert outside.sum() > 50 and np.all(op.carved[outside, 1] > 0.2)  # behind the box only
    h = op.handover
    assert h is not None and op.stats.get("unseen", {}).get("handover_clear_of_them"), (op.notes, op.stats)
    cells = SceneOctree(op.carved, 0.005)
    picking = GripperCollider(plan.gripper, PlanParams().sampler.approach)
    receiving = GripperCollider(plan.gripper, PlanParams().handover_params.receiver_pregrasp)
    pick = op.giver_picks.take([h.givers.index[h.giver_index]])
    assert not picking.collides(cells, pick.T_b1_g, pick.width)[0]
    T_rest = np.linalg.inv(h.T_move) @ h.receiver["T_b1_g"]  # the receiver where the object lay
    assert not receiving.collides(cells, T_rest[None], np.array([h.receiver["width"]]))[0]
    assert picking.collides(cells, op.grasps.T_b1_g, op.grasps.width).any()  # not a constraint for nothing


def test_a_handover_is_still_found_where_no_grasp_keeps_out_of_the_unseen_cells():
    """Cameras that saw nothing past the box (every pixel a hole): every cell near it is unseen, no grasp keeps
    out, and the hand-over comes from the search that ignores them, as without views."""
    from _grasp_fixtures import facing_T_b1_b2
    from _views_fixtures import render, ring_of_cameras
    from test_handover_search import _Cone

    from bimanual_app.views import DepthViews
    from grasping import Arm

    T12 = facing_T_b1_b2(0.6)
    box = ((0.3, 0.2), (0.05, 0.05, 0.08), 0.3)
    P, L = make_cloud([Obj("box", *box)], table_size=(0.8, 0.8))
    arms = {"primary": Arm("primary", np.eye(4), _Cone(10.0, (0.0, 5.0))),
            "secondary": Arm("secondary", T12, _Cone(8.0, (35.0, 45.0)))}
    seen = render(ring_of_cameras((0.3, 0.2, 0.04), [-90]), [], table_half=0.4, boxes=[box])
    cloud = scene_cloud(P, L)
    cloud.views = DepthViews(seen.T_b1_c, seen.K, np.full_like(seen.depth, np.nan), seen.arm)
    op = plan_grasps(cloud, arms=arms, T_b1_b2=T12, params=PlanParams(retry_factor=1)).objects[0]
    assert len(op.carved) > 100 and op.stats["unseen"]["handover_clear_of_them"] is False
    assert op.handover is not None, (op.notes, op.stats.get("handover"))
