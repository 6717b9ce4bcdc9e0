"""Point-map normals (``calibration._pointmaps.grid_normals``): the plane of a window of grid points, so a
model's depth noise does not tilt them (issue 21, docs/calibration.md "Normals")."""

from __future__ import annotations

import numpy as np
import pytest

from calibration._pointmaps import NORMAL_SAMPLES, NORMAL_WINDOW_RAD, grid_normals, next_pixel_normals

FOCAL_PX = 105.0  # the synthetic scenes' 160 x 120 maps


def _plane_map(noise_rel: float, seed: int = 0, W: int = 160, H: int = 120, f: float = FOCAL_PX):
    """(H, W, 3) camera-frame points of the plane n . p = d seen by a pinhole camera, depth times (1 + noise),
    and the plane's unit normal towards the camera."""
    n = np.array([0.3, -0.4, -1.0])
    n /= np.linalg.norm(n)
    d = -0.5  # n . p = d: the plane half a metre from the camera
    u, v = np.meshgrid(np.arange(W) - (W - 1) / 2, np.arange(H) - (H - 1) / 2)
    rays = np.stack([u / f, v / f, np.ones_like(u, dtype=float)], -1)
    t = d / (rays @ n)
    z = t * (1.0 + noise_rel * np.random.default_rng(seed).normal(size=t.shape))
    return rays * z[..., None], n


def _angle_deg(N: np.ndarray, n: np.ndarray) -> np.ndarray:
    ok = np.isfinite(N).all(-1)
    return np.degrees(np.arccos(np.clip(N[ok] @ n, -1.0, 1.0)))


def test_exact_plane_gives_its_normal_towards_the_camera_and_none_at_the_border():
    P, n = _plane_map(0.0)
    N = grid_normals(P, FOCAL_PX)
    half = NORMAL_SAMPLES // 2  # one cell per sample at this focal length
    inner = N[half:-half, half:-half]
    assert np.isfinite(inner).all()
    assert np.abs(inner.reshape(-1, 3) @ n - 1.0).max() < 1e-9
    assert np.isnan(N[:half]).all() and np.isnan(N[:, -half:]).all()
    assert np.all(np.einsum("ijk,ijk->ij", inner, P[half:-half, half:-half]) < 0)  # towards the camera


def test_depth_noise_tilts_window_normals_far_less_than_next_pixel_normals():
    P, n = _plane_map(0.005, seed=3)
    window = np.median(_angle_deg(grid_normals(P, FOCAL_PX), n))
    next_pixels = np.median(_angle_deg(next_pixel_normals(P), n))
    assert next_pixels > 8.0, next_pixels
    assert window < 0.25 * next_pixels and window < 3.0, (window, next_pixels)


@pytest.mark.parametrize("focal_px, step", [(FOCAL_PX, 1), (400.0, 4), (None, 1)])
def test_the_window_spans_the_same_view_angle_whatever_the_map_resolution(focal_px, step):
    P, _ = _plane_map(0.0, f=focal_px or FOCAL_PX)
    if focal_px:
        assert step == max(1, round(focal_px * NORMAL_WINDOW_RAD / (NORMAL_SAMPLES // 2)))
    r, c = 60, 80
    for off, hit in ((step, True), (step + 1, step == 1)):
        Q = P.copy()
        Q[r, c + off] = np.nan  # a missing point: the windows that sample it get no normal
        N = grid_normals(Q, focal_px)
        assert np.isnan(N[r, c]).any() == hit, (off, hit)
