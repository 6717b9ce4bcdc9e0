"""Point clouds in matplotlib figures, drawn as one raster image instead of one marker per point.

``Axes.scatter`` renders every marker as a path: about a second of CPU per 100 k points and axes, which
made the figures the slowest part of the segmentation stage. A picture of a cloud at screen resolution
needs only which colour lands in each pixel, so the points are splatted into an RGBA image with numpy
(later points over earlier ones) and shown with ``imshow`` on the same data coordinates.
"""

from __future__ import annotations

import numpy as np


def splat_image(u: np.ndarray, v: np.ndarray, rgb: np.ndarray, lim_u: tuple[float, float],
                lim_v: tuple[float, float], resolution: int = 400, size_px: int = 1) -> tuple[np.ndarray, float]:
    """Splat points into an image covering ``lim_u`` x ``lim_v`` (data units).

    Args:
        u, v: (N,) point coordinates along the image's horizontal and vertical axes.
        rgb: (N, 3) colours in [0, 1]; where points share a pixel the later one wins.
        resolution: pixels along the longer side of the window.
        size_px: side of the square each point covers, in pixels.
    Returns:
        ``(image, pixel)``: the (H, W, 4) RGBA image (alpha 0 where no point fell), row 0 at ``lim_v[0]``,
        and the pixel size in data units.
    """
    u, v, rgb = np.asarray(u, float).ravel(), np.asarray(v, float).ravel(), np.asarray(rgb, float)
    if rgb.shape != (len(u), 3) or v.shape != u.shape:
        raise ValueError(f"splat_image: u {u.shape}, v {v.shape}, rgb {rgb.shape}: expected (N,), (N,), (N, 3)")
    span_u, span_v = lim_u[1] - lim_u[0], lim_v[1] - lim_v[0]
    if not (span_u > 0 and span_v > 0):
        raise ValueError(f"splat_image: empty window {lim_u} x {lim_v}")
    pixel = max(span_u, span_v) / resolution
    W, H = max(int(np.ceil(span_u / pixel)), 1), max(int(np.ceil(span_v / pixel)), 1)
    image = np.zeros((H, W, 4))
    iu = np.floor((u - lim_u[0]) / pixel).astype(np.int64)
    iv = np.floor((v - lim_v[0]) / pixel).astype(np.int64)
    order = np.arange(len(u))
    for du in range(size_px):
        for dv in range(size_px):
            a, b = iu + du - size_px // 2, iv + dv - size_px // 2
            ok = (a >= 0) & (a < W) & (b >= 0) & (b < H)
            flat, k = (b * W + a)[ok], order[ok]
            # the last point in each pixel: unique over the reversed list keeps first occurrences
            _, first = np.unique(flat[::-1], return_index=True)
            last = k[::-1][first]
            image.reshape(-1, 4)[flat[::-1][first], :3] = rgb[last]
            image.reshape(-1, 4)[flat[::-1][first], 3] = 1.0
    return image, pixel


def _screen_pixels(ax, span_u: float, span_v: float, dpi: float) -> int:
    """Screen pixels along the longer side of an equal-aspect window of ``span_u`` x ``span_v`` in ``ax``."""
    w_in, h_in = ax.figure.get_size_inches() * ax.get_position().size
    per_unit = min(w_in / span_u, h_in / span_v) * dpi
    return max(int(per_unit * max(span_u, span_v)), 16)


def draw_points(ax, u: np.ndarray, v: np.ndarray, rgb: np.ndarray, lim_u: tuple[float, float] | None = None,
                lim_v: tuple[float, float] | None = None, dpi: float = 110, oversample: int = 2) -> None:
    """Draw points (u, v (N,), colours rgb (N, 3)) into the matplotlib axes ``ax`` as one image.

    The window defaults to the points' bounds plus 2 %; the axes get that window as their limits and an
    equal aspect (the image's pixels are square in data units). The image has ``oversample`` times the
    screen resolution the axes have at ``dpi`` (the dpi the figure is saved at), each point covering
    ``oversample`` pixels a side, and is smoothed down when drawn, so a point looks as a small scatter
    marker does.
    """
    u, v = np.asarray(u, float), np.asarray(v, float)
    if lim_u is None or lim_v is None:
        lo, hi = np.array([u.min(), v.min()]), np.array([u.max(), v.max()])
        pad = 0.02 * max(float(np.max(hi - lo)), 1e-3)
        lim_u = lim_u or (lo[0] - pad, hi[0] + pad)
        lim_v = lim_v or (lo[1] - pad, hi[1] + pad)
    screen = _screen_pixels(ax, lim_u[1] - lim_u[0], lim_v[1] - lim_v[0], dpi)
    image, pixel = splat_image(u, v, rgb, lim_u, lim_v, oversample * screen, oversample)
    H, W = image.shape[:2]
    ax.imshow(image, origin="lower", interpolation="antialiased", zorder=0,
              extent=(lim_u[0], lim_u[0] + W * pixel, lim_v[0], lim_v[0] + H * pixel))
    ax.set_xlim(*lim_u)
    ax.set_ylim(*lim_v)
    ax.set_aspect("equal")
