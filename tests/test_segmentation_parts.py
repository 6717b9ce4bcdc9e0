"""Parts that cannot stand on their own join the object they belong to (``attach_parts``): a bunny's ears,
held up beside its head and rising above it; a small object standing on the table beside it does not."""

import numpy as np

from segmentation import SegmentParams
from segmentation._graph import RegionGraph
from segmentation._parts import attach_parts


def _grid(x0, x1, y0, y1, z0, z1, step=0.004):
    g = np.mgrid[x0:x1:step, y0:y1:step, z0:z1:step].reshape(3, -1).T
    # the surface only: voxels on the faces of the block
    on = ((np.abs(g[:, 0] - x0) < step / 2) | (np.abs(g[:, 0] - g[:, 0].max()) < step / 2)
          | (np.abs(g[:, 1] - y0) < step / 2) | (np.abs(g[:, 1] - g[:, 1].max()) < step / 2)
          | (np.abs(g[:, 2] - g[:, 2].max()) < step / 2))
    return g[on]


def _attached(body, part, touching=True, colours=None, skip=()):
    """Whether ``attach_parts`` merges region ``part`` (voxels (M, 3), table frame) into ``body``: two
    regions (patches) whose junction the contraction did not merge (concave), or, not ``touching``, with no
    junction at all (the cloud has a gap between them). ``colours``: None (unknown), "same" or "different"
    colour histograms of the two."""
    xyz = np.vstack([body, part])
    patch = np.r_[np.zeros(len(body), int), np.ones(len(part), int)]
    nvox = np.bincount(patch).astype(float)
    hist = None
    if colours is not None:  # each region's voxels in one colour bin: the same bin, or two different ones
        hist = np.zeros((2, 4))
        hist[0, 0], hist[1, 0 if colours == "same" else 3] = nvox
    edges = (np.array([[0, 1]]), np.array([5.0]), np.array([-1.0]), np.array([0.0])) if touching else (
        np.zeros((0, 2), int), np.zeros(0), np.zeros(0), np.zeros(0))
    G = RegionGraph(nvox, hist, None, *edges, SegmentParams())
    attach_parts(G, patch, xyz, SegmentParams(skip=skip))
    return G.find(0) == G.find(1)


def test_a_bunnys_ears_join_its_body_a_neighbour_on_the_table_does_not():
    body = _grid(0.0, 0.07, 0.0, 0.04, 0.0, 0.045)  # 7 x 4 cm, 4.5 cm tall, on the table
    ears = _grid(0.072, 0.092, 0.01, 0.03, 0.025, 0.065)  # 2 x 2 cm, from 2.5 cm up to 6.5 cm, beside it
    assert _attached(body, ears)
    neighbour = _grid(0.072, 0.092, 0.01, 0.03, 0.0, 0.065)  # the same, standing on the table
    assert not _attached(body, neighbour)
    wide = _grid(0.072, 0.112, 0.0, 0.04, 0.025, 0.065)  # 4 cm wide: an object seen above its neighbour
    assert not _attached(body, wide)


def test_a_part_held_up_across_a_gap_in_the_cloud_joins_the_region_under_it():
    """A duck's head, its neck missing from the cloud: no junction links it to the body. Of the body's
    colour, resting on it (its bottom 1.2 cm above the body's top, inside its footprint), it joins the body;
    the same piece beside the body, or 4 cm above it, or of another colour (an object standing on it), does
    not."""
    body = _grid(0.0, 0.05, 0.0, 0.05, 0.012, 0.036)  # its lower sides unseen, down to 1.2 cm
    head = _grid(0.01, 0.045, 0.005, 0.045, 0.044, 0.066)  # 1.2 cm above the body's top
    assert _attached(body, head, touching=False, colours="same")
    assert not _attached(body, head + [0.07, 0.0, 0.0], touching=False, colours="same")  # beside it
    assert not _attached(body, head + [0.0, 0.0, 0.03], touching=False, colours="same")  # 4 cm above it
    # an object of another colour standing on it stays an object (as a touching one does)
    assert not _attached(body, head, touching=False, colours="different")
    assert not _attached(body, head, touching=False, colours="same", skip=("resting_parts",))  # the rule, left out
