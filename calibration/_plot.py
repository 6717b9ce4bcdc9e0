"""calibration.png: both arms' end-effector frames and calibrated cameras in b1 (as in the paper's
calibration figure: primary in reds, secondary in blues, cameras as cones), both bases, and the metric
point cloud seen from above. Headless (Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._closed_form import scaled
from ._files import atomic_file

#: zlib level 1: a third of the default's encoding time for a slightly larger file (figures, not archives)
PNG_OPTIONS = {"compress_level": 1}


class _Segments:
    """Collects 3D line segments and draws them as one Line3DCollection (one artist: fast)."""

    def __init__(self):
        self.segs, self.colors, self.widths, self.styles = [], [], [], []

    def add(self, p, q, color, lw=1.0, ls="solid"):
        self.segs.append([p, q])
        self.colors.append(color)
        self.widths.append(lw)
        self.styles.append(ls)

    def triad(self, T, length, lw=1.2):
        o = T[:3, 3]
        for k, c in enumerate(("r", "g", "b")):
            self.add(o, o + length * T[:3, k], c, lw)

    def cone(self, T, size, color):
        """A camera frustum (OpenCV camera: z forward) of depth ``size`` at pose T (4, 4)."""
        w, h = 0.5 * size, 0.375 * size
        corners = np.array([[-w, -h, size], [w, -h, size], [w, h, size], [-w, h, size]])
        pts = corners @ T[:3, :3].T + T[:3, 3]
        for k, p in enumerate(pts):
            self.add(T[:3, 3], p, color, 0.8)
            self.add(p, pts[(k + 1) % 4], color, 0.8)

    def draw(self, ax):
        from mpl_toolkits.mplot3d.art3d import Line3DCollection

        ax.add_collection3d(Line3DCollection(np.array(self.segs), colors=self.colors, linewidths=self.widths,
                                             linestyles=self.styles))


def _shades(cmap_name: str, n: int):
    import matplotlib

    cmap = matplotlib.colormaps[cmap_name]
    return [cmap(0.45 + 0.5 * k / max(n - 1, 1)) for k in range(n)]


def _cloud_3d(ax, points: np.ndarray | None, colors: np.ndarray | None, max_points: int) -> np.ndarray | None:
    """Scatter a random subset of the cloud in the 3D panel; returns the subset's indices (None without a cloud)."""
    if points is None or not len(points):
        return None
    rng = np.random.default_rng(0)
    sub = rng.choice(len(points), size=min(max_points, len(points)), replace=False)
    s3 = sub[: max_points // 2]  # the 3D panel needs fewer points to read and is the slow one to draw
    col3 = colors[s3] / 255.0 if colors is not None else "0.5"
    ax.scatter(*points[s3].T, c=col3, s=0.4, alpha=0.4, linewidths=0, depthshade=False)
    return sub


def _arms_and_cameras(ax, top, result, T_b1_e, T_w_c1, T_b2_e, T_w_c2) -> np.ndarray:
    """End-effector triads, camera cones and bases in both panels; returns the camera positions (N, 3) in b1."""
    arms = ((1, T_b1_e, T_w_c1, result.T_e1_c1, np.eye(4), "Reds"),
            (2, T_b2_e, T_w_c2, result.T_e2_c2, result.T_b1_b2, "Blues"))
    cam_pos = []
    seg = _Segments()
    for m, E, C, X, T_b1_b, cmap in arms:
        shades = _shades(cmap, len(E))
        P = result.T_b1_w @ scaled(C, result.scale)  # calibrated cameras in b1 (reconstruction poses)
        for k in range(len(E)):
            Eb1 = T_b1_b @ E[k]
            seg.triad(Eb1, 0.04, lw=1.0)
            seg.cone(P[k], 0.05, shades[k])
            seg.add(Eb1[:3, 3], (Eb1 @ X)[:3, 3], shades[k], 0.8, "dotted")
            top.plot(*P[k][:2, 3], marker="^", color=shades[k], ms=6, ls="")
            top.plot(*Eb1[:2, 3], marker="o", mfc="none", color=shades[k], ms=5, ls="")
            cam_pos.append(P[k][:3, 3])
        seg.triad(T_b1_b, 0.12, lw=2.5)
        ax.text(*T_b1_b[:3, 3] + [0, 0, -0.04], f"b{m}", fontsize=10, weight="bold")
    seg.draw(ax)
    return np.array(cam_pos)


def _bounds(cam_pos: np.ndarray, T_b1_b2: np.ndarray, points: np.ndarray | None,
            sub: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(3,) lower and upper corners of what the panels show: cameras, bases and the bulk of the cloud."""
    allp = np.vstack([cam_pos, np.zeros((1, 3)), T_b1_b2[:3, 3][None]])
    lo, hi = allp.min(0) - 0.1, allp.max(0) + 0.1
    if points is not None and len(points):
        # the bulk of the cloud (far background points of a reconstruction would squash the picture)
        q = np.percentile(points[sub], [10, 90], axis=0)
        lo, hi = np.minimum(lo, q[0]), np.maximum(hi, q[1])
    return lo, hi


def _frame_3d(ax, lo: np.ndarray, hi: np.ndarray) -> None:
    """Equal-aspect limits, labels, view and title of the 3D panel."""
    c, r = (lo + hi) / 2, (hi - lo).max() / 2 + 0.05
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(max(c[2] - r, lo[2] - 0.05), max(c[2] - r, lo[2] - 0.05) + 2 * r)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.view_init(elev=28, azim=-60)
    ax.set_title("end effectors (triads), calibrated cameras (cones) in b1\nprimary: reds, secondary: blues", fontsize=9)


def _top_view(top, result, points: np.ndarray | None, colors: np.ndarray | None, sub: np.ndarray | None,
              lo: np.ndarray, hi: np.ndarray) -> None:
    """The cloud from above with both bases' x/y axes, limits, labels and title."""
    if points is not None and len(points):
        col = colors[sub] / 255.0 if colors is not None else "0.5"
        top.scatter(points[sub, 0], points[sub, 1], c=col, s=1.5, linewidths=0)
    for m, T in ((1, np.eye(4)), (2, result.T_b1_b2)):
        o = T[:3, 3]
        for k, cc in ((0, "r"), (1, "g")):
            e = o + 0.1 * T[:3, k]
            top.plot([o[0], e[0]], [o[1], e[1]], color=cc, lw=2.5)
        top.text(o[0], o[1] - 0.03, f"b{m}", fontsize=10, weight="bold", ha="center", va="top")
    m = 0.08
    top.set_xlim(lo[0] - m, hi[0] + m)
    top.set_ylim(lo[1] - m, hi[1] + m)
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title("metric point cloud from above (b1); cameras ^, end effectors o", fontsize=9)
    top.grid(alpha=0.3)


def save_calibration_figure(path: Path, result, T_b1_e: np.ndarray, T_w_c1: np.ndarray, T_b2_e: np.ndarray,
                            T_w_c2: np.ndarray, points: np.ndarray | None, colors: np.ndarray | None,
                            title: str = "", max_points: int = 12000) -> None:
    """Draw and save the figure.

    Args:
        T_b1_e, T_w_c1, T_b2_e, T_w_c2: (N_m, 4, 4) the views used.
        points, colors: metric cloud in b1 (K, 3) and (K, 3) uint8, or None.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 6.2))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    top = fig.add_subplot(1, 2, 2)
    sub = _cloud_3d(ax, points, colors, max_points)
    cam_pos = _arms_and_cameras(ax, top, result, T_b1_e, T_w_c1, T_b2_e, T_w_c2)
    lo, hi = _bounds(cam_pos, result.T_b1_b2, points, sub)
    _frame_3d(ax, lo, hi)
    _top_view(top, result, points, colors, sub, lo, hi)
    u = result.uncertainty or {}
    lines = [title] if title else []
    lines.append(f"method {result.method}  scale {result.scale:.4f}" + (
        f" +- {u['scale']['percent']:.2f}%" if "scale" in u else ""))
    fig.suptitle("\n".join(lines), fontsize=10)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.08, top=0.86, wspace=0.12)
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=100, pil_kwargs=PNG_OPTIONS)
    plt.close(fig)



def _fits(rounds: list[dict]) -> list[list[dict]]:
    """The rounds split into the fits that made them: a new fit starts where the depth prior changes."""
    fits: list[list[dict]] = []
    for q in rounds:
        if not fits or q.get("depth_prior") != fits[-1][-1].get("depth_prior"):
            fits.append([])
        fits[-1].append(q)
    return fits


def save_point_map_figure(path: Path, before_m: np.ndarray, after_m: np.ndarray, report: dict, title: str = "") -> None:
    """point_maps.png: how far overlapping views lie from each other (point-to-plane, mm) with the joint
    solve and after the point-map refinement, and the RMS of each ICP round.

    Args:
        before_m, after_m: (R,) signed distances (m) of the same point pairs.
        report: ``result.info["point_maps"]`` (accepted, reason, rounds, ...).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    b, a = np.abs(np.asarray(before_m)) * 1e3, np.abs(np.asarray(after_m)) * 1e3
    fig, (h, r) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    top = float(np.percentile(np.concatenate([b, a]), 99)) if len(b) else 1.0
    bins = np.linspace(0, max(top, 1.0), 60)
    h.hist(b, bins=bins, alpha=0.55, color="tab:red", label=f"joint solve: median {np.median(b):.2f} mm")
    h.hist(a, bins=bins, alpha=0.55, color="tab:blue", label=f"refined: median {np.median(a):.2f} mm")
    h.set_xlabel("distance between overlapping views (point to plane, mm)")
    h.set_ylabel("point pairs")
    h.legend()
    h.grid(alpha=0.3)
    fits = _fits(report.get("rounds") or [])
    for k, fit in enumerate(fits):  # the joint estimate solves again when its depth factors spread wider
        prior = fit[0].get("depth_prior")
        r.plot([q["radius_m"] * 1e3 for q in fit], [q["rms_m"] * 1e3 for q in fit], "o-",
               color="tab:blue" if k == len(fits) - 1 else "tab:gray",
               label=None if prior is None else f"depth prior {prior * 100:.2f} %")
    if fits:
        r.invert_xaxis()
        if len(fits) > 1:
            r.legend(fontsize=8)
    r.set_xlabel("correspondence radius of the round (mm)")
    r.set_ylabel("RMS after the round (mm)")
    r.grid(alpha=0.3)
    verdict = "applied" if report.get("accepted") else f"NOT applied: {report.get('reason', '')}"
    fig.suptitle((title + "\n" if title else "") + f"views placed by the kinematics; refinement {verdict}", fontsize=10)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.13, top=0.83, wspace=0.22)  # fixed: tight_layout costs a draw
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=100, pil_kwargs=PNG_OPTIONS)
    plt.close(fig)
