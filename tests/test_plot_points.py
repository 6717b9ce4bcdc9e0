"""The raster point drawing used by the stage figures (bimanual_app/plot_points.py)."""

from __future__ import annotations

import numpy as np
import pytest

from bimanual_app.plot_points import draw_points, splat_image


def test_splat_puts_each_point_in_its_pixel_and_later_points_win():
    u = np.array([0.05, 0.05, 0.95, 2.0])  # the last one is outside the window
    v = np.array([0.05, 0.05, 0.45, 0.2])
    rgb = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 1.0]])
    image, pixel = splat_image(u, v, rgb, (0.0, 1.0), (0.0, 0.5), resolution=10)
    assert image.shape == (5, 10, 4) and pixel == pytest.approx(0.1)
    assert np.allclose(image[0, 0], [0, 1, 0, 1])  # second point over the first
    assert np.allclose(image[4, 9], [0, 0, 1, 1])  # row index grows with v
    assert image[..., 3].sum() == 2  # the point outside the window is dropped, the rest is transparent


def test_splat_size_covers_a_square():
    image, _ = splat_image(np.array([0.55]), np.array([0.55]), np.ones((1, 3)), (0, 1), (0, 1), 10, size_px=2)
    assert image[..., 3].sum() == 4


def test_splat_checks_shapes_and_window():
    with pytest.raises(ValueError, match="expected"):
        splat_image(np.zeros(3), np.zeros(3), np.zeros((2, 3)), (0, 1), (0, 1))
    with pytest.raises(ValueError, match="empty window"):
        splat_image(np.zeros(3), np.zeros(3), np.zeros((3, 3)), (1, 1), (0, 1))


def test_draw_points_sets_the_window_and_draws_the_colours(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    P = rng.uniform(0, 1, (5000, 2))
    C = np.where((P[:, :1] < 0.5), [[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]])
    fig, ax = plt.subplots(figsize=(4, 4))
    draw_points(ax, P[:, 0], P[:, 1], C, (0.0, 1.0), (0.0, 1.0), dpi=50)
    assert ax.get_xlim() == (0.0, 1.0) and ax.get_ylim() == (0.0, 1.0)
    fig.savefig(tmp_path / "p.png", dpi=50)
    plt.close(fig)
    img = plt.imread(tmp_path / "p.png")[..., :3]
    red = (img[..., 0] > 0.6) & (img[..., 2] < 0.4)
    blue = (img[..., 2] > 0.6) & (img[..., 0] < 0.4)
    assert red.sum() > 200 and blue.sum() > 200
    cols_red, cols_blue = np.nonzero(red)[1], np.nonzero(blue)[1]
    assert np.median(cols_red) < np.median(cols_blue)  # red on the left (u < 0.5), blue on the right
