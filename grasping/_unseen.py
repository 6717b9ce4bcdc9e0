"""The space around an object that no camera saw into, from the capture's depth views (free-space carving).

A wrist camera that saw a surface at depth D along a pixel saw through everything nearer along that ray, so
a place some camera saw past is empty; a place next to an object that no camera saw past may hold more of
the object: a mug's handle on its far side, the back half of a bunny seen from the front. The grasp checks
search hand-overs whose fingers keep out of those places first (``PlanParams.carve_radius``). The table-based
``_objects.unseen_space`` only knows the ground was hidden there; the depth views bound the hidden space in
3D, above the ground too.

Written with numpy and scipy's KD-tree: the test is a projection per view (``bimanual_app.views``); Open3D's
``VoxelBlockGrid`` integrates depth into a TSDF, which marks the same cells unknown but needs its own
intrinsics and image types for each view, and a GPU-sized grid for a few thousand cells.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_shape
from bimanual_app.views import DepthViews, seen_free

from ._objects import Support

__all__ = ["carved_unseen"]


def carved_unseen(obj_points: np.ndarray, other_points: np.ndarray, support: Support, views: DepthViews,
                  radius: float = 0.03, cell: float = 0.005, skin: float = 0.008, tol: float = 0.005,
                  min_elevation: float = 0.01) -> np.ndarray:
    """(K, 3) centres of the ``cell`` m cells within ``radius`` of an object that no view saw past.

    Only cells more than ``skin`` from the object's own points and from ``other_points`` count (nearer, the
    views' noise decides; the object's own surface is in its points), from ``min_elevation`` above the
    table to the object's top. A cell is seen when some view's surface at its pixel lies more than ``tol``
    beyond it (:func:`bimanual_app.views.seen_free`), or more than the views' own disagreement where that is
    larger (``views.disagreement``: a real capture's views see centimetres past each other's surfaces, and
    nearer than that a view seeing past a cell proves nothing). Cells inside the object (a mug's hollow, the
    body under a can's seen top) are unseen too.

    ``obj_points`` (M, 3), ``other_points`` (O, 3): the object's and the rest of the scene's points, in b1.
    """
    from scipy.spatial import cKDTree

    P = check_shape("obj_points", np.asarray(obj_points, dtype=np.float64), (None, 3))
    O = check_shape("other_points", np.asarray(other_points, dtype=np.float64), (None, 3))
    if len(P) == 0 or len(views) == 0:
        return np.zeros((0, 3))
    lo, hi = P.min(axis=0) - radius, P.max(axis=0) + radius
    G = np.stack(np.meshgrid(*[np.arange(lo[i], hi[i] + 0.5 * cell, cell) for i in range(3)], indexing="ij"),
                 axis=-1).reshape(-1, 3)
    elev = support.elevation(G)
    top = float(np.percentile(support.elevation(P), 99.5))
    G = G[(elev >= min_elevation) & (elev <= top)]
    d_own = cKDTree(P).query(G, distance_upper_bound=radius + cell)[0]
    G = G[(d_own > skin) & (d_own <= radius)]
    if len(O) and len(G):
        G = G[~np.isfinite(cKDTree(O).query(G, distance_upper_bound=skin)[0])]
    return G[~seen_free(G, views, views.tolerance(tol))] if len(G) else G
