"""Read the downstream results of a run: grasps.json (per object) and each task's task.json + plan.npz."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem

from ._io import as_T, read_json
from ._types import GripperPose, ObjectGrasps, PhaseSpan, TaskReplay

__all__ = ["read_grasps", "read_task"]

_GRASP_FIX = "re-run `bijcr grasp` (grasps.json, docs/grasping.md)"
_TASK_FIX = "re-run `bijcr task` (or `bijcr run`)"


def _pose(path: Path, where: str, d, caption: str, width=None) -> GripperPose:
    """A gripper pose from a grasps.json entry holding ``T_b1_g`` and ``width`` (or the given width)."""
    if not isinstance(d, dict) or "T_b1_g" not in d:
        raise InputError(Problem(str(path), where, "missing T_b1_g", _GRASP_FIX))
    w = d.get("width", width)
    try:
        w = float(w)
    except (TypeError, ValueError):
        raise InputError(Problem(str(path), f"{where}.width", f"not a number: {w!r}", _GRASP_FIX)) from None
    return GripperPose(as_T(path, f"{where}.T_b1_g", d["T_b1_g"], _GRASP_FIX), w, caption)


def _object(path: Path, k: int, o) -> ObjectGrasps:
    where = f"objects[{k}]"
    if not isinstance(o, dict) or not isinstance(o.get("id"), int):
        raise InputError(Problem(str(path), f"{where}.id", "missing or not an integer", _GRASP_FIX))
    og = ObjectGrasps(int(o["id"]))
    for j, g in enumerate(o.get("grasps") or []):
        og.single.append(_pose(path, f"{where}.grasps[{j}]", g, f"single #{g.get('rank', j + 1)} "
                               f"({g.get('arm', '?')}, score {float(g.get('score', 0.0)):.2f})"))
    for j, p in enumerate(o.get("joint_grasps") or []):
        w = f"{where}.joint_grasps[{j}]"
        if not isinstance(p, dict):
            raise InputError(Problem(str(path), w, "not an object", _GRASP_FIX))
        cap = f"pair #{p.get('rank', j + 1)} ({p.get('kind', '?')}, score {float(p.get('score', 0.0)):.2f})"
        og.joint.append((_pose(path, f"{w}.primary", p.get("primary"), cap + " primary"),
                         _pose(path, f"{w}.secondary", p.get("secondary"), cap + " secondary")))
    h = o.get("handover")
    if isinstance(h, dict) and h:
        w = f"{where}.handover"
        giver, rec = h.get("giver") or {}, h.get("receiver")
        pick = _pose(path, f"{w}.giver.pick", giver.get("pick"), "hand-over: giver picks")
        release = giver.get("release_width", pick.width)
        og.handover = {"pick": pick,
                       "transfer": _pose(path, f"{w}.giver.transfer", giver.get("transfer"),
                                         "hand-over: giver at the transfer pose", width=release),
                       "receiver": _pose(path, f"{w}.receiver", rec, "hand-over: receiver")}
        og.T_move = as_T(path, f"{w}.T_move", h.get("T_move"), _GRASP_FIX) if h.get("T_move") is not None else None
    return og


def read_grasps(path: Path) -> dict[int, ObjectGrasps]:
    """Object id -> its grasps, for the objects of grasps.json that have any."""
    d = read_json(path, _GRASP_FIX)
    objs = d.get("objects")
    if not isinstance(objs, list):
        raise InputError(Problem(str(path), "objects", "missing or not a list", _GRASP_FIX))
    out = {}
    for k, o in enumerate(objs):
        og = _object(path, k, o)
        if og.single or og.joint or og.handover:
            out[og.object_id] = og
    return out


def _phases(path: Path, plans) -> list[PhaseSpan]:
    """The phases of task.json ``plans`` laid end to end on the plan's clock."""
    if not isinstance(plans, list):
        raise InputError(Problem(str(path), "plans", "not a list of phases", _TASK_FIX))
    out, t = [], 0.0
    for k, p in enumerate(plans):
        try:
            dur, name = float(p["duration_s"]), str(p["phase"])
        except (KeyError, TypeError, ValueError):
            raise InputError(Problem(str(path), f"plans[{k}]", "needs 'phase' and 'duration_s'", _TASK_FIX)) from None
        out.append(PhaseSpan(name, t, t + dur, tuple(str(a) for a in p.get("arms") or ()), str(p.get("note", ""))))
        t += dur
    return out


def read_task(name: str, folder: Path) -> tuple[TaskReplay | None, str]:
    """(the task's replay, "") or (None, why there is none) for ``folder`` holding task.json."""
    from bimanual_app.hardware import load_plan

    tj = folder / "task.json"
    t = read_json(tj, _TASK_FIX)
    plan_path = folder / "plan.npz"
    if not plan_path.is_file():
        why = str(t.get("reason") or "no reason given")
        return None, f"no plan.npz in {folder} (the task {'succeeded' if t.get('success') else 'failed'}: {why})"
    try:
        trajs = load_plan(plan_path)
    except InputError:
        raise  # already names the file and the fix
    except Exception as e:  # a damaged zip / npy raises several kinds
        raise InputError(Problem(str(plan_path), "", f"cannot read the plan: {e}", _TASK_FIX)) from None
    missing = [a for a in ("primary", "secondary") if a not in trajs]
    if missing:
        raise InputError(Problem(str(plan_path), "/".join(missing), f"no trajectory of the {' and '.join(missing)} arm",
                                 _TASK_FIX))
    oid = t.get("object")
    obj = int(oid) if isinstance(oid, (int, np.integer)) else None
    return TaskReplay(name, trajs, _phases(tj, t.get("plans") or []), obj, bool(t.get("success")),
                      str(t.get("reason", ""))), ""
