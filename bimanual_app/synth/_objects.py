"""The catalogue of synthetic objects: kinds, random sizes, meshes with texture coordinates.

An object's frame ``o`` is the centre of its axis-aligned box in its resting pose, z up (so an object
resting on the table at z = 0 of b1 has ``T_b1_o`` translation z = size_z / 2). ``size`` is the box's
extents along o's x, y, z, in metres.

Kinds (all textured):
    large_box   30-40 cm long: needs two hands (too wide for one gripper, 1.6-2.6 kg).
    box         a packet, 8-16 cm.
    small_box   3.5-6 cm cube-ish: small enough to pass hand to hand.
    cylinder    a can, 5-7.5 cm across.
    duck        pybullet_data's duck.obj with its own texture, 5.5-7.5 cm long.
    mug         pybullet_data's objects/mug.obj (with handle), 8-10 cm tall.
    bunny       pybullet_data's bunny.obj (Stanford bunny, low poly), 7-10 cm.
    torus       pybullet_data's torus (a ring lying flat), 7-9 cm across.
Mesh kinds missing from the installed pybullet_data are skipped (the catalogue falls back to primitives).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bimanual_app.scene.meshes import CATALOGUE_MESHES, load_catalogue_mesh, pybullet_data

from ._textures import object_texture

# Largest opening of the Piper gripper is 70 mm; leave a margin for a one-hand grasp.
ONE_HAND_MAX_WIDTH = 0.065
ONE_HAND_MAX_MASS = 1.2
TWO_HANDS_MIN_LENGTH = 0.25

# mesh kinds (files and z-up rotations: bimanual_app.scene.meshes): target longest horizontal extent, texture
_MESHES = {
    "duck": ((0.055, 0.075), "duckCM.png"),
    "mug": ((0.08, 0.10), None),
    "bunny": ((0.07, 0.10), None),
    "torus": ((0.07, 0.09), None),
}
MESH_KINDS = tuple(_MESHES)
PRIMITIVE_KINDS = ("large_box", "box", "small_box", "cylinder")


@dataclass
class ObjectSpec:
    """One object before placement.

    Attributes:
        kind: catalogue kind.
        shape: ``"box"``, ``"cylinder"`` or ``"mesh"`` (how PyBullet builds it).
        size: (3,) box extents in o (metres).
        mass: kilograms (volume x a plausible density).
        texture: (H, W, 3) uint8 texture image.
        vertices, faces, uv, normals: the mesh in frame o (``shape == "mesh"``), else None.
        hull: (K, 3) convex-hull vertices in o for the collision shape (meshes), else None.
    """

    kind: str
    shape: str
    size: np.ndarray
    mass: float
    texture: np.ndarray
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    uv: np.ndarray | None = None
    normals: np.ndarray | None = None
    hull: np.ndarray | None = None
    extras: dict = field(default_factory=dict)

    @property
    def footprint_radius(self) -> float:
        """Radius (m) of the circle around o that holds the object's footprint."""
        return float(0.5 * np.hypot(self.size[0], self.size[1]))

    @property
    def fits_gripper(self) -> bool:
        """True when its narrower horizontal side fits in one Piper gripper (<= 65 mm)."""
        return bool(min(self.size[0], self.size[1]) <= ONE_HAND_MAX_WIDTH)

    @property
    def needs_two_hands(self) -> bool:
        """True when one arm cannot carry it: heavier than the payload or longer than 25 cm."""
        return bool(self.mass > ONE_HAND_MAX_MASS or max(self.size[0], self.size[1]) > TWO_HANDS_MIN_LENGTH)


def available_mesh_kinds() -> tuple[str, ...]:
    root = pybullet_data()
    return tuple(k for k in _MESHES if (root / CATALOGUE_MESHES[k][0]).is_file())


def _mesh_spec(kind: str, rng: np.random.Generator) -> ObjectSpec:
    import trimesh
    from PIL import Image

    (lo, hi), tex_name = _MESHES[kind]
    mesh, V = load_catalogue_mesh(kind)
    ext = V.max(0) - V.min(0)
    s = rng.uniform(lo, hi) / max(ext[0], ext[1])
    V = V * s
    centre = 0.5 * (V.max(0) + V.min(0))
    V -= centre
    size = V.max(0) - V.min(0)
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(V):
        # cylindrical projection: u around the vertical axis, v up it
        uv = np.stack([np.arctan2(V[:, 1], V[:, 0]) / (2 * np.pi) + 0.5,
                       (V[:, 2] - V[:, 2].min()) / max(size[2], 1e-9)], axis=1)
    if tex_name is not None:
        texture = np.asarray(Image.open(pybullet_data() / tex_name).convert("RGB"))
    else:
        texture = object_texture(rng)
    tm = trimesh.Trimesh(V, mesh.faces, process=False)
    hull = np.asarray(tm.convex_hull.vertices)
    density = {"duck": 350.0, "mug": 600.0, "bunny": 500.0, "torus": 400.0}[kind]
    mass = float(abs(tm.convex_hull.volume) * density * (0.35 if kind == "mug" else 1.0))
    return ObjectSpec(kind, "mesh", size, round(mass, 4), texture, V, np.asarray(mesh.faces),
                      np.asarray(uv, dtype=np.float64), np.asarray(tm.vertex_normals), hull)


def sample_spec(kind: str, rng: np.random.Generator) -> ObjectSpec:
    """A random object of ``kind`` (sizes in the ranges of the module docstring)."""
    if kind in _MESHES:
        return _mesh_spec(kind, rng)
    tex = object_texture(rng, 512 if kind == "large_box" else 256)
    if kind == "large_box":
        size = np.array([rng.uniform(0.30, 0.40), rng.uniform(0.15, 0.22), rng.uniform(0.08, 0.14)])
        mass = float(rng.uniform(1.6, 2.6))  # a loaded carton: more than one arm's 1.5 kg payload
        return ObjectSpec(kind, "box", size, round(mass, 3), tex)
    if kind == "box":
        size = np.array([rng.uniform(0.08, 0.16), rng.uniform(0.05, 0.10), rng.uniform(0.04, 0.12)])
        return ObjectSpec(kind, "box", size, round(float(np.prod(size) * rng.uniform(250, 450)), 4), tex)
    if kind == "small_box":
        size = rng.uniform(0.035, 0.06, 3)
        return ObjectSpec(kind, "box", size, round(float(np.prod(size) * rng.uniform(300, 600)), 4), tex)
    if kind == "cylinder":
        r, h = rng.uniform(0.025, 0.0375), rng.uniform(0.07, 0.15)
        size = np.array([2 * r, 2 * r, h])
        return ObjectSpec(kind, "cylinder", size, round(float(np.pi * r * r * h * rng.uniform(400, 800)), 4), tex)
    raise ValueError(f"unknown object kind {kind!r}; known: {PRIMITIVE_KINDS + MESH_KINDS}")


def choose_kinds(n: int, rng: np.random.Generator) -> list[str]:
    """Kinds for ``n`` objects: a large box, a small box, a cylinder, a mesh, then a random mix.

    Guarantees (for n >= 4) one object needing two hands, one passable hand to hand, a cylinder and a mesh.
    """
    meshes = list(available_mesh_kinds())
    first = ["large_box", "small_box", "cylinder"] + ([str(rng.choice(meshes))] if meshes else ["box"])
    pool = ["box", "small_box", "cylinder"] + meshes
    kinds = first[:n]
    while len(kinds) < n:
        k = str(rng.choice(pool))
        if k != kinds[-1]:
            kinds.append(k)
    return kinds


def box_mesh(size: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A box centred at the origin with the whole texture on every face.

    PyBullet's built-in box maps only part of a texture onto each face, so textured boxes are drawn as
    this mesh. Returns vertices (24, 3), triangles (12, 3), texture coordinates (24, 2), normals (24, 3).
    """
    h = np.asarray(size, dtype=np.float64) / 2
    V, F, UV, N = [], [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            a, b = [(axis + 1) % 3, (axis + 2) % 3]
            if sign < 0:
                a, b = b, a  # keep the winding counter-clockwise seen from outside
            base = len(V)
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                p = n * h
                p[a] = (2 * du - 1) * h[a]
                p[b] = (2 * dv - 1) * h[b]
                V.append(p)
                UV.append((du, dv))
                N.append(n)
            F += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.array(V), np.array(F), np.array(UV, dtype=np.float64), np.array(N)
