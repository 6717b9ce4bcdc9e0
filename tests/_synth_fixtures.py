"""Tiny synthetic scenes (made once per test session) and helpers for checking them.

The fixtures are registered in tests/conftest.py, so a test names them as arguments without importing them
(a fixture imported into a test module is a new fixture of that module, built again for each module).
Tests only read these folders: one that writes puts its output under its own ``tmp_path``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimanual_app.synth import make_synthetic_scene
from bimanual_app.transforms import inv_T


@pytest.fixture(scope="session")
def synth_none(tmp_path_factory) -> Path:
    """Rendered, noise none: 3 views per arm, 3 objects (one touching), seed 11."""
    return make_synthetic_scene(tmp_path_factory.mktemp("synth") / "none", seed=11, views=3, objects=3,
                                noise="none", render=True, progress=False)


@pytest.fixture(scope="session")
def synth_outliers(tmp_path_factory) -> Path:
    """Rendered, noise paper, one outlier view per arm (3 views), coarse point maps, seed 5."""
    return make_synthetic_scene(tmp_path_factory.mktemp("synth") / "outliers", seed=5, views=3, objects=2,
                                noise="paper", outliers=0.3, render=True, pointmap_size=(80, 60), progress=False,
                                preview=False)


@pytest.fixture(scope="session")
def synth_paper(tmp_path_factory) -> Path:
    """Rendered, noise paper, 6 views per arm, 2 objects, point maps 80 x 60, seed 3."""
    return make_synthetic_scene(tmp_path_factory.mktemp("synth") / "paper", seed=3, views=6, objects=2,
                                noise="paper", render=True, pointmap_size=(80, 60), progress=False, preview=False)


def true_T_b1_c(scene) -> np.ndarray:
    """(M, 4, 4) true camera poses in b1, in reconstruction.npz row order, from the ground truth and CSV poses."""
    gt = scene.ground_truth
    rec = scene.reconstruction
    out = []
    for a, key in zip(rec.arm, rec.image):
        arm = scene.arms[int(a) - 1]
        i = arm.images.index(str(key))
        T_b1_b = np.eye(4) if a == 1 else gt.T_b1_b2
        T_e_c = gt.T_e1_c1 if a == 1 else gt.T_e2_c2
        out.append(T_b1_b @ arm.T_b_e[i] @ T_e_c)
    return np.array(out)


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity ``dst ~ s R src + t`` (least squares, Umeyama 1991) from (N, 3) point pairs."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    A, B = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(B.T @ A / len(src))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / (A ** 2).sum(1).mean()
    return float(s), R, mu_d - s * R @ mu_s


def pointmaps_in_b1(scene) -> np.ndarray:
    """(M, h, w, 3) the reconstruction's point maps mapped to b1 with the ground truth (T_w_b1, scale)."""
    gt = scene.ground_truth
    T_b1_w = inv_T(np.array(gt.extras["T_w_b1"], dtype=np.float64))
    P = scene.reconstruction.pts3d.astype(np.float64) * gt.scale
    return P @ T_b1_w[:3, :3].T + T_b1_w[:3, 3]


def reported_T_b1_c(scene) -> np.ndarray:
    """(M, 4, 4) the reconstruction's camera poses mapped to b1 (metric) with the ground truth."""
    gt = scene.ground_truth
    T = scene.reconstruction.T_w_c.copy()
    T[:, :3, 3] *= gt.scale
    return inv_T(np.array(gt.extras["T_w_b1"], dtype=np.float64)) @ T


__all__ = ["synth_none", "synth_outliers", "true_T_b1_c", "umeyama", "pointmaps_in_b1", "reported_T_b1_c"]
