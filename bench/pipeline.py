"""Benchmark of the whole pipeline's speed: `bijcr run` on the demo scene and on synthetic bench scenes.

    .venv/bin/python bench/pipeline.py [--scenes N] [--quick] [--out docs/bench/pipeline.md]

For each scene, `bijcr run SCENE --out DIR` runs in a child process with a fresh output folder (no cached
stage), and the bench prints each stage's wall time and CPU time (the child times every stage it runs:
``bimanual_app.app.pipeline``'s stage runner, wrapped), the run's wall time and its peak resident memory
(``os.wait4``'s rusage of the child). Scenes: ``scenes/demo`` and ``--scenes`` synthetic captures
(``make_synthetic_scene(path, seed=100 + k, views=8, objects=5, noise="paper")``, made once under
``runs/bench_pipeline/scenes/`` and reused; seeds the other benches do not tune on). ``--quick``: the demo only.

Speed is set against a yardstick measured in the same run: the wall time of ``bijcr check scenes/demo``
(start-up and reading a scene), so that the ratio column compares across machines and loads.

Targets (2-core machine): ``bijcr run scenes/demo`` <= 25 s; grasp stage <= 5 s (median over the scenes);
one task (plan + physics preview) <= 8 s (median over the tasks that ran to the end, both kinds, all scenes);
calibrate <= 2 s (median); peak
RSS of the demo run <= 1.5 GB. Exit 0 when every run ran (a FAIL row is a finding, not an error).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WORK = ROOT / "runs" / "bench_pipeline"
TASKS = ("joint-grasp", "handover")
TARGETS = {"run": 25.0, "grasp": 5.0, "task": 8.0, "calibrate": 2.0, "rss_gb": 1.5}


def _child(scene: str, out: str, record: str) -> int:
    """In the child: `bijcr run SCENE --out OUT`, each stage timed in wall and CPU time into RECORD (json)."""
    import resource

    sys.path.insert(0, str(ROOT))
    import bimanual_app.app.pipeline as pipeline
    from bimanual_app.cli import main

    times: dict[str, dict] = {}
    run_one = pipeline._run_one

    def timed(st):
        w0, c0 = time.perf_counter(), time.process_time()
        rec = run_one(st)
        times[st.name] = {"wall": time.perf_counter() - w0, "cpu": time.process_time() - c0, "status": rec.status,
                          "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2}
        return rec

    pipeline._run_one = timed
    try:
        rc = main(["run", scene, "--out", out])
    except SystemExit as e:
        rc = int(e.code or 0)
    Path(record).write_text(json.dumps({"rc": rc, "stages": times}))
    return 0


def _spawn(argv: list[str]) -> tuple[float, int, float]:
    """Run argv; returns (wall s, exit status, peak RSS of the child in GB)."""
    t0 = time.perf_counter()
    p = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, ru = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    return time.perf_counter() - t0, p.returncode, ru.ru_maxrss / 1024 ** 2  # ru_maxrss: kB on Linux


def ensure_scene(seed: int) -> Path:
    sys.path.insert(0, str(ROOT))
    from bimanual_app.synth import make_synthetic_scene

    path = WORK / "scenes" / f"seed{seed:03d}_v8_o5"
    if not (path / "ground_truth.yaml").is_file():
        make_synthetic_scene(path, seed=seed, views=8, objects=5, noise="paper", progress=False, preview=False,
                             overwrite=True)
    return path


def run_scene(scene: Path, name: str) -> dict:
    out = WORK / "out" / name
    shutil.rmtree(out, ignore_errors=True)  # fresh: no cached stage
    record = WORK / "out" / f"{name}.json"
    record.parent.mkdir(parents=True, exist_ok=True)
    wall, rc, rss = _spawn([sys.executable, str(Path(__file__).resolve()), "--_child", str(scene), str(out), str(record)])
    rec = json.loads(record.read_text()) if record.is_file() else {"rc": None, "stages": {}}
    return {"name": name, "wall": wall, "rc": rec["rc"] if rc == 0 else rc, "rss_gb": rss, "stages": rec["stages"]}


def _verdict(value: float, target: float) -> str:
    return "PASS" if np.isfinite(value) and value <= target else "FAIL"


def report(runs: list[dict], yard: float, args) -> str:
    stages = []
    for r in runs:
        stages += [s for s in r["stages"] if s not in stages]
    lines = ["# Pipeline benchmark", "", "Command (from the repository root):", "",
             f"`nice .venv/bin/python bench/pipeline.py{' --quick' if args.quick else f' --scenes {args.scenes}'}`", "",
             f"Yardstick, measured in the same run: `bijcr check scenes/demo` took {yard:.2f} s wall; "
             "the ratio column is a time divided by it. Each `bijcr run` starts from an empty output folder.", "",
             "| scene | stage | wall s | CPU s | ratio | peak RSS so far | status |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in runs:
        for s in stages:
            if s in r["stages"]:
                t = r["stages"][s]
                lines.append(f"| {r['name']} | {s} | {t['wall']:.1f} | {t['cpu']:.1f} | {t['wall'] / yard:.1f} | "
                             f"{t.get('peak_rss_gb', float('nan')):.2f} GB | {t['status']} |")
        lines.append(f"| {r['name']} | **whole run** (exit {r['rc']}) | {r['wall']:.1f} | - | {r['wall'] / yard:.1f} | "
                     f"{r['rss_gb']:.2f} GB | - |")

    def med(key):
        v = [r["stages"][key]["wall"] for r in runs if key in r["stages"]]
        return float(np.median(v)) if v else float("nan")

    demo = next((r for r in runs if r["name"] == "demo"), None)
    # a task that stops before planning (no feasible object: a fraction of a second) is no plan + preview
    task_walls = [r["stages"][t]["wall"] for r in runs for t in TASKS
                  if t in r["stages"] and r["stages"][t]["status"] == "ran"]
    rows = [("`bijcr run scenes/demo`, wall", demo["wall"] if demo else float("nan"), TARGETS["run"], "s"),
            ("grasp stage, median over scenes", med("grasp"), TARGETS["grasp"], "s"),
            ("one task (plan + preview), median over the tasks that ran", float(np.median(task_walls)) if task_walls
             else float("nan"),
             TARGETS["task"], "s"),
            ("calibrate stage, median over scenes", med("calibrate"), TARGETS["calibrate"], "s"),
            ("peak RSS of the demo run", demo["rss_gb"] if demo else float("nan"), TARGETS["rss_gb"], "GB")]
    lines += ["", "| target | measured | ratio | target | verdict |", "| --- | --- | --- | --- | --- |"]
    for label, v, tgt, unit in rows:
        ratio = f"{v / yard:.1f}" if unit == "s" and np.isfinite(v) else "-"
        lines.append(f"| {label} | {v:.2f} {unit} | {ratio} | <= {tgt:g} {unit} | {_verdict(v, tgt)} |")
    lines += ["", "The stage times include each stage's own imports and model building in the one `bijcr run` "
              "process (the first stage to need Open3D, Pinocchio or PyBullet pays for loading it)."]
    return "\n".join(lines) + "\n"


def main() -> int:
    if len(sys.argv) == 5 and sys.argv[1] == "--_child":
        return _child(*sys.argv[2:5])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=5, help="synthetic bench scenes besides the demo (default 5)")
    ap.add_argument("--quick", action="store_true", help="the demo scene only")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "pipeline.md"), help="markdown table to write")
    args = ap.parse_args()
    bijcr = str(Path(sys.executable).with_name("bijcr"))
    yard, rc, _ = _spawn([bijcr, "check", str(ROOT / "scenes" / "demo")])
    if rc != 0:
        print(f"bijcr check scenes/demo failed (exit {rc})", file=sys.stderr)
        return 1
    scenes = [(ROOT / "scenes" / "demo", "demo")]
    if not args.quick:
        scenes += [(ensure_scene(100 + k), f"seed{100 + k:03d}") for k in range(args.scenes)]
    runs = []
    for scene, name in scenes:
        print(f"bijcr run {scene} ...", file=sys.stderr, flush=True)
        r = run_scene(scene, name)
        print(f"  {name}: {r['wall']:.1f} s, exit {r['rc']}, peak RSS {r['rss_gb']:.2f} GB", file=sys.stderr, flush=True)
        runs.append(r)
    text = report(runs, yard, args)
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(out)
    return 0  # it ran: FAIL rows are data (a run whose stages could not be read shows as such in the table)


if __name__ == "__main__":
    sys.exit(main())
