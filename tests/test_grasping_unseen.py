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
