"""Segmentation benchmark on ``bijcr synth`` scenes (issue 4).

    .venv/bin/python bench/segmentation.py [--quick] [--scenes N] [--work DIR] [--out docs/bench/segmentation.md]

Scenes: ``bimanual_app.synth.make_synthetic_scene(seed=i, views=8, objects=6, touching=0.5)`` (half the objects
placed in contact with a neighbour), cached under ``--work``. Clouds:

* ground truth: ``bimanual_app.synth.ground_truth_cloud(scene)``, the true metric cloud in b1 (table, floor
  and objects from the rendered depth of all 16 views, about 1.1M points) with per-point object labels;
* emulator: the scene's ``reconstruction.npz`` point maps (the foundation-model emulator at "paper" noise:
  1.5 deg / 10 mm per camera pose, 0.5 % depth noise, flying pixels at depth edges) mapped into b1 with the
  true ``T_w_b1`` and scale from ``ground_truth.yaml`` (``x_b1 = inv(T_w_b1) (scale x_w)``), confidence
  and self filtered like ``bijcr calibrate`` (each wrist camera's gripper, points other views see through); its labels come from the masks at each point-map pixel (robots and
  everything else unlabelled = -1).

Each cloud is segmented without and with the scene's masks (``MaskViews.from_scene`` with the true
transform), and by the plain distance-clustering reference (the same table fit and 5 mm voxels, then
Open3D DBSCAN, eps 1 cm). The robot bases (b1's origin and the true ``T_b1_b2``) are passed as ``bases``,
as ``bijcr segment`` does with a calibration.json. Metrics over the objects with at least 500 points in the
cloud: recall (true objects matched at IoU >= 0.7), precision (segments matching a true object at IoU >= 0.7),
mean best IoU, over-segmentation (true objects split over two segments each holding >= 10 % of it) and
under-segmentation (segments holding most of the points of two or more true objects), and the object dimension error
(%) of the segments' upright boxes against the true sizes (the paper's scale check), for primitives (boxes,
cylinders) and for meshes. Timing: 100k / 500k / 2M points from the first scene's cloud (subsets, or
jittered copies for 2M), against the DBSCAN reference on the same cloud in the same run. Targets print
PASS/FAIL.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MIN_POINTS = 500  # true objects with fewer points in the cloud are not counted (hidden from all views)
PRIMITIVES = {"box", "small_box", "large_box", "cylinder"}
TARGETS = {"recall": 0.95, "precision": 0.9, "miou": 0.85, "time500k": 3.0}


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------------ scenes

def make_scene(work: Path, seed: int) -> Path:
    """The bench's scene of ``seed`` under ``work`` (8 views per arm, 6 objects, half touching), made when missing."""
    from bimanual_app.synth import make_synthetic_scene

    path = work / f"scene{seed:02d}"
    if not (path / "ground_truth.yaml").is_file():
        log(f"generating {path} (seed {seed}, 8 views per arm, 6 objects, half touching)")
        make_synthetic_scene(path, seed=seed, views=8, objects=6, touching=0.5, overwrite=True,
                             progress=False, preview=False)
    return path


def make_scenes(work: Path, n: int) -> list[Path]:
    return [make_scene(work, seed) for seed in range(n)]


class Scene:
    """One synth scene: its clouds, truth, bases and masks."""

    def __init__(self, path: Path):
        from bimanual_app.scene import load_scene
        from bimanual_app.synth import ground_truth_cloud
        from bimanual_app.transforms import inv_T

        self.path = path
        self.scene = load_scene(path)
        gt = self.scene.ground_truth
        self.objects = gt.objects
        self.T_b1_w = inv_T(np.asarray(gt.extras["T_w_b1"], dtype=np.float64))
        self.scale = float(gt.scale)
        self.bases = [np.zeros(3), gt.T_b1_b2[:3, 3]]
        cache = path / "gt_cloud.npz"
        if cache.is_file():
            z = np.load(cache)
            self.gt = (z["P"], z["C"], z["L"])
        else:
            self.gt = ground_truth_cloud(path)
            np.savez(cache, P=self.gt[0], C=self.gt[1], L=self.gt[2])
        self.emu = self._emulator_cloud()

    def _emulator_cloud(self):
        from PIL import Image

        from calibration._fusion import free_space_outliers
        from calibration._selfmask import wrist_rig_pixels

        rec = self.scene.reconstruction
        # the self filters of `bijcr calibrate` (calibration.scene_cloud): each wrist camera's own gripper,
        # and points the other views see through
        drop = free_space_outliers(rec.pts3d, rec.T_w_c)
        for arm in self.scene.arms:
            mine = np.flatnonzero(np.asarray(rec.arm) == arm.index)
            drop[mine] |= wrist_rig_pixels(rec.pts3d[mine], rec.T_w_c[mine])[None]
        P, C, L = [], [], []
        for arm in self.scene.arms:
            _, rows = rec.rows_for(arm.index, arm.images)
            for j in rows:
                key = str(rec.image[j])
                mask = np.asarray(Image.open(self.path / arm.name / "masks" / f"{Path(key).stem}.png"))
                H, W = rec.pts3d.shape[1:3]
                vv = np.minimum(((np.arange(H) + 0.5) * mask.shape[0] / H).astype(int), mask.shape[0] - 1)
                uu = np.minimum(((np.arange(W) + 0.5) * mask.shape[1] / W).astype(int), mask.shape[1] - 1)
                ids = mask[vv[:, None], uu[None, :]].astype(np.int32) - 1
                conf = rec.conf[j]
                ok = (conf > 0.2 * np.median(conf[conf > 0])) & np.all(np.isfinite(rec.pts3d[j]), axis=-1) & ~drop[j]
                p = rec.pts3d[j][ok].astype(np.float64) * self.scale
                P.append(p @ self.T_b1_w[:3, :3].T + self.T_b1_w[:3, 3])
                C.append(rec.colors[j][ok])
                L.append(ids[ok])
        return np.concatenate(P), np.concatenate(C).astype(np.uint8), np.concatenate(L)

    def masks(self):
        from segmentation import MaskViews

        return MaskViews.from_scene(self.path, self.T_b1_w, self.scale)


# ------------------------------------------------------------------------------------------ methods

def dbscan_reference(points, colors=None, bases=None, voxel=0.005, eps=0.01, min_points=5):
    """Plain distance clustering with the same front end: table fit, 5 mm voxels, Open3D DBSCAN, back to points."""
    import open3d as o3d

    from segmentation import SegmentParams
    from segmentation._table import fit_table, on_table_mask
    from segmentation._voxels import voxelize

    p = SegmentParams()
    table = fit_table(points, p)
    pt = table.to_table(points)
    cand = (pt[:, 2] > table.min_height) & (pt[:, 2] < p.max_height) & on_table_mask(table, pt, p.table_margin)
    for b in table.to_table(np.asarray(bases, dtype=np.float64).reshape(-1, 3)) if bases is not None else []:
        cand &= np.hypot(pt[:, 0] - b[0], pt[:, 1] - b[1]) > p.base_radius
    idx = np.flatnonzero(cand)
    labels = np.full(len(points), -1, np.int32)
    if len(idx) == 0:
        return labels
    vox = voxelize(pt[idx], voxel)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(vox.xyz))
    lab = np.asarray(pc.cluster_dbscan(eps, min_points), dtype=np.int32)
    K = int(lab.max()) + 1
    if K > 0:  # the same size / height filter as the segmenter
        n = np.bincount(lab[lab >= 0], minlength=K)
        top = np.full(K, -np.inf)
        np.maximum.at(top, lab[lab >= 0], vox.xyz[lab >= 0, 2])
        keep = (n >= p.min_object_voxels) & (top >= p.min_object_height)
        remap = np.full(K, -1, np.int32)
        remap[keep] = np.arange(int(keep.sum()), dtype=np.int32)
        lab = np.where(lab >= 0, remap[np.maximum(lab, 0)], -1)
    labels[idx] = lab[vox.inverse]
    return labels


def ours(points, colors, bases, masks=None):
    from segmentation import segment

    return segment(points, colors, mask_ids=masks, bases=bases)


# ------------------------------------------------------------------------------------------ metrics

def score(gt: np.ndarray, pred: np.ndarray) -> dict:
    """Recall / precision at IoU 0.7, mean best IoU, over- and under-segmentation counts."""
    K = int(gt.max()) + 1
    P = int(pred.max()) + 1 if (pred >= 0).any() else 0
    gs = np.bincount(gt[gt >= 0], minlength=K)
    vis = gs >= MIN_POINTS
    inter = np.zeros((K, max(P, 1)))
    m = (gt >= 0) & (pred >= 0)
    np.add.at(inter, (gt[m], pred[m]), 1)
    ps = np.bincount(pred[pred >= 0], minlength=max(P, 1))
    iou = inter / (gs[:, None] + ps[None, :] - inter + 1e-9)
    best = iou.max(1)
    match = iou.argmax(1)
    frac_of_gt = inter / np.maximum(gs[:, None], 1)
    over = int(np.sum(vis & ((frac_of_gt >= 0.1).sum(1) >= 2)))
    under = int(np.sum((frac_of_gt[vis] >= 0.5).sum(0) >= 2)) if P else 0
    matched_pred = (iou[vis] >= 0.7).any(0) if P else np.zeros(0, bool)
    return {"gt": int(vis.sum()), "hidden": int((~vis).sum()), "pred": P,
            "tp": int(np.sum(best[vis] >= 0.7)), "pred_ok": int(matched_pred.sum()),
            "iou_sum": float(best[vis].sum()), "over": over, "under": under,
            "match": match, "best": best, "vis": vis}


def dimension_errors(sc: dict, result, objects: list[dict]) -> list[tuple[str, float]]:
    """(kind, mean % error of length/width/height) of each true object matched at IoU >= 0.7."""
    out = []
    for k, o in enumerate(objects):
        if k >= len(sc["best"]) or not sc["vis"][k] or sc["best"][k] < 0.7:
            continue
        ext = result.objects[int(sc["match"][k])].extents
        size = np.asarray(o["size"], dtype=np.float64)
        true = np.r_[np.sort(size[:2])[::-1], size[2]]
        out.append((str(o["kind"]), float(np.mean(np.abs(ext - true) / true) * 100.0)))
    return out


class Tally:
    def __init__(self):
        self.n = dict(gt=0, hidden=0, pred=0, tp=0, pred_ok=0, iou_sum=0.0, over=0, under=0)
        self.dims: list[tuple[str, float]] = []
        self.times: list[float] = []

    def add(self, sc: dict, dims=None, t=None):
        for k in self.n:
            self.n[k] += sc[k]
        self.dims += dims or []
        if t is not None:
            self.times.append(t)

    def row(self) -> dict:
        n = self.n
        prim = [e for k, e in self.dims if k in PRIMITIVES]
        mesh = [e for k, e in self.dims if k not in PRIMITIVES]
        return {"recall": n["tp"] / max(n["gt"], 1), "precision": n["pred_ok"] / max(n["pred"], 1),
                "miou": n["iou_sum"] / max(n["gt"], 1), "over": n["over"], "under": n["under"],
                "gt": n["gt"], "hidden": n["hidden"], "pred": n["pred"],
                "dim_prim": (np.mean(prim), np.max(prim)) if prim else None,
                "dim_mesh": (np.mean(mesh), np.max(mesh)) if mesh else None,
                "time": statistics.median(self.times) if self.times else None}


# ------------------------------------------------------------------------------------------ timing

def timing(points, colors, bases, sizes, repeats) -> list[dict]:
    rng = np.random.default_rng(0)
    rows = []
    for n in sizes:
        if n <= len(points):
            idx = rng.choice(len(points), n, replace=False)
            P, C = points[idx], colors[idx]
        else:  # jittered copies (0.3 mm): a denser cloud of the same scene
            k = n // len(points) + 1
            P = np.concatenate([points + rng.normal(scale=0.0003, size=points.shape) for _ in range(k)])[:n]
            C = np.concatenate([colors] * k)[:n]
        t_ours, t_ref = [], []
        for _ in range(repeats if n < 1_000_000 else max(1, repeats - 1)):
            t0 = time.perf_counter()
            r = ours(P, C, bases)
            t_ours.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            dbscan_reference(P, C, bases)
            t_ref.append(time.perf_counter() - t0)
        to, tr = statistics.median(t_ours), statistics.median(t_ref)
        rows.append({"n": n, "ours": to, "ref": tr, "stages": r.timings, "voxels": r.stats.get("voxels"),
                     "patches": r.stats.get("patches")})
        log(f"timing {n}: {to:.2f} s (reference {tr:.2f} s)")
    return rows


def cli_time(points, colors, work: Path) -> float:
    """Wall time of ``bijcr segment`` on a PLY (process start-up, imports and writing included)."""
    import open3d as o3d

    ply = work / "timing_500k.ply"
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.colors = o3d.utility.Vector3dVector(colors.astype(np.float64) / 255.0)
    o3d.io.write_point_cloud(str(ply), pc)
    t0 = time.perf_counter()
    subprocess.run([str(ROOT / ".venv" / "bin" / "bijcr"), "segment", str(ply), "--out", str(work / "cli_out"),
                    "--quiet"], check=True)
    return time.perf_counter() - t0


# ------------------------------------------------------------------------------------------ report

def fmt_dim(d):
    return "-" if d is None else f"{d[0]:.1f} ({d[1]:.1f})"


def report(args, rows: dict, times: list[dict], t_cli: float | None, n_scenes: int) -> str:
    lines = ["# Segmentation benchmark", "",
             f"Command: `nice .venv/bin/python bench/segmentation.py{' --quick' if args.quick else ''}`", "",
             f"{n_scenes} `bijcr synth` scenes (seeds 0-{n_scenes - 1}; 6 objects, half placed touching a "
             "neighbour; 8 views per arm). Objects with fewer than "
             f"{MIN_POINTS} points in a cloud are not counted (hidden from every view). Robot bases passed as "
             f"background. Machine: {os.cpu_count()} CPU cores shared with other jobs, load average "
             f"{os.getloadavg()[0]:.1f} at the end.", "",
             "## Accuracy", "",
             "| cloud | method | recall @ IoU 0.7 | precision | mean IoU | over-seg. | under-seg. | objects (hidden) / segments "
             "| dimension error % primitives, mean (max) | meshes, mean (max) | median time |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for (cloud, method), t in rows.items():
        r = t.row()
        lines.append(f"| {cloud} | {method} | {r['recall']:.3f} | {r['precision']:.3f} | {r['miou']:.3f} | {r['over']} | "
                     f"{r['under']} | {r['gt']} ({r['hidden']}) / {r['pred']} | {fmt_dim(r['dim_prim'])} | "
                     f"{fmt_dim(r['dim_mesh'])} | {r['time']:.2f} s |")
    main = rows[("ground truth", "graph segmenter")].row()
    lines += ["", "## Targets (ground-truth clouds, no masks)", "", "| target | value | result |", "| --- | --- | --- |"]
    for key, name in (("recall", "recall >= 0.95"), ("precision", "precision >= 0.9"), ("miou", "mean IoU >= 0.85")):
        ok = main[key] >= TARGETS[key]
        lines.append(f"| {name} | {main[key]:.3f} | {'PASS' if ok else 'FAIL'} |")
    t500 = next((t for t in times if t["n"] == 500_000), None)
    if t500:
        lines.append(f"| 500k points < 3 s (2 cores) | {t500['ours']:.2f} s | {'PASS' if t500['ours'] < 3.0 else 'FAIL'} |")
    lines += ["", "## Speed", "",
              "`segment()` in a warm process (imports done), median of repeated runs; reference: the same table fit and "
              "5 mm voxels, then Open3D DBSCAN (eps 1 cm) and label propagation, on the same cloud in the same run.", "",
              "| points | graph segmenter | reference (voxels + DBSCAN) | ratio | voxels / patches | stages (s) |",
              "| --- | --- | --- | --- | --- | --- |"]
    for t in times:
        st = ", ".join(f"{k} {v:.2f}" for k, v in t["stages"].items() if k != "total")
        lines.append(f"| {t['n']:,} | {t['ours']:.2f} s | {t['ref']:.2f} s | {t['ours'] / t['ref']:.2f} x | "
                     f"{t['voxels']} / {t['patches']} | {st} |")
    if t_cli is not None:
        lines.append(f"\n`bijcr segment` on a 500k-point PLY, as a new process (start-up, imports of Open3D / "
                     f"matplotlib, reading, writing npz/json/png included): {t_cli:.1f} s wall.")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 scenes, fewer timing repeats")
    ap.add_argument("--scenes", type=int, help="number of synth scenes (default 8, quick 2)")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "bijcr-bench-segmentation",
                    help="where the generated scenes are cached")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "segmentation.md")
    args = ap.parse_args()
    n_scenes = args.scenes or (2 if args.quick else 8)
    args.work.mkdir(parents=True, exist_ok=True)
    paths = make_scenes(args.work, n_scenes)

    import open3d  # noqa: F401

    import segmentation  # noqa: F401  (imports outside the timed regions)

    rows: dict = {}
    for path in paths:
        log(f"scene {path.name}")
        sc = Scene(path)
        masks = sc.masks()
        for cloud, (P, C, L) in (("ground truth", sc.gt), ("emulator (paper noise)", sc.emu)):
            for method in ("graph segmenter", "graph segmenter + masks", "reference: DBSCAN"):
                t0 = time.perf_counter()
                if method == "reference: DBSCAN":
                    lab, res = dbscan_reference(P, C, sc.bases), None
                else:
                    res = ours(P, C, sc.bases, masks if "masks" in method else None)
                    lab = res.labels
                dt = time.perf_counter() - t0
                s = score(L, lab)
                dims = dimension_errors(s, res, sc.objects) if res is not None else []
                rows.setdefault((cloud, method), Tally()).add(s, dims, dt)
                log(f"  {cloud} / {method}: {s['tp']}/{s['gt']} found, {s['pred']} segments, {dt:.2f} s")
    first = Scene(paths[0])
    times = timing(first.gt[0], first.gt[1], first.bases, (100_000, 500_000, 2_000_000), 2 if args.quick else 3)
    rng = np.random.default_rng(1)
    idx = rng.choice(len(first.gt[0]), 500_000, replace=False)
    t_cli = cli_time(first.gt[0][idx], first.gt[1][idx], args.work)
    text = report(args, rows, times, t_cli, n_scenes)
    print(text)
    from bench._doc import save_report

    save_report(args.out, text)  # the runs before stay below the new table
    log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
