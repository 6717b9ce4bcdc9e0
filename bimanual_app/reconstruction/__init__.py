"""Reconstruction stage: camera poses and point maps (reconstruction.npz) from a scene's images.

Backends: ``colmap`` (pycolmap on the CPU: SIFT, exhaustive matching, incremental mapping, then a
plane-sweep densification) and importers for exports of DUSt3R, MASt3R, VGGT and Ray Diffusion made
with ``tools/export_<model>.py`` in those projects' environments. See docs/reconstruction.md.
"""

from __future__ import annotations

from bimanual_app.lazy import lazy_exports

# name -> private module; imported on first use (PEP 562), so that ``bijcr --help`` and a mistyped
# ``bijcr reconstruct`` answer without loading OpenCV or pycolmap.
_EXPORTS = {
    "motion_agreement": "_agreement",
    "BACKENDS": "_api", "ReconstructResult": "_api", "build_reconstruction": "_api", "load_scene_for_reconstruction": "_api", "reconstruct": "_api",
    "ColmapOptions": "_colmap", "SparseModel": "_colmap", "run_colmap": "_colmap",
    "DenseOptions": "_dense",
    "IMPORT_MODELS": "_importers", "import_export": "_importers", "load_export": "_importers", "poses_to_T_w_c": "_importers",
    "inconsistent_views": "_kinematic", "motion_angle_errors": "_kinematic",
    "save_reconstruction": "_output",
}

__all__ = [
    "BACKENDS", "IMPORT_MODELS", "ReconstructResult", "ColmapOptions", "DenseOptions", "SparseModel",
    "reconstruct", "build_reconstruction", "load_scene_for_reconstruction", "run_colmap", "import_export", "load_export",
    "poses_to_T_w_c", "save_reconstruction", "inconsistent_views", "motion_angle_errors", "motion_agreement",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
