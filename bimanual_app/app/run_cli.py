"""``bijcr run SCENE --out DIR``: the whole pipeline, from a capture to a report.

Stages: reconstruct (when the scene has no reconstruction.npz) -> calibrate -> segment -> grasp ->
joint-grasp task -> handover task -> report.html. Each stage's outputs land in a sub-folder of DIR and are
reused on the next run while their inputs, and the product's code, are unchanged. Each stage is the library
call of its own command (bijcr calibrate, segment, grasp, task), in this process. A failed task is recorded and the run goes on;
Ctrl-C stops the whole run at once (exit code 130), keeping the stages finished so far, with no report.
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
    """The pipeline's stages for ``scene`` writing under ``out`` (only those whose package is installed).

    Each stage calls the library function of its ``bijcr`` sub-command (:mod:`bimanual_app.app.stages`);
    its key, part of the cache fingerprint, is the command line it equals.
    """
    import importlib.util
    from functools import partial
    from pathlib import Path

    from . import stages as S
    from .pipeline import Stage

    scene_p, out_p = Path(scene).resolve(), Path(out).resolve()
    have = lambda mod: importlib.util.find_spec(mod) is not None  # noqa: E731
    rec = scene_p / "reconstruction.npz"
    inputs_scene = [scene_p / "scene.yaml", scene_p / "primary" / "ee_poses.csv", scene_p / "secondary" / "ee_poses.csv"]
    cal, seg, grasp = out_p / "calibration", out_p / "segments", out_p / "grasps"
    cal_json, cloud, seg_npz = cal / "calibration.json", cal / "scene_b1.ply", seg / "segments.npz"
    stages = []
    if not rec.exists() and have("bimanual_app.reconstruction"):
        stages.append(Stage("reconstruct", partial(S.reconstruct, scene_p, backend),
                            inputs_scene + [scene_p / "primary" / "images", scene_p / "secondary" / "images"], [rec],
                            ["reconstruct", str(scene_p), "--backend", backend]))
    if have("calibration"):
        stages.append(Stage("calibrate", partial(S.calibrate, scene_p, cal), inputs_scene + [rec],
                            [cal_json, cloud, cal / "calibration.png"], ["calibrate", str(scene_p), "--out", str(cal)]))
    if have("segmentation"):
        masks = scene_p if S.scene_has_masks(scene_p) else None
        seg_inputs = [cloud, cal_json] + ([scene_p / "primary" / "masks", scene_p / "secondary" / "masks"] if masks else [])
        stages.append(Stage("segment", partial(S.segment, cloud, seg, cal_json, masks), seg_inputs,
                            [seg_npz, seg / "segments.png"],
                            ["segment", str(cloud), "--out", str(seg), "--calibration", str(cal_json)]
                            + (["--masks", str(scene_p)] if masks else [])))
    if have("grasping"):
        stages.append(Stage("grasp", partial(S.grasp, cloud, seg_npz, cal_json, grasp), [cloud, cal_json, seg_npz],
                            [grasp / "grasps.json", grasp / "grasps.png"],
                            ["grasp", str(cloud), "--segments", str(seg_npz), "--calibration", str(cal_json),
                             "--out", str(grasp)]))
    if have("bimanual_app.tasks"):
        for task in ("joint-grasp", "handover"):
            d = out_p / "tasks" / task
            stages.append(Stage(task, partial(S.task, task, scene_p, out_p, d),
                                [cal_json, seg_npz, grasp / "grasps.json"], [d / "task.json"],
                                ["task", task, str(scene_p), "--work", str(out_p), "--out", str(d)], optional=True))
    return [s for s in stages if s.name not in set(skip)]


def run(args: argparse.Namespace) -> int:
    import sys

    from bimanual_app.io_utils import check_output_dir, write_json
    from bimanual_app.scene import validate_scene

    from .pipeline import run_stages
    from .report import write_report

    out = check_output_dir(args.out)
    scene, problems = validate_scene(args.scene)
    warnings = [str(p) for p in problems if p.severity == "warning"]
    if scene is None:
        from bimanual_app.io_utils import InputError

        raise InputError([p for p in problems if p.severity == "error"])
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "run.json", {"format": 1, "scene": str(scene.path.resolve())})  # lets `bijcr view` find the scene
    stages = build_stages(args.scene, args.out, args.backend, tuple(args.skip))
    _preview(scene, out)
    # the report describes one finished run: an earlier one's goes now, so that a run stopped half-way
    # (Ctrl-C exits with 130) leaves none
    (out / "report.html").unlink(missing_ok=True)

    def on_start(st, k, n):
        print(f"[{k + 1}/{n}] {st.name} ...", file=sys.stderr, flush=True)

    def on_end(rec):
        note = f" ({rec.message})" if rec.message else ""
        print(f"      {rec.name}: {rec.status} in {rec.seconds:.1f} s{note}", file=sys.stderr, flush=True)

    records = run_stages(stages, out / ".stages", force=args.force, on_start=on_start, on_end=on_end)
    path = write_report(out, scene.name, records, warnings, scene=scene)
    print(f"report: {path}")
    print(f"3D view: bijcr view {out}")
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
