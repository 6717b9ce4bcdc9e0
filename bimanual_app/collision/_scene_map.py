"""The scene map: a metric point cloud as a coal octree, plus a distance field for the broad phase.

``coal.makeOctree(points, resolution)`` builds the octree the exact checks run against. The occupied
leaves of that octree (``OcTree.toBoxes``) are rasterised into a voxel grid of the same resolution and
alignment, and ``scipy.ndimage.distance_transform_edt`` gives, for every cell centre, the distance to the
nearest occupied cell centre. For any point p in cell c, with h the resolution:

    d(p, occupied) >= edt(c) - sqrt(3) h      (lower bound)
    d(p, occupied) <= edt(c) + sqrt(3) h / 2  (upper bound)

so one gather per sample point gives conservative answers, and only the undecided band goes to coal.
Points outside the grid (which is padded by ``pad`` around the occupied cells) are at least ``pad`` away.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import check_shape

__all__ = ["SceneMap"]


class SceneMap:
    """Occupancy of the scene in frame b1.

    Args:
        points: (N,3) metric points in b1 (non-finite rows are dropped).
        resolution: voxel size in metres.
        pad: the distance field extends this far beyond the occupied cells (m).
        crop: optional (lo (3,), hi (3,)) box; points outside are dropped (far from every arm).
        source: a name for messages (file name).
    """

    def __init__(self, points: np.ndarray, resolution: float = 0.01, pad: float = 0.15,
                 crop: tuple[np.ndarray, np.ndarray] | None = None, source: str = "scene map"):
        import coal

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
        self.points = P
        self.resolution = h = float(resolution)
        self.octree = coal.makeOctree(P, h)
        boxes = np.asarray(self.octree.toBoxes())
        occ = boxes[boxes[:, 4] >= boxes[:, 5]] if len(boxes) else boxes
        # rasterise the occupied leaves (pruned leaves can be larger than one cell) into cells of size h
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
        cells = np.unique(np.concatenate(cells), axis=0)
        self.n_cells = len(cells)
        self.pad = float(pad)
        npad = int(np.ceil(pad / h)) + 1
        self.cell_lo = cells.min(axis=0) - npad  # integer cell index of the grid's first cell
        shape = cells.max(axis=0) + npad + 1 - self.cell_lo
        occ_grid = np.zeros(shape, dtype=bool)
        idx = cells - self.cell_lo
        occ_grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
        self.shape = tuple(int(s) for s in shape)
        self.edt = _edt(~occ_grid, h).ravel()
        self._strides = np.array([self.shape[1] * self.shape[2], self.shape[2], 1], dtype=np.int64)
        self._dims = np.array(self.shape, dtype=np.int64)
        self.slack_lower = np.sqrt(3.0) * h
        self.slack_upper = np.sqrt(3.0) * h / 2
        self.bounds = ((cells.min(axis=0)) * h, (cells.max(axis=0) + 1) * h)  # occupied region (m)

    def __len__(self) -> int:
        return len(self.points)

    def lookup(self, P: np.ndarray) -> np.ndarray:
        """edt value of the cell of each point (..., 3) -> (...); ``pad`` outside the grid (conservative)."""
        k = np.floor(P * (1.0 / self.resolution)).astype(np.int64) - self.cell_lo
        inside = np.all((k >= 0) & (k < self._dims), axis=-1)
        flat = np.where(inside, k @ self._strides, 0)
        return np.where(inside, self.edt[flat], np.float32(self.pad))

    def lower_bound(self, P: np.ndarray) -> np.ndarray:
        """(...) lower bound of the distance from points (..., 3) to the occupied cells."""
        return self.lookup(P) - self.slack_lower

    def without(self, mask: np.ndarray) -> SceneMap:
        """A new map without the points where ``mask`` (N,) is True (an object cut out of the scene)."""
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (len(self.points),):
            raise ValueError(f"mask: expected shape ({len(self.points)},), got {mask.shape}")
        return SceneMap(self.points[~mask], self.resolution, self.pad, source=self.source)

    def near_mask(self, points: np.ndarray, radius: float) -> np.ndarray:
        """(N,) True for the map's points within ``radius`` of any of ``points`` (M,3)."""
        from scipy.spatial import cKDTree

        d, _ = cKDTree(np.asarray(points, dtype=np.float64)).query(self.points, k=1, distance_upper_bound=radius)
        return np.isfinite(d)

    def without_near(self, points: np.ndarray, radius: float) -> SceneMap:
        """A new map without the points within ``radius`` of any of ``points`` (M,3)."""
        return self.without(self.near_mask(points, radius))


def _edt(free: np.ndarray, h: float, chunk_cells: int = 2_000_000) -> np.ndarray:
    """``scipy.ndimage.distance_transform_edt(free, sampling=h)`` as float32, the same numbers, in a fifth of
    the memory: scipy turns its feature transform (3 int32 per cell) into distances through several
    whole-grid temporaries (about 60 bytes per cell: 700 MB for a 5 mm map of a table); here the same
    arithmetic runs slab by slab along the first axis (about 17 bytes per cell at the peak)."""
    from scipy import ndimage

    ft = ndimage.distance_transform_edt(free, sampling=h, return_distances=False, return_indices=True)
    out = np.empty(free.shape, dtype=np.float32)
    rest = np.indices(free.shape[1:], dtype=np.int32)  # (2, n1, n2)
    step = max(1, chunk_cells // max(1, int(np.prod(free.shape[1:]))))
    for a in range(0, free.shape[0], step):
        b = min(free.shape[0], a + step)
        d = (ft[0, a:b] - np.arange(a, b, dtype=np.int32)[:, None, None]).astype(np.float64) * h
        d2 = d * d
        for k in (1, 2):
            d = (ft[k, a:b] - rest[k - 1][None]).astype(np.float64) * h
            d2 += d * d
        out[a:b] = np.sqrt(d2)
    return out
