"""Point-map grids: which image pixel each cell of a reduced (H, W) map stands for, and resampling.

Convention (shared with the synth stage): cell ``(u, v)`` of an ``H x W`` map of an image of size
``W_img x H_img`` stands for the image point ``((u + 0.5) * W_img / W - 0.5, (v + 0.5) * H_img / H - 0.5)``
in OpenCV pixel coordinates (pixel centres at integers). It is what ``cv2.resize`` uses, so the
``colors`` map is simply the image resized with ``INTER_AREA``.

A *box* ``(x0, y0, x1, y1)`` is a region of an image in pixel-edge coordinates (the image spans
``0..W_img``); a model that ran on a crop/resize/pad of the image covers such a box with its own
``W_m x H_m`` grid (boxes may reach outside the image when the model input was padded).
"""

from __future__ import annotations

import cv2
import numpy as np

from bimanual_app.transforms import check_shape

__all__ = ["default_map_size", "grid_pixels", "box_to_model", "intrinsics_in_box", "intrinsics_from_box",
           "sample_nearest", "resize_colors", "pixels_to_cells"]


def default_map_size(width: int, height: int, map_width: int = 160) -> tuple[int, int]:
    """(W, H) of the reduced map for an image of ``width x height``: ``map_width`` wide, same aspect."""
    return int(map_width), max(1, int(round(map_width * height / width)))


def grid_pixels(img_size: tuple[int, int], map_size: tuple[int, int]) -> np.ndarray:
    """Image pixel coordinates (H, W, 2) [x, y] (OpenCV, centres at integers) of the map cells."""
    Wi, Hi = img_size
    W, H = map_size
    x = (np.arange(W) + 0.5) * Wi / W - 0.5
    y = (np.arange(H) + 0.5) * Hi / H - 0.5
    xx, yy = np.meshgrid(x, y)
    return np.stack([xx, yy], axis=-1)


def pixels_to_cells(xy: np.ndarray, img_size: tuple[int, int], map_size: tuple[int, int]) -> np.ndarray:
    """Map cell indices (N, 2) int [u, v] holding image points ``xy`` (N, 2) (inverse of grid_pixels, rounded)."""
    xy = check_shape("xy", xy, (None, 2))
    Wi, Hi = img_size
    W, H = map_size
    u = np.floor((xy[:, 0] + 0.5) * W / Wi).astype(int)
    v = np.floor((xy[:, 1] + 0.5) * H / Hi).astype(int)
    return np.stack([u, v], axis=1)


def box_to_model(xy: np.ndarray, box: np.ndarray, model_size: tuple[int, int]) -> np.ndarray:
    """Model pixel coordinates (..., 2) of image points ``xy`` (..., 2) for a model grid covering ``box``."""
    x0, y0, x1, y1 = (float(v) for v in box)
    Wm, Hm = model_size
    out = np.empty_like(np.asarray(xy, dtype=np.float64))
    out[..., 0] = (xy[..., 0] + 0.5 - x0) * Wm / (x1 - x0) - 0.5
    out[..., 1] = (xy[..., 1] + 0.5 - y0) * Hm / (y1 - y0) - 0.5
    return out


def intrinsics_in_box(K: np.ndarray, box: np.ndarray, model_size: tuple[int, int]) -> np.ndarray:
    """Intrinsics (3, 3) in model pixels of a camera ``K`` (3, 3) (image pixels) for a grid covering ``box``."""
    K = check_shape("K", K, (3, 3))
    x0, y0, x1, y1 = (float(v) for v in box)
    Wm, Hm = model_size
    sx, sy = Wm / (x1 - x0), Hm / (y1 - y0)
    return np.array([[K[0, 0] * sx, K[0, 1] * sx, (K[0, 2] + 0.5 - x0) * sx - 0.5],
                     [0.0, K[1, 1] * sy, (K[1, 2] + 0.5 - y0) * sy - 0.5],
                     [0.0, 0.0, 1.0]])


def intrinsics_from_box(K_model: np.ndarray, box: np.ndarray, model_size: tuple[int, int]) -> np.ndarray:
    """Inverse of :func:`intrinsics_in_box`: image-pixel intrinsics (3, 3) from model-pixel ``K_model``."""
    K_model = check_shape("K_model", K_model, (3, 3))
    x0, y0, x1, y1 = (float(v) for v in box)
    Wm, Hm = model_size
    sx, sy = Wm / (x1 - x0), Hm / (y1 - y0)
    return np.array([[K_model[0, 0] / sx, K_model[0, 1] / sx, (K_model[0, 2] + 0.5) / sx + x0 - 0.5],
                     [0.0, K_model[1, 1] / sy, (K_model[1, 2] + 0.5) / sy + y0 - 0.5],
                     [0.0, 0.0, 1.0]])


def sample_nearest(maps: np.ndarray, uv: np.ndarray, valid_size: tuple[int, int] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-cell lookup of ``maps`` (Hm, Wm, ...) at model pixel coordinates ``uv`` (..., 2).

    Nearest, not bilinear: interpolating point maps across a depth edge invents points in mid-air.
    ``valid_size`` (W, H) limits lookups to the top-left part of the map (a zero-padded export).
    Returns (values (..., ...), inside (...) bool); values outside are zero.
    """
    Hm, Wm = maps.shape[:2]
    Wv, Hv = valid_size if valid_size is not None else (Wm, Hm)
    iu = np.rint(uv[..., 0]).astype(np.int64)
    iv = np.rint(uv[..., 1]).astype(np.int64)
    inside = (iu >= 0) & (iu < min(Wv, Wm)) & (iv >= 0) & (iv < min(Hv, Hm))
    vals = maps[np.where(inside, iv, 0), np.where(inside, iu, 0)]
    vals = np.where(inside.reshape(inside.shape + (1,) * (vals.ndim - inside.ndim)), vals, 0)
    return vals, inside


def resize_colors(image: np.ndarray, map_size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 colours of the map cells: the image area-averaged onto the map grid."""
    W, H = map_size
    if image.shape[1] == W and image.shape[0] == H:
        return image.astype(np.uint8, copy=True)
    return cv2.resize(image, (W, H), interpolation=cv2.INTER_AREA).astype(np.uint8)
