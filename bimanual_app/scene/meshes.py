"""The catalogue meshes that ground-truth objects name (``shape: mesh``, ``kind`` duck / mug / bunny / torus).

Which pybullet_data file each kind is and how it is turned z-up; :func:`mesh_hull` gives the convex hull
at a ground-truth ``size``, the collision shape the synthetic scene was simulated with. Shared by the
generator (``bimanual_app.synth``) and the readers of ground truth (the physics preview).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

# kind: file in pybullet_data, rotation to z-up (rotation vector)
CATALOGUE_MESHES = {
    "duck": ("duck.obj", (np.pi / 2, 0.0, 0.0)),
    "mug": ("objects/mug.obj", (0.0, 0.0, 0.0)),
    "bunny": ("bunny.obj", (np.pi / 2, 0.0, 0.0)),
    "torus": ("torus/torus_textured.obj", (np.pi / 2, 0.0, 0.0)),
}


def pybullet_data() -> Path:
    """The folder of the installed pybullet_data package."""
    import pybullet_data as data

    return Path(data.getDataPath())


def load_catalogue_mesh(kind: str):
    """``(trimesh.Trimesh as stored, vertices (V, 3) float64 turned z-up)`` of catalogue mesh ``kind``.

    Raises ValueError for an unknown kind or a missing mesh file.
    """
    import trimesh

    from bimanual_app.transforms import so3_exp

    if kind not in CATALOGUE_MESHES:
        raise ValueError(f"{kind!r} is not a catalogue mesh ({', '.join(CATALOGUE_MESHES)})")
    fname, rotvec = CATALOGUE_MESHES[kind]
    path = pybullet_data() / fname
    if not path.is_file():
        raise ValueError(f"mesh file {path} not found")
    mesh = trimesh.load(path, force="mesh", process=False)
    return mesh, np.asarray(mesh.vertices, dtype=np.float64) @ so3_exp(np.array(rotvec)).T


def mesh_hull(kind: str, size) -> np.ndarray:
    """(K, 3) convex-hull vertices, in the object frame o, of catalogue mesh ``kind`` scaled to the box
    ``size`` (3,) that ground_truth.yaml records: the collision shape the scene was simulated with (a
    uniform scale, centred on the bounding box). Raises ValueError for an unknown kind, a missing mesh
    file, or a size no uniform scale of the mesh gives."""
    import trimesh

    _, V = load_catalogue_mesh(kind)
    ext = V.max(0) - V.min(0)
    size = np.asarray(size, dtype=np.float64).reshape(3)
    s = size / np.maximum(ext, 1e-12)
    if np.ptp(s) > 0.01 * s.mean():
        raise ValueError(f"size {size.tolist()} is not a uniform scale of the {kind} mesh")
    V = V * s.mean()
    V -= 0.5 * (V.max(0) + V.min(0))
    return np.asarray(trimesh.Trimesh(V, process=False).convex_hull.vertices)
