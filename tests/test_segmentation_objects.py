"""Segmentation of generated table-top clouds: touching objects split, single objects kept whole."""

from __future__ import annotations

import numpy as np
import pytest
from _seg_fixtures import PALETTE, Obj, make_table_scene

from segmentation import SegmentParams, segment

RED, GREEN, BLUE = PALETTE[0], PALETTE[1], PALETTE[2]


def best_iou(gt: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """(K,) best IoU of each true object (gt labels 0..K-1) against the predicted segments."""
    K = int(gt.max()) + 1
    P = max(int(pred.max()) + 1, 1)
    inter = np.zeros((K, P))
    m = (gt >= 0) & (pred >= 0)
    np.add.at(inter, (gt[m], pred[m]), 1)
    gs = np.bincount(gt[gt >= 0], minlength=K)
    ps = np.bincount(pred[pred >= 0], minlength=P)
    return (inter / (gs[:, None] + ps[None, :] - inter + 1e-9)).max(1)


def flush_boxes(colour_b=BLUE, gap=0.0005):
    """Two boxes of the same height touching face to face (flush tops): only colour tells them apart."""
    a = Obj("box", np.array([0.40, 0.10]), 0.3, np.array([0.10, 0.06, 0.05]), RED.copy())
    b = Obj("box", a.xy + a.R[:2, :2] @ np.array([0.05 + 0.04 + gap, 0.0]), 0.3, np.array([0.08, 0.06, 0.05]),
            np.asarray(colour_b, float).copy())
    return [a, b]


def box_and_cylinder(colour=RED):
    """A box and a taller cylinder of the same colour, touching: only shape tells them apart."""
    c = Obj("box", np.array([0.40, -0.10]), 0.0, np.array([0.10, 0.07, 0.06]), colour.copy())
    d = Obj("cylinder", c.xy + np.array([0.05 + 0.035 + 0.0005, 0.0]), 0.0, np.array([0.07, 0.07, 0.10]), colour.copy())
    return [c, d]


def test_touching_boxes_of_different_colour_are_separated():
    s = make_table_scene(0, flush_boxes(), n_points=40_000)
    r = segment(s.points, s.colors)
    assert len(r.objects) == 2
    assert best_iou(s.labels, r.labels).min() > 0.85


def test_flush_boxes_of_one_colour_are_one_segment_without_other_evidence():
    # the honest limit: neither shape nor colour separates them; masks do (test_segmentation_masks)
    s = make_table_scene(0, flush_boxes(colour_b=RED), n_points=40_000)
    r = segment(s.points, s.colors)
    assert len(r.objects) == 1


def test_touching_box_and_cylinder_of_one_colour_are_separated_by_shape():
    s = make_table_scene(0, box_and_cylinder(), n_points=40_000)
    for colors in (s.colors, None):
        r = segment(s.points, colors)
        assert len(r.objects) == 2
        assert best_iou(s.labels, r.labels).min() > 0.9


def test_one_object_is_not_cut():
    big = Obj("box", np.array([0.40, 0.0]), 0.5, np.array([0.30, 0.18, 0.10]), BLUE.copy())
    mug = Obj("mug", np.array([0.40, 0.25]), 0.2, np.array([0.107, 0.08, 0.09]), RED.copy())  # handle + open top
    s = make_table_scene(1, [big, mug], n_points=60_000)
    r = segment(s.points, s.colors)
    assert len(r.objects) == 2
    assert best_iou(s.labels, r.labels).min() > 0.9
    big_id = int(np.bincount(r.labels[s.labels == 0][r.labels[s.labels == 0] >= 0]).argmax())
    ext = r.objects[big_id].extents
    assert np.allclose(ext, [0.30, 0.18, 0.10], atol=0.01)


@pytest.mark.parametrize("seed", [3, 4])
def test_random_scene_half_touching(seed):
    s = make_table_scene(seed, 6, touching=0.5, n_points=80_000)
    assert s.touching, "the scene must have touching objects"
    r = segment(s.points, s.colors)
    iou = best_iou(s.labels, r.labels)
    assert len(r.objects) == 6
    assert iou.min() > 0.8 and iou.mean() > 0.9


def test_sparse_cloud_without_colours():
    objs = flush_boxes(gap=0.02) + box_and_cylinder()
    s = make_table_scene(2, objs, n_points=10_000, colors=False, object_fraction=0.15)
    r = segment(s.points)
    assert len(r.objects) == 4
    assert best_iou(s.labels, r.labels).min() > 0.8
    from scipy.spatial import cKDTree

    obj = s.points[s.labels >= 0]
    d, _ = cKDTree(obj).query(obj, k=2)
    assert np.median(d[:, 1]) > 0.003  # it really was sparse: fewer points than voxels of 5 mm


def test_labels_follow_input_order():
    s = make_table_scene(5, box_and_cylinder(), n_points=30_000)
    r = segment(s.points, s.colors)
    perm = np.random.default_rng(0).permutation(len(s.points))
    r2 = segment(s.points[perm], s.colors[perm])
    assert r.labels.dtype == np.int32 and r.labels.shape == (len(s.points),)
    # the same object ids may come out in another order: compare through the best match
    same = r2.labels == np.where(r.labels[perm] >= 0, r.labels[perm], -1)
    assert same.mean() > 0.995
    # each point's label is its own object's, in input order
    assert best_iou(s.labels, r.labels).min() > 0.9


def test_objects_are_summarised_in_metres_in_b1():
    s = make_table_scene(0, box_and_cylinder(), n_points=40_000)
    r = segment(s.points, s.colors)
    for o in r.objects:
        assert o.points == int((r.labels == o.id).sum())
        assert np.allclose(o.rotation.T @ o.rotation, np.eye(3), atol=1e-9)
        assert np.allclose(o.rotation[:, 2], r.table.normal, atol=1e-6)
    dims = sorted((o.extents for o in r.objects), key=lambda e: e[2])
    assert np.allclose(dims[0], [0.10, 0.07, 0.06], atol=0.01)
    assert np.allclose(dims[1], [0.07, 0.07, 0.10], atol=0.01)
    assert abs(r.table.offset) < 0.002 and r.table.normal[2] > 0.999


def test_background_and_bases_are_not_objects():
    s = make_table_scene(6, box_and_cylinder(), n_points=40_000, background=True)
    base = Obj("box", np.array([0.0, 0.0]), 0.0, np.array([0.11, 0.11, 0.03]), GREEN.copy())  # a plate at b1
    s2 = make_table_scene(6, box_and_cylinder() + [base], n_points=40_000)
    r = segment(s2.points, s2.colors, bases=[[0.0, 0.0, 0.0]])
    assert len(r.objects) == 2
    assert np.all(r.labels[s2.labels == 2] == -1)
    r = segment(s.points, s.colors)
    assert np.all(r.labels[s.points[:, 2] < -0.1] == -1)  # the floor below the table


def test_parameters_can_be_changed_and_are_checked():
    p = SegmentParams().with_(voxel=0.004)
    assert p.voxel == 0.004
    with pytest.raises(TypeError):
        SegmentParams().with_(no_such_thing=1)


def test_a_cartons_footprint_is_not_stretched_by_a_neighbours_stray_voxels():
    """A few voxels of a touching cylinder's side left in the carton's region by the contraction must not
    make the cylinder look like a part inside the carton's footprint (it was merged into it): a large
    region's footprint for that test is its core, without slivers under 2 cm wide."""
    from segmentation._parts import HULL_MARGIN, _inside_hull, core_hull

    rng = np.random.default_rng(0)
    carton = np.stack([rng.uniform(0.0, 0.30, 6000), rng.uniform(0.0, 0.20, 6000)], axis=1)
    # a 5.5 cm cylinder against the carton's +x side, 12 of its side voxels in the carton's region
    a = rng.uniform(0, 2 * np.pi, 800)
    r = 0.0275 * np.sqrt(rng.uniform(0, 1, 800))
    cyl = np.stack([0.3275 + r * np.cos(a), 0.10 + r * np.sin(a)], axis=1)
    stray = np.stack([np.full(12, 0.352), np.linspace(0.09, 0.11, 12)], axis=1)
    region = np.vstack([carton, stray])
    core = core_hull(region)
    plain = core_hull(region, radius=0.0)
    assert np.mean(_inside_hull(plain, cyl, HULL_MARGIN)) >= 0.9  # what merged it
    assert np.mean(_inside_hull(core, cyl, HULL_MARGIN)) < 0.5
    assert np.mean(_inside_hull(core, carton, HULL_MARGIN)) > 0.99  # the carton itself keeps its footprint
