#!/usr/bin/env python3
"""Run DUSt3R (global aligner) on a scene's images and save its output for ``bijcr reconstruct``.

Run it inside DUSt3R's own environment (https://github.com/naver/dust3r), not this project's:

    cd /path/to/dust3r && python /path/to/bijcr/tools/export_dust3r.py SCENE --out SCENE/dust3r_export.npz \
        --weights checkpoints/DUSt3R_ViTLarge_BaseDecoder_512_dpt.pth [--repo /path/to/dust3r]
    bijcr reconstruct SCENE --backend dust3r --input SCENE/dust3r_export.npz

It loads a local checkpoint (it never downloads), pairs all images of both arms (complete scene graph,
as the Bi-JCR paper does), runs the global aligner (PointCloudOptimizer, MST init) and writes the export
layout (tools/export_common.py, docs/reconstruction.md) with ``cam2world`` = ``scene.get_im_poses()``
(camera-to-world), the aligned point maps ``scene.get_pts3d()``, confidences ``scene.im_conf``, the
intrinsics from ``get_focals`` / ``get_principal_points`` and the crop box of DUSt3R's ``load_images``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from export_common import (  # noqa: E402
    add_repo,
    dust3r_crop_box,
    image_size,
    run_in_model_env,
    scene_images,
    stack_padded,
    to_uint8_images,
    write_packed,
)


def pack(model: str, names: list[str], orig_sizes: list[tuple[int, int]], size: int, cam2world, pts3d: list, conf: list,
         focals=None, pps=None, imgs: list | None = None) -> dict:
    """Export-layout arrays from DUSt3R/MASt3R outputs, already converted to numpy.

    Args:
        cam2world: (N, 4, 4) camera-to-world poses; pts3d: N maps (H, W, 3) (or (H*W, 3) with ``imgs``
        giving H, W); conf: N maps (H, W) (or flat); focals: (N,) or (N, 1) or (N, 2); pps: (N, 2);
        imgs: N model input images (H, W, 3).
    """
    N = len(names)
    boxes, msizes = zip(*(dust3r_crop_box(w, h, size) for w, h in orig_sizes))
    maps, confs = [], []
    for i in range(N):
        Wm, Hm = msizes[i]
        maps.append(np.asarray(pts3d[i], dtype=np.float32).reshape(Hm, Wm, 3))
        confs.append(np.asarray(conf[i], dtype=np.float32).reshape(Hm, Wm))
    out = {"cam2world": np.asarray(cam2world, dtype=np.float64).reshape(N, 4, 4),
           "pts3d": stack_padded(maps, np.float32), "conf": stack_padded(confs, np.float32)}
    if focals is not None:
        f = np.asarray(focals, dtype=np.float64).reshape(N, -1)
        fx, fy = f[:, 0], f[:, -1]
        pp = np.asarray(pps, dtype=np.float64).reshape(N, 2) if pps is not None else \
            np.array([[w / 2, h / 2] for w, h in msizes])
        K = np.zeros((N, 3, 3))
        K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = fx, fy, pp[:, 0], pp[:, 1], 1.0
        out["K_model"] = K
    if imgs is not None:
        out["images"] = stack_padded(to_uint8_images(imgs), np.uint8)
    return dict(model=model, names=names, orig_size=orig_sizes, model_size=list(msizes), crop_box=list(boxes), **out)


def run_model(paths: list[Path], weights: str, size: int, niter: int, device: str, batch_size: int) -> dict:
    """DUSt3R inference + global alignment; returns numpy outputs (imports DUSt3R here only)."""
    import torch
    from dust3r.cloud_opt import GlobalAlignerMode, global_aligner
    from dust3r.image_pairs import make_pairs
    from dust3r.inference import inference
    from dust3r.model import AsymmetricCroCo3DStereo

    try:
        from dust3r.inference import load_model
    except ImportError:
        load_model = None
    from dust3r.utils.image import load_images

    if Path(weights).is_file() and load_model is not None:
        model = load_model(weights, device)
    else:  # a local folder saved with save_pretrained
        model = AsymmetricCroCo3DStereo.from_pretrained(weights, local_files_only=True).to(device)
    imgs = load_images([str(p) for p in paths], size=size)
    if len(imgs) != len(paths):
        sys.exit(f"DUSt3R loaded {len(imgs)} of {len(paths)} images (unsupported extension?)")
    pairs = make_pairs(imgs, scene_graph="complete", prefilter=None, symmetrize=True)
    output = inference(pairs, model, device, batch_size=batch_size)
    scene = global_aligner(output, device=device, mode=GlobalAlignerMode.PointCloudOptimizer)
    scene.compute_global_alignment(init="mst", niter=niter, schedule="cosine", lr=0.01)

    def np_(x):
        return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)

    return {"cam2world": np_(scene.get_im_poses()), "pts3d": [np_(p) for p in scene.get_pts3d()],
            "conf": [np_(c) for c in scene.im_conf], "focals": np_(scene.get_focals()),
            "pps": np_(scene.get_principal_points()), "imgs": [np_(im) for im in scene.imgs]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="scene folder (primary/ and secondary/ with ee_poses.csv and images)")
    ap.add_argument("--out", required=True, help="export file to write (.npz)")
    ap.add_argument("--weights", required=True, help="local DUSt3R checkpoint (.pth) or save_pretrained folder")
    ap.add_argument("--repo", help="DUSt3R checkout to import from (if not installed)")
    ap.add_argument("--size", type=int, default=512, help="image size DUSt3R runs at (512 or 224)")
    ap.add_argument("--niter", type=int, default=300, help="global alignment iterations")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--batch-size", type=int, default=1)
    args = ap.parse_args(argv)
    add_repo(args.repo)
    names, paths = scene_images(args.scene)
    sizes = [image_size(p) for p in paths]
    raw = run_in_model_env(lambda: run_model(paths, args.weights, args.size, args.niter, args.device, args.batch_size), "DUSt3R")
    packed = pack("dust3r", names, sizes, args.size, raw["cam2world"], raw["pts3d"], raw["conf"], raw["focals"],
                  raw["pps"], raw["imgs"])
    write_packed(args.out, packed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
