"""Per-link collision shapes of one arm, from the URDF's collision elements, with bounding capsules.

Each shape keeps its exact coal geometry (for the narrow phase and for distances) and a capsule in its
joint's frame that contains it (for the vectorised broad phase). A URDF capsule written as a cylinder
plus two end spheres of the same radius (the Piper model) is merged back into one coal.Capsule, whose
bounding capsule is the shape itself (``exact``): the broad phase then decides on its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import perpendicular_basis

__all__ = ["Shape", "ArmShapes", "arm_shapes", "bounding_capsule", "obb_of_points"]


@dataclass
class Shape:
    """One collision shape fixed to a Pinocchio joint.

    name: link name (+ index); joint: Pinocchio joint id it moves with; group: the arm joint that moves
    it (0 for the fixed base): shapes in the same or adjacent groups are never checked against each other.
    geometry: coal shape; M: (4,4) placement in the joint frame; a, b: (3,) bounding-capsule segment in the
    joint frame; radius: bounding-capsule radius; exact: the bounding capsule equals the shape.
    """

    name: str
    joint: int
    group: int
    geometry: object
    M: np.ndarray
    a: np.ndarray
    b: np.ndarray
    radius: float
    exact: bool


def bounding_capsule(geometry) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """(a (3,), b (3,), radius, exact) of a capsule containing a coal geometry, in the geometry's frame."""
    import coal

    if isinstance(geometry, coal.Sphere):
        return np.zeros(3), np.zeros(3), float(geometry.radius), True
    if isinstance(geometry, coal.Capsule):
        h = float(geometry.halfLength)
        return np.array([0, 0, -h]), np.array([0, 0, h]), float(geometry.radius), True
    if isinstance(geometry, coal.Cylinder):
        h = float(geometry.halfLength)  # the capsule of the same radius and axis contains the cylinder
        return np.array([0, 0, -h]), np.array([0, 0, h]), float(geometry.radius), False
    if isinstance(geometry, coal.Box):
        half = np.asarray(geometry.halfSide, dtype=np.float64)
        k = int(np.argmax(half))
        a, b = np.zeros(3), np.zeros(3)
        a[k], b[k] = -half[k], half[k]
        others = np.delete(half, k)
        return a, b, float(np.linalg.norm(others)), False
    vertices = _vertices(geometry)
    if vertices is None or len(vertices) == 0:
        raise ValueError(f"unsupported collision geometry {type(geometry).__name__}")
    return _capsule_of_points(vertices) + (False,)


def _vertices(geometry) -> np.ndarray | None:
    for attr in ("vertices", "points"):
        if hasattr(geometry, attr):
            v = getattr(geometry, attr)
            v = v() if callable(v) else v
            return np.asarray(v, dtype=np.float64).reshape(-1, 3)
    return None


def _capsule_of_points(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule around points (N,3): axis = principal direction, radius = largest distance to the axis."""
    c = P.mean(axis=0)
    _, _, Vt = np.linalg.svd(P - c, full_matrices=False)
    u = Vt[0]
    s = (P - c) @ u
    perp = (P - c) - s[:, None] * u
    r = float(np.sqrt((perp * perp).sum(axis=1).max()))
    return c + s.min() * u, c + s.max() * u, r


def obb_of_points(P: np.ndarray, padding: float = 0.0, axis: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Oriented bounding box of points (N,3): (T (4,4) box-centre pose in the points' frame, half sizes (3,)).

    The box's axes are the points' principal axes; with ``axis`` (3,) (e.g. the table normal, for an
    object extruded down to the table) also the box with one edge along it and the least-area rectangle
    about it, and whichever of the two has the smaller volume is returned. Principal axes alone bloat a
    box-like object whose extents are close (a near-cube's covariance has no preferred axes), by tens of
    percent in volume (measured: docs/motion.md).
    """
    P = np.asarray(P, dtype=np.float64)
    c = P.mean(axis=0)
    _, _, Vt = np.linalg.svd(P - c, full_matrices=False)
    frames = [Vt.T]
    if axis is not None:
        frames.append(_frame_about_axis(P, np.asarray(axis, dtype=np.float64)))
    best = None
    for R in frames:
        R = R.copy()
        if np.linalg.det(R) < 0:
            R[:, 2] *= -1
        local = (P - c) @ R
        lo, hi = local.min(axis=0), local.max(axis=0)
        vol = float(np.prod(hi - lo))
        if best is None or vol < best[0] - 1e-12:
            best = (vol, R, lo, hi)
    _, R, lo, hi = best
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = c + R @ ((lo + hi) / 2)
    return T, (hi - lo) / 2 + padding


def _frame_about_axis(P: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(3,3) rotation whose z is ``axis`` and whose x, y are the sides of the least-area rectangle holding
    the points (N,3) projected along it (OpenCV's rotating calipers)."""
    import cv2

    z = axis / np.linalg.norm(axis)
    x0, y0 = perpendicular_basis(z)
    uv = np.stack([P @ x0, P @ y0], axis=1)
    (_, _), (_, _), ang = cv2.minAreaRect((uv - uv.mean(axis=0)).astype(np.float32))
    a = np.deg2rad(ang)
    x = np.cos(a) * x0 + np.sin(a) * y0
    return np.stack([x, np.cross(z, x), z], axis=1)


@dataclass
class ArmShapes:
    """All shapes of one arm as arrays for the vectorised checks (S shapes)."""

    shapes: list[Shape]
    joint: np.ndarray  # (S,) int
    group: np.ndarray  # (S,) int
    a: np.ndarray  # (S,3) in the joint frame (already including M)
    b: np.ndarray  # (S,3)
    radius: np.ndarray  # (S,)
    exact: np.ndarray  # (S,) bool
    M: np.ndarray  # (S,4,4)
    self_pairs: np.ndarray  # (P,2) int pairs checked for self collision

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.shapes]


def _merge_capsules(objs: list[tuple[str, int, object, np.ndarray]]) -> list[tuple[str, int, object, np.ndarray]]:
    """Merge (cylinder + sphere at each end, same radius, same joint) into one coal.Capsule."""
    import coal

    used: set[int] = set()
    out = []
    for i, (name, joint, geom, M) in enumerate(objs):
        if i in used or not isinstance(geom, coal.Cylinder):
            continue
        h, r = float(geom.halfLength), float(geom.radius)
        ends = [M[:3, :3] @ np.array([0, 0, z]) + M[:3, 3] for z in (-h, h)]
        caps = []
        for end in ends:
            for j, (_, joint2, g2, M2) in enumerate(objs):
                if j != i and j not in used and joint2 == joint and isinstance(g2, coal.Sphere) \
                        and abs(float(g2.radius) - r) < 1e-9 and np.linalg.norm(M2[:3, 3] - end) < 1e-6:
                    caps.append(j)
                    break
        if len(caps) == 2:
            used.update([i] + caps)
            out.append((name, joint, coal.Capsule(r, 2 * h), M))
    out += [o for k, o in enumerate(objs) if k not in used]
    return out


def arm_shapes(robot, extra: list[Shape] | None = None, disable_pairs: set[tuple[str, str]] | None = None) -> ArmShapes:
    """Shapes of ``robot``'s collision model (+ ``extra`` shapes such as an attached object).

    Self-collision pairs: every pair except shapes on the same arm joint group or on adjacent groups
    (parent / child arm joints), and except pairs named in ``disable_pairs`` (by shape name).
    """
    gm = robot.collision_model
    objs = []
    for go in gm.geometryObjects:
        objs.append((go.name.rsplit("_", 1)[0] if go.name.rsplit("_", 1)[-1].isdigit() else go.name,
                     int(go.parentJoint), go.geometry, np.asarray(go.placement.homogeneous)))
    objs = _merge_capsules(objs)
    arm_ids = list(robot._arm_joint_ids)

    def group_of(j: int) -> int:
        while j > 0 and j not in arm_ids:
            j = int(robot.model.parents[j])
        return j

    shapes = []
    seen: dict[str, int] = {}
    for name, joint, geom, M in objs:
        a, b, r, exact = bounding_capsule(geom)
        k = seen.get(name, 0)
        seen[name] = k + 1
        shapes.append(Shape(name if k == 0 else f"{name}#{k}", joint, group_of(joint), geom, M,
                            M[:3, :3] @ a + M[:3, 3], M[:3, :3] @ b + M[:3, 3], r, exact))
    shapes += list(extra or [])
    return _pack(robot, shapes, disable_pairs or set())


def _pack(robot, shapes: list[Shape], disable_pairs: set[tuple[str, str]]) -> ArmShapes:
    parent_group = {0: -1}
    arm_ids = list(robot._arm_joint_ids)
    for k, j in enumerate(arm_ids):
        parent_group[j] = arm_ids[k - 1] if k > 0 else 0
    pairs = []
    for i in range(len(shapes)):
        for j in range(i + 1, len(shapes)):
            gi, gj = shapes[i].group, shapes[j].group
            if gi == gj or parent_group.get(gi) == gj or parent_group.get(gj) == gi:
                continue
            if (shapes[i].name, shapes[j].name) in disable_pairs or (shapes[j].name, shapes[i].name) in disable_pairs:
                continue
            pairs.append((i, j))
    return ArmShapes(
        shapes=shapes,
        joint=np.array([s.joint for s in shapes], dtype=int),
        group=np.array([s.group for s in shapes], dtype=int),
        a=np.stack([s.a for s in shapes]),
        b=np.stack([s.b for s in shapes]),
        radius=np.array([s.radius for s in shapes]),
        exact=np.array([s.exact for s in shapes], dtype=bool),
        M=np.stack([s.M for s in shapes]),
        self_pairs=np.array(pairs, dtype=int).reshape(-1, 2),
    )
