"""Scene-level API: calibrate a loaded scene, build its metric cloud, write every output file."""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from bimanual_app.io_utils import InputError, Problem

from ._advice import base_to_base_advice
from ._correction import correction_limits
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


def calibrate(scene, method: str = DEFAULT_METHOD, options: CalibrationOptions | None = None,
              progress=None) -> CalibrationResult:
    """Calibrate a loaded :class:`bimanual_app.scene.Scene` from its ``reconstruction.npz``.

    Uses the end-effector poses of ``ee_poses.csv`` and the reconstruction's camera poses of the same image
    keys; rows the reconstruction did not register are skipped (and reported). Ground truth, when the
    scene has one, is not read.

    Args:
        scene: the scene (``bimanual_app.scene.load_scene``).
        method: "absolute" (default), "paper" or "paper-norefine".
        options: :class:`CalibrationOptions`. With ``point_maps`` (the default) and point maps in the
            reconstruction, the joint solve is refined so that the views' point maps agree
            (:func:`refine_point_maps`).
        progress: optional callable(str), one line per step of the point-map refinement.

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
    if (options or CalibrationOptions()).point_maps and rec.pts3d is not None:
        refine_point_maps(scene, res, options, progress)
    advice = base_to_base_advice(res.uncertainty)  # of the final values: after the point maps
    if advice:
        res.warnings.append(advice)
    return res


def _views_of(scene, result, include_dropped: bool = False):
    """``(rows (V,), arms (V,), T_b_e (V, 4, 4))``: the reconstruction rows of the views the calibration used
    (and those it dropped, with ``include_dropped``), sorted, with each one's arm and end-effector pose."""
    rec = scene.reconstruction
    found = []
    for arm in scene.arms:
        used = set(result.views_used[arm.name])
        if include_dropped:
            used |= {d["index"] for d in result.views_dropped[arm.name]}
        keys = {arm.images[i]: i for i in used}
        found += [(j, arm.index, arm.T_b_e[keys[str(k)]]) for j, (a, k) in enumerate(zip(rec.arm, rec.image))
                  if int(a) == arm.index and str(k) in keys]
    found.sort(key=lambda f: f[0])
    return (np.array([f[0] for f in found], dtype=int), np.array([f[1] for f in found], dtype=int),
            np.array([f[2] for f in found], dtype=np.float64).reshape(-1, 4, 4))


def kinematic_camera_poses(result, arms: np.ndarray, T_b_e: np.ndarray) -> np.ndarray:
    """(V, 4, 4) camera poses in b1 from the kinematics: ``T_b1_b(arm) T_b_e T_e_c(arm)``.

    Args:
        arms: (V,) 1 or 2; T_b_e: (V, 4, 4) each view's end-effector pose in its own arm's base.
    """
    E = np.asarray(T_b_e, dtype=np.float64).reshape(-1, 4, 4)
    return np.stack([(e @ result.T_e1_c1) if int(a) == 1 else (result.T_b1_b2 @ e @ result.T_e2_c2)
                     for a, e in zip(arms, E)])


#: the point-map refinement's raw (independent-residual) sigmas are this many times too small: its
#: residuals are correlated (neighbouring points share a view's depth warp). Set so that the RMS of
#: error / sigma is about 1 on rendered scenes with the emulator's paper noise (rotation and translation
#: factors apply to each block's rotation and translation parts; how they were set: docs/calibration.md);
#: bench/calibration.py ("Point-map refinement") reports how well they match the errors on its own scenes.
POINT_MAP_SIGMA_INFLATION = {"hand_eye_rotation": 10.0, "hand_eye_translation": 27.0, "scale": 20.0,
                             "T_b1_b2_rotation": 28.0, "T_b1_b2_translation": 38.0}


def _refine_with_point_maps(scene, result: CalibrationResult, options: CalibrationOptions | None = None,
                            progress=None) -> dict:
    """Refine ``result`` in place with the point maps (``calibration._pointmap_refine``, ``estimator="refine"``);
    returns the report that
    also goes to ``result.info["point_maps"]``.

    When accepted: ``T_e1_c1``, ``T_e2_c2``, ``scale``, ``T_b1_b2`` take the refined values; ``T_b1_w`` is
    re-fitted to the views (kinematic camera poses against the reconstruction's, at the new scale) and
    ``T_b2_w = T_b1_b2^-1 T_b1_w``; the residuals are recomputed; the uncertainty of the refined outputs
    comes from the refinement (inflated by :data:`POINT_MAP_SIGMA_INFLATION`). The joint solve's values
    stay in the report. When refused, ``result`` is unchanged but for a warning.
    """
    from bimanual_app.transforms import inv_T, mean_T

    from ._closed_form import pair_motions, scaled
    from ._pointmap_refine import refine_with_point_maps
    from ._solve import ARM_NAMES, _residual_summary

    opts = options or CalibrationOptions()
    t0 = time.perf_counter()
    rec = scene.reconstruction
    rows, arms, E = _views_of(scene, result)
    views = _map_views(scene, result, rows, arms, E, normals="next pixels")  # as it was built and tuned
    before = {"T_e1_c1": result.T_e1_c1, "T_e2_c2": result.T_e2_c2, "scale": result.scale,
              "T_b1_b2": result.T_b1_b2, "T_b1_w": result.T_b1_w, "T_b2_w": result.T_b2_w,
              "residuals": result.residuals}
    rr = refine_with_point_maps(views, result.T_e1_c1, result.T_e2_c2, result.scale, result.T_b1_b2,
                                progress=progress)
    report = {"accepted": rr.accepted, "reason": rr.reason, "views": int(len(views)),
              "rms_before_mm": rr.rms_before_m * 1e3, "rms_after_mm": rr.rms_after_m * 1e3,
              "median_before_mm": float(np.median(np.abs(rr.residuals_before_m)) * 1e3) if len(rr.residuals_before_m) else None,
              "median_after_mm": float(np.median(np.abs(rr.residuals_after_m)) * 1e3) if len(rr.residuals_after_m) else None,
              "point_pairs": rr.correspondences, "cross_arm_pairs": rr.cross_arm, "rounds": rr.rounds,
              "note": "RMS / median point-to-plane distance between overlapping views placed by the kinematics"}
    if not rr.accepted:
        result.warnings.append(f"point-map refinement not applied ({rr.reason}); the joint solve's values are kept")
    else:
        result.T_e1_c1, result.T_e2_c2, result.scale, result.T_b1_b2 = rr.T_e1_c1, rr.T_e2_c2, rr.scale, rr.T_b1_b2
        C_b1 = kinematic_camera_poses(result, arms, E)
        result.T_b1_w = mean_T(C_b1 @ inv_T(scaled(rec.T_w_c[rows], result.scale)))
        result.T_b2_w = inv_T(result.T_b1_b2) @ result.T_b1_w
        Es, Cs, kept = [], [], []
        for a in (1, 2):
            Es.append(E[arms == a])
            Cs.append(rec.T_w_c[rows][arms == a])
            kept.append(np.ones(int(np.sum(arms == a)), dtype=bool))
        pms = [pair_motions(e, c, consecutive=opts.pairs == "consecutive") for e, c in zip(Es, Cs)]

        state = SimpleNamespace(X=[result.T_e1_c1, result.T_e2_c2], W=[result.T_b1_w, result.T_b2_w],
                                scale=result.scale)  # what _residual_summary reads of a solver state
        result.residuals = _residual_summary(Es, Cs, kept, pms, state, ARM_NAMES)
        result.uncertainty = _refined_uncertainty(result, rr.covariance, before)
        report["joint_solve"] = before
    report["time_s"] = time.perf_counter() - t0
    result.info["point_maps"] = report
    if len(rr.residuals_before_m):
        result.diagnostics["point_map_residuals_m"] = (rr.residuals_before_m, rr.residuals_after_m)
    return report


def _refined_uncertainty(result, cov: np.ndarray, before: dict) -> dict:
    """The uncertainty dict with the refined outputs' blocks from the refinement's covariance (19, 19)."""
    from ._uncertainty import _block

    k = POINT_MAP_SIGMA_INFLATION
    he = [k["hand_eye_rotation"]] * 3 + [k["hand_eye_translation"]] * 3
    D = np.diag(he + he + [k["scale"]] + [k["T_b1_b2_rotation"]] * 3 + [k["T_b1_b2_translation"]] * 3)
    C = D @ np.asarray(cov, dtype=np.float64) @ D
    u = dict(result.uncertainty or {})
    for name, k0, T in (("T_e1_c1", 0, result.T_e1_c1), ("T_e2_c2", 6, result.T_e2_c2)):
        G = np.zeros((6, 6))  # right correction: rotvec R w, translation R v
        G[:3, :3] = G[3:, 3:] = T[:3, :3]
        u[name] = _block(G @ C[k0:k0 + 6, k0:k0 + 6] @ G.T)
    sd = float(np.sqrt(max(C[12, 12], 0.0)))
    u["scale"] = {"std": result.scale * sd, "percent": 100 * sd}
    t = result.T_b1_b2[:3, 3]
    G = np.eye(6)  # left correction: rotvec w, translation w x t + v
    G[3:, :3] = -np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    u["T_b1_b2"] = _block(G @ C[13:19, 13:19] @ G.T)
    u["estimator"] = ("point-map refinement: linearised covariance, sigmas inflated for correlated residuals "
                      f"({', '.join(f'{n} x {v:g}' for n, v in k.items())}); T_b1_w, T_b2_w: "
                      f"{(result.uncertainty or {}).get('estimator', 'joint solve')}")
    return u


def refine_point_maps(scene, result: CalibrationResult, options: CalibrationOptions | None = None,
                      progress=None) -> dict:
    """The point-map stage of :func:`calibrate`: ``options.estimator`` "joint" (default) or "refine"."""
    opts = options or CalibrationOptions()
    if opts.estimator == "joint":
        return _estimate_jointly(scene, result, options, progress)
    return _refine_with_point_maps(scene, result, options, progress)


def _estimate_jointly(scene, result: CalibrationResult, options: CalibrationOptions | None = None,
                      progress=None) -> dict:
    """Re-solve ``result`` in place as one weighted estimate of the kinematic loop and the point maps
    (``calibration._estimate``); returns the report that also goes to ``result.info["point_maps"]``.

    When the held-out check prefers it: ``T_e1_c1``, ``T_e2_c2``, ``scale``, ``T_b1_b2`` and ``T_b1_w`` take the
    joint values, ``T_b2_w = T_b1_b2^-1 T_b1_w``, the residuals are recomputed, and the uncertainty comes
    from the same weighted problem. Otherwise ``result`` keeps the pose-only values and a warning says why.
    """
    from ._estimate import estimate_jointly
    from ._joint import JointState

    t0 = time.perf_counter()
    rows, arms, E = _views_of(scene, result)
    views = _map_views(scene, result, rows, arms, E)
    P = scene.reconstruction.T_w_c[rows]
    start = JointState(result.T_e1_c1, result.T_e2_c2, result.scale, result.T_b1_b2, result.T_b1_w, np.zeros(len(rows)))
    noise = (np.radians(result.noise["rotation_deg"]), result.noise["translation_mm"] * 1e-3)
    pivot = np.asarray(result.noise.get("pivot_m", np.zeros(3)), dtype=np.float64)  # the pose-only noise model's
    fit = estimate_jointly(views, arms, E, P, start, noise, progress, pivot, correction_limits(result.uncertainty))
    report = _fit_report(scene, fit, rows, views)
    for v in fit.dropped_views:
        result.warnings.append(f"the point map of {report['depth_factors'][v]['image']} contradicts its own pose "
                               "(depth factor or spread far from the other views'): left out of the joint estimate")
    if not fit.accepted:
        result.warnings.append(f"point-map refinement not applied ({fit.reason}); the pose-only values are kept")
    else:
        report["joint_solve"] = {"T_e1_c1": result.T_e1_c1, "T_e2_c2": result.T_e2_c2, "scale": result.scale,
                                 "T_b1_b2": result.T_b1_b2, "T_b1_w": result.T_b1_w, "T_b2_w": result.T_b2_w,
                                 "residuals": result.residuals}
        _apply(scene, result, fit, rows, arms, E, options)
    report["time_s"] = time.perf_counter() - t0
    result.info["point_maps"] = report
    if len(fit.residuals_before_m):
        result.diagnostics["point_map_residuals_m"] = (fit.residuals_before_m, fit.residuals_after_m)
    return report


def _map_views(scene, result, rows, arms, E, normals: str = "window") -> list:
    """The used views' point maps in their camera frames: confident pixels, not the arm's own rig (``normals``:
    see ``camera_frame_views``)."""
    from ._cloud import auto_conf_threshold
    from ._pointmaps import camera_frame_views

    rec = scene.reconstruction
    keep = np.all(np.isfinite(rec.pts3d[rows]), axis=-1)
    if rec.conf is not None:
        conf = rec.conf[rows]
        keep &= (conf > auto_conf_threshold(rec.conf)) & (conf > 0)
    for arm in scene.arms:  # each arm's own fingers move with the camera: not scene points
        keep[arms == arm.index] &= ~_rig_pixels(scene, result, arm)[None]
    return camera_frame_views(rec.pts3d[rows], rec.T_w_c[rows], keep, arms, E, normals)


def _fit_report(scene, fit, rows, views) -> dict:
    rec = scene.reconstruction
    r0, r1 = fit.residuals_before_m, fit.residuals_after_m
    kappa = np.asarray(getattr(fit.state, "kappa", np.zeros(len(rows))))
    return {"accepted": fit.accepted, "reason": fit.reason, "views": int(len(views)),
            "estimator": "one weighted estimate: kinematic loop + point maps + per-view depth factors",
            "rms_before_mm": float(np.sqrt(np.mean(r0 ** 2)) * 1e3) if len(r0) else None,
            "rms_after_mm": float(np.sqrt(np.mean(r1 ** 2)) * 1e3) if len(r1) else None,
            "median_before_mm": float(np.median(np.abs(r0)) * 1e3) if len(r0) else None,
            "median_after_mm": float(np.median(np.abs(r1)) * 1e3) if len(r1) else None,
            "point_pairs": fit.pairs, "cross_arm_pairs": fit.cross_arm, "rounds": fit.rounds,
            "noise": fit.noise, "held_out_cost": fit.held_out,
            "depth_factors": [{"image": str(rec.image[j]), "arm": int(rec.arm[j]), "factor": float(np.exp(k))}
                              for j, k in zip(rows, kappa)],
            "dropped_views": fit.dropped_views,
            "note": "RMS / median point-to-plane distance between overlapping views placed by the kinematics"}


def _apply(scene, result, fit, rows, arms, E, options) -> None:
    """Take the joint estimate into ``result``: values, residuals, uncertainty, depth factors."""
    from bimanual_app.transforms import inv_T

    from ._closed_form import pair_motions
    from ._solve import ARM_NAMES, _residual_summary

    opts = options or CalibrationOptions()
    st, rec = fit.state, scene.reconstruction
    result.T_e1_c1, result.T_e2_c2, result.scale, result.T_b1_b2 = st.T_e1_c1, st.T_e2_c2, st.scale, st.T_b1_b2
    result.T_b1_w = st.T_b1_w
    result.T_b2_w = inv_T(result.T_b1_b2) @ result.T_b1_w
    Es = [E[arms == a] for a in (1, 2)]
    Cs = [rec.T_w_c[rows][arms == a] for a in (1, 2)]
    kept = [np.ones(len(e), dtype=bool) for e in Es]
    pms = [pair_motions(e, c, consecutive=opts.pairs == "consecutive") for e, c in zip(Es, Cs)]
    state = SimpleNamespace(X=[result.T_e1_c1, result.T_e2_c2], W=[result.T_b1_w, result.T_b2_w],
                            scale=result.scale)  # what _residual_summary reads of a solver state
    result.residuals = _residual_summary(Es, Cs, kept, pms, state, ARM_NAMES)
    result.uncertainty = _joint_uncertainty(result, fit.covariance)
    result.diagnostics["depth_log_factor"] = {int(j): float(k) for j, k in zip(rows, st.kappa)}


def _joint_uncertainty(result, cov: np.ndarray) -> dict:
    """The uncertainty dict of every output from the joint problem's covariance (25 + V, 25 + V)."""
    from ._uncertainty import _block, propagate

    C = np.asarray(cov, dtype=np.float64)
    u = dict(result.uncertainty or {})
    for name, k0, T in (("T_e1_c1", 0, result.T_e1_c1), ("T_e2_c2", 6, result.T_e2_c2)):
        G = np.zeros((6, 6))  # right correction: rotvec R w, translation R v
        G[:3, :3] = G[3:, 3:] = T[:3, :3]
        u[name] = _block(propagate(G, C[k0:k0 + 6, k0:k0 + 6]))
    sd = float(np.sqrt(C[12, 12])) if np.isfinite(C[12, 12]) else float("inf")
    u["scale"] = {"std": result.scale * sd, "percent": 100 * sd}
    for name, k0, T in (("T_b1_b2", 13, result.T_b1_b2), ("T_b1_w", 19, result.T_b1_w)):
        t = T[:3, 3]
        G = np.eye(6)  # left correction: rotvec w, translation w x t + v
        G[3:, :3] = -np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
        u[name] = _block(propagate(G, C[k0:k0 + 6, k0:k0 + 6]))
    u["estimator"] = ("joint weighted estimate (kinematic loop + point maps): linearised covariance with the noise "
                      "levels estimated from the data, point maps down-weighted by their correlation factor; "
                      f"T_b2_w: {(result.uncertainty or {}).get('estimator', 'pose-only solve')}")
    return u


ROBOT_RADIUS = 0.15  # m: points this close to a base's vertical axis are taken as the robot itself


def scene_cloud(scene, result: CalibrationResult, conf_threshold: float | None = None, include_dropped: bool = False,
                robot_radius: float = ROBOT_RADIUS, wrist_rig: bool = True, free_space: bool = True,
                confirm_unsure: bool = False):
    """Metric cloud in b1 of a calibrated scene: ``(points (K, 3), colors (K, 3) uint8 or None, info)``.

    Uses the point maps of the views the calibration used (a view dropped as badly registered has a point
    map consistent with its bad pose), unless ``include_dropped``. Points of the robots themselves are
    removed with :func:`robot_self_mask` (``robot_radius=0`` keeps them). Returns ``(empty, None, info)``
    when the reconstruction has no point maps.
    """
    points, colors, info = scene_cloud_and_views(scene, result, conf_threshold, include_dropped, robot_radius,
                                                 wrist_rig, free_space, confirm_unsure)[:3]
    return points, colors, info


def scene_cloud_and_views(scene, result: CalibrationResult, conf_threshold: float | None = None,
                          include_dropped: bool = False, robot_radius: float = ROBOT_RADIUS, wrist_rig: bool = True,
                          free_space: bool = True, confirm_unsure: bool = False):
    """:func:`scene_cloud`'s ``(points, colors, info)``, the depth views those points come from
    (:class:`bimanual_app.views.DepthViews`, the pixels the cloud keeps; None without point maps) and which
    points are unsure ((K,) bool: the points kept as below).

    With ``confirm_unsure`` (opt-in, docs/calibration.md "Metric cloud"), a point under the confidence threshold
    is kept where other views saw a surface at the same place (``_fusion.confirmed_points``; needs
    ``free_space``): the steep sides of objects, which every view sees at a grazing angle and marks unsure."""
    from ._cloud import kept_pixels, metric_cloud

    rec = scene.reconstruction
    if rec is None or rec.pts3d is None:
        return (np.zeros((0, 3)), None, {"points": 0, "note": "the reconstruction has no point maps (pts3d)"}, None,
                np.zeros(0, dtype=bool))
    rows, arms, E = _views_of(scene, result, include_dropped)
    pts3d, T_w_c, info, confirmed = _placed_maps(scene, result, rows, arms, E, wrist_rig, free_space)
    conf = None if rec.conf is None else rec.conf[rows]
    keep, thr = kept_pixels(pts3d, conf, conf_threshold)
    unsure = np.zeros_like(keep)
    if conf is not None and confirm_unsure:  # unsure points that other views saw there too
        unsure = confirmed & ~keep & (conf > 0)
        keep |= unsure
        info["unsure_points_confirmed"] = int(unsure.sum())
    pts3d = np.where(keep[..., None], pts3d, np.nan)
    points, colors, cinfo = metric_cloud(pts3d, result.T_b1_w, result.scale, None,
                                         None if rec.colors is None else rec.colors[rows])
    unsure = unsure[keep]  # metric_cloud keeps the finite points, in the same order
    info = {**cinfo, "conf_threshold": thr, **info}
    views = _depth_views(pts3d, T_w_c, result, arms)
    if robot_radius > 0 and len(points):
        keep = ~robot_self_mask(points, [np.eye(4), result.T_b1_b2], robot_radius)
        info["robot_points_removed"] = int((~keep).sum())
        info["robot_filter_radius_m"] = robot_radius
        points, unsure = points[keep], unsure[keep]
        colors = None if colors is None else colors[keep]
        info["points"] = int(len(points))
    if views is not None and len(points):
        from dataclasses import replace

        from bimanual_app.views import views_disagreement

        views = replace(views, disagreement=views_disagreement(points, views))
        info["views_disagreement_m"] = views.disagreement
    return points, colors, info, views, unsure


def _placed_maps(scene, result: CalibrationResult, rows: np.ndarray, arms: np.ndarray, E: np.ndarray,
                 wrist_rig: bool, free_space: bool) -> tuple[np.ndarray, np.ndarray, dict, np.ndarray]:
    """The point maps (V, H, W, 3) and camera poses (V, 4, 4) of reconstruction ``rows`` as the cloud uses
    them: placed by the kinematics when the point-map refinement was accepted, each wrist's own rig and the
    points other views see through set to NaN; with what was done (info) and the points other views confirm
    ((V, H, W) bool, ``_fusion.confirmed_points``; none without ``free_space``)."""
    rec = scene.reconstruction
    pts3d = rec.pts3d[rows].copy()
    T_w_c = rec.T_w_c[rows]
    anchored = bool((result.info.get("point_maps") or {}).get("accepted"))
    if anchored:
        logk = result.diagnostics.get("depth_log_factor", {})
        factor = np.exp([logk.get(int(j), 0.0) for j in rows])
        pts3d, T_w_c = _kinematic_anchor(pts3d, T_w_c, result, arms, E, factor)
    info = {"views_placed_by": "kinematics" if anchored else "reconstruction"}
    if wrist_rig:
        rig_pixels = {}
        for arm in scene.arms:  # each arm's own fingers, found over all its registered views
            mask = _rig_pixels(scene, result, arm)
            rig_pixels[arm.name] = int(mask.sum())
            views = np.flatnonzero(np.asarray(rec.arm)[rows] == arm.index)
            ys, xs = np.nonzero(mask)
            pts3d[views[:, None], ys, xs] = np.nan
        info["wrist_rig_pixels"] = rig_pixels
    confirmed = np.zeros(pts3d.shape[:3], dtype=bool)
    if free_space:
        seen_through = 0
        if len(rows) >= 3:
            from ._fusion import confirmed_points, free_space_outliers, view_votes

            votes = view_votes(pts3d, T_w_c)
            drop = free_space_outliers(pts3d, T_w_c, votes=votes)
            confirmed = confirmed_points(votes) & ~drop
            seen_through = int(drop.sum())
            pts3d[drop] = np.nan
        info["seen_through_removed"] = seen_through
    return pts3d, T_w_c, info, confirmed


def _depth_views(pts3d: np.ndarray, T_w_c: np.ndarray, result: CalibrationResult, arms: np.ndarray):
    """The metric depth views in b1 of point maps ``pts3d`` (V, H, W, 3) with poses ``T_w_c`` (V, 4, 4) in w:
    the pixels the cloud keeps (finite), NaN elsewhere."""
    from bimanual_app.views import DepthViews

    from ._fusion import pointmap_intrinsics, points_in_cameras

    Pc = points_in_cameras(pts3d.astype(np.float64), T_w_c)
    ok = np.all(np.isfinite(Pc), axis=-1) & (np.nan_to_num(Pc[..., 2], nan=-1.0) > 0)
    K = np.stack([pointmap_intrinsics(Pc[v], ok[v]) for v in range(len(Pc))])
    depth = np.where(ok, Pc[..., 2] * result.scale, np.nan).astype(np.float32)
    S = np.tile(np.eye(4), (len(T_w_c), 1, 1))
    S[:, :3, :3] = T_w_c[:, :3, :3]
    S[:, :3, 3] = result.scale * T_w_c[:, :3, 3]
    return DepthViews(result.T_b1_w @ S, K, depth, np.asarray(arms, dtype=np.int64))


def _rig_pixels(scene, result, arm) -> np.ndarray:
    """(H, W) bool: ``arm``'s wrist-rig pixels (``_selfmask.wrist_rig_pixels`` over all its registered views),
    computed once per result (the refinement and the cloud both need them)."""
    from ._selfmask import wrist_rig_pixels

    cache = result.diagnostics.setdefault("wrist_rig_pixels", {})
    if arm.name not in cache:
        rec = scene.reconstruction
        mine = np.flatnonzero(np.asarray(rec.arm) == arm.index)
        cache[arm.name] = wrist_rig_pixels(rec.pts3d[mine], rec.T_w_c[mine])
    return cache[arm.name]


def _kinematic_anchor(pts3d_w: np.ndarray, T_w_c: np.ndarray, result, arms: np.ndarray, T_b_e: np.ndarray,
                      depth_factor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Move each view's point map (V, H, W, 3) in w to where the kinematics put its camera: ``T_w_c`` (V, 4, 4)
    becomes ``(T_b1_w^-1 T_b1_c)`` with its translation in w units, and each map follows its camera. The
    map keeps its shape in its own camera frame (scaled by the view's ``depth_factor`` (V,) when given);
    only the reconstruction's error in the view's pose goes.
    Returns the moved maps and poses (the input arrays are not changed)."""
    from bimanual_app.transforms import inv_T

    C_w = inv_T(result.T_b1_w) @ kinematic_camera_poses(result, arms, T_b_e)
    C_w[:, :3, 3] /= result.scale
    f = np.ones(len(C_w)) if depth_factor is None else np.asarray(depth_factor, dtype=np.float64)
    D = np.tile(np.eye(4), (len(C_w), 1, 1))
    D[:, :3, :3] *= f[:, None, None]
    M = C_w @ D @ inv_T(np.asarray(T_w_c, dtype=np.float64))  # (V, 4, 4): old camera pose -> new, in w
    V = len(M)
    # one BLAS matmul per view (an einsum over these shapes is about 10x slower)
    out = np.matmul(pts3d_w.astype(np.float64).reshape(V, -1, 3), np.ascontiguousarray(M[:, :3, :3].transpose(0, 2, 1)))
    out = out.reshape(pts3d_w.shape) + M[:, None, None, :3, 3]
    return out.astype(pts3d_w.dtype), C_w


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
        local = (P - T[:3, 3]) @ np.ascontiguousarray(T[:3, :3])  # points in that base's frame (contiguous: BLAS)
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
                  figure: bool = True, log=None, figures=None, confirm_unsure: bool = False) -> dict:
    """Write calibration.json, scene_b1.ply, calibration.png and the ROS exports into ``out_dir``.

    ``confirm_unsure``: keep the unsure points other views confirm, flagged in scene_b1.ply (vertex property
    ``unsure``; :func:`scene_cloud_and_views`).

    ``figures``: a started :class:`~calibration._figures.FigureWorker` to draw the figures in (it is
    finished here); None: one is started here. Every file is complete when this returns.
    Returns ``{name: Path}`` of the files written.
    """
    from bimanual_app.views import VIEWS_FILE, write_views

    from ._export import default_frames, write_calibration_json, write_ply, write_ros
    from ._figures import FigureWorker

    log = log or (lambda msg: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with figures if figures is not None else FigureWorker(parallel=figure) as figures:
        pm_figure = figure and "point_map_residuals_m" in result.diagnostics
        if pm_figure:  # drawn while the cloud is built
            figures.draw("save_point_map_figure", out / "point_maps.png", *result.diagnostics["point_map_residuals_m"],
                         result.info.get("point_maps", {}), title=f"point-map refinement of '{scene.name}'")
        pts, cols, cinfo, views, unsure = scene_cloud_and_views(scene, result, conf_threshold,
                                                                confirm_unsure=confirm_unsure)
        log(f"metric cloud: {cinfo['points']} points" + (f" (conf > {cinfo['conf_threshold']:.3g})"
                                                          if cinfo.get("conf_threshold") is not None else ""))
        if figure:  # drawn while the files below are written
            arrs = []
            for arm in scene.arms:
                used = result.views_used[arm.name]
                keys = [arm.images[i] for i in used]
                _, rec_rows = scene.reconstruction.rows_for(arm.index, keys)
                arrs += [arm.T_b_e[used], scene.reconstruction.T_w_c[rec_rows]]
            figures.draw("save_calibration_figure", out / "calibration.png", result, *arrs, pts if len(pts) else None,
                         cols, title=f"Bi-JCR calibration of '{scene.name}'")
        files = {}
        frames = default_frames(_ee_link_name(scene))
        write_calibration_json(out / "calibration.json", result, scene.name,
                               extra={"cloud": {k: v for k, v in cinfo.items()}, "ros_frames": frames})
        files["calibration.json"] = out / "calibration.json"
        if len(pts):
            write_ply(out / "scene_b1.ply", pts, cols, unsure if confirm_unsure else None)
            files["scene_b1.ply"] = out / "scene_b1.ply"
        if views is not None:  # what the cameras saw through, for the grasp stage (bimanual_app/views.py)
            files[VIEWS_FILE] = write_views(out / VIEWS_FILE, views)
        for p in write_ros(out, result, scene.name, frames):
            files[str(p.relative_to(out))] = p
        figures.finish()
    if figure:
        files["calibration.png"] = out / "calibration.png"
        if pm_figure:
            files["point_maps.png"] = out / "point_maps.png"
    log(f"wrote {len(files)} files in {time.perf_counter() - t0:.2f} s")
    return files
