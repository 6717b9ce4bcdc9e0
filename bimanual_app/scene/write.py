"""Write a scene folder's metadata (scene.yaml, ee_poses.csv, reconstruction.npz, ground_truth.yaml).

Every file is written to a temporary name and renamed, so a crash never leaves a file that looks
complete. Images are written by whoever produced them (a capture or ``bijcr synth``).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import yaml

from bimanual_app.io_utils import atomic_open, atomic_path, to_jsonable
from bimanual_app.transforms import check_T, xyz_quat_from_T

from .load import POSE_COLUMNS
from .types import ArmCapture, GroundTruth, Reconstruction, Scene


def _fmt(v: float) -> str:
    return repr(float(v))


def write_ee_poses(path: Path, arm: ArmCapture, as_joints: bool = False) -> None:
    """Write one arm's ee_poses.csv: poses ``T_b_e`` or (``as_joints``) joint angles j1..jJ."""
    with atomic_open(path, "w") as f:
        w = csv.writer(f, lineterminator="\n")
        if as_joints:
            if arm.joints is None:
                raise ValueError(f"{arm.name}: as_joints=True but the capture has no joint angles")
            J = arm.joints.shape[1]
            w.writerow(["image"] + [f"j{i}" for i in range(1, J + 1)])
            for key, q in zip(arm.images, arm.joints):
                w.writerow([key] + [_fmt(v) for v in q])
        else:
            T = check_T(f"{arm.name}.T_b_e", arm.T_b_e)
            xyz, quat = xyz_quat_from_T(T)
            w.writerow(["image"] + POSE_COLUMNS)
            for key, p, q in zip(arm.images, xyz, quat):
                w.writerow([key] + [_fmt(v) for v in p] + [_fmt(v) for v in q])


def write_reconstruction(path: Path, rec: Reconstruction, compress: bool = True) -> None:
    """Write reconstruction.npz (contract keys, plus ``colors`` and any extras)."""
    M = len(rec.arm)
    check_T("T_w_c", rec.T_w_c)
    if rec.T_w_c.shape != (M, 4, 4) or len(rec.image) != M:
        raise ValueError(f"reconstruction: arm ({M},), image {np.shape(rec.image)}, T_w_c {rec.T_w_c.shape} disagree")
    data = {"arm": np.asarray(rec.arm, dtype=np.int64), "image": np.asarray(rec.image, dtype=str),
            "T_w_c": np.asarray(rec.T_w_c, dtype=np.float64), "model": np.array(str(rec.model))}
    if rec.pts3d is not None:
        data["pts3d"] = np.asarray(rec.pts3d, dtype=np.float32)
    if rec.conf is not None:
        data["conf"] = np.asarray(rec.conf, dtype=np.float32)
    if rec.colors is not None:
        data["colors"] = np.asarray(rec.colors, dtype=np.uint8)
    data.update(rec.extras)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            (np.savez_compressed if compress else np.savez)(f, **data)


def write_ground_truth(path: Path, gt: GroundTruth) -> None:
    data = {"T_e1_c1": gt.T_e1_c1, "T_e2_c2": gt.T_e2_c2, "T_b1_b2": gt.T_b1_b2}
    if gt.scale is not None:
        data["scale"] = float(gt.scale)
    if gt.objects:
        data["objects"] = gt.objects
    data.update(gt.extras)
    with atomic_open(path) as f:
        yaml.safe_dump(to_jsonable(data), f, sort_keys=False, default_flow_style=None)


def write_scene(scene: Scene, path: str | Path | None = None, as_joints: bool = False) -> Path:
    """Write ``scene``'s metadata into ``path`` (default ``scene.path``); returns the folder.

    Images are not copied. Files not produced by this call are left untouched.
    """
    root = Path(path if path is not None else scene.path)
    root.mkdir(parents=True, exist_ok=True)
    meta: dict = {"format": 1, "name": scene.name}
    if scene.robot is not None:
        meta["robot"] = scene.robot
    if scene.ee_link is not None:
        meta["ee_link"] = scene.ee_link
    if scene.camera is not None:
        c = scene.camera
        meta["camera"] = {"width": c.width, "height": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy}
    meta.update(scene.extras)
    with atomic_open(root / "scene.yaml") as f:
        yaml.safe_dump(to_jsonable(meta), f, sort_keys=False)
    for arm in scene.arms:
        (root / arm.name).mkdir(exist_ok=True)
        write_ee_poses(root / arm.name / "ee_poses.csv", arm, as_joints=as_joints)
    if scene.reconstruction is not None:
        write_reconstruction(root / "reconstruction.npz", scene.reconstruction)
    if scene.ground_truth is not None:
        write_ground_truth(root / "ground_truth.yaml", scene.ground_truth)
    return root
