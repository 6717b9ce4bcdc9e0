"""The capture's depth views: what a camera saw through (``bimanual_app.views``)."""

import numpy as np
import pytest
from _views_fixtures import render, ring_of_cameras

from bimanual_app.io_utils import InputError
from bimanual_app.views import DepthViews, load_views, seen_free, write_views

CYL = ((0.3, 0.0), 0.03, 0.08)


def test_a_point_is_free_only_where_a_camera_saw_past_it():
    views = render(ring_of_cameras((0.3, 0.0, 0.04), [-90]), [CYL])  # one camera, on the -y side
    P = np.array([
        [0.3, -0.06, 0.04],   # between the camera and the cylinder: seen through
        [0.3, 0.06, 0.04],    # behind the cylinder: occluded
        [0.3, -0.032, 0.04],  # 2 mm in front of its surface: within the tolerance
        [0.3, 0.0, 0.04],     # inside it
        [2.0, 0.0, 0.04],     # outside the image
        [0.3, -0.5, 0.5],     # behind the camera
    ])
    assert seen_free(P, views, tol=0.005).tolist() == [True, False, False, False, False, False]
    # a camera on the other side sees behind it
    both = render(ring_of_cameras((0.3, 0.0, 0.04), [-90, 90]), [CYL])
    assert seen_free(P, both, tol=0.005).tolist() == [True, True, False, False, False, False]


def test_a_pixel_without_a_surface_says_nothing():
    views = render(ring_of_cameras((0.3, 0.0, 0.04), [-90]), [CYL])
    P = np.array([[0.3, -0.06, 0.04]])
    assert seen_free(P, views)[0]
    holes = DepthViews(views.T_b1_c, views.K, np.full_like(views.depth, np.nan), views.arm)
    assert not seen_free(P, holes)[0]
    no_pinhole = DepthViews(views.T_b1_c, np.full_like(views.K, np.nan), views.depth, views.arm)
    assert not seen_free(P, no_pinhole)[0]


def test_views_round_trip_and_bad_files_name_the_field(tmp_path):
    views = render(ring_of_cameras((0.3, 0.0, 0.04), [-90, 0]), [CYL])
    path = write_views(tmp_path / "views.npz", views)
    back = load_views(path)
    assert np.allclose(back.T_b1_c, views.T_b1_c) and np.array_equal(np.isnan(back.depth), np.isnan(views.depth))
    assert not list(tmp_path.glob("*.tmp*"))
    np.savez(tmp_path / "bad.npz", T_b1_c=views.T_b1_c, K=views.K, arm=views.arm)
    with pytest.raises(InputError, match="depth"):
        load_views(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match="K"):
        DepthViews(views.T_b1_c, views.K[:1], views.depth, views.arm)
