"""preview.png of a synthetic capture: an overview of the setup with every camera pose, and the views.

Drawn with matplotlib (headless, Agg), then stored as a 256-colour PNG to keep shipped scenes small.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import atomic_path
from bimanual_app.transforms import apply_T, inv_T

ARM_COLORS = ("tab:orange", "tab:cyan")


def _project(K: np.ndarray, T_c_x: np.ndarray, p_x: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of points (N, 3) of frame x, for a camera with pose T_c_x; NaN behind the camera."""
    pc = apply_T(T_c_x, p_x)
    uv = pc[:, :2] / pc[:, 2:3] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    uv[pc[:, 2] <= 0.01] = np.nan
    return uv


def save_preview(path: Path, overview: np.ndarray, K_ov: np.ndarray, T_b1_ov: np.ndarray,
                 cams: list[np.ndarray], K: np.ndarray, image_size: tuple[int, int],
                 objects: list[dict], thumbs: list[list[np.ndarray]] | None, outliers: list[np.ndarray],
                 title: str) -> None:
    """Write the preview picture.

    Args:
        overview: (H, W, 3) uint8 render of the whole setup from camera ``T_b1_ov`` (4, 4), intrinsics ``K_ov``.
        cams: per arm, (N, 4, 4) true camera poses T_b1_c of the capture.
        K, image_size: the capture camera (drawn as small frusta).
        objects: ground-truth objects (``id``, ``kind``, ``T_b1_o``).
        thumbs: per arm, the rendered views (H, W, 3) uint8 (None when nothing was rendered).
        outliers: per arm, (N,) bool: views the emulator posed badly (framed in red).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    n = max(len(c) for c in cams)
    ncols = max(n, 4)
    rows = 2 if thumbs else 0
    fig_w = 1.6 * ncols if thumbs else 8.0
    ov_h = min(fig_w * 0.56, 7.5)  # the overview (4:3) spans ~3/4 of the width
    th_h = 0.75 * fig_w / ncols + 0.25  # a thumbnail row, with its title
    fig = plt.figure(figsize=(fig_w, ov_h + rows * th_h + 0.3), dpi=100)
    gs = fig.add_gridspec(1 + rows, ncols, height_ratios=[ov_h] + [th_h] * rows, hspace=0.1, wspace=0.04,
                          left=0.01, right=0.99, top=0.96, bottom=0.01)
    ax = fig.add_subplot(gs[0, :])
    ax.imshow(overview)
    T_ov_b1 = inv_T(T_b1_ov)
    W, H = image_size
    corners = np.array([[0, 0], [W, 0], [W, H], [0, H]], dtype=np.float64)
    d = 0.05  # frustum depth drawn (m)
    for Ts, col in zip(cams, ARM_COLORS):
        for i, T in enumerate(Ts):
            rays = np.c_[(corners - K[:2, 2]) / [K[0, 0], K[1, 1]], np.ones(4)] * d
            pts = np.vstack([T[:3, 3], apply_T(T, rays)])
            uv = _project(K_ov, T_ov_b1, pts)
            if np.isnan(uv).any():
                continue
            for j in range(4):
                ax.plot(uv[[0, j + 1], 0], uv[[0, j + 1], 1], color=col, lw=0.8, clip_on=True)
            ax.plot(uv[[1, 2, 3, 4, 1], 0], uv[[1, 2, 3, 4, 1], 1], color=col, lw=1.2, clip_on=True)
            ax.text(uv[0, 0], uv[0, 1], str(i), color=col, fontsize=7, ha="right", va="bottom", clip_on=True)
    for o in objects:
        uv = _project(K_ov, T_ov_b1, np.asarray(o["T_b1_o"])[:3, 3][None])[0]
        if np.all(np.isfinite(uv)):
            ax.text(uv[0], uv[1], f"{o['id']}:{o['kind']}", color="white", fontsize=7, ha="center", clip_on=True,
                    bbox=dict(facecolor="black", alpha=0.55, pad=1.0, lw=0))
    ax.set_xlim(0, overview.shape[1])
    ax.set_ylim(overview.shape[0], 0)
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)
    ax.plot([], [], color=ARM_COLORS[0], label="primary camera poses")
    ax.plot([], [], color=ARM_COLORS[1], label="secondary camera poses")
    ax.legend(loc="lower left", fontsize=7, framealpha=0.7)
    if thumbs:
        for arm, ims in enumerate(thumbs):
            for i, im in enumerate(ims[:ncols]):
                a = fig.add_subplot(gs[1 + arm, i])
                a.imshow(im)
                a.set_xticks([])
                a.set_yticks([])
                bad = bool(outliers[arm][i])
                for s in a.spines.values():
                    s.set_color("red" if bad else ARM_COLORS[arm])
                    s.set_linewidth(2.0)
                a.set_title(f"{('primary', 'secondary')[arm]} {i:03d}" + (" outlier" if bad else ""), fontsize=6,
                            color="red" if bad else "black", pad=2)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight", pad_inches=0.05)
    plt.close(fig)
    img = Image.open(io.BytesIO(buf.getvalue())).convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT)
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG", optimize=True)
