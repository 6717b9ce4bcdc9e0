"""Depth views rendered analytically for the free-space tests: a table (z = 0) and upright cylinders, seen
by pinhole cameras looking at a target. Frame b1, z up, metres."""

from __future__ import annotations

import numpy as np

from bimanual_app.views import DepthViews

W, H, F = 160, 120, 140.0  # about 3 mm pixels at 0.45 m, as the pipeline's 160 x 120 point maps


def look_at(eye, target) -> np.ndarray:
    """(4, 4) camera pose in b1 (z forward, towards ``target``; x to the right, y down)."""
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def _hit_cylinder(o, d, centre, radius, height) -> np.ndarray:
    """(N,) ray parameter of the first hit on a closed upright cylinder (inf: none)."""
    t = np.full(len(d), np.inf)
    oc = o[:2] - np.asarray(centre)
    a = np.sum(d[:, :2] ** 2, axis=1)
    b = 2 * d[:, :2] @ oc
    c = oc @ oc - radius ** 2
    disc = b ** 2 - 4 * a * c
    ok = disc >= 0
    for sign in (-1.0, 1.0):
        ts = np.where(ok, (-b + sign * np.sqrt(np.where(ok, disc, 0.0))) / (2 * np.maximum(a, 1e-12)), np.inf)
        z = o[2] + ts * d[:, 2]
        t = np.where((ts > 0) & (z >= 0) & (z <= height) & (ts < t), ts, t)
    tt = np.where(np.abs(d[:, 2]) > 1e-12, (height - o[2]) / np.where(np.abs(d[:, 2]) > 1e-12, d[:, 2], 1.0), np.inf)
    p = o[:2] + tt[:, None] * d[:, :2]
    top = (tt > 0) & (np.sum((p - centre) ** 2, axis=1) <= radius ** 2)
    return np.where(top & (tt < t), tt, t)


def _hit_cup(o, d, centre, radius, height) -> np.ndarray:
    """(N,) ray parameter of the first hit on an upright cup without a lid (thin wall, inside bottom at z = 0;
    inf: none): its outer side, or through its opening its inner side or its bottom."""
    closed = _hit_cylinder(o, d, centre, radius, height)
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = (height - o[2]) / d[:, 2]
        tb = -o[2] / d[:, 2]
    p = o[:2] + tt[:, None] * d[:, :2]
    through = (tt > 0) & (np.sum((p - centre) ** 2, axis=1) <= radius ** 2) & np.isclose(closed, tt)
    oc = o[:2] - np.asarray(centre)
    a = np.maximum(np.sum(d[:, :2] ** 2, axis=1), 1e-12)
    b = 2 * d[:, :2] @ oc
    disc = np.maximum(b ** 2 - 4 * a * (oc @ oc - radius ** 2), 0.0)
    t_wall = (-b + np.sqrt(disc)) / (2 * a)  # leaving the circle: the inner side, seen from inside
    z = o[2] + t_wall * d[:, 2]
    inside = np.where((z >= 0) & (z <= height), t_wall, tb)
    return np.where(through, inside, closed)


def _hit_box(o, d, centre, size, yaw) -> np.ndarray:
    """(N,) ray parameter of the first hit on a box standing on the table (slab method; inf: none)."""
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    half = np.asarray(size, dtype=np.float64) / 2
    o_l = (o - np.array([centre[0], centre[1], half[2]])) @ R
    d_l = d @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - o_l) / d_l, (half - o_l) / d_l
    t_near = np.nanmax(np.minimum(t1, t2), axis=1)
    t_far = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((t_near <= t_far) & (t_near > 0), t_near, np.inf)


def render(cameras: list[np.ndarray], cylinders: list[tuple[tuple[float, float], float, float]],
           table_half: float = 0.3, table_centre=(0.3, 0.0), boxes=(), cups=()) -> DepthViews:
    """Depth views of the table, ``cylinders`` ((x, y), radius, height), ``boxes`` ((x, y), (sx, sy, sz),
    yaw) and ``cups`` (as cylinders, without a lid) from ``cameras`` (4, 4) poses."""
    K = np.array([F, F, (W - 1) / 2, (H - 1) / 2])
    cols, rows = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays_c = np.stack([(cols - K[2]) / K[0], (rows - K[3]) / K[1], np.ones_like(cols)], axis=-1).reshape(-1, 3)
    depths = []
    for T in cameras:
        d = rays_c @ T[:3, :3].T  # z-depth = the ray parameter (camera-frame z of the ray is 1)
        o = T[:3, 3]
        t = np.where(d[:, 2] < -1e-9, -o[2] / np.where(d[:, 2] < -1e-9, d[:, 2], -1.0), np.inf)
        p = o[:2] + t[:, None] * d[:, :2]
        t = np.where(np.all(np.abs(p - np.asarray(table_centre)) <= table_half, axis=1), t, np.inf)
        for centre, radius, height in cylinders:
            t = np.minimum(t, _hit_cylinder(o, d, np.asarray(centre, dtype=np.float64), radius, height))
        for centre, size, yaw in boxes:
            t = np.minimum(t, _hit_box(o, d, centre, size, yaw))
        for centre, radius, height in cups:
            t = np.minimum(t, _hit_cup(o, d, np.asarray(centre, dtype=np.float64), radius, height))
        depths.append(np.where(np.isfinite(t), t, np.nan).reshape(H, W))
    return DepthViews(np.stack(cameras), np.tile(K, (len(cameras), 1)), np.stack(depths).astype(np.float32),
                      np.ones(len(cameras), dtype=np.int64))


def ring_of_cameras(target, azimuths_deg, distance: float = 0.35, height: float = 0.3) -> list[np.ndarray]:
    """Cameras around ``target`` (3,) at these azimuths, ``distance`` away horizontally, ``height`` up."""
    target = np.asarray(target, dtype=np.float64)
    out = []
    for a in np.deg2rad(azimuths_deg):
        eye = target + np.array([distance * np.cos(a), distance * np.sin(a), height])
        out.append(look_at(eye, target))
    return out
