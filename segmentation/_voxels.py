"""Voxel nodes of the graph: down-sampling with a point -> voxel map, neighbours, normals."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass
class Voxels:
    """Occupied voxels of a cloud.

    Attributes:
        inverse: (M,) voxel index of each input point (labels go back to points through this map: exact
            and O(M), faster than a KD-tree query for 2M points).
        xyz: (V, 3) centroid of each voxel's points.
        count: (V,) points per voxel.
        rgb: (V, 3) mean colour in [0, 1], or None.
        size: the voxel edge (m).
    """

    inverse: np.ndarray
    xyz: np.ndarray
    count: np.ndarray
    rgb: np.ndarray | None
    size: float

    def __len__(self) -> int:
        return len(self.xyz)


def voxel_keys(points: np.ndarray, size: float) -> np.ndarray:
    """(M,) int64 key of the voxel holding each point (M, 3)."""
    q = np.floor(points / size).astype(np.int64)
    q -= q.min(0)
    dims = q.max(0) + 1
    return (q[:, 0] * dims[1] + q[:, 1]) * dims[2] + q[:, 2]


def voxelize(points: np.ndarray, size: float, rgb: np.ndarray | None = None) -> Voxels:
    """Down-sample ``points`` (M, 3) to voxel centroids; ``rgb`` (M, 3) uint8 or None.

    Hand-written (numpy ``unique`` + ``bincount``) rather than Open3D's ``voxel_down_sample_and_trace``
    because we need the point -> voxel map as one flat array for the label propagation.
    """
    keys = voxel_keys(points, size)
    _, inv, count = np.unique(keys, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    V = len(count)
    xyz = np.stack([np.bincount(inv, points[:, k], V) for k in range(3)], 1) / count[:, None]
    col = None
    if rgb is not None:
        c = rgb.astype(np.float64) / 255.0
        col = np.stack([np.bincount(inv, c[:, k], V) for k in range(3)], 1) / count[:, None]
    return Voxels(inv, xyz, count, col, size)


def knn_edges(xyz: np.ndarray, k: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges (E, 2) int (i < j) joining each node to its ``k`` nearest within ``radius``.

    Returns ``(edges, length)``: the index pairs and their lengths (E,).
    """
    tree = cKDTree(xyz)
    d, j = tree.query(xyz, k=k + 1, distance_upper_bound=radius, workers=-1)
    i = np.repeat(np.arange(len(xyz)), k + 1).reshape(len(xyz), k + 1)
    ok = np.isfinite(d) & (j != i) & (j < len(xyz))
    a, b = i[ok], j[ok]
    e = np.stack([np.minimum(a, b), np.maximum(a, b)], 1)
    if len(e) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    e = np.unique(e, axis=0)
    return e, np.linalg.norm(xyz[e[:, 0]] - xyz[e[:, 1]], axis=1)


def median_spacing(xyz: np.ndarray) -> float:
    """Median distance (m) from a node to its nearest other node."""
    if len(xyz) < 2:
        return 0.0
    step = max(1, len(xyz) // 20000)
    d, _ = cKDTree(xyz).query(xyz[::step], k=2, workers=-1)
    return float(np.median(d[:, 1]))


def normals_and_curvature(xyz: np.ndarray, radius: float, k: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Unoriented unit normals (V, 3) and surface variation (V,) of ``xyz`` (V, 3).

    PCA of each node's neighbourhood (``k`` nearest within ``radius``): the normal is the smallest
    eigenvector, the surface variation ``l0 / (l0 + l1 + l2)`` (0 on a plane, 1/3 for isotropic noise).
    Written out (batched ``eigh``) because Open3D's ``estimate_normals`` does not return the variation.
    """
    V = len(xyz)
    tree = cKDTree(xyz)
    d, j = tree.query(xyz, k=min(k, V), distance_upper_bound=radius, workers=-1)
    if j.ndim == 1:
        d, j = d[:, None], j[:, None]
    w = np.isfinite(d).astype(np.float64)
    j = np.where(j < V, j, 0)
    P = xyz[j]  # (V, k, 3)
    wsum = np.maximum(w.sum(1), 1.0)
    mu = (P * w[..., None]).sum(1) / wsum[:, None]
    D = (P - mu[:, None, :]) * np.sqrt(w)[..., None]
    C = np.einsum("vki,vkj->vij", D, D) / wsum[:, None, None]
    evals, evecs = np.linalg.eigh(C)
    n = evecs[:, :, 0]
    var = evals[:, 0] / np.maximum(evals.sum(1), 1e-18)
    few = w.sum(1) < 3
    n[few] = [0.0, 0.0, 1.0]
    var[few] = 1.0 / 3.0
    return n, var
