"""Per-image masks as extra evidence: they split what neither shape nor colour can, and are optional."""

from __future__ import annotations

import numpy as np
import pytest
from _seg_fixtures import PALETTE, make_table_scene, write_mask_scene
from test_segmentation_objects import best_iou, flush_boxes

from bimanual_app.io_utils import InputError
from segmentation import MaskViews, segment

RED = PALETTE[0]


@pytest.fixture(scope="module")
def twins():
    """Two flush boxes of one colour: one segment by shape and colour alone."""
    return make_table_scene(0, flush_boxes(colour_b=RED), n_points=9_000)


def test_per_point_mask_ids_split_flush_twins(twins):
    s = twins
    assert len(segment(s.points, s.colors).objects) == 1
    rng = np.random.default_rng(0)
    # two views, each seeing a random 60% of the points; ids differ between views (view 2 uses 7 and 9)
    ids = np.full((len(s.points), 2), -1, np.int64)
    seen = rng.random((len(s.points), 2)) < 0.6
    ids[seen[:, 0], 0] = (s.labels + 1)[seen[:, 0]]
    ids[seen[:, 1], 1] = np.array([0, 7, 9])[(s.labels + 1)][seen[:, 1]]
    flip = rng.random(len(s.points)) < 0.03  # a few wrong pixels at mask borders
    ids[flip, 0] = 0
    r = segment(s.points, s.colors, mask_ids=ids)
    assert len(r.objects) == 2
    assert best_iou(s.labels, r.labels).min() > 0.85


def test_masks_from_a_scene_folder(tmp_path, twins):
    s = twins
    root = write_mask_scene(tmp_path / "scene", s)
    mv = MaskViews.from_scene(root, np.eye(4), 1.0)
    assert len(mv) == 4
    ids = mv.lookup(s.points)
    known = ids >= 0
    assert known.any(1).mean() > 0.95
    truth = np.broadcast_to((s.labels + 1)[:, None], ids.shape)
    assert np.mean(ids[known] == truth[known]) > 0.97  # nearest pixel within 8 mm: borders may differ
    r = segment(s.points, s.colors, mask_ids=mv)
    assert len(r.objects) == 2
    # in another frame and scale: x_b1 = T_b1_w (scale x_w)
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.0]
    mv2 = MaskViews.from_scene(root, T, 1.0)
    assert (mv2.lookup(s.points + [0.1, -0.2, 0.0]) >= 0).any(1).mean() > 0.95


def test_masks_do_not_merge_what_shape_splits():
    s = make_table_scene(3, 5, n_points=40_000)
    ids = np.where(s.labels >= 0, 1, 0)[:, None]  # a useless mask: every object is "instance 1"
    r = segment(s.points, s.colors, mask_ids=ids)
    assert len(r.objects) == 5


def test_scene_without_masks_is_an_input_error(tmp_path, twins):
    root = write_mask_scene(tmp_path / "scene", twins)
    for p in root.rglob("masks/*.png"):
        p.unlink()
    with pytest.raises(InputError) as e:
        MaskViews.from_scene(root, np.eye(4), 1.0)
    assert "mask" in str(e.value)
