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


def _disc(cx, cy, r, z, keep=lambda x, y: True, step=0.004):
    """Voxels (M, 3) and upward normals of a flat disc's top at height z, where ``keep(x, y)``."""
    g = np.mgrid[cx - r:cx + r:step, cy - r:cy + r:step].reshape(2, -1).T
    g = g[(np.hypot(g[:, 0] - cx, g[:, 1] - cy) <= r) & keep(g[:, 0], g[:, 1])]
    xyz = np.c_[g, np.full(len(g), z)]
    return xyz, np.tile([0.0, 0.0, 1.0], (len(xyz), 1))


def _side(cx, cy, r, z0, z1, keep=lambda x, y: True, step=0.004):
    """Voxels and outward normals of a cylinder's side from z0 to z1, where ``keep(x, y)``."""
    a = np.arange(0.0, 2 * np.pi, step / r)
    a = a[keep(cx + r * np.cos(a), cy + r * np.sin(a))]
    z = np.arange(z0, z1, step)
    A, Z = np.meshgrid(a, z)
    xyz = np.c_[cx + r * np.cos(A.ravel()), cy + r * np.sin(A.ravel()), Z.ravel()]
    return xyz, np.c_[np.cos(A.ravel()), np.sin(A.ravel()), np.zeros(A.size)]


def _cut(body, part, skip=()):
    """Whether ``attach_parts`` (with normals) merges ``part`` into ``body`` ((xyz, normals) each): two regions
    of different colours across a flat junction, which colour alone keeps apart."""
    xyz, nrm = np.vstack([body[0], part[0]]), np.vstack([body[1], part[1]])
    patch = np.r_[np.zeros(len(body[0]), int), np.ones(len(part[0]), int)]
    nvox = np.bincount(patch).astype(float)
    hist = np.zeros((2, 4))
    hist[0, 0], hist[1, 3] = nvox
    G = RegionGraph(nvox, hist, None, np.array([[0, 1]]), np.array([8.0]), np.array([1.0]), np.array([1.0]),
                    SegmentParams())
    attach_parts(G, patch, xyz, SegmentParams(skip=skip), normals=nrm)
    return G.find(0) == G.find(1)


def _join(*parts):
    return np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])


def test_a_can_top_cut_in_two_by_its_print_is_one_top_a_neighbour_met_at_a_tangent_is_not():
    """A 6.6 cm can, 10 cm tall, whose side towards a carton no camera saw: a printed band cuts its top in two,
    and the half over the unseen side (no wall down to the table) floats, level with the other half and meeting
    it along the cut: it joins (rule ``cut_tops``), whatever its colour. A can top of its own, level with a
    carton's wall or a box's top and meeting it at a tangent, does not; nor does a half that reaches the table
    (two flush objects)."""
    r, h = 0.033, 0.10
    seen = _join(_disc(0.0, 0.0, r, h, lambda x, y: x <= 0.0), _side(0.0, 0.0, r, 0.0, h, lambda x, y: x <= 0.0))
    half = _join(_disc(0.0, 0.0, r, h, lambda x, y: x > 0.0), _side(0.0, 0.0, r, h - 0.008, h, lambda x, y: x > 0.0))
    assert _cut(seen, half)
    assert not _cut(seen, half, skip=("cut_tops",))  # the rule left out: colour keeps them apart
    standing = _join(half, _side(0.0, 0.0, r, 0.0, h, lambda x, y: x > 0.0))
    assert not _cut(seen, standing)  # reaches the table: an object flush with the other
    # a carton's wall (its top face a region of its own) and a can top floating beside it, tangent
    wall_y = np.arange(-0.08, 0.08, 0.004)
    wall_z = np.arange(0.0, h, 0.004)
    Y, Z = np.meshgrid(wall_y, wall_z)
    wall = (np.c_[np.full(Y.size, -r - 0.002), Y.ravel(), Z.ravel()], np.tile([1.0, 0.0, 0.0], (Y.size, 1)))
    can_top = _join(_disc(0.0, 0.0, r, h), _side(0.0, 0.0, r, h - 0.008, h))
    assert not _cut(wall, can_top)
    # ... or beside a box's top at its height (the box's sides seen down to the table)
    box = _grid(-0.099, -r - 0.002, -0.05, 0.05, 0.0, h + 0.001)
    box_n = np.where(np.abs(box[:, 2] - box[:, 2].max())[:, None] < 0.002, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    assert not _cut((box, box_n), can_top)


def test_one_primitive_top_tells_one_top_from_two_met_at_a_tangent():
    from segmentation._parts import one_primitive_top

    g = np.mgrid[-0.04:0.04:0.005, -0.04:0.04:0.005].reshape(2, -1).T
    disc = g[np.hypot(g[:, 0], g[:, 1]) <= 0.033]  # a 6.6 cm can's top
    box = np.mgrid[0:0.05:0.005, 0:0.05:0.005].reshape(2, -1).T  # a 5 cm box's
    carton = np.mgrid[0:0.3:0.005, 0:0.17:0.005].reshape(2, -1).T
    assert one_primitive_top(disc) and one_primitive_top(box) and one_primitive_top(carton)
    assert one_primitive_top(disc[::2])  # a ragged top (every other cell missing) is still one top
    assert not one_primitive_top(np.vstack([disc, disc + [0.067, 0.0]]))  # two cans side by side
    assert not one_primitive_top(np.vstack([box, disc + [0.086, 0.025]]))  # a can beside a box
    assert not one_primitive_top(np.vstack([carton, disc + [0.15, 0.205]]))  # ... beside a carton's long side
    assert not one_primitive_top(np.vstack([carton, disc + [0.335, 0.085]]))  # ... its short side


def test_a_part_held_up_by_a_smaller_region_on_the_table_joins_it():
    """A duck seen from above: its head (a region of its own at the concave neck) has more voxels than the body
    under it, which reaches the table. The head joins the body though it is the larger (rule ``held_parts``);
    the same head beside a smaller object standing on the table (outside its footprint) does not."""
    body = _grid(0.0, 0.07, 0.0, 0.05, 0.0, 0.045, step=0.008)  # sparse: its sides seen obliquely
    # dense (seen from above), from 2.2 cm up: its lower part beside the body's upper part, not resting on it
    head = _grid(0.025, 0.05, 0.015, 0.04, 0.022, 0.07, step=0.0025)
    assert len(head) > len(body)
    assert _attached(body, head, colours="same")
    assert not _attached(body, head, colours="same", skip=("held_parts",))
    beside = _grid(0.075, 0.115, 0.005, 0.045, 0.022, 0.07, step=0.0025)  # 4 cm wide, beside it: an object
    assert not _attached(body, beside, colours="same")
