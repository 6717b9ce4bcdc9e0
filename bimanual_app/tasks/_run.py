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

__all__ = ["TaskOptions", "TaskResult", "run_task"]

ARMS = ("primary", "secondary")
MAX_FALLBACK_OBJECTS = 2  # without --object: objects tried after the best-scoring one cannot be planned
MAX_CANDIDATES = 4  # grasp candidates (pairs, hand-overs) planned per object
MAX_PREVIEWS = 3  # plans previewed before the task gives up: a failed preview moves on to the next candidate
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
            ensure_stages(scene.path, paths, timings, quiet=opts.quiet, scene=scene, masks=opts.masks)
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


def _run_loaded(opts, scene, inputs, robot, staging: OutputDir, timings: dict) -> TaskResult:
    from bimanual_app.hardware import approve_plan, save_plan, write_approval
    from bimanual_app.simulation import estimated_shapes, table_from_segments

    from ._grasps import choose, handover_candidates, joint_candidates
    from ._motion import BASE_RADIUS, PlanFailure, TaskMotion, robot_points_mask
    from ._planners import plan_handover, plan_joint_grasp
    from ._preview import preview_plan

    rec: dict = {"format": 1, "task": opts.task, "scene": scene.name, "success": False, "reason": "",
                 "object": None, "object_reason": "", "plans": [], "approval": None,
                 "inputs": {"calibration": str(inputs.paths.calibration), "cloud": str(inputs.paths.cloud),
                            "segments": str(inputs.paths.segments), "grasps": str(inputs.paths.grasps)},
                 "options": {"truth_objects": opts.truth_objects, "execute": opts.execute,
                             "plan_time_s": opts.plan_time, "speed": opts.speed},
                 "warnings": list(inputs.warnings)}
    res = TaskResult(opts.task, False, "", None, record=rec)

    def fail(stage: str, reason: str) -> TaskResult:
        res.success, res.failed_stage = False, stage
        res.reason = reason
        rec.update(success=False, reason=reason, failed_stage=stage)
        _log(opts, f"FAILED at {stage}: {reason}")
        return res

    # ---- which object
    known = sorted(int(k) for k in np.unique(inputs.labels) if k >= 0)
    gpath = str(inputs.paths.grasps)
    cands = (joint_candidates if opts.task == "joint-grasp" else handover_candidates)(inputs.grasps, gpath)
    mine, why = choose(cands, opts.object_id, opts.task, gpath, known)
    oid = mine[0].object_id if mine else opts.object_id
    res.object_id, res.object_reason = oid, why
    rec.update(object=oid, object_reason=why)
    if oid is not None:
        _log(opts, f"object {oid}: {why}")
    if not mine:
        what = "two-arm grasp pair" if opts.task == "joint-grasp" else "hand-over (giver and receiver grasps)"
        if oid is None:
            return fail("grasp", f"{why}: the objects are out of reach of the arms or too small/large to grasp "
                                 f"(see {gpath})")
        return fail("grasp", f"object {oid} has no reachable {what} in {gpath}: it is out of reach, or no "
                             "collision-free grasp exists")

    # ---- start configuration: the arms' own (hardware) or the rest pose
    hw = None
    if opts.execute == "hardware":
        t = time.perf_counter()
        try:
            hw = _connect_hardware(opts, robot)
            fb = hw.read()
            q_start = {a: np.asarray(fb[a].q, dtype=np.float64) for a in ARMS}
            width_start = {a: float(fb[a].gripper_m) if fb[a].gripper_m is not None else OPEN_START for a in ARMS}
        except Exception as e:
            if hw is not None:
                hw.close()
            timings["hardware"] = time.perf_counter() - t
            rec["hardware"] = {"ok": False, "error": str(e), "connected": False}
            return fail("hardware", f"cannot connect to the arms ({e}); nothing was planned or sent")
        timings["hardware_connect"] = time.perf_counter() - t
    else:
        from bimanual_app.planning import default_ready

        q_start = {a: default_ready(robot) for a in ARMS}
        width_start = {a: OPEN_START for a in ARMS}

    try:
        # ---- plan: the chosen object's candidates in order; without --object, the next objects (by their
        # best score) when none of the first one's can be planned
        t_start = time.perf_counter()
        table = table_from_segments(inputs.points, inputs.labels, inputs.seg_extras)
        robot_pts = robot_points_mask(inputs.points, inputs.labels, np.stack([np.zeros(3), inputs.T_b1_b2[:3, 3]]),
                                      table.normal, -table.d)
        if robot_pts.any():
            rec["planning_map"] = {"robot_points_removed": int(robot_pts.sum()),
                                   "note": f"background points within {BASE_RADIUS} m of a base axis (the arms "
                                           "seen by the cameras) are not obstacles"}
        order = [oid]
        if opts.object_id is None:
            order += [o for o in dict.fromkeys(c.object_id for c in cands) if o != oid][:MAX_FALLBACK_OBJECTS]
        # each candidate that plans and validates is previewed on the reconstruction (never on the ground
        # truth: that is only for judging); the first that passes is the task's plan. A failed preview moves
        # on to the next candidate, up to MAX_PREVIEWS previews; if none passes, the first failed one is
        # reported (and approved as 'fail').
        motion, tried, attempts = None, [], []
        chosen = failed = None  # _Attempt
        t_preview = 0.0
        select_record = opts.record and not opts.truth_objects
        for o in order:
            shapes, warns = estimated_shapes(inputs.points, inputs.labels, table, ids=[o])
            rec["warnings"] += warns
            if o not in shapes:
                tried.append((o, PlanFailure("input", f"no collision body from its points ({'; '.join(warns)})"), 0))
                continue
            sh = shapes[o]
            pts_o = sh.surface_points_b1()
            motion_o = TaskMotion(robot, inputs.T_b1_b2, inputs.points[~robot_pts], pts_o,
                                  inputs.points[inputs.labels == o], plan_time=opts.plan_time, speed=opts.speed,
                                  body=sh, up=table.normal)
            if motion is None:  # the first map built: the start must be free in it
                problems = motion_o.problems(q_start)
                if problems:
                    return fail("start", "the arms' start configuration is in collision: " + "; ".join(problems[:3]))
            motion = motion_o
            errors = []
            for k, c in enumerate([c for c in cands if c.object_id == o][:MAX_CANDIDATES]):
                if len(attempts) >= MAX_PREVIEWS:
                    break
                try:
                    if opts.task == "joint-grasp":
                        plan = plan_joint_grasp(motion_o, c, q_start, width_start, up=table.normal)
                    else:
                        plan = plan_handover(motion_o, c, q_start, width_start, pts_o, up=table.normal)
                    plan.info["candidate_rank"] = k
                    plan.info["candidate"] = {"grasps_json": c.info.get("source"), "score": round(float(c.score), 4)}
                    timeline = plan.timeline()
                    try:  # the samples the preview and the hardware get
                        motion_o.validate_timeline(timeline, plan.opening_spans())
                    except PlanFailure as e:
                        raise PlanFailure("validation", f"the assembled plan failed validation: {e.message}") from None
                except PlanFailure as e:
                    errors.append(e)
                    _log(opts, f"candidate {k + 1} of object {o}: {e}")
                    continue
                t = time.perf_counter()
                _log(opts, f"object {o}, candidate {k + 1}: previewing {len(plan.phases)} phases "
                           f"({plan.duration:.1f} s) in PyBullet")
                pv = preview_plan(plan, inputs, robot, o, gui=opts.gui and not opts.truth_objects,
                                  record=select_record, frame_size=tuple(opts.frame_size),
                                  log=None if opts.quiet else (lambda m: _log(opts, m)))
                t_preview += time.perf_counter() - t
                att = _Attempt(o, k, plan, motion_o, timeline, pv)
                attempts.append(att)
                if pv.success:
                    chosen = att
                    break
                failed = failed or att
                errors.append(PlanFailure("preview", f"the physics preview failed: {pv.reason}"))
                _log(opts, f"candidate {k + 1} of object {o}: the physics preview failed: {pv.reason}")
            if chosen is not None or len(attempts) >= MAX_PREVIEWS:
                if chosen is None:
                    tried.append((o, errors[0], len(errors)))
                break
            tried.append((o, errors[0], len(errors)) if errors else (o, PlanFailure("grasp", "no candidate"), 0))
        timings["plan"] = time.perf_counter() - t_start - t_preview
        if attempts:
            timings["preview"] = t_preview
        if motion is not None:
            rec["planning"] = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in motion.stats.items()}
        if tried:
            rec["objects_tried"] = [{"object": o, "reason": e.message, "candidates": n} for o, e, n in tried]
        if attempts:
            rec["previews_tried"] = [{"object": a.object_id, "candidate_rank": a.rank, "success": a.preview.success,
                                      "reason": a.preview.reason} for a in attempts]
        pick = chosen or failed
        if pick is None:
            o, e, n_c = tried[0]
            stage = {"reach": "reach", "cartesian": "reach", "plan": "plan", "validation": "plan"}.get(e.stage, e.stage)
            more = f" ({n_c} grasp candidates tried)" if n_c > 1 else ""
            others = f"; {len(tried) - 1} other object(s) could not be planned either" if len(tried) > 1 else ""
            return fail(stage, f"no valid plan for object {o}{more}: {e.message}{others}")
        plan, motion, timeline = pick.plan, pick.motion, pick.timeline
        if pick.object_id != oid:
            first = tried[0][1]
            why = (f"object {pick.object_id}, the next best: the best-scoring object {oid} "
                   + ("failed its physics preview" if first.stage == "preview" else "could not be planned")
                   + f" ({first.message})")
            oid = pick.object_id
            res.object_id, res.object_reason = oid, why
            rec.update(object=oid, object_reason=why)
            _log(opts, why)
        rec["plans"] = plan.summary()
        rec["plan"] = {"duration_s": round(plan.duration, 3),
                       "n_waypoints": {a: len(tr) for a, tr in timeline.items()}, "info": plan.info}
        save_plan(staging.path("plan.npz"), timeline)

        # ---- the physics preview reported (and approved): the chosen plan's on the reconstruction, or with
        # --truth-objects the same plan in the ground-truth world
        pv = pick.preview
        if opts.truth_objects:
            t = time.perf_counter()
            _log(opts, f"previewing the chosen plan ({len(plan.phases)} phases) against the ground truth")
            pv = preview_plan(plan, inputs, robot, oid, truth=True, gui=opts.gui, record=opts.record,
                              frame_size=tuple(opts.frame_size), log=None if opts.quiet else (lambda m: _log(opts, m)))
            timings["preview_truth"] = time.perf_counter() - t
        res.preview = pv.to_json()
        rec["preview"] = res.preview
        if pv.recorder is not None and pv.recorder.frames:
            pv.recorder.save_gif(staging.path("preview.gif"))
            pv.recorder.save_keyframes(staging.staging)
        approval = approve_plan(timeline, "pass" if pv.success else "fail",
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
        if not pv.success:
            more = f" ({len(attempts)} plans previewed, none passed)" if len(attempts) > 1 else ""
            return fail("preview", f"the physics preview failed: {pv.reason}{more}")
        res.success, res.reason = True, f"preview passed: {pv.reason}"
        rec.update(success=True, reason=res.reason)

        # ---- hardware
        if hw is not None:
            t = time.perf_counter()
            ok, msg = _execute(hw, timeline, approval, rec)
            timings["hardware"] = time.perf_counter() - t
            if not ok:
                return fail("hardware", msg)
            res.reason = rec["reason"] = res.reason + "; executed on the hardware"
        return res
    except InputError:
        raise
    except Exception as e:  # a bug must not leave a half result; report it as a failed task with the trace
        rec["traceback"] = traceback.format_exc()[-4000:]
        return fail("internal", f"{type(e).__name__}: {e}")
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
