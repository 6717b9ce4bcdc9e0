#!/usr/bin/env python3
"""Run VGGT on a scene's images and save its output for ``bijcr reconstruct``.

Run it inside VGGT's own environment (https://github.com/facebookresearch/vggt), not this project's:

    python /path/to/bijcr/tools/export_vggt.py SCENE --out SCENE/vggt_export.npz --weights /path/to/vggt/model.pt \
        [--repo /path/to/vggt] [--mode crop|pad] [--points depth|head]
    bijcr reconstruct SCENE --backend vggt --input SCENE/vggt_export.npz

It loads local weights (never downloads), runs all images of both arms in one batch, and writes the
export layout with ``extrinsic`` exactly as VGGT gives it: (N, 3, 4) world-to-camera [R | t], OpenCV
axes, world = the first image's camera (the importer inverts it). Point maps: ``--points depth``
(default, VGGT's README finds it more accurate) back-projects the depth head with VGGT's own cameras;
``--points head`` stores the point head's ``world_points``. The crop box follows
``load_and_preprocess_images`` (crop: width 518 and height a multiple of 14, centre-cropped to 518;
pad: long side 518, padded to a square), including its padding of different shapes to one size.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from export_common import (  # noqa: E402
    add_repo,
    image_size,
    pad_box,
    run_in_model_env,
    scene_images,
    stack_padded,
    to_uint8_images,
    vggt_crop_box,
    write_packed,
)


def crop_boxes(orig_sizes: list[tuple[int, int]], mode: str) -> tuple[list[list[float]], list[tuple[int, int]]]:
    """Per image the box and model size, after VGGT's batch padding of different shapes to the largest."""
    boxes, sizes = zip(*(vggt_crop_box(w, h, mode) for w, h in orig_sizes))
    Hmax = max(h for _, h in sizes)
    Wmax = max(w for w, _ in sizes)
    out_b, out_s = [], []
    for b, (w, h) in zip(boxes, sizes):
        hp, wp = Hmax - h, Wmax - w
        if hp > 0 or wp > 0:
            b, (w, h) = pad_box(b, (w, h), wp // 2, hp // 2, wp - wp // 2, hp - hp // 2)
        out_b.append(b)
        out_s.append((w, h))
    return out_b, out_s


def unproject(depth: np.ndarray, extrinsic: np.ndarray, intrinsic: np.ndarray) -> np.ndarray:
    """World points (N, H, W, 3) from depth (N, H, W), world-to-camera extrinsic (N, 3, 4), intrinsic (N, 3, 3)."""
    N, H, W = depth.shape
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    out = np.zeros((N, H, W, 3), np.float32)
    for i in range(N):
        K = intrinsic[i]
        x = (u - K[0, 2]) / K[0, 0] * depth[i]
        y = (v - K[1, 2]) / K[1, 1] * depth[i]
        X_c = np.stack([x, y, depth[i]], -1)
        R, t = extrinsic[i, :, :3], extrinsic[i, :, 3]
        out[i] = (X_c - t) @ R  # R^T (X_c - t), row-vector form
    return out


def pack(names: list[str], orig_sizes: list[tuple[int, int]], mode: str, extrinsic, intrinsic, pts3d, conf,
         images=None) -> dict:
    """Export-layout arrays from VGGT outputs (numpy, batch dimension removed): extrinsic (N, 3, 4),
    intrinsic (N, 3, 3), pts3d (N, H, W, 3), conf (N, H, W), images (N, H, W, 3) or (N, 3, H, W)."""
    boxes, sizes = crop_boxes(orig_sizes, mode)
    out = {"extrinsic": np.asarray(extrinsic, dtype=np.float64), "K_model": np.asarray(intrinsic, dtype=np.float64),
           "pts3d": np.asarray(pts3d, dtype=np.float32), "conf": np.asarray(conf, dtype=np.float32)}
    if images is not None:
        out["images"] = stack_padded(to_uint8_images(list(images)), np.uint8)
    return dict(model="vggt", names=names, orig_size=orig_sizes, model_size=sizes, crop_box=boxes, **out)


def run_model(paths: list[Path], weights: str, mode: str, points: str, device: str) -> dict:
    """VGGT forward pass; returns numpy outputs without the batch dimension (imports VGGT here only)."""
    import torch
    from vggt.models.vggt import VGGT
    from vggt.utils.load_fn import load_and_preprocess_images
    from vggt.utils.pose_enc import pose_encoding_to_extri_intri

    if Path(weights).is_file():
        model = VGGT()
        state = torch.load(weights, map_location="cpu")
        model.load_state_dict(state.get("model", state) if isinstance(state, dict) else state)
    else:  # a local folder saved with save_pretrained
        model = VGGT.from_pretrained(weights, local_files_only=True)
    model = model.to(device).eval()
    images = load_and_preprocess_images([str(p) for p in paths], mode=mode).to(device)
    dtype = torch.bfloat16 if device.startswith("cuda") and torch.cuda.get_device_capability()[0] >= 8 else torch.float16
    with torch.no_grad():
        with torch.autocast(device_type="cuda", dtype=dtype, enabled=device.startswith("cuda")):
            pred = model(images)
    extrinsic, intrinsic = pose_encoding_to_extri_intri(pred["pose_enc"], images.shape[-2:])
    ext = extrinsic[0].float().cpu().numpy()
    intr = intrinsic[0].float().cpu().numpy()
    if points == "depth":
        depth = pred["depth"][0, ..., 0].float().cpu().numpy()
        pts = unproject(depth, ext, intr)
        conf = pred["depth_conf"][0].float().cpu().numpy()
    else:
        pts = pred["world_points"][0].float().cpu().numpy()
        conf = pred["world_points_conf"][0].float().cpu().numpy()
    return {"extrinsic": ext, "intrinsic": intr, "pts3d": pts, "conf": conf, "images": images.float().cpu().numpy()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="scene folder (primary/ and secondary/ with ee_poses.csv and images)")
    ap.add_argument("--out", required=True, help="export file to write (.npz)")
    ap.add_argument("--weights", required=True, help="local VGGT weights (model.pt) or save_pretrained folder")
    ap.add_argument("--repo", help="VGGT checkout to import from (if not installed)")
    ap.add_argument("--mode", choices=("crop", "pad"), default="crop", help="load_and_preprocess_images mode")
    ap.add_argument("--points", choices=("depth", "head"), default="depth", help="point maps from depth+cameras or the point head")
    ap.add_argument("--device", default="cuda")
    args = ap.parse_args(argv)
    add_repo(args.repo)
    names, paths = scene_images(args.scene)
    sizes = [image_size(p) for p in paths]
    raw = run_in_model_env(lambda: run_model(paths, args.weights, args.mode, args.points, args.device), "VGGT")
    packed = pack(names, sizes, args.mode, raw["extrinsic"], raw["intrinsic"], raw["pts3d"], raw["conf"], raw["images"])
    write_packed(args.out, packed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
