"""Unsure points join the segments the sure points make, and never link two.

A point map marks a surface it sees at a grazing angle unsure (the steep side of a box or a can: its depth
spreads over the pixel); the metric cloud keeps such a point only where other views saw a surface there
too (``calibration._fusion.confirmed_points``). Those sides are what closes the gap between two touching
objects, so the graph segmenter runs on the sure points alone, and each unsure point then takes the label of
the segment it is connected to: the nearest sure point above the table along chains of points within
``radius`` (a shortest path from each segment's sure points, scipy's Dijkstra), so a box's side joins the box
down to the table, and the sides of two touching objects each join their own. A side is no higher than the
object it bounds: an unsure point joins only a segment whose sure points reach its height (less ``RISE``), so
the side of a tall box never joins the lower neighbour whose rim it passes on the way down. Unsure points
that no chain reaches, or that lie in the table's band, are background.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape

__all__ = ["join_unsure"]

RADIUS = 0.008  # m: the longest link of a chain (the confirmed sides' spacing: 3-6 mm on the bench's clouds)
RISE = 0.004  # m: how far an unsure point may lie above the top of the segment it joins (half a link: noise)


def join_unsure(points: np.ndarray, labels: np.ndarray, unsure: np.ndarray, height: np.ndarray,
                min_height: float, radius: float = RADIUS, rise: float = RISE) -> np.ndarray:
    """(N,) int32: ``labels`` (N,) of the sure points kept, the unsure points' labels filled in.

    Args:
        points: (N, 3) metres.
        labels: (N,) int32 segment ids of the sure points (-1 background); unsure points' entries ignored.
        unsure: (N,) bool.
        height: (N,) height above the table (m); points under ``min_height`` are the table's band.
        min_height: the lowest height of an object point (the segmenter's candidates).
        radius: the longest link between two points of a chain (m).
        rise: how far (m) an unsure point may lie above the highest sure point of the segment it joins.
    """
    P = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    n = len(P)
    unsure = check_shape("unsure", np.asarray(unsure, dtype=bool), (n,))
    out = check_shape("labels", np.asarray(labels, dtype=np.int32), (n,)).copy()
    out[unsure] = -1
    height = check_shape("height", np.asarray(height, dtype=np.float64), (n,))
    free = np.flatnonzero(unsure & (height >= min_height))
    if not len(free):
        return out
    graph, src = _chains(P, unsure, height, free, min_height, radius)
    if not len(src):
        return out
    best = np.full(len(free), np.inf)
    for lab in np.unique(out[src]):  # each segment's chains (background's too), the nearest segment wins
        dist = _from_segment(graph, np.flatnonzero(out[src] == lab), len(src))
        top = height[(out == lab) & ~unsure].max()
        take = (height[free] <= top + rise) & (dist < best)
        best[take] = dist[take]
        out[free[take]] = lab
    return out


def _chains(P: np.ndarray, unsure: np.ndarray, height: np.ndarray, free: np.ndarray, min_height: float,
            radius: float):
    """The graph of chains: nodes are the sure points above the table within ``radius`` of an unsure one (the
    sources, returned as indices into ``P``) then the unsure points ``free``; links of at most ``radius`` m,
    each with an unsure end (a chain runs through unsure points). Returns (CSR graph, sources)."""
    from scipy.sparse import coo_matrix
    from scipy.spatial import cKDTree

    src = np.flatnonzero(~unsure)
    near = cKDTree(P[free]).query(P[src], k=1, distance_upper_bound=radius)[0] <= radius
    src = src[near & (height[src] >= min_height)]
    nodes = np.concatenate([src, free])
    pairs = cKDTree(P[nodes]).query_pairs(radius, output_type="ndarray")
    pairs = pairs[(pairs >= len(src)).any(axis=1)]  # no sure-sure links
    w = np.linalg.norm(P[nodes[pairs[:, 0]]] - P[nodes[pairs[:, 1]]], axis=1) + 1e-9
    graph = coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(len(nodes), len(nodes))).tocsr()
    return graph, src


def _from_segment(graph, sources: np.ndarray, n_src: int) -> np.ndarray:
    """(F,) chain length from the nearest of ``sources`` (indices among the graph's first ``n_src`` nodes) to
    each unsure node (inf where none reaches)."""
    from scipy.sparse.csgraph import dijkstra

    return dijkstra(graph, directed=False, indices=sources, min_only=True)[n_src:]
