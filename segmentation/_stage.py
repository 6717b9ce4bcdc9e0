"""The segmentation stage as one library call: a metric cloud file in, segments.npz / .json / .png out.

``bijcr segment``, ``bijcr run`` and ``bijcr task`` (when it produces missing segments) all call
:func:`segment_stage`; it raises InputError for bad input instead of printing it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem, check_output_dir

from ._io import read_cloud, read_unsure, write_segments
from ._masks import MaskViews, read_calibration
from ._params import SegmentParams
from ._pipeline import segment

__all__ = ["SegmentStage", "segment_stage"]


@dataclass
class SegmentStage:
    """What :func:`segment_stage` made: the result, the cloud's points (N, 3), the files and mask views."""

    result: object
    points: np.ndarray
    cloud: Path
    paths: dict = field(default_factory=dict)
    mask_views: int = 0


def segment_stage(cloud: str | Path, out: str | Path, calibration: str | Path | None = None,
                  masks: str | Path | None = None, params: SegmentParams | None = None, keep_bases: bool = False,
                  plot: bool = True, progress: bool = False) -> SegmentStage:
    """Segment the metric cloud in b1 at ``cloud`` and write the segments into ``out``.

    ``calibration``: calibration.json (default: the one beside the cloud, when there is one): the
    secondary base (background, not an object) and, with ``masks`` (a scene folder), how the scene's
    per-image masks map into b1. ``keep_bases``: do not treat the robot bases as background. The output
    folder is checked first. Raises InputError naming the file, field and fix.
    """
    out = check_output_dir(out)
    cloud = Path(cloud)
    points, colors, normals = read_cloud(cloud)
    unsure = read_unsure(cloud, len(points))  # bijcr calibrate's unsure points: they join segments, never link two
    calib_path = Path(calibration) if calibration else cloud.parent / "calibration.json"
    calib = read_calibration(calib_path) if (calibration or calib_path.is_file()) else None
    bases = None
    if not keep_bases:
        bases = [np.zeros(3)]
        if calib is not None and calib[2] is not None:
            bases.append(calib[2][:3, 3])
    views = None
    if masks:
        if calib is None:
            raise InputError(Problem(str(calib_path), "", "--masks needs the calibration that maps the scene's point "
                                     "maps into b1", "give --calibration DIR/calibration.json (from bijcr calibrate)"))
        views = MaskViews.from_scene(masks, calib[0], calib[1])
    result = segment(points, colors, normals, mask_ids=views, params=params or SegmentParams(), bases=bases,
                     source=str(cloud), progress=progress, unsure=unsure)
    paths = write_segments(out, result, points, source=str(cloud), plot=plot)
    return SegmentStage(result, points, cloud, paths, 0 if views is None else len(views))
