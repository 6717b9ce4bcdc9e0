"""Task benchmark (issue 7): joint grasp and hand-over on synthetic scenes, judged against reality.

    nice .venv/bin/python bench/tasks.py [--quick] [--scenes N] [--first-seed S] [--fresh] [--no-save] [--with-masks]
        [--jobs N] [--seeds 2,11,16] [--tasks handover] [--modes pipeline]

``--seeds``, ``--tasks`` and ``--modes`` run a subset (to look into failures; the saved table is the full run's).

For each of N ``bijcr synth`` scenes (seeds S..S+N-1; 20 by default, 3 with --quick; 8 views per arm,
5 objects, the emulator's "paper" noise), both tasks run twice:

- **pipeline**: everything from the pipeline: ``calibrate`` (the calibrated T_b1_b2 and metric cloud),
  ``segment``, ``grasp``, then the task's plan and its PyBullet preview on the reconstruction;
- **ground-truth transforms**: calibration.json written from ground_truth.yaml (hand-eye, T_b1_b2, scale,
  frame w) and the true metric cloud (``bimanual_app.synth.ground_truth_cloud``) as scene_b1.ply; then the
  same ``segment``, ``grasp`` and task.

``segment`` runs without the scenes' per-image masks in both modes, although ``bijcr run`` and ``bijcr task``
use masks when a scene has them: the synthetic scenes' masks are exact renders, which a lab's would not be.
``--with-masks`` adds a third mode, the pipeline with those masks given to the segmenter (as ``bijcr run``
does), to show what segmentation costs.

A task counts as a success when the *same plan* also succeeds in the ground-truth world: the true objects
(ground_truth.yaml: pose, size, mass) and the secondary arm at its true base pose
(``TaskOptions(compare_truth=True)``): the plan is executed in reality, not in the world it was planned
in. The table also reports how often the preview on the reconstruction agreed with reality. Planning
failures (no grasp, no plan) count as failures. The scenes and stage outputs are kept under
``runs/bench_tasks/`` and reused (``--fresh`` re-makes them). Saves the output to docs/bench/tasks.md.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TASKS = ("joint-grasp", "handover")
MODES = ("pipeline", "masks", "gt")
MODE_NAME = {"pipeline": "pipeline (calibrated)", "masks": "pipeline (calibrated), segmented with the masks",
             "gt": "ground-truth transforms"}
TARGET = 0.90


def _log(msg: str) -> None:
    print(f"[bench tasks] {msg}", file=sys.stderr, flush=True)


def make_scene(base: Path, seed: int, fresh: bool) -> tuple[Path, float]:
    """The synthetic scene of ``seed`` (made once, then reused); returns (folder, seconds spent now)."""
    from bimanual_app.synth import make_synthetic_scene

    path = base / "scenes" / f"synth_{seed:03d}"
    if fresh and path.exists():
        shutil.rmtree(path)
    if (path / "scene.yaml").exists():
        return path, 0.0
    t = time.perf_counter()
    with contextlib.redirect_stderr(io.StringIO()):
        make_synthetic_scene(path, seed=seed, views=8, objects=5, noise="paper", progress=False)
    return path, time.perf_counter() - t


def write_gt_calibration(scene_path: Path, cal_dir: Path) -> float:
    """calibration.json from the ground truth and the true cloud as scene_b1.ply (once); returns seconds."""
    import open3d as o3d

    from bimanual_app.io_utils import atomic_path, write_json
    from bimanual_app.scene import load_scene
    from bimanual_app.synth import ground_truth_cloud

    if (cal_dir / "calibration.json").exists() and (cal_dir / "scene_b1.ply").exists():
        return 0.0
    t = time.perf_counter()
    scene = load_scene(scene_path)
    gt = scene.ground_truth
    T_b1_w = np.linalg.inv(np.asarray(gt.extras["T_w_b1"], dtype=np.float64))
    pts, cols, _ = ground_truth_cloud(scene_path, voxel=0.002)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.colors = o3d.utility.Vector3dVector(cols.astype(np.float64) / 255.0)
    cal_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(cal_dir / "scene_b1.ply") as tmp:
        o3d.io.write_point_cloud(str(tmp), pc)
    write_json(cal_dir / "calibration.json", {
        "format": 1, "scene": scene.name, "scale": gt.scale, "T_e1_c1": gt.T_e1_c1, "T_e2_c2": gt.T_e2_c2,
        "T_b1_w": T_b1_w, "T_b2_w": np.linalg.inv(gt.T_b1_b2) @ T_b1_w, "T_b1_b2": gt.T_b1_b2,
        "views_used": {"primary": len(scene.primary), "secondary": len(scene.secondary)},
        "residuals": {"rotation_rad": 0.0, "translation_m": 0.0}, "method": "ground truth (bench/tasks.py)"})
    return time.perf_counter() - t


def run_one(scene: Path, work: Path, task: str, masks: bool = False) -> dict:
    """One task run; returns the facts the table needs."""
    from bimanual_app.io_utils import InputError
    from bimanual_app.tasks import TaskOptions, run_task

    out = work / "tasks" / task
    t = time.perf_counter()
    row = {"task": task, "planned": False, "estimate_ok": False, "truth_ok": False, "stage": "", "reason": "",
           "timings": {}}
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            res = run_task(TaskOptions(task, str(scene), work=str(work), out=str(out), quiet=True, record=False,
                                       compare_truth=True, masks=masks))
        rec = res.record
        row["timings"] = dict(res.timings)
        row["planned"] = bool(rec.get("plans"))
        row["estimate_ok"] = bool(rec.get("preview", {}).get("success"))
        truth = rec.get("preview_truth") or {}
        row["truth_ok"] = bool(truth.get("success"))
        row["stage"] = rec.get("failed_stage", "") if not row["truth_ok"] else ""
        row["reason"] = truth.get("reason", "") if row["planned"] else rec.get("reason", "")
        row["object"] = rec.get("object")
        row["sim_s"] = float(rec.get("preview", {}).get("sim_time_s", 0.0))
    except InputError as e:  # an earlier stage failed (e.g. no grasp at all): a failure of the pipeline
        row["stage"] = "input"
        row["reason"] = str(e).splitlines()[0][:200]
        row["timings"] = dict(getattr(e, "timings", {}))
    row["wall"] = time.perf_counter() - t
    return row


def run_scene(job) -> tuple[dict, dict, float]:
    """Every mode and task on one scene: (rows: mode -> task -> [row], stage seconds: mode -> stage -> [s],
    seconds spent making the scene)."""
    base, seed, i, n, modes, fresh, tasks = job
    scene, synth_dt = make_scene(base, seed, fresh)
    rows = {m: {t: [] for t in TASKS} for m in modes}
    stage_t = {m: {} for m in modes}
    for mode in modes:
        work = base / mode / scene.name
        if fresh and work.exists():
            shutil.rmtree(work)
        if mode == "gt":
            dt = write_gt_calibration(scene, work / "calibration")
            if dt:
                stage_t[mode].setdefault("ground-truth cloud", []).append(dt)
        for task in tasks:
            r = run_one(scene, work, task, masks=mode == "masks")
            rows[mode][task].append(r)
            for k, v in r["timings"].items():
                if k != "total":
                    stage_t[mode].setdefault(k, []).append(v)
            r["scene"] = scene.name
            _log(f"scene {i + 1}/{n} (seed {seed}) {mode:8s} {task:11s}: "
                 f"{'OK  ' if r['truth_ok'] else 'FAIL'} object {r.get('object')} ({r['wall']:.1f} s)"
                 + ("" if r["truth_ok"] else f" [{r['stage']}] {r['reason'][:150]}"))
    return rows, stage_t, synth_dt


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 scenes")
    ap.add_argument("--scenes", type=int, default=None, help="number of scenes (default 20, 3 with --quick)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--fresh", action="store_true", help="re-make the scenes and every stage output")
    ap.add_argument("--no-save", action="store_true", help="do not write docs/bench/tasks.md")
    ap.add_argument("--base", default=str(ROOT / "runs" / "bench_tasks"), help="cache folder")
    ap.add_argument("--jobs", type=int, default=1, help="scenes run in parallel (processes)")
    ap.add_argument("--with-masks", action="store_true",
                    help="also run the pipeline with the scenes' (exact, synthetic) masks given to the segmenter")
    ap.add_argument("--seeds", default=None, help="comma-separated seeds instead of --first-seed/--scenes")
    ap.add_argument("--tasks", default=",".join(TASKS), help="comma-separated tasks (default both)")
    ap.add_argument("--modes", default=None, help="comma-separated modes: pipeline, gt (and masks with --with-masks)")
    args = ap.parse_args()
    modes = [m for m in MODES if m != "masks" or args.with_masks]
    if args.modes:
        modes = [m for m in modes if m in args.modes.split(",")]
    tasks = [t for t in TASKS if t in args.tasks.split(",")]
    subset = bool(args.seeds) or tasks != list(TASKS) or modes != [m for m in MODES if m != "masks" or args.with_masks]
    if subset:
        args.no_save = True
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    n = args.scenes or (3 if args.quick else 20)
    base = Path(args.base)
    seeds = [int(x) for x in args.seeds.split(",")] if args.seeds else list(range(args.first_seed, args.first_seed + n))
    n = len(seeds)
    rows = {m: {t: [] for t in TASKS} for m in modes}
    stage_t = {m: {} for m in modes}
    synth_s = []
    t_all = time.perf_counter()
    jobs = [(base, seed, i, n, modes, args.fresh, tasks) for i, seed in enumerate(seeds)]
    if args.jobs > 1:  # scenes in parallel (one process each at a time); results gathered in seed order
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # one fresh process per scene: OMPL takes its random seed once per process, so a worker that ran
        # other scenes first would plan this one from another point of its random sequence (which scene a
        # worker gets depends on timing: the table changed from run to run by a scene either way)
        with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn"),
                                 max_tasks_per_child=1) as ex:
            results = list(ex.map(run_scene, jobs))
    else:
        results = [run_scene(j) for j in jobs]
    for scene_rows, scene_t, dt in results:
        if dt:
            synth_s.append(dt)
        for mode in modes:
            for task in TASKS:
                rows[mode][task] += scene_rows[mode][task]
            for k, v in scene_t[mode].items():
                stage_t[mode].setdefault(k, []).extend(v)
    total = time.perf_counter() - t_all
    text = report(rows, stage_t, synth_s, n, seeds, total, args)
    print(text)
    if not args.no_save:
        from bimanual_app.io_utils import atomic_open

        with atomic_open(ROOT / "docs" / "bench" / "tasks.md") as f:
            f.write(text)
    ok = all(np.mean([r["truth_ok"] for r in rows["pipeline"][t]]) >= TARGET
             for t in TASKS if rows.get("pipeline", {}).get(t))
    return 0 if ok else 1


def report(rows, stage_t, synth_s, n, seeds, total, args) -> str:
    cmd = "nice .venv/bin/python bench/tasks.py" + (" --quick" if args.quick else "") + \
        (f" --scenes {args.scenes}" if args.scenes else "") + (" --with-masks" if args.with_masks else "") + \
        (f" --jobs {args.jobs}" if args.jobs > 1 else "")
    L = ["# Task benchmark (joint grasp, hand-over)", "",
         f"Command: `{cmd}`", "",
         f"{n} synthetic scenes (`bijcr synth`, seeds {seeds[0]}..{seeds[-1]}, 8 views per arm, 5 objects, "
         "paper noise). Success = the plan also succeeds physically in the ground-truth world (true objects, "
         "true secondary base): object up 10 cm and held 2 s by both grippers (joint grasp) / by the secondary "
         "only after the release (hand-over). Planning failures count as failures. "
         f"Total {total / 60:.1f} min on {os.cpu_count()} cores.", "",
         "| task | transforms | success (reality) | target | result | planned | preview on the reconstruction: success / agrees with reality |",
         "| --- | --- | --- | --- | --- | --- | --- |"]
    modes = list(rows)
    ran = [t for t in TASKS if any(rows[m][t] for m in modes)]
    for task in ran:
        for mode in modes:
            rs = rows[mode][task]
            k = len(rs)
            succ = sum(r["truth_ok"] for r in rs)
            planned = sum(r["planned"] for r in rs)
            est = sum(r["estimate_ok"] for r in rs)
            agree = sum(r["estimate_ok"] == r["truth_ok"] for r in rs if r["planned"])
            target = f">= {TARGET * 100:.0f} %" if mode == "pipeline" else ""
            res = ("PASS" if succ / max(k, 1) >= TARGET else "FAIL") if mode == "pipeline" else ""
            L.append(f"| {task} | {MODE_NAME[mode]} | {succ}/{k} = {100 * succ / max(k, 1):.0f} % | {target} | {res} "
                     f"| {planned}/{k} | {est}/{k} / {agree}/{planned} |")
    L += ["", "Time per stage (median seconds per run; a stage's time counts only where it ran):", "",
          "| stage | " + " | ".join(MODE_NAME[m] for m in modes) + " | ratio |",
          "| --- " * (len(modes) + 2) + "|"]
    names = ["calibrate", "ground-truth cloud", "segment", "grasp", "load", "plan", "preview", "preview_truth"]
    sims = [r.get("sim_s", 0.0) for m in modes for t in TASKS for r in rows[m][t] if r.get("sim_s")]
    prev = [v for m in modes for v in stage_t[m].get("preview", [])]
    for s in names:
        vals = [stage_t[m].get(s, []) for m in modes]
        if not any(vals):
            continue
        cells = [f"{np.median(v):.2f} s (n={len(v)})" if v else "-" for v in vals]
        ratio = ""
        if s == "preview" and sims and prev:
            ratio = f"{np.median(prev) / np.median(sims):.2f} x simulated time"
        L.append(f"| {s} | {' | '.join(cells)} | {ratio} |")
    if synth_s:
        L.append(f"| (making a synthetic scene) | {np.median(synth_s):.1f} s (n={len(synth_s)}) |" + " |" * len(modes))
    fails = [(m, t, r) for m in modes for t in TASKS for r in rows[m][t] if not r["truth_ok"]]
    if fails:
        L += ["", "Failures:", ""]
        for m, t, r in fails:
            L.append(f"- {r.get('scene')}, {MODE_NAME[m]}, {t}, object {r.get('object')}: [{r['stage'] or 'preview'}] {r['reason'][:220]}")
    for task in ran:
        if not rows.get("pipeline", {}).get(task):
            continue
        rate = np.mean([r["truth_ok"] for r in rows["pipeline"][task]])
        L.append("")
        L.append(f"{'PASS' if rate >= TARGET else 'FAIL'}: {task} success with the pipeline's own calibration "
                 f"{rate * 100:.0f} % (target >= {TARGET * 100:.0f} %)")
    return "\n".join(L) + "\n"


if __name__ == "__main__":
    sys.exit(main())
