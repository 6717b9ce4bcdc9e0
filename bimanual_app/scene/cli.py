"""``bijcr check SCENE``: validate a scene folder and summarise it."""

from __future__ import annotations

import argparse

HELP = "validate a scene folder and print a summary (or the list of problems, exit 1)"
DESCRIPTION = (
    "Validate a scene folder against the scene format (docs/scene-format.md) and run the checks `bijcr calibrate` "
    "runs on the views it would use (enough views per arm; rotations about more than one axis; enough travel "
    "for the scale): a capture calibrate would refuse is a problem here too (exit 1), one it would warn about "
    "a warning. Prints a summary of the scene, then OK or the problems, each with its fix."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene folder (holds scene.yaml)")
    p.add_argument("--quiet", action="store_true", help="print problems only")


def summarize(scene) -> list[str]:
    """Human-readable summary lines of a loaded :class:`Scene`."""
    import numpy as np

    lines = [f"scene '{scene.name}' at {scene.path}"]
    lines.append(f"  robot: {scene.robot or '(not given: poses only)'}" + (f", ee_link {scene.ee_link}" if scene.ee_link else ""))
    if scene.camera is not None:
        c = scene.camera
        lines.append(f"  camera: {c.width}x{c.height}, fx {c.fx:.1f} fy {c.fy:.1f} cx {c.cx:.1f} cy {c.cy:.1f}")
    else:
        lines.append("  camera: intrinsics not given (taken from the reconstruction)")
    rec = scene.reconstruction
    for arm in scene.arms:
        n_img = sum((scene.path / arm.name / k).is_file() for k in arm.images)
        src = "joint angles (FK)" if arm.joints is not None else "poses"
        reach = np.linalg.norm(arm.T_b_e[:, :3, 3], axis=1)
        line = f"  {arm.name}: {len(arm)} views from {src}, {n_img} image files, ee distance from base {reach.min():.2f}-{reach.max():.2f} m"
        if rec is not None:
            csv_rows, _ = rec.rows_for(arm.index, arm.images)
            line += f", {len(csv_rows)} registered"
        lines.append(line)
    if rec is not None:
        extra = []
        if rec.pts3d is not None:
            M, H, W, _ = rec.pts3d.shape
            extra.append(f"point maps {W}x{H}")
        if rec.conf is not None:
            extra.append("confidences")
        if rec.colors is not None:
            extra.append("colours")
        lines.append(f"  cached reconstruction: model '{rec.model}', {len(rec)} images" + (f" ({', '.join(extra)})" if extra else ""))
    else:
        lines.append("  cached reconstruction: none (make one with: bijcr reconstruct SCENE)")
    if scene.ground_truth is not None:
        gt = scene.ground_truth
        d = np.linalg.norm(gt.T_b1_b2[:3, 3])
        lines.append(f"  ground truth: present (bases {d:.3f} m apart" + (f", scale {gt.scale:.4f}" if gt.scale else "")
                     + (f", {len(gt.objects)} objects" if gt.objects else "") + ") - evaluation only")
    else:
        lines.append("  ground truth: none")
    return lines


def capture_problems(scene) -> list:
    """The degeneracy and view-count checks ``bijcr calibrate`` runs (calibration/_degeneracy.py), on the
    views it would use (those the reconstruction registered, else every row), as Problems."""
    from bimanual_app.io_utils import Problem
    from calibration import analyse_capture

    rec = scene.reconstruction
    poses = {}
    for arm in scene.arms:
        rows = rec.rows_for(arm.index, arm.images)[0] if rec is not None else slice(None)
        poses[arm.name] = arm.T_b_e[rows]
    names = set(poses)
    return [Problem(str(scene.path / f.arm / "ee_poses.csv" if f.arm in names else scene.path), f.arm, f"bijcr calibrate would {'refuse' if f.severity == 'error' else 'warn about'} "
                    f"this capture: {f.message}", f.fix, f.severity) for f in analyse_capture(poses)]


def run(args: argparse.Namespace) -> int:
    from bimanual_app.scene import validate_scene

    scene, problems = validate_scene(args.scene)
    if scene is not None:
        problems = list(problems) + capture_problems(scene)
    errors = [p for p in problems if p.severity == "error"]
    warnings = [p for p in problems if p.severity == "warning"]
    if scene is not None and not args.quiet:
        print("\n".join(summarize(scene)))
    for p in warnings:
        print(f"warning: {p}")
    if errors:
        print(f"{len(errors)} problem(s) in {args.scene}:")
        for p in errors:
            print(f"  - {p}")
        return 1
    if not args.quiet:
        print("OK")
    return 0
