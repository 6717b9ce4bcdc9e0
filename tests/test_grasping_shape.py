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


def test_support_without_a_segments_plane_is_the_shared_fitters_level_plane():
    """Segments without a table plane: the table comes from segmentation.fit_plane (RANSAC refined by least
    squares), level planes only; a background that is one steep wall falls back on the lowest object point."""
    rng = np.random.default_rng(4)
    tilt = np.deg2rad(2.0)
    xy = rng.uniform(-0.3, 0.6, (4000, 2))
    z = np.tan(tilt) * xy[:, 0] + 0.01 + rng.normal(0.0, 0.002, 4000)
    obj = np.c_[rng.uniform(0.3, 0.35, (300, 2)), rng.uniform(0.02, 0.08, 300)]
    P, L = np.vstack([np.c_[xy, z], obj]), np.r_[np.full(4000, -1), np.zeros(300, int)]
    sup = estimate_support(P, L)
    n_true = np.array([-np.sin(tilt), 0.0, np.cos(tilt)])
    assert sup.source.startswith("RANSAC") and sup.up @ n_true > np.cos(np.deg2rad(0.1))
    assert abs(sup.elevation(np.array([[0.0, 0.0, 0.01]]))[0]) < 1e-3
    wall = np.c_[np.full(2000, 0.9), rng.uniform(-0.5, 0.5, 2000), rng.uniform(0.0, 0.8, 2000)]
    sup = estimate_support(np.vstack([wall, obj]), np.r_[np.full(2000, -1), np.zeros(300, int)])
    assert sup.source.startswith("b1 xy plane") and np.allclose(sup.up, [0.0, 0.0, 1.0])


def _fit_with_views(P, L, views, k=0):
    sup = estimate_support(P, L)
    geo = object_geometry(k, P[L == k], sup, background=P[L < 0])
    return primitive_fit(geo, sup, views=views)


def test_the_views_tell_a_can_whose_top_was_seen_in_part_from_an_open_cup():
    """Points alone: a can whose top the cloud holds in part looks as open as a cup (no lid points over much
    of the disc). The depth views decide: no camera saw through the can's top, and every camera looking down
    saw into the cup."""
    from _views_fixtures import render, ring_of_cameras

    centre, d, h = (0.35, 0.0), 0.07, 0.10
    T = table_points()
    can = cylinder_points(centre, d, h)
    can = can[~((can[:, 2] > h - 1e-6) & (can[:, 0] > centre[0]))]  # half of its top never made it into the cloud
    P = np.concatenate([T, can])
    L = np.r_[np.full(len(T), -1), np.zeros(len(can), int)].astype(np.int32)
    cams = ring_of_cameras((centre[0], centre[1], 0.05), [-150, -90, -30, 30, 90, 150], distance=0.3, height=0.3)
    assert _fit(P, L)[0] == "free-form"  # the points alone cannot tell
    kind, fit = _fit_with_views(P, L, render(cams, [(centre, d / 2, h)]))
    assert kind == "cylinder" and fit > 0.9

    cup = _open_cup(centre, d, h)
    P = np.concatenate([T, cup])
    L = np.r_[np.full(len(T), -1), np.zeros(len(cup), int)].astype(np.int32)
    assert _fit_with_views(P, L, render(cams, [], cups=[(centre, d / 2, h)]))[0] == "free-form"


def test_a_top_no_view_saw_is_not_called_closed():
    """A can whose top no camera saw (cameras below its top) stays free-form: a cup seen so would look the same."""
    from _views_fixtures import render, ring_of_cameras

    centre, d, h = (0.35, 0.0), 0.07, 0.16
    T = table_points()
    can = cylinder_points(centre, d, h)
    can = can[can[:, 2] < h - 0.02]  # the cloud holds its lower side only
    P = np.concatenate([T, can])
    L = np.r_[np.full(len(T), -1), np.zeros(len(can), int)].astype(np.int32)
    cams = ring_of_cameras((centre[0], centre[1], 0.02), [-120, -60, 0, 60, 120], distance=0.3, height=0.05)
    assert _fit_with_views(P, L, render(cams, [(centre, d / 2, h)]))[0] == "free-form"


def test_a_can_whose_segment_holds_a_piece_of_its_neighbour_is_not_a_cylinder():
    """Most of the segment on the can's surface, and a 3 x 3 cm piece of a neighbour's top 3 cm beyond it (3 %
    of the points): the simulated cylinder would leave that piece out, so the segment is free-form."""
    centre, d, h = (0.35, 0.0), 0.07, 0.10
    T = table_points()
    can = cylinder_points(centre, d, h)
    g = np.arange(-0.015, 0.015, 0.003)
    X, Y = np.meshgrid(g, g)
    piece = np.c_[X.ravel() + centre[0] + d / 2 + 0.03, Y.ravel(), np.full(X.size, 0.02)]
    L = np.r_[np.full(len(T), -1), np.zeros(len(can), int)].astype(np.int32)
    assert _fit(np.concatenate([T, can]), L)[0] == "cylinder"
    L = np.r_[L, np.zeros(len(piece), int)].astype(np.int32)
    assert _fit(np.concatenate([T, can, piece]), L)[0] == "free-form"


def _rounded_box(centre=(0.35, 0.0), size=(0.044, 0.041), h=0.05, corner=0.012, step=0.002) -> np.ndarray:
    """A small box whose vertical edges are rounded (radius ``corner``), as the pipeline's clouds draw one:
    its sides (M, 3) and its flat top."""
    a, b = size[0] / 2 - corner, size[1] / 2 - corner
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    # the outline: the inner rectangle grown by ``corner`` (straight faces, quarter circles at the edges)
    ring = np.c_[np.clip(np.cos(t) * 10, -1, 1) * a + corner * np.cos(t), np.clip(np.sin(t) * 10, -1, 1) * b
                 + corner * np.sin(t)]
    z = np.arange(0.0, h + 1e-9, step)
    side = np.c_[np.repeat(ring, len(z), axis=0), np.tile(z, len(ring))]
    g = np.mgrid[-size[0] / 2:size[0] / 2:step, -size[1] / 2:size[1] / 2:step].reshape(2, -1).T
    inside = (np.maximum(np.abs(g[:, 0]) - a, 0) ** 2 + np.maximum(np.abs(g[:, 1]) - b, 0) ** 2) <= corner ** 2
    top = np.c_[g[inside], np.full(inside.sum(), h)]
    return np.vstack([side, top]) + [centre[0], centre[1], 0.0]


def _cylinder_share(P, L, k=0):
    """The cylinder's fit alone (``_cylinder_fit``): the share of the seen points on its surface, 0 when not a can."""
    from grasping._objects import PRIMITIVE_TOL, _cylinder_fit

    sup = estimate_support(P, L)
    geo = object_geometry(k, P[L == k], sup, background=P[L < 0])
    return _cylinder_fit(geo, geo.points[geo.observed], geo.normals[geo.observed], sup, PRIMITIVE_TOL, None)


def test_a_small_box_with_rounded_edges_is_no_cylinder_its_top_keeps_its_corners():
    """Its sides lie on a circle within the tolerance (4.4 x 4.1 cm, the vertical edges rounded by 12 mm, as
    the pipeline's clouds draw small boxes), but its top's outline fills its least rectangle (0.93) where a
    disc's fills pi/4: no upright cylinder, whatever the box's own fit (on the pipeline's clouds a tilted or
    noisy box frame lowers it below the circle's: 21000-21049 had two such boxes simulated as cans). A can of
    the same size still fits its cylinder."""
    box = _rounded_box()
    table = table_points()
    table = table[np.hypot(table[:, 0] - 0.35, table[:, 1]) > 0.04]
    P = np.vstack([table, box])
    L = np.r_[np.full(len(table), -1), np.zeros(len(box), int)].astype(np.int32)
    assert _cylinder_share(P, L) == 0.0 and _fit(P, L)[0] == "box"
    P, L = make_cloud([Obj("cylinder", (0.35, 0.0), (0.045, 0.045, 0.05))])
    assert _cylinder_share(P, L) > 0.9 and _fit(P, L)[0] == "cylinder"
