"""Inject a reconstruction into the preview world: table from the cloud, objects from their segments,
and (for evaluation on synthetic scenes) the true objects from ground_truth.yaml."""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape, check_T

from ._bodies import BodyShape, TablePlane, box_shape, fit_table, hull_shape, shape_from_points, table_from_plane
from ._record import Recorder
from ._world import PreviewWorld, SimObject

__all__ = ["table_from_segments", "estimated_shapes", "truth_shapes", "match_truth", "build_world",
           "ESTIMATE_COLOR", "TRUTH_COLOR"]

ESTIMATE_COLOR = (0.20, 0.55, 0.85, 1.0)
TRUTH_COLOR = (0.90, 0.35, 0.20, 1.0)
GHOST_ALPHA = 0.35


def table_from_segments(points: np.ndarray, labels: np.ndarray, seg_extras: dict | None = None) -> TablePlane:
    """The table: the segmentation's plane when it recorded one (``table_plane`` = (a, b, c, d)), else a
    RANSAC fit on the points labelled -1."""
    points = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    labels = check_shape("labels", np.asarray(labels), (len(points),))
    table_pts = points[labels < 0]
    if seg_extras and "table_plane" in seg_extras:
        pl = np.asarray(seg_extras["table_plane"], dtype=np.float64).reshape(-1)
        if pl.shape == (4,) and np.all(np.isfinite(pl)):
            n = pl[:3]
            near = table_pts[np.abs(table_pts @ (n / np.linalg.norm(n)) + pl[3] / np.linalg.norm(n)) < 0.01]
            return table_from_plane(n, pl[3], near if len(near) >= 3 else table_pts)
    return fit_table(points, labels)


def estimated_shapes(points: np.ndarray, labels: np.ndarray, table: TablePlane | None, ids=None,
                     kind: str = "auto", density: float | None = None) -> tuple[dict[int, BodyShape], list[str]]:
    """One collision shape per segmented object (label >= 0), from its points.

    Returns ``(shapes by object id, warnings)``: objects whose points cannot make a body (too few,
    degenerate) are left out with a warning.
    """
    from ._bodies import DEFAULT_DENSITY

    points = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    labels = check_shape("labels", np.asarray(labels), (len(points),))
    ids = sorted(int(i) for i in np.unique(labels) if i >= 0) if ids is None else [int(i) for i in ids]
    out, warnings = {}, []
    for k in ids:
        try:
            out[k] = shape_from_points(points[labels == k], table, kind=kind, density=density or DEFAULT_DENSITY)
        except ValueError as e:
            warnings.append(f"object {k}: no collision body ({e})")
    return out, warnings


def truth_shapes(objects: list[dict]) -> dict[int, BodyShape]:
    """Shapes of ground_truth.yaml ``objects`` (``id``, ``kind``, ``T_b1_o``, ``size``, ``mass``).

    ``shape`` (else ``kind``) box / cylinder / sphere map to the same primitive (a cylinder's axis is o's z,
    size = (2r, 2r, h)). A mesh of the synthetic catalogue (``shape: mesh``, ``kind`` duck / mug / bunny /
    torus) is the convex hull of that mesh at its ``size``, the shape the scene was simulated with
    (``bimanual_app.scene.mesh_hull``); any other mesh is simulated as the box of its ``size``.
    """
    out = {}
    for i, o in enumerate(objects):
        oid = int(o.get("id", i))
        T = check_T(f"ground_truth objects[{i}].T_b1_o", np.asarray(o["T_b1_o"], dtype=np.float64))
        size = np.asarray(o["size"], dtype=np.float64).reshape(-1)
        kind = str(o.get("shape", o.get("kind", "box"))).lower()  # synth: shape box/cylinder/mesh
        if kind == "mesh" and size.size == 3:
            try:
                from bimanual_app.scene import mesh_hull

                out[oid] = hull_shape(T, mesh_hull(str(o.get("kind", "")), size), o.get("mass"))
                continue
            except ValueError:
                pass  # not a catalogue mesh: its box
        if kind not in ("box", "cylinder", "sphere"):
            kind = "box"
        if kind == "sphere" and size.size == 1:
            size = np.repeat(size, 3)
        if kind == "cylinder" and size.size == 2:  # (diameter, height)
            size = np.array([size[0], size[0], size[1]])
        out[oid] = box_shape(T, size.reshape(3), o.get("mass"), kind)
    return out


def _color(c: tuple, alpha: float) -> tuple:
    return (c[0], c[1], c[2], alpha)


def _inner_points(shape: BodyShape, n: int = 6) -> np.ndarray:
    """(K, 3) points in b1 filling ``shape``: an n x n x n grid over its box, those inside it (its centre
    when none are)."""
    g = (np.arange(n) + 0.5) / n - 0.5
    local = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) * np.asarray(shape.size, float)
    P = local @ shape.T_b1_o[:3, :3].T + shape.T_b1_o[:3, 3]
    inside = shape.contains(P)
    return P[inside] if inside.any() else shape.T_b1_o[None, :3, 3]


def match_truth(estimated: dict[int, BodyShape], truth: dict[int, BodyShape], max_dist: float = 0.08,
                margin: float = 0.01, min_overlap: float = 0.5) -> dict[int, int]:
    """Estimated object id -> the true object it stands for (each true object used once).

    An estimated body stands for the true body that holds most of it: the share of points filling the
    estimated body that lie inside the true one grown by ``margin`` m. A body fitted to the visible part
    of a large object has its centre far from the true centre but lies inside it, so volume decides, not
    centres. Pairs with a share of at least ``min_overlap``, or centres within ``max_dist`` m, are
    matched, the most volume in common first (the share times the estimated body's volume: of two
    estimates of one true object, the one that fills more of it, not a fragment wholly inside it; then
    nearest centres); the rest are left out (no real object there).
    """
    pairs = []
    for ke, e in estimated.items():
        P = _inner_points(e)
        for kt, t in truth.items():
            share = float(t.contains(P, margin=margin).mean())
            d = float(np.linalg.norm(e.T_b1_o[:3, 3] - t.T_b1_o[:3, 3]))
            if share >= min_overlap or d <= max_dist:
                pairs.append((-share * float(e.volume), d, ke, kt))
    out, used = {}, set()
    for _, _, ke, kt in sorted(pairs):
        if ke not in out and kt not in used:
            out[ke] = kt
            used.add(kt)
    return out


def build_world(robot, T_b1_b2: np.ndarray, table: TablePlane | None, estimated: dict[int, BodyShape],
                truth: dict[int, BodyShape] | None = None, gui: bool = False,
                recorder: Recorder | None = None) -> tuple[PreviewWorld, dict[int, SimObject]]:
    """A :class:`PreviewWorld` with the table and objects; returns it and, per *estimated* object id, the
    physical body that stands for it.

    Without ``truth`` the estimated bodies are the physical objects. With ``truth`` (ground-truth shapes
    by true id) the true bodies are the physical ones and the estimated bodies are drawn beside them as
    ghosts (visual only, translucent): the preview's verdict is then tested against reality. Each
    estimated id maps to its nearest true object (:func:`match_truth`); an estimated object with no true
    object near it maps to nothing (it does not exist physically).
    """
    world = PreviewWorld(robot, T_b1_b2, gui=gui, recorder=recorder)
    try:
        if table is not None:
            world.add_table(table)
        physical: dict[int, SimObject] = {}
        ghost = bool(truth)
        for k, sh in estimated.items():
            col = _color(ESTIMATE_COLOR, GHOST_ALPHA) if ghost else ESTIMATE_COLOR
            o = world.add_object(f"est:{k}", sh, k, "estimate", col, ghost=ghost)
            if not ghost:
                physical[k] = o
        if truth:
            match = match_truth(estimated, truth)
            true_objs = {kt: world.add_object(f"true:{kt}", sh, kt, "truth", TRUTH_COLOR) for kt, sh in truth.items()}
            physical = {ke: true_objs[kt] for ke, kt in match.items()}
        world.settle_objects(0.3)
        return world, physical
    except BaseException:
        world.close()
        raise
