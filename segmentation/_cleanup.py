"""The clean-up after the contraction: a list of named steps, run in order on the voxels' region ids.

The contraction (``_graph``) joins patches by the convexity of their junctions. What it cannot tell from
junctions alone is cleaned up afterwards by these steps (each module's docstring gives its reasons):

- ``attach_parts`` (``_parts``, on the region graph): tiny regions and parts that cannot stand alone (a
  handle, a mug's inside) join their object; its rule ``bunny_ears`` joins thin parts held up beside an
  object's top, its rule ``resting_parts`` a part that rests on the region under it across a gap in the cloud,
  its rule ``cut_tops`` a piece of a top that a printed band cut off, its rule ``held_parts`` a part with
  more voxels than the region on the table that holds it up;
- ``dissolve_slivers`` (``_parts``): regions narrower than 1.5 cm (valleys between objects) go to a neighbour;
- ``split_by_tops`` (``_tops``): a region holding two flat tops at different heights is split; its rule
  ``level_tops`` (``_bump``) cuts a top that bulges out of a level neighbour's;
- ``shed_walls`` (``_walls``): a small box gives back the piece of a neighbour's wall it took;
- ``carton_neighbours`` (``_cartons``): object-sized pieces outside a carton's top rectangle become regions.

``SegmentParams.skip`` leaves named steps (or rules) out, so that each one's effect can be measured on
clouds it was not tuned on (``bench/segmentation_steps.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ._cartons import split_carton_neighbours
from ._params import SegmentParams
from ._parts import dissolve_slivers
from ._tops import split_by_tops
from ._walls import shed_neighbour_walls

__all__ = ["CLEANUP_STEPS", "Voxels", "clean_up_regions"]

#: every step and rule ``SegmentParams.skip`` may name, in the order they run
CLEANUP_STEPS = ("attach_parts", "bunny_ears", "resting_parts", "cut_tops", "held_parts", "dissolve_slivers",
                 "split_by_tops", "level_tops", "shed_walls", "carton_neighbours")

SLIVER_WIDTH = 0.015  # m: regions narrower than this in x-y are valleys between objects, not objects


@dataclass(frozen=True)
class Voxels:
    """The graph's voxels in the table frame: ``xyz`` (V, 3) (z = height), ``normals`` (V, 3) (sign free),
    ``edges`` (E, 2) neighbour pairs, and ``min_top`` (m): the lowest top an object region may have."""

    xyz: np.ndarray
    normals: np.ndarray
    edges: np.ndarray
    min_top: float


def _slivers(region: np.ndarray, v: Voxels, p: SegmentParams) -> tuple[np.ndarray, int]:
    out = dissolve_slivers(region, v.xyz, SLIVER_WIDTH, p.min_object_voxels)
    return out, int(np.count_nonzero(out != region))


def _tops(region: np.ndarray, v: Voxels, p: SegmentParams) -> tuple[np.ndarray, int]:
    return split_by_tops(region, v.xyz, v.normals, v.edges, p)


def _walls(region: np.ndarray, v: Voxels, p: SegmentParams) -> tuple[np.ndarray, int]:
    return shed_neighbour_walls(region, v.xyz, v.normals, v.edges, p, v.min_top)


def _cartons(region: np.ndarray, v: Voxels, p: SegmentParams) -> tuple[np.ndarray, int]:
    return split_carton_neighbours(region, v.xyz, v.normals, v.edges, p)


#: (step name, the stats key it reports under, the step): region ids (V,) -> (new ids, count of what it did)
REGION_STEPS: tuple[tuple[str, str, Callable], ...] = (
    ("dissolve_slivers", "slivers_dissolved", _slivers),
    ("split_by_tops", "split_by_tops", _tops),
    ("shed_walls", "walls_shed", _walls),
    ("carton_neighbours", "carton_neighbours", _cartons),
)


def clean_up_regions(region: np.ndarray, v: Voxels, p: SegmentParams, stats: dict) -> np.ndarray:
    """Run the region steps not in ``p.skip`` on ``region`` (V,) region ids; each step's count goes into
    ``stats`` under its key (0 when skipped). Returns the new (V,) ids."""
    for name, key, step in REGION_STEPS:
        if name in p.skip:
            stats[key] = 0
            continue
        region, n = step(region, v, p)
        stats[key] = int(n)
    return region
