"""A carton is a box under its top (``split_carton_neighbours``): a cylinder left in a carton's region beside
it becomes a region of its own; the carton's own walls, a strip of noise and a non-carton region stay."""

import numpy as np

from segmentation import SegmentParams
from segmentation._cartons import split_carton_neighbours
from segmentation._voxels import knn_edges

STEP = 0.005


def _carton(size=(0.30, 0.18, 0.10)):
    """Voxels (M, 3) and normals of a box's top and walls, centred at the origin, on the table (z = 0)."""
    lx, ly, h = size
    xs, ys = (np.arange(-v / 2, v / 2 + 1e-9, STEP) for v in (lx, ly))
    zs = np.arange(0.0, h + 1e-9, STEP)
    X, Y = np.meshgrid(xs, ys)
    top = np.c_[X.ravel(), Y.ravel(), np.full(X.size, h)]
    walls, nw = [], []
    for x0, n in ((-lx / 2, (-1, 0, 0)), (lx / 2, (1, 0, 0))):
        Y2, Z2 = np.meshgrid(ys, zs[:-1])
        walls.append(np.c_[np.full(Y2.size, x0), Y2.ravel(), Z2.ravel()])
        nw.append(np.tile(n, (Y2.size, 1)))
    for y0, n in ((-ly / 2, (0, -1, 0)), (ly / 2, (0, 1, 0))):
        X2, Z2 = np.meshgrid(xs, zs[:-1])
        walls.append(np.c_[X2.ravel(), np.full(X2.size, y0), Z2.ravel()])
        nw.append(np.tile(n, (X2.size, 1)))
    return np.vstack([top, *walls]), np.vstack([np.tile((0, 0, 1), (len(top), 1)), *nw]).astype(float)


def _cylinder(centre, r=0.03, h=0.14):
    """Voxels and normals of an upright cylinder's side and top."""
    a = np.arange(0, 2 * np.pi, STEP / r)
    zs = np.arange(0.0, h, STEP)
    A, Z = np.meshgrid(a, zs)
    side = np.c_[centre[0] + r * np.cos(A.ravel()), centre[1] + r * np.sin(A.ravel()), Z.ravel()]
    ns = np.c_[np.cos(A.ravel()), np.sin(A.ravel()), np.zeros(A.size)]
    g = np.arange(-r, r + 1e-9, STEP)
    X, Y = np.meshgrid(g, g)
    inside = X.ravel() ** 2 + Y.ravel() ** 2 <= r * r
    top = np.c_[centre[0] + X.ravel()[inside], centre[1] + Y.ravel()[inside], np.full(inside.sum(), h)]
    return np.vstack([side, top]), np.vstack([ns, np.tile((0, 0, 1), (len(top), 1))]).astype(float)


def _split(*parts):
    xyz = np.vstack([p[0] for p in parts])
    normals = np.vstack([p[1] for p in parts])
    edges, _ = knn_edges(xyz, 10, 2.5 * STEP)
    region = np.zeros(len(xyz), int)  # one region: what the contraction and the part rules left
    return split_carton_neighbours(region, xyz, normals, edges, SegmentParams()), [len(p[0]) for p in parts]


def test_a_cylinder_in_a_cartons_region_beside_it_is_split_off():
    (out, n_split), (n_carton, n_cyl) = _split(_carton(), _cylinder((0.0, 0.09 + 0.03)))
    assert n_split == 1
    carton, cyl = out[:n_carton], out[n_carton:]
    assert np.all(carton == 0)  # the carton keeps all of its voxels
    assert np.mean(cyl != 0) > 0.6 and len(set(cyl[cyl != 0])) == 1  # the cylinder, but its side against the carton
    low = _cylinder((0.0, 0.09 + 0.03))[0][:, 2] <= 0.1 + 0.02
    assert np.all(cyl[~low] != 0)  # all of it that rises above the carton's top


def test_a_carton_alone_and_a_strip_of_noise_beside_it_stay_whole():
    (out, n_split), _ = _split(_carton())
    assert n_split == 0 and np.all(out == 0)
    strip = np.c_[np.linspace(-0.1, 0.1, 40), np.full(40, 0.105), np.full(40, 0.05)]  # 1.5 cm out, a line
    (out, n_split), _ = _split(_carton(), (strip, np.tile((0.0, 1.0, 0.0), (40, 1))))
    assert n_split == 0 and np.all(out == 0)


def test_a_region_without_a_cartons_top_is_left_alone():
    # two cylinders: no rectangular top 8 cm wide, whatever sticks out of what
    (out, n_split), _ = _split(_cylinder((0.0, 0.0), r=0.05), _cylinder((0.0, 0.11)))
    assert n_split == 0 and np.all(out == 0)


def test_a_carton_whose_top_was_seen_in_part_keeps_its_walls():
    xyz, normals = _carton()
    seen = (xyz[:, 2] < 0.099) | (xyz[:, 0] < 0.05)  # the top's far end (10 cm of 30) not seen
    (out, n_split), _ = _split((xyz[seen], normals[seen]))
    assert n_split == 0 and np.all(out == 0)


def _sheet(x0, x1, y0, y1, z):
    """Upward-facing voxels of a flat sheet at height ``z``."""
    X, Y = np.meshgrid(np.arange(x0, x1, STEP), np.arange(y0, y1, STEP))
    xyz = np.c_[X.ravel(), Y.ravel(), np.full(X.size, z)]
    return xyz, np.tile((0.0, 0.0, 1.0), (len(xyz), 1))


def test_a_copy_of_the_top_above_it_and_a_low_sheet_beside_it_stay():
    # a view registered 2.5 cm off: a second copy of part of the top, inside the carton's outline
    (out, n_split), _ = _split(_carton(), _sheet(-0.12, 0.02, -0.08, 0.08, 0.125))
    assert n_split == 0 and np.all(out == 0)
    # a sheet of table 2 cm up beside the carton: not as high as the carton, so not a neighbour it hides
    (out, n_split), _ = _split(_carton(), _sheet(-0.1, 0.1, 0.105, 0.16, 0.02))
    assert n_split == 0 and np.all(out == 0)


def test_a_can_whose_top_is_level_with_the_cartons_is_split_off():
    """A can as tall as the carton, against its side: its top disc joins the carton's top plateau and
    stretches the plateau's rectangle over it; the rectangle is the carton's core (the plateau's narrow end
    cut off), so the can lies outside it and becomes a region of its own."""
    carton = _carton()
    can = _cylinder((0.15 + 0.03, 0.0), r=0.03, h=0.10)  # against the +x end, its top at the carton's height
    keep = can[0][:, 0] > 0.15 + 0.002  # the half facing the carton is hidden
    (out, n_split), (n_carton, _) = _split(carton, (can[0][keep], can[1][keep]))
    assert n_split == 1
    assert np.mean(out[:n_carton] == 0) > 0.98  # the carton keeps (nearly) all of its voxels
    assert np.mean(out[n_carton:] != 0) > 0.8


def test_a_cartons_top_seen_narrower_at_one_end_keeps_that_end():
    """The far end of a carton's top seen only in a narrow strip (the rest of that end hidden): a narrow end of
    the plateau, but with no side of its own it is the carton's top, not a neighbour."""
    xyz, normals = _carton()
    hidden = (xyz[:, 0] > 0.07) & (np.abs(xyz[:, 1]) > 0.03) & (xyz[:, 2] > 0.099)  # 8 cm of the top, all but a strip
    hidden |= (xyz[:, 0] > 0.07) & (xyz[:, 2] < 0.099)  # and the walls under that end
    (out, n_split), _ = _split((xyz[~hidden], normals[~hidden]))
    assert n_split == 0 and np.all(out == 0)


def test_a_carton_with_a_corner_of_its_top_unseen_still_sheds_a_level_can():
    """A corner of the carton's top hidden (behind a neighbour): its plateau fills under ``FILL`` of its rectangle,
    but two adjacent sides of it are seen whole (a corner of its own, which a disc has not): still a carton, and a
    can level with it against its side is split off."""
    from segmentation._cartons import FILL

    xyz, normals = _carton()
    hidden = (xyz[:, 2] > 0.099) & (xyz[:, 0] - 0.03 > 0.0) & (xyz[:, 1] + 0.0 < 0.0) \
        & ((xyz[:, 0] - 0.03) / 0.12 - (xyz[:, 1] - 0.0) / 0.09 > 0.6)  # a triangle off the (+x, -y) corner
    top = (xyz[:, 2] > 0.099) & ~hidden
    assert top.sum() / ((xyz[:, 2] > 0.099).sum()) < FILL  # the old test alone called it no carton
    can = _cylinder((-0.08, 0.09 + 0.03), r=0.03, h=0.10)  # against the +y side, its top level with the carton's
    keep = can[0][:, 1] > 0.09 + 0.002
    (out, n_split), (n_carton, _) = _split((xyz[~hidden], normals[~hidden]), (can[0][keep], can[1][keep]))
    assert n_split == 1
    assert np.mean(out[:n_carton] == 0) > 0.98 and np.mean(out[n_carton:] != 0) > 0.6  # its side against the carton stays


def test_a_flat_disc_is_no_carton_even_with_a_corner_test():
    """A flat-topped disc 9 cm across (wider than ``CARTON_WIDTH``) lines each side of its square over less than
    ``EDGE_COVER``: no carton, so a cylinder beside it in its region is left where it is."""
    from segmentation._cartons import _seen_corner

    g = np.arange(-0.045, 0.045 + 1e-9, STEP)
    X, Y = np.meshgrid(g, g)
    disc = np.c_[X.ravel(), Y.ravel()][X.ravel() ** 2 + Y.ravel() ** 2 <= 0.045 ** 2]
    assert not _seen_corner(disc, np.array([0.045, 0.045]))
    (out, n_split), _ = _split(_cylinder((0.0, 0.0), r=0.045, h=0.1), _cylinder((0.0, 0.075), r=0.03, h=0.14))
    assert n_split == 0 and np.all(out == 0)
