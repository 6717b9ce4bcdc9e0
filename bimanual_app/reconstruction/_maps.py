"""Per-image point maps (pts3d, conf, colors) at reduced resolution from a COLMAP model.

Two layers, both in the reconstruction frame ``w``:
- sparse: each map cell holding an observation of a triangulated COLMAP point gets that point, with
  ``conf = 1 + min(track length, 10) / 10`` (in (1, 2]: triangulated from several views, the best data);
- dense (optional): plane-sweep depth (``_dense``), ``conf`` = its NCC score in (0, 1], kept only where
  another view's depth agrees.
Cells with neither hold the point on the cell's ray at the view's median depth, with ``conf = 0``
(finite values, as the contract asks; nothing downstream should use them).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import cv2
import numpy as np

from bimanual_app.scene import CameraIntrinsics
from bimanual_app.transforms import apply_T, inv_T

from ._colmap import SparseModel
from ._dense import (
    FILL_CONF,
    DenseOptions,
    choose_sources,
    consistency_counts,
    fill_horizontal_holes,
    fit_plane,
    plane_sweep,
    sweep_planes,
)
from ._pointmap import grid_pixels, pixels_to_cells, resize_colors, sample_nearest

__all__ = ["colmap_point_maps"]

PINHOLE_MODELS = {"PINHOLE", "SIMPLE_PINHOLE"}


def _cam_from_img_cv(camera, xy: np.ndarray) -> np.ndarray:
    """Normalised camera coordinates (N, 2) of OpenCV pixels ``xy`` (N, 2) through COLMAP's camera model."""
    return np.asarray(camera.cam_from_img(np.ascontiguousarray(xy + 0.5, dtype=np.float64)), dtype=np.float64)


def _undistort(rgb: np.ndarray, camera, K: np.ndarray) -> np.ndarray:
    """The image re-sampled as a pinhole camera ``K`` (3, 3) (same size), removing the model's distortion."""
    if camera.model_name in PINHOLE_MODELS:
        return rgb
    H, W = rgb.shape[:2]
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], -1) @ np.linalg.inv(K).T
    xy = np.asarray(camera.img_from_cam(rays, check_cheirality=False), dtype=np.float64) - 0.5
    mx = xy[:, 0].reshape(H, W).astype(np.float32)
    my = xy[:, 1].reshape(H, W).astype(np.float32)
    return cv2.remap(rgb, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _scaled_K(K: np.ndarray, size: tuple[int, int], new: tuple[int, int]) -> np.ndarray:
    c = CameraIntrinsics(size[0], size[1], K[0, 0], K[1, 1], K[0, 2], K[1, 2]).scaled(*new)
    return c.K


def _cell_rays(model: SparseModel, images: dict[str, np.ndarray], map_size: tuple[int, int],
               colors: np.ndarray) -> tuple[list[np.ndarray], list[tuple[int, int]]]:
    """Rays (Hm, Wm, 3) of every map cell through each camera's model (undistorted normalised coordinates,
    z = 1) and each image's (W, H); fills ``colors`` (M, Hm, Wm, 3) with the resized images."""
    Wm, Hm = map_size
    rays, sizes = [], []
    for i, name in enumerate(model.names):
        img = images[name]
        size = (img.shape[1], img.shape[0])
        sizes.append(size)
        xy = _cam_from_img_cv(model.cameras[i], grid_pixels(size, map_size).reshape(-1, 2))
        rays.append(np.concatenate([xy, np.ones((len(xy), 1))], 1).reshape(Hm, Wm, 3))
        colors[i] = resize_colors(img, map_size)
    return rays, sizes


def _work_images(model: SparseModel, images: dict[str, np.ndarray], sizes: list[tuple[int, int]],
                 opts: DenseOptions) -> list[tuple[np.ndarray, np.ndarray]]:
    """(grey float32 image at the working width, its pinhole K (3, 3)) per view, undistorted."""
    work = []
    for i, name in enumerate(model.names):
        size = sizes[i]
        wsize = (min(opts.work_width, size[0]), max(1, round(min(opts.work_width, size[0]) * size[1] / size[0])))
        und = _undistort(images[name], model.cameras[i], model.K[i])
        grey = cv2.cvtColor(cv2.resize(und, wsize, interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
        work.append((grey.astype(np.float32) / 255.0, _scaled_K(model.K[i], size, wsize)))
    return work


def _table_heights(model: SparseModel, centres: np.ndarray, n_w: np.ndarray, d_w: float,
                   opts: DenseOptions) -> tuple[np.ndarray, float, tuple[float, float]]:
    """Heights above the table plane of the sweep planes, the cameras' median height above it, and the
    (lowest, highest) height."""
    h = model.xyz @ n_w + d_w
    cam_h = float(np.median(centres @ n_w + d_w))
    # the dominant plane may be a large object's top rather than the table: span the sparse
    # points' heights (1st..99th percentile) with a margin, and at least a quarter of the way up
    bottom = min(float(np.percentile(h, 1)), 0.0) - 0.03 * cam_h
    top = float(np.clip(1.2 * np.percentile(h, 99), 0.25 * cam_h, 0.8 * cam_h))
    return np.linspace(bottom, top, opts.planes), cam_h, (bottom, top)


def _fronto_parallel_planes(model: SparseModel, i: int, opts: DenseOptions) -> tuple[np.ndarray, np.ndarray]:
    """Sweep planes of view ``i`` facing the camera, spaced in inverse depth over its sparse points' depths."""
    T = model.T_w_c[i]
    z = apply_T(inv_T(T), model.xyz[model.obs[i][1]])[:, 2] if len(model.obs[i][1]) else \
        apply_T(inv_T(T), model.xyz)[:, 2]
    z = z[z > 0]
    zlo, zhi = np.percentile(z, 1) * 0.8, np.percentile(z, 99) * 1.25
    return np.array([0.0, 0.0, 1.0]), 1.0 / np.linspace(1 / zlo, 1 / zhi, opts.planes)


def _sample_dense(i: int, d: np.ndarray, s: np.ndarray, K: np.ndarray, rays: list[np.ndarray], model: SparseModel,
                  pts3d: np.ndarray, conf: np.ndarray, depth_cells: list[np.ndarray]) -> float:
    """Write view ``i``'s depth ``d`` and score ``s`` (working resolution, intrinsics ``K``) into its map cells;
    returns the share of cells that got a depth."""
    px = rays[i].reshape(-1, 3) @ K.T
    vals, inside = sample_nearest(np.stack([d, s], -1), px[:, :2])
    z, sc = vals[:, 0], vals[:, 1]
    good = inside & (z > 0)
    pc = rays[i].reshape(-1, 3) * z[:, None]
    pw = apply_T(model.T_w_c[i], pc)
    pts3d[i].reshape(-1, 3)[good] = pw[good]
    conf[i].reshape(-1)[good] = np.clip(sc[good], 1e-3, 1.0)
    depth_cells[i].reshape(-1)[good] = z[good]
    return float(good.mean())


def _dense_layer(model: SparseModel, images: dict[str, np.ndarray], sizes: list[tuple[int, int]],
                 rays: list[np.ndarray], opts: DenseOptions, log: Callable[[str], None], pts3d: np.ndarray,
                 conf: np.ndarray, depth_cells: list[np.ndarray], info: dict) -> None:
    """Plane-sweep depth of every view, kept where another view agrees, written into the maps."""
    M = len(model.names)
    centres = model.T_w_c[:, :3, 3]
    t0 = time.perf_counter()
    scale = float(np.median(np.linalg.norm(model.xyz[None, ::7] - centres[:, None], axis=-1)))
    n_w, d_w, frac = fit_plane(model.xyz, centres, threshold=0.01 * scale)
    table = frac >= opts.min_plane_inliers
    work = _work_images(model, images, sizes, opts)
    neighbours = choose_sources([p for _, p in model.obs], opts.sources)
    if table:
        heights, cam_h, span = _table_heights(model, centres, n_w, d_w, opts)
        info.update(dense="plane-sweep along the table normal", plane_inliers=frac,
                    heights=span, camera_height=cam_h)
    else:
        info.update(dense="plane-sweep fronto-parallel", plane_inliers=frac)
    depths, scores = [], []
    for i in range(M):
        T = model.T_w_c[i]
        n_c, c = sweep_planes(n_w, d_w, heights, T) if table else _fronto_parallel_planes(model, i, opts)
        srcs = [(work[j][0], work[j][1], model.T_w_c[j]) for j in neighbours[i]]
        d, s = plane_sweep(work[i][0], work[i][1], T, srcs, n_c, c, opts)
        depths.append(d)
        scores.append(s)
        if (i + 1) % 4 == 0 or i + 1 == M:
            log(f"    plane sweep: {i + 1}/{M} views ({time.perf_counter() - t0:.1f} s)")
    counts = consistency_counts(depths, [w[1] for w in work], model.T_w_c, neighbours, opts.rel_tol)
    cover, filled_frac = [], []
    for i in range(M):
        keep = counts[i] >= 1
        d = np.where(keep, depths[i], 0.0)
        s = np.where(keep, scores[i], 0.0)
        if table and opts.fill_holes:
            filled = fill_horizontal_holes(d, work[i][1], model.T_w_c[i], n_w, d_w,
                                           opts.fill_max_spread * cam_h, opts.fill_min_area)
            s[filled] = FILL_CONF
            filled_frac.append(float(filled.mean()))
        cover.append(_sample_dense(i, d, s, work[i][1], rays, model, pts3d, conf, depth_cells))
    info["dense_coverage"] = float(np.mean(cover))
    info["filled_fraction"] = float(np.mean(filled_frac)) if filled_frac else 0.0
    info["dense_seconds"] = time.perf_counter() - t0


def _sparse_layer(model: SparseModel, sizes: list[tuple[int, int]], rays: list[np.ndarray],
                  map_size: tuple[int, int], pts3d: np.ndarray, conf: np.ndarray,
                  depth_cells: list[np.ndarray]) -> None:
    """Triangulated COLMAP points on top of the maps, then a finite filler (conf 0) for the empty cells."""
    Wm, Hm = map_size
    centres = model.T_w_c[:, :3, 3]
    for i in range(len(model.names)):
        xy, pidx = model.obs[i]
        T_c_w = inv_T(model.T_w_c[i])
        if len(pidx):
            cells = pixels_to_cells(xy, sizes[i], map_size)
            ok = (cells[:, 0] >= 0) & (cells[:, 0] < Wm) & (cells[:, 1] >= 0) & (cells[:, 1] < Hm)
            cu, cv_, p = cells[ok, 0], cells[ok, 1], pidx[ok]
            pts3d[i, cv_, cu] = model.xyz[p]
            conf[i, cv_, cu] = 1.0 + np.minimum(model.track_len[p], 10) / 10.0
            depth_cells[i][cv_, cu] = apply_T(T_c_w, model.xyz[p])[:, 2]
        known = depth_cells[i] > 0
        zfill = float(np.median(depth_cells[i][known])) if known.any() else \
            float(np.median(np.linalg.norm(model.xyz - centres[i], axis=1))) if len(model.xyz) else 1.0
        empty = conf[i] <= 0
        pts3d[i][empty] = apply_T(model.T_w_c[i], rays[i][empty] * zfill)


def colmap_point_maps(model: SparseModel, images: dict[str, np.ndarray], map_size: tuple[int, int],
                      dense: bool = True, opts: DenseOptions | None = None,
                      log: Callable[[str], None] = print) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Point maps of the registered images of ``model``.

    Args:
        images: scene-relative name -> (H, W, 3) uint8 RGB image (the originals COLMAP saw).
        map_size: (W, H) of the maps.
        dense: run the plane sweep (else only the sparse layer).
    Returns ``(pts3d (M, H, W, 3) float32, conf (M, H, W) float32, colors (M, H, W, 3) uint8, info)``.
    """
    opts = opts or DenseOptions()
    M = len(model.names)
    Wm, Hm = map_size
    pts3d = np.zeros((M, Hm, Wm, 3), np.float32)
    conf = np.zeros((M, Hm, Wm), np.float32)
    colors = np.zeros((M, Hm, Wm, 3), np.uint8)
    info: dict = {"dense": "none"}
    rays, sizes = _cell_rays(model, images, map_size, colors)
    depth_cells = [np.zeros((Hm, Wm)) for _ in range(M)]
    if dense and M >= 2 and len(model.xyz) >= 10:
        _dense_layer(model, images, sizes, rays, opts, log, pts3d, conf, depth_cells, info)
    _sparse_layer(model, sizes, rays, map_size, pts3d, conf, depth_cells)
    info["sparse_cells"] = float(np.mean(conf > 1.0))
    info["valid_cells"] = float(np.mean(conf > 0))
    return pts3d, conf, colors, info
