"""``bijcr reconstruct SCENE``: camera poses and point maps (reconstruction.npz) from the scene's images."""

from __future__ import annotations

import argparse

HELP = "make SCENE/reconstruction.npz: COLMAP on the CPU, or import a DUSt3R/MASt3R/VGGT/Ray Diffusion export"
DESCRIPTION = (
    "Make SCENE/reconstruction.npz (camera poses, point maps, confidences, colours). "
    "--backend colmap (default) runs pycolmap on the scene's images on the CPU and densifies by plane sweep; "
    "--backend dust3r|mast3r|vggt|raydiffusion imports the file written by tools/export_<backend>.py "
    "(run in that project's environment) given with --input. An existing reconstruction.npz is replaced "
    "only with --force (a backup copy is kept)."
)
BACKENDS = ("colmap", "dust3r", "mast3r", "vggt", "raydiffusion")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene folder (holds scene.yaml)")
    p.add_argument("--backend", choices=BACKENDS, default="colmap", help="how to reconstruct (default: colmap)")
    p.add_argument("--input", metavar="FILE", help="export file of tools/export_<backend>.py (importer backends)")
    p.add_argument("--force", action="store_true", help="replace an existing reconstruction.npz (a backup is kept)")
    p.add_argument("--map-width", type=int, default=160, help="width of the stored point maps (default 160)")
    p.add_argument("--no-dense", action="store_true", help="colmap: sparse points only, no plane-sweep densification")
    p.add_argument("--max-features", type=int, default=4096, help="colmap: SIFT features per image (default 4096)")
    p.add_argument("--threads", type=int, default=2, help="colmap: CPU threads (default 2)")
    p.add_argument("--no-retries", action="store_true", help="colmap: one mapper run with default options only")
    p.add_argument("--min-views", type=int, default=3, help="fewest registered views per arm accepted (default 3)")
    p.add_argument("--workdir", metavar="DIR", help="colmap: keep the database and models here (default: temporary)")
    p.add_argument("--plot", metavar="PNG", help="where to save the picture (default SCENE/reconstruction.png)")
    p.add_argument("--no-plot", action="store_true", help="do not save a picture")
    p.add_argument("--verbose", action="store_true", help="colmap: show COLMAP's own log")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bimanual_app.io_utils import check_output_dir, check_output_file
    from bimanual_app.reconstruction import ColmapOptions, reconstruct

    if args.workdir:
        check_output_dir(args.workdir, "--workdir")
    if args.plot and not args.no_plot:
        check_output_file(args.plot, "--plot", "give a .png path in a folder you can write to")
    copts = ColmapOptions(max_features=args.max_features, num_threads=args.threads, retries=not args.no_retries,
                          min_views=args.min_views, verbose=args.verbose)
    plot = False if args.no_plot else (Path(args.plot) if args.plot else True)
    res = reconstruct(args.scene, backend=args.backend, input=args.input, force=args.force, map_width=args.map_width,
                      dense=not args.no_dense, colmap_options=copts,
                      workdir=Path(args.workdir) if args.workdir else None, plot=plot)
    rec = res.reconstruction
    print(f"wrote {res.path} (model '{rec.model}', {len(rec)} views)")
    for arm, n in res.registered.items():
        print(f"  {arm}: {n}/{res.total[arm]} views registered")
    info = res.info
    if "attempts" in info:
        for a in info["attempts"]:
            regs = ", ".join(f"{k} {v}" for k, v in a["registered"].items())
            g = a.get("agreement")
            agr = (f"; motions vs robot {g['rot_deg']:.2f} deg / {100 * g['trans_rel']:.1f} % (score {g['score']:.3f})"
                   if g else "; not scored (too few views)")
            mark = "  <- kept" if a["name"] == info["chosen"] else ""
            print(f"  colmap attempt {a['name']}: {regs} ({a['models']} model(s), {a['points']} points, {a['seconds']:.1f} s)"
                  f"{agr}{mark}")
        if info.get("dropped"):
            print(f"  dropped as kinematically inconsistent (wrongly registered): {', '.join(info['dropped'])}")
        print(f"  kept: {info['chosen']}; {info['points']} sparse points; densification: {info['dense']}"
              + (f", {100 * info['valid_cells']:.0f}% of map cells valid" if "valid_cells" in info else ""))
    elif "valid_cells" in info:
        print(f"  point maps {info['map_size'][0]}x{info['map_size'][1]}, {100 * info['valid_cells']:.0f}% of cells seen by the model")
    else:
        print("  poses only (no point maps)")
    if info.get("agreement"):
        g = info["agreement"]
        print(f"  camera motions vs robot: {g['rot_deg']:.2f} deg / {100 * g['trans_rel']:.1f} % of the motion "
              "(median AX=XB residual after the closed-form hand-eye fit)")
    if info.get("inconsistent"):
        print(f"  warning: camera rotations contradict the arm's motions for {', '.join(info['inconsistent'])} "
              "(the calibration may drop them)")
    if res.backup is not None:
        print(f"  previous file kept as {res.backup}")
    if res.plot is not None:
        print(f"  picture: {res.plot}")
    print(f"  {info['seconds']:.1f} s")
    return 0
