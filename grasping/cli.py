"""``bijcr grasp SCENE_DIR_OR_CLOUD --segments DIR/segments.npz --out DIR``: grasps for every segmented object.

Reads the metric cloud in b1 (``scene_b1.ply``, or the folder holding it), its segments and, when found,
``calibration.json`` (for ``T_b1_b2``: the secondary arm, joint grasps and hand-overs) and ``views.npz`` (where the
cameras saw through: a hand-over keeps its fingers out of the space near the object no camera saw, where it can). Writes
``DIR/grasps.json`` (per object: ranked single-arm grasps with ``T_b1_g``, ``T_b2_g``, width, score, the arms
that reach them with joint solutions; two-arm pairs; a hand-over) and ``DIR/grasps.png``.
"""

from __future__ import annotations

import argparse
import sys

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
    p.add_argument("--handover-giver", choices=("either", "primary"), default="either",
                   help="which arm may pick and give in a hand-over: 'either' (default: the primary where it "
                        "can, else the secondary) or 'primary' only")
    p.add_argument("--seed", type=int, default=0, help="random seed of the sampler")
    p.add_argument("--quiet", action="store_true", help="print only the summary")


def run(args: argparse.Namespace) -> int:
    import time

    from ._stage import grasp_stage

    t0 = time.perf_counter()

    def log(msg: str) -> None:
        if not args.quiet:
            print(f"[grasp {time.perf_counter() - t0:6.1f}s] {msg}", file=sys.stderr, flush=True)

    st = grasp_stage(args.scene, args.segments, args.out, calibration=args.calibration, robot=args.robot,
                     objects=args.objects, candidates=args.candidates, handover=not args.no_handover,
                     seed=args.seed, log=log, givers=GIVERS[args.handover_giver])
    for p in st.warnings:
        print(f"bijcr grasp: warning: {p}", file=sys.stderr)
    print("\n".join(report_lines(st)) + f" ({time.perf_counter() - t0:.1f} s)")
    return 0


GIVERS = {"either": ("primary", "secondary"), "primary": ("primary",)}  # --handover-giver -> PlanParams.handover_givers


def _handover_cell(op) -> str:
    """'yes', 'no', or 'yes (2->1)' for a hand-over the secondary gives."""
    if op.handover is None:
        return "no"
    return "yes" if op.handover.giver_arm == "primary" else "yes (2->1)"


def report_lines(st) -> list[str]:
    """The per-object table of a grasping stage's result and the files written."""
    lines = [f"{'object':>6}  {'mode':<6}  {'grasps':>6}  {'primary':>7}  {'secondary':>9}  {'joint':>5}  "
             f"{'hand-over':>9}  note"]
    for op in st.plan.objects:
        n = len(op.grasps) if op.grasps is not None else 0
        r1 = len(op.reach.get("primary", []))
        r2 = len(op.reach.get("secondary", [])) if "secondary" in op.reach else "-"
        note = (str(op.problems[0].message) if op.problems else (op.notes[0] if op.notes else ""))
        lines.append(f"{op.id:>6}  {op.mode:<6}  {n:>6}  {r1:>7}  {r2!s:>9}  {len(op.joint):>5}  "
                     f"{_handover_cell(op):>9}  {note}")
    return lines + [f"wrote {st.files['grasps.json']} and {st.files['grasps.png']}"]
