"""Scene-level API: calibrate a loaded scene, build its metric cloud, write every output file."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem

from ._solve import DEFAULT_METHOD, CalibrationOptions, CalibrationResult, solve_bijcr


def _arm_rows(scene, arm, rec) -> tuple[np.ndarray, np.ndarray]:
    """(csv_rows, rec_rows) of one arm; raises on keys that match no CSV row or an arm without registered images."""
    rec_path = "reconstruction.npz"
    own = [str(k) for a, k in zip(rec.arm, rec.image) if int(a) == arm.index]
    unknown = sorted(set(own) - set(arm.images))
    if unknown:
        shown = ", ".join(unknown[:5]) + (f" (+{len(unknown) - 5} more)" if len(unknown) > 5 else "")
        raise InputError(Problem(rec_path, "image", f"{len(unknown)} {arm.name} image key(s) match no row of "
                                 f"{arm.name}/ee_poses.csv: {shown}",
                                 "re-run 'bijcr reconstruct SCENE' on this scene's images, or fix the keys to match "
                                 "the 'image' column of ee_poses.csv"))
    csv_rows, rec_rows = rec.rows_for(arm.index, arm.images)
    if len(csv_rows) == 0:
        raise InputError(Problem(rec_path, "arm", f"the reconstruction has none of the {arm.name} arm's images "
                                 f"(arm = {arm.index})",
                                 "re-run 'bijcr reconstruct SCENE' with both arms' images (each arm needs 3 or more "
                                 "registered views)"))
    return csv_rows, rec_rows


def calibrate(scene, method: str = DEFAULT_METHOD, options: CalibrationOptions | None = None) -> CalibrationResult:
    """Calibrate a loaded :class:`bimanual_app.scene.Scene` from its ``reconstruction.npz``.

    Uses the end-effector poses of ``ee_poses.csv`` and the reconstruction's camera poses of the same image
    keys; rows the reconstruction did not register are skipped (and reported). Ground truth, when the
    scene has one, is not read.

    Args:
        scene: the scene (``bimanual_app.scene.load_scene``).
        method: "absolute" (default), "paper" or "paper-norefine".
        options: :class:`CalibrationOptions`.

    Returns:
        :class:`CalibrationResult`; ``views_used`` / ``views_dropped`` index the rows of each arm's
        ee_poses.csv, ``images`` holds their keys.
    """
    rec = scene.reconstruction
    if rec is None:
        raise InputError(Problem(str(Path(scene.path) / "reconstruction.npz"), "", "file is missing: calibration "
                                 "needs the reconstruction's camera poses", "run 'bijcr reconstruct SCENE' to make it"))
    arrays, images, notes = [], [], []
    for arm in scene.arms:
        csv_rows, rec_rows = _arm_rows(scene, arm, rec)
        arrays += [arm.T_b_e[csv_rows], rec.T_w_c[rec_rows]]
        images.append([arm.images[i] for i in csv_rows])
        missing = len(arm) - len(csv_rows)
        if missing:
            skipped = [k for i, k in enumerate(arm.images) if i not in set(csv_rows.tolist())]
            notes.append(f"{arm.name} arm: {missing} of {len(arm)} image(s) not registered by the reconstruction, "
                         f"skipped: {', '.join(skipped[:5])}" + (" ..." if len(skipped) > 5 else ""))
    sources = {"T_b1_e": "primary/ee_poses.csv", "T_w_c1": "reconstruction.npz",
               "T_b2_e": "secondary/ee_poses.csv", "T_w_c2": "reconstruction.npz"}
    res = solve_bijcr(*arrays, method=method, options=options, images=(images[0], images[1]), sources=sources)
    # re-index views to the CSV rows
    for arm, imgs in zip(scene.arms, images):
        row_of = {k: i for i, k in enumerate(arm.images)}
        res.views_used[arm.name] = [row_of[imgs[i]] for i in res.views_used[arm.name]]
        for d in res.views_dropped[arm.name]:
            d["index"] = row_of[imgs[d["index"]]]
    res.images = {arm.name: list(arm.images) for arm in scene.arms}
    res.warnings = notes + res.warnings
    res.info["registered"] = {arm.name: len(im) for arm, im in zip(scene.arms, images)}
    return res


ROBOT_RADIUS = 0.15  # m: points this close to a base's vertical axis are taken as the robot itself


def scene_cloud(scene, result: CalibrationResult, conf_threshold: float | None = None, include_dropped: bool = False,
                robot_radius: float = ROBOT_RADIUS, wrist_rig: bool = True, free_space: bool = True):
    """Metric cloud in b1 of a calibrated scene: ``(points (K, 3), colors (K, 3) uint8 or None, info)``.

    Uses the point maps of the views the calibration used (a view dropped as badly registered has a point
    map consistent with its bad pose), unless ``include_dropped``. Points of the robots themselves are
    removed with :func:`robot_self_mask` (``robot_radius=0`` keeps them). Returns ``(empty, None, info)``
    when the reconstruction has no point maps.
    """
    from ._cloud import metric_cloud

    rec = scene.reconstruction
    if rec is None or rec.pts3d is None:
        return np.zeros((0, 3)), None, {"points": 0, "note": "the reconstruction has no point maps (pts3d)"}
    rows = []
    for arm in scene.arms:
        used = set(result.views_used[arm.name])
        if include_dropped:
            used |= {d["index"] for d in result.views_dropped[arm.name]}
        keys = {arm.images[i] for i in used}
        rows += [j for j, (a, k) in enumerate(zip(rec.arm, rec.image)) if int(a) == arm.index and str(k) in keys]
    rows = np.array(sorted(rows), dtype=int)
    pts3d = rec.pts3d[rows].copy()
    rig_pixels = {}
    if wrist_rig:
        from ._selfmask import wrist_rig_pixels

        for arm in scene.arms:  # each arm's own fingers, found over all its registered views
            mine = np.flatnonzero(np.asarray(rec.arm) == arm.index)
            mask = wrist_rig_pixels(rec.pts3d[mine], rec.T_w_c[mine])
            rig_pixels[arm.name] = int(mask.sum())
            views = np.flatnonzero(np.asarray(rec.arm)[rows] == arm.index)
            ys, xs = np.nonzero(mask)
            pts3d[views[:, None], ys, xs] = np.nan
    seen_through = 0
    if free_space and len(rows) >= 3:
        from ._fusion import free_space_outliers

        drop = free_space_outliers(pts3d, rec.T_w_c[rows])
        seen_through = int(drop.sum())
        pts3d[drop] = np.nan
    points, colors, info = metric_cloud(pts3d, result.T_b1_w, result.scale,
                                        None if rec.conf is None else rec.conf[rows],
                                        None if rec.colors is None else rec.colors[rows], conf_threshold)
    if rig_pixels:
        info["wrist_rig_pixels"] = rig_pixels
    if free_space:
        info["seen_through_removed"] = seen_through
    if robot_radius > 0 and len(points):
        keep = ~robot_self_mask(points, [np.eye(4), result.T_b1_b2], robot_radius)
        info["robot_points_removed"] = int((~keep).sum())
        info["robot_filter_radius_m"] = robot_radius
        points = points[keep]
        colors = None if colors is None else colors[keep]
        info["points"] = int(len(points))
    return points, colors, info


def robot_self_mask(points_b1: np.ndarray, T_b1_bases: list[np.ndarray], radius: float = ROBOT_RADIUS,
                    above: float = 0.015) -> np.ndarray:
    """(N,) True for points that are most likely the robots themselves (a self filter).

    The wrist cameras see both arms, so the reconstruction holds them, at their capture poses. Kept in the
    metric cloud they would be obstacles that put each arm in collision with itself in every later stage.
    Without the arms' joint angles at capture time the arms cannot be rendered out exactly, so this drops
    the points within ``radius`` m of each base's vertical (z) axis and more than ``above`` m over that
    base's plane: the column where a parked or capturing arm stands. Objects that close to a base are out
    of reach of a useful grasp anyway.

    Args:
        points_b1: (N, 3) metric points in b1.
        T_b1_bases: list of (4, 4) base poses in b1 (``np.eye(4)`` for b1 itself, ``T_b1_b2``).
    """
    P = np.asarray(points_b1, dtype=np.float64)
    mask = np.zeros(len(P), dtype=bool)
    for T in T_b1_bases:
        local = (P - T[:3, 3]) @ T[:3, :3]  # points in that base's frame
        mask |= (np.hypot(local[:, 0], local[:, 1]) < radius) & (local[:, 2] > above)
    return mask


def _ee_link_name(scene) -> str | None:
    if scene.ee_link:
        return scene.ee_link
    try:  # the registry is a plain table (no pinocchio import)
        from bimanual_app.robots._registry import REGISTRY

        spec = REGISTRY.get(scene.robot or "")
        return spec.ee_link if spec else None
    except ImportError:
        return None


def write_outputs(out_dir: str | Path, scene, result: CalibrationResult, conf_threshold: float | None = None,
                  figure: bool = True, log=None) -> dict:
    """Write calibration.json, scene_b1.ply, calibration.png and the ROS exports into ``out_dir``.

    Returns ``{name: Path}`` of the files written.
    """
    from ._export import default_frames, write_calibration_json, write_ply, write_ros

    log = log or (lambda msg: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    pts, cols, cinfo = scene_cloud(scene, result, conf_threshold)
    log(f"metric cloud: {cinfo['points']} points" + (f" (conf > {cinfo['conf_threshold']:.3g})"
                                                      if cinfo.get("conf_threshold") is not None else ""))
    files = {}
    frames = default_frames(_ee_link_name(scene))
    write_calibration_json(out / "calibration.json", result, scene.name,
                           extra={"cloud": {k: v for k, v in cinfo.items()}, "ros_frames": frames})
    files["calibration.json"] = out / "calibration.json"
    if len(pts):
        write_ply(out / "scene_b1.ply", pts, cols)
        files["scene_b1.ply"] = out / "scene_b1.ply"
    for p in write_ros(out, result, scene.name, frames):
        files[str(p.relative_to(out))] = p
    if figure:
        from ._plot import save_calibration_figure

        arrs = []
        for arm in scene.arms:
            used = result.views_used[arm.name]
            keys = [arm.images[i] for i in used]
            _, rec_rows = scene.reconstruction.rows_for(arm.index, keys)
            arrs += [arm.T_b_e[used], scene.reconstruction.T_w_c[rec_rows]]
        save_calibration_figure(out / "calibration.png", result, *arrs, pts if len(pts) else None, cols,
                                title=f"Bi-JCR calibration of '{scene.name}'")
        files["calibration.png"] = out / "calibration.png"
    log(f"wrote {len(files)} files in {time.perf_counter() - t0:.2f} s")
    return files
