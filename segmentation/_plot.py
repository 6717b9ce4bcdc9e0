"""segments.png: the cloud coloured by segment, from above and from the side (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._summary import ObjectSummary

TABLE_GREY = np.array([0.78, 0.78, 0.78])


def segment_colours(labels: np.ndarray) -> np.ndarray:
    """(N, 3) RGB in [0, 1]: light grey for -1, a distinct tab20 colour per object."""
    import matplotlib

    cmap = matplotlib.colormaps["tab20"]
    pal = np.array([cmap(i)[:3] for i in (list(range(0, 20, 2)) + list(range(1, 20, 2)))])
    out = np.tile(TABLE_GREY, (len(labels), 1))
    m = labels >= 0
    out[m] = pal[labels[m] % len(pal)]
    return out


def _box_corners_xy(o: ObjectSummary) -> np.ndarray:
    hx, hy = o.extents[0] / 2, o.extents[1] / 2
    loc = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0], [-hx, -hy, 0]])
    return (loc @ o.rotation.T + o.center)[:, :2]


def _windows(points: np.ndarray, obj: np.ndarray) -> tuple[tuple, tuple, tuple]:
    """x, y and z limits of the figure: the objects plus a margin of table (all points when no object)."""
    P = points[obj] if len(obj) else points
    m = np.array([0.08, 0.08, 0.04]) if len(obj) else np.full(3, 0.02)
    lo, hi = P.min(0) - m, P.max(0) + m
    hi[2] = max(hi[2], lo[2] + 0.05)
    return (lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2])


def plot_segments(path: str | Path, points: np.ndarray, labels: np.ndarray, objects: list[ObjectSummary],
                  title: str = "", max_points: int = 80_000, seed: int = 0, gt_labels: np.ndarray | None = None) -> None:
    """Save a figure: top view (x-y of b1) and side view (x-z), objects coloured and boxed.

    ``points`` (N, 3) in b1, ``labels`` (N,). ``gt_labels`` (N,), when given, adds a top view coloured by
    the ground truth (for benchmarks). Subsamples to ``max_points`` (objects keep a larger share than the
    table); the points are drawn as one raster image (:mod:`bimanual_app.plot_points`).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bimanual_app.plot_points import draw_points

    rng = np.random.default_rng(seed)
    N = len(points)
    obj = np.flatnonzero(labels >= 0)
    rest = np.flatnonzero(labels < 0)
    k_obj = min(len(obj), int(0.6 * max_points))
    k_rest = min(len(rest), max_points - k_obj)
    sel = np.r_[rng.choice(obj, k_obj, replace=False) if k_obj < len(obj) else obj,
                rng.choice(rest, k_rest, replace=False) if k_rest < len(rest) else rest].astype(np.int64)
    sel = sel[np.argsort(labels[sel], kind="stable")]  # objects drawn over the table
    P, L = points[sel], labels[sel]
    C = segment_colours(L)
    lim_x, lim_y, lim_z = _windows(points, obj)
    ncol = 3 if gt_labels is not None else 2
    fig, axes = plt.subplots(1, ncol, figsize=(6.5 * ncol, 6.0))
    ax = axes[0]
    draw_points(ax, P[:, 0], P[:, 1], C, lim_x, lim_y)
    for o in objects:
        xy = _box_corners_xy(o)
        ax.plot(xy[:, 0], xy[:, 1], "k-", lw=0.8)
        ax.text(o.center[0], o.center[1], str(o.id), fontsize=9, ha="center", va="center",
                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.7))
    ax.set_xlabel("x (m, b1)")
    ax.set_ylabel("y (m, b1)")
    ax.set_title("from above")
    ax = axes[1]
    draw_points(ax, P[:, 0], P[:, 2], C, lim_x, lim_z)
    ax.set_xlabel("x (m, b1)")
    ax.set_ylabel("z (m, b1)")
    ax.set_title("from the side")
    if gt_labels is not None:
        ax = axes[2]
        gsel = sel[np.argsort(gt_labels[sel], kind="stable")]
        draw_points(ax, points[gsel, 0], points[gsel, 1], segment_colours(gt_labels[gsel]), lim_x, lim_y)
        ax.set_title("ground truth")
    fig.suptitle(title or f"{len(objects)} objects, {N} points")
    fig.tight_layout()
    from bimanual_app.io_utils import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
