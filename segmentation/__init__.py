"""Graph-based segmentation of a metric table-top cloud in b1: the table and one segment per object.

Public API:
    segment(points, colors=None, normals=None, mask_ids=None, params=None, bases=None, source="points",
            progress=False, unsure=None) -> SegmentResult  (unsure (N,) bool: points that join a segment, never
            link two)
    SegmentParams: the tunables (with the reasons for their defaults).
    CLEANUP_STEPS: the names of the clean-up steps after the contraction (``SegmentParams.skip``).
    SegmentResult: labels (N,) int32 (-1 table/background, 0..K-1 objects), table, objects, stats, timings.
    ObjectSummary: per object: points, centroid, table-aligned oriented box (center, rotation, extents).
    TablePlane: the fitted table.
    fit_plane(points, threshold, up=None, near=None, level_only=False, ...) -> PlaneFit | None: the robust
        plane fitter the table uses (also the physics preview's table and the plane sweep's dominant plane);
        uniform_sample(points, n_max, seed=0, cell=0.01): one point per voxel, a plane's support its area.
    MaskViews: per-image masks carried into b1 through a scene's point maps (``mask_ids=`` of segment).
    read_cloud(path) -> (points, colors, normals); write_segments(out_dir, result, points, source)
    read_unsure(path, n) -> (N,) bool or None: the points a bijcr calibrate cloud marks unsure (other views
        confirmed them)
    read_calibration(path) -> (T_b1_w, scale, T_b1_b2 or None)
    segment_stage(cloud_path, out_dir, calibration=None, masks=None, ...) -> SegmentStage  (bijcr segment / run)
CLI: ``bijcr segment CLOUD --out DIR [--masks SCENE]``. See docs/segmentation.md.
"""

from __future__ import annotations

from bimanual_app.lazy import lazy_exports

# name -> private module; imported on first use (PEP 562), so that ``bijcr --help`` and a mistyped
# ``bijcr segment`` answer without loading scipy, Open3D or coal.
_EXPORTS = {
    "read_cloud": "_io", "read_unsure": "_io", "write_segments": "_io",
    "MaskViews": "_masks", "read_calibration": "_masks",
    "SegmentParams": "_params", "CLEANUP_STEPS": "_cleanup",
    "SegmentResult": "_pipeline", "segment": "_pipeline",
    "PlaneFit": "_plane", "fit_plane": "_plane", "uniform_sample": "_plane",
    "SegmentStage": "_stage", "segment_stage": "_stage",
    "ObjectSummary": "_summary",
    "TablePlane": "_table",
}

__all__ = [
    "segment", "SegmentParams", "SegmentResult", "ObjectSummary", "TablePlane", "MaskViews",
    "CLEANUP_STEPS", "fit_plane", "PlaneFit", "uniform_sample", "read_cloud", "read_unsure", "write_segments",
    "read_calibration",
    "segment_stage", "SegmentStage",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
