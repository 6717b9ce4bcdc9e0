"""grasps.json (the plan as plain JSON, written atomically) and grasps.png (grippers drawn on the cloud)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimanual_app.io_utils import atomic_path, to_jsonable, write_json
from bimanual_app.transforms import inv_T

from ._plan import GraspPlan, ObjectPlan

__all__ = ["plan_to_dict", "write_grasps_json", "draw_plan", "FORMAT"]

FORMAT = 1
FRAME_NOTE = ("g: origin midway between the fingertips when closed, z = approach (palm -> object), "
              "y = closing direction, x = y cross z")


def _grasp_fields(gs, i: int) -> dict:
    return {
        "kind": gs.kind,
        "T_b1_g": gs.T_b1_g[i],
        "width": float(gs.width[i]),
        "contact_width": float(gs.contact_width[i]),
        "depth": float(gs.depth[i]),
        "score": float(gs.score[i]),
        "terms": {k: float(v[i]) for k, v in gs.terms.items()},
    }


def _in_b2(T_b1_g: np.ndarray, T_b1_b2: np.ndarray | None):
    return None if T_b1_b2 is None else inv_T(T_b1_b2) @ T_b1_g


def _object_dict(op: ObjectPlan, T_b1_b2: np.ndarray | None, arms_checked: bool) -> dict:
    geo = op.geometry
    d = {
        "id": op.id,
        "mode": op.mode,
        "problems": [str(p) for p in op.problems],
        "notes": list(op.notes),
    }
    if geo is not None:
        d.update({"n_points": geo.n_points, "centre_b1": geo.centre, "T_b1_box": geo.T_b1_box, "extent": geo.extent,
                  "mass_estimate": round(op.mass_estimate, 3),
                  "shape": {"kind": op.shape, "fit": round(op.shape_fit, 3), "open_ends": len(op.open_ends)}})
    grasps = []
    rank_of: dict[int, int] = {}
    gs = op.grasps
    if gs is not None and len(gs):
        if arms_checked:
            where: dict[int, dict] = {}
            for arm, ag in op.reach.items():
                for k, i in enumerate(ag.index):
                    where.setdefault(int(i), {})[arm] = k
            listed = sorted(where)
        else:
            where, listed = {}, list(range(len(gs)))
        for i in listed:
            e = _grasp_fields(gs, i)
            e["T_b2_g"] = _in_b2(gs.T_b1_g[i], T_b1_b2)
            arms = where.get(i, {})
            e["arm"] = ("both" if len(arms) == 2 else next(iter(arms))) if arms else None
            e["arms"] = {}
            for arm, k in arms.items():
                ag = op.reach[arm]
                T_used = ag.grasps.T_b1_g[k]
                e["arms"][arm] = {"T_b1_g": T_used, "T_b_g": ag.T_b_g[k], "q": ag.q[k], "q_pregrasp": ag.q_pre[k],
                                  "turned": bool(T_used[:3, 1] @ gs.T_b1_g[i][:3, 1] < 0)}
            e["reach_checked"] = arms_checked
            grasps.append(e)
        order = np.argsort([-e["score"] for e in grasps], kind="stable")
        grasps = [grasps[j] for j in order]
        for r, j in enumerate(order):
            grasps[r]["rank"] = r + 1
            rank_of[int(listed[j])] = r + 1
    d["grasps"] = grasps
    joint = []
    for r, pair in enumerate(op.joint):
        p_ag, s_ag = op.pair_grasps(pair)
        ent = {"rank": r + 1, "kind": pair.kind, "score": pair.score, "imbalance": pair.imbalance,
               "separation": pair.separation, "liftable": bool(pair.liftable)}
        for arm, ag, k in (("primary", p_ag, pair.i_primary), ("secondary", s_ag, pair.i_secondary)):
            g = _grasp_fields(ag.grasps, k)
            g.update({"T_b2_g": _in_b2(ag.grasps.T_b1_g[k], T_b1_b2), "T_b_g": ag.T_b_g[k], "q": ag.q[k],
                      "q_pregrasp": ag.q_pre[k]})
            if pair.kind == "push":
                g["press"] = float(-ag.grasps.depth[k])
                g["squeeze_b1"] = ag.grasps.extra["squeeze"][k]
                g["contact_b1"] = ag.grasps.extra["contact"][k]
                g["retreat_b1"] = ag.grasps.extra["retreat"][k]
            else:
                g["grasp_rank"] = rank_of.get(int(ag.index[k]))
            ent[arm] = g
        joint.append(ent)
    d["joint_grasps"] = joint
    d["handover"] = _handover_dict(op.handover, op, rank_of, T_b1_b2) if op.handover is not None else None
    d["handover_alternatives"] = [_handover_dict(h, op, rank_of, T_b1_b2) for h in op.handover_alternatives]
    d["stats"] = op.stats
    d["timings"] = {k: round(v, 4) for k, v in op.timings.items()}
    return d


def _handover_dict(h, op, rank_of: dict, T_b1_b2) -> dict:
    """One hand-over as grasps.json writes it (``handover`` and each of ``handover_alternatives``)."""
    giver = h.givers if h.givers is not None else op.reach[h.giver_arm]
    gi = h.giver_index
    return {
        "T_move": h.T_move,
        "object_centre_b1": h.centre,
        "gap": h.gap,
        "score": h.score,
        "catch": {"probability": h.catch, "margin_m": h.margin, "position_sigma_m": h.sigma},
        "giver": {"arm": h.giver_arm, "grasp_rank": rank_of.get(int(giver.index[gi])),
                  "pick": {"T_b1_g": giver.grasps.T_b1_g[gi], "q": giver.q[gi], "q_pregrasp": giver.q_pre[gi],
                           "width": float(giver.grasps.width[gi])},
                  "transfer": {"T_b1_g": h.giver_T_b1_g, "T_b2_g": _in_b2(h.giver_T_b1_g, T_b1_b2), "q": h.giver_q},
                  "contact_width": h.giver_width, "release_width": h.giver_release_width},
        "receiver": {"arm": h.receiver_arm, "T_b1_g": h.receiver["T_b1_g"],
                     "T_b2_g": _in_b2(h.receiver["T_b1_g"], T_b1_b2), "width": h.receiver["width"],
                     "contact_width": h.receiver["contact_width"], "depth": h.receiver["depth"],
                     "score": h.receiver["score"], "terms": h.receiver["terms"], "q": h.receiver["q"],
                     "q_pregrasp": h.receiver["q_pre"]},
    }


def plan_to_dict(plan: GraspPlan, inputs: dict | None = None) -> dict:
    """The plan as a JSON-ready dict (format documented in docs/grasping.md)."""
    g = plan.gripper
    arms_checked = bool(plan.arms)
    return to_jsonable({
        "format": FORMAT,
        "frame": "b1",
        "gripper": {"robot": g.robot, "min_width": g.min_width, "max_width": g.max_width, "stroke": g.stroke,
                    "finger_length": g.finger_length, "finger_width": g.finger_width, "frame": FRAME_NOTE},
        "inputs": dict(inputs or {}),
        "T_b1_b2": plan.T_b1_b2,
        "arms": plan.arms,
        "reach_checked": arms_checked,
        "pregrasp_distance": plan.params.sampler.approach,
        "table": {"up": plan.support.up, "height": plan.support.height, "source": plan.support.source},
        "objects": [_object_dict(op, plan.T_b1_b2, arms_checked) for op in plan.objects],
        "timings": {k: round(v, 4) for k, v in plan.timings.items()},
    })


def write_grasps_json(path: str | Path, plan: GraspPlan, inputs: dict | None = None) -> dict:
    """Write ``plan`` to ``path`` atomically; returns the dict written."""
    d = plan_to_dict(plan, inputs)
    write_json(path, d)
    return d


# ---------------------------------------------------------------------------------------------- drawing
_EDGES = [(0, 1), (0, 2), (0, 4), (1, 3), (1, 5), (2, 3), (2, 6), (3, 7), (4, 5), (4, 6), (5, 7), (6, 7)]


def _gripper_segments(gripper, T_b1_g: np.ndarray, width: float) -> np.ndarray:
    """(E, 2, 3) wireframe edges of every gripper shape's box at ``width``, in b1."""
    segs = []
    for s in gripper.shapes:
        c = s.corners_g(width) @ T_b1_g[:3, :3].T + T_b1_g[:3, 3]
        segs += [(c[a], c[b]) for a, b in _EDGES]
    return np.array(segs)


def _drawn_grippers(plan: GraspPlan) -> list[tuple[np.ndarray, str, str]]:
    """The grippers drawn: each object's best grasp per arm, joint pair and hand-over, as
    ``(segments (E, 2, 3), colour, label)``."""
    drawn = []
    for op in plan.objects:
        if op.grasps is not None:
            for arm, ag in op.reach.items():
                if len(ag):
                    drawn.append((_gripper_segments(plan.gripper, ag.grasps.T_b1_g[0], ag.grasps.width[0]),
                                  "tab:red" if arm == "primary" else "tab:blue", f"obj {op.id} best {arm}"))
            if not op.reach and len(op.grasps):
                drawn.append((_gripper_segments(plan.gripper, op.grasps.T_b1_g[0], op.grasps.width[0]), "tab:red",
                              f"obj {op.id} best (reach not checked)"))
        if op.joint:
            pair = op.joint[0]
            p_ag, s_ag = op.pair_grasps(pair)
            drawn.append((_gripper_segments(plan.gripper, p_ag.grasps.T_b1_g[pair.i_primary], p_ag.grasps.width[pair.i_primary]),
                          "darkred", f"obj {op.id} joint ({pair.kind}) primary"))
            drawn.append((_gripper_segments(plan.gripper, s_ag.grasps.T_b1_g[pair.i_secondary], s_ag.grasps.width[pair.i_secondary]),
                          "navy", f"obj {op.id} joint ({pair.kind}) secondary"))
        if op.handover is not None:
            h = op.handover
            drawn.append((_gripper_segments(plan.gripper, h.giver_T_b1_g, h.giver_width), "darkorange",
                          f"obj {op.id} hand-over giver ({h.giver_arm})"))
            drawn.append((_gripper_segments(plan.gripper, h.receiver["T_b1_g"], h.receiver["width"]), "purple",
                          f"obj {op.id} hand-over receiver ({h.receiver_arm})"))
    return drawn


def _draw_objects(ax, plan: GraspPlan, a: int, b: int) -> None:
    """The unseen space (table-based, and what no camera saw past), each object moved to its hand-over's transfer
    pose, and each object's id and mode."""
    unseen = [op.unseen for op in plan.objects if op.unseen is not None and len(op.unseen)]
    if unseen:  # the space no camera saw into, solid for the grasps: light crosses under the points
        U = np.concatenate(unseen)
        ax.scatter(U[:, a], U[:, b], s=4, marker="x", c="0.55", linewidths=0.4, alpha=0.35, zorder=0,
                   label="unseen (solid for grasps)" if a == 0 and b == 1 else None)
    carved = [op.carved for op in plan.objects if op.carved is not None and len(op.carved)]
    if carved:  # what no camera saw past near each object (hand-overs keep out of it where they can)
        C = np.concatenate(carved)
        ax.scatter(C[:, a], C[:, b], s=5, marker="s", c="steelblue", linewidths=0, alpha=0.3, zorder=0,
                   label="no camera saw past" if a == 0 and b == 1 else None)
    for op in plan.objects:
        if op.handover is not None and op.geometry is not None:
            Q = op.geometry.points @ op.handover.T_move[:3, :3].T + op.handover.T_move[:3, 3]
            ax.scatter(Q[:, a], Q[:, b], s=0.6, c="tan", linewidths=0)
        if op.geometry is not None:
            c = op.geometry.centre
            ax.annotate(f"{op.id}: {op.mode}", (c[a], c[b]), fontsize=8, ha="center",
                        bbox=dict(boxstyle="round,pad=0.2", fc="white", alpha=0.7))


def _frame_view(ax, plan: GraspPlan, drawn: list, title: str, a: int, b: int) -> None:
    """Title, bases, axes and limits of one view: the region that matters (the bases, the objects and the
    grippers drawn), not far background points."""
    if plan.T_b1_b2 is not None:
        for name, T in (("b1", np.eye(4)), ("b2", plan.T_b1_b2)):
            ax.plot(T[a, 3], T[b, 3], "k^", ms=8)
            ax.annotate(name, (T[a, 3], T[b, 3]), textcoords="offset points", xytext=(5, 5))
    ax.set_title(title)
    ax.set_aspect("equal")
    focus = [np.zeros(3)] + ([plan.T_b1_b2[:3, 3]] if plan.T_b1_b2 is not None else [])
    focus += [op.geometry.centre for op in plan.objects if op.geometry is not None]
    focus += [segs.reshape(-1, 3) for segs, _, _ in drawn]
    F = np.vstack([np.atleast_2d(f) for f in focus])
    lo, hi = F.min(axis=0) - 0.15, F.max(axis=0) + 0.15
    ax.set_xlim(lo[a], hi[a])
    ax.set_ylim(lo[b], hi[b])
    ax.set_xlabel("xyz"[a] + " (m)")
    ax.set_ylabel("xyz"[b] + " (m)")


def _dots(ax, x: np.ndarray, y: np.ndarray, labels: np.ndarray, colors: np.ndarray, depth: np.ndarray) -> None:
    """Points (N,) at (x, y) as one-pixel dots, one ``plot`` per label (coloured ``colors`` (N, 4)), the labels
    nearest the viewer (largest mean ``depth``) drawn last: Agg draws a pixel marker several times faster than
    a scatter's per-point circles (0.2 s for 30,000 points), which at this size look the same."""
    keys = np.unique(labels)
    for k in sorted(keys, key=lambda k: (k >= 0, float(depth[labels == k].mean()))):  # unlabelled below
        m = labels == k
        ax.plot(x[m], y[m], ",", color=colors[np.argmax(m)], linestyle="none", zorder=1)  # a scatter's layer


def draw_plan(path: str | Path, plan: GraspPlan, points: np.ndarray, labels: np.ndarray, max_points: int = 30000) -> None:
    """grasps.png: top and side views of the cloud with each object's best grasp, joint pair and hand-over."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    rng = np.random.default_rng(0)
    sel = rng.choice(len(points), size=min(max_points, len(points)), replace=False)
    P, L = points[sel], labels[sel]
    cmap = plt.get_cmap("tab10")
    colors = np.where(L[:, None] < 0, np.array([[0.75, 0.75, 0.75, 1.0]]), cmap(np.maximum(L, 0) % 10))
    fig, axes = plt.subplots(1, 2, figsize=(14, 6.5))
    views = [("top view (x-y in b1)", 0, 1), ("side view (x-z in b1)", 0, 2)]
    drawn = _drawn_grippers(plan)
    for ax, (title, a, b) in zip(axes, views):
        _dots(ax, P[:, a], P[:, b], L, colors, P[:, 2] if b != 2 else P[:, 1])
        _draw_objects(ax, plan, a, b)
        seen = set()
        for segs, col, lab in drawn:
            lc = LineCollection(segs[:, :, [a, b]], colors=col, linewidths=0.9,
                                label=lab if lab not in seen else None)
            seen.add(lab)
            ax.add_collection(lc)
        _frame_view(ax, plan, drawn, title, a, b)
    handles, labs = axes[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labs, loc="lower center", ncol=4, fontsize=7)
    fig.suptitle("grasps: best per arm (red primary, blue secondary), joint pair, hand-over at the transfer pose")
    fig.tight_layout(rect=(0, 0.08, 1, 0.96))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
