"""Regions holding two objects whose flat tops differ in height are split (``split_by_tops``); parts of one
object (a cup's inside bottom under its rim) and equal-height neighbours are not."""

import numpy as np
from _grasp_fixtures import box_points, cylinder_points

from segmentation import SegmentParams
from segmentation._tops import split_by_tops
from segmentation._voxels import knn_edges, normals_and_curvature, voxelize


def _region(*clouds):
    """Voxels (5 mm) of the union of ``clouds`` as one region: (region, xyz, normals, edges, truth id per voxel)."""
    P = np.concatenate(clouds)
    truth_pts = np.concatenate([np.full(len(c), k) for k, c in enumerate(clouds)])
    vox = voxelize(P, 0.005)
    xyz = vox.xyz
    truth = np.zeros(len(xyz), int)
    for k in range(len(clouds)):
        cnt = np.bincount(vox.inverse, truth_pts == k, len(xyz))
        truth[cnt > 0] = np.where(truth[cnt > 0] == 0, k, truth[cnt > 0]) if k else truth[cnt > 0]
    edges, _ = knn_edges(xyz, 10, 2.5 * 0.005)
    normals, _ = normals_and_curvature(xyz, 2.4 * 0.005)
    return np.zeros(len(xyz), int), xyz, normals, edges, truth


def test_a_small_box_merged_into_a_carton_is_split_off_by_its_lower_top():
    carton = box_points((0.3, 0.0), (0.20, 0.30, 0.10), step=0.0025)
    small = box_points((0.3 + 0.10 + 0.021, 0.05), (0.04, 0.04, 0.05), step=0.0025)  # against the +x face
    # the faces where they touch are hidden from every camera
    small = small[small[:, 0] > 0.4 + 0.002]
    carton = carton[~((carton[:, 0] > 0.4 - 0.001) & (np.abs(carton[:, 1] - 0.05) < 0.02) & (carton[:, 2] < 0.05))]
    region, xyz, nrm, edges, truth = _region(carton, small)
    out, n = split_by_tops(region, xyz, nrm, edges, SegmentParams())
    assert n == 1
    for k in (0, 1):  # each object is (nearly all) one region, the two regions differ
        ids, cnt = np.unique(out[truth == k], return_counts=True)
        assert cnt.max() >= 0.95 * cnt.sum()
    assert np.bincount(out[truth == 0]).argmax() != np.bincount(out[truth == 1]).argmax()


def test_a_cup_and_two_equal_boxes_are_not_split():
    outer = cylinder_points((0.3, 0.0), 0.08, 0.09, step=0.0025)
    outer = outer[outer[:, 2] < 0.09 - 1e-6]  # open at the top
    inner = cylinder_points((0.3, 0.0), 0.07, 0.08, step=0.0025, z0=0.01)  # its 'top' is the cup's inside bottom
    inner[:, 2] = np.where(inner[:, 2] > 0.0899, 0.012, inner[:, 2])
    region, xyz, nrm, edges, _ = _region(outer, inner)
    assert split_by_tops(region, xyz, nrm, edges, SegmentParams())[1] == 0
    a = box_points((0.3, 0.0), (0.06, 0.06, 0.07), step=0.0025)
    b = box_points((0.3 + 0.061, 0.0), (0.06, 0.06, 0.075), step=0.0025)  # 5 mm taller, flush against it
    region, xyz, nrm, edges, _ = _region(a, b)
    assert split_by_tops(region, xyz, nrm, edges, SegmentParams())[1] == 0


def test_a_can_as_tall_as_the_carton_it_stands_against_is_cut_off_its_top():
    """Tops 3 mm apart make one plateau; the can's disc bulges out of the carton's rectangle, joined along
    the chord where it touches the carton's side (task bench, seed 16), and is cut off there."""
    carton = box_points((0.3, 0.0), (0.19, 0.37, 0.128), step=0.0025)
    can = cylinder_points((0.3 + 0.095 + 0.0265, 0.1), 0.053, 0.131, step=0.0025)  # against the +x face
    can = can[can[:, 0] > 0.3 + 0.095 + 0.002]  # the half facing the carton is hidden
    carton = carton[~((carton[:, 0] > 0.395 - 0.001) & (np.abs(carton[:, 1] - 0.1) < 0.02))]
    region, xyz, nrm, edges, truth = _region(carton, can)
    out, n = split_by_tops(region, xyz, nrm, edges, SegmentParams())
    assert n == 1
    for k in (0, 1):
        ids, cnt = np.unique(out[truth == k], return_counts=True)
        assert cnt.max() >= 0.95 * cnt.sum()
    assert np.bincount(out[truth == 0]).argmax() != np.bincount(out[truth == 1]).argmax()


def test_a_carton_with_a_corner_missing_from_its_top_is_not_split():
    """One concave corner (a corner of the top no camera saw) is no second object."""
    carton = box_points((0.3, 0.0), (0.19, 0.37, 0.128), step=0.0025)
    bite = (carton[:, 0] > 0.3 + 0.095 - 0.04) & (carton[:, 1] > 0.185 - 0.05) & (carton[:, 2] > 0.128 - 0.001)
    region, xyz, nrm, edges, _ = _region(carton[~bite])
    assert split_by_tops(region, xyz, nrm, edges, SegmentParams())[1] == 0
