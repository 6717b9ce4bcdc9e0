"""Outward normals: which side of a surface patch is free space, from sky visibility in an occupancy grid.

Convexity needs normals that point out of the objects. A cloud from cameras above a table carries no
viewpoints, and propagating a sign over a k-NN graph (Open3D ``orient_normals_consistent_tangent_plane``)
flips at sharp box edges. Instead: the outside of a patch is the side from which the cameras could have
seen it, i.e. from which rays into the upper half-space escape without hitting other surfaces. For each
patch we start rays a little in front of and a little behind it and keep the side where more escape.
Patches where neither side wins (both open, both closed) take the sign that agrees with their oriented
neighbours, and finally face up.

Rays are not marched one by one: for each of 25 directions with integer steps per grid layer (one layer
up, 0-2 cells sideways), one sweep from the top layer down marks every cell from which that ray is
blocked (``blocked[z] = occupied[z] | blocked[z + 1] shifted``). A ray test is then one look-up.
"""

from __future__ import annotations

import numpy as np


def _steps() -> np.ndarray:
    """(D, 3) integer steps (sx, sy, 1): zenith, 45-55 deg (one cell sideways), 63-71 deg (two cells)."""
    s = [(0, 0)]
    s += [(x, y) for x in (-1, 0, 1) for y in (-1, 0, 1) if (x, y) != (0, 0)]
    s += [(x, y) for x in (-2, 0, 2) for y in (-2, 0, 2) if (x, y) != (0, 0)]
    s += [(2, 1), (2, -1), (-2, 1), (-2, -1), (1, 2), (-1, 2), (1, -2), (-1, -2)]
    return np.array([(x, y, 1) for x, y in s], dtype=np.int64)


STEPS = _steps()
DIRECTIONS = STEPS / np.linalg.norm(STEPS, axis=1, keepdims=True)


def _shift_xy(a: np.ndarray, sx: int, sy: int) -> np.ndarray:
    """``out[i, j] = a[i + sx, j + sy]`` (False outside)."""
    out = np.zeros_like(a)
    nx, ny = a.shape
    xs, xd = (slice(sx, nx), slice(0, nx - sx)) if sx >= 0 else (slice(0, nx + sx), slice(-sx, nx))
    ys, yd = (slice(sy, ny), slice(0, ny - sy)) if sy >= 0 else (slice(0, ny + sy), slice(-sy, ny))
    out[xd, yd] = a[xs, ys]
    return out


def blocked_grids(occ: np.ndarray) -> np.ndarray:
    """(D, nx, ny, nz) bool: a ray along ``STEPS[d]`` starting in the cell hits an occupied cell.

    Rays that jump two cells sideways per layer test a horizontally dilated grid, so they do not slip
    through a one-cell wall.
    """
    from scipy.ndimage import binary_dilation

    D = len(STEPS)
    nz = occ.shape[2]
    occ_wide = binary_dilation(occ, structure=np.ones((3, 3, 1), bool))
    out = np.zeros((D,) + occ.shape, bool)
    for d, (sx, sy, _) in enumerate(STEPS):
        o = occ_wide if max(abs(sx), abs(sy)) > 1 else occ
        b = out[d]
        b[:, :, nz - 1] = o[:, :, nz - 1]
        for z in range(nz - 2, -1, -1):
            b[:, :, z] = o[:, :, z] | _shift_xy(b[:, :, z + 1], int(sx), int(sy))
    return out


def orient_patches(centroids: np.ndarray, normals: np.ndarray, occupied_xyz: np.ndarray, cell: float,
                   adjacency: np.ndarray | None = None) -> np.ndarray:
    """Flip ``normals`` (P, 3, table frame, z up) of patches at ``centroids`` (P, 3) to point outwards.

    ``occupied_xyz`` (V, 3) are the surface samples (voxel centroids) that block rays, rasterised at
    ``cell``. ``adjacency`` (E, 2) patch pairs settle the patches the rays leave undecided. Returns the
    oriented normals (P, 3).
    """
    P = len(centroids)
    n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    if P == 0:
        return n
    lo = occupied_xyz.min(0) - 3 * cell
    hi = occupied_xyz.max(0) + 3 * cell
    shape = np.ceil((hi - lo) / cell).astype(int) + 1
    occ = np.zeros(shape, bool)
    ijk = np.floor((occupied_xyz - lo) / cell).astype(int)
    occ[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    blocked = blocked_grids(occ)
    delta = 1.5 * cell
    score = np.zeros((P, 2))
    for side, sign in enumerate((1.0, -1.0)):
        start = np.floor((centroids + sign * delta * n - lo) / cell).astype(np.int64)  # (P, 3)
        nxt = start[:, None, :] + STEPS[None, :, :]  # (P, D, 3): the first cell along each ray
        inside = np.all((nxt >= 0) & (nxt < shape), axis=-1)
        hit = np.zeros(inside.shape, bool)
        pi, di = np.nonzero(inside)
        c = nxt[pi, di]
        hit[pi, di] = blocked[di, c[:, 0], c[:, 1], c[:, 2]]
        eligible = (sign * n) @ DIRECTIONS.T > 0.2  # rays leaving into this side's half-space
        cnt = eligible.sum(1)
        score[:, side] = np.where(cnt > 0, (~hit & eligible).sum(1) / np.maximum(cnt, 1), 0.0)
    sign = np.zeros(P)
    margin = 0.15
    sign[score[:, 0] > score[:, 1] + margin] = 1.0
    sign[score[:, 1] > score[:, 0] + margin] = -1.0
    n = n * np.where(sign == 0, 1.0, sign)[:, None]
    # undecided: vote of decided neighbours whose normals are within 60 degrees (either sign)
    if adjacency is not None and len(adjacency) and np.any(sign == 0):
        a, b = adjacency[:, 0], adjacency[:, 1]
        for _ in range(3):
            und = sign == 0
            if not und.any():
                break
            dot = np.einsum("ij,ij->i", n[a], n[b])
            strong = np.abs(dot) > 0.5
            vote = np.zeros(P)
            m = strong & und[a] & ~und[b]
            np.add.at(vote, a[m], np.sign(dot[m]))
            m = strong & und[b] & ~und[a]
            np.add.at(vote, b[m], np.sign(dot[m]))
            flip = und & (vote < 0)
            n[flip] *= -1.0
            sign[und & (vote != 0)] = 1.0
    rest = (sign == 0) & (n[:, 2] < 0)
    n[rest] *= -1.0
    return n
