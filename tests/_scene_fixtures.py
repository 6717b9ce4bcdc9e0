"""Small, valid scene folders built in code (no rendering) for I/O tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from bimanual_app.scene import ArmCapture, CameraIntrinsics, GroundTruth, Reconstruction, Scene, write_scene
from bimanual_app.transforms import make_T, so3_exp


def random_ee_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4, 4) plausible table-top T_b_e: 0.2-0.5 m from the base, varied orientations."""
    t = np.stack([rng.uniform(0.2, 0.4, n), rng.uniform(-0.2, 0.2, n), rng.uniform(0.15, 0.4, n)], 1)
    R = so3_exp(rng.normal(scale=0.6, size=(n, 3)))
    return make_T(R, t)


def make_scene(root: Path, n: int = 5, seed: int = 0, images: bool = True, reconstruction: bool = True,
               pointmaps: bool = True) -> Scene:
    """Write a consistent scene with ground truth to ``root`` and return it."""
    rng = np.random.default_rng(seed)
    T_e1_c1 = make_T(so3_exp(np.array([0.1, -0.2, 0.05])), [0.03, -0.05, 0.06])
    T_e2_c2 = make_T(so3_exp(np.array([-0.1, 0.15, 0.1])), [-0.02, 0.05, 0.07])
    T_b1_b2 = make_T(so3_exp(np.array([0.0, 0.0, np.pi])), [0.6, 0.02, 0.0])
    scale = 0.7
    T_w_b1 = make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    arms, T_w_c, arm_idx, keys = [], [], [], []
    for a, (name, X, T_b1_b) in enumerate([("primary", T_e1_c1, np.eye(4)), ("secondary", T_e2_c2, T_b1_b2)], 1):
        T_b_e = random_ee_poses(rng, n)
        ims = [f"images/{i:03d}.png" for i in range(n)]
        arms.append(ArmCapture(name, ims, T_b_e))
        Twc = T_w_b1 @ T_b1_b @ T_b_e @ X
        Twc[:, :3, 3] /= scale
        T_w_c.append(Twc)
        arm_idx += [a] * n
        keys += ims
    rec = None
    if reconstruction:
        M = 2 * n
        pts = rng.normal(size=(M, 12, 16, 3)).astype(np.float32) if pointmaps else None
        conf = np.ones((M, 12, 16), np.float32) if pointmaps else None
        rec = Reconstruction(np.array(arm_idx), np.array(keys), np.concatenate(T_w_c), pts, conf, "synthetic")
    T_w_b1_metric = T_w_b1
    gt = GroundTruth(T_e1_c1, T_e2_c2, T_b1_b2, scale, extras={"T_w_b1": T_w_b1_metric.tolist()})
    scene = Scene(root, "fixture", arms[0], arms[1], robot="piper",
                  camera=CameraIntrinsics(64, 48, 60.0, 60.0, 32.0, 24.0), reconstruction=rec, ground_truth=gt)
    write_scene(scene, root)
    if images:
        for arm in scene.arms:
            for k in arm.images:
                p = root / arm.name / k
                p.parent.mkdir(parents=True, exist_ok=True)
                Image.fromarray(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)).save(p)
    return scene
