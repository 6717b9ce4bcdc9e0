"""Parameters of the segmenter, with the reasons for their defaults (all lengths in metres)."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace


@dataclass(frozen=True)
class SegmentParams:
    """Tunables of :func:`segmentation.segment`. The defaults suit table-top scenes in metres.

    Table:
        plane_threshold: RANSAC inlier distance. 8 mm: above the point noise of foundation-model clouds
            (a few mm), well below the height of any graspable object.
        plane_sample: points handed to RANSAC (a random subset: the plane does not need all 2M points).
        min_height: points at most this high above the table are table. ``None``: from the plane's own
            residuals (3.5 sigma, at least 3 mm, at most 12 mm).
        max_height: points higher than this are background (arms, people, shelves).
        table_margin: points further than this outside the table's outline are background.
        base_radius: points within this horizontal distance of a robot base given to ``segment`` are
            background (the Piper's base is 5.5 cm in radius; a base plate reaches a little further).

    Graph:
        voxel: voxel edge of the graph's nodes. ``None``: 5 mm (enough to resolve gaps of a centimetre),
            grown when the objects would need more than ``max_voxels`` voxels (speed bound).
        patch_cell: patches never cross a cell of this size (``None``: 4 voxels, >= 2.5 point spacings),
            so every patch is small and local, and its normal meaningful.
        patch_normal_deg: neighbouring voxels join a patch when their normals differ by less than this.
        smooth_deg: two patches whose normals differ by less than this meet smoothly (neither convex
            nor concave), unless one steps above the other.
        concave_deg: the normal change over which a concave junction goes from "tolerated" (noise) to
            "certainly two objects" (LCCP's concavity tolerance is 10 degrees; the ramp starts there).
        voxel_colour_tol: neighbouring voxels whose chromaticities differ by more than this start
            different patches.
        colour_tol, colour_span: colour distance of two regions (1 - intersection of their chromaticity
            histograms, see ``_patches.colour_histograms``) below which they look alike, and the span
            over which the colour penalty then ramps to 1.
        colour_weight, mask_weight: how much colour and mask disagreement weigh against geometry
            (geometry is in [-1, 1]).
        merge_threshold: contraction stops when no edge has at least this affinity.
        min_object_voxels, min_object_height, min_object_size: smaller segments are dropped (noise,
            table texture, stray pixels): fewer voxels, lower top, shorter footprint (longer side); a
            segment must also rise 2.5 table-noise sigmas (at least 8 mm) above the table band.

    Clean-up after the contraction:
        skip: names of clean-up steps to leave out (``segmentation.CLEANUP_STEPS``: ``attach_parts``,
            ``bunny_ears``, ``resting_parts``, ``cut_tops`` and ``held_parts`` (rules of attach_parts),
            ``dissolve_slivers``,
            ``split_by_tops``, ``level_tops`` (the ``_bump`` rule of split_by_tops), ``shed_walls``,
            ``carton_neighbours``); every step runs by default. For measuring what each step does
            (``bench/segmentation_steps.py``), not for users.
    """

    plane_threshold: float = 0.008
    plane_sample: int = 120_000
    min_height: float | None = None
    max_height: float = 0.45
    table_margin: float = 0.04
    base_radius: float = 0.095

    voxel: float | None = None
    max_voxels: int = 60_000
    patch_cell: float | None = None
    patch_normal_deg: float = 20.0
    smooth_deg: float = 12.0
    concave_deg: float = 15.0
    voxel_colour_tol: float = 0.08
    colour_tol: float = 0.3
    colour_span: float = 0.25
    colour_weight: float = 1.2
    mask_weight: float = 1.5
    merge_threshold: float = 0.15
    min_object_voxels: int = 25
    min_object_height: float = 0.012
    min_object_size: float = 0.02
    skip: tuple[str, ...] = ()

    def with_(self, **kw) -> SegmentParams:
        """A copy with some fields changed (unknown names raise ``TypeError``)."""
        names = {f.name for f in fields(self)}
        bad = set(kw) - names
        if bad:
            raise TypeError(f"unknown segmentation parameter(s): {sorted(bad)}")
        return replace(self, **kw)

    def __post_init__(self):
        from ._cleanup import CLEANUP_STEPS

        unknown = sorted(set(self.skip) - set(CLEANUP_STEPS))
        if unknown:
            raise ValueError(f"SegmentParams.skip: unknown clean-up step(s) {unknown}; known: {list(CLEANUP_STEPS)}")
