"""The stage's picture: cameras and cloud from above, registration per arm, one confidence map."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimanual_app.io_utils import atomic_path
from bimanual_app.scene import Reconstruction, Scene

__all__ = ["plot_reconstruction"]

ARM_COLOURS = {1: "tab:blue", 2: "tab:orange"}


def _plane_axes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre and two in-plane axes of the best-fit plane of points (N, 3) (PCA): a view from above."""
    c = points.mean(0)
    _, _, Vt = np.linalg.svd(points - c, full_matrices=False)
    return c, Vt[0], Vt[1]


def plot_reconstruction(path: Path, scene: Scene, rec: Reconstruction, title: str, max_points: int = 40000) -> Path:
    """Save a PNG: top view (cloud coloured by its colours, camera centres by arm), views registered per
    arm, and the confidence map of the first view. Written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    ax = axes[0]
    centres = rec.T_w_c[:, :3, 3]
    pts = cols = None
    if rec.pts3d is not None:
        ok = (rec.conf > 0) if rec.conf is not None else np.ones(rec.pts3d.shape[:3], bool)
        pts = rec.pts3d[ok].astype(np.float64)
        cols = rec.colors[ok] / 255.0 if rec.colors is not None else None
        if len(pts) > max_points:
            idx = np.random.default_rng(0).choice(len(pts), max_points, replace=False)
            pts = pts[idx]
            cols = cols[idx] if cols is not None else None
    ref = pts if pts is not None and len(pts) >= 3 else centres
    c, e1, e2 = _plane_axes(ref)
    if pts is not None and len(pts):
        ax.scatter((pts - c) @ e1, (pts - c) @ e2, s=0.5, c=cols if cols is not None else "0.5", linewidths=0)
    for a in (1, 2):
        m = rec.arm == a
        ax.scatter((centres[m] - c) @ e1, (centres[m] - c) @ e2, s=40, marker="^", c=ARM_COLOURS[a],
                   edgecolors="k", label=f"{'primary' if a == 1 else 'secondary'} cameras")
    ax.set_aspect("equal")
    ax.set_title("cloud and cameras, seen along the cloud's normal (units of w)")
    ax.legend(loc="best", fontsize=8)
    ax = axes[1]
    names, reg, tot = [], [], []
    for arm in scene.arms:
        names.append(arm.name)
        reg.append(len(rec.rows_for(arm.index, arm.images)[0]))
        tot.append(len(arm))
    ax.bar(names, tot, color="0.85", label="views captured")
    ax.bar(names, reg, color=[ARM_COLOURS[1], ARM_COLOURS[2]], label="views registered")
    for i, (r, t) in enumerate(zip(reg, tot)):
        ax.text(i, r, f"{r}/{t}", ha="center", va="bottom")
    ax.set_title("registered views per arm")
    ax.legend(loc="lower right", fontsize=8)
    ax = axes[2]
    if rec.conf is not None:
        im = ax.imshow(rec.conf[0], cmap="viridis")
        fig.colorbar(im, ax=ax, fraction=0.035)
        ax.set_title(f"confidence map of {rec.image[0]} (arm {rec.arm[0]})")
    else:
        ax.text(0.5, 0.5, "no point maps (poses only)", ha="center", va="center")
    ax.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path
