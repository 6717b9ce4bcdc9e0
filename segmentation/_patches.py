"""Over-segmentation: voxels -> small, flat, single-coloured patches (the nodes of the contraction graph).

Region growing on normals, vectorised as connected components: two neighbouring voxels join when their
normals agree, both or neither sit on a crease (high surface variation), their colours agree (when known), their
per-view mask ids do not disagree (when known), and both fall in the same cell of a coarse grid. The grid
keeps every patch local (a few cm), so that a patch never runs around a box edge or along a junction
between two objects, and its centroid and normal describe it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ._voxels import voxel_keys

CREASE_VARIATION = 0.06  # surface variation above which a voxel sits on an edge or junction


@dataclass
class Patches:
    """Patches over V voxels.

    Attributes:
        of_voxel: (V,) patch index of each voxel.
        xyz: (P, 3) centroid (table frame).
        normal: (P, 3) unit normal (sign not yet meaningful until oriented).
        nvox: (P,) voxels per patch.
        rgb: (P, 3) mean colour in [0, 1] or None.
        hist: (P, B) colour histogram (chromaticity, soft-binned, voxel counts) or None.
    """

    of_voxel: np.ndarray
    xyz: np.ndarray
    normal: np.ndarray
    nvox: np.ndarray
    rgb: np.ndarray | None
    hist: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.xyz)


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) ``rgb / (r + g + b)``: unchanged by shading (a light that scales all channels)."""
    s = rgb.sum(-1, keepdims=True)
    return rgb / np.maximum(s, 0.05)


HIST_BINS = 6  # chromaticity histogram: HIST_BINS x HIST_BINS cells over (r', g') in [0, 1]^2


def colour_histograms(rgb: np.ndarray) -> np.ndarray:
    """(V, HIST_BINS**2) soft-binned chromaticity histogram of each colour (V, 3) in [0, 1] (rows sum to 1).

    Objects are printed: a region's colours are a mixture (base colour, bands, logos), and two regions of
    one object share that mixture while two objects rarely do. Comparing histograms (intersection) rather
    than mean colours keeps a logo from cutting a box and still tells a red box from a blue one.
    Chromaticity (r, g over r + g + b) ignores shading. Bilinear soft binning avoids bin-edge jumps.
    """
    ch = chromaticity(rgb)[:, :2]
    B = HIST_BINS
    x = np.clip(ch * B - 0.5, 0, B - 1)
    i0 = np.floor(x).astype(np.int64)
    i1 = np.minimum(i0 + 1, B - 1)
    f = x - i0
    H = np.zeros((len(rgb), B * B))
    rows = np.arange(len(rgb))
    for ia, wa in ((i0[:, 0], 1 - f[:, 0]), (i1[:, 0], f[:, 0])):
        for ib, wb in ((i0[:, 1], 1 - f[:, 1]), (i1[:, 1], f[:, 1])):
            np.add.at(H, (rows, ia * B + ib), wa * wb)
    return H


def mask_disagree(mask_vox: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(E,) bool: voxels ``a`` and ``b`` carry different mask ids in at least half the views seeing both."""
    ma, mb = mask_vox[a], mask_vox[b]
    both = (ma >= 0) & (mb >= 0)
    diff = both & (ma != mb)
    nb = both.sum(1)
    return (nb > 0) & (diff.sum(1) * 2 >= nb)


def make_patches(xyz: np.ndarray, normals: np.ndarray, variation: np.ndarray, edges: np.ndarray,
                 cell: float, normal_deg: float, rgb: np.ndarray | None = None, colour_tol: float = 0.08,
                 mask_vox: np.ndarray | None = None) -> Patches:
    """Group voxels (``xyz`` (V, 3), unoriented ``normals`` (V, 3), ``variation`` (V,)) joined by ``edges`` (E, 2)."""
    V = len(xyz)
    a, b = edges[:, 0], edges[:, 1]
    keep = np.abs(np.einsum("ij,ij->i", normals[a], normals[b])) > np.cos(np.deg2rad(normal_deg))
    crease = variation >= CREASE_VARIATION
    keep &= crease[a] == crease[b]  # creases form their own thin patches along edges and junctions
    cells = voxel_keys(xyz, cell)
    keep &= cells[a] == cells[b]
    if rgb is not None:
        ch = chromaticity(rgb)
        keep &= np.linalg.norm(ch[a] - ch[b], axis=1) < colour_tol
    if mask_vox is not None:
        keep &= ~mask_disagree(mask_vox, a, b)
    g = coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(V, V))
    P, of = connected_components(g, directed=False)
    nvox = np.bincount(of, minlength=P).astype(np.int64)
    cen = np.stack([np.bincount(of, xyz[:, k], P) for k in range(3)], 1) / nvox[:, None]
    # patch normal: principal direction of the voxel normals' scatter (sign-free average)
    S = np.zeros((P, 3, 3))
    outer = normals[:, :, None] * normals[:, None, :]
    for i in range(3):
        for j in range(i, 3):
            S[:, i, j] = S[:, j, i] = np.bincount(of, outer[:, i, j], P)
    _, vecs = np.linalg.eigh(S)
    pn = vecs[:, :, 2]
    col = hist = None
    if rgb is not None:
        col = np.stack([np.bincount(of, rgb[:, k], P) for k in range(3)], 1) / nvox[:, None]
        vh = colour_histograms(rgb)
        hist = np.stack([np.bincount(of, vh[:, k], P) for k in range(vh.shape[1])], 1)
    return Patches(of, cen, pn, nvox, col, hist)


def patch_adjacency(of_voxel: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Patch pairs (A, 2) (i < j) joined by at least one voxel edge, and the number of such edges (A,)."""
    pa, pb = of_voxel[edges[:, 0]], of_voxel[edges[:, 1]]
    m = pa != pb
    lo, hi = np.minimum(pa[m], pb[m]), np.maximum(pa[m], pb[m])
    if len(lo) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    P = int(of_voxel.max()) + 1
    key = lo.astype(np.int64) * P + hi
    u, cnt = np.unique(key, return_counts=True)
    return np.stack([u // P, u % P], 1), cnt
