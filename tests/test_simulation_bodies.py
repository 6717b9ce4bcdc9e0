"""Collision bodies from points: table plane fit, convex hull extruded to the table, boxes, masses."""

import numpy as np
import pytest

from bimanual_app.simulation import box_shape, fit_table, match_truth, shape_from_points, table_from_plane, truth_shapes
from bimanual_app.simulation._bodies import DEFAULT_DENSITY
from bimanual_app.transforms import make_T, so3_exp
from tests._task_fixtures import box_surface_points, table_points


def test_table_fit_finds_the_horizontal_plane_not_a_wall():
    rng = np.random.default_rng(0)
    table = table_points(4000, z=0.02)
    wall = np.stack([np.full(3000, 0.9), rng.uniform(-0.5, 0.5, 3000), rng.uniform(0, 0.8, 3000)], 1)
    pts = np.vstack([table, wall])
    plane = fit_table(pts, np.full(len(pts), -1))
    assert plane.normal[2] > 0.999
    assert abs(plane.height(np.array([0.3, 0.1, 0.02]))) < 0.002
    # the rectangle covers the table points (plus margin) and sits on the plane
    assert plane.size[0] > 1.0 and plane.size[1] > 0.9
    assert abs(plane.T_b1_t[2, 3] - 0.02) < 0.002


def test_table_fit_ignores_object_points_and_needs_enough_background():
    pts = np.vstack([table_points(2000), box_surface_points([0.3, 0, 0.05], [0.2, 0.2, 0.1], 3000)])
    labels = np.r_[np.full(2000, -1), np.zeros(3000, int)]
    plane = fit_table(pts, labels)
    assert abs(plane.d) < 0.002
    with pytest.raises(ValueError, match="background"):
        fit_table(pts[:40], np.full(40, -1))


def test_hull_from_visible_points_reaches_the_table_and_gets_its_mass_from_volume():
    size = np.array([0.05, 0.04, 0.10])
    pts = box_surface_points([0.3, 0.05, 0.05], size, 2000, noise=0.0005)
    pts = np.vstack([pts, [[0.3, 0.05, 0.4]]])  # a stray point far above: dropped as an outlier
    table = table_from_plane([0, 0, 1], 0.0)
    sh = shape_from_points(pts, table)
    assert sh.kind == "hull"
    world_v = sh.vertices @ sh.T_b1_o[:3, :3].T + sh.T_b1_o[:3, 3]
    assert world_v[:, 2].min() < 0.002  # extruded down to the table (the bottom was never seen)
    assert world_v[:, 2].max() < 0.105  # the stray point did not inflate it
    assert sh.volume == pytest.approx(np.prod(size), rel=0.15)  # noise widens a hull by ~1 mm a side
    assert sh.mass == pytest.approx(sh.volume * DEFAULT_DENSITY, rel=1e-6)
    # centroid at the box centre; faces index the vertices and point outwards
    assert np.allclose(sh.T_b1_o[:3, 3], [0.3, 0.05, 0.05], atol=0.004)
    c = sh.vertices.mean(0)
    a, b, d = (sh.vertices[sh.faces[:, i]] for i in range(3))
    assert np.all(np.einsum("ij,ij->i", np.cross(b - a, d - a), a - c) > -1e-12)


def test_box_shape_recovers_a_yawed_box():
    size = np.array([0.12, 0.05, 0.06])
    R = so3_exp(np.array([0, 0, 0.5]))
    local = box_surface_points([0, 0, 0], size, 2000, visible_only=False)
    pts = local @ R.T + [0.35, -0.1, 0.03]
    sh = shape_from_points(pts, table_from_plane([0, 0, 1], 0.0), kind="box")
    assert np.allclose(np.sort(sh.size), np.sort(size), atol=0.006)
    long_axis = sh.T_b1_o[:3, int(np.argmax(sh.size))]
    assert abs(abs(long_axis @ R[:, 0]) - 1) < 0.01


def test_degenerate_or_tiny_segments_are_refused():
    with pytest.raises(ValueError, match="at least 10"):
        shape_from_points(np.zeros((5, 3)))
    flat = np.c_[np.random.default_rng(0).uniform(0, 0.1, (100, 2)), np.zeros(100)]
    with pytest.raises(ValueError, match="degenerate"):
        shape_from_points(flat)
    with pytest.raises(ValueError, match="unknown primitive"):
        box_shape(np.eye(4), [0.1, 0.1, 0.1], kind="torus")


def test_truth_shapes_and_matching_to_estimates():
    objs = [{"id": 0, "kind": "box", "T_b1_o": make_T(np.eye(3), [0.3, 0, 0.05]).tolist(), "size": [0.05, 0.04, 0.1],
             "mass": 0.2},
            {"id": 1, "kind": "cylinder", "T_b1_o": make_T(np.eye(3), [0.4, 0.2, 0.04]).tolist(),
             "size": [0.06, 0.06, 0.08], "mass": 0.1}]
    truth = truth_shapes(objs)
    assert truth[0].mass == 0.2 and truth[1].kind == "cylinder"
    assert truth[1].volume == pytest.approx(np.pi * 0.03**2 * 0.08)
    est = {5: box_shape(make_T(np.eye(3), [0.41, 0.19, 0.04]), [0.06, 0.06, 0.08]),
           7: box_shape(make_T(np.eye(3), [0.31, 0.0, 0.05]), [0.05, 0.04, 0.1]),
           9: box_shape(make_T(np.eye(3), [0.0, -0.4, 0.05]), [0.05, 0.04, 0.1])}  # nothing real there
    assert match_truth(est, truth) == {5: 1, 7: 0}


def test_a_body_fitted_to_part_of_a_long_object_stands_for_it():
    """The visible half of a 40 cm box: its centre is 10 cm from the true centre, but it lies inside it."""
    truth = truth_shapes([{"id": 0, "kind": "box", "T_b1_o": make_T(np.eye(3), [0.35, -0.1, 0.06]).tolist(),
                           "size": [0.40, 0.16, 0.12], "mass": 0.5},
                          {"id": 1, "kind": "box", "T_b1_o": make_T(np.eye(3), [0.35, 0.2, 0.03]).tolist(),
                           "size": [0.05, 0.05, 0.06], "mass": 0.1}])
    part = box_shape(make_T(np.eye(3), [0.45, -0.1, 0.06]), [0.20, 0.16, 0.12])
    assert match_truth({3: part}, truth) == {3: 0}
    # beside the long box, not in it, and far from every centre: no real object there
    beside = box_shape(make_T(np.eye(3), [0.45, 0.05, 0.06]), [0.10, 0.08, 0.12])
    assert match_truth({4: beside}, truth) == {}
    # two estimates of one true object: the one that fills it more gets it
    inside = box_shape(make_T(np.eye(3), [0.30, -0.1, 0.06]), [0.25, 0.15, 0.11])
    half_out = box_shape(make_T(np.eye(3), [0.35, -0.16, 0.06]), [0.10, 0.16, 0.12])
    assert match_truth({1: half_out, 2: inside}, truth) == {2: 0}
    # a fragment wholly inside it (a few points split off the object) does not take it from the body that fills it
    fragment = box_shape(make_T(np.eye(3), [0.20, -0.1, 0.10]), [0.03, 0.03, 0.02])
    body = box_shape(make_T(np.eye(3), [0.35, -0.1, 0.06]), [0.50, 0.22, 0.13])  # pokes out past it: share < 1
    assert match_truth({5: fragment, 6: body}, truth) == {6: 0}
    assert match_truth({5: fragment}, truth) == {5: 0}


def test_auto_body_is_a_box_for_a_noisy_box_and_a_hull_for_a_cylinder():
    size = np.array([0.20, 0.12, 0.08])
    rng = np.random.default_rng(3)
    pts = box_surface_points([0.35, 0.0, 0.04], size, 6000, noise=0.002)
    # a view registered a little off: 4 % of the points, 1.5 cm outwards and up (the fused cloud's layers)
    bad = rng.choice(len(pts), 240, replace=False)
    pts[bad] += np.array([0.015, 0.0, 0.012])
    table = table_from_plane([0, 0, 1], 0.0)
    sh = shape_from_points(pts, table, kind="auto")
    assert sh.kind == "box"
    assert np.allclose(np.sort(sh.size), np.sort(size), atol=0.007)  # not inflated by the layer
    S = sh.surface_points_b1(spacing=0.01)
    local = (S - sh.T_b1_o[:3, 3]) @ sh.T_b1_o[:3, :3]
    on_face = np.isclose(np.abs(local), sh.size / 2, atol=1e-9).any(axis=1)
    assert on_face.all() and len(S) > 2 * (20 * 12)
    # a cylinder fills pi/4 of its box: it stays a hull (its round side is what a gripper meets)
    ang = rng.uniform(0, 2 * np.pi, 3000)
    cyl = np.c_[0.3 + 0.03 * np.cos(ang), 0.1 + 0.03 * np.sin(ang), rng.uniform(0, 0.1, 3000)]
    sh = shape_from_points(cyl, table, kind="auto")
    assert sh.kind == "hull"
    assert len(sh.surface_points_b1()) == len(sh.vertices)
    with pytest.raises(ValueError, match="kind must be"):
        shape_from_points(cyl, table, kind="mesh")


def test_trim_outer_drops_the_spread_not_the_body():
    from bimanual_app.simulation import trim_outer

    pts = box_surface_points([0.0, 0.0, 0.05], [0.1, 0.1, 0.1], 5000, noise=0.001)
    out = np.vstack([pts, pts[:100] + [0.03, 0.0, 0.0]])  # 2 % spread 3 cm outwards
    kept = trim_outer(out, np.array([0.0, 0.0, 1.0]))
    assert kept[:, 0].max() < 0.055  # the spread is gone ...
    assert np.all(np.ptp(kept, axis=0) > [0.096, 0.096, 0.046])  # ... the body is not (to the noise)
    assert np.array_equal(trim_outer(out[:20], np.array([0.0, 0.0, 1.0])), out[:20])  # too few to trim


def test_box_from_faces_ignores_a_neighbour_bleeding_into_the_segment():
    from bimanual_app.simulation import box_from_faces

    size = np.array([0.30, 0.18, 0.09])
    R = so3_exp(np.array([0, 0, 0.6]))
    box = box_surface_points([0, 0, 0], size, 6000, seed=4) @ R.T + [0.35, 0.0, 0.045]
    # 6 % of the segment is a cylinder standing against the box's long face (under-segmentation)
    rng = np.random.default_rng(5)
    ang = rng.uniform(0, 2 * np.pi, 400)
    c = np.array([0.35, 0.0, 0.0]) + R[:, 1] * (0.09 + 0.03)
    cyl = np.c_[c[0] + 0.03 * np.cos(ang), c[1] + 0.03 * np.sin(ang), rng.uniform(0, 0.1, 400)]
    pts = np.vstack([box, cyl])
    table = table_from_plane([0, 0, 1], 0.0)
    est, boxness = box_from_faces(pts, np.array([0.0, 0.0, 1.0]), table)
    assert boxness > 0.8
    assert np.allclose(np.sort(est.size), np.sort(size), atol=0.006)  # not widened by the cylinder
    yaw_err = np.degrees(np.arccos(min(1.0, abs(est.T_b1_o[:3, int(np.argmax(est.size))] @ R[:, 0]))))
    assert yaw_err < 2.0
    # the enclosing box of the same points is pulled off by the cylinder
    from bimanual_app.simulation._bodies import box_shape_from_points

    enclosing = box_shape_from_points(pts, np.array([0.0, 0.0, 1.0]))
    assert np.max(np.abs(np.sort(enclosing.size) - np.sort(size))) > 0.02
    _, b_cyl = box_from_faces(cyl, np.array([0.0, 0.0, 1.0]), table)
    assert b_cyl < 0.6  # a cylinder is not box-like


def test_long_box_keeps_its_end_faces_and_ignores_a_small_box_merged_into_it():
    """A 35 x 18 cm carton, one end face seen at a grazing angle, with a 4 x 4 cm box touching its long face,
    segmented as one object: the body the preview simulates has the carton's size (trimming 2 % of the
    points along its length cut the sparse end face away, and the 98th percentile that replaced it left the
    box 3 cm short; the small box's faces are too few to move the carton's)."""
    size = np.array([0.354, 0.181, 0.088])
    rng = np.random.default_rng(7)

    def by_area(c, s, n):  # points spread evenly over the visible faces (as a camera sees them), 1 mm noise
        s = np.asarray(s, float)
        faces = [(2, +1), (0, -1), (0, +1), (1, -1), (1, +1)]
        area = np.array([np.prod(np.delete(s, ax)) for ax, _ in faces])
        k = rng.choice(len(faces), n, p=area / area.sum())
        u = rng.uniform(-0.5, 0.5, (n, 3)) * s
        for i, (ax, sign) in enumerate(faces):
            u[k == i, ax] = sign * s[ax] / 2
        return np.asarray(c) + u + rng.normal(scale=0.001, size=(n, 3))

    carton = by_area([0.39, -0.03, 0.044], size, 12000)
    # the end face towards x- seen at a grazing angle: a tenth of its points
    end = np.isclose(carton[:, 0], 0.39 - size[0] / 2, atol=0.004)
    carton = carton[~end | (rng.uniform(size=len(carton)) < 0.1)]
    small = by_area([0.39, -0.03 - 0.0905 - 0.021, 0.025], [0.042, 0.042, 0.05], 500)
    pts = np.vstack([carton, small])
    sh = shape_from_points(pts, table_from_plane([0, 0, 1], 0.0), kind="auto")
    assert sh.kind == "box"
    assert np.allclose(np.sort(sh.size), np.sort(size), atol=0.008), sh.size
    assert np.allclose(sh.T_b1_o[:2, 3], [0.39, -0.03], atol=0.006)


def test_truth_meshes_are_their_convex_hulls_not_their_boxes():
    """A synthetic scene's torus is simulated (in synth and in the truth world) as the convex hull of its mesh:
    a disc, not the square box of its size; an unknown mesh still falls back to its box."""
    from bimanual_app.synth._objects import sample_spec

    spec = sample_spec("torus", np.random.default_rng(0))  # what synth put in the scene
    size = spec.size.tolist()
    T = make_T(np.eye(3), [0.3, 0.1, size[2] / 2])
    truth = truth_shapes([{"id": 0, "kind": "torus", "shape": "mesh", "T_b1_o": T.tolist(), "size": size, "mass": 0.05},
                          {"id": 1, "kind": "teapot", "shape": "mesh", "T_b1_o": T.tolist(), "size": size}])
    torus, other = truth[0], truth[1]
    assert torus.kind == "hull" and other.kind == "box" and torus.mass == 0.05
    assert np.allclose(torus.size, size, atol=1e-6)
    assert 0.6 < torus.volume / np.prod(size) < 0.8  # a (faceted) disc: pi/4 of its box at most
    corner = T[:3, 3] + np.array([0.45 * size[0], 0.45 * size[1], 0.0])
    assert not torus.contains(corner[None])[0] and other.contains(corner[None])[0]
    assert torus.contains(T[:3, 3][None])[0]  # (its hull: the hole is filled)


def test_enclosing_box_is_the_minimum_area_rectangle_longer_side_first():
    """box_shape_from_points: OpenCV's minimum-area rectangle of the footprint (centred, so float32 keeps
    sub-millimetre precision far from b1's origin), its longer side along the body's x."""
    from bimanual_app.simulation._bodies import box_shape_from_points

    size = np.array([0.12, 0.30, 0.08])  # longer along y before the yaw
    R = so3_exp(np.array([0.0, 0.0, 0.6]))
    centre = np.array([2.5, -1.7, 0.04])
    pts = box_surface_points(np.zeros(3), size, 4000, visible_only=False) @ R.T + centre
    box = box_shape_from_points(pts, np.array([0.0, 0.0, 1.0]))
    assert np.allclose(box.size, [0.30, 0.12, 0.08], atol=1e-4)
    assert np.allclose(box.T_b1_o[:3, 3], centre, atol=1e-4)
    assert abs(abs(box.T_b1_o[:3, 0] @ R[:, 1]) - 1) < 1e-6  # the body's x along the box's long side
    assert np.isclose(np.linalg.det(box.T_b1_o[:3, :3]), 1.0)


def test_contains_agrees_with_every_face_plane_at_once():
    from scipy.spatial import ConvexHull
    from scipy.spatial.transform import Rotation

    from bimanual_app.simulation._bodies import hull_shape

    rng = np.random.default_rng(3)
    V = rng.normal(size=(400, 3)) * [0.04, 0.03, 0.06]  # a hull of many faces
    T = make_T(Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix(), [0.3, 0.1, 0.05])
    body = hull_shape(T, V, 0.1)
    P = T[:3, 3] + rng.normal(size=(200_000, 3)) * 0.08
    local = (P - body.T_b1_o[:3, 3]) @ body.T_b1_o[:3, :3]
    eq = ConvexHull(body.vertices).equations
    for margin in (0.0, 0.015):
        ref = np.all(local @ eq[:, :3].T + eq[:, 3] <= margin, axis=1)
        got = body.contains(P, margin)
        np.testing.assert_array_equal(got, ref)
        assert 1000 < got.sum() < len(P) - 1000  # both answers exercised
