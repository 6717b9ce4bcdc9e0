"""Reconstruction stage: camera poses and point maps (reconstruction.npz) from a scene's images.

Backends: ``colmap`` (pycolmap on the CPU: SIFT, exhaustive matching, incremental mapping, then a
plane-sweep densification) and importers for exports of DUSt3R, MASt3R, VGGT and Ray Diffusion made
with ``tools/export_<model>.py`` in those projects' environments. See docs/reconstruction.md.
"""

from ._agreement import motion_agreement
from ._api import BACKENDS, ReconstructResult, build_reconstruction, load_scene_for_reconstruction, reconstruct
from ._colmap import ColmapOptions, SparseModel, run_colmap
from ._dense import DenseOptions
from ._importers import IMPORT_MODELS, import_export, load_export, poses_to_T_w_c
from ._kinematic import inconsistent_views, motion_angle_errors
from ._output import save_reconstruction

__all__ = [
    "BACKENDS", "IMPORT_MODELS", "ReconstructResult", "ColmapOptions", "DenseOptions", "SparseModel",
    "reconstruct", "build_reconstruction", "load_scene_for_reconstruction", "run_colmap",
    "import_export", "load_export", "poses_to_T_w_c", "save_reconstruction", "inconsistent_views", "motion_angle_errors",
    "motion_agreement",
]
