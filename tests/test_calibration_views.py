"""`bijcr calibrate` writes the depth views its cloud came from (views.npz): placed where the cloud is, and
what they saw through is empty."""

import numpy as np
import pytest
from _synth_fixtures import true_T_b1_c
from scipy.spatial import cKDTree

from bimanual_app.scene import load_scene
from bimanual_app.views import load_views, seen_free
from calibration._stage import calibrate_stage


def _pixels_in_b1(views, v: int) -> np.ndarray:
    """(K, 3) the points in b1 that view ``v``'s kept depth pixels back-project to."""
    rows, cols = np.nonzero(np.isfinite(views.depth[v]))
    z = views.depth[v][rows, cols].astype(np.float64)
    fx, fy, cx, cy = views.K[v]
    p_c = np.stack([(cols - cx) / fx * z, (rows - cy) / fy * z, z], axis=1)
    return p_c @ views.T_b1_c[v][:3, :3].T + views.T_b1_c[v][:3, 3]


def test_views_put_each_pixel_on_the_cloud_and_see_through_free_space(synth_none, tmp_path):
    calibrate_stage(synth_none, tmp_path / "cal", figure=False)
    views = load_views(tmp_path / "cal" / "views.npz")
    import open3d as o3d

    cloud = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "cal" / "scene_b1.ply")).points)
    assert len(views) == 6 and np.all(np.isfinite(views.K))  # rendered maps are pinhole images
    # the cameras where they truly were (noise none)
    T_true = true_T_b1_c(load_scene(synth_none))
    assert np.max(np.linalg.norm(views.T_b1_c[:, :3, 3] - T_true[:, :3, 3], axis=1)) < 2e-3
    tree = cKDTree(cloud)
    for v in range(len(views)):
        assert np.percentile(tree.query(_pixels_in_b1(views, v))[0], 95) < 1e-3  # the robots' own points aside
    sample = cloud[::25]
    assert seen_free(sample, views).mean() < 0.01  # nobody sees through a surface
    # exact views agree on their own cloud (to the maps' sampling); the calibration says how far
    import json

    info = json.loads((tmp_path / "cal" / "calibration.json").read_text())["cloud"]
    assert views.disagreement < 0.003 and info["views_disagreement_m"] == pytest.approx(views.disagreement)
    above = sample + np.array([0.0, 0.0, 0.05])
    above = above[tree.query(above)[0] > 0.02]  # clear of everything
    assert seen_free(above, views).mean() > 0.8


def test_true_views_of_a_rendered_scene_put_each_pixel_on_the_true_cloud(synth_none):
    """The bench's ground-truth rows get the true depth views (``ground_truth_views``): each depth pixel, at the
    maps' stride, lands on the true cloud, and no view sees through it."""
    from bimanual_app.scene.truth import ground_truth_cloud, ground_truth_views

    views = ground_truth_views(synth_none)
    P = ground_truth_cloud(synth_none)[0]
    assert len(views) == 6 and np.all(np.isfinite(views.K))
    tree = cKDTree(P)
    for v in range(len(views)):
        assert np.max(tree.query(_pixels_in_b1(views, v)[::7])[0]) < 1e-4  # the same pixels, the same geometry
    assert seen_free(P[::25], views).mean() < 0.001
