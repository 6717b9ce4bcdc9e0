"""Synthetic table-top clouds for the segmentation tests and benchmark (no rendering, built in code).

A scene is a table plane z = 0 of b1 with boxes, upright cylinders, spheres and mugs (a cylinder with an
open top and a handle) on it, sampled as a camera rig above the table would see them: the table outside
the objects' footprints, the objects' tops and sides (no bottoms), nothing inside another object, and
not the faces two touching objects turn to each other. Each
point carries a colour (a per-object base colour, shaded by its normal like a rendered image, plus noise)
and the true label (-1 table/background, k for object k).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PALETTE = np.array([
    [200, 40, 40], [40, 150, 60], [40, 70, 200], [230, 190, 30], [150, 60, 170],
    [30, 170, 190], [240, 120, 30], [110, 80, 50], [220, 90, 160], [90, 140, 30],
], dtype=np.float64)
TABLE_RGB = np.array([196.0, 164.0, 124.0])
LIGHT = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])


@dataclass
class Obj:
    """One object: ``kind`` in box / cylinder / sphere / mug, centre xy, yaw, ``size`` (3,) extents in o."""

    kind: str
    xy: np.ndarray
    yaw: float
    size: np.ndarray
    rgb: np.ndarray

    @property
    def R(self) -> np.ndarray:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    @property
    def T_b1_o(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = [self.xy[0], self.xy[1], self.size[2] / 2]
        return T

    @property
    def radius(self) -> float:
        """Footprint circle radius (m); the mug's includes its handle."""
        return float(0.5 * np.hypot(self.size[0], self.size[1]))


@dataclass
class TableScene:
    """A generated cloud: ``points`` (N, 3) b1 metres, ``colors`` (N, 3) uint8, ``labels`` (N,) int32."""

    points: np.ndarray
    colors: np.ndarray
    labels: np.ndarray
    objects: list[Obj] = field(default_factory=list)
    touching: list[tuple[int, int]] = field(default_factory=list)


def _area_samples(rng, n, parts):
    """Split ``n`` samples over surface parts by area; ``parts`` = [(area, sampler(k) -> (p, n))]."""
    out_p, out_n = [], []
    areas = np.array([a for a, _ in parts])
    counts = rng.multinomial(n, areas / areas.sum()) if n > 0 else np.zeros(len(parts), int)
    for (_, f), k in zip(parts, counts):
        if k:
            p, nn = f(k)
            out_p.append(p)
            out_n.append(nn)
    if not out_p:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(out_p), np.concatenate(out_n)


def _box_surface(rng, size, n):
    sx, sy, sz = size
    def face(axis, sign):
        def f(k):
            u = rng.uniform(-0.5, 0.5, (k, 3)) * size
            u[:, axis] = sign * size[axis] / 2
            nn = np.zeros((k, 3))
            nn[:, axis] = sign
            return u + [0, 0, sz / 2], nn
        return f
    parts = [(sx * sy, face(2, 1.0)), (sy * sz, face(0, 1.0)), (sy * sz, face(0, -1.0)),
             (sx * sz, face(1, 1.0)), (sx * sz, face(1, -1.0))]
    return _area_samples(rng, n, parts)


def _cylinder_surface(rng, r, h, n, open_top=False, wall=0.004):
    def top(k):
        rr = r * np.sqrt(rng.uniform(0, 1, k))
        t = rng.uniform(0, 2 * np.pi, k)
        return np.c_[rr * np.cos(t), rr * np.sin(t), np.full(k, h)], np.tile([0, 0, 1.0], (k, 1))

    def side(k, radius=r, sign=1.0, z0=0.0):
        t = rng.uniform(0, 2 * np.pi, k)
        z = rng.uniform(z0, h, k)
        nn = sign * np.c_[np.cos(t), np.sin(t), np.zeros(k)]
        return np.c_[radius * np.cos(t), radius * np.sin(t), z], nn

    if not open_top:
        parts = [(np.pi * r * r, top), (2 * np.pi * r * h, side)]
    else:
        ri = r - wall
        def rim(k):
            rr = np.sqrt(rng.uniform(ri ** 2, r ** 2, k))
            t = rng.uniform(0, 2 * np.pi, k)
            return np.c_[rr * np.cos(t), rr * np.sin(t), np.full(k, h)], np.tile([0, 0, 1.0], (k, 1))
        def inner_bottom(k):
            rr = ri * np.sqrt(rng.uniform(0, 1, k))
            t = rng.uniform(0, 2 * np.pi, k)
            return np.c_[rr * np.cos(t), rr * np.sin(t), np.full(k, 0.3 * h)], np.tile([0, 0, 1.0], (k, 1))
        parts = [(np.pi * (r * r - ri * ri), rim), (2 * np.pi * r * h, side),
                 (2 * np.pi * ri * 0.7 * h, lambda k: side(k, ri, -1.0, 0.3 * h)), (np.pi * ri * ri, inner_bottom)]
    return _area_samples(rng, n, parts)


def _sphere_surface(rng, r, n, lowest=-0.7):
    v = rng.normal(size=(int(n * 1.6) + 10, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = v[v[:, 2] > lowest][:n]
    return v * r + [0, 0, r], v


def _handle_surface(rng, r_body, h, n, R=0.022, tube=0.005):
    """A half torus on the +x side of a mug body (radius ``r_body``), centred at 55% of the height."""
    a = rng.uniform(-np.pi / 2, np.pi / 2, n)  # around the handle's big circle (in the x-z plane)
    b = rng.uniform(0, 2 * np.pi, n)  # around the tube
    c = np.array([r_body, 0.0, 0.55 * h])
    ring = np.c_[np.cos(a), np.zeros(n), np.sin(a)]
    nn = np.cos(b)[:, None] * ring + np.sin(b)[:, None] * np.array([0, 1.0, 0])
    p = c + R * ring + tube * nn
    keep = p[:, 0] > r_body  # the part outside the body
    return p[keep], nn[keep]


def _inside(obj: Obj, p: np.ndarray, margin: float = 0.001) -> np.ndarray:
    """(M,) bool: points strictly inside ``obj``'s solid (shrunk by ``margin``)."""
    q = (p - [obj.xy[0], obj.xy[1], 0.0]) @ obj.R
    sx, sy, sz = obj.size
    if obj.kind == "box":
        return np.all(np.abs(q - [0, 0, sz / 2]) < np.array([sx, sy, sz]) / 2 - margin, axis=1)
    if obj.kind == "sphere":
        r = sz / 2
        return np.linalg.norm(q - [0, 0, r], axis=1) < r - margin
    if obj.kind == "cylinder":
        rb, x0 = sx / 2, 0.0
    else:  # mug body (the handle is thin: ignored)
        rb, x0 = sy / 2, -(sx - sy) / 2
    return (np.hypot(q[:, 0] - x0, q[:, 1]) < rb - margin) & (q[:, 2] > margin) & (q[:, 2] < sz - margin)


def _surface(rng, obj: Obj, n: int):
    sx, sy, sz = obj.size
    if obj.kind == "box":
        p, nn = _box_surface(rng, obj.size, n)
    elif obj.kind == "cylinder":
        p, nn = _cylinder_surface(rng, sx / 2, sz, n)
    elif obj.kind == "sphere":
        p, nn = _sphere_surface(rng, sz / 2, n)
    else:  # mug: body radius sy/2, handle sticks out along +x
        rb = sy / 2
        k_handle = int(0.12 * n)
        p1, n1 = _cylinder_surface(rng, rb, sz, n - k_handle, open_top=True)
        p2, n2 = _handle_surface(rng, rb, sz, k_handle * 2)
        p2, n2 = p2[:k_handle], n2[:k_handle]
        p, nn = np.r_[p1, p2], np.r_[n1, n2]
        p[:, 0] -= (sx - sy) / 2  # centre the bounding box (body + handle) on the origin
    perm = rng.permutation(len(p))  # callers truncate: keep every part represented
    return p[perm] @ obj.R.T + [obj.xy[0], obj.xy[1], 0.0], nn[perm] @ obj.R.T


def _area(obj: Obj) -> float:
    sx, sy, sz = obj.size
    if obj.kind == "box":
        return sx * sy + 2 * (sx + sy) * sz
    if obj.kind == "cylinder":
        return np.pi * sx * sx / 4 + np.pi * sx * sz
    if obj.kind == "sphere":
        return 2.7 * np.pi * (sz / 2) ** 2
    return 2.2 * np.pi * sy * sz


def _shade(rng, rgb, normals, noise=8.0):
    lam = 0.55 + 0.45 * np.clip(normals @ LIGHT, 0, 1)
    c = rgb[None, :] * lam[:, None] + rng.normal(scale=noise, size=(len(normals), 3))
    return np.clip(c, 0, 255).astype(np.uint8)


def random_object(rng, kind: str | None = None) -> Obj:
    kind = kind or str(rng.choice(["box", "box", "cylinder", "sphere", "mug"]))
    if kind == "box":
        size = np.array([rng.uniform(0.05, 0.16), rng.uniform(0.04, 0.10), rng.uniform(0.03, 0.12)])
    elif kind == "cylinder":
        d = rng.uniform(0.05, 0.08)
        size = np.array([d, d, rng.uniform(0.06, 0.15)])
    elif kind == "sphere":
        d = rng.uniform(0.05, 0.08)
        size = np.array([d, d, d])
    else:
        d = rng.uniform(0.07, 0.09)
        size = np.array([d + 0.022 + 0.005, d, rng.uniform(0.08, 0.10)])
    return Obj(kind, np.zeros(2), float(rng.uniform(-np.pi, np.pi)), size, PALETTE[0].copy())


def _half_extent_along(obj: Obj, u: np.ndarray) -> float:
    """Support distance of ``obj``'s footprint (centred at 0) along unit ``u`` (2,)."""
    if obj.kind in ("cylinder", "sphere"):
        return obj.size[0] / 2
    if obj.kind == "mug":
        return obj.radius
    q = obj.R[:2, :2].T @ u
    return float(abs(q[0]) * obj.size[0] / 2 + abs(q[1]) * obj.size[1] / 2)


def make_table_scene(seed: int = 0, objects: list[Obj] | int = 5, touching: float = 0.5, n_points: int = 100_000,
                     noise: float = 0.0007, colors: bool = True, table_size=(1.0, 0.8),
                     table_center=(0.35, 0.0), gap: float = 0.0005, background: bool = True,
                     object_fraction: float = 0.45) -> TableScene:
    """A table-top cloud in b1 with ``objects`` (a count, or a list placed as given).

    With a count, about ``touching`` of the objects are placed in contact with a neighbour (``gap`` apart
    along a random direction), the rest at least 3 cm from everything. About ``object_fraction`` of the
    points lie on objects. ``noise`` is the Gaussian point noise (m). ``background`` adds a floor patch
    below the table and a few outliers (labelled -1).
    """
    rng = np.random.default_rng(seed)
    tc = np.asarray(table_center, float)
    tsz = np.asarray(table_size, float)
    touching_pairs: list[tuple[int, int]] = []
    if isinstance(objects, int):
        n = objects
        objs: list[Obj] = []
        n_touch = int(round(touching * n))
        touched: set[int] = set()
        for k in range(n):
            for _ in range(500):
                o = random_object(rng)
                o.rgb = PALETTE[k % len(PALETTE)].copy()
                if k > 0 and len(touched) < n_touch:
                    free = [i for i in range(k) if i not in touched]
                    nb = int(rng.choice(free if (n_touch - len(touched) >= 2 and free) else range(k)))
                    u = rng.normal(size=2)
                    u /= np.linalg.norm(u)
                    d = _half_extent_along(objs[nb], u) + _half_extent_along(o, -u) + gap
                    o.xy = objs[nb].xy + d * u
                    ok = _fits(o, tc, tsz) and all(np.linalg.norm(o.xy - q.xy) > o.radius + q.radius + 0.03
                                                     for i, q in enumerate(objs) if i != nb)
                    ok = ok and not _overlap(o, objs[nb])
                    if ok:
                        touched |= {k, nb}
                        touching_pairs.append((nb, k))
                        break
                else:
                    o.xy = tc + rng.uniform(-0.5, 0.5, 2) * (tsz - 0.25)
                    if _fits(o, tc, tsz) and all(np.linalg.norm(o.xy - q.xy) > o.radius + q.radius + 0.03 for q in objs):
                        break
            else:
                raise RuntimeError("could not place the objects; use fewer")
            objs.append(o)
    else:
        objs = list(objects)

    n_obj_pts = int(object_fraction * n_points)
    areas = np.array([_area(o) for o in objs]) if objs else np.zeros(0)
    counts = rng.multinomial(n_obj_pts, areas / areas.sum()) if objs else []
    P, C, L = [], [], []
    for k, (o, m) in enumerate(zip(objs, counts)):
        p, nn = _surface(rng, o, int(m * 1.15) + 20)
        keep = np.ones(len(p), bool)
        for j, q in enumerate(objs):
            if j != k:
                keep &= ~_inside(q, p) & ~_hidden(q, p, nn)
        p, nn = p[keep][:m], nn[keep][:m]
        P.append(p)
        C.append(_shade(rng, o.rgb, nn))
        L.append(np.full(len(p), k, np.int32))
    n_table = n_points - sum(len(p) for p in P)
    n_bg = int(0.04 * n_table) if background else 0
    n_table -= n_bg
    tp = np.c_[tc + rng.uniform(-0.5, 0.5, (int(n_table * 1.4) + 10, 2)) * tsz, np.zeros(int(n_table * 1.4) + 10)]
    keep = np.ones(len(tp), bool)
    for o in objs:
        keep &= ~_footprint(o, tp[:, :2])
    tp = tp[keep][:n_table]
    P.append(tp)
    C.append(_shade(rng, TABLE_RGB, np.tile([0, 0, 1.0], (len(tp), 1)), noise=14.0))
    L.append(np.full(len(tp), -1, np.int32))
    if n_bg:
        k1 = int(0.9 * n_bg)
        floor = np.c_[tc + rng.uniform(-1.0, 1.0, (k1, 2)) * tsz, np.full(k1, -0.75)]
        out = np.c_[tc + rng.uniform(-0.8, 0.8, (n_bg - k1, 2)) * tsz, rng.uniform(-0.7, 0.8, n_bg - k1)]
        P += [floor, out]
        C += [_shade(rng, np.array([110.0, 110, 115]), np.tile([0, 0, 1.0], (k1, 1))),
              rng.integers(0, 255, (n_bg - k1, 3)).astype(np.uint8)]
        L += [np.full(k1, -1, np.int32), np.full(n_bg - k1, -1, np.int32)]
    pts = np.concatenate(P)
    pts = pts + rng.normal(scale=noise, size=pts.shape) if noise > 0 else pts
    col = np.concatenate(C)
    lab = np.concatenate(L)
    perm = rng.permutation(len(pts))
    return TableScene(pts[perm], col[perm] if colors else None, lab[perm], objs, touching_pairs)


def _footprint(o: Obj, xy: np.ndarray) -> np.ndarray:
    q = (xy - o.xy) @ o.R[:2, :2]
    if o.kind == "box":
        return np.all(np.abs(q) < o.size[:2] / 2, axis=1)
    if o.kind == "mug":
        return np.hypot(q[:, 0] + (o.size[0] - o.size[1]) / 2, q[:, 1]) < o.size[1] / 2
    if o.kind == "sphere":
        return np.hypot(q[:, 0], q[:, 1]) < 0.3 * o.size[0] / 2  # only the contact patch hides the table
    return np.hypot(q[:, 0], q[:, 1]) < o.size[0] / 2


BASE_CLEAR = 0.12  # objects keep clear of the primary arm's base at b1's origin (as a real set-up does)


def _footprint_distance(o: Obj, xy: np.ndarray) -> np.ndarray:
    """(M,) horizontal distance (m) from points ``xy`` (M, 2) to the footprint of ``o`` (0 inside)."""
    q = (xy - o.xy) @ o.R[:2, :2]
    if o.kind == "box":
        return np.linalg.norm(np.maximum(np.abs(q) - o.size[:2] / 2, 0.0), axis=1)
    if o.kind == "mug":
        return np.maximum(np.hypot(q[:, 0] + (o.size[0] - o.size[1]) / 2, q[:, 1]) - o.size[1] / 2, 0.0)
    return np.maximum(np.hypot(q[:, 0], q[:, 1]) - o.size[0] / 2, 0.0)


def _hidden(o: Obj, p: np.ndarray, nn: np.ndarray, gap: float = 0.012) -> np.ndarray:
    """(M,) bool: surface points (M, 3) with normals (M, 3) that face ``o`` from closer than ``gap``,
    below its top: the faces two touching objects turn to each other, which no camera sees."""
    d = _footprint_distance(o, p[:, :2])
    to_o = np.c_[o.xy - p[:, :2], np.zeros(len(p))]
    facing = np.einsum("ij,ij->i", nn, to_o) > 0.3 * np.linalg.norm(to_o, axis=1)
    return (d < gap) & facing & (p[:, 2] < o.size[2] + 0.005)


def _fits(o: Obj, tc, tsz) -> bool:
    return bool(np.all(np.abs(o.xy - tc) < tsz / 2 - o.radius - 0.02) and np.linalg.norm(o.xy) > BASE_CLEAR + o.radius)


def _overlap(a: Obj, b: Obj) -> bool:
    """Rough check that two footprints do not overlap (sampled points of one inside the other)."""
    rng = np.random.default_rng(0)
    pts = a.xy + rng.uniform(-1, 1, (400, 2)) * a.radius
    return bool(np.any(_footprint(a, pts) & _footprint(b, pts)))


def write_ply(path, points: np.ndarray, colors: np.ndarray | None = None) -> None:
    """Write a binary PLY with Open3D (colours as uint8 -> [0, 1] floats)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    if colors is not None:
        pc.colors = o3d.utility.Vector3dVector(np.asarray(colors, dtype=np.float64) / 255.0)
    o3d.io.write_point_cloud(str(path), pc)


def write_mask_scene(root, scene: TableScene, views_per_arm: int = 2, size=(60, 40), seed: int = 0):
    """A contract scene folder whose point maps hold ``scene``'s points (frame w = b1, scale 1) and whose
    ``masks/NNN.png`` (twice the point-map size) hold each pixel's object id + 1 (0 = table).

    Each view gets a random share of the points laid out as an (H, W) map (the layout does not matter to
    the segmenter, which matches points by position); unused pixels are at the origin with confidence 0.
    Returns the scene path.
    """
    from pathlib import Path

    from PIL import Image

    from bimanual_app.scene import ArmCapture, Reconstruction, Scene, write_scene
    from bimanual_app.transforms import make_T

    rng = np.random.default_rng(seed)
    root = Path(root)
    W, H = size
    M = 2 * views_per_arm
    if len(scene.points) > M * H * W:
        raise ValueError("too many points for the point maps: use larger maps")
    view = rng.integers(0, M, len(scene.points))
    pts = np.zeros((M, H, W, 3), np.float32)
    conf = np.zeros((M, H, W), np.float32)
    ids = np.zeros((M, H, W), np.uint8)
    for m in range(M):
        sel = np.flatnonzero(view == m)
        pts[m].reshape(-1, 3)[: len(sel)] = scene.points[sel]
        conf[m].reshape(-1)[: len(sel)] = 5.0
        ids[m].reshape(-1)[: len(sel)] = scene.labels[sel] + 1
    arms, keys, arm_idx = [], [], []
    for a, name in enumerate(("primary", "secondary"), 1):
        ims = [f"images/{i:03d}.png" for i in range(views_per_arm)]
        T = np.stack([make_T(np.eye(3), [0.3, 0.05 * i, 0.4]) for i in range(views_per_arm)])
        arms.append(ArmCapture(name, ims, T))
        keys += ims
        arm_idx += [a] * views_per_arm
    T_w_c = np.stack([make_T(np.eye(3), [0.3, 0.0, 0.5])] * M)
    rec = Reconstruction(np.array(arm_idx), np.array(keys), T_w_c, pts, conf, "synthetic")
    write_scene(Scene(root, "masks", arms[0], arms[1], reconstruction=rec), root)
    for m in range(M):
        arm = ("primary", "secondary")[m // views_per_arm]
        p = root / arm / "masks" / f"{m % views_per_arm:03d}.png"
        p.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.kron(ids[m], np.ones((2, 2), np.uint8))).save(p)
    return root
