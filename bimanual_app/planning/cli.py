"""``bijcr reach``: plan one arm to a point (or pose) in b1 against the scene map, write the trajectory
(JSON) and a PyBullet preview of its end state."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HELP = "plan one arm to a target in frame b1 (collision checked against the scene map); write trajectory + preview"
DESCRIPTION = (
    "Plans the chosen arm's gripper frame to --to x,y,z (position only) or x,y,z,roll,pitch,yaw (R = Rz Ry Rx,"
    " radians) in the primary base frame b1, with both arms placed by the calibration (T_b1_b2) and checked"
    " against the metric scene cloud (scene_b1.ply next to calibration.json). Writes trajectory_<arm>.json,"
    " preview_<arm>.png (end state, PyBullet) and joints_<arm>.png. Only a densely validated trajectory is"
    " written; otherwise it says why (out of reach, start in collision, ...) and exits with 1."
)

_CAL_CANDIDATES = ("calibration/calibration.json", "calibration.json")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene folder (scene.yaml, ...)")
    p.add_argument("--arm", choices=["primary", "secondary"], default="primary", help="the arm that moves")
    p.add_argument("--to", required=True, metavar="X,Y,Z[,ROLL,PITCH,YAW]",
                   help="target of the gripper frame in b1 (metres, radians)")
    p.add_argument("--calibration", metavar="JSON",
                   help="calibration.json (default: SCENE/calibration/calibration.json or SCENE/calibration.json)")
    p.add_argument("--cloud", metavar="PLY", help="metric scene cloud in b1 (default: scene_b1.ply beside the calibration)")
    p.add_argument("--use-ground-truth", action="store_true",
                   help="without a calibration, use the scene's ground_truth.yaml T_b1_b2 (synthetic scenes)")
    p.add_argument("--from", dest="q_from", metavar="J1,...,J6", help="start configuration of the moving arm (rad);"
                   " default: the rest pose")
    p.add_argument("--other", metavar="J1,...,J6", help="configuration of the arm that holds still (default: rest pose)")
    p.add_argument("--out", metavar="DIR", help="output folder (default: SCENE/reach)")
    p.add_argument("--margin", type=float, default=0.01, help="required clearance in metres (default 0.01)")
    p.add_argument("--resolution", type=float, default=0.01, help="scene map voxel size in metres (default 0.01)")
    p.add_argument("--speed", type=float, default=0.5, help="fraction of the joint velocity/acceleration limits (default 0.5)")
    p.add_argument("--timeout", type=float, default=5.0, help="planning time limit in seconds (default 5)")
    p.add_argument("--seed", type=int, default=0, help="random seed (IK seeds, OMPL)")
    p.add_argument("--no-preview", action="store_true", help="skip the PyBullet picture")


def _floats(text: str, field: str, counts: tuple[int, ...]):
    from bimanual_app.io_utils import InputError, Problem

    try:
        vals = [float(x) for x in text.replace(" ", "").split(",") if x != ""]
    except ValueError:
        vals = None
    import math

    if vals is None or len(vals) not in counts or not all(math.isfinite(v) for v in vals):
        raise InputError(Problem("command line", field, f"cannot read {text!r}",
                                 f"give {' or '.join(map(str, counts))} comma-separated numbers"))
    return vals


def _read_T(data: dict, key: str, file: str):
    import numpy as np

    from bimanual_app.io_utils import InputError, Problem
    from bimanual_app.transforms import check_T

    if key not in data:
        raise InputError(Problem(file, key, "missing", "re-run `bijcr calibrate` (calibration.json per the contract)"))
    try:
        return check_T(key, np.asarray(data[key], dtype=np.float64))
    except (ValueError, TypeError) as e:
        raise InputError(Problem(file, key, f"not a valid 4x4 transform: {e}", "re-run `bijcr calibrate`")) from e


def _load_inputs(args):
    """(scene, robot, T_b1_b2, points_b1, colors, cloud path, calibration source)."""
    import numpy as np

    from bimanual_app.io_utils import InputError, Problem
    from bimanual_app.robots import load_robot
    from bimanual_app.scene import load_scene

    scene = load_scene(args.scene)
    robot = load_robot(scene.robot or "piper", base_dir=scene.path, ee_link=scene.ee_link)
    cal_path = Path(args.calibration) if args.calibration else next(
        (scene.path / c for c in _CAL_CANDIDATES if (scene.path / c).is_file()), None)
    if cal_path is not None and not cal_path.is_file():
        raise InputError(Problem(str(cal_path), "", "calibration file not found", "check the --calibration path"))
    cloud_path = Path(args.cloud) if args.cloud else None
    if cal_path is not None:
        try:
            data = json.loads(cal_path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise InputError(Problem(str(cal_path), "", f"cannot read JSON: {e}", "re-run `bijcr calibrate`")) from e
        if not isinstance(data, dict):
            raise InputError(Problem(str(cal_path), "", "not a calibration object", "re-run `bijcr calibrate`"))
        from bimanual_app.tasks import check_calibration_scene

        check_calibration_scene(scene, data, cal_path)  # the check `bijcr task` runs: made for this scene?
        T_b1_b2 = _read_T(data, "T_b1_b2", str(cal_path))
        source = str(cal_path)
        if cloud_path is None:
            cloud_path = cal_path.parent / "scene_b1.ply"
    elif args.use_ground_truth:
        if scene.ground_truth is None:
            raise InputError(Problem(str(scene.path / "ground_truth.yaml"), "", "no ground truth in this scene",
                                     f"run `bijcr calibrate {args.scene} --out DIR` and pass --calibration DIR/calibration.json"))
        T_b1_b2 = scene.ground_truth.T_b1_b2
        source = "ground_truth.yaml"
    else:
        raise InputError(Problem(str(scene.path), "calibration", "no calibration.json found (T_b1_b2 and the scene map"
                                 " come from the calibration)",
                                 f"run `bijcr calibrate {args.scene} --out DIR` and pass --calibration DIR/calibration.json;"
                                 " for a synthetic scene, --use-ground-truth uses ground_truth.yaml instead"))
    if cloud_path is None:
        from bimanual_app.scene import ground_truth_cloud

        points, colors, _ = ground_truth_cloud(scene.path)
        cloud_src = "ground truth (synthetic scene)"
    else:
        from segmentation import read_cloud

        points, colors, _ = read_cloud(cloud_path)
        finite = np.all(np.isfinite(points), axis=1)
        points, colors = points[finite], None if colors is None else colors[finite]
        cloud_src = str(cloud_path)
        if len(points) == 0:
            raise InputError(Problem(str(cloud_path), "points", "the scene map has no finite points",
                                     "give a non-empty metric cloud (scene_b1.ply from `bijcr calibrate`)"))
    return scene, robot, T_b1_b2, points, colors, cloud_src, source


def _target(args):
    import numpy as np
    from scipy.spatial.transform import Rotation

    vals = _floats(args.to, "--to", (3, 6))
    T = np.eye(4)
    T[:3, 3] = vals[:3]
    if len(vals) == 6:
        T[:3, :3] = Rotation.from_euler("ZYX", [vals[5], vals[4], vals[3]]).as_matrix()  # R = Rz Ry Rx
    return T, len(vals) == 3


def _config(text: str | None, field: str, robot):
    import numpy as np

    from bimanual_app.io_utils import InputError, Problem
    from bimanual_app.planning import default_ready

    if text is None:
        return default_ready(robot)
    q = np.array(_floats(text, field, (robot.nq_arm,)))
    bad = [f"{robot.joint_names[j]} = {q[j]:.4f} outside [{robot.lower[j]:.4f}, {robot.upper[j]:.4f}]"
           for j in range(robot.nq_arm) if not robot.lower[j] - 1e-9 <= q[j] <= robot.upper[j] + 1e-9]
    if bad:
        raise InputError(Problem("command line", field, "joint limits violated: " + "; ".join(bad),
                                 "give angles (radians) within the robot's joint limits"))
    return q


def run(args) -> int:
    import numpy as np

    from bimanual_app.io_utils import InputError, Problem, check_output_dir, write_json
    from bimanual_app.planning import BimanualSetup
    from bimanual_app.planning._preview import plot_trajectory, render_end_state

    out = check_output_dir(args.out if args.out else Path(args.scene) / "reach")
    T_target, position_only = _target(args)
    scene, robot, T_b1_b2, points, colors, cloud_src, cal_src = _load_inputs(args)
    arm, other = args.arm, ("secondary" if args.arm == "primary" else "primary")
    q_now = {arm: _config(args.q_from, "--from", robot), other: _config(args.other, "--other", robot)}
    print(f"bijcr reach: {scene.name}: {arm} arm -> {np.round(T_target[:3, 3], 4).tolist()}"
          f"{' (position only)' if position_only else ''}; T_b1_b2 from {cal_src}; cloud {cloud_src} ({len(points)} points)",
          file=sys.stderr)
    setup = BimanualSetup(robot, T_b1_b2, points, margin=args.margin, resolution=args.resolution, speed=args.speed)
    print(f"  scene map: {len(setup.world.scene)} points in reach, {setup.world.scene.n_cells} occupied voxels",
          file=sys.stderr)
    plan = setup.plan_reach(arm, T_target, q_now, position_only=position_only, timeout=args.timeout, seed=args.seed)
    if not plan.success:
        field = {"reach": "--to", "goal": "--to", "start": "--from", "search": "--to", "validation": "--to"}.get(plan.reason, "")
        fix = {
            "reach": "choose a target within the arm's reach (about 0.6 m from its shoulder) or drop the orientation",
            "goal": "move the target away from obstacles and the other arm",
            "start": "start from a configuration clear of the scene and the other arm (--from / --other)",
            "search": "try a longer --timeout or another target",
            "validation": "try another target or a larger --timeout",
        }.get(plan.reason, "")
        raise InputError(Problem(str(scene.path), field, plan.message, fix))

    out.mkdir(parents=True, exist_ok=True)
    traj = plan.trajectories[arm]
    data = plan.to_json()
    data.update(scene=scene.name, frame="b1", robot=robot.name, moving_arm=arm,
                target={"T_b1_g": T_target, "position_only": position_only, "link": robot.tcp_link or robot.ee_link},
                T_b1_b2=T_b1_b2, calibration=cal_src, cloud=cloud_src,
                limits={"velocity": robot.velocity_limits * args.speed, "acceleration": robot.accel_limits * args.speed,
                        "speed_fraction": args.speed, "margin_m": args.margin})
    json_path = out / f"trajectory_{arm}.json"
    write_json(json_path, data)
    plot_trajectory(out / f"joints_{arm}.png", traj.times, traj.q, traj.joint_names,
                    robot.velocity_limits * args.speed, f"{scene.name}: {arm} reach ({traj.duration:.2f} s)")
    link = robot.tcp_link or robot.ee_link
    tcp_path = (setup.T_b1_b(arm) @ robot.fk_link(traj.q[:: max(1, len(traj.q) // 25)], link))[:, :3, 3]
    if not args.no_preview:
        end = dict(q_now)
        end[arm] = traj.q[-1]
        # the cloud as seen by the planner (cropped to the arms' reach), one point per 1.2 cm voxel, in colour
        lo, hi = setup.world.scene.bounds
        inside = np.all((points >= lo - 1e-9) & (points <= hi + 1e-9), axis=1)
        P = points[inside]
        C = None if colors is None else np.asarray(colors)[inside]
        _, first = np.unique(np.floor(P / 0.012).astype(np.int64), axis=0, return_index=True)
        render_end_state(out / f"preview_{arm}.png", [robot, robot], [setup.T_b1_b("primary"), setup.T_b1_b("secondary")],
                         [end["primary"], end["secondary"]], P[first], None if C is None else C[first],
                         target_b1=T_target[:3, 3], tcp_path_b1=tcp_path, max_points=12000)
    v = plan.validation
    print(f"  planned with {plan.method} in {plan.timings.get('total', 0) * 1e3:.0f} ms; {traj.duration:.2f} s,"
          f" {len(traj.times)} samples; validated {v.states_checked} states (max step {v.max_step * 1e3:.1f} mm)",
          file=sys.stderr)
    print(f"  wrote {json_path}" + ("" if args.no_preview else f", {out / f'preview_{arm}.png'}") +
          f", {out / f'joints_{arm}.png'}", file=sys.stderr)
    return 0
