"""One task run, end to end: inputs -> object choice -> plan -> physics preview -> approval -> (hardware).

Bad input (a missing or foreign calibration, an unknown object id, an output folder holding other
files, a failed earlier stage) raises :class:`~bimanual_app.io_utils.InputError` before anything is
written. A task that cannot be done (no reachable grasp, no plan in time, a preview that drops the
object, a hardware failure) is a *result*: ``task.json`` says ``success: false`` and why, with whatever
was made (plans, preview), and the exit code is 1. All outputs are staged and moved into ``OUT`` at
once (:class:`~._output.OutputDir`).
"""

from __future__ import annotations

import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem, to_jsonable, write_json

from ._output import OutputDir

__all__ = ["TaskOptions", "TaskResult", "run_task", "fallback_names"]

ARMS = ("primary", "secondary")
MAX_FALLBACK_OBJECTS = 2  # without --object: objects tried after the best-scoring one cannot be planned
MAX_CANDIDATES = 4  # grasp candidates (pairs, hand-overs) planned per object
MAX_PREVIEWS = 3  # plans previewed before the task gives up: a failed preview moves on to the next candidate
# previews one object gets while other objects are left to try: an object's previews fail together when its
# estimated body is what fails them (a partly seen object, a neighbour's body in the fingers' way), so the
# last preview goes to the next object rather than to a third grasp of the same doubtful one
PREVIEWS_PER_OBJECT = 2
# previews for the hand-overs drawn again where every previewed one failed (the "preview-redraw" fallback)
REDRAW_PREVIEWS = 2
OPEN_START = 0.0  # gripper width at the start when nothing is known (closed, as the Piper rests)


@dataclass
class TaskOptions:
    task: str
    scene: str
    object_id: int | None = None
    work: str | None = None
    out: str | None = None
    gui: bool = False
    execute: str | None = None
    truth_objects: bool = False
    plan_time: float = 5.0
    quiet: bool = False
    can_primary: str = "can0"
    can_secondary: str = "can1"
    can_interface: str = "socketcan"
    record: bool = True
    frame_size: tuple = (320, 240)
    speed: float = 0.5
    compare_truth: bool = False  # also run the same plan in the ground-truth world (task.json "preview_truth")
    masks: bool | None = None  # segment with the scene's masks when it runs the stage; None: when it has them
    # fallbacks not to try, a measuring knob: the planner's (tasks.FALLBACKS) and, where the task runs the grasp
    # stage, the hand-over search's (grasping.HANDOVER_FALLBACKS)
    leave_out: tuple[str, ...] = ()


@dataclass
class TaskResult:
    task: str
    success: bool
    reason: str
    out: Path | None
    object_id: int | None = None
    object_reason: str = ""
    failed_stage: str = ""
    timings: dict = field(default_factory=dict)
    preview: dict | None = None
    record: dict = field(default_factory=dict)


@dataclass
class _Attempt:
    """A candidate that planned and validated, with its physics preview on the reconstruction."""

    object_id: int
    rank: int
    plan: object
    motion: object
    timeline: dict
    preview: object


def _log(opts: TaskOptions, msg: str) -> None:
    if not opts.quiet:
        print(f"task {opts.task}: {msg}", file=sys.stderr, flush=True)


def _default_paths(opts: TaskOptions, scene) -> tuple[Path, Path]:
    work = Path(opts.work) if opts.work else Path("runs") / scene.name
    out = Path(opts.out) if opts.out else work / "tasks" / opts.task
    return work, out


def _check_output_folders(work, out) -> None:
    """InputError before any work when the work or output folder is a file or cannot be written."""
    from bimanual_app.io_utils import check_output_dir

    if work is not None:
        check_output_dir(work, "--work", "give a folder (new, or one holding earlier results) you can write to")
    if out is not None:
        check_output_dir(out, "--out", "give a new folder, or an earlier task result, you can write to")


def _connect_hardware(opts: TaskOptions, robot):
    """Both arms, connected (listening only); their joint angles are the plan's start."""
    from bimanual_app.hardware import BimanualHardware

    hw = BimanualHardware.from_channels(opts.can_primary, opts.can_secondary, robot=robot,
                                        bustype=opts.can_interface, check_port=opts.can_interface == "socketcan",
                                        execute=opts.execute)
    hw.connect()
    return hw


def run_task(opts: TaskOptions) -> TaskResult:
    """Run one task (see the module docstring). Raises InputError for bad input."""
    from bimanual_app.robots import load_robot
    from bimanual_app.scene import load_scene

    from ._inputs import ensure_stages, load_inputs, stage_paths

    if opts.task not in ("joint-grasp", "handover"):
        raise InputError(Problem("", "task", f"unknown task {opts.task!r}", "use joint-grasp or handover"))
    if opts.execute not in (None, "hardware"):
        raise InputError(Problem("", "--execute", f"unknown target {opts.execute!r}", "use --execute hardware"))
    if opts.execute and opts.truth_objects:
        raise InputError(Problem("", "--execute", "--truth-objects is an evaluation on synthetic scenes; the hardware "
                                 "runs only plans previewed on the reconstruction", "leave out one of the two"))
    if not opts.plan_time > 0:
        raise InputError(Problem("", "--plan-time", "must be > 0", "give seconds, e.g. --plan-time 5"))
    _check_leave_out(opts.leave_out)
    _check_output_folders(opts.work, opts.out)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    scene = load_scene(opts.scene)
    if (opts.truth_objects or opts.compare_truth) and (scene.ground_truth is None or not scene.ground_truth.objects):
        raise InputError(Problem(str(scene.path / "ground_truth.yaml"), "objects",
                                 "--truth-objects (and compare_truth) needs the scene's ground-truth objects",
                                 "use a synthetic scene (bijcr synth) or leave out --truth-objects"))
    work, out = _default_paths(opts, scene)
    _check_output_folders(None if opts.work else work, None if opts.out else out)  # the defaults, too
    paths = stage_paths(work)
    staging = OutputDir(out)  # refuses a folder of foreign files before any work
    try:
        try:
            ensure_stages(scene.path, paths, timings, quiet=opts.quiet, scene=scene, masks=opts.masks,
                          leave_out=tuple(n for n in opts.leave_out if n in _grasp_fallbacks()))
        except InputError as e:
            e.timings = timings  # what ran before the failure (the bench reports stage times)
            raise
        t = time.perf_counter()
        inputs = load_inputs(scene, paths)
        robot = load_robot(scene.robot or "piper", base_dir=scene.path)
        timings["load"] = time.perf_counter() - t
        result = _run_loaded(opts, scene, inputs, robot, staging, timings)
        timings["total"] = time.perf_counter() - t0
        result.timings = timings
        result.record["timings_s"] = {k: round(v, 3) for k, v in timings.items()}
        write_json(staging.path("task.json"), result.record)
        staging.commit()
        result.out = staging.out
        return result
    finally:
        staging.abort()


def _new_record(opts, scene, inputs) -> dict:
    """task.json's content before anything is decided: inputs and options, no object, no plan."""
    return {"format": 1, "task": opts.task, "scene": scene.name, "success": False, "reason": "",
            "object": None, "object_reason": "", "plans": [], "approval": None,
            "inputs": {"calibration": str(inputs.paths.calibration), "cloud": str(inputs.paths.cloud),
                       "segments": str(inputs.paths.segments), "grasps": str(inputs.paths.grasps)},
            "options": {"truth_objects": opts.truth_objects, "execute": opts.execute,
                        "plan_time_s": opts.plan_time, "speed": opts.speed},
            "warnings": list(inputs.warnings) + _input_warnings(opts, inputs)}


def _input_warnings(opts, inputs) -> list[str]:
    """Warnings about what this task is given (each also printed): a hand-over from a calibration whose
    second base is too loose for the grippers to meet (``calibration.base_to_base_advice``)."""
    from calibration import base_to_base_advice

    advice = base_to_base_advice(inputs.calibration.get("uncertainty")) if opts.task == "handover" else None
    out = [f"{inputs.paths.calibration}: {advice}"] if advice else []
    for w in out:
        _log(opts, f"warning: {w}")
    return out


def _fail(opts, res: TaskResult, stage: str, reason: str) -> TaskResult:
    """Mark the result failed at ``stage`` for ``reason`` (in the result and its record) and return it."""
    res.success, res.failed_stage = False, stage
    res.reason = reason
    res.record.update(success=False, reason=reason, failed_stage=stage)
    _log(opts, f"FAILED at {stage}: {reason}")
    return res


def _set_object(res: TaskResult, oid, why: str) -> None:
    """The object the task is about, and why, in the result and its record."""
    res.object_id, res.object_reason = oid, why
    res.record.update(object=oid, object_reason=why)


def _choose_object(opts, inputs, res: TaskResult):
    """The candidates of the task and those of the chosen object: ``(cands, mine, oid)``; ``mine`` is empty
    (and the result failed at "grasp") when no object has a reachable candidate."""
    from ._grasps import choose, handover_candidates, joint_candidates

    known = sorted(int(k) for k in np.unique(inputs.labels) if k >= 0)
    gpath = str(inputs.paths.grasps)
    cands = (joint_candidates if opts.task == "joint-grasp" else handover_candidates)(inputs.grasps, gpath)
    mine, why = choose(cands, opts.object_id, opts.task, gpath, known)
    oid = mine[0].object_id if mine else opts.object_id
    _set_object(res, oid, why)
    if oid is not None:
        _log(opts, f"object {oid}: {why}")
    if not mine:
        what = "two-arm grasp pair" if opts.task == "joint-grasp" else "hand-over (giver and receiver grasps)"
        if oid is None:
            _fail(opts, res, "grasp", f"{why}: the objects are out of reach of the arms or too small/large to "
                                      f"grasp (see {gpath})")
        else:
            _fail(opts, res, "grasp", f"object {oid} has no reachable {what} in {gpath}: it is out of reach, or "
                                      "no collision-free grasp exists")
    return cands, mine, oid


def _start_state(opts, robot, res: TaskResult, timings: dict):
    """The start configuration: the arms' own (hardware) or the rest pose. Returns ``(hw, q_start,
    width_start)``; ``q_start`` is None (and the result failed at "hardware") when the arms cannot be
    reached."""
    if opts.execute != "hardware":
        from bimanual_app.planning import default_ready

        return None, {a: default_ready(robot) for a in ARMS}, {a: OPEN_START for a in ARMS}
    t = time.perf_counter()
    hw = None
    try:
        hw = _connect_hardware(opts, robot)
        fb = hw.read()
        q_start = {a: np.asarray(fb[a].q, dtype=np.float64) for a in ARMS}
        width_start = {a: float(fb[a].gripper_m) if fb[a].gripper_m is not None else OPEN_START for a in ARMS}
    except Exception as e:
        if hw is not None:
            hw.close()
        timings["hardware"] = time.perf_counter() - t
        res.record["hardware"] = {"ok": False, "error": str(e), "connected": False}
        _fail(opts, res, "hardware", f"cannot connect to the arms ({e}); nothing was planned or sent")
        return None, None, None
    timings["hardware_connect"] = time.perf_counter() - t
    return hw, q_start, width_start


@dataclass
class _Search:
    """The search over objects and candidates (see :func:`_plan_objects`): its fixed inputs and its state."""

    table: object  # the table plane (``simulation.table_from_segments``)
    robot_pts: np.ndarray  # (N,) bool: the cloud's points on the arms, not obstacles
    q_start: dict  # arm -> (J,) start configuration
    width_start: dict  # arm -> gripper width at the start (m)
    motion: object = None  # the last TaskMotion built
    motions: dict = field(default_factory=dict)  # object id -> (TaskMotion, its surface points), None: no body
    next_k: dict = field(default_factory=dict)  # object id -> its next candidate to plan
    errors: dict = field(default_factory=dict)  # object id -> the PlanFailure of each candidate that failed
    attempts: list = field(default_factory=list)  # _Attempt: every candidate previewed
    chosen: _Attempt | None = None  # the first whose preview passed
    failed: _Attempt | None = None  # the first whose preview failed
    t_preview: float = 0.0
    max_previews: int = MAX_PREVIEWS  # raised by the redraw (REDRAW_PREVIEWS)
    start_problems: list = field(default_factory=list)  # the start configuration's collisions, if any

    @property
    def tried(self) -> list:
        """(object id, its first PlanFailure, candidates that failed) of each object tried but not chosen."""
        from ._motion import PlanFailure

        chosen = None if self.chosen is None else self.chosen.object_id
        return [(o, e[0] if e else PlanFailure("grasp", "no candidate"), len(e)) for o, e in self.errors.items()
                if o != chosen]

    def done(self) -> bool:
        return self.chosen is not None or len(self.attempts) >= self.max_previews


def _plan_candidate(opts, motion_o, c, k: int, q_start, width_start, pts_o, up):
    """One candidate planned and its timeline validated: ``(plan, timeline)``; raises PlanFailure."""
    from ._motion import PlanFailure
    from ._planners import plan_handover, plan_joint_grasp

    if opts.task == "joint-grasp":
        plan = plan_joint_grasp(motion_o, c, q_start, width_start, up=up)
    else:
        plan = plan_handover(motion_o, c, q_start, width_start, pts_o, up=up)
    plan.info["candidate_rank"] = k
    plan.info["candidate"] = {"grasps_json": c.info.get("source"), "score": round(float(c.score), 4)}
    timeline = plan.timeline()
    try:  # the samples the preview and the hardware get
        motion_o.validate_timeline(timeline, plan.opening_spans())
    except PlanFailure as e:
        raise PlanFailure("validation", f"the assembled plan failed validation: {e.message}") from None
    return plan, timeline


def _grasp_fallbacks() -> dict:
    """The hand-over search's fallbacks by name (``grasping.HANDOVER_FALLBACKS``; imported when needed)."""
    from grasping import HANDOVER_FALLBACKS

    return HANDOVER_FALLBACKS


def fallback_names() -> list[str]:
    """The names ``TaskOptions.leave_out`` takes: the planner's fallbacks (``FALLBACKS``), then the hand-over
    search's (``grasping.HANDOVER_FALLBACKS``: they act when the task runs the grasp stage)."""
    from ._planners import FALLBACKS

    return [*FALLBACKS, *_grasp_fallbacks()]


def _check_leave_out(names) -> None:
    """InputError for a name in ``TaskOptions.leave_out`` that is not in :func:`fallback_names`."""
    known = fallback_names()
    unknown = sorted(set(names) - set(known))
    if isinstance(names, str) or unknown:
        raise InputError(Problem("", "leave_out", f"unknown fallback(s) {unknown or [names]}",
                                 f"a tuple of names from {', '.join(known)}"))


def _object_motion(opts, inputs, robot, o: int, rec: dict, s: _Search):
    """``(TaskMotion, surface points (M, 3))`` of object ``o``, built once; None when it has no body or when,
    as the first map built, it finds the start configuration blocked (``s.start_problems``)."""
    from ._motion import PlanFailure, TaskMotion
    from ._preview import scene_bodies

    if o in s.motions:
        return s.motions[o]
    s.motions[o] = None
    _, shapes, warns = scene_bodies(inputs, [o])
    rec["warnings"] += warns
    if o not in shapes:
        s.errors[o] = [PlanFailure("input", f"no collision body from its points ({'; '.join(warns)})")]
        return None
    sh = shapes[o]
    pts_o = sh.surface_points_b1()
    motion_o = TaskMotion(robot, inputs.T_b1_b2, inputs.points[~s.robot_pts], pts_o,
                          inputs.points[inputs.labels == o], plan_time=opts.plan_time, speed=opts.speed,
                          body=sh, up=s.table.normal, leave_out=opts.leave_out)
    if s.motion is None:  # the first map built: the start must be free in it
        s.start_problems = motion_o.problems(s.q_start)
        if s.start_problems:
            return None
    s.motion = motion_o
    s.motions[o] = (motion_o, pts_o)
    return s.motions[o]


def _try_object(opts, inputs, robot, o: int, cands, rec: dict, s: _Search, previews: int = MAX_PREVIEWS) -> None:
    """Plan and preview object ``o``'s candidates in order, from where an earlier call stopped, until one
    passes its preview (``s.chosen``), ``previews`` more were previewed or ``s.max_previews`` previews were made
    in all; records what was tried in ``s``."""
    from ._motion import PlanFailure
    from ._preview import preview_plan

    built = _object_motion(opts, inputs, robot, o, rec, s)
    if built is None:
        return
    motion_o, pts_o = built
    errors = s.errors.setdefault(o, [])
    mine = [c for c in cands if c.object_id == o][:MAX_CANDIDATES]
    budget = min(s.max_previews, len(s.attempts) + previews)
    while s.next_k.get(o, 0) < len(mine) and len(s.attempts) < budget:
        k = s.next_k.get(o, 0)
        s.next_k[o] = k + 1
        try:
            plan, timeline = _plan_candidate(opts, motion_o, mine[k], k, s.q_start, s.width_start, pts_o,
                                             s.table.normal)
        except PlanFailure as e:
            errors.append(e)
            _log(opts, f"candidate {k + 1} of object {o}: {e}")
            continue
        t = time.perf_counter()
        _log(opts, f"object {o}, candidate {k + 1}: previewing {len(plan.phases)} phases "
                   f"({plan.duration:.1f} s) in PyBullet")
        pv = preview_plan(plan, inputs, robot, o, gui=opts.gui and not opts.truth_objects,
                          record=opts.record and not opts.truth_objects, frame_size=tuple(opts.frame_size),
                          log=None if opts.quiet else (lambda m: _log(opts, m)))
        s.t_preview += time.perf_counter() - t
        att = _Attempt(o, k, plan, motion_o, timeline, pv)
        s.attempts.append(att)
        if pv.success:
            s.chosen = att
            return
        s.failed = s.failed or att
        errors.append(PlanFailure("preview", f"the physics preview failed: {pv.reason}"))
        _log(opts, f"candidate {k + 1} of object {o}: the physics preview failed: {pv.reason}")


def _plan_objects(opts, inputs, robot, cands, oid, q_start, width_start, rec: dict, timings: dict) -> _Search:
    """Plan: the chosen object's candidates in order; without --object, the next objects (by their best
    score) when none of the first one's can be planned.

    Each candidate that plans and validates is previewed on the reconstruction (never on the ground truth:
    that is only for judging); the first that passes is the task's plan. A failed preview moves on to the
    next candidate, up to MAX_PREVIEWS previews, of which an object with other objects after it gets
    PREVIEWS_PER_OBJECT; if none passes, the first failed one is reported (and approved as 'fail')."""
    from ._motion import BASE_RADIUS, START_PAD, arms_at_start_mask, robot_points_mask
    from ._preview import scene_bodies

    t_start = time.perf_counter()
    table = scene_bodies(inputs)[0]
    robot_pts = robot_points_mask(inputs.points, inputs.labels, np.stack([np.zeros(3), inputs.T_b1_b2[:3, 3]]),
                                  table.normal, -table.d)
    at_start = arms_at_start_mask(robot, inputs.T_b1_b2, inputs.points, q_start) & ~robot_pts
    if robot_pts.any() or at_start.any():
        rec["planning_map"] = {"robot_points_removed": int(robot_pts.sum()),
                               "arms_at_start_points_removed": int(at_start.sum()),
                               "note": f"background points within {BASE_RADIUS} m of a base axis (the arms "
                                       "seen by the cameras) and points within "
                                       f"{START_PAD} m of the arms at their start configuration are not obstacles"}
    robot_pts |= at_start
    order = [oid]
    if opts.object_id is None:
        order += [o for o in dict.fromkeys(c.object_id for c in cands) if o != oid][:MAX_FALLBACK_OBJECTS]
    s = _Search(table, robot_pts, q_start, width_start)
    for i, o in enumerate(order):
        _try_object(opts, inputs, robot, o, cands, rec, s,
                    previews=PREVIEWS_PER_OBJECT if i + 1 < len(order) else MAX_PREVIEWS)
        if s.start_problems:
            return s
        if s.done():
            break
    for o in order:  # previews left when the later objects planned none: the objects cut short get them
        if s.done():
            break
        _try_object(opts, inputs, robot, o, cands, rec, s)
    _redraw(opts, inputs, robot, rec, s)
    timings["plan"] = time.perf_counter() - t_start - s.t_preview
    if s.attempts:
        timings["preview"] = s.t_preview
    if s.motion is not None:
        rec["planning"] = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in s.motion.stats.items()}
    if s.tried:
        rec["objects_tried"] = [{"object": o, "reason": e.message, "candidates": n} for o, e, n in s.tried]
    if s.attempts:
        rec["previews_tried"] = [{"object": a.object_id, "candidate_rank": a.rank, "success": a.preview.success,
                                  "reason": a.preview.reason} for a in s.attempts]
    return s


def _redraw(opts, inputs, robot, rec: dict, s: _Search) -> None:
    """Hand-over, where every candidate previewed failed its preview (the "preview-redraw" fallback): the
    grasp stage's search runs again on each object previewed, in that order, without the giver's picks its
    previews saw fail (``grasping.redraw_handovers``: another draw of picks and receivers), and the hand-overs
    it finds get ``REDRAW_PREVIEWS`` more previews between them. Recorded in ``rec["redrawn"]``."""
    from grasping import redraw_handovers

    from ._grasps import handover_candidates
    from ._planners import _used

    if opts.task != "handover" or s.chosen is not None or not s.attempts or "preview-redraw" in opts.leave_out:
        return
    s.max_previews = len(s.attempts) + REDRAW_PREVIEWS
    rec["redrawn"] = []
    for o in dict.fromkeys(a.object_id for a in s.attempts):
        if s.done():
            break
        refused = [np.asarray(a.plan.info["grasps"]["pick"]["T_b1_g"]) for a in s.attempts if a.object_id == o]
        _log(opts, f"object {o}: every hand-over previewed failed; its hand-overs drawn again without "
                   f"{len(refused)} refused pick(s)")
        p = inputs.paths
        try:
            found = redraw_handovers(p.cloud, p.segments, p.calibration, o, refused)
        except InputError as e:  # the task ends as it would have without the redraw, saying why it did not run
            rec["redrawn"].append({"object": o, "refused_picks": len(refused), "error": str(e).splitlines()[0]})
            continue
        rec["redrawn"].append({"object": o, "refused_picks": len(refused), "found": len(found)})
        if not found:
            continue
        obj = next((d for d in inputs.grasps.get("objects", []) if d.get("id") == o), {})
        again = {"pregrasp_distance": inputs.grasps.get("pregrasp_distance"),
                 "objects": [{**obj, "handover": found[0], "handover_alternatives": found[1:]}]}
        cands = handover_candidates(again, str(p.grasps))
        for c in cands:
            c.info["source"] = "redrawn " + c.info["source"]
        s.next_k[o] = 0
        _try_object(opts, inputs, robot, o, cands, rec, s, previews=REDRAW_PREVIEWS)
    if s.chosen is not None:
        _used(s.chosen.plan, "preview-redraw")


def _no_plan_failure(s: _Search) -> tuple[str, str]:
    """``(stage, reason)`` of a search that planned nothing: the first object's first failure."""
    o, e, n_c = s.tried[0]
    stage = {"reach": "reach", "cartesian": "reach", "plan": "plan", "validation": "plan"}.get(e.stage, e.stage)
    more = f" ({n_c} grasp candidates tried)" if n_c > 1 else ""
    others = f"; {len(s.tried) - 1} other object(s) could not be planned either" if len(s.tried) > 1 else ""
    return stage, f"no valid plan for object {o}{more}: {e.message}{others}"


def _preview_and_approve(opts, scene, inputs, robot, pick: _Attempt, oid, res: TaskResult, staging: OutputDir,
                         timings: dict):
    """The physics preview reported (and approved): the chosen plan's on the reconstruction, or with
    --truth-objects the same plan in the ground-truth world. Returns ``(preview, approval)``."""
    from bimanual_app.hardware import approve_plan, write_approval

    from ._preview import preview_plan

    rec, plan = res.record, pick.plan
    log = None if opts.quiet else (lambda m: _log(opts, m))
    pv = pick.preview
    if opts.truth_objects:
        t = time.perf_counter()
        _log(opts, f"previewing the chosen plan ({len(plan.phases)} phases) against the ground truth")
        pv = preview_plan(plan, inputs, robot, oid, truth=True, gui=opts.gui, record=opts.record,
                          frame_size=tuple(opts.frame_size), log=log)
        timings["preview_truth"] = time.perf_counter() - t
    res.preview = pv.to_json()
    rec["preview"] = res.preview
    if pv.recorder is not None and pv.recorder.frames:
        pv.recorder.save_gif(staging.path("preview.gif"))
        pv.recorder.save_keyframes(staging.staging)
    approval = approve_plan(pick.timeline, "pass" if pv.success else "fail",
                            {"task": opts.task, "scene": scene.name, "object": oid, "reason": pv.reason,
                             "checks": pv.checks, "world": "ground truth" if opts.truth_objects else "estimate"})
    write_approval(staging.path("approval.json"), approval)
    rec["approval"] = to_jsonable(approval.__dict__)
    if opts.compare_truth and not opts.truth_objects:
        t = time.perf_counter()
        pvt = preview_plan(plan, inputs, robot, oid, truth=True, record=False)
        timings["preview_truth"] = time.perf_counter() - t
        rec["preview_truth"] = pvt.to_json()
        _log(opts, f"the same plan against the ground truth: {'success' if pvt.success else 'failure'} - "
                   f"{pvt.reason}")
    return pv, approval


def _report_plan(opts, s: _Search, pick: _Attempt, oid, res: TaskResult, staging: OutputDir):
    """Record the picked plan (and why another object than the best-scoring one, if so) and save plan.npz.
    Returns the object id now planned for."""
    from bimanual_app.hardware import save_plan

    rec = res.record
    if pick.object_id != oid:
        first = s.tried[0][1]
        why = (f"object {pick.object_id}, the next best: the best-scoring object {oid} "
               + ("failed its physics preview" if first.stage == "preview" else "could not be planned")
               + f" ({first.message})")
        oid = pick.object_id
        _set_object(res, oid, why)
        _log(opts, why)
    rec["plans"] = pick.plan.summary()
    rec["plan"] = {"duration_s": round(pick.plan.duration, 3),
                   "n_waypoints": {a: len(tr) for a, tr in pick.timeline.items()}, "info": pick.plan.info}
    save_plan(staging.path("plan.npz"), pick.timeline)
    return oid


def _run_loaded(opts, scene, inputs, robot, staging: OutputDir, timings: dict) -> TaskResult:
    res = TaskResult(opts.task, False, "", None, record=_new_record(opts, scene, inputs))
    rec = res.record
    cands, mine, oid = _choose_object(opts, inputs, res)
    if not mine:
        return res
    hw, q_start, width_start = _start_state(opts, robot, res, timings)
    if q_start is None:
        return res
    try:
        s = _plan_objects(opts, inputs, robot, cands, oid, q_start, width_start, rec, timings)
        if s.start_problems:
            return _fail(opts, res, "start", "the arms' start configuration is in collision: "
                                             + "; ".join(s.start_problems[:3]))
        pick = s.chosen or s.failed
        if pick is None:
            return _fail(opts, res, *_no_plan_failure(s))
        oid = _report_plan(opts, s, pick, oid, res, staging)
        pv, approval = _preview_and_approve(opts, scene, inputs, robot, pick, oid, res, staging, timings)
        if not pv.success:
            more = f" ({len(s.attempts)} plans previewed, none passed)" if len(s.attempts) > 1 else ""
            return _fail(opts, res, "preview", f"the physics preview failed: {pv.reason}{more}")
        res.success, res.reason = True, f"preview passed: {pv.reason}"
        rec.update(success=True, reason=res.reason)
        if hw is not None:  # ---- hardware
            t = time.perf_counter()
            ok, msg = _execute(hw, pick.timeline, approval, rec)
            timings["hardware"] = time.perf_counter() - t
            if not ok:
                return _fail(opts, res, "hardware", msg)
            res.reason = rec["reason"] = res.reason + "; executed on the hardware"
        return res
    except InputError:
        raise
    except Exception as e:  # a bug must not leave a half result; report it as a failed task with the trace
        rec["traceback"] = traceback.format_exc()[-4000:]
        return _fail(opts, res, "internal", f"{type(e).__name__}: {e}")
    finally:
        if hw is not None:
            hw.close()


def _execute(hw, timeline: dict, approval, rec: dict) -> tuple[bool, str]:
    """Run the approved timeline on the arms; (ok, message). Errors leave the arms stopped (backend)."""
    from bimanual_app.hardware import HardwareError

    try:
        report = hw.execute(timeline, approval)
    except HardwareError as e:
        rec["hardware"] = {"ok": False, "error": str(e), "stopped": list(e.stopped)}
        return False, f"hardware run failed: {e}"
    except InputError as e:  # approval or limit problems found before anything moved (or arms stopped)
        rec["hardware"] = {"ok": False, "error": str(e)}
        return False, f"hardware run refused: {e}"
    except KeyboardInterrupt:
        rec["hardware"] = {"ok": False, "error": "interrupted (Ctrl-C): the arms were stopped"}
        raise
    rec["hardware"] = {"ok": True, "wall_s": round(report.wall_s, 3), "cycles": report.cycles,
                       "max_tracking_rad": report.max_tracking_rad, "final_error_rad": report.final_error_rad}
    return True, ""
