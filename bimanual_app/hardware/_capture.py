"""Capture one arm's half of a scene: move through joint poses, take a wrist-camera frame at each.

Output (docs/scene-format.md): ``SCENE/<arm>/images/NNN.png`` and ``SCENE/<arm>/ee_poses.csv`` with the
joint angles j1..j6 (radians) *measured by the arm* after it settled at each pose (not the commanded
ones), plus ``SCENE/scene.yaml`` (``robot: piper``) when the scene has none yet.

Nothing is overwritten: the arm folder must not exist or be empty, an existing scene.yaml is kept (and
must name the same robot). Everything is written into a hidden staging folder inside SCENE first and
renamed to ``SCENE/<arm>`` only after the last frame, so an interrupted capture never leaves a folder
that looks complete; on failure the staging folder is removed and the arm is stopped.
"""

from __future__ import annotations

import csv
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from bimanual_app.io_utils import InputError, Problem, atomic_open, atomic_path, check_output_dir

from ._errors import FeedbackTimeout, HardwareError
from ._limits import DEFAULT_WORKSPACE, SafetyLimits
from ._poses import PoseList, load_poses
from ._trajectory import joint_move

__all__ = ["CapturePlan", "CaptureResult", "plan_capture", "capture_scene", "ARMS"]

ARMS = ("primary", "secondary")


@dataclass
class CapturePlan:
    """A checked capture: what will be done, before any hardware is touched.

    Attributes:
        arm: ``primary`` or ``secondary``.
        poses: the pose list.
        out: the scene folder; ``arm_dir`` = ``out / arm``.
        limits: the safety limits (robot model, workspace box).
        write_scene_yaml: True when ``out/scene.yaml`` does not exist yet.
        lines: human-readable plan.
    """

    arm: str
    poses: PoseList
    out: Path
    arm_dir: Path
    limits: SafetyLimits
    write_scene_yaml: bool
    lines: list[str] = field(default_factory=list)


@dataclass
class CaptureResult:
    arm_dir: Path
    q_measured: np.ndarray          # (N, 6) rad
    q_error_rad: np.ndarray         # (N,) max |measured - commanded|
    images: list[str]
    wall_s: float
    overview_png: Path | None = None


def _check_output(out: Path, arm: str, robot: str) -> tuple[list[Problem], bool]:
    P: list[Problem] = []
    if out.exists() and not out.is_dir():
        return [Problem(str(out), "", "exists and is not a folder", "choose another --out")], False
    arm_dir = out / arm
    if arm_dir.exists():
        if not arm_dir.is_dir():
            P.append(Problem(str(arm_dir), "", "exists and is not a folder", "move it away or choose another --out"))
        elif any(arm_dir.iterdir()):
            P.append(Problem(str(arm_dir), "", f"the {arm} arm of this scene is already captured (folder not empty); "
                             "refusing to overwrite it", "choose another --out, or move that folder away"))
    scene_yaml = out / "scene.yaml"
    write_yaml = not scene_yaml.exists()
    if not write_yaml:
        try:
            meta = yaml.safe_load(scene_yaml.read_text())
        except yaml.YAMLError as e:
            meta = None
            P.append(Problem(str(scene_yaml), "", f"not valid YAML: {e}", "fix or remove it"))
        if isinstance(meta, dict) and meta.get("robot") not in (None, robot):
            P.append(Problem(str(scene_yaml), "robot", f"the scene is for robot {meta.get('robot')!r}, the poses for "
                             f"{robot!r}", "capture into another --out, or fix the poses file's robot"))
        elif meta is not None and not isinstance(meta, dict):
            P.append(Problem(str(scene_yaml), "", "must be a YAML mapping", "fix or remove it"))
    return P, write_yaml


def plan_capture(poses: str | Path | PoseList, out: str | Path, arm: str = "primary",
                 limits: SafetyLimits | None = None, speed: float | None = None) -> CapturePlan:
    """Load and check everything a capture needs, without any hardware.

    Checks: the poses file; every pose against the joint limits and the workspace box (FK of the
    elbow, wrist, flange and tool point); every move between consecutive poses (sampled densely); the
    output folder (no overwrite, same robot as an existing scene.yaml). Raises :class:`InputError`
    (or :class:`LimitViolation`) with every problem found.
    """
    if arm not in ARMS:
        raise InputError(Problem("--arm", "arm", f"arm must be primary or secondary, got {arm!r}", "use --arm primary"))
    check_output_dir(out, fix="give a new scene folder, or one you can write to")  # before anything else is read
    pl = poses if isinstance(poses, PoseList) else load_poses(poses)
    if speed is not None:
        pl.speed = float(speed)
    out = Path(out)
    if limits is None:
        limits = SafetyLimits.from_robot(pl.robot, workspace=pl.workspace or DEFAULT_WORKSPACE, name=arm)
    P, write_yaml = _check_output(out, arm, pl.robot)
    src = pl.source or "poses"
    for i, (name, q) in enumerate(zip(pl.names, pl.q)):
        for p in limits.config_problems(q[None], f"poses[{i}] ({name})"):
            P.append(Problem(src, p.field.replace("[0]", ""), p.message, p.fix))
    seq = list(pl.q) + ([pl.home] if pl.home is not None else [])
    if pl.home is not None:
        for p in limits.config_problems(pl.home[None], "home"):
            P.append(Problem(src, "home", p.message, p.fix))
    v = limits.velocity * pl.speed
    durations = []
    for k, (a, b) in enumerate(zip(seq[:-1], seq[1:])):
        move = joint_move(a, b, v, np.asarray(getattr(limits.robot, "accel_limits", 2 * v)) * pl.speed)
        durations.append(move.duration)
        probs = limits.trajectory_problems(move)
        if probs and not P:
            P.append(Problem(src, f"poses[{k}] -> poses[{k + 1}]", f"the move between these poses leaves the limits: "
                             f"{probs[0].message}", "insert an intermediate pose, or reorder the poses"))
    if P:
        raise InputError(P)
    T = limits.robot.fk(pl.q)
    lines = [f"capture plan: {len(pl)} poses for the {arm} arm ({pl.robot}) -> {out / arm}",
             f"  moves at {pl.speed:.0%} of the allowed joint speeds ({limits.velocity.max():.2f} rad/s max), "
             f"settle {pl.settle_s:.1f} s before each frame",
             f"  workspace box (base frame, m): min {list(limits.workspace.lower) if limits.workspace else '-'} "
             f"max {list(limits.workspace.upper) if limits.workspace else '-'}"]
    for i, (name, q) in enumerate(zip(pl.names, pl.q)):
        p = T[i, :3, 3]
        lines.append(f"  {i:3d} {name:>12s}: q = [{', '.join(f'{v:+.3f}' for v in q)}] rad, flange at "
                     f"({p[0]:+.3f}, {p[1]:+.3f}, {p[2]:+.3f}) m")
    if pl.home is not None:
        lines.append(f"  then home: [{', '.join(f'{v:+.3f}' for v in pl.home)}]")
    lines.append(f"  estimated motion time between poses: {sum(durations):.1f} s (+ the move to the first pose)")
    lines.append("  scene.yaml: " + (f"will be written (robot: {pl.robot})" if write_yaml else "exists, kept"))
    return CapturePlan(arm, pl, out, out / arm, limits, write_yaml, lines)


def _settle_and_measure(arm, settle_s: float, timeout_s: float, sample_s: float = 0.1) -> np.ndarray:
    """Wait ``settle_s`` watching the feedback (stale -> stop + FeedbackTimeout), then average the joint
    feedback over ``sample_s``. Returns (6,) rad."""
    t_end = time.monotonic() + settle_s
    samples = []
    while True:
        fb = arm.read()
        if fb.age_s > timeout_s:
            raise FeedbackTimeout(f"joint feedback stopped while settling ({fb.age_s:.2f} s old)", arm.name)
        if fb.status not in (None, 0x00):
            raise HardwareError(f"the arm reports '{fb.status_text}' while settling", arm.name)
        now = time.monotonic()
        if now >= t_end - sample_s:
            samples.append(fb.q)
        if now >= t_end and samples:
            break
        time.sleep(0.01)
    return np.mean(samples, axis=0)


def _overview(images: list[np.ndarray], names: list[str], path: Path) -> None:
    """Contact sheet of the captured frames (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(images)
    cols = min(4, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3 * cols, 2.4 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, img, name in zip(axes.ravel(), images, names):
        ax.imshow(img[..., ::-1])
        ax.set_title(name, fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=80)
    plt.close(fig)


def capture_scene(plan: CapturePlan, arm, camera, config=None,
                  log: Callable[[str], None] | None = None) -> CaptureResult:
    """Run a checked capture on a connected :class:`PiperArm` with a camera source.

    For each pose: guarded move (:meth:`PiperArm.move_to`), settle while watching the feedback, average
    the measured joints, grab a frame, check the arm did not move meanwhile. On any error or Ctrl-C the
    arm is stopped, the staging folder removed, and the exception re-raised.
    """
    import cv2

    from ._executor import ExecutionConfig, stop_all

    say = log or (lambda s: print(s, file=sys.stderr))
    cfg = config or ExecutionConfig(settle_tol_rad=0.01)  # measured joints are recorded: no need to be exact
    pl = plan.poses
    plan.out.mkdir(parents=True, exist_ok=True)
    # re-check the output now: another capture may have written it since the plan was made
    P, _ = _check_output(plan.out, plan.arm, pl.robot)
    if P:
        raise InputError(P)
    staging = Path(tempfile.mkdtemp(prefix=f".{plan.arm}.incomplete-", dir=plan.out))
    (staging / "images").mkdir()
    t0 = time.monotonic()
    q_meas, q_err, keys, thumbs = [], [], [], []
    try:
        camera.open()
        for i, (name, q) in enumerate(zip(pl.names, pl.q)):
            say(f"[{plan.arm}] pose {i + 1}/{len(pl)} ({name}): moving")
            arm.move_to(q, speed=pl.speed, config=cfg)
            q_before = _settle_and_measure(arm, pl.settle_s, cfg.feedback_timeout_s)
            frame = camera.grab()
            q_after = _settle_and_measure(arm, 0.0, cfg.feedback_timeout_s, sample_s=0.0)
            if np.max(np.abs(q_after - q_before)) > 0.005:
                raise HardwareError(f"the arm moved while the frame was taken ({np.max(np.abs(q_after - q_before)):.3f} "
                                    "rad); increase settle_s", arm.name)
            key = f"images/{i:03d}.png"
            with atomic_path(staging / key) as tmp:
                if not cv2.imwrite(str(tmp), frame):
                    raise HardwareError(f"could not write image {key}", arm.name)
            q_meas.append(q_before)
            q_err.append(float(np.max(np.abs(q_before - q))))
            keys.append(key)
            thumbs.append(cv2.resize(frame, (160, max(1, int(160 * frame.shape[0] / frame.shape[1])))))
            say(f"[{plan.arm}] pose {i + 1}/{len(pl)}: frame {frame.shape[1]}x{frame.shape[0]} taken, measured joints "
                f"within {q_err[-1]:.4f} rad of the pose")
        if pl.home is not None:
            say(f"[{plan.arm}] returning home")
            arm.move_to(pl.home, speed=pl.speed, config=cfg)
        with atomic_open(staging / "ee_poses.csv") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(["image"] + [f"j{k}" for k in range(1, 7)])
            for key, q in zip(keys, q_meas):
                w.writerow([key] + [repr(float(v)) for v in q])
        overview = staging / "capture_overview.png"
        _overview(thumbs, [f"{k}: {n}" for k, n in zip(range(len(keys)), pl.names)], overview)
        # publish: the arm folder appears complete, in one rename
        if plan.arm_dir.exists():
            plan.arm_dir.rmdir()  # empty (checked above); rmdir fails loudly if something appeared since
        os.replace(staging, plan.arm_dir)
    except BaseException as e:
        stopped: tuple[str, ...] = ()
        if not getattr(arm, "stopped", False) and getattr(arm, "connected", False):
            stopped = stop_all({arm.name: arm})
        shutil.rmtree(staging, ignore_errors=True)
        if isinstance(e, HardwareError) and stopped and not e.stopped:
            e.with_stopped(stopped)
        raise
    finally:
        camera.close()
    if plan.write_scene_yaml and not (plan.out / "scene.yaml").exists():
        with atomic_open(plan.out / "scene.yaml") as f:
            yaml.safe_dump({"format": 1, "name": plan.out.resolve().name, "robot": pl.robot}, f, sort_keys=False)
    return CaptureResult(plan.arm_dir, np.array(q_meas), np.array(q_err), keys, time.monotonic() - t0,
                         plan.arm_dir / "capture_overview.png")
