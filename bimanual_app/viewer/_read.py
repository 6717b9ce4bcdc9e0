"""Read a run folder into :class:`RunLayers`: calibration (required), cloud and segments, the capture
views (when the scene folder is found), grasps and task plans (each optional).

An absent part is an absent layer with a note; a part that is present but unreadable raises InputError
naming the file, the field and the fix.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem

from ._find import RunPaths, find_run, find_scene
from ._io import as_T, read_json
from ._results import read_grasps, read_task
from ._types import CameraView, Cloud, RunLayers

__all__ = ["load_run"]

DEFAULT_FOV_Y = math.radians(60.0)  # drawing only: a capture without intrinsics still gets a frustum


def _calibration(path: Path) -> tuple[dict, np.ndarray, dict, np.ndarray | None]:
    """(calibration dict, T_b1_b2, {arm: T_e_c}, 1-sigma of T_b1_b2's translation (3,) m or None)."""
    fix = "re-run `bijcr calibrate SCENE --out DIR` (or `bijcr run`)"
    cal = read_json(path, fix)
    for k in ("T_b1_b2", "T_e1_c1", "T_e2_c2"):
        if k not in cal:
            raise InputError(Problem(str(path), k, "missing", fix))
    T_b1_b2 = as_T(path, "T_b1_b2", cal["T_b1_b2"], fix)
    T_e_c = {"primary": as_T(path, "T_e1_c1", cal["T_e1_c1"], fix),
             "secondary": as_T(path, "T_e2_c2", cal["T_e2_c2"], fix)}
    sigma = None
    u = (cal.get("uncertainty") or {}).get("T_b1_b2") if isinstance(cal.get("uncertainty"), dict) else None
    if isinstance(u, dict) and u.get("translation_mm") is not None:
        try:
            sigma = np.asarray(u["translation_mm"], dtype=np.float64).reshape(3) * 1e-3
        except (TypeError, ValueError):
            raise InputError(Problem(str(path), "uncertainty.T_b1_b2.translation_mm", "not three numbers",
                                     fix)) from None
        if not np.all(np.isfinite(sigma)):
            sigma = None
    return cal, T_b1_b2, T_e_c, sigma


def _cloud(paths: RunPaths, notes: list[str]) -> Cloud | None:
    from grasping import load_cloud, load_segments

    if paths.cloud is None:
        notes.append(f"cloud: no scene_b1.ply beside {paths.calibration}")
        return None
    P, C = load_cloud(paths.cloud)
    labels = None
    if paths.segments is None:
        notes.append("segments: no segments.npz (run `bijcr segment`); the cloud is drawn in its own colours")
    else:
        labels, _ = load_segments(paths.segments)
        labels = np.asarray(labels).reshape(-1)
        if len(labels) != len(P) or not np.issubdtype(labels.dtype, np.integer):
            raise InputError(Problem(str(paths.segments), "labels", f"{len(labels)} labels ({labels.dtype}) for "
                                     f"{len(P)} cloud points in {paths.cloud}", "re-run `bijcr segment` on this cloud"))
        labels = labels.astype(np.int32)
    return Cloud(P, C, labels, paths.cloud)


def _intrinsics(scene, image_path: Path | None) -> tuple[float, float, bool]:
    """(vertical fov rad, aspect, known): scene.yaml's camera, else the image's aspect and a default fov."""
    if scene.camera is not None:
        c = scene.camera
        return 2.0 * math.atan(c.height / (2.0 * c.fy)), c.width / c.height, True
    if image_path is not None:
        from PIL import Image

        with Image.open(image_path) as im:
            return DEFAULT_FOV_Y, im.width / im.height, False
    return DEFAULT_FOV_Y, 4.0 / 3.0, False


def _cameras(scene_dir: Path, cal: dict, T_b1_b2: np.ndarray, T_e_c: dict, notes: list[str]) -> tuple[list, str]:
    """The capture views the calibration used, in b1; and the scene's robot."""
    from bimanual_app.scene import load_scene

    scene = load_scene(scene_dir)
    views = cal.get("views") if isinstance(cal.get("views"), dict) else {}
    out, guessed = [], False
    for arm in scene.arms:
        used = (views.get(arm.name) or {}).get("used") if isinstance(views.get(arm.name), dict) else None
        keep = set(map(str, used)) if isinstance(used, list) else None
        T_b1_b = np.eye(4) if arm.name == "primary" else T_b1_b2
        for i, key in enumerate(arm.images):
            if keep is not None and key not in keep and str(i) not in keep:
                continue
            img = scene_dir / arm.name / key
            img = img if img.is_file() else None
            fov, aspect, known = _intrinsics(scene, img)
            guessed |= not known
            T_b1_e = T_b1_b @ arm.T_b_e[i]
            out.append(CameraView(arm.name, key, T_b1_e, T_b1_e @ T_e_c[arm.name], fov, aspect, img))
    if guessed:
        notes.append(f"cameras: {scene_dir / 'scene.yaml'} gives no intrinsics; frustums drawn with a 60 deg "
                     "field of view")
    if out and all(v.image_path is None for v in out):
        notes.append(f"cameras: the scene {scene_dir} holds no images; frustums drawn without them")
    robot = scene.robot or "piper"
    if robot.lower().endswith(".urdf") and not Path(robot).is_absolute():
        robot = str(scene_dir / robot)  # a scene's URDF path is relative to the scene folder
    return out, robot


def load_run(root: str | Path, scene: str | Path | None = None) -> RunLayers:
    """Read run folder ``root`` (``scene``: the scene folder, when the run does not say where it is)."""
    paths = find_run(root)
    notes: list[str] = []
    cal, T_b1_b2, T_e_c, sigma = _calibration(paths.calibration)
    if sigma is None:
        notes.append("uncertainty: calibration.json has no uncertainty.T_b1_b2.translation_mm; no ellipsoid")
    layers = RunLayers(Path(root), T_b1_b2, T_e_c, sigma, notes=notes)
    layers.cloud = _cloud(paths, notes)
    scene_dir, how = find_scene(paths, cal, scene)
    if scene_dir is None:
        notes.append(f"cameras: {how}")
    else:
        layers.scene_dir = scene_dir
        layers.cameras, layers.robot = _cameras(scene_dir, cal, T_b1_b2, T_e_c, notes)
    if paths.grasps is None:
        notes.append("grasps: no grasps.json (run `bijcr grasp`)")
    else:
        layers.grasps = read_grasps(paths.grasps)
        if not layers.grasps:
            notes.append(f"grasps: {paths.grasps} holds no grasp of any object")
    if not paths.tasks:
        notes.append("tasks: no tasks/<task>/task.json (run `bijcr task` or `bijcr run`)")
    for name, d in paths.tasks.items():
        task, why = read_task(name, d)
        if task is None:
            notes.append(f"task {name}: {why}")
        else:
            layers.tasks.append(task)
    return layers
