"""The capture's depth views: what a camera saw through (``bimanual_app.views``)."""

import numpy as np
import pytest
from _views_fixtures import render, ring_of_cameras

from bimanual_app.io_utils import InputError
from bimanual_app.views import DepthViews, load_views, see_past, seen_free, views_disagreement, write_views

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
    assert back.disagreement == 0.0
    from dataclasses import replace

    assert load_views(write_views(tmp_path / "d.npz", replace(views, disagreement=0.02))).disagreement == 0.02
    np.savez(tmp_path / "old.npz", T_b1_c=views.T_b1_c, K=views.K, depth=views.depth, arm=views.arm)
    assert load_views(tmp_path / "old.npz").disagreement == 0.0  # written before the field existed
    np.savez(tmp_path / "neg.npz", T_b1_c=views.T_b1_c, K=views.K, depth=views.depth, arm=views.arm,
             disagreement=-1.0)
    with pytest.raises(InputError, match="disagreement"):
        load_views(tmp_path / "neg.npz")
    np.savez(tmp_path / "bad.npz", T_b1_c=views.T_b1_c, K=views.K, arm=views.arm)
    with pytest.raises(InputError, match="depth"):
        load_views(tmp_path / "bad.npz")
    np.savez(tmp_path / "arm.npz", T_b1_c=views.T_b1_c, K=views.K, depth=views.depth, arm=views.arm[:1])
    with pytest.raises(InputError) as e:  # the field is named by the check, not guessed from a message
        load_views(tmp_path / "arm.npz")
    assert e.value.problems[0].field == "arm"
    with pytest.raises(ValueError, match="K"):
        DepthViews(views.T_b1_c, views.K[:1], views.depth, views.arm)


def _cloud_of(views: DepthViews) -> np.ndarray:
    """The points (N, 3) in b1 that ``views`` kept: each pixel's depth back along its ray."""
    V, H, W = views.depth.shape
    cols, rows = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    out = []
    for v in range(V):
        K, z = views.K[v], views.depth[v].astype(np.float64)
        c = np.stack([(cols - K[2]) / K[0] * z, (rows - K[3]) / K[1] * z, z], axis=-1).reshape(-1, 3)
        c = c[np.isfinite(c).all(axis=1)]
        out.append(c @ views.T_b1_c[v][:3, :3].T + views.T_b1_c[v][:3, 3])
    return np.concatenate(out)


def test_see_past_says_how_far_and_seen_free_is_its_threshold():
    views = render(ring_of_cameras((0.3, 0.0, 0.04), [-90]), [CYL])
    P = np.array([[0.3, -0.06, 0.04], [0.3, 0.06, 0.04], [2.0, 0.0, 0.04]])
    past = see_past(P, views)
    assert 0.03 < past[0] < 0.05  # 3 cm in front of the cylinder, along a ray looking down at it
    assert past[1] < 0 and past[2] == -np.inf  # occluded; outside the image
    assert seen_free(P, views, 0.02).tolist() == [True, False, False]
    assert seen_free(P, views, 0.06).tolist() == [False, False, False]


def test_the_views_disagreement_is_how_far_they_see_past_their_own_cloud():
    cams = ring_of_cameras((0.3, 0.0, 0.04), [-90, -30, 30, 90, 150, 210])
    views = render(cams, [CYL])
    assert views_disagreement(_cloud_of(views), views) < 0.002  # exact views agree
    # one view in six placed 3 cm too far along its axis (a real reconstruction's per-view error): the others'
    # cloud lies in front of what it saw
    far = views.depth.copy()
    far[0] += 0.03
    off = DepthViews(views.T_b1_c, views.K, far, views.arm)
    assert 0.02 < views_disagreement(_cloud_of(off), off) < 0.035
    assert views_disagreement(np.zeros((0, 3)), views) == 0.0
