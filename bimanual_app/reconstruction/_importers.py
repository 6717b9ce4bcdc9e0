"""Import what a GPU user ran elsewhere (DUSt3R, MASt3R, VGGT, Ray Diffusion) into reconstruction.npz.

The user runs ``tools/export_<model>.py`` inside that project's own environment; it writes one ``.npz``
in the *export layout* (format 1, documented in docs/reconstruction.md and checked here):

| key | shape, dtype | meaning |
| --- | --- | --- |
| ``format`` | () int | 1 |
| ``model`` | () str | ``dust3r`` / ``mast3r`` / ``vggt`` / ``raydiffusion`` |
| ``image`` | (N,) str | image paths in the model's order; scene-relative (``primary/images/000.png``) or any path ending so |
| ``orig_size`` | (N, 2) int | [W, H] of each original image |
| ``model_size`` | (N, 2) int | [W, H] of the image the model ran on (= its point map) |
| ``crop_box`` | (N, 4) float | [x0, y0, x1, y1]: region of the original image (pixel-edge coordinates) that the model image covers; outside 0..W/0..H where the model input was padded |
| ``cam2world`` | (N, 4, 4) float | dust3r / mast3r: camera-to-world poses (OpenCV camera axes) |
| ``extrinsic`` | (N, 3, 4) float | vggt: world-to-camera [R | t] (OpenCV camera axes) |
| ``R``, ``T`` | (N, 3, 3), (N, 3) float | raydiffusion: PyTorch3D cameras, ``X_view = X_world @ R + T``, view axes x left, y up, z forward |
| ``pts3d`` | (N, Hm, Wm, 3) float | world points per model pixel (not raydiffusion); maps smaller than (Hm, Wm) are zero-padded at the bottom/right |
| ``conf`` | (N, Hm, Wm) float | confidence per model pixel, higher is better, 0 in padding |
| ``K_model`` | (N, 3, 3) float, optional | intrinsics in model pixels (OpenCV) |
| ``images`` | (N, Hm, Wm, 3) uint8, optional | the model's input images (colours when the scene has no images) |

The importer matches each entry to an ``ee_poses.csv`` row by its path, converts the poses to
camera-to-world (OpenCV), and resamples the point maps onto the reduced full-image grid of the contract
(``_pointmap``): a map cell takes the model pixel that covers the same spot of the original image
(nearest), or confidence 0 where the model did not see that part (cropped away).
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.scene import ARM_INDEX, Reconstruction, Scene
from bimanual_app.transforms import check_T, inv_T, make_T, project_to_SO3

from ._images import read_rgb
from ._pointmap import box_to_model, default_map_size, grid_pixels, intrinsics_from_box, resize_colors, sample_nearest

__all__ = ["IMPORT_MODELS", "EXPORT_FORMAT", "load_export", "import_export", "poses_to_T_w_c", "match_images"]

EXPORT_FORMAT = 1
IMPORT_MODELS = ("dust3r", "mast3r", "vggt", "raydiffusion")
POSE_KEYS = {"dust3r": ("cam2world",), "mast3r": ("cam2world",), "vggt": ("extrinsic",), "raydiffusion": ("R", "T")}
# PyTorch3D view axes (x left, y up, z forward) -> OpenCV (x right, y down, z forward)
P3D_TO_CV = np.diag([-1.0, -1.0, 1.0])


def _problem(path: Path, key: str, msg: str, fix: str) -> Problem:
    return Problem(str(path), key, msg, fix)


def load_export(path: Path, model: str) -> dict:
    """Read and check an export file; raise :class:`InputError` naming the file, the key and the fix."""
    path = Path(path)
    tool = f"tools/export_{model}.py"
    if not path.is_file():
        raise InputError(_problem(path, "", "export file is missing",
                                  f"run {tool} in the {model} environment and pass its output with --input"))
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except Exception as e:  # zip errors, pickled objects, truncated files
        raise InputError(_problem(path, "", f"cannot be read as .npz: {e}", f"re-run {tool}")) from None
    probs: list[Problem] = []
    for k in ("format", "model"):
        if k not in data:
            raise InputError(_problem(path, k, "required key is missing", f"re-run {tool} (see docs/reconstruction.md)"))
    if int(data["format"]) != EXPORT_FORMAT:
        raise InputError(_problem(path, "format", f"format {int(data['format'])} is not {EXPORT_FORMAT}",
                                  f"re-run {tool} from this checkout"))
    got = str(data["model"])
    if got != model:
        raise InputError(_problem(path, "model", f"file was written for '{got}', not '{model}'", f"use --backend {got}"))
    need = ["image", "orig_size", "model_size", "crop_box", *POSE_KEYS[model]]
    if model != "raydiffusion":
        need += ["pts3d", "conf"]
    for k in need:
        if k not in data:
            probs.append(_problem(path, k, "required key is missing", f"re-run {tool} (see docs/reconstruction.md)"))
    if probs:
        raise InputError(probs)
    N = len(data["image"])
    shapes = {"orig_size": (N, 2), "model_size": (N, 2), "crop_box": (N, 4), "cam2world": (N, 4, 4),
              "extrinsic": (N, 3, 4), "R": (N, 3, 3), "T": (N, 3), "K_model": (N, 3, 3)}
    for k, shp in shapes.items():
        if k in data and data[k].shape != shp:
            probs.append(_problem(path, k, f"shape {data[k].shape}, expected {shp} (N={N} images)", f"re-run {tool}"))
    if "pts3d" in data:
        p = data["pts3d"]
        if p.ndim != 4 or p.shape[0] != N or p.shape[3] != 3:
            probs.append(_problem(path, "pts3d", f"shape {p.shape}, expected (N={N}, Hm, Wm, 3)", f"re-run {tool}"))
        elif "conf" in data and data["conf"].shape != p.shape[:3]:
            probs.append(_problem(path, "conf", f"shape {data['conf'].shape}, expected {p.shape[:3]}", f"re-run {tool}"))
        if "images" in data and (data["images"].shape != p.shape or data["images"].dtype != np.uint8):
            probs.append(_problem(path, "images", f"must be uint8 {p.shape}, got {data['images'].dtype} {data['images'].shape}",
                                  f"re-run {tool}"))
    if probs:
        raise InputError(probs)
    box = data["crop_box"].astype(np.float64)
    if np.any(box[:, 2] <= box[:, 0]) or np.any(box[:, 3] <= box[:, 1]):
        raise InputError(_problem(path, "crop_box", "x1 <= x0 or y1 <= y0", "boxes are [x0, y0, x1, y1] in original pixels"))
    return data


def poses_to_T_w_c(data: dict, model: str) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4), OpenCV camera axes, from an export's poses in its model's convention.

    - dust3r / mast3r: ``cam2world`` is already camera-to-world (OpenCV axes).
    - vggt: ``extrinsic`` [R | t] is world-to-camera: ``T_w_c = inv([R | t; 0 0 0 1])``.
    - raydiffusion: PyTorch3D ``X_view = X_world @ R + T`` with view axes x left, y up: in columns
      ``x_cv = F (R^T x_world + T)``, ``F = diag(-1, -1, 1)``, so ``T_c_w = [F R^T | F T]``, inverted.
    Rotations are re-orthonormalised (models store float32).
    """
    if model in ("dust3r", "mast3r"):
        T = np.asarray(data["cam2world"], dtype=np.float64)
        T = make_T(project_to_SO3(T[:, :3, :3]), T[:, :3, 3])
    elif model == "vggt":
        E = np.asarray(data["extrinsic"], dtype=np.float64)
        T = inv_T(make_T(project_to_SO3(E[:, :3, :3]), E[:, :3, 3]))
    elif model == "raydiffusion":
        R = np.asarray(data["R"], dtype=np.float64)
        t = np.asarray(data["T"], dtype=np.float64)
        R_c_w = P3D_TO_CV @ np.swapaxes(R, -1, -2)
        t_c_w = t @ P3D_TO_CV.T
        T = inv_T(make_T(project_to_SO3(R_c_w), t_c_w))
    else:
        raise ValueError(f"unknown model {model!r}")
    return T


def match_images(names: list[str], scene: Scene, source: Path) -> list[tuple[str, str]]:
    """(arm, image key) of each export entry, matched to the scene's ee_poses.csv rows by path.

    An entry matches a row when it equals ``<arm>/<key>`` or ends with ``/<arm>/<key>``; a bare file name
    matches when exactly one row of the two arms ends with it. Raises :class:`InputError` listing every
    entry that matches no row, matches several, or repeats.
    """
    rows = [(arm.name, key, f"{arm.name}/{key}") for arm in scene.arms for key in arm.images]
    probs, out, seen = [], [], {}
    for i, raw in enumerate(names):
        name = str(PurePosixPath(str(raw).replace("\\", "/")))
        hits = [(a, k) for a, k, full in rows if name == full or name.endswith("/" + full)]
        if not hits:
            hits = [(a, k) for a, k, full in rows if PurePosixPath(full).name == PurePosixPath(name).name]
            if len(hits) > 1:
                probs.append(_problem(source, f"image[{i}]", f"'{raw}' matches {len(hits)} rows ("
                                      + ", ".join(f"{a}/{k}" for a, k in hits) + ")",
                                      "export with scene-relative paths (run the exporter on the scene folder)"))
                continue
        if not hits:
            probs.append(_problem(source, f"image[{i}]", f"'{raw}' matches no row of primary/ or secondary/ee_poses.csv",
                                  "export the images of this scene (paths must end with <arm>/<image key>)"))
            continue
        if hits[0] in seen:
            probs.append(_problem(source, f"image[{i}]", f"'{raw}' is the same image as entry {seen[hits[0]]}",
                                  "export each image once"))
            continue
        seen[hits[0]] = i
        out.append(hits[0])
    if probs:
        raise InputError(probs)
    return out


def import_export(scene: Scene, path: Path, model: str, map_width: int = 160) -> tuple[Reconstruction, dict]:
    """Turn an export file into a :class:`Reconstruction` of ``scene`` (not written; see ``_output``).

    Returns the reconstruction (rows in CSV order, primary first) and an info dict.
    """
    if model not in IMPORT_MODELS:
        raise ValueError(f"unknown model {model!r}; one of {IMPORT_MODELS}")
    data = load_export(path, model)
    names = [str(s) for s in data["image"]]
    matched = match_images(names, scene, Path(path))
    T_w_c = poses_to_T_w_c(data, model)
    try:
        check_T("T_w_c", T_w_c, tol=1e-6)
    except ValueError as e:
        raise InputError(_problem(Path(path), POSE_KEYS[model][0], f"not usable poses: {e}", "re-run the exporter")) from None
    order = sorted(range(len(matched)), key=lambda i: (ARM_INDEX[matched[i][0]],
                                                        scene.arms[ARM_INDEX[matched[i][0]] - 1].images.index(matched[i][1])))
    arm = np.array([ARM_INDEX[matched[i][0]] for i in order], dtype=np.int64)
    image = np.array([matched[i][1] for i in order])
    rec = Reconstruction(arm=arm, image=image, T_w_c=T_w_c[order], model=model)
    info = {"images": len(order), "point_maps": "pts3d" in data}
    orig = data["orig_size"].astype(np.int64)
    model_size = data["model_size"].astype(np.int64)
    box = data["crop_box"].astype(np.float64)
    if "K_model" in data:
        rec.extras["K"] = np.array([intrinsics_from_box(data["K_model"][i], box[i], tuple(model_size[i])) for i in order])
        rec.extras["image_size"] = orig[order]
    if "pts3d" not in data:
        return rec, info
    W0, H0 = (int(v) for v in orig[order[0]])
    map_size = default_map_size(W0, H0, map_width)
    Wm, Hm = map_size
    M = len(order)
    pts3d = np.zeros((M, Hm, Wm, 3), np.float32)
    conf = np.zeros((M, Hm, Wm), np.float32)
    colors = np.zeros((M, Hm, Wm, 3), np.uint8)
    have_colors = True
    src_pts = np.asarray(data["pts3d"])
    src_conf = np.asarray(data["conf"])
    for j, i in enumerate(order):
        size = tuple(int(v) for v in orig[i])
        if abs(size[0] / size[1] - W0 / H0) > 0.01:
            raise InputError(_problem(Path(path), f"orig_size[{i}]", f"image '{names[i]}' is {size[0]}x{size[1]}, another aspect "
                                      f"ratio than {W0}x{H0}", "reconstruction.npz needs one map size: capture one aspect ratio"))
        uv = box_to_model(grid_pixels(size, map_size), box[i], tuple(model_size[i]))
        stack = np.concatenate([src_pts[i].astype(np.float64), src_conf[i][..., None].astype(np.float64)], -1)
        vals, inside = sample_nearest(stack, uv, valid_size=tuple(model_size[i]))
        ok = inside & np.all(np.isfinite(vals), axis=-1)
        pts3d[j][ok] = vals[..., :3][ok]
        conf[j][ok] = np.maximum(vals[..., 3][ok], 0.0)
        # cells the model did not see: a finite filler (the camera centre) with confidence 0
        pts3d[j][~ok] = T_w_c[i][:3, 3]
        img_path = scene.path / matched[i][0] / matched[i][1]
        rgb = read_rgb(img_path) if img_path.is_file() else None
        if rgb is not None:
            colors[j] = resize_colors(rgb, map_size)
        elif "images" in data:
            cvals, cin = sample_nearest(data["images"][i], uv, valid_size=tuple(model_size[i]))
            colors[j] = np.where(cin[..., None], cvals, 0).astype(np.uint8)
        else:
            have_colors = False
    rec.pts3d, rec.conf = pts3d, conf
    rec.colors = colors if have_colors else None
    info["map_size"] = map_size
    info["valid_cells"] = float(np.mean(conf > 0))
    return rec, info
