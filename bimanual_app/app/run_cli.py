"""``bijcr run SCENE --out DIR``: the whole pipeline, from a capture to a report.

Stages: reconstruct (when the scene has no reconstruction.npz) -> calibrate -> segment -> grasp ->
joint-grasp task -> handover task -> report.html. Each stage's outputs land in a sub-folder of DIR and are
reused on the next run while their inputs are unchanged.
"""

from __future__ import annotations

import argparse

HELP = "run the whole pipeline on a scene and write DIR/report.html"
DESCRIPTION = __doc__


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene folder")
    p.add_argument("--out", required=True, help="output folder (created; earlier results inside are reused)")
    p.add_argument("--force", action="store_true", help="re-run every stage even when cached")
    p.add_argument("--backend", default="colmap", help="reconstruction backend when the scene has no reconstruction.npz")
    p.add_argument("--skip", action="append", default=[], metavar="STAGE",
                   help="leave a stage out (e.g. --skip handover); repeatable")


def build_stages(scene: str, out: str, backend: str = "colmap", skip: tuple[str, ...] = ()) -> list:
    """The pipeline's stages for ``scene`` writing under ``out`` (only those whose package is installed)."""
    import importlib.util
    from pathlib import Path

    from .pipeline import Stage

    scene_p, out_p = Path(scene).resolve(), Path(out).resolve()
    have = lambda mod: importlib.util.find_spec(mod) is not None  # noqa: E731
    rec = scene_p / "reconstruction.npz"
    inputs_scene = [scene_p / "scene.yaml", scene_p / "primary" / "ee_poses.csv", scene_p / "secondary" / "ee_poses.csv"]
    cal, seg, grasp = out_p / "calibration", out_p / "segments", out_p / "grasps"
    stages = []
    if not rec.exists() and have("bimanual_app.reconstruction.cli"):
        stages.append(Stage("reconstruct", ["reconstruct", str(scene_p), "--backend", backend],
                            inputs_scene + [scene_p / "primary" / "images", scene_p / "secondary" / "images"], [rec]))
    if have("calibration.cli"):
        stages.append(Stage("calibrate", ["calibrate", str(scene_p), "--out", str(cal)], inputs_scene + [rec],
                            [cal / "calibration.json", cal / "scene_b1.ply", cal / "calibration.png"]))
    if have("segmentation.cli"):
        seg_argv = ["segment", str(cal / "scene_b1.ply"), "--out", str(seg), "--calibration", str(cal / "calibration.json")]
        seg_inputs = [cal / "scene_b1.ply", cal / "calibration.json"]
        if (scene_p / "primary" / "masks").is_dir() or (scene_p / "secondary" / "masks").is_dir():
            # per-image masks (a user's, or a synthetic scene's renders) are extra evidence for the segmenter
            seg_argv += ["--masks", str(scene_p)]
            seg_inputs += [scene_p / "primary" / "masks", scene_p / "secondary" / "masks"]
        stages.append(Stage("segment", seg_argv, seg_inputs, [seg / "segments.npz", seg / "segments.png"]))
    if have("grasping.cli"):
        stages.append(Stage("grasp", ["grasp", str(cal / "scene_b1.ply"), "--segments", str(seg / "segments.npz"),
                                      "--calibration", str(cal / "calibration.json"), "--out", str(grasp)],
                            [cal / "scene_b1.ply", cal / "calibration.json", seg / "segments.npz"],
                            [grasp / "grasps.json", grasp / "grasps.png"]))
    if have("bimanual_app.tasks.cli"):
        for task in ("joint-grasp", "handover"):
            d = out_p / "tasks" / task
            stages.append(Stage(task, ["task", task, str(scene_p), "--work", str(out_p), "--out", str(d)],
                                [cal / "calibration.json", seg / "segments.npz", grasp / "grasps.json"],
                                [d / "task.json"], optional=True))
    return [s for s in stages if s.name not in set(skip)]


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from bimanual_app.scene import validate_scene

    from .pipeline import run_stages
    from .report import write_report

    out = Path(args.out)
    scene, problems = validate_scene(args.scene)
    warnings = [str(p) for p in problems if p.severity == "warning"]
    if scene is None:
        from bimanual_app.io_utils import InputError

        raise InputError([p for p in problems if p.severity == "error"])
    out.mkdir(parents=True, exist_ok=True)
    stages = build_stages(args.scene, args.out, args.backend, tuple(args.skip))
    _preview(scene, out)

    def on_start(st, k, n):
        print(f"[{k + 1}/{n}] {st.name} ...", file=sys.stderr, flush=True)

    def on_end(rec):
        note = f" ({rec.message})" if rec.message else ""
        print(f"      {rec.name}: {rec.status} in {rec.seconds:.1f} s{note}", file=sys.stderr, flush=True)

    records = run_stages(stages, out / ".stages", force=args.force, on_start=on_start, on_end=on_end)
    path = write_report(out, scene.name, records, warnings)
    print(f"report: {path}")
    failed = [r for r in records if r.status == "failed"]
    hard = [r for r in failed if not next(s for s in stages if s.name == r.name).optional]
    for r in failed:
        print(f"stage '{r.name}' failed: {r.message}", file=sys.stderr)
    return 1 if hard else 0


def _preview(scene, out) -> None:
    """Copy the capture's preview picture (written by bijcr synth or capture) next to the report."""
    import shutil

    src = scene.path / "preview.png"
    if src.exists():
        shutil.copyfile(src, out / "scene_preview.png")
