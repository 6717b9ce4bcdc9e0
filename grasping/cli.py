"""``bijcr grasp SCENE_DIR_OR_CLOUD --segments DIR/segments.npz --out DIR``: grasps for every segmented object.

Reads the metric cloud in b1 (``scene_b1.ply``, or the folder holding it), its segments and, when found,
``calibration.json`` (for ``T_b1_b2``: the secondary arm, joint grasps and hand-overs). Writes
``DIR/grasps.json`` (per object: ranked single-arm grasps with ``T_b1_g``, ``T_b2_g``, width, score, the arms
that reach them with joint solutions; two-arm pairs; a hand-over) and ``DIR/grasps.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "grasps for the segmented objects: single-arm (antipodal), two-arm joint pairs and hand-overs -> grasps.json"
DESCRIPTION = __doc__


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene_b1.ply (metric cloud in b1) or the folder holding it (e.g. the calibrate --out DIR)")
    p.add_argument("--segments", required=True, help="segments.npz from `bijcr segment` (labels per cloud point)")
    p.add_argument("--out", required=True, help="output folder (grasps.json, grasps.png)")
    p.add_argument("--calibration", default=None,
                   help="calibration.json with T_b1_b2 (default: beside the cloud when present; without it only the"
                        " primary arm is planned for)")
    p.add_argument("--robot", default="piper", help="robot model name or URDF path (default: piper)")
    p.add_argument("--objects", type=int, nargs="+", default=None, help="plan only these object ids")
    p.add_argument("--candidates", type=int, default=500, help="hand frames sampled per object (default 500)")
    p.add_argument("--no-handover", action="store_true", help="do not plan hand-overs")
    p.add_argument("--seed", type=int, default=0, help="random seed of the sampler")
    p.add_argument("--quiet", action="store_true", help="print only the summary")


def run(args: argparse.Namespace) -> int:
    import time
    from dataclasses import replace

    from bimanual_app.io_utils import InputError, Problem
    from bimanual_app.robots import load_robot

    from ._antipodal import SamplerParams
    from ._arms import make_arms
    from ._gripper import load_gripper
    from ._inputs import b2b_sigma, load_calibration, load_cloud, load_segments, resolve_inputs, scene_cloud
    from ._output import draw_plan, write_grasps_json
    from ._plan import PlanParams, plan_grasps

    t0 = time.perf_counter()

    def log(msg: str) -> None:
        if not args.quiet:
            print(f"[grasp {time.perf_counter() - t0:6.1f}s] {msg}", file=sys.stderr, flush=True)

    if args.candidates < 10:
        raise InputError(Problem("command line", "--candidates", f"{args.candidates} is too few", "use 100 or more"))
    cloud_path, cal_path = resolve_inputs(args.scene, args.calibration)
    seg_path = Path(args.segments)
    points, colors = load_cloud(cloud_path)
    labels, seg_extra = load_segments(seg_path)
    cloud = scene_cloud(points, labels, colors, seg_extra.get("table_plane"),
                        {"cloud": str(cloud_path), "segments": str(seg_path)}, str(cloud_path), str(seg_path))
    T_b1_b2, sigma = None, None
    if cal_path is not None:
        cal = load_calibration(cal_path)
        T_b1_b2, sigma = cal["T_b1_b2"], b2b_sigma(cal)
    else:
        log("no calibration.json: planning for the primary arm only (no joint grasps or hand-overs)")
    robot = load_robot(args.robot)
    gripper = load_gripper(args.robot)
    log(f"{len(points)} points, objects {cloud.object_ids}; gripper {gripper.robot}: opening "
        f"{gripper.min_width * 1000:.0f}-{gripper.max_width * 1000:.0f} mm, fingers {gripper.finger_length * 1000:.0f} mm")
    arms = make_arms(robot, gripper, T_b1_b2)
    params = PlanParams(sampler=replace(SamplerParams(), n_candidates=args.candidates, seed=args.seed),
                        handover=not args.no_handover)
    if sigma is not None:  # hand-over receivers ranked by how likely they catch the object despite it
        params = replace(params, handover_params=replace(params.handover_params, b2b_sigma_m=sigma[0],
                                                         b2b_sigma_rad=sigma[1]))
        log(f"base-to-base uncertainty (1 sigma, per axis): {sigma[0] * 1000:.1f} mm, {sigma[1] * 180 / 3.141592653589793:.2f} deg")
    plan = plan_grasps(cloud, gripper, arms, T_b1_b2, params, args.objects, log)

    usable = [op for op in plan.objects if (any(len(a) for a in op.reach.values()) or op.joint)]
    for op in plan.objects:
        for p in op.problems:
            print(f"bijcr grasp: warning: {p}", file=sys.stderr)
    if not usable:
        problems = [p for op in plan.objects for p in op.problems]
        # and why the rest found nothing either (for an object too wide for one gripper: why no two-arm pair)
        problems += [Problem(str(seg_path), f"object {op.id}", n, "") for op in plan.objects for n in op.notes
                     if not n.startswith("needs two arms")]
        if not problems:
            problems = [Problem(str(seg_path), "", "no object has a grasp that passed the checks", "")]
        raise InputError(problems)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    inputs = {"cloud": str(cloud_path), "segments": str(seg_path), "calibration": None if cal_path is None else str(cal_path),
              "robot": args.robot}
    write_grasps_json(out / "grasps.json", plan, inputs)
    draw_plan(out / "grasps.png", plan, cloud.points, cloud.labels)
    print(f"{'object':>6}  {'mode':<6}  {'grasps':>6}  {'primary':>7}  {'secondary':>9}  {'joint':>5}  {'hand-over':>9}  note")
    for op in plan.objects:
        n = len(op.grasps) if op.grasps is not None else 0
        r1 = len(op.reach.get("primary", []))
        r2 = len(op.reach.get("secondary", [])) if "secondary" in op.reach else "-"
        note = (str(op.problems[0].message) if op.problems else (op.notes[0] if op.notes else ""))
        print(f"{op.id:>6}  {op.mode:<6}  {n:>6}  {r1:>7}  {r2!s:>9}  {len(op.joint):>5}  "
              f"{'yes' if op.handover is not None else 'no':>9}  {note}")
    print(f"wrote {out / 'grasps.json'} and {out / 'grasps.png'} ({time.perf_counter() - t0:.1f} s)")
    return 0
