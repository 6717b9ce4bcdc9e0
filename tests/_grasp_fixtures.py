"""Small synthetic segmented clouds for the grasping tests: a table plane plus boxes and cylinders.

Surfaces are sampled on a regular grid (the visible faces only: no bottom face, as a camera above the
table sees them), in frame b1 with z up and the table at z = 0. Labels: -1 table, 0..K-1 objects.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class Obj:
    kind: str  # "box" | "cylinder"
    centre_xy: tuple[float, float]
    size: tuple[float, float, float]  # box: x, y, z extents; cylinder: diameter, diameter, height
    yaw: float = 0.0


def _grid(a: float, b: float, step: float) -> np.ndarray:
    u = np.arange(-a / 2, a / 2 + 1e-9, step)
    v = np.arange(-b / 2, b / 2 + 1e-9, step)
    U, V = np.meshgrid(u, v, indexing="ij")
    return np.stack([U.ravel(), V.ravel()], axis=1)


def box_points(centre_xy, size, yaw=0.0, step=0.003, z0=0.0) -> np.ndarray:
    """Top and four side faces of a box standing on z = z0; (M, 3)."""
    sx, sy, sz = size
    faces = []
    g = _grid(sx, sy, step)
    faces.append(np.c_[g, np.full(len(g), sz / 2)])
    g = _grid(sy, sz, step)
    for s in (-1, 1):
        faces.append(np.c_[np.full(len(g), s * sx / 2), g[:, 0], g[:, 1]])
    g = _grid(sx, sz, step)
    for s in (-1, 1):
        faces.append(np.c_[g[:, 0], np.full(len(g), s * sy / 2), g[:, 1]])
    P = np.concatenate(faces)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return P @ R.T + np.array([centre_xy[0], centre_xy[1], z0 + sz / 2])


def cylinder_points(centre_xy, diameter, height, step=0.003, z0=0.0) -> np.ndarray:
    """Side and top of an upright cylinder on z = z0; (M, 3)."""
    r = diameter / 2
    n_a = max(12, int(np.ceil(2 * np.pi * r / step)))
    a = np.linspace(0, 2 * np.pi, n_a, endpoint=False)
    z = np.arange(0, height + 1e-9, step)
    A, Z = np.meshgrid(a, z, indexing="ij")
    side = np.stack([r * np.cos(A).ravel(), r * np.sin(A).ravel(), Z.ravel()], axis=1)
    g = _grid(diameter, diameter, step)
    top = np.c_[g[np.linalg.norm(g, axis=1) <= r], ]
    top = np.c_[top, np.full(len(top), height)]
    return np.concatenate([side, top]) + np.array([centre_xy[0], centre_xy[1], z0])


def object_points(o: Obj, step=0.003) -> np.ndarray:
    if o.kind == "box":
        return box_points(o.centre_xy, o.size, o.yaw, step)
    if o.kind == "cylinder":
        return cylinder_points(o.centre_xy, o.size[0], o.size[2], step)
    raise ValueError(o.kind)


def table_points(centre_xy=(0.3, 0.0), size=(0.6, 0.6), step=0.006) -> np.ndarray:
    g = _grid(size[0], size[1], step) + np.asarray(centre_xy)
    return np.c_[g, np.zeros(len(g))]


def make_cloud(objects: list[Obj], table_centre=(0.3, 0.0), table_size=(0.6, 0.6), step=0.003, noise=0.0,
               seed=0) -> tuple[np.ndarray, np.ndarray]:
    """(points (N, 3), labels (N,) int32) of a table with ``objects`` (labels in list order).

    Table points under an object's footprint are removed (the object hides them).
    """
    rng = np.random.default_rng(seed)
    T = table_points(table_centre, table_size, step=2 * step)
    keep = np.ones(len(T), dtype=bool)
    for o in objects:
        c, s = np.cos(-o.yaw), np.sin(-o.yaw)
        d = T[:, :2] - np.asarray(o.centre_xy)
        loc = d @ np.array([[c, s], [-s, c]])
        if o.kind == "box":
            keep &= ~np.all(np.abs(loc) <= np.asarray(o.size[:2]) / 2, axis=1)
        else:
            keep &= np.linalg.norm(d, axis=1) > o.size[0] / 2
    parts = [T[keep]]
    labels = [np.full(int(keep.sum()), -1)]
    for k, o in enumerate(objects):
        Pk = object_points(o, step)
        parts.append(Pk)
        labels.append(np.full(len(Pk), k))
    P = np.concatenate(parts)
    if noise > 0:
        P = P + rng.normal(scale=noise, size=P.shape)
    return P, np.concatenate(labels).astype(np.int32)


def write_inputs(folder: Path, points: np.ndarray, labels: np.ndarray, T_b1_b2: np.ndarray | None = None
                 ) -> tuple[Path, Path, Path | None]:
    """Write scene_b1.ply, segments.npz and (with T_b1_b2) calibration.json into ``folder``."""
    import json

    import open3d as o3d

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    ply = folder / "scene_b1.ply"
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    o3d.io.write_point_cloud(str(ply), pc)
    seg = folder / "segments.npz"
    np.savez(seg, labels=labels.astype(np.int32))
    cal = None
    if T_b1_b2 is not None:
        cal = folder / "calibration.json"
        cal.write_text(json.dumps({"format": 1, "scene": "test", "T_b1_b2": np.asarray(T_b1_b2).tolist()}))
    return ply, seg, cal


def facing_T_b1_b2(distance: float = 0.6) -> np.ndarray:
    """The secondary arm ``distance`` along b1's x, facing the primary (yaw 180 degrees)."""
    T = np.eye(4)
    T[:3, :3] = np.diag([-1.0, -1.0, 1.0])
    T[0, 3] = distance
    return T


def accept_all_arms(T_b1_b2: np.ndarray | None = None) -> dict:
    """Arms whose reach filter accepts every grasp (no joint solutions): for tests of the geometry only."""
    from grasping import Arm, callable_filter

    f = callable_filter(lambda T: np.ones(len(T), dtype=bool))
    arms = {"primary": Arm("primary", np.eye(4), f)}
    if T_b1_b2 is not None:
        arms["secondary"] = Arm("secondary", np.asarray(T_b1_b2, float), f)
    return arms


def box_scene(noise: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 4 x 6 x 5 cm box alone on the table at (0.3, 0.1): the simplest graspable object."""
    return make_cloud([Obj("box", (0.3, 0.1), (0.04, 0.06, 0.05), 0.2)], noise=noise, seed=seed)
