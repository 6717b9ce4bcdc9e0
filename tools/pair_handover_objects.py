"""Pair two task-bench bases object by object: which objects have a feasible hand-over, and do the new ones hold.

The task bench (``bench/tasks.py``) hands over one object per scene, the best-scoring one, so a change that
gives more objects a hand-over (or takes some away) can leave every scene's outcome as it was. A user asks
for one particular object; this tool counts, for the single-arm objects of the stage outputs kept under two
bench bases (``--base`` of two runs on the same scenes), which have a hand-over in ``grasps.json``:

    .venv/bin/python tools/pair_handover_objects.py BEFORE_BASE AFTER_BASE [--mode pipeline]
        [--check] [--jobs N] [--address ADDR]

``--check`` also runs the hand-over task of every object gained (on AFTER's stage outputs) and lost (on
BEFORE's), each judged as the bench judges a scene (``bench.tasks.outcome``: approved by its preview on the
reconstruction and holding in the ground-truth world; ``bench.tasks.run_one``), as Ray tasks (``bench/_ray.py``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

ObjectKey = tuple[str, int]  # (scene folder name, object id)


def handover_objects(base: Path, mode: str = "pipeline") -> dict[ObjectKey, dict]:
    """``(scene, object id) -> {"handover": bool, "kind": shape kind}`` for the single-arm objects (those the
    antipodal sampler ran on) of every ``BASE/MODE/SCENE/grasps/grasps.json``."""
    out = {}
    for path in sorted(Path(base, mode).glob("*/grasps/grasps.json")):
        for obj in json.loads(path.read_text())["objects"]:
            if "sampler" not in obj.get("stats", {}):
                continue  # two hands only (joint grasps) or no usable points
            out[(path.parent.parent.name, int(obj["id"]))] = {
                "handover": obj.get("handover") is not None, "kind": (obj.get("shape") or {}).get("kind", "")}
    return out


def pair_objects(before: dict[ObjectKey, dict], after: dict[ObjectKey, dict]) -> dict:
    """Totals over the objects in both (``objects``, ``before``, ``after`` with a hand-over) and the objects
    ``gained`` and ``lost`` (sorted lists of keys)."""
    keys = sorted(set(before) & set(after))
    return {"objects": len(keys), "before": sum(before[k]["handover"] for k in keys),
            "after": sum(after[k]["handover"] for k in keys),
            "gained": [k for k in keys if after[k]["handover"] and not before[k]["handover"]],
            "lost": [k for k in keys if before[k]["handover"] and not after[k]["handover"]]}


def check_job(job: dict) -> dict:
    """Run one object's hand-over on a base's stage outputs (a Ray task): ``bench.tasks.run_one``'s facts."""
    from bench.tasks import run_one

    base, scene, oid = Path(job["base"]), job["scene"], job["object"]
    return {**job, **run_one(base / "scenes" / scene, base / job["mode"] / scene, "handover", object_id=oid,
                             out=Path(job["out"]) / f"{scene}_{oid}")}


def verdict(row: dict) -> str:
    """One word for a checked hand-over: held, not approved (its preview failed: never sent), or approved but
    dropped in reality (the dangerous kind)."""
    if row.get("truth_ok"):
        return "held"
    if row.get("planned") and row.get("estimate_ok"):
        return "approved, fails in reality"
    return "not approved" if row.get("planned") else "no plan"


def check(p: dict, args: argparse.Namespace) -> list[dict]:
    """Run the gained objects' hand-overs on AFTER's outputs and the lost ones' on BEFORE's (Ray tasks),
    printing each verdict as it comes."""
    from bench._ray import SceneError, map_scenes

    jobs = [{"base": str(base), "mode": args.mode, "scene": s, "object": i, "out": str(args.out), "side": name}
            for name, keys, base in (("gained", p["gained"], args.after), ("lost", p["lost"], args.before))
            for s, i in keys]

    def show(done: int, total: int, i: int, row) -> None:
        job = jobs[i]
        said = f"crashed ({row})" if isinstance(row, SceneError) else verdict(row)
        print(f"[{done}/{total}] {job['side']} {job['scene']} #{job['object']}: {said}", flush=True)
        if not isinstance(row, SceneError) and row.get("reason"):
            print(f"    {row['reason'][:160]}", flush=True)

    return map_scenes(check_job, jobs, address=args.address, num_cpus=args.jobs, progress=show,
                      return_exceptions=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--mode", default="pipeline")
    ap.add_argument("--check", action="store_true", help="run the gained and lost objects' hand-overs")
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--address", default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "handover_objects")
    args = ap.parse_args(argv)
    a, b = handover_objects(args.before, args.mode), handover_objects(args.after, args.mode)
    p = pair_objects(a, b)
    print(f"objects with a hand-over: {p['before']} -> {p['after']} of {p['objects']}")
    for name, keys, src in (("gained", p["gained"], b), ("lost", p["lost"], a)):
        print(f"{name}: " + (", ".join(f"{s} #{i} ({src[(s, i)]['kind']})" for s, i in keys) or "-"))
    if args.check and (p["gained"] or p["lost"]):
        check(p, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
