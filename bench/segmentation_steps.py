"""Segmentation clean-up steps, each left out in turn, on the clouds ``bijcr calibrate`` makes (issue 22).

    .venv/bin/python bench/segmentation_steps.py [--first-seed S] [--scenes N] [--jobs J] [--address A]
        [--work DIR] [--no-save]

Why: the segmenter's clean-up after the contraction (``segmentation._cleanup``: attach parts, the bunny-ears rule,
dissolve slivers, split by tops, the level-tops rule, shed walls, carton neighbours) was added step by step for
particular scenes. This measures what each step does on scenes none of them was made for: the full segmenter
against the same one with that step (or rule) left out (``SegmentParams(skip=...)``), and with every step
left out, scene by scene on the same clouds.

Scenes: ``make_synthetic_scene(seed, views=8, objects=6, touching=0.5)`` (as ``bench/segmentation.py``: half the
objects touch a neighbour), seeds S..S+N-1 (default 28000-28029, a range no step was tuned on), cached under
``--work``. Cloud: the one ``bijcr calibrate`` writes (``calibration.calibrate`` then ``scene_cloud``: each view
placed by the calibrated kinematics, the robots and what other views see through removed), with the
calibrated ``T_b1_b2`` as the second base; each of its points takes the object id of the nearest point of the
scene's true cloud within 6 mm (-1: the table, or no true surface that near). Metrics as in
``bench/segmentation.py`` over the objects with at least 500 points: recall and precision at IoU 0.7, mean best
IoU, over- and under-segmentation, and, against the full segmenter, the true objects whose best IoU rose or
fell by more than 0.05. The scenes run as Ray tasks (``bench/_ray.py``; local by default, ``--address`` for
a cluster).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LABEL_TOL = 0.006  # m: a cloud point is a true object's when that object's surface lies this near
CHANGED = 0.05  # an object's best IoU moved by more than this
FIRST_SEED = 28000
N_SCENES = 30


def log(msg: str) -> None:
    print(f"[bench segmentation_steps] {msg}", file=sys.stderr, flush=True)


def variants() -> list[tuple[str, tuple[str, ...]]]:
    """(row name, steps skipped): the full segmenter, each step left out, every step left out."""
    from segmentation import CLEANUP_STEPS

    return [("none (all steps)", ())] + [(s, (s,)) for s in CLEANUP_STEPS] + [("all steps", tuple(CLEANUP_STEPS))]


def true_labels(points: np.ndarray, scene: Path) -> np.ndarray:
    """(N,) the true object id of each cloud point (N, 3): the nearest true-cloud point's within LABEL_TOL, else -1."""
    from scipy.spatial import cKDTree

    from bimanual_app.synth import ground_truth_cloud

    P, _, L = ground_truth_cloud(scene, voxel=0.002)
    d, j = cKDTree(P).query(points, distance_upper_bound=LABEL_TOL)
    return np.where(np.isfinite(d), L[np.minimum(j, len(L) - 1)], -1).astype(np.int32)


def run_scene(job: tuple[int, str]) -> dict:
    """One scene: make it (when missing), calibrate it, segment its cloud with every variant; the scores."""
    seed, work = job
    from bench.segmentation import make_scene, score
    from bimanual_app.scene import load_scene
    from calibration import calibrate
    from calibration._api import scene_cloud_and_views
    from segmentation import SegmentParams, segment

    path = make_scene(Path(work), seed)
    sc = load_scene(path)
    result = calibrate(sc)
    points, colors, _, _, unsure = scene_cloud_and_views(sc, result)  # the cloud and flags bijcr calibrate writes
    labels = true_labels(points, path)
    bases = np.array([np.zeros(3), result.T_b1_b2[:3, 3]])
    out = {"seed": seed, "rows": {}}
    for name, skip in variants():
        s = score(labels, segment(points, colors, bases=bases, params=SegmentParams(skip=skip), unsure=unsure).labels)
        out["rows"][name] = {k: s[k] for k in ("gt", "hidden", "pred", "tp", "pred_ok", "iou_sum", "over", "under")}
        out["rows"][name]["best"] = np.where(s["vis"], s["best"], np.nan).tolist()
    return out


def table(results: list[dict]) -> list[str]:
    """The markdown rows: per variant, totals over the scenes and the objects it changed against the full one."""
    from bench.segmentation import Tally

    L = ["| left out | recall @ IoU 0.7 | precision | mean IoU | over-seg. | under-seg. | segments "
         f"| objects better / worse (IoU +-{CHANGED}) than with every step |",
         "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, _ in variants():
        tally, better, worse = Tally(), 0, 0
        for r in results:
            tally.add(r["rows"][name])
            d = np.array(r["rows"][name]["best"]) - np.array(r["rows"]["none (all steps)"]["best"])
            better += int(np.sum(d > CHANGED))
            worse += int(np.sum(d < -CHANGED))
        t, n = tally.row(), tally.n
        L.append(f"| {name} | {t['recall']:.3f} ({n['tp']}/{n['gt']}) | {t['precision']:.3f} | {t['miou']:.3f} | "
                 f"{t['over']} | {t['under']} | {t['pred']} | {better} / {worse} |")
    return L


def report(args, results: list[dict], failed: list[str], minutes: float) -> str:
    seeds = f"{args.first_seed}-{args.first_seed + args.scenes - 1}"
    where = f"cluster {args.address}" if args.address else f"local, {args.jobs or os.cpu_count()} CPUs"
    cmd = "nice .venv/bin/python bench/segmentation_steps.py" + (
        f" --first-seed {args.first_seed} --scenes {args.scenes}"
        if (args.first_seed, args.scenes) != (FIRST_SEED, N_SCENES) else "")
    L = ["# Segmentation clean-up steps, each left out", "", f"Command: `{cmd}`", "",
         f"{len(results)} `bijcr synth` scenes, seeds {seeds} (8 views per arm, 6 objects, half touching a neighbour), "
         "each calibrated as `bijcr calibrate` does and segmented on that cloud with every clean-up step, with each "
         "step (or rule) left out, and with all of them left out; objects with fewer than 500 points in the cloud "
         f"are not counted. {minutes:.1f} min on Ray ({where}).",
         ""] + table(results)
    if failed:
        L += ["", "Scenes that did not run: " + "; ".join(failed)]
    return "\n".join(L) + "\n"


def main() -> int:
    from bench._ray import SceneError, map_scenes

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--first-seed", type=int, default=FIRST_SEED, help=f"first seed (default {FIRST_SEED})")
    ap.add_argument("--scenes", type=int, default=N_SCENES, help=f"number of scenes (default {N_SCENES})")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "bijcr-bench-segmentation-steps",
                    help="where the generated scenes are cached")
    ap.add_argument("--jobs", type=int, help="CPUs of the local Ray instance (default: all cores)")
    ap.add_argument("--address", help="join this Ray cluster (e.g. auto) instead of starting Ray here")
    ap.add_argument("--no-save", action="store_true", help="do not write docs/bench/segmentation_steps.md")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    jobs = [(s, str(args.work)) for s in range(args.first_seed, args.first_seed + args.scenes)]
    t0 = time.perf_counter()

    def progress(done, total, i, r):
        log(f"{done}/{total} seed {jobs[i][0]}" + (f": {r}" if isinstance(r, SceneError) else ""))

    out = map_scenes(run_scene, jobs, address=args.address, num_cpus=args.jobs, progress=progress,
                     return_exceptions=True)
    results = [r for r in out if not isinstance(r, SceneError)]
    failed = [f"seed {j[0]}: {r}" for j, r in zip(jobs, out) if isinstance(r, SceneError)]
    text = report(args, results, failed, (time.perf_counter() - t0) / 60)
    print(text)
    if not args.no_save:
        from bench._doc import save_report

        path = save_report(ROOT / "docs" / "bench" / "segmentation_steps.md", text)  # the runs before stay below
        log(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
