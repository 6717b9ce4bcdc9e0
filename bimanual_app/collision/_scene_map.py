"""The scene map: a metric point cloud as a coal octree, plus a distance field for the broad phase.

``coal.makeOctree(points, resolution)`` builds the octree the exact checks run against. The occupied
leaves of that octree (``OcTree.toBoxes``) are rasterised into a voxel grid of the same resolution and
alignment, and an exact Euclidean distance transform (the ``edt`` package: float32, linear time, no
feature transform kept) gives, for every cell centre, the distance to the nearest occupied cell centre,
capped at ``pad``. For any point p in cell c, with h the resolution and e(c) the stored value:

    d(p, occupied) >= e(c) - sqrt(3) h      (lower bound)
    d(p, occupied) <= e(c) + sqrt(3) h / 2  (upper bound, where e(c) < pad)

so one gather per sample point gives conservative answers, and only the undecided band goes to coal.
Points outside the grid (which is padded by ``pad`` around the occupied cells) read ``pad`` too: "at
least ``pad`` away". The cap is what makes a cut cheap: removing points changes the field only within
``pad`` of the removed cells, so :meth:`SceneMap.without` recomputes that box alone.

:func:`shared_scene_map` keeps the maps it builds, by content, for the process: the two tasks of one
``bijcr run`` (and every object a task tries) plan against one map built once.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import check_shape

__all__ = ["SceneMap", "shared_scene_map", "clear_shared_maps"]

SHARED_MAPS = 2  # maps kept by shared_scene_map (each holds a float32 field of the workspace: ~0.2 GB at 5 mm)
_SHARED: OrderedDict[bytes, SceneMap] = OrderedDict()


class SceneMap:
    """Occupancy of the scene in frame b1 (never edited in place: a cut makes a new map).

    Args:
        points: (N,3) metric points in b1 (non-finite rows are dropped).
        resolution: voxel size in metres.
        pad: the distance field extends this far beyond the occupied cells (m); its values are capped here.
        crop: optional (lo (3,), hi (3,)) box; points outside are dropped (far from every arm).
        source: a name for messages (file name).
    """

    def __init__(self, points: np.ndarray, resolution: float = 0.01, pad: float = 0.15,
                 crop: tuple[np.ndarray, np.ndarray] | None = None, source: str = "scene map"):
        P = check_shape("points", np.asarray(points, dtype=np.float64), (None, 3))
        P = P[np.all(np.isfinite(P), axis=1)]
        if crop is not None:
            lo, hi = np.asarray(crop[0], float), np.asarray(crop[1], float)
            P = P[np.all((P >= lo) & (P <= hi), axis=1)]
        if len(P) == 0:
            raise InputError(Problem(source, "points", "the scene map has no points (in the arms' workspace)",
                                     "give the metric scene cloud (scene_b1.ply from `bijcr calibrate`)"))
        if not resolution > 0:
            raise ValueError(f"resolution must be > 0, got {resolution}")
        self.source = source
        self.resolution = h = float(resolution)
        self.pad = float(pad)
        self._set_points(P)
        npad = int(np.ceil(pad / h)) + 1
        self.cell_lo = self.cells.min(axis=0) - npad  # integer cell index of the grid's first cell
        self._set_grid(tuple(int(s) for s in self.cells.max(axis=0) + npad + 1 - self.cell_lo))
        occ_grid = np.zeros(self.shape, dtype=bool)
        idx = self.cells - self.cell_lo
        occ_grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
        self.edt = _capped_edt(~occ_grid, h, self.pad).ravel()

    def _set_points(self, P: np.ndarray) -> None:
        """Points (N,3), their octree, its occupied cells (C,3) int64 and the occupied region (m)."""
        import coal

        h = self.resolution
        self.points = P
        self.octree = coal.makeOctree(P, h)
        self.cells = _occupied_cells(np.asarray(self.octree.toBoxes()), h)
        self.n_cells = len(self.cells)
        self.bounds = (self.cells.min(axis=0) * h, (self.cells.max(axis=0) + 1) * h)  # occupied region (m)
        self.slack_lower = np.sqrt(3.0) * h
        self.slack_upper = np.sqrt(3.0) * h / 2

    def _set_grid(self, shape: tuple[int, int, int]) -> None:
        self.shape = shape
        self._strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
        self._dims = np.array(shape, dtype=np.int64)

    def __len__(self) -> int:
        return len(self.points)

    def lookup(self, P: np.ndarray) -> np.ndarray:
        """Field value of the cell of each point (..., 3) -> (...); ``pad`` outside the grid (conservative)."""
        k = np.floor(P * (1.0 / self.resolution)).astype(np.int64) - self.cell_lo
        inside = np.all((k >= 0) & (k < self._dims), axis=-1)
        flat = np.where(inside, k @ self._strides, 0)
        return np.where(inside, self.edt[flat], np.float32(self.pad))

    def lower_bound(self, P: np.ndarray) -> np.ndarray:
        """(...) lower bound of the distance from points (..., 3) to the occupied cells."""
        return self.lookup(P) - self.slack_lower

    def without(self, mask: np.ndarray) -> SceneMap:
        """A new map without the points where ``mask`` (N,) is True (an object cut out of the scene).

        The same octree and field values as ``SceneMap`` of the remaining points (on this map's grid, which
        is at least as large; cells beyond either grid read ``pad``); only the field within ``pad`` of the
        cells that emptied is recomputed."""
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (len(self.points),):
            raise ValueError(f"mask: expected shape ({len(self.points)},), got {mask.shape}")
        if mask.all():
            raise InputError(Problem(self.source, "points", "the cut leaves the scene map without points",
                                     "cut out less (the object's own points only)"))
        new = object.__new__(SceneMap)
        new.source, new.resolution, new.pad, new.cell_lo = self.source, self.resolution, self.pad, self.cell_lo
        new._set_points(self.points[~mask])
        new._set_grid(self.shape)
        new.edt = _patched_edt(self, new.cells)
        return new

    def near_mask(self, points: np.ndarray, radius: float) -> np.ndarray:
        """(N,) True for the map's points within ``radius`` of any of ``points`` (M,3)."""
        from scipy.spatial import cKDTree

        d, _ = cKDTree(np.asarray(points, dtype=np.float64)).query(self.points, k=1, distance_upper_bound=radius)
        return np.isfinite(d)

    def without_near(self, points: np.ndarray, radius: float) -> SceneMap:
        """A new map without the points within ``radius`` of any of ``points`` (M,3)."""
        return self.without(self.near_mask(points, radius))


def shared_scene_map(points: np.ndarray, resolution: float, pad: float,
                     crop: tuple[np.ndarray, np.ndarray] | None = None, source: str = "scene map") -> SceneMap:
    """``SceneMap(points, resolution, pad, crop, source)``, built once per process for the same arguments
    (points by content): maps are never edited, so every world of a process can plan against the one map.
    Keeps the ``SHARED_MAPS`` most recently used maps; :func:`clear_shared_maps` frees them."""
    P = np.ascontiguousarray(points, dtype=np.float64)
    h = hashlib.sha256(P.tobytes())
    h.update(np.array([P.shape[0], resolution, pad], dtype=np.float64).tobytes())
    if crop is not None:
        h.update(np.asarray(crop, dtype=np.float64).tobytes())
    key = h.digest()
    if key in _SHARED:
        _SHARED.move_to_end(key)
        return _SHARED[key]
    m = SceneMap(P, resolution, pad=pad, crop=crop, source=source)
    _SHARED[key] = m
    while len(_SHARED) > SHARED_MAPS:
        _SHARED.popitem(last=False)
    return m


def clear_shared_maps() -> None:
    """Forget the maps :func:`shared_scene_map` keeps (their memory is freed once no world uses them)."""
    _SHARED.clear()


def _occupied_cells(boxes: np.ndarray, h: float) -> np.ndarray:
    """(C,3) int64 indices (unique, sorted) of the cells of size ``h`` covered by the octree's occupied
    leaves ``boxes`` (B,6: centre, size, occupancy, threshold; pruned leaves can be larger than one cell)."""
    occ = boxes[boxes[:, 4] >= boxes[:, 5]] if len(boxes) else boxes
    cells = []
    for size in np.unique(occ[:, 3]):
        sel = occ[occ[:, 3] == size]
        n = int(round(size / h))
        lo = np.floor((sel[:, :3] - size / 2) / h + 0.5).astype(np.int64)
        if n == 1:
            cells.append(lo)
        else:
            g = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
            cells.append((lo[:, None, :] + g[None]).reshape(-1, 3))
    return np.unique(np.concatenate(cells), axis=0)


def _capped_edt(free: np.ndarray, h: float, cap: float) -> np.ndarray:
    """(X,Y,Z) float32 distance (m) from each cell centre of a grid ``free`` (X,Y,Z) bool to the nearest
    occupied (False) cell centre, capped at ``cap`` (also where the grid has no occupied cell).

    The ``edt`` package computes the exact Euclidean transform in linear time, in float32, with no feature
    transform: scipy's ``distance_transform_edt`` needs one (12 bytes per cell) and was 4x slower on a 5 mm
    map of a workspace. It runs on up to 4 threads (the same values: the lines of each pass are independent;
    1.6 s -> 1.15 s for a 2 m workspace at 5 mm on 2 cores)."""
    import os

    import edt

    threads = max(1, min(4, os.cpu_count() or 1))
    d = edt.edt(np.ascontiguousarray(free), anisotropy=(h, h, h), black_border=False, parallel=threads)
    return np.minimum(d, np.float32(cap), out=d)


def _patched_edt(old: SceneMap, cells: np.ndarray) -> np.ndarray:
    """The flat capped field of ``old``'s grid with occupied cells ``cells`` (C,3), a subset of ``old``'s.

    Cells farther than ``pad`` from every emptied cell keep their value (their nearest occupied cell within
    the cap is still there); the box within ``ncap`` cells of the emptied ones is recomputed from the
    occupied cells within ``ncap`` more (all that can be within ``pad`` of it)."""
    lin_old = (old.cells - old.cell_lo) @ old._strides
    lin_new = (cells - old.cell_lo) @ old._strides
    gone = np.setdiff1d(lin_old, lin_new, assume_unique=True)
    if len(gone) == 0:
        return old.edt
    G = np.stack(np.unravel_index(gone, old.shape), axis=1)
    ncap = int(np.ceil(old.pad / old.resolution)) + 1
    dims = np.array(old.shape)
    u_lo, u_hi = np.maximum(G.min(axis=0) - ncap, 0), np.minimum(G.max(axis=0) + ncap + 1, dims)
    s_lo, s_hi = np.maximum(u_lo - ncap, 0), np.minimum(u_hi + ncap, dims)
    idx = cells - old.cell_lo
    idx = idx[np.all((idx >= s_lo) & (idx < s_hi), axis=1)] - s_lo
    occ = np.zeros(tuple(s_hi - s_lo), dtype=bool)
    occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    d = _capped_edt(~occ, old.resolution, old.pad)
    out = old.edt.copy().reshape(old.shape)
    a, b = u_lo - s_lo, u_hi - s_lo
    out[u_lo[0]:u_hi[0], u_lo[1]:u_hi[1], u_lo[2]:u_hi[2]] = d[a[0]:b[0], a[1]:b[1], a[2]:b[2]]
    return out.ravel()
