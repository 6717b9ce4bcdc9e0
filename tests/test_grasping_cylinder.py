"""A can seen from one side (a half shell) is completed as the whole cylinder: real centre, real width; a
box seen from one corner is not."""

import numpy as np

from _grasp_fixtures import Obj, make_cloud
from grasping import estimate_support, object_geometry

CAN = Obj("cylinder", (0.35, 0.05), (0.075, 0.075, 0.15))
BOX = Obj("box", (0.35, 0.05), (0.06, 0.05, 0.08), 0.4)


def _seen_from(P, L, towards, half_angle_deg=80.0):
    """The object's points whose horizontal direction from its axis is within ``half_angle_deg`` of
    ``towards`` (2,) (one camera side), and its top; the table as it is."""
    obj = L == 0
    c = P[obj, :2].mean(axis=0)
    d = P[:, :2] - c
    cosang = (d @ np.asarray(towards)) / np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    top = P[:, 2] > P[obj, 2].max() - 0.003
    keep = ~obj | (cosang > np.cos(np.deg2rad(half_angle_deg))) | (obj & top & (cosang > 0))
    return P[keep], L[keep]


def test_a_can_seen_from_one_side_is_completed_as_a_cylinder():
    P, L = _seen_from(*make_cloud([CAN], table_size=(0.8, 0.8)), towards=(-1.0, 0.0))
    sup = estimate_support(P, L)
    raw = object_geometry(0, P[L == 0], sup, background=P[L < 0], complete=False)
    assert raw.extent[:2].min() < 0.05  # the shell: about half as deep as the can
    geo = object_geometry(0, P[L == 0], sup, background=P[L < 0])
    assert np.allclose(np.sort(geo.extent[:2]), 0.075, atol=0.004)
    assert np.linalg.norm(geo.centre[:2] - CAN.centre_xy) < 0.004
    added = geo.points[~geo.observed]
    r = np.linalg.norm(added[:, :2] - CAN.centre_xy, axis=1)
    assert len(added) > 300 and np.all(np.abs(r - 0.0375) < 0.004)  # on the real can's unseen side
    assert added[:, 0].max() > CAN.centre_xy[0] + 0.03  # the far side, away from the camera
    n = geo.normals[~geo.observed][:, :2]
    assert np.all(np.einsum("ij,ij->i", n, added[:, :2] - CAN.centre_xy) > 0)  # outward


def test_a_box_seen_from_a_corner_is_not_made_a_cylinder():
    P, L = _seen_from(*make_cloud([BOX], table_size=(0.8, 0.8)), towards=(-1.0, -0.6))
    sup = estimate_support(P, L)
    from grasping._objects import complete_cylinder

    raw = object_geometry(0, P[L == 0], sup, background=P[L < 0], complete=False)
    assert np.sum(np.abs(raw.normals[:, 2]) < 0.3) > 100  # two faces seen: something to fit a circle to
    assert complete_cylinder(raw, sup) is raw
