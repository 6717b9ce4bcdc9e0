"""Bi-JCR joint calibration: both wrist-camera hand-eye transforms, the reconstruction's metric scale, the
second base, and the metric scene cloud in b1 (docs/calibration.md).

Public API:
    calibrate(scene, method="absolute", options=None, progress=None) -> CalibrationResult  (a loaded Scene;
        with point maps, the joint solve is refined with them: CalibrationOptions.point_maps)
    solve_bijcr(T_b1_e, T_w_c1, T_b2_e, T_w_c2, method=..., options=None) -> CalibrationResult  (arrays)
    solve_single_arm(T_b_e, T_w_c, method=..., options=None) -> dict            (one arm, its own scale)
    scene_cloud(scene, result, conf_threshold=None) -> (points_b1, colors, info)
    metric_cloud(pts3d, T_b1_w, scale, conf=None, colors=None, conf_threshold=None) -> (points, colors, info)
    write_outputs(out_dir, scene, result) -> {name: Path}   (calibration.json, scene_b1.ply, calibration.png, ros/)
    calibrate_stage(scene_dir, out_dir, method, options) -> CalibrationStage  (the stage of bijcr calibrate / run)
    analyse_capture({arm: T_b_e (N, 4, 4)}) -> [Finding]   the view-count / degeneracy checks (also bijcr check)
    base_to_base_advice(uncertainty) -> str | None  the warning when T_b1_b2 is too loose for a hand-over
    CalibrationOptions, CalibrationResult, DegenerateCaptureError, METHODS, DEFAULT_METHOD
CLI: ``bijcr calibrate SCENE --out DIR [--method absolute|paper|paper-norefine]`` (calibration.cli).
"""

from __future__ import annotations

from bimanual_app.lazy import lazy_exports

# name -> private module; imported on first use (PEP 562) so that importing ``calibration.cli`` for
# ``bijcr --help`` does not pull in numpy/scipy.
_EXPORTS = {
    "calibrate": "_api", "scene_cloud": "_api", "write_outputs": "_api",
    "calibrate_stage": "_stage", "CalibrationStage": "_stage", "analyse_capture": "_degeneracy",
    "metric_cloud": "_cloud", "base_to_base_advice": "_advice",
    "solve_bijcr": "_solve", "solve_single_arm": "_solve", "CalibrationOptions": "_solve",
    "CalibrationResult": "_solve", "DegenerateCaptureError": "_solve", "METHODS": "_solve", "DEFAULT_METHOD": "_solve",
}

__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
