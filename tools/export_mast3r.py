#!/usr/bin/env python3
"""Run MASt3R (sparse global alignment) on a scene's images and save its output for ``bijcr reconstruct``.

Run it inside MASt3R's own environment (https://github.com/naver/mast3r), not this project's:

    cd /path/to/mast3r && python /path/to/bijcr/tools/export_mast3r.py SCENE --out SCENE/mast3r_export.npz \
        --weights checkpoints/MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric.pth [--repo /path/to/mast3r]
    bijcr reconstruct SCENE --backend mast3r --input SCENE/mast3r_export.npz

It loads a local checkpoint (never downloads), pairs all images (complete scene graph, as the Bi-JCR
paper's ablation does), runs ``sparse_global_alignment`` and writes the export layout with
``cam2world`` = ``scene.get_im_poses()`` (camera-to-world), the dense point maps of
``scene.get_dense_pts3d(clean_depth=True)`` (MASt3R returns them flattened, (H*W, 3): reshaped here to
the model image), their confidences, and the crop box of DUSt3R's ``load_images`` (MASt3R uses it).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from export_common import add_repo, image_size, run_in_model_env, scene_images, write_packed  # noqa: E402
from export_dust3r import pack  # noqa: E402  (same layout: camera-to-world poses + point maps)


def run_model(paths: list[Path], weights: str, size: int, device: str, niter1: int, niter2: int,
              matching_conf_thr: float) -> dict:
    """MASt3R inference + sparse global alignment; returns numpy outputs (imports MASt3R here only)."""
    import mast3r.utils.path_to_dust3r  # noqa: F401  (puts MASt3R's dust3r submodule on the path)
    import torch
    from dust3r.utils.image import load_images
    from mast3r.cloud_opt.sparse_ga import sparse_global_alignment
    from mast3r.image_pairs import make_pairs
    from mast3r.model import AsymmetricMASt3R

    model = AsymmetricMASt3R.from_pretrained(weights).to(device)
    files = [str(p) for p in paths]
    imgs = load_images(files, size=size)
    if len(imgs) != len(files):
        sys.exit(f"MASt3R loaded {len(imgs)} of {len(files)} images (unsupported extension?)")
    pairs = make_pairs(imgs, scene_graph="complete", prefilter=None, symmetrize=True)
    with tempfile.TemporaryDirectory(prefix="mast3r-cache-") as cache:
        scene = sparse_global_alignment(files, pairs, cache, model, lr1=0.07, niter1=niter1, lr2=0.014, niter2=niter2,
                                        device=device, opt_depth=True, shared_intrinsics=False,
                                        matching_conf_thr=matching_conf_thr)
        pts3d, _, confs = scene.get_dense_pts3d(clean_depth=True)

        def np_(x):
            return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)

        return {"cam2world": np_(scene.get_im_poses()), "pts3d": [np_(p) for p in pts3d], "conf": [np_(c) for c in confs],
                "focals": np_(scene.get_focals()), "pps": np_(scene.get_principal_points()),
                "imgs": [np_(im) for im in scene.imgs]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="scene folder (primary/ and secondary/ with ee_poses.csv and images)")
    ap.add_argument("--out", required=True, help="export file to write (.npz)")
    ap.add_argument("--weights", required=True, help="local MASt3R checkpoint (.pth) or save_pretrained folder")
    ap.add_argument("--repo", help="MASt3R checkout to import from (if not installed)")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--niter1", type=int, default=500, help="coarse alignment iterations")
    ap.add_argument("--niter2", type=int, default=200, help="refinement iterations")
    ap.add_argument("--matching-conf-thr", type=float, default=5.0)
    ap.add_argument("--device", default="cuda")
    args = ap.parse_args(argv)
    add_repo(args.repo)
    names, paths = scene_images(args.scene)
    sizes = [image_size(p) for p in paths]
    raw = run_in_model_env(lambda: run_model(paths, args.weights, args.size, args.device, args.niter1, args.niter2, args.matching_conf_thr), "MASt3R")
    packed = pack("mast3r", names, sizes, args.size, raw["cam2world"], raw["pts3d"], raw["conf"], raw["focals"],
                  raw["pps"], raw["imgs"])
    write_packed(args.out, packed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
