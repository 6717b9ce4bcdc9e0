"""Unsure points join the segments the sure points make, and never link two.

A point map marks a surface it sees at a grazing angle unsure (the steep side of a box or a can: its depth
spreads over the pixel); the metric cloud keeps such a point only where other views saw a surface there
too (``calibration._fusion.confirmed_points``). Those sides are what closes the gap between two touching
objects, so the graph segmenter runs on the sure points alone, and each unsure point then takes the label of
the segment it is connected to: the nearest sure point above the table along chains of points within
``radius`` (a multi-source shortest path, scipy's Dijkstra), so a box's side joins the box down to the
table, and the sides of two touching objects each join their own. Unsure points that no chain reaches, or
that lie in the table's band, are background.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape

__all__ = ["join_unsure"]

RADIUS = 0.008  # m: the longest link of a chain (the confirmed sides' spacing: 3-6 mm on the bench's clouds)


def join_unsure(points: np.ndarray, labels: np.ndarray, unsure: np.ndarray, height: np.ndarray,
                min_height: float, radius: float = RADIUS) -> np.ndarray:
    """(N,) int32: ``labels`` (N,) of the sure points kept, the unsure points' labels filled in.

    Args:
        points: (N, 3) metres.
        labels: (N,) int32 segment ids of the sure points (-1 background); unsure points' entries ignored.
        unsure: (N,) bool.
        height: (N,) height above the table (m); points under ``min_height`` are the table's band.
        min_height: the lowest height of an object point (the segmenter's candidates).
        radius: the longest link between two points of a chain (m).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra
    from scipy.spatial import cKDTree

    P = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    n = len(P)
    unsure = check_shape("unsure", np.asarray(unsure, dtype=bool), (n,))
    out = check_shape("labels", np.asarray(labels, dtype=np.int32), (n,)).copy()
    out[unsure] = -1
    height = check_shape("height", np.asarray(height, dtype=np.float64), (n,))
    free = np.flatnonzero(unsure & (height >= min_height))
    if not len(free):
        return out
    # the sure points an unsure one can link to: the sources, each with its segment (background too)
    src = np.flatnonzero(~unsure)
    near = cKDTree(P[free]).query(P[src], k=1, distance_upper_bound=radius)[0] <= radius
    src = src[near & (height[src] >= min_height)]
    if not len(src):
        return out
    nodes = np.concatenate([src, free])
    pairs = cKDTree(P[nodes]).query_pairs(radius, output_type="ndarray")
    pairs = pairs[(pairs >= len(src)).any(axis=1)]  # no sure-sure links: a chain runs through unsure points
    w = np.linalg.norm(P[nodes[pairs[:, 0]]] - P[nodes[pairs[:, 1]]], axis=1) + 1e-9
    graph = coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(len(nodes), len(nodes))).tocsr()
    dist, _, origin = dijkstra(graph, directed=False, indices=np.arange(len(src)), min_only=True,
                               return_predecessors=True)
    reached = np.isfinite(dist[len(src):])
    out[free[reached]] = out[src[origin[len(src):][reached]]]
    return out
