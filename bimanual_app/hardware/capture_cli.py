"""``bijcr capture``: capture one arm's half of a scene on a real Piper, or suggest capture poses.

    bijcr capture --arm primary --poses POSES.yaml --out SCENE [--can can0] [--camera 0] [--execute hardware]
    bijcr capture --suggest [--arm primary] [--views 8] > POSES.yaml

Without ``--execute hardware`` nothing is connected or moved: the poses and the output folder are
checked and the plan is printed.
"""

from __future__ import annotations

import argparse
import sys

HELP = "capture a scene on a real Piper arm (dry run unless --execute hardware), or --suggest poses"
DESCRIPTION = (
    "Move one Piper arm through the joint poses of POSES.yaml, take a wrist-camera frame at each after the "
    "arm settles, and write SCENE/<arm>/images + ee_poses.csv (measured joints, radians) and scene.yaml. "
    "Without --execute hardware it only checks the poses and the output folder and prints the plan. "
    "With --suggest it prints well-conditioned capture poses as a POSES.yaml. See docs/hardware.md."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--arm", choices=["primary", "secondary"], default="primary", help="which arm (default primary)")
    p.add_argument("--poses", metavar="POSES.yaml", help="joint poses to visit (see docs/hardware.md)")
    p.add_argument("--out", metavar="SCENE", help="scene folder to write (the arm's folder must not exist or be empty)")
    p.add_argument("--can", default="can0", help="CAN interface of this arm (default can0)")
    p.add_argument("--can-interface", default="socketcan", metavar="KIND",
                   help="python-can interface: socketcan (default, a real arm) or virtual (simulated arm)")
    p.add_argument("--camera", default="0",
                   help="wrist camera: OpenCV device index (default 0), /dev/videoN or URL, or a folder of images "
                        "(stand-in: serves the files in name order)")
    p.add_argument("--camera-size", metavar="WxH", help="request this frame size from the camera, e.g. 640x480")
    p.add_argument("--speed", type=float, help="override the poses file's speed (fraction of allowed joint speeds)")
    p.add_argument("--feedback-timeout", type=float, default=0.25, metavar="S",
                   help="stop the arm when its joint feedback is older than S seconds (default 0.25, at most 1.0; "
                        "raise it only for a busy PC or a slow USB-CAN adapter)")
    p.add_argument("--execute", choices=["hardware"],
                   help="actually move the arm: '--execute hardware'. Without it, a dry run")
    p.add_argument("--suggest", action="store_true", help="print suggested capture poses (YAML) and exit")
    p.add_argument("--views", type=int, default=8, help="number of views for --suggest (default 8)")
    p.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "Z"), default=(0.40, 0.0, 0.0),
                   help="table point the views look at, in the arm's base frame, metres (default 0.40 0 0)")
    p.add_argument("--seed", type=int, default=0, help="random seed of --suggest")
    p.add_argument("--plot", metavar="PNG", help="with --suggest: also save a picture of the viewpoints")


def _suggest(args) -> int:
    from bimanual_app.io_utils import InputError, Problem, check_output_file

    from ._limits import SafetyLimits
    from ._poses import dump_poses
    from ._suggest import suggest_viewpoints

    if args.views < 3:
        raise InputError(Problem("--views", "views", "need at least 3 views for a calibration", "use --views 8"))
    if args.plot:
        check_output_file(args.plot, "--plot", "give a .png path in a folder you can write to")
    limits = SafetyLimits.from_robot("piper", name=args.arm)
    try:
        s = suggest_viewpoints(limits.robot, views=args.views, target=tuple(args.target), limits=limits, seed=args.seed)
    except ValueError as e:
        raise InputError(Problem("--suggest", "views", str(e), "lower --views or move --target")) from None
    text = dump_poses(s.as_pose_list(args.arm, "piper", limits))
    sys.stdout.write(text)
    print(f"suggested {len(s.q)} views (of {s.candidates} reachable candidates): min rotation between views "
          f"{s.min_angle_deg:.1f} deg, rotation-axis spread {s.axis_spread:.3f}", file=sys.stderr)
    if args.plot:
        _plot_suggestion(s, args.plot)
        print(f"picture: {args.plot}", file=sys.stderr)
    return 0


def _plot_suggestion(s, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from bimanual_app.io_utils import atomic_path

    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    p = s.T_b_t[:, :3, 3]
    z = s.T_b_t[:, :3, 2]
    ax.scatter(*p.T, c="C0")
    for a, d in zip(p, z):  # viewing ray down to the table plane (z = target height)
        t = (s.target[2] - a[2]) / d[2] if d[2] < -1e-6 else 0.3
        b = a + t * d
        ax.plot([a[0], b[0]], [a[1], b[1]], [a[2], b[2]], color="C1", lw=1)
    lo = np.minimum(np.minimum(p.min(0), s.target), 0.0) - 0.05
    hi = np.maximum(np.maximum(p.max(0), s.target), 0.0) + 0.05
    lo[2] = min(lo[2], 0.0)
    ax.set_xlim(lo[0], hi[0]), ax.set_ylim(lo[1], hi[1]), ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)
    for i, q in enumerate(p):
        ax.text(*q, str(i), fontsize=8)
    ax.scatter(*s.target, c="C3", marker="x", s=60)
    ax.scatter(0, 0, 0, c="k", marker="^", s=60)
    ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)"), ax.set_zlabel("z (m)")
    ax.set_title(f"{len(p)} suggested views (tool point, viewing axis)")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def run(args) -> int:
    if args.suggest:
        return _suggest(args)

    from bimanual_app.io_utils import InputError, Problem

    from ._camera import open_camera
    from ._capture import capture_scene, plan_capture
    from ._errors import HardwareError
    from ._piper import PiperArm

    missing = [Problem(f"--{k}", k, f"--{k} is required for a capture", f"add --{k} ...")
               for k in ("poses", "out") if not getattr(args, k)]
    if missing:
        raise InputError(missing)
    if not 0.02 <= args.feedback_timeout <= 1.0:
        raise InputError(Problem("--feedback-timeout", "feedback_timeout_s",
                                 f"must be in [0.02, 1.0] s, got {args.feedback_timeout:g}",
                                 "leave it at 0.25 (the Piper sends joint feedback at 200 Hz)"))
    plan = plan_capture(args.poses, args.out, args.arm, speed=args.speed)
    for line in plan.lines:
        print(line)
    if args.execute != "hardware":
        print("dry run: nothing was connected or moved. Add --execute hardware to run this capture on the arm.")
        return 0

    size = (None, None)
    if args.camera_size:
        try:
            w, h = (int(v) for v in args.camera_size.lower().split("x"))
            size = (w, h)
        except ValueError:
            raise InputError(Problem("--camera-size", "", f"expected WxH, got {args.camera_size!r}", "e.g. 640x480")) from None
    camera = open_camera(args.camera, *size)
    arm = PiperArm(args.can, args.arm, limits=plan.limits, bustype=args.can_interface,
                   check_port=args.can_interface == "socketcan", execute=args.execute)
    try:
        print(f"connecting to the {args.arm} arm on {args.can} ({args.can_interface}); camera: {camera.description}",
              file=sys.stderr)
        arm.connect()
        from ._executor import ExecutionConfig

        config = ExecutionConfig(settle_tol_rad=0.01, feedback_timeout_s=args.feedback_timeout)
        result = capture_scene(plan, arm, camera, config=config)
    except HardwareError as e:
        print(f"bijcr capture: failed: {e}", file=sys.stderr)
        print("nothing was written to the scene folder.", file=sys.stderr)
        return 1
    finally:
        arm.close()
    print(f"captured {len(result.images)} views in {result.wall_s:.1f} s -> {result.arm_dir} "
          f"(measured joints within {result.q_error_rad.max():.4f} rad of the poses); overview: {result.overview_png}")
    other = "secondary" if args.arm == "primary" else "primary"
    if not (plan.out / other / "ee_poses.csv").exists():
        print(f"next: capture the {other} arm into the same folder (bijcr capture --arm {other} --out {plan.out} ...)")
    else:
        print(f"both arms captured: bijcr check {plan.out}")
    return 0
