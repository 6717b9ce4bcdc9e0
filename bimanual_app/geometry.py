"""Small geometric kernels on point arrays shared by the grasping stage and the physics preview.

Pure functions on numpy arrays; metres.
"""

from __future__ import annotations

import numpy as np

__all__ = ["dominant_plane_offset"]


def dominant_plane_offset(depths: np.ndarray, bin_size: float = 0.005) -> float:
    """The depth (m) of the most populated plane among points at ``depths`` (M,) along a face normal.

    The points whose normal points one way (a box face) are mostly that face's, but a small object
    touching the face and merged into the segment adds a parallel patch a few centimetres out (its own
    front) or in (its sides): the outermost patch and the plain median both move with it. This is the
    histogram's fullest ``bin_size`` bin, refined to the median of the depths within a bin of it.
    """
    d = np.asarray(depths, dtype=np.float64).reshape(-1)
    if d.size == 0:
        raise ValueError("dominant_plane_offset: no depths")
    lo = float(d.min())
    k = np.floor((d - lo) / bin_size).astype(int)
    peak = lo + (np.argmax(np.bincount(k)) + 0.5) * bin_size
    return float(np.median(d[np.abs(d - peak) <= bin_size]))
