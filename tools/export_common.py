"""Shared helpers of the exporter scripts (tools/export_<model>.py); keep this file beside them.

These scripts run inside another project's Python environment (DUSt3R, MASt3R, VGGT, Ray Diffusion),
where this package is not installed: they use only the standard library, numpy and Pillow here, and
import the model's own project inside their ``run_model`` function.

The file they write is the *export layout*, format 1 (docs/reconstruction.md, checked by
``bijcr reconstruct --backend <model> --input FILE``):

    format      () int                  1
    model       () str                  dust3r | mast3r | vggt | raydiffusion
    image       (N,) str                scene-relative image paths, in the model's order
    orig_size   (N, 2) int              [W, H] of each original image
    model_size  (N, 2) int              [W, H] of the image the model ran on (= its point map)
    crop_box    (N, 4) float            [x0, y0, x1, y1] region of the original image (pixel-edge
                                        coordinates) the model image covers (beyond the image if padded)
    cam2world   (N, 4, 4) float         dust3r / mast3r: camera-to-world (OpenCV axes)
    extrinsic   (N, 3, 4) float         vggt: world-to-camera [R | t] (OpenCV axes)
    R, T        (N, 3, 3), (N, 3)       raydiffusion: PyTorch3D X_view = X_world @ R + T (x left, y up)
    pts3d       (N, Hm, Wm, 3) float32  world points per model pixel (zero-padded to the largest map)
    conf        (N, Hm, Wm) float32     confidence per model pixel (0 in padding)
    K_model     (N, 3, 3) float         optional: intrinsics in model pixels (OpenCV)
    images      (N, Hm, Wm, 3) uint8    optional: the model's input images
"""

from __future__ import annotations

import csv
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

EXPORT_FORMAT = 1
ARMS = ("primary", "secondary")


def add_repo(repo: str | None) -> None:
    """Put a model project's checkout on ``sys.path`` (those projects are usually run from their folder)."""
    if repo:
        sys.path.insert(0, str(Path(repo).expanduser().resolve()))


def scene_images(scene: str | Path) -> tuple[list[str], list[Path]]:
    """Both arms' images of a scene folder, primary first, in ee_poses.csv order.

    Returns ``(names, paths)``: scene-relative names (``primary/images/000.png``) and absolute paths.
    Exits with a message naming the file when a CSV or an image is missing.
    """
    root = Path(scene).expanduser().resolve()
    names, paths, missing = [], [], []
    for arm in ARMS:
        csv_path = root / arm / "ee_poses.csv"
        if not csv_path.is_file():
            sys.exit(f"{csv_path}: missing (is {root} a scene folder?)")
        with open(csv_path, newline="") as f:
            rows = list(csv.DictReader(f))
        if not rows or "image" not in rows[0]:
            sys.exit(f"{csv_path}: no 'image' column")
        for r in rows:
            key = r["image"].strip()
            p = root / arm / key
            if not p.is_file():
                missing.append(str(p))
            names.append(f"{arm}/{key}")
            paths.append(p)
    if missing:
        sys.exit("missing image file(s): " + ", ".join(missing[:10]))
    return names, paths


def image_size(path: Path) -> tuple[int, int]:
    """(W, H) of an image as the models load it (EXIF orientation applied, as their loaders do)."""
    from PIL import Image, ImageOps

    with Image.open(path) as im:
        return ImageOps.exif_transpose(im).size


def dust3r_crop_box(W0: int, H0: int, size: int = 512, square_ok: bool = False) -> tuple[list[float], tuple[int, int]]:
    """Box of the original image and model size that ``dust3r.utils.image.load_images(size=...)`` makes.

    It resizes (long side to ``size``; for 224 the short side to 224) and crops around ``(W//2, H//2)``
    of the resized image: to a centre square for 224, else to multiples of 16 (4:3 when square).
    """
    if size == 224:
        long = round(size * max(W0 / H0, H0 / W0))
    else:
        long = size
    S = max(W0, H0)
    Wr, Hr = int(round(W0 * long / S)), int(round(H0 * long / S))
    cx, cy = Wr // 2, Hr // 2
    if size == 224:
        half = min(cx, cy)
        l, t, r, b = cx - half, cy - half, cx + half, cy + half
    else:
        halfw, halfh = ((2 * cx) // 16) * 8, ((2 * cy) // 16) * 8
        if not square_ok and Wr == Hr:
            halfh = 3 * halfw / 4
        l, t, r, b = cx - halfw, cy - halfh, cx + halfw, cy + halfh
    sx, sy = W0 / Wr, H0 / Hr
    return [l * sx, t * sy, r * sx, b * sy], (int(round(r - l)), int(round(b - t)))


def vggt_crop_box(W0: int, H0: int, mode: str = "crop", target: int = 518) -> tuple[list[float], tuple[int, int]]:
    """Box and model size of ``vggt.utils.load_fn.load_and_preprocess_images`` for one image (before the
    batch padding that equalises different shapes; see :func:`pad_box`).

    crop: width -> 518, height -> round(H * 518 / W / 14) * 14 (the two scales differ slightly), then a
    centre crop of the height to 518 if taller. pad: long side -> 518, the other to a multiple of 14, then
    padded (white) to 518 x 518.
    """
    if mode == "pad":
        if W0 >= H0:
            w, h = target, round(H0 * (target / W0) / 14) * 14
        else:
            w, h = round(W0 * (target / H0) / 14) * 14, target
    else:
        w, h = target, round(H0 * (target / W0) / 14) * 14
    sy = H0 / h
    box = [0.0, 0.0, float(W0), float(H0)]
    if mode == "crop" and h > target:
        start = (h - target) // 2
        box = [0.0, start * sy, float(W0), (start + target) * sy]
        h = target
    if mode == "pad":
        box, (w, h) = pad_box(box, (w, h), (target - w) // 2, (target - h) // 2, target - w - (target - w) // 2,
                              target - h - (target - h) // 2)
    return box, (int(w), int(h))


def pad_box(box: list[float], size: tuple[int, int], left: int, top: int, right: int, bottom: int
            ) -> tuple[list[float], tuple[int, int]]:
    """Box and size after padding a model image of ``size`` covering ``box`` by whole pixels."""
    w, h = size
    sx, sy = (box[2] - box[0]) / w, (box[3] - box[1]) / h
    return [box[0] - left * sx, box[1] - top * sy, box[2] + right * sx, box[3] + bottom * sy], \
        (w + left + right, h + top + bottom)


def stack_padded(maps: list[np.ndarray], dtype) -> np.ndarray:
    """Stack maps (H_i, W_i, ...) into (N, max H, max W, ...), zero-padded at the bottom/right."""
    H = max(m.shape[0] for m in maps)
    W = max(m.shape[1] for m in maps)
    out = np.zeros((len(maps), H, W) + maps[0].shape[2:], dtype=dtype)
    for i, m in enumerate(maps):
        out[i, : m.shape[0], : m.shape[1]] = m
    return out


def to_uint8_images(imgs: list[np.ndarray]) -> list[np.ndarray]:
    """Model input images as uint8 RGB: accepts [0, 1] floats, [-1, 1] floats (normalised) or uint8."""
    out = []
    for im in imgs:
        im = np.asarray(im)
        if im.ndim == 3 and im.shape[0] == 3 and im.shape[2] != 3:
            im = im.transpose(1, 2, 0)
        if im.dtype != np.uint8:
            im = (im * 0.5 + 0.5) if im.min() < -0.01 else im
            im = np.clip(np.rint(im * 255), 0, 255).astype(np.uint8)
        out.append(im)
    return out


def write_export(out: str | Path, model: str, names: list[str], orig_size, model_size, crop_box, **arrays) -> Path:
    """Write the export file atomically (temporary name, then rename) and print a summary."""
    out = Path(out).expanduser().resolve()
    data = {"format": np.array(EXPORT_FORMAT), "model": np.array(model), "image": np.array(names),
            "orig_size": np.asarray(orig_size, dtype=np.int64), "model_size": np.asarray(model_size, dtype=np.int64),
            "crop_box": np.asarray(crop_box, dtype=np.float64)}
    for k, v in arrays.items():
        if v is not None:
            data[k] = np.asarray(v)
    N = len(names)
    for k, v in data.items():
        if v.ndim and k not in ("format", "model") and v.shape[0] != N:
            raise ValueError(f"{k}: {v.shape[0]} entries for {N} images")
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.stem}.tmp-", suffix=".npz", dir=out.parent)
    os.close(fd)
    try:
        np.savez_compressed(tmp, **data)
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    print(f"wrote {out}: {model}, {N} images, keys {', '.join(sorted(data))}")
    return out


def write_packed(out: str | Path, packed: dict) -> Path:
    """:func:`write_export` of a script's ``pack`` result (its ``model``, ``names``, size and crop keys, then
    its arrays)."""
    arrays = dict(packed)
    head = [arrays.pop(k) for k in ("model", "names", "orig_size", "model_size", "crop_box")]
    return write_export(out, *head, **arrays)


def run_in_model_env(run, model: str):
    """``run()``, the model's own inference; a missing module of the model's project becomes a one-line exit
    that says which environment to run the script in."""
    try:
        return run()
    except ModuleNotFoundError as e:
        sys.exit(f"{e}: run this script with {model}'s Python environment, or pass --repo PATH_TO_ITS_CHECKOUT")
