"""A can seen from one side (a half shell) is completed as the whole cylinder: real centre, real width; a
box seen from one corner is not."""

import _grasp_fixtures as _fx
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


def test_the_geometric_circle_fit_does_not_shrink_a_noisy_half_arc():
    """The algebraic fit of a half arc with 3 mm noise comes out millimetres small and off centre (on the
    task bench: a 6.4 cm can as 5.8 cm); the geometric refinement recovers it."""
    from grasping._objects import fit_circle, refine_circle

    rng = np.random.default_rng(3)
    a = rng.uniform(-np.pi / 2, np.pi / 2, 1500)
    rho = 0.032 + rng.normal(0.0, 0.003, a.size)
    xy = np.c_[0.35 + rho * np.cos(a), 0.05 + rho * np.sin(a)]
    c0, r0 = fit_circle(xy)
    c, r = refine_circle(xy, c0, r0)
    assert abs(r - 0.032) < 0.001 and np.linalg.norm(c - (0.35, 0.05)) < 0.001
    assert abs(r - 0.032) < abs(r0 - 0.032)


def _seen_from_above_and(P, L, towards, half_angle_deg=95.0):
    """As :func:`_seen_from`, with the object's whole top seen (a wrist camera above it)."""
    Ps, Ls = _seen_from(P, L, towards, half_angle_deg)
    obj = L == 0
    top = obj & (P[:, 2] > P[obj, 2].max() - 0.003)
    return np.concatenate([Ps, P[top]]), np.concatenate([Ls, L[top]])


def _noisy(P, L, sigma, seed=0):
    """The object's points (label 0) moved by a normal error of ``sigma`` (m) per axis, as the pipeline's
    fused depth leaves them."""
    P = P.copy()
    obj = L == 0
    P[obj] += np.random.default_rng(seed).normal(0.0, sigma, (int(obj.sum()), 3))
    return P


def test_a_noisy_can_seen_from_one_side_is_completed_as_a_cylinder():
    """At 3 mm of noise the side points miss the circle by more than CYL_MAX_RMS of its radius; the can is
    still completed: its arc is nearer the circle than any box's sides, keeps to it all the way up, and its
    top is a closed disc."""
    from grasping import _objects

    can = Obj("cylinder", (0.35, 0.05), (0.064, 0.064, 0.13))
    P, L = _seen_from_above_and(*make_cloud([can], table_size=(0.8, 0.8)), towards=(-1.0, 0.0))
    P = _noisy(P, L, 0.003)
    sup = estimate_support(P, L)
    raw = object_geometry(0, P[L == 0], sup, background=P[L < 0], complete=False)
    side = np.abs(raw.normals @ sup.up) < 0.3
    xy = raw.points[side][:, :2]
    c0, r0 = _objects.fit_circle(xy)
    assert np.sqrt(np.mean((np.linalg.norm(xy - c0, axis=1) - r0) ** 2)) > _objects.CYL_MAX_RMS * r0  # noisy
    geo = object_geometry(0, P[L == 0], sup, background=P[L < 0])
    assert (~geo.observed).sum() > 200
    assert np.allclose(np.sort(geo.extent[:2]), 0.064, atol=0.004)
    assert np.linalg.norm(geo.centre[:2] - can.centre_xy) < 0.004


def test_a_toy_whose_head_tops_a_body_is_not_made_a_cylinder():
    """A duck-like toy: a round body (5 cm) and a narrower head (4 cm) on top, seen from one side through
    1.5 mm of noise. Its side points fit one circle about as well as a noisy can's, more of them lie on it
    than on the box's sides, and its head's top is a closed disc; but its side does not keep to that circle
    up its height."""
    body = Obj("cylinder", (0.35, 0.05), (0.05, 0.05, 0.035))
    P, L = make_cloud([body], table_size=(0.8, 0.8))
    body_pts = P[L == 0]
    body_pts = body_pts[body_pts[:, 2] < 0.035 - 1e-6]  # the body's side only: the head stands on it
    head = _fx.cylinder_points((0.35, 0.05), 0.040, 0.025, z0=0.035)
    P = np.concatenate([P[L != 0], body_pts, head])
    L = np.concatenate([L[L != 0], np.zeros(len(body_pts) + len(head), dtype=L.dtype)])
    P, L = _seen_from_above_and(P, L, towards=(-1.0, 0.0), half_angle_deg=85.0)
    P = _noisy(P, L, 0.0015)
    sup = estimate_support(P, L)
    from grasping._objects import complete_cylinder

    raw = object_geometry(0, P[L == 0], sup, background=P[L < 0], complete=False)
    assert complete_cylinder(raw, sup) is raw


def test_a_noisy_can_seen_over_most_of_its_round_is_grasped_across_its_fitted_circle():
    """A 6.5 cm can seen over about 250 degrees through 1.5 mm of noise: the points' own box falls short of
    its diameter and its points' extremes lie millimetres past its surface. Completed, its box is the fitted
    circle's square, its seen side lies on that circle, and every grasp's contact width is the can's (within
    the 66 mm the 72 mm stroke takes with 3 mm a side), where the noisy extremes alone measure more."""
    from _grasp_fixtures import accept_all_arms

    from grasping import PlanParams, plan_grasps, scene_cloud

    can = Obj("cylinder", (0.35, 0.05), (0.065, 0.065, 0.12))
    P, L = _seen_from_above_and(*make_cloud([can], table_size=(0.8, 0.8)), towards=(-1.0, 0.0), half_angle_deg=125.0)
    P = _noisy(P, L, 0.0015, seed=4)
    sup = estimate_support(P, L)
    seen = P[L == 0]
    assert np.ptp(seen[:, 1]) > 0.066  # the noisy extremes: past what the stroke takes
    geo = object_geometry(0, seen, sup, background=P[L < 0])
    assert np.allclose(np.sort(geo.extent[:2]), 0.065, atol=0.0015)
    assert np.linalg.norm(geo.centre[:2] - can.centre_xy) < 0.0015
    side = geo.observed & (np.abs(geo.normals @ sup.up) < 0.3)
    r = np.linalg.norm(geo.points[side][:, :2] - geo.centre[:2], axis=1)
    on = np.abs(r - np.median(r)) < 1e-6
    assert np.mean(on) > 0.98 and abs(np.median(r) - 0.0325) < 0.0008  # strays over 5 mm off stay where seen
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(), params=PlanParams(handover=False))
    gs = plan.objects[0].grasps
    assert gs is not None and len(gs), plan.objects[0].notes
    assert np.all(np.abs(gs.contact_width - 0.065) < 0.002)
