"""Whether the cloud determines an object's shape (``primitive_fit``): boxes and closed cylinders do, with
noise and when seen from one side; an open cup (rim and inside, no lid) and a blob do not."""

import numpy as np
from _grasp_fixtures import Obj, cylinder_points, make_cloud, table_points

from grasping import estimate_support, object_geometry
from grasping._objects import primitive_fit


def _fit(P, L, k=0):
    sup = estimate_support(P, L)
    geo = object_geometry(k, P[L == k], sup, background=P[L < 0])
    return primitive_fit(geo, sup)


def test_a_noisy_box_and_a_noisy_can_fit_their_primitive():
    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.05, 0.04, 0.06), 0.5),
                       Obj("cylinder", (0.4, 0.15), (0.065, 0.065, 0.10))], noise=0.0015, seed=3)
    kind, fit = _fit(P, L, 0)
    assert kind == "box"
    kind, fit = _fit(P, L, 1)
    assert kind == "cylinder"


def test_a_can_seen_from_one_side_still_fits_a_cylinder():
    P, L = make_cloud([Obj("cylinder", (0.35, 0.05), (0.07, 0.07, 0.12))])
    obj = L == 0
    far = obj & (P[:, 0] > 0.35 + 0.01) & (P[:, 2] < 0.12 - 1e-6)  # the far half of the side unseen
    P, L = P[~far], L[~far]
    assert _fit(P, L)[0] == "cylinder"


def _open_cup(centre=(0.35, 0.0), d=0.07, h=0.09, wall=0.004, step=0.003) -> np.ndarray:
    """A cup without a lid: its outer side, rim, inner side and the inside of its bottom (M, 3)."""
    outer = cylinder_points(centre, d, h, step)
    outer = outer[outer[:, 2] < h - 1e-6]  # no lid
    inner = cylinder_points(centre, d - 2 * wall, h - 0.01, step, z0=0.01)
    inner_side = inner[inner[:, 2] < h - 1e-6]
    bottom = inner[np.isclose(inner[:, 2], h)]  # the inner cylinder's 'top' is the cup's inside bottom
    bottom[:, 2] = 0.01
    rim_a = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    rim = np.c_[centre[0] + (d / 2 - wall / 2) * np.cos(rim_a), centre[1] + (d / 2 - wall / 2) * np.sin(rim_a),
                np.full(len(rim_a), h)]
    return np.concatenate([outer, inner_side, bottom, rim])


def test_an_open_cup_and_a_blob_are_free_form():
    T = table_points()
    cup = _open_cup()
    P = np.concatenate([T, cup])
    L = np.r_[np.full(len(T), -1), np.zeros(len(cup), int)].astype(np.int32)
    assert _fit(P, L)[0] == "free-form"
    rng = np.random.default_rng(0)
    u = rng.normal(size=(4000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    blob = u * np.array([0.035, 0.025, 0.03]) + np.array([0.3, 0.1, 0.03])
    blob = blob[blob[:, 2] > 0.002]
    P = np.concatenate([T, blob])
    L = np.r_[np.full(len(T), -1), np.zeros(len(blob), int)].astype(np.int32)
    kind, fit = _fit(P, L)
    assert kind == "free-form" and fit < 0.9
