"""The true metric point cloud of a scene with rendered ground truth, in b1, with per-point object labels.

Recomputed from what a synthetic scene stores for evaluation (``ground_truth.yaml`` ``synthetic.depth``):
the ground-truth depth PNGs (table and object surfaces only), the masks, the images, the ee poses and the
true hand-eye and base transforms.
Nothing here reads reconstruction.npz (whose point maps are perturbed on purpose).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem


def _read(path: Path) -> np.ndarray:
    from PIL import Image

    if not path.is_file():
        raise InputError(Problem(str(path), "", "file is missing", "re-generate the scene with bijcr synth"))
    return np.asarray(Image.open(path))


def _rendered_depth(scene) -> tuple[int, float, str]:
    """``(stride, metres per unit, folder)`` of a loaded scene's ground-truth depth maps (ground_truth.yaml
    ``synthetic.depth``); InputError when it has none (not a rendered synthetic scene) or no camera."""
    gt = scene.ground_truth
    info = ((gt.extras.get("synthetic") if gt is not None else None) or {}).get("depth")
    if not info or scene.camera is None:
        raise InputError(Problem(str(scene.path / "ground_truth.yaml"), "synthetic.depth",
                                 "no ground-truth depth: not a rendered synthetic scene",
                                 "generate it with bijcr synth (without --no-render)"))
    return int(info["stride"]), float(info["units_m"]), str(info.get("folder", "depth"))


def ground_truth_cloud(scene_path: str | Path, stride: int = 1, max_depth: float | None = None,
                       voxel: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True cloud of a rendered synthetic scene.

    Args:
        scene_path: a folder made by ``bijcr synth`` (with rendering).
        stride: keep every ``stride``-th pixel of the stored depth maps (which already keep every
            ``synthetic.depth.stride``-th image pixel).
        max_depth: drop points farther than this from their camera (m); None keeps all.
        voxel: if given, keep one point per cube of this edge (m), the first seen.
    Returns:
        ``points_b1`` (N, 3) float64 metres in b1, ``colors`` (N, 3) uint8 (from the images), ``labels``
        (N,) int32: object id k (ground_truth.yaml ``objects``), -1 for the table and the floor. Robots
        and cameras are not part of it.
    """
    from .load import load_scene

    scene = load_scene(scene_path)
    gt = scene.ground_truth
    s, units, folder = _rendered_depth(scene)
    K = scene.camera.K
    T_b1_b = [np.eye(4), gt.T_b1_b2]
    T_e_c = [gt.T_e1_c1, gt.T_e2_c2]
    pts, cols, labs = [], [], []
    for a, arm in enumerate(scene.arms):
        for i, key in enumerate(arm.images):
            stem = Path(key).stem
            depth = _read(scene.path / arm.name / folder / f"{stem}.png").astype(np.float64) * units
            mask = _read(scene.path / arm.name / "masks" / f"{stem}.png")
            rgb = _read(scene.path / arm.name / key)[..., :3]
            h, w = depth.shape
            vv, uu = np.mgrid[0:h:stride, 0:w:stride]
            z = depth[vv, uu]
            ok = z > 0
            if max_depth is not None:
                ok &= z <= max_depth
            u_img, v_img = uu[ok] * s, vv[ok] * s
            z = z[ok]
            P_c = np.stack([(u_img - K[0, 2]) / K[0, 0] * z, (v_img - K[1, 2]) / K[1, 1] * z, z], axis=1)
            T_b1_c = T_b1_b[a] @ arm.T_b_e[i] @ T_e_c[a]
            pts.append(P_c @ T_b1_c[:3, :3].T + T_b1_c[:3, 3])
            cols.append(rgb[v_img, u_img])
            labs.append(mask[v_img, u_img].astype(np.int32) - 1)
    P = np.concatenate(pts)
    C = np.concatenate(cols).astype(np.uint8)
    L = np.concatenate(labs).astype(np.int32)
    if voxel is not None and len(P):
        _, first = np.unique(np.floor(P / voxel).astype(np.int64), axis=0, return_index=True)
        first = np.sort(first)
        P, C, L = P[first], C[first], L[first]
    return P, C, L


def ground_truth_views(scene_path: str | Path):
    """The true depth views of a rendered synthetic scene (:class:`bimanual_app.views.DepthViews`): each image's
    true camera pose in b1, the camera's intrinsics at the stored depth maps' stride, and their depth (NaN
    where the ray meets a robot, a camera or nothing), in the order of :func:`ground_truth_cloud`'s views."""
    from bimanual_app.views import DepthViews

    from .load import load_scene

    scene = load_scene(scene_path)
    gt = scene.ground_truth
    s, units, folder = _rendered_depth(scene)
    K = scene.camera.K
    # a depth pixel (i, j) is image pixel (s j, s i): col = (fx x / z + cx) / s
    K_map = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]) / s
    T_b1_b, T_e_c = [np.eye(4), gt.T_b1_b2], [gt.T_e1_c1, gt.T_e2_c2]
    poses, depths, arms = [], [], []
    for a, arm in enumerate(scene.arms):
        for i, key in enumerate(arm.images):
            z = _read(scene.path / arm.name / folder / f"{Path(key).stem}.png").astype(np.float64) * units
            depths.append(np.where(z > 0, z, np.nan).astype(np.float32))
            poses.append(T_b1_b[a] @ arm.T_b_e[i] @ T_e_c[a])
            arms.append(a + 1)
    return DepthViews(np.array(poses), np.tile(K_map, (len(poses), 1)), np.array(depths), np.array(arms, dtype=np.int64))
