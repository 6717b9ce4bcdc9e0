"""The one robust plane fitter (segmentation.fit_plane) and its users: the segmentation's table, the physics
preview's table (bimanual_app.simulation.fit_table) and the plane sweep's dominant plane (reconstruction)."""

import numpy as np
import pytest

from segmentation import fit_plane, uniform_sample

UP = np.array([0.0, 0.0, 1.0])


def _patch(n, lo, hi, z, noise, seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(lo, hi, (n, 2))
    return np.c_[xy, np.full(n, z) + rng.normal(0.0, noise, n)]


def _table_and_box_top(seed=0):
    """A table at z = 0.01 through b1's origin and a bigger, denser box top 30 cm above it."""
    table = _patch(3000, -0.2, 0.8, 0.01, 0.002, seed)
    top = _patch(6000, 0.2, 0.6, 0.31, 0.001, seed + 1)
    return np.vstack([top, table])


def test_prefers_the_level_plane_near_the_origin_over_a_bigger_one():
    P = _table_and_box_top()
    table = fit_plane(P, 0.008, up=UP, near=0.2)
    assert abs(abs(table.normal[2]) - 1) < 1e-3
    assert abs(abs(table.offset) - 0.01) < 1e-3  # the table, not the box top
    biggest = fit_plane(P, 0.008)  # no "up": the plane with most support
    assert abs(abs(biggest.offset) - 0.31) < 1e-3
    assert biggest.support >= 5000


def test_the_table_through_the_origin_wins_over_a_floor_seen_far_wider():
    """A floor 75 cm down seen over 5 x 5 m outnumbers the 1.2 x 0.8 m table in an evenly spread sample (more
    than three to one), and so do three walls of the room: the table, the level plane through b1's origin, is
    still the one taken, by the segmentation and by the preview."""
    from bimanual_app.simulation import fit_table as preview_table
    from segmentation import SegmentParams
    from segmentation._table import fit_table

    floor = _patch(12000, -2.5, 2.5, -0.75, 0.0005, 4)
    table = _patch(3000, -0.1, 1.1, -0.001, 0.0005, 5)
    table[:, 1] = table[:, 1] * 0.8 / 1.2 - 0.4
    walls = [_patch(n, -2.5, 2.5, 0.0, 0.0005, 6 + k)[:, order] + offset for k, (n, order, offset) in enumerate(
        [(6000, [2, 0, 1], [2.8, 0.0, 0.0]), (5000, [0, 2, 1], [0.0, 2.5, 0.0]), (4000, [2, 0, 1], [-2.2, 0.0, 0.0])])]
    P = np.vstack([floor, table, *walls])  # the room's floor and three walls all hold more points than the table
    assert len(table) < len(floor) / 3
    fit = fit_plane(P, 0.008, up=UP, near=0.2)
    assert abs(fit.offset) < 0.005
    assert abs(abs(fit_plane(P, 0.008, up=UP).offset) - 0.75) < 0.005  # without "near": the bigger level plane
    seg = fit_table(P, SegmentParams())
    assert abs(seg.offset) < 0.005 and seg.extent.max() < 1.5
    assert abs(preview_table(P).d) < 0.005


def test_level_only_refuses_a_wall_and_otherwise_takes_it():
    rng = np.random.default_rng(2)
    wall = np.c_[np.full(2000, 0.9), rng.uniform(-0.5, 0.5, 2000), rng.uniform(0.0, 0.8, 2000)]
    assert fit_plane(wall, 0.006, up=UP, level_only=True) is None
    fit = fit_plane(wall, 0.006, up=UP)
    assert abs(abs(fit.normal[0]) - 1) < 1e-6 and abs(abs(fit.offset) - 0.9) < 1e-6
    assert fit_plane(wall[:40], 0.006) is None  # too few points for a plane
    assert fit_plane(wall[:40], 0.006, min_points=10) is not None


def test_noise_is_measured_and_the_fit_is_a_fixed_point():
    P = _patch(20000, -0.5, 0.5, 0.0, 0.004, 3)  # noise wider than the RANSAC window
    a = fit_plane(P, 0.006, up=UP, seed=0)
    assert 0.0035 < a.sigma < 0.0045
    assert a.fraction > 0.95  # the refit window (2.5 sigma) holds what RANSAC's 6 mm cut off
    # the same plane whatever the seed (or Open3D's threads, which reorder RANSAC's draws under load): the
    # refit's fixed point can differ by a point on the window's edge, 1e-6 here, not RANSAC's ~1e-4
    for seed in range(1, 9):
        b = fit_plane(P, 0.006, up=UP, seed=seed)
        assert abs(a.normal @ b.normal) > 1 - 1e-10 and abs(abs(a.offset) - abs(b.offset)) < 1e-5


def test_uniform_sample_spreads_one_point_per_voxel():
    P = np.vstack([_patch(50000, 0.0, 0.1, 0.3, 0.0, 4), _patch(2000, -0.5, 0.5, 0.0, 0.0, 5)])
    S = uniform_sample(P, 100_000, cell=0.01)
    keys = np.floor(S / 0.01).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(S)  # one per voxel
    assert np.count_nonzero(S[:, 2] > 0.2) <= 121  # the dense patch: at most its 11 x 11 voxels
    assert len(uniform_sample(P, 50)) == 50  # capped at n_max


def test_simulation_table_is_the_table_not_a_large_box_top():
    from bimanual_app.simulation import fit_table

    P = _table_and_box_top()
    table = fit_table(P, np.full(len(P), -1))
    assert table.normal[2] > 0.999 and abs(table.height(np.array([0.0, 0.0, 0.01]))) < 1e-3
    with pytest.raises(ValueError, match="near-horizontal"):
        rng = np.random.default_rng(6)
        fit_table(np.c_[np.full(500, 0.9), rng.uniform(-0.5, 0.5, 500), rng.uniform(0, 0.8, 500)])


def test_dense_plane_is_the_shared_fit_oriented_to_the_cameras():
    from bimanual_app.reconstruction._dense import fit_plane as dense_plane

    rng = np.random.default_rng(7)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]  # an SfM world has no "up"
    P = _table_and_box_top() @ R.T * 3.0  # and arbitrary units
    centres = np.array([[0.3, 0.2, 1.0]]) @ R.T * 3.0
    n, d, frac = dense_plane(P, centres, threshold=0.01 * 3.0)
    shared = fit_plane(P, 0.03, iterations=2000, noise_window=0.0, min_points=10)
    assert abs(abs(n @ shared.normal) - 1) < 1e-12 and abs(abs(d) - abs(shared.offset)) < 1e-12
    assert float(centres[0] @ n + d) > 0  # the cameras on its + side
    assert frac == pytest.approx(shared.fraction)
    assert dense_plane(P[:5], centres, 0.03)[2] == 0.0  # too few points: no plane
