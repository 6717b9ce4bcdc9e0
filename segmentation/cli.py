"""``bijcr segment CLOUD --out DIR``: the table and one segment per object of a metric cloud in b1."""

from __future__ import annotations

import argparse

HELP = "split a metric cloud in b1 into the table and objects (segments.npz / .json / .png)"
DESCRIPTION = (
    "Segment a metric point cloud in frame b1 (such as scene_b1.ply from bijcr calibrate): fit the table "
    "plane, over-segment what stands on it into small patches and contract the patch graph into objects "
    "(convexity, colour, optional masks). Writes DIR/segments.npz (labels per input point, -1 for the table "
    "and background, boxes, table plane), DIR/segments.json (per-object summary) and DIR/segments.png."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("cloud", help="metric point cloud in b1 (.ply, .pcd, .xyz or .npz with 'points')")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--masks", metavar="SCENE", help="use the scene's per-image masks (<arm>/masks/NNN.png) as extra "
                   "evidence, carried into b1 through its point maps and the calibration")
    p.add_argument("--calibration", metavar="JSON", help="calibration.json (default: the one next to CLOUD, if any); "
                   "gives T_b1_w / scale for --masks and the secondary base, which is not an object")
    p.add_argument("--voxel", type=float, metavar="M", help="graph voxel size in metres (default: 5 mm, more for "
                   "very large scenes)")
    p.add_argument("--max-height", type=float, metavar="M", help="points higher above the table are background "
                   "(default 0.45)")
    p.add_argument("--keep-bases", action="store_true", help="do not treat the robot bases as background")
    p.add_argument("--no-plot", action="store_true", help="skip segments.png")
    p.add_argument("--quiet", action="store_true", help="print nothing but problems")


def run(args: argparse.Namespace) -> int:
    from bimanual_app.io_utils import InputError, Problem

    from . import SegmentParams
    from ._stage import segment_stage

    params = SegmentParams()
    if args.voxel is not None:
        if not (0.0005 <= args.voxel <= 0.1):
            raise InputError(Problem("--voxel", "", f"{args.voxel} m is outside 0.0005-0.1 m", "give a size in metres"))
        params = params.with_(voxel=args.voxel)
    if args.max_height is not None:
        if not args.max_height > 0:
            raise InputError(Problem("--max-height", "", "must be positive", "give a height in metres"))
        params = params.with_(max_height=args.max_height)
    st = segment_stage(args.cloud, args.out, calibration=args.calibration, masks=args.masks, params=params,
                       keep_bases=args.keep_bases, plot=not args.no_plot, progress=not args.quiet)
    if not args.quiet:
        print("\n".join(report_lines(st)))
    return 0


def report_lines(st) -> list[str]:
    """The summary lines of a segmentation stage's result (masks used, table, objects, files)."""
    from ._io import format_table

    res, t = st.result, st.result.table
    lines = [f"masks: {st.mask_views} views"] if st.mask_views else []
    lines.append(f"{st.cloud}: {len(st.points)} points, table {t.extent[0]:.2f} x {t.extent[1]:.2f} m, "
                 f"{len(res.objects)} objects ({res.timings['total']:.2f} s)")
    if res.objects:
        lines.append(format_table(res))
    return lines + ["wrote " + ", ".join(str(p) for p in st.paths.values())]
