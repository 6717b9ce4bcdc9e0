"""The segmenter's clean-up after the contraction is a list of named steps (``segmentation._cleanup``), each of
which ``SegmentParams.skip`` can leave out (``bench/segmentation_steps.py`` measures each one that way)."""

import numpy as np
import pytest
from _grasp_fixtures import box_points, cylinder_points
from test_segmentation_tops import _region

from segmentation import CLEANUP_STEPS, SegmentParams, segment
from segmentation._cleanup import REGION_STEPS, Voxels, clean_up_regions


def _can_against_carton():
    """One region holding a carton and a can as tall as it, flush against its side (tops 3 mm apart)."""
    carton = box_points((0.3, 0.0), (0.19, 0.37, 0.128), step=0.0025)
    can = cylinder_points((0.3 + 0.095 + 0.0265, 0.1), 0.053, 0.131, step=0.0025)
    can = can[can[:, 0] > 0.3 + 0.095 + 0.002]
    carton = carton[~((carton[:, 0] > 0.395 - 0.001) & (np.abs(carton[:, 1] - 0.1) < 0.02))]
    return _region(carton, can)


def test_an_unknown_step_is_refused_with_the_known_names():
    with pytest.raises(ValueError, match="unknown clean-up step.*'shed_walls'"):
        SegmentParams(skip=("shed_wall",))
    assert SegmentParams(skip=CLEANUP_STEPS).skip == CLEANUP_STEPS


def test_every_region_step_is_named_and_each_skip_leaves_its_work_undone():
    region, xyz, nrm, edges, truth = _can_against_carton()
    v = Voxels(xyz, nrm, edges, min_top=0.01)
    stats = {}
    full = clean_up_regions(region, v, SegmentParams(), stats)
    assert stats["split_by_tops"] == 1  # the can is cut off the carton's level top
    assert np.bincount(full[truth == 0]).argmax() != np.bincount(full[truth == 1]).argmax()
    assert {name for name, _, _ in REGION_STEPS} <= set(CLEANUP_STEPS)
    for skip in ("split_by_tops", "level_tops"):  # the step, or only its level-tops rule
        stats = {}
        out = clean_up_regions(region, v, SegmentParams(skip=(skip, "carton_neighbours")), stats)
        assert stats["split_by_tops"] == 0 and np.array_equal(out, region), skip
        stats = {}  # the carton step, on its own, takes the can out of the carton's top too
        out = clean_up_regions(region, v, SegmentParams(skip=(skip,)), stats)
        assert stats["split_by_tops"] == 0 and stats["carton_neighbours"] == 1, skip
    stats = {}
    assert np.array_equal(clean_up_regions(region, v, SegmentParams(skip=CLEANUP_STEPS), stats), region)
    assert all(stats[key] == 0 for _, key, _ in REGION_STEPS)


def test_segment_reports_each_step_and_skipping_attach_parts_skips_its_merges():
    """A mug's handle hangs off its side: ``attach_parts`` joins it to the body (one merge); left out, no merge."""
    body = cylinder_points((0.3, 0.0), 0.08, 0.09, step=0.002)
    handle = box_points((0.3 + 0.04 + 0.012, 0.0), (0.02, 0.012, 0.05), step=0.002)
    handle[:, 2] += 0.025  # held up beside the body, not standing on the table
    table = np.stack(np.meshgrid(np.arange(0.0, 0.6, 0.004), np.arange(-0.3, 0.3, 0.004), [0.0]), -1).reshape(-1, 3)
    pts = np.concatenate([table, body, handle])
    full = segment(pts)
    assert {"attached", "slivers_dissolved", "split_by_tops", "walls_shed", "carton_neighbours"} <= set(full.stats)
    assert full.stats["attached"] >= 1 and len(full.objects) == 1
    assert segment(pts, params=SegmentParams(skip=("attach_parts",))).stats["attached"] == 0
