"""``bijcr view``: a run's scene, calibration, grasps and task plans in an interactive 3D page (viser).

Public API (imported on use, so ``bijcr --help`` does not load numpy or viser):
    load_run(run_dir, scene=None) -> RunLayers     read a run folder into typed layers (no 3D library)
    RunLayers, Cloud, CameraView, GripperPose, ObjectGrasps, PhaseSpan, TaskReplay   the layers
    object_track(phases, pose_fn) / object_pose(track, pose_fn, t) / hold_intervals(phases)
        the carried object during a replay (pure functions)
    serve(layers, host, port, timeout) / build_scene(server, layers)   the viser server (needs `viser`)
CLI: ``bijcr view RUN_DIR [--port P] [--host H] [--scene SCENE] [--timeout S]``. See docs/viewer.md.
"""

from __future__ import annotations

from bimanual_app.lazy import lazy_exports

_EXPORTS = {
    "load_run": "_read",
    "RunLayers": "_types", "Cloud": "_types", "CameraView": "_types", "GripperPose": "_types",
    "ObjectGrasps": "_types", "PhaseSpan": "_types", "TaskReplay": "_types",
    "hold_intervals": "_motion", "object_track": "_motion", "object_pose": "_motion",
    "serve": "_server", "build_scene": "_server",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
