"""The grasping stage as one library call: a metric cloud and its segments in, grasps.json / .png out.

``bijcr grasp``, ``bijcr run`` and ``bijcr task`` (when it produces missing grasps) all call
:func:`grasp_stage`; it raises InputError for bad input, or when no object has a usable grasp.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from bimanual_app.io_utils import InputError, Problem, check_output_dir

__all__ = ["GraspStage", "grasp_stage", "redraw_handovers"]


@dataclass
class GraspStage:
    """What :func:`grasp_stage` made: the plan, the output folder and files, and the objects' problems."""

    plan: object
    out: Path
    files: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


def _no_grasp_problems(plan, seg_path: Path) -> list:
    """Why no object has a usable grasp: each object's problems, then its notes (for an object too wide for
    one gripper: why no two-arm pair)."""
    problems = [p for op in plan.objects for p in op.problems]
    problems += [Problem(str(seg_path), f"object {op.id}", n, "") for op in plan.objects for n in op.notes
                 if not n.startswith("needs two arms")]
    return problems or [Problem(str(seg_path), "", "no object has a grasp that passed the checks", "")]


@dataclass
class _Setup:
    """A grasp stage's inputs, loaded and checked: the cloud (with its views), the gripper, the arms' reach
    filters, the plan's parameters and what grasps.json names as its inputs."""

    cloud: object
    gripper: object
    arms: dict
    T_b1_b2: object
    params: object
    inputs: dict


def _setup(scene, segments, calibration, robot: str, candidates: int, handover: bool, seed: int,
           givers: tuple[str, ...], leave_out: tuple[str, ...], log: Callable[[str], None]) -> _Setup:
    """Load the cloud, its segments and views, the calibration, the gripper and the arms (see grasp_stage)."""
    from bimanual_app.robots import load_robot
    from bimanual_app.views import VIEWS_FILE, load_views

    from ._antipodal import SamplerParams
    from ._arms import make_arms
    from ._gripper import load_gripper
    from ._handover import without_fallbacks
    from ._inputs import b2b_sigma, load_calibration, load_cloud, load_segments, resolve_inputs, scene_cloud
    from ._plan import PlanParams

    cloud_path, cal_path = resolve_inputs(scene, calibration)
    seg_path = Path(segments)
    points, colors = load_cloud(cloud_path)
    labels, seg_extra = load_segments(seg_path)
    cloud = scene_cloud(points, labels, colors, seg_extra.get("table_plane"),
                        {"cloud": str(cloud_path), "segments": str(seg_path)}, str(cloud_path), str(seg_path))
    views_path = cloud_path.parent / VIEWS_FILE
    if views_path.is_file():  # what the cameras saw through (written by `bijcr calibrate` beside the cloud)
        cloud.views = load_views(views_path)
    T_b1_b2, sigma = None, None
    if cal_path is not None:
        cal = load_calibration(cal_path)
        T_b1_b2, sigma = cal["T_b1_b2"], b2b_sigma(cal)
    else:
        log("no calibration.json: planning for the primary arm only (no joint grasps or hand-overs)")
    gripper = load_gripper(robot)
    log(f"{len(points)} points, objects {cloud.object_ids}; gripper {gripper.robot}: opening "
        f"{gripper.min_width * 1000:.0f}-{gripper.max_width * 1000:.0f} mm, fingers {gripper.finger_length * 1000:.0f} mm")
    arms = make_arms(load_robot(robot), gripper, T_b1_b2)
    params = PlanParams(sampler=replace(SamplerParams(), n_candidates=candidates, seed=seed), handover=handover,
                        handover_givers=tuple(givers))
    params = replace(params, handover_params=without_fallbacks(params.handover_params, leave_out))
    if sigma is not None:  # hand-over receivers ranked by how likely they catch the object despite it
        params = replace(params, handover_params=replace(params.handover_params, b2b_sigma_m=sigma[0],
                                                         b2b_sigma_rad=sigma[1]))
        log(f"base-to-base uncertainty (1 sigma, per axis): {sigma[0] * 1000:.1f} mm, "
            f"{sigma[1] * 180 / 3.141592653589793:.2f} deg")
    inputs = {"cloud": str(cloud_path), "segments": str(seg_path),
              "views": str(views_path) if cloud.views is not None else None,
              "calibration": None if cal_path is None else str(cal_path), "robot": robot}
    return _Setup(cloud, gripper, arms, T_b1_b2, params, inputs)


def grasp_stage(scene: str | Path, segments: str | Path, out: str | Path, calibration: str | Path | None = None,
                robot: str = "piper", objects: list[int] | None = None, candidates: int = 500,
                handover: bool = True, seed: int = 0, log: Callable[[str], None] | None = None,
                givers: tuple[str, ...] = ("primary", "secondary"), leave_out: tuple[str, ...] = ()) -> GraspStage:
    """Plan grasps for the objects of ``segments`` in the cloud ``scene`` (scene_b1.ply or its folder).

    ``calibration``: calibration.json with T_b1_b2 (default: beside the cloud; without one, the primary arm
    only). ``candidates``: hand frames sampled per object (>= 10). ``givers``: the arms that may pick and give
    in a hand-over, in order of preference (``PlanParams.handover_givers``). ``leave_out``: hand-over fallbacks
    not to try (keys of ``HANDOVER_FALLBACKS``; a measuring knob). The output folder is checked first.
    Raises InputError for bad input, or listing why when no object has a usable grasp.
    """
    from ._handover import HANDOVER_FALLBACKS
    from ._output import draw_plan, write_grasps_json
    from ._plan import plan_grasps

    log = log or (lambda msg: None)
    out = check_output_dir(out)
    if candidates < 10:
        raise InputError(Problem("command line", "--candidates", f"{candidates} is too few", "use 100 or more"))
    unknown = sorted(set(leave_out) - set(HANDOVER_FALLBACKS))
    if isinstance(leave_out, str) or unknown:
        raise InputError(Problem("grasp_stage", "leave_out", f"unknown hand-over fallback(s) {unknown or [leave_out]}",
                                 f"a tuple of names from {', '.join(HANDOVER_FALLBACKS)}"))
    st = _setup(scene, segments, calibration, robot, candidates, handover, seed, givers, leave_out, log)
    plan = plan_grasps(st.cloud, st.gripper, st.arms, st.T_b1_b2, st.params, objects, log)
    warnings = [p for op in plan.objects for p in op.problems]
    if not any(any(len(a) for a in op.reach.values()) or op.joint for op in plan.objects):
        raise InputError(_no_grasp_problems(plan, Path(segments)))
    out.mkdir(parents=True, exist_ok=True)
    write_grasps_json(out / "grasps.json", plan, st.inputs)
    draw_plan(out / "grasps.png", plan, st.cloud.points, st.cloud.labels)
    return GraspStage(plan, out, {"grasps.json": out / "grasps.json", "grasps.png": out / "grasps.png"}, warnings)


def redraw_handovers(scene: str | Path, segments: str | Path, calibration: str | Path | None, object_id: int,
                     refused_picks, robot: str = "piper", candidates: int = 500, seed: int = 1,
                     log: Callable[[str], None] | None = None) -> list[dict]:
    """More hand-overs of object ``object_id``, as grasps.json writes them (its ``handover`` then its
    ``handover_alternatives``; [] when none is found): the grasp stage's search run again on that object with
    another sampler ``seed`` and the giver's picks near ``refused_picks`` ((K, 4, 4) T_b1_g: picks a task's
    physics preview saw fail; ``HandoverParams.refused_picks``) left out. Nothing is written."""
    import numpy as np

    from ._output import plan_to_dict
    from ._plan import plan_grasps

    log = log or (lambda msg: None)
    st = _setup(scene, segments, calibration, robot, candidates, True, seed, ("primary", "secondary"), (), log)
    refused = np.asarray(refused_picks, dtype=np.float64).reshape(-1, 4, 4)
    params = replace(st.params, handover_params=replace(st.params.handover_params, refused_picks=tuple(refused)))
    plan = plan_grasps(st.cloud, st.gripper, st.arms, st.T_b1_b2, params, [int(object_id)], log)
    d = plan_to_dict(plan, st.inputs)
    o = next((o for o in d.get("objects", []) if o.get("id") == int(object_id)), {})
    return [h for h in [o.get("handover"), *(o.get("handover_alternatives") or [])] if h]
