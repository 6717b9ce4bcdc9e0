"""Draw docs/img/frames.png: the frames of a bimanual setup and the transforms Bi-JCR solves for.

Run: .venv/bin/python tools/draw_frames.py
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch  # noqa: E402

NODES = {
    "b1": (0.0, 0.0), "e1": (0.0, 2.2), "c1": (1.3, 3.6),
    "b2": (6.0, 0.0), "e2": (6.0, 2.2), "c2": (4.7, 3.6),
    "w": (3.0, 5.2),
}
EDGES = [  # (from, to, label, known, curvature)
    ("b1", "e1", "T_b1_e1\n(forward kinematics)", True, 0.0),
    ("e1", "c1", "T_e1_c1 ?", False, 0.0),
    ("b2", "e2", "T_b2_e2\n(forward kinematics)", True, 0.0),
    ("e2", "c2", "T_e2_c2 ?", False, 0.0),
    ("w", "c1", "T_w_c1\n(model, up to scale)", True, 0.0),
    ("w", "c2", "T_w_c2\n(model, up to scale)", True, 0.0),
    ("b1", "b2", "T_b1_b2 ?", False, 0.0),
    ("b1", "w", "T_b1_w ?, scale ?", False, 0.25),
]


DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "frames.png"


def main(out: Path = DEFAULT_OUT) -> Path:
    fig, ax = plt.subplots(figsize=(9, 5.5))
    for a, b, label, known, rad in EDGES:
        (x0, y0), (x1, y1) = NODES[a], NODES[b]
        style = "-" if known else "--"
        color = "#333333" if known else "#c0392b"
        ax.add_patch(FancyArrowPatch((x0, y0), (x1, y1), arrowstyle="-|>", mutation_scale=14, linestyle=style,
                                     color=color, shrinkA=18, shrinkB=18, lw=1.6,
                                     connectionstyle=f"arc3,rad={rad}"))
        # label at the arc's midpoint (arc3 bows perpendicular to the chord by rad * length / 2)
        mx, my = (x0 + x1) / 2 + rad * (y1 - y0) / 2, (y0 + y1) / 2 - rad * (x1 - x0) / 2
        ax.text(mx, my, label, fontsize=8.5, ha="center", va="center", color=color,
                bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.9))
    for name, (x, y) in NODES.items():
        ax.scatter([x], [y], s=900, c="#eaf2fb" if name != "w" else "#fdf2e9", edgecolors="#2c3e50", zorder=3)
        ax.text(x, y, name, ha="center", va="center", fontsize=12, weight="bold", zorder=4)
    ax.text(3.0, -0.9, "solid: known (robot FK, foundation model)   dashed red: solved by Bi-JCR\n"
            "T_a_b maps points in frame b to frame a: p_a = T_a_b @ p_b", ha="center", fontsize=9)
    ax.set_xlim(-1, 7)
    ax.set_ylim(-1.3, 5.9)
    ax.axis("off")
    ax.set_title("Frames of a bimanual setup with wrist cameras")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(main())
