"""Per-object geometry for grasping: the support plane, a gravity-aligned box, surface points with normals.

The table is the plane the objects stand on: the segments file's ``table_plane`` when it has one, else a
RANSAC plane (Open3D ``segment_plane``) through the points labelled -1, else b1's xy plane under the
lowest object point. Its normal ``up`` points to the side the objects are on.

Each object gets a box aligned with gravity: the minimum-area rectangle (OpenCV ``minAreaRect``) of its
points projected on the table, from the table up to its highest point (objects rest on the table, whose
cloud usually lacks their bottom face). The box centre is the estimate of the centre of mass used for
balance and centring. Surface points are voxel-downsampled and get normals from Open3D
(``estimate_normals``), oriented away from the box's vertical axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.io_utils import Problem
from bimanual_app.transforms import perpendicular_basis

__all__ = ["Support", "ObjectGeometry", "estimate_support", "object_geometry", "check_graspable", "closed_geometry",
           "complete_by_symmetry", "complete_walls", "hides_table", "fit_circle", "refine_circle", "primitive_fit"]


@dataclass(frozen=True)
class Support:
    """The table plane: points p with ``up @ p = height`` (up (3,) unit, pointing to the objects' side)."""

    up: np.ndarray
    height: float
    source: str

    def elevation(self, P: np.ndarray) -> np.ndarray:
        """Height (...,) of points (..., 3) above the table."""
        return np.asarray(P) @ self.up - self.height


@dataclass
class ObjectGeometry:
    """One segmented object.

    Attributes:
        id: its label.
        n_points: raw points in the segment.
        points: (M, 3) voxel-downsampled surface points in b1.
        normals: (M, 3) unit outward normals.
        T_b1_box: (4, 4) gravity-aligned box: z = up, x = the box's longer horizontal side, origin = centre.
        extent: (3,) box side lengths along its x, y, z (m).
        centre: (3,) box centre in b1 (the estimate of the centre of mass).
        voxel: the downsampling voxel size (m).
        observed: (M,) bool, False for points added by symmetric completion (not seen by a camera).
    """

    id: int
    n_points: int
    points: np.ndarray
    normals: np.ndarray
    T_b1_box: np.ndarray
    extent: np.ndarray
    centre: np.ndarray
    voxel: float
    observed: np.ndarray | None = None

    def __post_init__(self):
        if self.observed is None:
            self.observed = np.ones(len(self.points), dtype=bool)

    @property
    def narrowest(self) -> float:
        """The smallest side of the box (m)."""
        return float(np.min(self.extent))


def _perp_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e1, e2) spanning the plane normal to unit ``up`` (3,), e1 the one nearer the base x axis: the shared
    ``perpendicular_basis`` turned a quarter turn about up."""
    e1, e2 = perpendicular_basis(up)
    return -e2, e1


def estimate_support(points: np.ndarray, labels: np.ndarray, table_plane: np.ndarray | None = None,
                     seed: int = 0) -> Support:
    """The table plane under the objects (see the module docstring). points (N, 3), labels (N,)."""
    obj = points[labels >= 0]
    ref = obj.mean(axis=0) if len(obj) else points.mean(axis=0)

    def oriented(n: np.ndarray, d: float, src: str) -> Support:
        n = np.asarray(n, dtype=np.float64)
        s = 1.0 / np.linalg.norm(n)
        n, d = n * s, float(d) * s
        if n @ ref + d < 0:
            n, d = -n, -d
        return Support(n, -d, src)

    if table_plane is not None:
        return oriented(table_plane[:3], table_plane[3], "segments table_plane")
    table = points[labels < 0]
    if len(table) >= 50:
        from segmentation import fit_plane

        # the project's one plane fitter; a plane through the background that is not roughly horizontal in b1
        # (normal within 37 degrees of z), or that holds under 30 % of it, is not the table
        fit = fit_plane(table, 0.005, up=np.array([0.0, 0.0, 1.0]), cos_level=0.8, level_only=True,
                        iterations=200, min_points=50, seed=seed)
        if fit is not None and fit.support >= 0.3 * len(table):
            return oriented(fit.normal, fit.offset, "RANSAC plane of the table points")
    z0 = float(obj[:, 2].min()) if len(obj) else float(points[:, 2].min())
    return Support(np.array([0.0, 0.0, 1.0]), z0, "b1 xy plane under the lowest object point")


def object_geometry(obj_id: int, P: np.ndarray, support: Support, voxel: float = 0.003,
                    normal_radius: float | None = None, complete: bool = True,
                    background: np.ndarray | None = None, others: np.ndarray | None = None) -> ObjectGeometry:
    """Gravity-aligned box, downsampled points and outward normals of one object's points P (M, 3);
    with ``complete``, unseen sides filled by :func:`complete_by_symmetry` and, for a carton standing on the
    table (both sides >= ``WALLS_MIN_SIDE``, its points covering its footprint rectangle), by
    :func:`complete_walls`.

    ``background`` (K, 3): the scene's other points (the table); ``others`` (O, 3): the other objects' points.
    An object whose lowest points are above the table (only its top was seen, as wrist cameras looking down
    see a carton or a small box) still stands on the table when the table is hidden under its footprint and
    no other object is seen under it (:func:`hides_table`): its box then reaches down to the table.
    """
    import cv2
    import open3d as o3d

    up = support.up
    e1, e2 = _perp_basis(up)
    xy = np.stack([P @ e1, P @ e2], axis=1)
    (_, _), (w, h), ang = cv2.minAreaRect(xy.astype(np.float32))
    a = np.deg2rad(ang)
    u = np.cos(a) * e1 + np.sin(a) * e2
    v = np.cross(up, u)
    if h > w:  # x along the longer side
        u, v = v, -u
    # extents from trimmed ranges: a few noisy points must not make an object look wider than it is
    q = (0.5, 99.5) if len(P) >= 200 else (0.0, 100.0)
    lo_u, hi_u = np.percentile(P @ u, q)
    lo_v, hi_v = np.percentile(P @ v, q)
    elev = support.elevation(P)
    top = float(np.percentile(elev, q[1]))
    bottom = max(0.0, float(np.percentile(elev, q[0])))
    bottom = 0.0 if bottom < 0.02 else bottom  # resting on the table: the box reaches down to it
    if bottom > 0.0 and background is not None and hides_table(background, support, u, v, (lo_u, hi_u), (lo_v, hi_v),
                                                               others=others, bottom=bottom):
        bottom = 0.0  # only the top was seen, but nothing under it: it stands on the table
    centre = 0.5 * (lo_u + hi_u) * u + 0.5 * (lo_v + hi_v) * v + (support.height + 0.5 * (top + bottom)) * up
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = u, v, up, centre
    extent = np.maximum(np.array([hi_u - lo_u, hi_v - lo_v, top - bottom]), 1e-6)

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc = pc.voxel_down_sample(voxel)
    r = normal_radius or max(3.0 * voxel, 0.008)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=r, max_nn=30))
    Q = np.asarray(pc.points, dtype=np.float64)
    N = np.asarray(pc.normals, dtype=np.float64)
    # outward: away from the box's vertical axis for side faces, up for the top. For convex shapes this
    # is exact; Open3D's consistent-tangent-plane orientation is slower and no better on open scans.
    rel = Q - centre
    radial = rel - np.outer(rel @ up, up)
    top_like = np.abs(N @ up) > 0.7
    ref = np.where(top_like[:, None], np.outer(np.sign(rel @ up + 1e-12), up), radial)
    flip = np.einsum("ij,ij->i", N, ref) < 0
    N[flip] *= -1
    geo = ObjectGeometry(int(obj_id), len(P), Q, N, T, extent, centre, voxel)
    if not complete:
        return geo
    geo = complete_cylinder(geo, support, bottom)
    geo = complete_by_symmetry(geo, support)
    big = min(extent[0], extent[1]) >= WALLS_MIN_SIDE
    if bottom == 0.0 and big and _footprint_cover(P @ u, P @ v, (lo_u, hi_u), (lo_v, hi_v)) >= WALLS_MIN_COVER:
        geo = complete_walls(geo, support)
    return geo


WALLS_MIN_SIDE = 0.08  # m: side walls are completed for objects at least this wide both ways (cartons) ...
WALLS_MIN_COVER = 0.95  # ... whose points cover this share of their footprint rectangle (a 20 cm disc: 0.93)


def _footprint_cover(pu: np.ndarray, pv: np.ndarray, range_u: tuple, range_v: tuple, cell: float = 0.015) -> float:
    """Share of the footprint rectangle's ``cell``-sized cells that hold a point (coordinates pu, pv (M,))."""
    (lu, hu), (lv, hv) = range_u, range_v
    nu, nv = max(1, int(round((hu - lu) / cell))), max(1, int(round((hv - lv) / cell)))
    ok = (pu >= lu) & (pu <= hu) & (pv >= lv) & (pv <= hv)
    iu = np.clip(((pu[ok] - lu) / max(hu - lu, 1e-9) * nu).astype(int), 0, nu - 1)
    iv = np.clip(((pv[ok] - lv) / max(hv - lv, 1e-9) * nv).astype(int), 0, nv - 1)
    occ = np.zeros((nu, nv), dtype=bool)
    occ[iu, iv] = True
    return float(occ.mean())


def hides_table(background: np.ndarray, support: Support, u: np.ndarray, v: np.ndarray, range_u: tuple,
                range_v: tuple, inset: float = 0.02, ring: float = 0.06, max_ratio: float = 0.2,
                min_ring_points: int = 50, others: np.ndarray | None = None, bottom: float = 0.0,
                min_side: float = 0.02) -> bool:
    """Whether an object with footprint ``range_u`` x ``range_v`` (along the horizontal unit axes u, v (3,))
    hides the table: table points (``background`` (K, 3) within 1.5 cm of the table plane) inside the
    footprint, ``inset`` m in from its edges (a quarter of its narrower side where that is less), are under
    ``max_ratio`` times as dense as in the ``ring`` m wide band around it (which must hold
    ``min_ring_points``), and no point of another object (``others`` (O, 3)) lies there between the table and
    the object's lowest seen point (``bottom`` m above the table): what stands on the table hides it from
    every camera, something held above it or resting on another object does not. Footprints narrower than
    ``min_side`` are too small to tell."""
    B = np.asarray(background, dtype=np.float64).reshape(-1, 3)
    B = B[np.abs(support.elevation(B)) < 0.015]
    if not len(B):
        return False
    (lu, hu), (lv, hv) = range_u, range_v
    if min(hu - lu, hv - lv) < min_side:
        return False  # too small to tell
    inset = min(inset, 0.25 * min(hu - lu, hv - lv))
    if others is not None and len(others):
        O = np.asarray(others, dtype=np.float64).reshape(-1, 3)
        e = support.elevation(O)
        ou, ov = O @ u, O @ v
        if np.any((e > 0.015) & (e < bottom) & (ou > lu + inset) & (ou < hu - inset) & (ov > lv + inset)
                  & (ov < hv - inset)):
            return False  # it rests on another object
    bu, bv = B @ u, B @ v

    def inside(m: float) -> np.ndarray:
        return (bu > lu - m) & (bu < hu + m) & (bv > lv - m) & (bv < hv + m)

    n_in = int(inside(-inset).sum())
    n_ring = int((inside(ring) & ~inside(0.01)).sum())
    a_in = (hu - lu - 2 * inset) * (hv - lv - 2 * inset)
    a_ring = (hu - lu + 2 * ring) * (hv - lv + 2 * ring) - (hu - lu + 0.02) * (hv - lv + 0.02)
    if n_ring < min_ring_points:
        return False
    return n_in / a_in < max_ratio * n_ring / a_ring


def complete_walls(geo: ObjectGeometry, support: Support, gap: float | None = None) -> ObjectGeometry:
    """Fill the unseen parts of the four side faces of a box standing on the table (``geo``'s gravity-aligned
    box, from the table to its top), as unobserved points (``observed=False``) with outward normals.

    Wrist cameras looking down often see a carton's top and little of its sides; the top's outline fixes
    where the side faces are, and a box standing on the table (see :func:`hides_table`) has them down to the
    table. A face some of whose points were seen gets its wall at their median depth (a noisy face's seen
    points and the wall then make one plane), else at the box's side. Only points farther than ``gap``
    from every point so far are added, so what was seen (or filled by
    :func:`complete_by_symmetry`) is kept; collision checks treat the new points as solid, scores trust
    them less.
    """
    gap = 2.5 * geo.voxel if gap is None else gap
    step = max(2.0 * geo.voxel, 0.005)
    T, ext = geo.T_b1_box, geo.extent
    ax, ay, up = T[:3, 0], T[:3, 1], T[:3, 2]
    hs = np.arange(0.5 * step, ext[2] - 0.25 * step, step)
    pts, nrm = [], []
    for axis, along, half_n, half_a in ((ax, ay, 0.5 * ext[0], 0.5 * ext[1]), (ay, ax, 0.5 * ext[1], 0.5 * ext[0])):
        ls = np.arange(-half_a + 0.5 * step, half_a - 0.25 * step, step)
        L, H = np.meshgrid(ls, hs, indexing="ij")
        for sgn in (1.0, -1.0):
            n = sgn * axis
            # the wall where the face's seen points are (their median depth), else at the box's side
            rel = (geo.points - geo.centre) @ n
            own = geo.observed & (rel > half_n - 0.03) & (geo.normals @ n > 0.7)
            off = float(np.median(rel[own])) if own.sum() >= 20 else half_n
            pts.append(geo.centre + off * n + L.reshape(-1, 1) * along + (H.reshape(-1, 1) - 0.5 * ext[2]) * up)
            nrm.append(np.broadcast_to(n, (L.size, 3)))
    if not pts:
        return geo
    Q, Nq = np.concatenate(pts), np.concatenate(nrm)
    return _add_unseen(geo, Q, Nq, gap)


def _add_unseen(geo: ObjectGeometry, Q: np.ndarray, Nq: np.ndarray, gap: float) -> ObjectGeometry:
    """``geo`` with the points Q (K, 3) (normals Nq (K, 3)) that lie farther than ``gap`` from all of its
    points added as unobserved."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(geo.points).query(Q, k=1)
    new = d > gap
    if not new.any():
        return geo
    return ObjectGeometry(geo.id, geo.n_points, np.concatenate([geo.points, Q[new]]), np.concatenate([geo.normals, Nq[new]]),
                          geo.T_b1_box, geo.extent, geo.centre, geo.voxel,
                          np.concatenate([geo.observed, np.zeros(int(new.sum()), dtype=bool)]))


CYL_RADIUS = (0.012, 0.06)  # m: radii of the cans, bottles and mugs completed as cylinders
CYL_MAX_RMS = 0.06  # ... whose side points fit a circle within this share of its radius (RMS) ...
# ... over an arc at least this wide (however much more of the round was seen: the points' own box of a can
# seen over 210-280 degrees falls short of its diameter and sits off its centre)
CYL_MIN_ARC = np.deg2rad(90.0)
CYL_MIN_RADIAL = 0.9  # ... with normals this well along the radius (mean |cos|; a box's corner: ~0.7)
# A noisier arc (over CYL_MAX_RMS) is completed when its RMS is within this (m; the bench's pipeline clouds:
# 1-3 mm), more of its side points lie on the circle than on the box's sides, and its top disc is closed
# (this share of it holds points at the top; a can's top is seen from above, a duck's or a bunny's back is not
# a disc)
CYL_NOISY_RMS = 0.0035
CYL_MIN_TOP = 0.9
CYL_BAND_OFF = 0.002  # m: every completed arc keeps to its circle within this in each third of its height
# (median; the bench's cans: <= 1.4 mm, the ducks whose head tops look like a closed disc: >= 2.3 mm)


def refine_circle(xy: np.ndarray, centre: np.ndarray, radius: float, scale: float = 0.003) -> tuple[np.ndarray, float]:
    """The geometric least-squares circle through ``xy`` (M, 2) from a first guess: minimises
    ``sum rho((|p - c| - r) / scale)`` (scipy's least_squares, soft-L1 loss: points beyond ``scale`` m count
    less). The algebraic fit (:func:`fit_circle`) shrinks the circle of a noisy arc: on the task bench a
    6.4 cm can seen over half its round came out 5.8 cm across and 1 cm off centre (refined: 6.4 cm, 5 mm)."""
    from scipy.optimize import least_squares

    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    res = least_squares(lambda x: np.linalg.norm(xy - x[:2], axis=1) - x[2],
                        np.r_[np.asarray(centre, dtype=np.float64), float(radius)], loss="soft_l1", f_scale=scale)
    return res.x[:2].copy(), float(abs(res.x[2]))


def _top_cells(c: np.ndarray, r: float) -> np.ndarray:
    """(K, 2) centres of the cells (``TOP_CELL``) of the disc of radius ``r`` - 7 mm about ``c`` (2,)."""
    g = np.arange(-r, r, TOP_CELL) + 0.5 * TOP_CELL
    X, Y = np.meshgrid(g, g)
    disc = np.hypot(X, Y) < r - 0.007
    return np.c_[X[disc], Y[disc]] + np.asarray(c, dtype=np.float64)


def _top_lid_cells(xy: np.ndarray, elev: np.ndarray, cells: np.ndarray, top: float) -> np.ndarray:
    """(K,) bool: the cells (K, 2) that hold a point (``xy`` (M, 2), elevations ``elev`` (M,)) within 4 mm of
    the height ``top``."""
    from scipy.spatial import cKDTree

    at_top = xy[np.abs(elev - top) < 0.004]
    if not len(cells) or not len(at_top):
        return np.zeros(len(cells), dtype=bool)
    dd, _ = cKDTree(at_top).query(cells, k=1)
    return dd < 0.6 * TOP_CELL


def _top_cover(xy: np.ndarray, elev: np.ndarray, c: np.ndarray, r: float, top: float) -> float:
    """Share of the cells of the top disc (:func:`_top_cells`) that hold a point at the height ``top``
    (:func:`_top_lid_cells`): 1 for a closed top seen whole."""
    cells = _top_cells(c, r)
    return float(np.mean(_top_lid_cells(xy, elev, cells, top))) if len(cells) else 0.0


def _top_closed(xy: np.ndarray, elev: np.ndarray, c: np.ndarray, r: float, top: float, support: Support,
                views) -> float:
    """How closed the top disc is, as the capture's depth views saw it: the share of its seen cells that are a
    lid, 0 when less than ``TOP_MIN_SEEN`` of it was seen.

    A cell is seen *through* when some view saw more than its tolerance past the cell's centre at the top's
    height (``bimanual_app.views.see_past``; the tolerance is ``PRIMITIVE_TOL`` or the views' own
    disagreement where larger): the inside of an open cup. It is a *lid* when, instead, a point of the object
    lies there at the top's height or a view's surface lies within the tolerance of it. A cell neither is
    hidden and counts for nothing: the points alone cannot tell an unseen part of a can's lid from a cup's
    opening, the views can."""
    from bimanual_app.views import see_past

    cells = _top_cells(c, r)
    if not len(cells):
        return 0.0
    e1, e2 = _perp_basis(support.up)
    X = cells[:, :1] * e1 + cells[:, 1:] * e2 + (support.height + top - 0.002) * support.up
    past = see_past(X, views)
    tol = views.tolerance(PRIMITIVE_TOL)
    through = past > tol
    lid = (_top_lid_cells(xy, elev, cells, top) | (np.abs(past) <= tol)) & ~through
    seen = int(lid.sum() + through.sum())
    if seen < TOP_MIN_SEEN * len(cells):
        return 0.0
    return float(lid.sum()) / seen


def fit_circle(xy: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Least-squares circle through points ``xy`` (M, 2): (centre (2,), radius), or None when degenerate.

    Algebraic (Kasa) fit: x^2 + y^2 + D x + E y + F = 0 by linear least squares (a small linear solve;
    written here rather than pulled from a library: scikit-image's CircleModel is the same three lines)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) < 3:
        return None
    A = np.c_[xy, np.ones(len(xy))]
    D, E, F = np.linalg.lstsq(A, -(xy ** 2).sum(axis=1), rcond=None)[0]
    c = -0.5 * np.array([D, E])
    r2 = float(c @ c - F)
    if r2 <= 0:
        return None
    return c, float(np.sqrt(r2))


PRIMITIVE_TOL = 0.005  # m: a seen point this near a box's or cylinder's surface fits it (cloud noise ~2-3 mm)
PRIMITIVE_MIN_FIT = 0.9  # share of the seen points that must fit; the bench's mugs, ducks, bunnies and tori: <= 0.86
TOP_BAND = 0.004  # m: the top's points, this far below its highest, outline it ...
TOP_ROUND_MAX = 0.87  # ... a cylinder's outline fills at most this share of its least rectangle (a disc: 0.79)
TOP_MIN_POINTS = 20  # ... with at least this many points (else the outline is not judged)
TOP_CELL = 0.01  # m: cells of a cylinder's top disc that must hold a point at the top (a mug shows a rim only)
TOP_MIN_SEEN = 0.5  # share of the top disc the depth views must have seen (a lid, or through it) to judge it


def _beyond_circle(geo: ObjectGeometry, r: float, tol: float) -> bool:
    """The segment is more than the can: its box reaches past the square of the circle of radius ``r`` grown by
    ``tol`` a side (a piece of a neighbour in it)."""
    return float(np.max(geo.extent[:2])) > 2 * (r + tol)


def _top_outline_square(xy: np.ndarray) -> bool:
    """Whether the top's seen points ``xy`` (K, 2) fill their least rectangle like a box's top, not a disc's:
    the convex hull's area over the min-area rectangle's above ``TOP_ROUND_MAX`` (a disc: pi/4 = 0.79; a
    rectangle: 1). The pipeline's clouds round a small box's vertical edges, so its sides fit a circle as
    well as a can's; its top's outline keeps its corners. False with too few points to tell."""
    import cv2

    if len(xy) < TOP_MIN_POINTS:
        return False
    pts = np.asarray(xy, dtype=np.float32)
    (_, _), (w, h), _ = cv2.minAreaRect(pts)
    return float(cv2.contourArea(cv2.convexHull(pts))) > TOP_ROUND_MAX * max(float(w * h), 1e-12)


def _cylinder_fit(geo: ObjectGeometry, P: np.ndarray, N: np.ndarray, support: Support, tol: float, views) -> float:
    """:func:`primitive_fit`'s upright cylinder for the seen points ``P`` (M, 3) with normals ``N`` (M, 3): the
    share of them within ``tol`` of its side or top, capped by how closed its top is; 0 without a can's
    circle, or when the segment's box reaches past the circle's square grown by ``tol`` a side."""
    side = np.abs(N @ support.up) < 0.3
    if side.sum() < 30:
        return 0.0
    e1, e2 = _perp_basis(support.up)
    xy = np.stack([P @ e1, P @ e2], axis=1)
    fit = fit_circle(xy[side])
    if fit is None or not CYL_RADIUS[0] <= fit[1] <= CYL_RADIUS[1]:
        return 0.0
    c, r = fit
    if _beyond_circle(geo, r, tol):
        return 0.0
    rho = np.linalg.norm(xy - c, axis=1)
    elev = support.elevation(P)
    top = float(np.percentile(elev, 99.5))
    if _top_outline_square(xy[elev > top - TOP_BAND]):
        return 0.0
    d = np.minimum(np.abs(rho - r), np.where(rho <= r + tol, np.abs(elev - top), np.inf))
    closed = (_top_cover(xy, elev, c, r, top) if views is None or not len(views)
              else _top_closed(xy, elev, c, r, top, support, views))
    return min(float(np.mean(d < tol)), closed)


def primitive_fit(geo: ObjectGeometry, support: Support, tol: float = PRIMITIVE_TOL, views=None) -> tuple[str, float]:
    """Whether the object's seen points are a box or an upright cylinder: ``("box" | "cylinder", fit)`` when
    at least ``PRIMITIVE_MIN_FIT`` of them lie within ``tol`` of that primitive's surface, else
    ``("free-form", best fit)``.

    The box is the object's gravity-aligned box (``geo.T_b1_box``, ``geo.extent``); the cylinder is the
    least-squares circle of the side points (radius ``CYL_RADIUS``) from the table to the top; the segment's
    box must lie within the circle's square grown by ``tol`` a side (the points that miss the surface are
    not a neighbour's piece merged into the segment, which the simulated cylinder would leave out), and it
    must also be closed at the top. With the capture's depth ``views`` (``bimanual_app.views.DepthViews``), the
    share of its top disc seen as a lid among the part seen at all (:func:`_top_closed`: a cup's opening is
    seen through); without them, the share of the disc's cells (``TOP_CELL``, 7 mm in from the rim) that
    hold a point at the top's height (a mug seen from above shows its rim and its inside, not a lid; nor does
    a can whose top no camera saw whole). Only seen points count (``geo.observed``): completion fills in the
    primitive it assumes.

    A hand-over of an object whose shape the cloud determines is safer than of a free-form one (a mug's
    handle or a bunny's far side that no camera saw meets the receiver's fingers; on the task bench, two
    such hand-overs passed the preview on the reconstruction and failed in reality, where the scene's
    cylinder, chosen instead, was handed over).
    """
    obs = geo.observed
    P, N = geo.points[obs], geo.normals[obs]
    if len(P) < 10:
        return "free-form", 0.0
    T, h = geo.T_b1_box, 0.5 * geo.extent
    q = (P - T[:3, 3]) @ T[:3, :3]
    inside = np.all(np.abs(q) <= h, axis=1)
    d_box = np.where(inside, np.min(h - np.abs(q), axis=1), np.linalg.norm(np.maximum(np.abs(q) - h, 0.0), axis=1))
    box = float(np.mean(d_box < tol))
    cyl = _cylinder_fit(geo, P, N, support, tol, views)
    if max(box, cyl) >= PRIMITIVE_MIN_FIT:
        return ("box", box) if box >= cyl else ("cylinder", cyl)
    return "free-form", max(box, cyl)


@dataclass
class _SideArc:
    """The seen side of an upright object as an arc of a circle in the table plane (see :func:`complete_cylinder`)."""

    e1: np.ndarray  # (3,) table-plane basis
    e2: np.ndarray  # (3,)
    side: np.ndarray  # (M,) bool: the seen side points of the object
    S: np.ndarray  # (K, 3) those points
    strict: bool  # the algebraic circle fits them within CYL_MAX_RMS of its radius
    c: np.ndarray  # (2,) the refined circle's centre in (e1, e2)
    r: float  # ... and radius
    rel: np.ndarray  # (K, 2) the points from the centre
    dist: np.ndarray  # (K,) ... their distances


def _side_arc(geo: ObjectGeometry, support: Support) -> _SideArc | None:
    """The circle through the object's seen side points, or None (too few, no circle, not a can's radius)."""
    up = support.up
    side = geo.observed & (np.abs(geo.normals @ up) < 0.3)
    if side.sum() < 30:
        return None
    e1, e2 = _perp_basis(up)
    S = geo.points[side]
    xy = np.stack([S @ e1, S @ e2], axis=1)
    fit = fit_circle(xy)
    if fit is None:
        return None
    rms_algebraic = float(np.sqrt(np.mean((np.linalg.norm(xy - fit[0], axis=1) - fit[1]) ** 2)))
    strict = rms_algebraic <= CYL_MAX_RMS * fit[1]
    c, r = refine_circle(xy, *fit)
    rel = xy - c
    dist = np.linalg.norm(rel, axis=1)
    if not (CYL_RADIUS[0] <= r <= CYL_RADIUS[1]):
        return None
    return _SideArc(e1, e2, side, S, strict, c, r, rel, dist)


def _keeps_to_circle(arc: _SideArc, support: Support, top: float) -> bool:
    """Its side keeps to the circle from the table to the top (in thirds of its height): a duck's head does not."""
    elev_side = support.elevation(arc.S)
    edges = np.linspace(0.0, top, 4)
    bands = [arc.dist[(elev_side >= lo) & (elev_side < hi)] - arc.r for lo, hi in zip(edges[:-1], edges[1:])]
    return max((abs(float(np.median(b))) for b in bands if len(b) >= 10), default=np.inf) <= CYL_BAND_OFF


def _noisy_cylinder(geo: ObjectGeometry, arc: _SideArc, P_obs: np.ndarray, elev_obs: np.ndarray, top: float) -> bool:
    """A noisier arc (1-3 mm clouds) is still a cylinder's when it is not a box's (its side points nearer the
    circle than the box's sides) and its top is a closed disc (not a toy's back)."""
    T, h = geo.T_b1_box, 0.5 * geo.extent[:2]
    q = np.abs((arc.S - T[:3, 3]) @ T[:3, :2])
    on_box = float(np.mean(np.min(np.abs(h - q), axis=1) < PRIMITIVE_TOL))
    on_circle = float(np.mean(np.abs(arc.dist - arc.r) < PRIMITIVE_TOL))
    rms = float(np.sqrt(np.mean((arc.dist - arc.r) ** 2)))
    cover = _top_cover(np.stack([P_obs @ arc.e1, P_obs @ arc.e2], axis=1), elev_obs, arc.c, arc.r, top)
    return not (rms > CYL_NOISY_RMS or on_circle <= on_box or cover < CYL_MIN_TOP)


def _radial_normals(geo: ObjectGeometry, arc: _SideArc) -> bool:
    """The side points' normals point along the radius (CYL_MIN_RADIAL)."""
    radial = arc.rel / np.maximum(arc.dist[:, None], 1e-9)
    n2 = np.stack([geo.normals[arc.side] @ arc.e1, geo.normals[arc.side] @ arc.e2], axis=1)
    n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-9)
    return np.mean(np.abs(np.einsum("ij,ij->i", n2, radial))) >= CYL_MIN_RADIAL


def _unseen_arc(arc: _SideArc) -> tuple[float, float] | None:
    """(start angle, span) of the unseen arc: the largest gap between the points' angles; None when the
    points cover less than CYL_MIN_ARC."""
    ang = np.sort(np.arctan2(arc.rel[:, 1], arc.rel[:, 0]))
    gaps = np.diff(np.r_[ang, ang[0] + 2 * np.pi])
    k = int(np.argmax(gaps))
    if 2 * np.pi - float(gaps[k]) < CYL_MIN_ARC:
        return None
    return ang[k], gaps[k]


def _in_plane(arc: _SideArc, uv: np.ndarray) -> np.ndarray:
    """(K, 3) the table-plane coordinates ``uv`` (K, 2) along the arc's basis (e1, e2), through the origin."""
    return uv[:, :1] * arc.e1 + uv[:, 1:] * arc.e2


def _on_circle(geo: ObjectGeometry, arc: _SideArc, support: Support) -> ObjectGeometry:
    """``geo`` with its seen surface laid on the fitted circle: side points within ``PRIMITIVE_TOL`` of it, and
    any point up to that far outside it (the top's rim), moved onto it along the radius (side normals radial).

    The sampler's contact width is the extent of the points between the fingers, and the points' noise and
    the fused views' depth blur widen it by millimetres a side (a 6.5 cm can came out past the 66 mm the
    stroke takes): the fitted circle places the can's surface to about a millimetre, its points do not."""
    P = geo.points
    rel = np.stack([P @ arc.e1, P @ arc.e2], axis=1) - arc.c
    d = np.linalg.norm(rel, axis=1)
    side = geo.observed & (np.abs(geo.normals @ support.up) < 0.3)
    move = geo.observed & (d > 1e-9) & (np.where(side, np.abs(d - arc.r), d - arc.r) <= PRIMITIVE_TOL)
    move &= side | (d > arc.r)
    if not move.any():
        return geo
    radial = rel / np.maximum(d, 1e-12)[:, None]  # (M, 2) unit, in the plane
    Q, N = P.copy(), geo.normals.copy()
    Q[move] += _in_plane(arc, (arc.r - d[move])[:, None] * radial[move])
    rs = move & side
    N[rs] = _in_plane(arc, radial[rs])
    return ObjectGeometry(geo.id, geo.n_points, Q, N, geo.T_b1_box, geo.extent, geo.centre, geo.voxel, geo.observed)


def _cylinder_box(geo: ObjectGeometry, out: ObjectGeometry, arc: _SideArc, up: np.ndarray) -> ObjectGeometry:
    """``out`` with the box grown to hold the whole cylinder (its axes stay).

    The fitted circle's square, not the points' extremes, whose noise and the depth blur of the fused views
    widen it by millimetres (and millimetres decide whether a can fits the stroke).
    """
    c, r = arc.c, arc.r
    u, v = geo.T_b1_box[:3, 0], geo.T_b1_box[:3, 1]
    c3 = c[0] * arc.e1 + c[1] * arc.e2
    lo_u, hi_u = c3 @ u - r, c3 @ u + r
    lo_v, hi_v = c3 @ v - r, c3 @ v + r
    zc = geo.centre @ up
    centre = 0.5 * (lo_u + hi_u) * u + 0.5 * (lo_v + hi_v) * v + zc * up
    T = geo.T_b1_box.copy()
    T[:3, 3] = centre
    extent = np.array([hi_u - lo_u, hi_v - lo_v, geo.extent[2]])
    if extent[1] > extent[0]:  # x stays along the longer side
        T[:3, 0], T[:3, 1] = v, -u
        extent[:2] = extent[1::-1]
    return ObjectGeometry(out.id, out.n_points, out.points, out.normals, T, extent, centre, out.voxel, out.observed)


def complete_cylinder(geo: ObjectGeometry, support: Support, bottom: float = 0.0) -> ObjectGeometry:
    """Complete an upright cylinder seen from one side (a can, a bottle, a mug's body) with its unseen arc.

    Its seen side is an arc of a circle in the table plane. Turned about the centre of its box, as
    :func:`complete_by_symmetry` does, a half shell stays a half shell: the box of a shell is about half as
    deep as the cylinder, so the turned points land on the seen ones (a 7.5 cm can came out as a 3.5 cm
    shell, its grasps sized for that, and the fingers met the real can). A least-squares circle through
    the seen side points gives the real centre and radius; the unseen arc is added (``observed=False``),
    from ``bottom`` (the elevation of the box's bottom) to the top, the seen surface is laid on the circle
    (:func:`_on_circle`: its noise would widen the grasps' contact width) and the box is the circle's square.

    The circle: the algebraic fit (:func:`fit_circle`) refined geometrically (:func:`refine_circle`).
    Completed only when the side points fit it closely (the algebraic fit within ``CYL_MAX_RMS`` of the
    radius; or, on a noisier cloud, the refined one within ``CYL_NOISY_RMS`` with more side points on the
    circle than on the box's sides and a closed top disc, ``CYL_MIN_TOP``), keep to it in every third of
    the height (``CYL_BAND_OFF``), the radius is a graspable cylinder's (``CYL_RADIUS``), the points cover
    an arc of at least ``CYL_MIN_ARC`` about the centre, their normals point along the radius (``CYL_MIN_RADIAL``)
    and the points' box lies within the circle's square (``PRIMITIVE_TOL`` a side): a box's corner, an irregular
    toy or a can with a piece of its neighbour fits none of these. Returns ``geo`` unchanged otherwise.
    """
    up = support.up
    arc = _side_arc(geo, support)
    if arc is None:
        return geo
    P_obs = geo.points[geo.observed]
    elev_obs = support.elevation(P_obs)
    top = float(np.percentile(elev_obs, 99.5))
    if not _keeps_to_circle(arc, support, top):
        return geo
    if not arc.strict and not _noisy_cylinder(geo, arc, P_obs, elev_obs, top):
        return geo
    if not _radial_normals(geo, arc):
        return geo
    gap = _unseen_arc(arc)
    if gap is None or _beyond_circle(geo, arc.r, PRIMITIVE_TOL):
        return geo
    out = _on_circle(geo, arc, support)
    Q, Nq = _arc_points(arc, gap, np.arange(bottom + 0.5 * geo.voxel, top, geo.voxel), geo.voxel, support)
    if len(Q):
        out = _add_unseen(out, Q, Nq, 1.5 * geo.voxel)
    return _cylinder_box(geo, out, arc, up)


def _arc_points(arc: _SideArc, gap: tuple[float, float], zs: np.ndarray, step: float,
                support: Support) -> tuple[np.ndarray, np.ndarray]:
    """Points (K, 3) and outward normals (K, 3) on the circle's arc ``gap`` (start angle, span), ``step`` m
    apart along it, at the elevations ``zs`` (Z,) above the table."""
    da = step / arc.r
    a_new = gap[0] + np.arange(da, gap[1] - 0.5 * da, da)
    ring = np.stack([np.cos(a_new), np.sin(a_new)], axis=1)
    base = _in_plane(arc, arc.c + arc.r * ring)  # (A, 3) in the plane through 0
    Q = (base[:, None, :] + (support.height + zs)[None, :, None] * support.up).reshape(-1, 3)
    return Q, np.repeat(_in_plane(arc, ring), len(zs), axis=0)


def complete_by_symmetry(geo: ObjectGeometry, support: Support, gap: float | None = None) -> ObjectGeometry:
    """Fill the sides the cameras did not see by turning the seen sides half a turn about the object's
    vertical axis (the centre of its box).

    A cloud of an object on a table usually shows it from one side: an antipodal pair needs the far side
    too. Objects on a table are mostly symmetric about a vertical axis under a half turn (boxes, cylinders,
    cans, cups without their handle), so the seen sides, turned about the centre of the box (whose footprint
    comes from all the points, the top included), stand in for the unseen ones (Bohg et al., "Mind the
    gap", ICRA 2011, complete by mirroring). Only turned points farther than ``gap`` from every seen point
    are added (they fill holes; they never replace what was seen), and they are marked ``observed=False``:
    the collision checks treat them as solid, the antipodal score trusts them less.
    """
    gap = 2.5 * geo.voxel if gap is None else gap
    up = support.up
    side = np.abs(geo.normals @ up) < 0.7
    if not side.any():
        return geo
    R = 2.0 * np.outer(up, up) - np.eye(3)  # half a turn about the vertical axis
    Q = (geo.points[side] - geo.centre) @ R.T + geo.centre
    Nq = geo.normals[side] @ R.T
    return _add_unseen(geo, Q, Nq, gap)


def check_graspable(geo: ObjectGeometry, min_width: float, max_width: float, source: str = "segments",
                    min_points: int = 30) -> list[Problem]:
    """Problems that rule out every single-arm grasp of ``geo`` ([] when it may be graspable).

    ``min_width``: narrowest object the fingers can resolve (m); ``max_width``: widest contact width the
    stroke takes with clearance (m).
    """
    field = f"object {geo.id}"
    if geo.n_points < min_points:
        return [Problem(source, field, f"segment has {geo.n_points} point(s); at least {min_points} are needed to place fingers",
                        "check the segmentation (an empty or speck segment), or capture the object from more views")]
    ext = geo.extent
    if float(np.max(ext)) < min_width:
        return [Problem(source, field, f"object is {float(np.max(ext)) * 1000:.1f} mm across at most: narrower than the"
                        f" {min_width * 1000:.1f} mm the fingers can resolve", "too small to grasp; remove it from the segments")]
    if float(np.max(ext[:2])) < min_width:
        return [Problem(source, field, f"object is {float(np.max(ext[:2])) * 1000:.1f} mm wide: narrower than the"
                        f" {min_width * 1000:.1f} mm the fingers can resolve", "too thin to grasp from the side or above")]
    if float(np.min(ext)) > max_width:
        return [Problem(source, field, f"object is {float(np.min(ext)) * 1000:.0f} mm across at its narrowest: wider than"
                        f" the gripper's stroke allows ({max_width * 1000:.0f} mm with clearance)",
                        "no single-arm grasp; lift it with both arms (joint grasp)")]
    return []


def closed_geometry(geo: ObjectGeometry, support: Support) -> ObjectGeometry:
    """The object with its unseen bottom filled in: its points projected onto its base (normals down).

    For grasps on an object held in the air (a hand-over), where a gripper may come from below: the cloud
    of an object standing on the table has no bottom face, and fingers must not pass through it.
    """
    up = support.up
    base = support.height + max(0.0, float(support.elevation(geo.T_b1_box[:3, 3])) - 0.5 * float(geo.extent[2]))
    Q = geo.points - np.outer(geo.points @ up - base, up)
    # keep one point per voxel of the footprint
    key = np.floor(Q / geo.voxel).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    Q = Q[np.sort(first)]
    P = np.concatenate([geo.points, Q])
    N = np.concatenate([geo.normals, np.broadcast_to(-up, Q.shape)])
    return ObjectGeometry(geo.id, geo.n_points + len(Q), P, N, geo.T_b1_box, geo.extent, geo.centre, geo.voxel,
                          np.concatenate([geo.observed, np.zeros(len(Q), dtype=bool)]))


def unseen_space(obj_points: np.ndarray, table_points: np.ndarray, other_points: np.ndarray, support: Support,
                 radius: float = 0.05, cell: float = 0.005, z_step: float = 0.01,
                 normals: np.ndarray | None = None, sectors: int = 12) -> np.ndarray:
    """(K, 3) points filling the space around an object that no camera saw into, as columns from the
    table up to the object's top; to be treated as solid by the grasp checks.

    Objects stand on the table, so wherever a camera saw the table nothing stands; around an object, the
    ground it could still cover is where neither the table nor another object was seen. A cylinder seen
    from one side comes out as a half shell 3.5 cm deep, a mug without its far half: fingers closing
    across the seen part (or a receiver's coming in from the unseen side) meet the rest. The unknown
    cells (``cell`` m, in the table plane) within ``radius`` m of the object's footprint and joined to it
    are filled; cells of the footprint itself, of seen table (points within 1.5 cm of the plane; one cell
    of slack for their spacing) and of other objects' points are not.

    With ``normals`` (M, 3) (the points' outward normals), only the directions in which the object's
    side was not seen are filled: around its centre, ``sectors`` sectors of azimuth, a sector counting as
    seen when it or a neighbour holds seen side normals (a box's four faces cover all twelve). An object
    seen from every side then gets nothing: the unseen table around it is the shadow its own height
    casts, not more of it (filled, such shadows cost the bench scenes grasps that worked).

    ``obj_points`` (M, 3), ``table_points`` (T, 3), ``other_points`` (O, 3) in b1.
    """
    from scipy import ndimage

    P = np.asarray(obj_points, dtype=np.float64).reshape(-1, 3)
    if not len(P):
        return np.zeros((0, 3))
    up = support.up
    e1, e2 = _perp_basis(up)
    pad = radius + 3 * cell
    lo = np.array([(P @ e1).min(), (P @ e2).min()]) - pad
    hi = np.array([(P @ e1).max(), (P @ e2).max()]) + pad
    shape = np.ceil((hi - lo) / cell).astype(int) + 1

    def grid(Q: np.ndarray) -> np.ndarray:
        Q = np.asarray(Q, dtype=np.float64).reshape(-1, 3)
        ij = np.floor((np.stack([Q @ e1, Q @ e2], axis=1) - lo) / cell).astype(int)
        ok = np.all((ij >= 0) & (ij < shape), axis=1)
        g = np.zeros(shape, dtype=bool)
        g[ij[ok, 0], ij[ok, 1]] = True
        return g

    seg = ndimage.binary_closing(grid(P), iterations=2) | grid(P)
    T = np.asarray(table_points, dtype=np.float64).reshape(-1, 3)
    table = ndimage.binary_dilation(grid(T[np.abs(support.elevation(T)) < 0.015]), iterations=1)
    other = grid(other_points)
    near = ndimage.distance_transform_edt(~seg) * cell <= radius
    unknown = near & ~seg & ~table & ~other
    lab, n = ndimage.label(unknown)
    if n == 0:
        return np.zeros((0, 3))
    touching = np.unique(lab[ndimage.binary_dilation(seg) & (lab > 0)])
    cells = np.argwhere(np.isin(lab, touching[touching > 0]))
    if normals is not None and len(cells):
        Nn = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        side = np.abs(Nn @ up) < 0.7
        centre = np.array([(P @ e1).mean(), (P @ e2).mean()])
        width = 2 * np.pi / sectors

        def sector(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
            return (np.floor((np.arctan2(dy, dx) + np.pi) / width).astype(int)) % sectors

        count = np.bincount(sector(Nn[side] @ e1, Nn[side] @ e2), minlength=sectors)
        seen = count >= max(5, 0.01 * side.sum())
        seen = seen | np.roll(seen, 1) | np.roll(seen, -1)
        uv_c = (cells + 0.5) * cell + lo - centre
        cells = cells[~seen[sector(uv_c[:, 0], uv_c[:, 1])]]
    if not len(cells):
        return np.zeros((0, 3))
    top = float(np.percentile(support.elevation(P), 99.5))
    zs = np.arange(0.5 * z_step, max(top, z_step), z_step)
    uv = (cells + 0.5) * cell + lo
    base = uv[:, :1] * e1 + uv[:, 1:] * e2 + support.height * up  # (C, 3) on the table plane
    return (base[:, None, :] + zs[None, :, None] * up).reshape(-1, 3)
