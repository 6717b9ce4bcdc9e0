"""``bijcr synth OUT``: generate a synthetic scene folder (PyBullet render + foundation-model emulator)."""

from __future__ import annotations

import argparse

HELP = "generate a synthetic capture (two Piper arms, wrist cameras, emulated reconstruction)"
DESCRIPTION = (
    "Build a PyBullet table-top scene with two Piper arms facing each other, drive each wrist camera by IK "
    "through N viewpoints, render RGB / depth / masks, and write a scene folder (docs/scene-format.md) with "
    "ground truth and an emulated foundation-model reconstruction. See docs/synth.md."
)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"expected WxH like 160x120, got {text!r}") from e
    return w, h


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", metavar="OUT", help="scene folder to create (must be new or empty)")
    p.add_argument("--seed", type=int, default=0, help="random seed: the same seed gives the same scene (default 0)")
    p.add_argument("--views", type=int, default=8, help="viewpoints per arm (default 8)")
    p.add_argument("--objects", type=int, default=5, help="objects on the table (default 5)")
    p.add_argument("--noise", choices=["none", "low", "paper", "harsh"], default="paper",
                   help="emulated reconstruction noise (default paper: ~1.5 deg, 1 cm per camera pose)")
    p.add_argument("--map-noise", choices=["fm"], default=None,
                   help="point-map errors replacing the noise level's depth noise: fm = foundation-model like "
                        "(per-view depth scale 1 %%, smooth quadratic warp 0.5 %%, correlated noise 0.3 %%; "
                        "default: the level's own depth noise)")
    p.add_argument("--pose-pivot-m", type=float, default=0.0, metavar="L",
                   help="the camera poses' rotation errors turn about the point L metres ahead of each camera "
                        "(on its optical axis) instead of its centre, so the centre errs by about L x the rotation "
                        "error, as in real reconstructions (e.g. 1.0; default 0: about the camera centre)")
    p.add_argument("--outliers", type=float, default=0.0, metavar="F",
                   help="fraction of each arm's views with a gross pose error (default 0)")
    p.add_argument("--touching", type=float, default=0.5, metavar="F",
                   help="fraction of objects placed touching a neighbour (default 0.5)")
    p.add_argument("--no-render", action="store_true",
                   help="skip images, masks and point maps: poses-only reconstruction (fast)")
    p.add_argument("--pointmap-size", type=_size, default=(160, 120), metavar="WxH",
                   help="resolution of the emulated point maps (default 160x120; must divide 640x480)")
    p.add_argument("--joints", action="store_true", help="write ee_poses.csv as joint angles instead of poses")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it is a scene made by bijcr synth")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def run(args: argparse.Namespace) -> int:
    from bimanual_app.io_utils import check_output_dir
    from bimanual_app.synth import make_synthetic_scene

    check_output_dir(args.out, "OUT", "give a new or empty folder you can write to")
    path = make_synthetic_scene(args.out, seed=args.seed, views=args.views, objects=args.objects, noise=args.noise,
                                outliers=args.outliers, render=not args.no_render, touching=args.touching,
                                pointmap_size=args.pointmap_size, as_joints=args.joints, overwrite=args.overwrite,
                                map_noise=args.map_noise, pose_pivot_m=args.pose_pivot_m,
                                progress=not args.quiet)
    print(path)
    return 0
