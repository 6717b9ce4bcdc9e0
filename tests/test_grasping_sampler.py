"""Antipodal sampling on small synthetic clouds: antipodal, within the stroke, frame convention, collisions."""

import numpy as np
import pytest
from _grasp_fixtures import Obj, box_scene, make_cloud

from grasping import (
    GripperCollider,
    SamplerParams,
    SceneOctree,
    estimate_support,
    load_gripper,
    object_geometry,
    sample_grasps,
)
from grasping._collision import points_in_gripper


def _sample(P, L, k, **kw):
    g = load_gripper()
    sup = estimate_support(P, L)
    geo = object_geometry(k, P[L == k], sup)
    col = GripperCollider(g)
    others = SceneOctree(P[L != k], 0.003)
    gs, st = sample_grasps(geo, sup, g, col, others, SamplerParams(**kw))
    return g, sup, geo, gs, st


@pytest.fixture(scope="module")
def box_grasps():
    P, L = box_scene(noise=0.0005)
    return (P, L) + _sample(P, L, 0)


def test_box_grasps_are_antipodal_and_within_stroke(box_grasps):
    P, L, g, sup, geo, gs, st = box_grasps
    assert len(gs) >= 10, st
    # box axes (yaw 0.2 about z): the closing axis must be across one of the two horizontal faces
    c, s = np.cos(0.2), np.sin(0.2)
    faces = np.array([[c, s, 0.0], [-s, c, 0.0]])
    sizes = np.array([0.04, 0.06])
    y = gs.T_b1_g[:, :3, 1]
    along = np.abs(y @ faces.T)  # (n, 2)
    best = along.max(axis=1)
    assert np.all(best > np.cos(np.deg2rad(30))), best.min()
    # the measured contact width is the box's width across that face, and the opening exceeds it
    across = sizes[np.argmax(along, axis=1)]
    top = gs.score >= np.median(gs.score)
    assert np.all(np.abs(gs.contact_width[top] - across[top]) < 0.008)
    assert np.all(gs.width >= gs.contact_width + 2 * SamplerParams().min_clearance - 1e-9)
    assert np.all(gs.width <= g.max_width + 1e-9) and np.all(gs.contact_width >= SamplerParams().min_width)
    assert np.all((gs.score >= 0) & (gs.score <= 1)) and np.all(np.diff(gs.score) <= 1e-12)  # best first


def test_frame_convention(box_grasps):
    P, L, g, sup, geo, gs, st = box_grasps
    T = gs.T_b1_g
    R = T[:, :3, :3]
    assert np.allclose(np.einsum("nji,njk->nik", R, R), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(np.cross(R[:, :, 1], R[:, :, 2]), R[:, :, 0], atol=1e-9)  # x = y cross z
    # z is the approach, from above or the side (never from below the table)
    assert np.all(R[:, :, 2] @ sup.up <= 0.1 + 1e-9)
    # the object lies between the fingers, ahead of the palm: its centre is at z < 0 within the finger length
    c_g = np.einsum("nji,nj->ni", R, geo.centre - T[:, :3, 3])
    assert np.all(c_g[:, 2] < 0.0) and np.all(c_g[:, 2] > -g.finger_length - 0.03)
    assert np.all(np.abs(c_g[:, 1]) < 0.02)  # centred between the fingers


def test_fingers_and_palm_clear_table_and_object(box_grasps):
    P, L, g, sup, geo, gs, st = box_grasps
    for i in range(len(gs)):
        inside = points_in_gripper(g, gs.T_b1_g[i], gs.width[i], P)
        assert not inside.any(), f"grasp {i} overlaps {int(inside.sum())} cloud points"


def test_neighbour_blocks_the_fingers():
    """A second box 1 cm away along x: no finger may go into that gap (the fingers are 1 cm thick + clearance),
    so every grasp of the first box closes along y; alone, the same box is also grasped along x."""
    alone = [Obj("box", (0.3, 0.0), (0.04, 0.04, 0.06))]
    pair = alone + [Obj("box", (0.3 + 0.04 + 0.01, 0.0), (0.04, 0.1, 0.09))]
    ys = []
    for objs in (alone, pair):
        P, L = make_cloud(objs)
        g, sup, geo, gs, st = _sample(P, L, 0)
        assert len(gs) > 0, st
        ys.append(np.abs(gs.T_b1_g[:, :3, 1] @ np.array([1.0, 0.0, 0.0])))
        if len(objs) == 2:
            nb = P[L == 1]
            for i in range(len(gs)):
                assert not points_in_gripper(g, gs.T_b1_g[i], gs.width[i], nb, margin=0.001).any()
    assert ys[0].max() > 0.9  # alone: some grasps close along x
    assert ys[1].max() < 0.5  # with the neighbour: none does


def test_collider_detects_overlap():
    g = load_gripper()
    col = GripperCollider(g, approach=0.0)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # approach straight down
    T[:3, 3] = [0.0, 0.0, 0.10]
    # a point inside one open finger collides; one between the fingers does not
    w = 0.06
    finger = [s for s in g.shapes if s.role == "finger"][0]
    c = finger.corners_g(w).mean(axis=0)
    p_b1 = T[:3, :3] @ c + T[:3, 3]
    assert col.collides(SceneOctree(p_b1[None], 0.002), T[None], np.array([w]))[0]
    between = T[:3, :3] @ np.array([0.0, 0.0, -0.02]) + T[:3, 3]  # 2 cm behind the fingertips, between them
    assert not col.collides(SceneOctree(between[None], 0.002), T[None], np.array([w]))[0]
    # the swept gripper hits what lies on its way in: a point behind the palm (clear of the final pose)
    col_swept = GripperCollider(g, approach=0.09)
    behind = np.array([0.0, 0.04, g.palm_z - 0.09 - 0.05])
    assert g.palm_z - 0.09 - 0.05 > min(s.corners_g(w)[:, 2].min() for s in g.shapes) - 0.09
    on_the_way = T[:3, :3] @ behind + T[:3, 3]
    assert not col.collides(SceneOctree(on_the_way[None], 0.002), T[None], np.array([w]))[0]
    assert col_swept.collides(SceneOctree(on_the_way[None], 0.002), T[None], np.array([w]))[0]


def test_grasps_open_wide_where_free_and_narrow_beside_a_neighbour():
    """A box alone: the fingers open ``wide_clearance`` past it on each side (the object's position in the
    cloud is off by the calibration error). With a neighbour 3.2 cm away across one face, the grasps that
    close across that face open only as far as the neighbour leaves room (never into it)."""
    alone = [Obj("box", (0.3, 0.0), (0.04, 0.04, 0.06))]
    P, L = make_cloud(alone)
    g, sup, geo, gs, st = _sample(P, L, 0)
    p = SamplerParams()
    assert len(gs) > 0, st
    want = np.minimum(gs.contact_width + 2 * p.wide_clearance, g.max_width)
    assert np.mean(np.abs(gs.width - want) < 1e-6) > 0.8
    off, _, _, gs_off, _ = _sample(P, L, 0, wide_clearance=0.0)
    assert np.allclose(gs_off.width, np.minimum(gs_off.contact_width + 2 * p.clearance, g.max_width))
    pair = alone + [Obj("box", (0.3 + 0.04 + 0.032, 0.0), (0.04, 0.1, 0.09))]
    P, L = make_cloud(pair)
    g, sup, geo, gs, st = _sample(P, L, 0)
    nb = P[L == 1]
    across_x = np.abs(gs.T_b1_g[:, :3, 1] @ np.array([1.0, 0.0, 0.0])) > 0.9
    assert across_x.any() and np.all(gs.width[across_x] < gs.contact_width[across_x] + 2 * p.wide_clearance - 1e-6)
    for i in range(len(gs)):
        assert not points_in_gripper(g, gs.T_b1_g[i], gs.width[i], nb, margin=0.001).any()
