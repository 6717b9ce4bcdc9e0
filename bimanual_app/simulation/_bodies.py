"""Collision bodies from the reconstruction: the table plane and each segmented object's shape.

Pure functions on arrays (no PyBullet here): :func:`fit_table` finds the table plane and its extent,
:func:`shape_from_points` turns one object's points into a convex hull (or an oriented box) expressed in
a body frame, with a volume and a plausible mass. :mod:`._world` makes PyBullet bodies from these.

Choices:
- The cameras never see an object's underside, so a hull of the visible points floats above the table.
  The points are *extruded down to the table plane* (each point's projection on the plane is added)
  before the hull is taken: the body then stands on the table like the real object does.
- Stray points (segmentation bleed, depth noise) would inflate a hull; points whose mean distance to
  their k nearest neighbours is far above the typical value are dropped first (the statistical outlier
  test of PCL / Open3D, written with scipy's cKDTree to avoid loading Open3D for it); then the outermost 2%
  in every horizontal direction and in height (:func:`trim_outer`): noisy faces spread outwards.
- Mass = volume x density (default 400 kg/m^3, between cardboard boxes and wood), clipped to
  [0.02, 1.5] kg (the Piper's payload is about 1.5 kg).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import check_shape, make_T

__all__ = ["TablePlane", "BodyShape", "fit_table", "table_from_plane", "shape_from_points", "box_shape",
           "hull_shape", "remove_outliers", "trim_outer", "box_from_faces", "DEFAULT_DENSITY", "MASS_RANGE"]

DEFAULT_DENSITY = 400.0  # kg/m^3
MASS_RANGE = (0.02, 1.5)  # kg
BOXNESS = 0.7  # kind="auto": objects whose side normals are this box-like are simulated as their box ...
BOX_FILL = 0.85  # ... or, when the normals are too noisy to tell, whose hull fills this much of its box
TABLE_SAMPLE = 20_000  # fit_table: points handed to the plane fitter (one per 1 cm voxel)
NEAR_B1 = 0.2  # fit_table: the primary arm stands on the table: its plane passes this close to b1's origin
OUTER_PERCENTILE = 98.0  # trim_outer: the body's faces sit at this percentile of the points, not their extreme


@dataclass
class TablePlane:
    """The table top: plane ``n . p + d = 0`` (``n`` pointing up, unit) and a rectangle on it.

    Attributes:
        normal: (3,) unit normal in b1, pointing away from the table (up).
        d: plane offset (m).
        T_b1_t: (4,4) table-top frame: origin at the rectangle's centre on the plane, z = normal.
        size: (2,) rectangle extent along the frame's x and y (m).
        thickness: slab thickness below the plane (m).
    """

    normal: np.ndarray
    d: float
    T_b1_t: np.ndarray
    size: np.ndarray
    thickness: float = 0.04

    def height(self, p: np.ndarray) -> np.ndarray:
        """Signed height above the plane of points (..., 3) -> (...)."""
        return np.asarray(p, dtype=np.float64) @ self.normal + self.d

    def project(self, p: np.ndarray) -> np.ndarray:
        """Points (..., 3) projected onto the plane."""
        p = np.asarray(p, dtype=np.float64)
        return p - self.height(p)[..., None] * self.normal


def _frame_from_normal(n: np.ndarray) -> np.ndarray:
    """(3,3) rotation whose z is ``n`` and whose x is as close to b1's x as possible."""
    n = n / np.linalg.norm(n)
    x = np.array([1.0, 0.0, 0.0]) - n[0] * n
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - n[1] * n
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(n, x), n], axis=1)


def table_from_plane(normal: np.ndarray, d: float, points: np.ndarray | None = None,
                     margin: float = 0.10, min_size: float = 1.0) -> TablePlane:
    """A :class:`TablePlane` from a plane (``normal`` (3,), ``d``) and, optionally, the table's points (N,3).

    The rectangle covers the points' 1st..99th percentiles plus ``margin``, at least ``min_size`` square,
    so the arms never reach past its edge in the preview.
    """
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    s = np.linalg.norm(n)
    if not np.isfinite(s) or s < 1e-9:
        raise ValueError("table normal must be a finite non-zero vector")
    n, d = n / s, float(d) / s
    if n[2] < 0:  # point up (b1's z is up for a table-top setup)
        n, d = -n, -d
    R = _frame_from_normal(n)
    origin = -d * n
    if points is not None and len(points) >= 3:
        p = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
        uv = (p - origin) @ R[:, :2]
        lo, hi = np.percentile(uv, 1, axis=0) - margin, np.percentile(uv, 99, axis=0) + margin
        centre = (lo + hi) / 2
        size = np.maximum(hi - lo, min_size)
        origin = origin + R[:, :2] @ centre
    else:
        size = np.array([min_size, min_size], dtype=np.float64) * 1.5
    return TablePlane(n, d, make_T(R, origin), np.asarray(size, dtype=np.float64))


def fit_table(points: np.ndarray, labels: np.ndarray | None = None, threshold: float = 0.006,
              iterations: int = 1000, seed: int = 0) -> TablePlane:
    """Fit the table plane to a cloud (N,3) in b1 on the background points (``labels == -1``).

    The segmentation's plane fitter (:func:`segmentation.fit_plane`: Open3D RANSAC on an evenly spread
    subset, refined by least squares to a fixed point) restricted to near-horizontal planes (normal within
    30 degrees of b1's z), so a box side or a wall does not win; among those, the one passing near b1's
    origin (where the primary arm stands) wins over a large box top.

    Raises:
        ValueError: fewer than 50 background points, or no near-horizontal plane.
    """
    from segmentation import fit_plane, uniform_sample

    p = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    if labels is not None:
        labels = check_shape("labels", np.asarray(labels), (len(p),))
        p = p[labels < 0]
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 50:
        raise ValueError(f"only {len(p)} table/background points: cannot fit the table plane")
    fit = fit_plane(uniform_sample(p, TABLE_SAMPLE, seed), threshold, up=np.array([0.0, 0.0, 1.0]),
                    cos_level=np.cos(np.radians(30)), near=NEAR_B1, level_only=True, iterations=iterations, seed=seed)
    if fit is None:
        raise ValueError("no near-horizontal plane found in the background points")
    inl = p[np.abs(p @ fit.normal + fit.offset) < max(threshold, 2.5 * fit.sigma)]
    return table_from_plane(fit.normal, fit.offset, inl if len(inl) >= 3 else fit.inliers)


@dataclass
class BodyShape:
    """One object's collision shape in its own body frame ``o``.

    Attributes:
        T_b1_o: (4,4) body frame in b1 (origin at the shape's centroid; z along the table normal).
        kind: ``"hull"``, ``"box"``, ``"cylinder"`` or ``"sphere"``.
        vertices: (V,3) hull vertices in ``o`` (hull), else None.
        faces: (F,3) int triangles of the hull (outward), else None.
        size: (3,) extent along o's axes (box: edge lengths; cylinder: 2r, 2r, height; sphere: 2r x3).
        volume: m^3.
        mass: kg.
    """

    T_b1_o: np.ndarray
    kind: str
    size: np.ndarray
    volume: float
    mass: float
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None

    def contains(self, points_b1: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N,) True for points (N,3) in b1 inside the body grown by ``margin`` m (a hull by its face
        planes, so near its edges a little more than ``margin``; a box, cylinder or sphere by its box)."""
        P = check_shape("points", np.asarray(points_b1, dtype=np.float64), (None, 3))
        local = (P - self.T_b1_o[:3, 3]) @ self.T_b1_o[:3, :3]
        if self.vertices is None:
            return np.all(np.abs(local) <= 0.5 * np.asarray(self.size) + margin, axis=1)
        from scipy.spatial import ConvexHull

        eq = ConvexHull(self.vertices).equations  # unit outward normals, n.x + d <= 0 inside
        return _inside_planes(local, eq, margin)

    def surface_points_b1(self, spacing: float = 0.01) -> np.ndarray:
        """(K, 3) points on the body's surface in b1: the hull's vertices, or a grid at most ``spacing`` m
        apart on each face of a box (a cylinder or sphere: of its bounding box)."""
        if self.vertices is not None:
            local = np.asarray(self.vertices, dtype=np.float64)
        else:
            size = np.asarray(self.size, dtype=np.float64)
            axes = [np.linspace(-0.5, 0.5, int(np.ceil(L / spacing)) + 1) * L for L in size]
            faces = []
            for ax in range(3):
                i, j = (ax + 1) % 3, (ax + 2) % 3
                a, b = (m.ravel() for m in np.meshgrid(axes[i], axes[j]))
                for sgn in (-0.5, 0.5):
                    f = np.zeros((len(a), 3))
                    f[:, ax], f[:, i], f[:, j] = sgn * size[ax], a, b
                    faces.append(f)
            local = np.unique(np.concatenate(faces), axis=0)
        return local @ self.T_b1_o[:3, :3].T + self.T_b1_o[:3, 3]


def _inside_planes(P: np.ndarray, eq: np.ndarray, margin: float, chunk: int = 65536) -> np.ndarray:
    """(N,) True for points P (N,3) with ``n.p + d <= margin`` for every plane ``eq`` (F,4) (unit n).

    The same test as on all planes at once, in a fraction of the time and memory (an (N,F) array was
    hundreds of MB for a scene cloud against a hull): first the planes facing 26 directions around the body,
    which a point far from the body fails, then all of them for the points left, in chunks."""
    dirs = np.stack(np.meshgrid(*[np.array([-1.0, 0.0, 1.0])] * 3, indexing="ij"), -1).reshape(-1, 3)
    dirs = dirs[np.any(dirs != 0, axis=1)]  # the 26 directions to a cube's faces, edges and corners
    few = eq[np.unique(np.argmax(eq[:, :3] @ dirs.T, axis=0))]
    idx = np.nonzero(np.all(P @ few[:, :3].T + few[:, 3] <= margin, axis=1))[0]
    out = np.zeros(len(P), dtype=bool)
    for lo in range(0, len(idx), chunk):
        sel = idx[lo:lo + chunk]
        out[sel] = np.all(P[sel] @ eq[:, :3].T + eq[:, 3] <= margin, axis=1)
    return out


def remove_outliers(points: np.ndarray, k: int = 8, std_ratio: float = 2.5) -> np.ndarray:
    """Points (N,3) without statistical outliers (mean k-NN distance above mean + std_ratio x std)."""
    from scipy.spatial import cKDTree

    p = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    if len(p) <= k + 1:
        return p
    dist, _ = cKDTree(p).query(p, k=k + 1)
    m = dist[:, 1:].mean(axis=1)
    keep = m <= m.mean() + std_ratio * m.std()
    return p[keep]


def trim_outer(points: np.ndarray, up: np.ndarray, q: float = OUTER_PERCENTILE, n_dirs: int = 32) -> np.ndarray:
    """Points (N,3) without the outermost ``100 - q`` % in any horizontal direction (``n_dirs`` directions
    perpendicular to ``up``) and above the ``q`` th percentile of height.

    A convex hull is set by its outermost points; in a fused reconstruction those are the noise and the
    views registered a little off, which spread each face outwards by their error (a centimetre at the
    paper's noise). A body that much too large is touched too early by a gripper squeezing it, so the
    preview would see a push where the real object is still a centimetre away.
    """
    P = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    if len(P) < 50:  # too few for percentiles to mean anything
        return P
    R = _frame_from_normal(np.asarray(up, dtype=np.float64))
    local = P @ R
    ang = np.linspace(0.0, np.pi, n_dirs, endpoint=False)
    D = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    proj = local[:, :2] @ D.T  # (N, n_dirs)
    hi = np.percentile(proj, q, axis=0)
    lo = np.percentile(proj, 100.0 - q, axis=0)
    keep = np.all((proj <= hi) & (proj >= lo), axis=1) & (local[:, 2] <= np.percentile(local[:, 2], q))
    return P[keep] if keep.sum() >= 10 else P


def _mass(volume: float, density: float) -> float:
    return float(np.clip(volume * density, *MASS_RANGE))


def shape_from_points(points: np.ndarray, table: TablePlane | None = None, kind: str = "hull",
                      density: float = DEFAULT_DENSITY, max_points: int = 4000, seed: int = 0,
                      trim: bool = True) -> BodyShape:
    """A collision shape for one segmented object from its points (N,3) in b1.

    Args:
        points: (N,3) the object's points (N >= 10).
        table: when given, the points are extruded down to the table plane first (see module notes).
        kind: ``"hull"`` (convex hull, scipy/Qhull), ``"box"`` (box aligned with the table normal, fitted
            to the object's faces, :func:`box_from_faces`; else the minimum-area rectangle of the footprint,
            via trimesh) or ``"auto"``: that box when the object is box-like (``BOXNESS``; or, when the
            normals are too noisy to tell, the enclosing box when the hull fills ``BOX_FILL`` of it): a
            noisy hull's facets and tilted top make a squeezing gripper slip where the real planar face
            holds. Otherwise the hull.
        density: kg/m^3 for the mass.
        trim: drop the outermost 2% of the points in every horizontal direction and in height first
            (:func:`trim_outer`), so that noise does not inflate the body (hulls and enclosing boxes; the
            box fitted to the faces takes the untrimmed points).
    Raises:
        ValueError: too few points, or a degenerate (flat) set.
    """
    from scipy.spatial import ConvexHull, QhullError

    p = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 10:
        raise ValueError(f"an object needs at least 10 points for a collision body, got {len(p)}")
    if len(p) > max_points:
        p = p[np.random.default_rng(seed).choice(len(p), max_points, replace=False)]
    p = remove_outliers(p)
    up = np.array([0.0, 0.0, 1.0]) if table is None else table.normal
    # the face fit is robust on its own, and trimming would cut a long box's small end faces away (2% of
    # the points along its length are most of an end face: the box came out 3 cm short)
    p_faces = p
    if trim:
        p = trim_outer(p, up)
    p_seen = p
    if table is not None:
        h = table.height(p)
        p = p[h > -0.01]  # points below the table top are noise
        if len(p) < 10:
            raise ValueError("the object's points lie below the table plane")
        p = np.concatenate([p, table.project(p) + 0.0005 * table.normal])
    if kind == "box":
        box, _ = box_from_faces(p_faces, up, table, density=density)
        return box if box is not None else box_shape_from_points(p, up, density)
    if kind not in ("hull", "auto"):
        raise ValueError(f"kind must be 'hull', 'box' or 'auto', got {kind!r}")
    try:
        hull = ConvexHull(p)
    except QhullError as e:
        raise ValueError(f"the object's points are degenerate (flat or collinear): {e}") from None
    verts = p[hull.vertices]
    R = _frame_from_normal(up)
    # body frame: yaw of the footprint's principal axis, origin at the hull's centroid (of volume)
    uv = (verts - verts.mean(0)) @ R[:, :2]
    if len(uv) >= 2:
        w, v = np.linalg.eigh(np.cov(uv.T))
        ax = v[:, np.argmax(w)]
        c, s = ax
        R = R @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    centroid = _hull_centroid(p[hull.vertices], hull)
    T = make_T(R, centroid)
    local = (verts - centroid) @ R
    faces = _outward_faces(hull, local)
    size = local.max(0) - local.min(0)
    if kind == "auto":  # box-like objects as their box: planar faces and a flat top, not noisy facets
        # box-like or not from the trimmed points (the spread layers of a fused cloud blur the normals); the
        # faces from all of them
        _, boxness = box_from_faces(p_seen, up, table, density=density)
        box = box_from_faces(p_faces, up, table, density=density)[0] if boxness >= BOXNESS else None
        if box is not None:  # clean faces: the box fitted to them
            return box
        box = box_shape_from_points(p, up, density)  # noisy normals: the enclosing box, if the hull fills it
        if hull.volume >= BOX_FILL * box.volume:
            return box
    return BodyShape(T, "hull", size, float(hull.volume), _mass(float(hull.volume), density), local, faces)


def _outward_faces(hull, local: np.ndarray) -> np.ndarray:
    """(F, 3) int triangles of a scipy ConvexHull re-indexed onto its kept vertices (``local`` (V, 3), in
    ``hull.vertices`` order), each turned to face outward."""
    remap = {int(v): i for i, v in enumerate(hull.vertices)}
    faces = np.array([[remap[int(a)] for a in f] for f in hull.simplices], dtype=np.int64)
    ctr = local.mean(0)
    for i, f in enumerate(faces):
        a, b, c = local[f]
        if np.dot(np.cross(b - a, c - a), a - ctr) < 0:
            faces[i] = f[[0, 2, 1]]
    return faces


def _hull_centroid(points: np.ndarray, hull) -> np.ndarray:
    """Volume centroid of a convex hull (sum of tetrahedra from an interior point)."""
    o = hull.points[hull.vertices].mean(0)
    tri = hull.points[hull.simplices]
    vol = np.abs(np.einsum("ij,ij->i", tri[:, 0] - o, np.cross(tri[:, 1] - o, tri[:, 2] - o))) / 6.0
    if vol.sum() <= 0:
        return o
    cent = (tri.sum(axis=1) + o) / 4.0
    return (vol[:, None] * cent).sum(0) / vol.sum()


def box_from_faces(points: np.ndarray, up: np.ndarray, table: TablePlane | None = None, k: int = 16,
                   density: float = DEFAULT_DENSITY) -> tuple[BodyShape | None, float]:
    """A box (z along ``up``) fitted to the object's vertical *faces*, and how box-like the object is.

    The enclosing box of a segment is pulled off by any points that are not the object's (a touching
    neighbour's surface that bled into the segment, a view registered a little off): a few percent of
    points on one side turn and widen it by centimetres. Here the yaw is the dominant direction (mod 90
    degrees) of the vertical surfaces' normals (local plane fits over ``k`` neighbours), and each face sits
    at the median of the points whose normal points that way -- a bleed cluster with normals of its own
    moves neither. A side no camera saw falls back to the 99.5th percentile of the points
    along it; the top is the 98th percentile of height, the bottom the table (or the lowest point).

    Args:
        points: (N,3) the object's points in b1 (not extruded).
    Returns:
        ``(box or None, boxness)``: boxness in [0, 1] is the share of vertical-surface points whose normal
        lies within 15 degrees of one of the four face directions (a box: near 1; a cylinder: about 1/3).
        None when there are too few vertical-surface points to tell.
    """
    from scipy.spatial import cKDTree

    P = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    if len(P) < 3 * k:
        return None, 0.0
    _, nb = cKDTree(P).query(P, k=k)
    Q = P[nb] - P[nb].mean(axis=1, keepdims=True)
    normals = np.linalg.eigh(np.einsum("nki,nkj->nij", Q, Q))[1][:, :, 0]  # smallest eigenvector per point
    R0 = _frame_from_normal(up)
    loc = P @ R0
    nl = normals @ R0
    centre_xy = np.median(loc[:, :2], axis=0)
    side = np.abs(nl[:, 2]) < 0.3  # on a vertical surface
    if side.sum() < 20:
        return None, 0.0
    # outward normals, horizontal angle modulo 90 degrees
    nh = nl[side, :2] / np.linalg.norm(nl[side, :2], axis=1, keepdims=True)
    nh *= np.where(np.einsum("ij,ij->i", nh, loc[side, :2] - centre_xy) < 0, -1.0, 1.0)[:, None]
    ang = np.mod(np.arctan2(nh[:, 1], nh[:, 0]), np.pi / 2)
    bins = np.deg2rad(np.arange(0.0, 90.0, 1.0))
    dist = np.abs(np.angle(np.exp(4j * (ang[:, None] - bins[None]))) / 4)  # circular, period 90 deg
    votes = (dist < np.deg2rad(5.0)).sum(axis=0)
    yaw = float(bins[int(np.argmax(votes))])
    boxness = float(np.mean(np.abs(np.angle(np.exp(4j * (ang - yaw))) / 4) < np.deg2rad(15.0)))
    axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])  # local x, y of the box
    lo, hi = np.zeros(2), np.zeros(2)
    for i, a in enumerate(axes):
        proj_all = loc[:, :2] @ a
        proj = loc[side, :2] @ a
        for sgn in (1.0, -1.0):
            face = (nh @ (sgn * a)) > np.cos(np.deg2rad(25.0))
            if face.sum() >= max(20, 0.05 * len(nh)):  # a face, not a few stray normals
                pos = float(np.median(proj[face]))
            else:  # a face no camera saw: the points' extent that way (its edges, on the faces beside it;
                # outliers are gone, and a 2% tail would take 7 mm off a 35 cm box)
                pos = float(np.percentile(proj_all, 99.5 if sgn > 0 else 0.5))
            if sgn > 0:
                hi[i] = pos
            else:
                lo[i] = pos
    if np.any(hi - lo <= 0.005):
        return None, boxness
    h = loc[:, 2]  # height along up (R0's z)
    top = float(np.percentile(h, 98.0))
    bottom = float(-table.d) if table is not None else float(h.min())  # the plane n.x + d = 0, n = up
    c2 = 0.5 * (lo + hi) @ axes  # in the local frame's xy
    Rz = np.array([[axes[0, 0], axes[1, 0], 0.0], [axes[0, 1], axes[1, 1], 0.0], [0.0, 0.0, 1.0]])
    R = R0 @ Rz
    centre = R0 @ np.array([c2[0], c2[1], 0.5 * (top + bottom)])
    size = np.maximum(np.array([hi[0] - lo[0], hi[1] - lo[1], top - bottom]), 0.005)
    vol = float(np.prod(size))
    return BodyShape(make_T(R, centre), "box", size, vol, _mass(vol, density)), boxness


def box_shape_from_points(points: np.ndarray, up: np.ndarray, density: float = DEFAULT_DENSITY) -> BodyShape:
    """A box (z along ``up``) around points (N,3): footprint from OpenCV's minimum-area rectangle, its
    longer side along the box's x."""
    import cv2

    R0 = _frame_from_normal(np.asarray(up, dtype=np.float64))
    local = points @ R0
    mid = local[:, :2].mean(axis=0)  # centred: minAreaRect works in float32
    rect = cv2.minAreaRect((local[:, :2] - mid).astype(np.float32))
    corners = cv2.boxPoints(rect).astype(np.float64)
    sides = np.array([corners[1] - corners[0], corners[2] - corners[1]])
    lengths = np.linalg.norm(sides, axis=1)
    order = np.argsort(-lengths, kind="stable")  # longer side first
    ext = lengths[order]
    ax = sides[order[0]] / max(lengths[order[0]], 1e-12)
    c2 = mid + np.asarray(rect[0], dtype=np.float64)
    Rz = np.array([[ax[0], -ax[1], 0], [ax[1], ax[0], 0], [0, 0, 1.0]])
    zlo, zhi = local[:, 2].min(), local[:, 2].max()
    R = R0 @ Rz
    centre = R0 @ np.array([c2[0], c2[1], (zlo + zhi) / 2])
    size = np.array([ext[0], ext[1], zhi - zlo], dtype=np.float64)
    size = np.maximum(size, 0.005)
    vol = float(np.prod(size))
    return BodyShape(make_T(R, centre), "box", size, vol, _mass(vol, density))


def box_shape(T_b1_o: np.ndarray, size: np.ndarray, mass: float | None = None, kind: str = "box",
              density: float = DEFAULT_DENSITY) -> BodyShape:
    """A primitive shape with a known pose (ground-truth objects).

    ``kind`` is ``box`` (size = edges), ``cylinder`` (size = (2r, 2r, height), axis = o's z) or
    ``sphere`` (size = (2r, 2r, 2r)).
    """
    size = np.asarray(size, dtype=np.float64).reshape(3)
    if kind == "box":
        vol = float(np.prod(size))
    elif kind == "cylinder":
        vol = float(np.pi * (size[0] / 2) ** 2 * size[2])
    elif kind == "sphere":
        vol = float(4 / 3 * np.pi * (size[0] / 2) ** 3)
    else:
        raise ValueError(f"unknown primitive kind {kind!r} (box, cylinder, sphere)")
    m = float(mass) if mass is not None else _mass(vol, density)
    return BodyShape(np.asarray(T_b1_o, dtype=np.float64), kind, size, vol, m)


def hull_shape(T_b1_o: np.ndarray, vertices_o: np.ndarray, mass: float | None = None,
               density: float = DEFAULT_DENSITY) -> BodyShape:
    """The convex hull of ``vertices_o`` (V, 3), given in a frame ``o`` with a known pose ``T_b1_o`` (4, 4)
    (ground-truth mesh objects). The body frame keeps o's axes, its origin moved to the hull's centroid."""
    from scipy.spatial import ConvexHull

    V = check_shape("vertices_o", np.asarray(vertices_o, dtype=np.float64), (None, 3))
    hull = ConvexHull(V)
    centroid = _hull_centroid(V[hull.vertices], hull)
    local = V[hull.vertices] - centroid
    faces = _outward_faces(hull, local)
    T = np.asarray(T_b1_o, dtype=np.float64) @ make_T(np.eye(3), centroid)
    vol = float(hull.volume)
    m = float(mass) if mass is not None else _mass(vol, density)
    return BodyShape(T, "hull", local.max(0) - local.min(0), vol, m, local, faces)
