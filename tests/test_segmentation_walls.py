"""A strip of a can's side taken into a small box's region goes back to the can (``shed_neighbour_walls``);
a box's own sides, a cup and a region without a neighbour keep their voxels."""

import numpy as np
from _grasp_fixtures import box_points, cylinder_points

from segmentation import SegmentParams
from segmentation._voxels import knn_edges, normals_and_curvature, voxelize
from segmentation._walls import shed_neighbour_walls


def _voxels(clouds):
    """Voxels (5 mm) of the union of ``clouds``: (xyz, normals, edges, truth id per voxel: the cloud it came from)."""
    P = np.concatenate(clouds)
    truth_pts = np.concatenate([np.full(len(c), k) for k, c in enumerate(clouds)])
    vox = voxelize(P, 0.005)
    truth = np.zeros(len(vox.xyz), int)
    np.maximum.at(truth, vox.inverse, truth_pts)
    edges, _ = knn_edges(vox.xyz, 10, 2.5 * 0.005)
    normals, _ = normals_and_curvature(vox.xyz, 2.4 * 0.005)
    return vox.xyz, normals, edges, truth


def _box_and_can():
    box = box_points((0.30, 0.0), (0.045, 0.04, 0.055), step=0.0025)
    can = cylinder_points((0.30 + 0.0225 + 0.035, 0.0), 0.07, 0.085, step=0.0025)
    # the faces where they touch are hidden
    box = box[box[:, 0] < 0.3225 - 0.002]
    can = can[~((can[:, 0] < 0.3225 + 0.004) & (np.abs(can[:, 1]) < 0.02))]
    return box, can


def test_a_strip_of_a_cans_side_goes_back_to_the_can():
    box, can = _box_and_can()
    xyz, nrm, edges, truth = _voxels([box, can])
    # the segmenter joined the can's side next to the box (a 2 cm strip, up to its top's edge) to the box
    strip = (truth == 1) & (xyz[:, 0] < 0.3225 + 0.02) & (np.abs(xyz[:, 1]) < 0.025) & (xyz[:, 2] < 0.08)
    region = np.where((truth == 0) | strip, 0, 1)
    out, moved = shed_neighbour_walls(region, xyz, nrm, edges, SegmentParams())
    # what stands clearly outside the box's top, or rises above it, is the can's again; the can's side
    # within a few millimetres of the box's edge, below its top, cannot be told from the box's own side
    clear = strip & ((xyz[:, 0] > 0.3225 + 0.010) | (xyz[:, 2] > 0.055 + 0.010))
    assert clear.sum() > 12
    assert (out[clear] == 1).mean() >= 0.9
    assert moved <= strip.sum()
    assert (out[truth == 0] == 0).all()  # the box keeps every voxel of its own


def test_box_cup_and_lone_regions_keep_their_voxels():
    box, can = _box_and_can()
    xyz, nrm, edges, truth = _voxels([box, can])
    out, moved = shed_neighbour_walls(truth.copy(), xyz, nrm, edges, SegmentParams())
    assert moved == 0 and (out == truth).all()  # right already: nothing moves
    # a cup (its inside bottom is its only flat top, small within its rim) against a box: the rim stays
    outer = cylinder_points((0.30, 0.0), 0.08, 0.09, step=0.0025)
    outer = outer[outer[:, 2] < 0.09 - 1e-6]
    inner = cylinder_points((0.30, 0.0), 0.05, 0.08, step=0.0025, z0=0.01)
    inner[:, 2] = np.where(inner[:, 2] > 0.0899, 0.012, inner[:, 2])
    other = box_points((0.30 + 0.04 + 0.031, 0.0), (0.06, 0.06, 0.10), step=0.0025)
    xyz, nrm, edges, truth = _voxels([np.concatenate([outer, inner]), other])
    out, moved = shed_neighbour_walls(truth.copy(), xyz, nrm, edges, SegmentParams())
    assert moved == 0
    # a lone box with a strip of nothing beside it: no neighbour to give it to
    xyz, nrm, edges, truth = _voxels([box])
    out, moved = shed_neighbour_walls(np.zeros(len(xyz), int), xyz, nrm, edges, SegmentParams())
    assert moved == 0
