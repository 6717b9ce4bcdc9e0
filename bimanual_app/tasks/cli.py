"""``bijcr task joint-grasp|handover SCENE``: plan a bimanual task, preview it in PyBullet with physics,
and (only with ``--execute hardware`` and a passing preview) run it on the two Piper arms.

joint-grasp: both arms grasp one large object and lift it together; the object's motion is planned and
both grippers follow it (IK at every waypoint; arms, and the carried object, collision-checked).
handover: one arm picks a small object and brings it to the transfer pose, the other grasps it, the giver
releases and retreats; the primary gives where it can, else the secondary (as grasps.json says).

Missing earlier results are produced first, in-process: calibrate -> segment -> grasp (under --work).
Writes OUT/task.json (outcome, chosen object and why, plans per phase, timings, approval record,
warnings), OUT/preview.gif, key frames OUT/NN_<phase>.png, OUT/plan.npz and OUT/approval.json, all at once;
prints the warnings (e.g. a calibration whose second base is too loose for a hand-over).
Exit code 0: the preview succeeded (and the hardware run, when asked); 1: it did not, or bad input.
"""

from __future__ import annotations

import argparse

HELP = "plan, preview (PyBullet physics) and optionally execute a bimanual task: joint-grasp or handover"
DESCRIPTION = __doc__

TASKS = ("joint-grasp", "handover")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("task", choices=TASKS, help="which task")
    p.add_argument("scene", help="scene folder (holds scene.yaml)")
    p.add_argument("--object", type=int, default=None, metavar="ID",
                   help="segment id of the object (default: the best candidate, with the reason printed)")
    p.add_argument("--work", default=None, metavar="DIR",
                   help="folder of the earlier stages' results (default runs/<scene name>)")
    p.add_argument("--out", default=None, metavar="DIR", help="output folder (default WORK/tasks/<task>)")
    p.add_argument("--gui", action="store_true", help="open a PyBullet window (when a display exists)")
    p.add_argument("--execute", choices=["hardware"], default=None,
                   help="after a passing preview, run the plan on the real arms (CAN)")
    p.add_argument("--can-primary", default="can0", help="CAN channel of the primary arm (with --execute)")
    p.add_argument("--can-secondary", default="can1", help="CAN channel of the secondary arm (with --execute)")
    p.add_argument("--can-interface", default="socketcan", choices=["socketcan", "virtual"],
                   help="python-can interface of the arms (virtual: a simulated arm on a virtual bus, for tests)")
    p.add_argument("--truth-objects", action="store_true",
                   help="evaluation on synthetic scenes: simulate the ground-truth objects and secondary base "
                        "(ground_truth.yaml) while planning with the estimates, drawn as ghosts")
    p.add_argument("--plan-time", type=float, default=5.0, metavar="S",
                   help="time limit per motion-planning query in seconds (default 5)")
    p.add_argument("--frame-size", default="320x240", metavar="WxH", help="size of the preview frames (default 320x240)")
    p.add_argument("--no-record", action="store_true", help="no GIF / key frames (faster; the verdict is the same)")
    p.add_argument("--no-masks", action="store_true",
                   help="when the segment stage runs here, do not give it the scene's per-image masks (used by "
                        "default when the scene has them, as `bijcr run` does)")
    p.add_argument("--quiet", action="store_true", help="print only the outcome")


def run(args: argparse.Namespace) -> int:
    import sys

    from bimanual_app.io_utils import InputError, Problem

    from ._run import TaskOptions, run_task

    try:
        w, h = (int(v) for v in args.frame_size.lower().split("x"))
        if not (32 <= w <= 1920 and 32 <= h <= 1080):
            raise ValueError
    except ValueError:
        raise InputError(Problem("command line", "--frame-size", f"{args.frame_size!r} is not WxH within 32x32..1920x1080",
                                 "e.g. --frame-size 320x240")) from None

    opts = TaskOptions(task=args.task, scene=args.scene, object_id=args.object, work=args.work, out=args.out,
                       gui=args.gui, execute=args.execute, truth_objects=args.truth_objects,
                       plan_time=args.plan_time, quiet=args.quiet, can_primary=args.can_primary,
                       can_secondary=args.can_secondary, can_interface=args.can_interface,
                       record=not args.no_record, frame_size=(w, h), masks=False if args.no_masks else None)
    res = run_task(opts)
    status = "SUCCESS" if res.success else "FAILED"
    print(f"{args.task}: {status} - {res.reason}")
    if res.object_id is not None:
        print(f"object {res.object_id}: {res.object_reason}")
    print(f"results: {res.out}")
    for w in [] if args.quiet else res.record.get("warnings", []):
        print(f"warning: {w}")
    if not res.success:
        print(f"bijcr task {args.task}: {res.reason}", file=sys.stderr)
    return 0 if res.success else 1
