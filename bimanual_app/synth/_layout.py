"""Random ground truth of a synthetic setup: base poses, hand-eye mounts, object placements.

Pure sampling functions (``rng`` in, transforms out) plus :func:`place_objects`, which asks the PyBullet
world for exact collision-shape distances so that objects never overlap and "touching" ones really touch.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import make_T, so3_exp

from ._objects import ObjectSpec

# Objects keep this clearance (m) between their footprint and a base's centre (the base is 5.5 cm in radius).
BASE_CLEARANCE = 0.10
# ... and stay within this distance of both bases (both arms reach them: hand-overs, two-hand lifts).
REACH_LIMIT = 0.50
GAP_FREE = 0.03  # minimum gap between objects that are not placed touching
GAP_TOUCH = 0.0005  # the gap of touching objects (collision shapes 0.5 mm apart: they look in contact)
TOUCH_TOL = 0.002  # objects closer than this count as touching in the ground truth


def Rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def sample_base_pose(rng: np.random.Generator) -> np.ndarray:
    """``T_b1_b2`` (4, 4): the secondary faces the primary across the table.

    0.5-0.7 m along b1's x, up to +-6 cm sideways, 0-3 cm higher (a base plate), yaw 180 +- 12 degrees.
    """
    d = rng.uniform(0.5, 0.7)
    t = np.array([d, rng.uniform(-0.06, 0.06), rng.uniform(0.0, 0.03)])
    yaw = np.pi + np.deg2rad(rng.uniform(-12.0, 12.0))
    return make_T(Rz(yaw), t)


def sample_hand_eye(rng: np.random.Generator) -> np.ndarray:
    """``T_e_c`` (4, 4): a wrist camera beside the gripper, looking along the approach axis, tilted in.

    The flange frame e has z = approach, y = finger closing direction. The camera sits 5.5-7.5 cm off the
    axis on the -x side (around it by +-12 degrees), 3-6 cm along it, its optical axis tilted 2-8 degrees
    towards the gripper axis, image "down" towards the gripper, plus about 3 degrees (RMS) of mounting
    error about random axes and a random roll of +-6 degrees. The fingertips then stay at or just below
    the image's bottom edge.
    """
    off = rng.uniform(0.055, 0.075)
    phi = np.deg2rad(rng.uniform(-12.0, 12.0))  # where around the flange axis the camera sits
    radial = np.array([-np.cos(phi), -np.sin(phi), 0.0])  # from the axis to the camera
    t = off * radial + np.array([0.0, 0.0, rng.uniform(0.03, 0.06)])
    tilt = np.deg2rad(rng.uniform(2.0, 8.0))
    z = np.cos(tilt) * np.array([0.0, 0.0, 1.0]) - np.sin(tilt) * radial  # optical axis leans towards the axis
    y = -radial - np.dot(-radial, z) * z  # image down: towards the gripper
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=1)
    R = R @ so3_exp(np.array([0.0, 0.0, np.deg2rad(rng.uniform(-6.0, 6.0))]))
    R = so3_exp(rng.normal(scale=np.deg2rad(1.7), size=3)) @ R
    return make_T(R, t + rng.normal(scale=0.002, size=3))


def _footprint_ok(c: np.ndarray, spec: ObjectSpec, yaw: float, bases: list[np.ndarray], table,
                  reach: float = REACH_LIMIT) -> bool:
    """Object at xy ``c`` with ``yaw``: clear of both bases, within reach of both, on the table."""
    hx, hy = spec.size[0] / 2, spec.size[1] / 2
    corners = np.array([[sx * hx, sy * hy] for sx in (-1, 1) for sy in (-1, 1)]) @ Rz(yaw)[:2, :2].T + c
    for b in bases:
        if _box_point_distance(c, hx, hy, yaw, b) < BASE_CLEARANCE or np.linalg.norm(c - b) > reach:
            return False
    local = (np.linalg.inv(table.T_b1_t) @ np.c_[corners, np.zeros(4), np.ones(4)].T)[:2].T
    return bool(np.all(np.abs(local) < table.size[:2] / 2 - 0.05))


def _box_point_distance(c, hx, hy, yaw, p) -> float:
    q = Rz(-yaw)[:2, :2] @ (np.asarray(p) - c)
    d = np.maximum(np.abs(q) - [hx, hy], 0.0)
    return float(np.linalg.norm(d))


def place_objects(world, specs: list[ObjectSpec], rng: np.random.Generator, touching: float = 0.5,
                  tries: int = 400) -> list[np.ndarray]:
    """Place ``specs`` on the table of ``world`` (adds their bodies); returns their ``T_b1_o`` (4, 4).

    The first object (the large box) goes near the middle, across the line between the bases. The
    others go at random, at least ``GAP_FREE`` from everything (half that, and up to 8 cm farther from the
    bases, when the table is crowded), except that about ``touching`` of all objects are placed in
    contact with a neighbour (slid along a random direction until their collision
    shapes are ``GAP_TOUCH`` apart).
    """
    t12 = world.T_b1_b[1][:3, 3]
    bases = [np.zeros(2), t12[:2].copy()]
    mid = 0.5 * t12[:2]
    line_yaw = float(np.arctan2(t12[1], t12[0]))
    along = np.array([np.cos(line_yaw), np.sin(line_yaw)])
    across = np.array([-along[1], along[0]])
    d = float(np.linalg.norm(t12[:2]))
    n_touch_target = int(np.floor(touching * len(specs) + 0.5))
    poses: list[np.ndarray] = []
    bodies: list[int] = []
    touching_set: set[int] = set()

    def pose(c, yaw, spec):
        return make_T(Rz(yaw), [c[0], c[1], spec.size[2] / 2])

    def clear_of_others(body, skip=(), gap=GAP_FREE):
        return all(world.distance(body, b, 0.2) >= (0.0 if b in skip else gap) for b in bodies)

    for k, spec in enumerate(specs):
        body = world.add_object(spec, make_T(np.eye(3), [0.0, 0.0, -5.0 - k]))
        placed = None
        want_touch = k > 0 and len(touching_set) < n_touch_target
        for attempt in range(tries):
            yaw = float(rng.uniform(-np.pi, np.pi))
            if k == 0 and spec.kind == "large_box":
                yaw = line_yaw + np.pi / 2 + np.deg2rad(rng.uniform(-25, 25))
                c = mid + rng.normal(scale=0.03, size=2)
            elif want_touch and attempt < tries // 2:
                # neighbour: one that touches nothing yet when two more are needed, else any
                need = n_touch_target - len(touching_set)
                free = [i for i in range(k) if i not in touching_set]
                pool = free if (need >= 2 and free) else list(range(k))
                nb = int(rng.choice(pool))
                u = rng.normal(size=2)
                u /= np.linalg.norm(u)
                cn = poses[nb][:2, 3]
                lo, hi = 0.0, specs[nb].footprint_radius + spec.footprint_radius + 0.05
                world.move_object(body, pose(cn + hi * u, yaw, spec))
                if world.distance(body, bodies[nb]) <= GAP_TOUCH:
                    continue
                for _ in range(30):  # bisection on the slide distance: gap(s) grows with s
                    s = 0.5 * (lo + hi)
                    world.move_object(body, pose(cn + s * u, yaw, spec))
                    if world.distance(body, bodies[nb]) < GAP_TOUCH:
                        lo = s
                    else:
                        hi = s
                c = cn + hi * u
            else:
                c = mid + along * rng.uniform(-d / 2, d / 2) + across * rng.uniform(-0.34, 0.34)
            crowded = attempt >= tries // 2  # a full table: allow a wider region and smaller gaps
            if not _footprint_ok(c, spec, yaw, bases, world.table, REACH_LIMIT + (0.08 if crowded else 0.0)):
                continue
            T = pose(c, yaw, spec)
            world.move_object(body, T)
            if want_touch and attempt < tries // 2:
                gap = world.distance(body, bodies[nb])
                if not (0.0 <= gap <= TOUCH_TOL) or not clear_of_others(body, skip=(bodies[nb],), gap=0.0):
                    continue
                touching_set |= {k, nb}
            elif not clear_of_others(body, gap=GAP_FREE / 2 if crowded else GAP_FREE):
                continue
            placed = T
            break
        if placed is None:
            raise RuntimeError(f"could not place object {k} ({spec.kind}) on the table after {tries} tries;"
                               " use fewer objects or another seed")
        poses.append(placed)
        bodies.append(body)
    return poses


def touching_pairs(world, bodies: list[int]) -> list[tuple[int, int]]:
    """Index pairs (i < j) of objects whose collision shapes are within ``TOUCH_TOL``."""
    out = []
    for i in range(len(bodies)):
        for j in range(i + 1, len(bodies)):
            if world.distance(bodies[i], bodies[j], 0.05) <= TOUCH_TOL:
                out.append((i, j))
    return out
