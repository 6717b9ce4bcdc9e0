#!/usr/bin/env python3
"""Run Ray Diffusion on a scene's images and save its camera poses for ``bijcr reconstruct``.

Run it inside Ray Diffusion's own environment (https://github.com/jasonyzhang/RayDiffusion), not this
project's:

    cd /path/to/RayDiffusion && python /path/to/bijcr/tools/export_raydiffusion.py SCENE \
        --out SCENE/raydiffusion_export.npz --model-dir models/co3d_diffusion [--repo .]
    bijcr reconstruct SCENE --backend raydiffusion --input SCENE/raydiffusion_export.npz

Ray Diffusion gives camera poses only (no point maps): the Bi-JCR paper's second baseline. Its cameras
are PyTorch3D ``PerspectiveCameras``: ``X_view = X_world @ R + T`` (row vectors) with view axes x left,
y up, z forward. The export stores ``R`` and ``T`` exactly so (the importer converts them to OpenCV
camera-to-world). Each whole image is the "object" box (the robot scene has no single object), which
Ray Diffusion's CustomDataset squares and enlarges by 1.15 before resizing to 224 x 224; that box is
the ``crop_box``. Images are handed over in the scene's order through numbered links, because
CustomDataset sorts the folder it reads.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from export_common import add_repo, image_size, run_in_model_env, scene_images, write_packed  # noqa: E402

CROP_SCALE = 1.15   # CustomDataset.jitter_scale (both bounds), no jitter translation
MODEL_SIZE = 224


def crop_box(W0: int, H0: int) -> list[float]:
    """Square box CustomDataset crops for the whole-image bbox [0, 0, W0, H0] (integer corners, like its _jitter_bbox)."""
    c = np.array([W0 / 2, H0 / 2])
    extent = max(W0, H0) / 2 * CROP_SCALE
    ul = np.round(c - extent).astype(int)
    lr = ul + int(np.round(2 * extent))
    return [float(ul[0]), float(ul[1]), float(lr[0]), float(lr[1])]


def pack(names: list[str], orig_sizes: list[tuple[int, int]], R, T, focal_length=None, principal_point=None) -> dict:
    """Export-layout arrays from Ray Diffusion's PyTorch3D cameras (numpy): R (N, 3, 3), T (N, 3)."""
    N = len(names)
    out = {"R": np.asarray(R, dtype=np.float64).reshape(N, 3, 3), "T": np.asarray(T, dtype=np.float64).reshape(N, 3)}
    if focal_length is not None:
        out["focal_length_ndc"] = np.asarray(focal_length, dtype=np.float64).reshape(N, -1)
    if principal_point is not None:
        out["principal_point_ndc"] = np.asarray(principal_point, dtype=np.float64).reshape(N, 2)
    return dict(model="raydiffusion", names=names, orig_size=orig_sizes, model_size=[(MODEL_SIZE, MODEL_SIZE)] * N,
                crop_box=[crop_box(w, h) for w, h in orig_sizes], **out)


def run_model(paths: list[Path], model_dir: str, device: str) -> dict:
    """Ray Diffusion prediction as in its demo.py; returns numpy R, T (imports Ray Diffusion here only)."""
    import torch
    from ray_diffusion.dataset import CustomDataset
    from ray_diffusion.inference.load_model import load_model
    from ray_diffusion.inference.predict import predict_cameras

    model, cfg = load_model(model_dir, device=torch.device(device))
    with tempfile.TemporaryDirectory(prefix="raydiff-") as tmp:
        for i, p in enumerate(paths):  # numbered links: CustomDataset sorts the folder
            (Path(tmp) / f"{i:05d}{p.suffix.lower()}").symlink_to(p)
        bboxes = [[0, 0, *image_size(p)] for p in paths]
        dataset = CustomDataset(image_dir=tmp, mask_dir=None, bboxes=bboxes, mask_images=False)
        batch = dataset.get_data(ids=np.arange(len(paths)))
    images = batch["image"].to(device)
    crop_params = batch["crop_params"].to(device)
    n = len(paths)
    if cfg.training.regression:
        pred = predict_cameras(model=model, images=images, device=device, pred_x0=cfg.model.pred_x0,
                               crop_parameters=crop_params, use_regression=True)
        cams = pred[0]
    else:
        pred = predict_cameras(model=model, images=images, device=device, pred_x0=cfg.model.pred_x0,
                               crop_parameters=crop_params, additional_timesteps=(70,), rescale_noise="zero",
                               use_regression=False, max_num_images=None if n <= 8 else 8, pbar=True)
        cams = pred[1][0]
    out = {"R": cams.R.detach().cpu().numpy(), "T": cams.T.detach().cpu().numpy()}
    for k in ("focal_length", "principal_point"):
        v = getattr(cams, k, None)
        out[k] = None if v is None else v.detach().cpu().numpy()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="scene folder (primary/ and secondary/ with ee_poses.csv and images)")
    ap.add_argument("--out", required=True, help="export file to write (.npz)")
    ap.add_argument("--model-dir", required=True, help="local Ray Diffusion model folder (e.g. models/co3d_diffusion)")
    ap.add_argument("--repo", help="Ray Diffusion checkout to import from (if not installed)")
    ap.add_argument("--device", default="cuda:0")
    args = ap.parse_args(argv)
    add_repo(args.repo)
    names, paths = scene_images(args.scene)
    sizes = [image_size(p) for p in paths]
    raw = run_in_model_env(lambda: run_model(paths, args.model_dir, args.device), "Ray Diffusion")
    packed = pack(names, sizes, raw["R"], raw["T"], raw.get("focal_length"), raw.get("principal_point"))
    write_packed(args.out, packed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
