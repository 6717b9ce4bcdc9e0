"""Run a :class:`TaskPlan` in the PyBullet preview world and judge it physically.

The world holds both arms (secondary at the calibrated ``T_b1_b2``), the table fitted to the cloud and one
convex body per segmented object. With ``truth`` (synthetic scenes) the true objects and the true
secondary base replace them and the estimated bodies are drawn as ghosts: the same plan is then judged
against reality. The plan runs phase by phase, exactly as :meth:`TaskPlan.timeline` lays it out; a key
frame is rendered at the end of every phase; the phases that carry a ``check`` are judged with a
:class:`~bimanual_app.simulation.HoldMonitor`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from bimanual_app.simulation import (
    HoldMonitor,
    HoldSample,
    Recorder,
    box_shape,
    build_world,
    default_camera,
    estimated_shapes,
    table_from_segments,
    truth_shapes,
)

from ._grasps import shape_kind
from ._plan import TaskPlan

__all__ = ["PreviewResult", "preview_plan", "scene_bodies", "primitive_bodies", "CHECKS"]

# check name -> (arms that must hold, exclusive, rise m, hold s)
CHECKS = {
    "joint-lift": ({"primary", "secondary"}, False, 0.10, 2.0),
    "lift": ({"primary"}, False, 0.10, 2.0),
    "handover": ({"secondary"}, True, 0.10, 2.0),
    "handover-to-primary": ({"primary"}, True, 0.10, 2.0),  # a hand-over the secondary gives
}


@dataclass
class PreviewResult:
    """What the preview measured.

    Attributes:
        success: every check passed and no arm hit the table or the other arm.
        reason: one sentence.
        checks: per checked phase: the verdict (ok, held_s, max_rise, detail).
        contacts: unexpected contacts seen (``primary-secondary``, ``primary-table``...).
        tracking_error: per phase, the largest joint error at the phase's end (rad).
        object_track: per phase, where the object was at the phase's end (:func:`phase_state`): how far up,
            which arms held it (both fingers pressing), which touched it, whether it lay on the table.
        sim_time: simulated seconds; wall_time: seconds it took.
        recorder: the frames (GIF and key frames are written by the caller).
        world_truth: whether the world was the ground truth.
    """

    success: bool
    reason: str
    checks: dict = field(default_factory=dict)
    contacts: list = field(default_factory=list)
    tracking_error: dict = field(default_factory=dict)
    object_mass: float | None = None
    sim_time: float = 0.0
    wall_time: float = 0.0
    recorder: Recorder | None = None
    world_truth: bool = False
    warnings: list = field(default_factory=list)
    object_track: list = field(default_factory=list)

    def to_json(self) -> dict:
        return {"success": self.success, "reason": self.reason, "checks": self.checks, "contacts": self.contacts,
                "tracking_error_rad": self.tracking_error, "object_track": self.object_track,
                "object_mass_kg": self.object_mass,
                "sim_time_s": round(self.sim_time, 3), "wall_time_s": round(self.wall_time, 3),
                "world": "ground truth" if self.world_truth else "estimate", "warnings": self.warnings}


def primitive_bodies(grasps: dict, ids: list[int], table=None) -> dict:
    """Object id -> BodyShape for the objects of ``ids`` whose shape the grasping stage determined
    (grasps.json ``shape.kind`` box or cylinder): its gravity-aligned box (``T_b1_box``, ``extent``), or the
    upright cylinder in that box (diameter: the mean of the box's two horizontal edges). The grasps were
    planned on that primitive; a hull of the same points is rounder where the cloud's edges are noisy, and
    a push pair planned on a box's faces lets a rounded hull slip (docs/tasks.md, *One shape*). With the
    ``table`` (a TablePlane), the box reaches down to it, as the bodies of points are extruded to it: the box
    spans the points the cameras saw, and an object's lower part hidden behind a neighbour would otherwise
    leave it floating (it falls in the preview, away from where the grasps were planned)."""
    out = {}
    for o in grasps.get("objects") or []:
        if not isinstance(o, dict) or int(o.get("id", -1)) not in ids:
            continue
        kind = shape_kind(o)
        if kind not in ("box", "cylinder") or o.get("T_b1_box") is None or o.get("extent") is None:
            continue
        T = np.asarray(o["T_b1_box"], dtype=np.float64).reshape(4, 4)
        size = np.asarray(o["extent"], dtype=np.float64).reshape(3)
        if table is not None:
            T, size = _down_to_table(T, size, table)
        if kind == "cylinder":
            d = float(size[:2].mean())
            size = np.array([d, d, size[2]])
        out[int(o["id"])] = box_shape(T, size, kind=kind)
    return out


def _down_to_table(T_b1_box: np.ndarray, size: np.ndarray, table) -> tuple[np.ndarray, np.ndarray]:
    """The gravity-aligned box (4, 4), (3,) with its bottom face (along its z, the table's normal) moved onto
    the table plane."""
    T, size = T_b1_box.copy(), size.copy()
    z = T[:3, 2] * np.sign(T[:3, 2] @ table.normal)
    if abs(z @ table.normal) < 0.95:  # not standing on the table: left as it is
        return T, size
    gap = float(table.height(T[:3, 3] - 0.5 * size[2] * z))  # the bottom's height above the table
    if size[2] + gap > 0:
        size[2] += gap
        T[:3, 3] -= 0.5 * gap * z
    return T, size


def scene_bodies(inputs, ids: list[int] | None = None) -> tuple:
    """``(table, shapes, warnings)`` of a task's inputs: the table plane (``table_from_segments``) and the
    estimated bodies (object id -> BodyShape, and why objects are left out) of the objects ``ids`` (default:
    every segmented object): the grasping stage's primitive where it determined one (``primitive_bodies``),
    else ``estimated_shapes`` of the object's points. Each is computed once and kept on the inputs: the
    planner and each preview of a task use the same."""
    cache = getattr(inputs, "_scene_bodies", None)
    if cache is None:
        cache = inputs._scene_bodies = {"table": table_from_segments(inputs.points, inputs.labels,
                                                                     inputs.seg_extras), "objects": {}}
    table, done = cache["table"], cache["objects"]
    if ids is None:
        ids = sorted(int(i) for i in np.unique(inputs.labels) if i >= 0)
    todo = [int(i) for i in ids if int(i) not in done]
    if todo:
        est, warnings = estimated_shapes(inputs.points, inputs.labels, table, ids=todo)
        prim = primitive_bodies(getattr(inputs, "grasps", None) or {}, todo, table)
        est.update(prim)
        for i in todo:
            done[i] = (est.get(i), [] if i in prim else [w for w in warnings if w.startswith(f"object {i}:")])
    shapes = {int(i): done[int(i)][0] for i in ids if done[int(i)][0] is not None}
    return table, shapes, [w for i in ids for w in done[int(i)][1]]


def preview_plan(plan: TaskPlan, inputs, robot, object_id: int, truth: bool = False, gui: bool = False,
                 record: bool = True, frame_size: tuple[int, int] = (320, 240), fps: float = 10.0,
                 log=None) -> PreviewResult:
    """Simulate ``plan`` with physics and judge it (see module notes). ``log(str)`` gets a line per phase."""
    t_wall = time.perf_counter()
    table, est, warnings = scene_bodies(inputs)
    T_b1_b2 = inputs.T_b1_b2
    true_shapes = None
    if truth:
        gt = inputs.scene.ground_truth
        true_shapes = truth_shapes(gt.objects)
        T_b1_b2 = gt.T_b1_b2
    focus = est[object_id].T_b1_o[:3, 3] if object_id in est else None
    rec = Recorder(*frame_size, fps=fps, camera=default_camera(T_b1_b2, focus)) if record else None
    world, physical = build_world(robot, T_b1_b2, table, est, true_shapes, gui=gui, recorder=rec)
    try:
        for arm, q in plan.q_start.items():
            world.arms[arm].reset(q, plan.width_start[arm])
        for arm, grip in (plan.info.get("grip") or {}).items():
            if grip == "push" and arm in world.arms:  # the arm's compliance makes the squeeze force
                world.arms[arm].set_push_compliance()
        world.hold(0.2)
        obj = physical.get(object_id)
        if obj is None:
            why = ("no true object near the estimated one: the segment is not a real object" if truth
                   else f"object {object_id} has no collision body ({'; '.join(warnings) or 'no points'})")
            return PreviewResult(False, why, warnings=warnings, world_truth=truth,
                                 wall_time=time.perf_counter() - t_wall)
        if rec is not None:
            rec.keyframe("start")
        mon = HoldMonitor(world, obj, grip=plan.info.get("grip"))
        world.add_listener(mon)
        contacts: set[str] = set()
        checks: dict = {}
        tracking: dict = {}
        track: list = []

        def watch(w):
            for a, b in w.arm_contacts():
                contacts.add(f"{a}-{b}")

        world.add_listener(watch)
        phase_start = {}
        for k, ph in enumerate(plan.phases):
            phase_start[ph.name] = world.time
            trs = plan.phase_trajectories(k)
            world.run_plan(trs)
            tracking[ph.name] = float(max(np.max(np.abs(world.arms[a].q() - tr.q[-1])) for a, tr in trs.items()))
            track.append(phase_state(ph.name, mon.sample()))
            if rec is not None:
                rec.keyframe(ph.name)
            if log is not None:
                log(f"  preview {k + 1}/{len(plan.phases)} {ph.name}: {ph.duration:.1f} s simulated")
            if ph.check:
                arms, exclusive, rise, hold_s = CHECKS[ph.check]
                # judged over the checked phase only (a hold phase of >= hold_s after the lift / release)
                v = mon.lifted_and_held(arms, rise=rise, hold_s=hold_s, since=phase_start[ph.name],
                                        exclusive=exclusive)
                checks[ph.name] = {"check": ph.check, "ok": v.ok, "held_s": round(v.held_s, 3),
                                   "max_rise_m": round(v.max_rise, 4), "detail": v.detail}
        failed = [f"{n}: {c['detail']}{where_lost(track)}" for n, c in checks.items() if not c["ok"]]
        if not checks:
            failed.append("the plan has no success check")
        bad_contacts = sorted(contacts)
        if failed:
            reason = "; ".join(failed)
        elif bad_contacts:
            reason = f"unexpected contact during the motion: {', '.join(bad_contacts)}"
        else:
            reason = "; ".join(f"{n}: {c['detail']}" for n, c in checks.items())
        ok = not failed and not bad_contacts
        return PreviewResult(ok, reason, checks, bad_contacts, tracking, obj.shape.mass, world.time,
                             time.perf_counter() - t_wall, rec, truth, warnings, track)
    finally:
        world.close()


def phase_state(phase: str, s: HoldSample) -> dict:
    """One ``PreviewResult.object_track`` entry: the object at the end of ``phase`` (a HoldMonitor sample)."""
    return {"phase": phase, "rise_m": round(float(s.rise), 4), "held_by": sorted(s.holders),
            "touched_by": sorted(s.touching), "on_table": bool(s.on_table)}


def last_loss(track: list[dict]) -> dict | None:
    """Where the object of a preview's ``object_track`` (:func:`phase_state` entries) was last lost: ``{"held_after":
    the last phase after which an arm held it (None: no arm ever did), "by": those arms, "lost_after": the next
    phase (None when none held it), "rise_m": its height then (at the end when none held it)}``; None when an
    arm held it at the end or the track is empty."""
    held = [bool(e["held_by"]) for e in track]
    if not track or held[-1]:
        return None
    if not any(held):
        return {"held_after": None, "by": [], "lost_after": None, "rise_m": track[-1]["rise_m"]}
    k = max(i for i in range(len(track) - 1) if held[i] and not held[i + 1])
    return {"held_after": track[k]["phase"], "by": track[k]["held_by"], "lost_after": track[k + 1]["phase"],
            "rise_m": track[k + 1]["rise_m"]}


def where_lost(track: list[dict]) -> str:
    """A clause for a failed check's reason from :func:`last_loss` (" (held by the primary after grasp; by no arm
    after lift, 0.0 cm up)", or " (no arm held it after any phase)"); "" when it was held at the end."""
    loss = last_loss(track)
    if loss is None:
        return ""
    if loss["held_after"] is None:
        return " (no arm held it after any phase)"
    return (f" (held by the {' and '.join(loss['by'])} after {loss['held_after']}; by no arm after "
            f"{loss['lost_after']}, {100 * loss['rise_m']:.1f} cm up)")
