"""``bijcr calibrate SCENE --out DIR``: Bi-JCR calibration of both arms from the scene's reconstruction."""

from __future__ import annotations

import argparse
import sys

HELP = "calibrate both wrist cameras, the metric scale and the second base from SCENE/reconstruction.npz"
DESCRIPTION = (
    "Bi-JCR joint calibration from SCENE/reconstruction.npz and the arms' ee_poses.csv: both hand-eye transforms "
    "(T_e1_c1, T_e2_c2), the reconstruction's metric scale, T_b1_w, T_b2_w and the second base T_b1_b2, each with "
    "a 1-sigma uncertainty. Writes DIR/calibration.json, DIR/scene_b1.ply (metric cloud in b1), DIR/views.npz (the "
    "depth views the cloud came from, placed in b1: what each camera saw through), "
    "DIR/calibration.png and ROS exports under DIR/ros/. Methods: absolute (default: joint refinement on absolute "
    "poses, outlier views dropped, robust loss), paper (the paper's closed form + gradient refinement in "
    "PyTorch, the optional extra: pip install -e .[paper]), "
    "paper-norefine (closed form only). When the reconstruction has point maps, the solve is then refined so "
    "that the views' point maps, each placed by its arm's kinematics, lie on each other (DIR/point_maps.png), "
    "and the cloud is built from the views placed that way (--no-point-maps: skip). Ground truth, when "
    "present, is only used to print an evaluation."
)
METHODS = ("absolute", "paper", "paper-norefine")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene folder (holds scene.yaml and reconstruction.npz)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--method", choices=METHODS, default="absolute", help="solver (default: absolute)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--reject-outliers", dest="reject", action="store_true", default=None,
                   help="find and drop badly registered views (default for absolute)")
    g.add_argument("--no-reject-outliers", dest="reject", action="store_false",
                   help="keep every registered view (default for paper methods)")
    p.add_argument("--no-robust", action="store_true", help="absolute: plain least squares instead of the soft_l1 loss")
    p.add_argument("--noise", nargs=2, type=float, metavar=("DEG", "MM"),
                   help="expected camera-pose noise of one view (rotation deg, position mm); default: estimated")
    p.add_argument("--alpha", type=float, default=0.5, help="paper: rotation weight of the refinement loss (default 0.5)")
    p.add_argument("--pairs", choices=("all", "consecutive"), default="all",
                   help="motion pairs: all i<j (default) or consecutive only (the paper's printed form)")
    p.add_argument("--uncertainty", choices=("jacobian", "jackknife", "none"), default="jacobian",
                   help="uncertainty estimator (default jacobian)")
    p.add_argument("--allow-degenerate", action="store_true",
                   help="solve a degenerate capture anyway (with warnings) instead of stopping")
    p.add_argument("--conf-threshold", type=float, default=None,
                   help="keep point-map points with conf above this (default: 0.2 x median confidence)")
    p.add_argument("--confirm-unsure", action="store_true",
                   help="also keep the points under the threshold that other views confirm (the steep sides of "
                        "objects), flagged 'unsure' in scene_b1.ply; off by default (docs/calibration.md, Metric cloud)")
    p.add_argument("--no-point-maps", action="store_true",
                   help="skip the point-map refinement: keep the joint solve's values and build the cloud from "
                        "the reconstruction's camera poses (the paper's cloud)")
    p.add_argument("--estimator", choices=("joint", "refine"), default="joint",
                   help="how the point maps are used: 'joint' (default: one weighted estimate of the kinematic loop "
                        "and the point maps, checked on held-out views) or 'refine' (the previous point-map ICP "
                        "that trusts the kinematics; docs/calibration.md)")
    p.add_argument("--no-figure", action="store_true", help="skip calibration.png and point_maps.png")
    p.add_argument("--quiet", action="store_true", help="print only errors and the output folder")


def _num(x: float, fmt: str = "+.2f") -> str:
    """A value, or "unbounded" for a sigma the views do not determine (infinite)."""
    return "unbounded" if x == float("inf") else format(x, fmt)


def _fmt_vec(v, unit: str, k: float = 1.0) -> str:
    return "[" + ", ".join(_num(k * x) for x in v) + f"] {unit}"


def summary(result, scene) -> list[str]:
    """Human-readable lines: each value with its 1-sigma uncertainty."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    u = result.uncertainty or {}
    lines = [f"method {result.method}"]
    s = f"scale    {result.scale:.5f}"
    if "scale" in u:
        s += f"  +- {_num(u['scale']['std'], '.5f')} ({_num(u['scale']['percent'], '.2f')}%)"
    lines.append(s + "   (metric = scale * reconstruction units)")
    for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2"):
        T = getattr(result, key)
        rpy = np.rad2deg(Rotation.from_matrix(T[:3, :3]).as_euler("xyz"))
        line = f"{key}  t {_fmt_vec(T[:3, 3], 'mm', 1000)}"
        if key in u:
            line += f" +- {_fmt_vec(u[key]['translation_mm'], 'mm')}"
        line += f";  rpy {_fmt_vec(rpy, 'deg')}"
        if key in u:
            line += f" +- {_num(u[key]['rotation_deg'], '.3f')} deg"
        lines.append(line)
    for arm in scene.arms:
        used, dropped = result.views_used[arm.name], result.views_dropped[arm.name]
        line = f"{arm.name}: {len(used)} of {len(arm)} views used"
        if dropped:
            line += "; dropped " + "; ".join(f"{d['image']} ({d['reason']})" for d in dropped)
        lines.append(line)
    r = result.residuals
    lines.append(f"AX=XB residuals: rotation {r['rotation_rad']:.4f} rad, translation {1000 * r['translation_m']:.2f} mm "
                 f"(noise per view: {result.noise['rotation_deg']:.2f} deg, {result.noise['translation_mm']:.1f} mm, "
                 f"{result.noise['source']})")
    pm = (result.info or {}).get("point_maps")
    if pm and pm.get("accepted"):
        nz, ho = pm.get("noise", {}), pm.get("held_out_cost", {})
        if "estimator" not in pm:  # the default point-map refinement
            lines.append(f"point-map refinement: overlapping views {pm['median_before_mm']:.2f} -> "
                         f"{pm['median_after_mm']:.2f} mm apart (median, {pm['point_pairs']} point pairs, "
                         f"{pm['cross_arm_pairs']} between the arms); cloud placed by the kinematics")
            return lines
        lines.append(f"joint estimate (kinematic loop + point maps): overlapping views {pm['median_before_mm']:.2f} -> "
                     f"{pm['median_after_mm']:.2f} mm apart (median, {pm['point_pairs']} point pairs, "
                     f"{pm['cross_arm_pairs']} between the arms); cloud placed by the kinematics")
        lines.append(f"  noise from the data: loop {nz.get('loop_rotation_deg', float('nan')):.2f} deg / "
                     f"{nz.get('loop_position_mm', float('nan')):.1f} mm per view, maps "
                     f"{nz.get('map_mm_median', float('nan')):.2f} mm (pair summaries x "
                     f"{nz.get('pair_summary_noise', float('nan')):.1f}); held-out cost "
                     f"{ho.get('joint', float('nan')):.0f} (joint) vs {ho.get('pose_only', float('nan')):.0f} (pose-only)")
    elif pm:
        what = "joint estimate" if "estimator" in pm else "point-map refinement"
        lines.append(f"{what}: not applied, pose-only values kept ({pm['reason']})")
    return lines


def evaluation_lines(result, gt, model: str | None = "synthetic") -> list[str]:
    """The calibration against ground_truth.yaml. Its ``scale`` is that of the synthetic reconstruction's
    frame; after ``bijcr reconstruct --force`` (``model`` is then COLMAP's or another's) the frame and its
    scale are new, so the scale is not compared."""
    from ._evaluate import calibration_errors

    e = calibration_errors(result.T_e1_c1, result.T_e2_c2, result.scale, result.T_b1_b2, gt)
    out = ["EVALUATION against ground_truth.yaml (not used by the solver):"]
    for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2"):
        out.append(f"  {key}: {e[key][0]:.3f} deg, {e[key][1]:.2f} mm")
    if e["scale_percent"] is not None and model == "synthetic":
        out.append(f"  scale: {e['scale_percent']:.3f}%")
    elif e["scale_percent"] is not None:
        out.append(f"  scale: not compared (ground_truth.yaml's scale is the synthetic reconstruction's; "
                   f"this one is {model!r})")
    return out


def run(args: argparse.Namespace) -> int:
    import time

    t0 = time.perf_counter()
    from ._solve import CalibrationOptions
    from ._stage import calibrate_stage

    def log(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:5.2f} s] calibrate: {msg}", file=sys.stderr)

    try:
        opts = CalibrationOptions(
            alpha=args.alpha, pairs=args.pairs, reject_outliers=args.reject, robust=not args.no_robust,
            noise_rot_deg=args.noise[0] if args.noise else None, noise_trans_mm=args.noise[1] if args.noise else None,
            on_degenerate="warn" if args.allow_degenerate else "raise", uncertainty=args.uncertainty,
            point_maps=not args.no_point_maps, estimator=args.estimator)
    except ValueError as e:
        print(f"bijcr calibrate: {e}", file=sys.stderr)
        return 2
    st = calibrate_stage(args.scene, args.out, method=args.method, options=opts,
                         conf_threshold=args.conf_threshold, figure=not args.no_figure, log=log,
                         confirm_unsure=args.confirm_unsure)
    if args.quiet:
        print(args.out)
        return 0
    print("\n".join(report_lines(st)))
    print("wrote " + ", ".join(sorted(st.files)) + f" in {args.out}")
    return 0


def report_lines(st) -> list[str]:
    """The summary, warnings and (with ground truth) evaluation lines of a calibration stage's result."""
    scene, result = st.scene, st.result
    lines = summary(result, scene) + [f"warning: {w}" for w in result.warnings]
    if scene.ground_truth is not None:
        model = scene.reconstruction.model if scene.reconstruction is not None else None
        lines += evaluation_lines(result, scene.ground_truth, model)
    return lines
