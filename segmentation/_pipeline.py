"""``segment()``: metric cloud in b1 -> table + one label per object, per input point."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from bimanual_app.io_utils import InputError, Problem

from ._cleanup import Voxels, clean_up_regions
from ._graph import RegionGraph, pair_geometry
from ._orient import orient_patches
from ._params import SegmentParams
from ._parts import attach_parts
from ._patches import make_patches, patch_adjacency
from ._summary import ObjectSummary, summarize
from ._table import TablePlane, check_metric, fit_table, on_table_mask
from ._voxels import knn_edges, median_spacing, normals_and_curvature, voxelize

DEFAULT_VOXEL = 0.005
MIN_POINTS = 200
BASE_FRINGE = 0.035  # regions within base_radius + this of a base are the base's plate, not objects


@dataclass
class SegmentResult:
    """Output of :func:`segment`.

    Attributes:
        labels: (N,) int32 per input point, input order: -1 table/background, 0..K-1 objects.
        table: the table plane.
        objects: K summaries (id = label).
        voxel: the graph's voxel size (m).
        stats: counts of the stages (points, candidates, voxels, patches, graph edges, merges).
        timings: seconds per stage.
    """

    labels: np.ndarray
    table: TablePlane
    objects: list[ObjectSummary]
    voxel: float
    stats: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


def _log(progress, msg: str) -> None:
    if progress:
        print(f"[segment] {msg}", file=sys.stderr, flush=True)


def _check_inputs(points, colors, normals, mask_ids, source: str):
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(Problem(source, "points", f"expected an (N, 3) array of x, y, z, got shape {pts.shape}",
                                 "give one x, y, z row per point"))
    if len(pts) == 0:
        raise InputError(Problem(source, "points", "the cloud is empty",
                                 "give a non-empty metric cloud in b1 (e.g. scene_b1.ply from bijcr calibrate)"))
    pts = pts.astype(np.float64, copy=False)
    bad = ~np.isfinite(pts).all(1)
    if bad.any():
        raise InputError(Problem(source, "points", f"{int(bad.sum())} of {len(pts)} points have NaN or infinite "
                                 f"coordinates (first at index {int(np.flatnonzero(bad)[0])})",
                                 "remove invalid points before segmenting (e.g. Open3D remove_non_finite_points) "
                                 "so that labels stay aligned with the points you keep"))
    if len(pts) < MIN_POINTS:
        raise InputError(Problem(source, "points", f"only {len(pts)} points: too few to find a table and objects",
                                 f"give at least {MIN_POINTS} points"))
    col = None
    if colors is not None:
        col = np.asarray(colors)
        if col.shape != pts.shape:
            raise InputError(Problem(source, "colors", f"expected ({len(pts)}, 3) colours, got {col.shape}",
                                     "one RGB colour per point, or none"))
        if col.dtype != np.uint8:
            c = col.astype(np.float64)
            if not np.isfinite(c).all():
                raise InputError(Problem(source, "colors", "colours contain NaN", "give finite RGB colours"))
            col = np.clip(np.round(c * 255.0 if c.max() <= 1.0 else c), 0, 255).astype(np.uint8)
    nrm = None
    if normals is not None:
        nrm = np.asarray(normals, dtype=np.float64)
        if nrm.shape != pts.shape or not np.isfinite(nrm).all():
            raise InputError(Problem(source, "normals", f"expected ({len(pts)}, 3) finite normals, got {nrm.shape}",
                                     "give one normal per point, or none"))
    if mask_ids is not None and not callable(getattr(mask_ids, "lookup", None)):
        m = np.asarray(mask_ids)
        if m.ndim == 1:
            m = m[:, None]
        if m.ndim != 2 or len(m) != len(pts) or not np.issubdtype(m.dtype, np.integer):
            raise InputError(Problem(source, "mask_ids", f"expected (N,) or (N, V) integer mask ids for N = {len(pts)}"
                                     f" points, got {m.shape} {m.dtype}", "-1 = unknown, 0 = background, k > 0 = instance"))
        mask_ids = m
    return pts, col, nrm, mask_ids


def _voxel_masks(mask_pts: np.ndarray, inverse: np.ndarray, V: int) -> np.ndarray:
    """(V, views) majority mask id per voxel from per-point ids (M, views); -1 where no point knows."""
    out = np.full((V, mask_pts.shape[1]), -1, np.int64)
    for v in range(mask_pts.shape[1]):
        ids = mask_pts[:, v]
        known = ids >= 0
        if not known.any():
            continue
        u, comp = np.unique(ids[known], return_inverse=True)
        L = len(u)
        cnt = np.bincount(inverse[known] * L + comp.reshape(-1), minlength=V * L).reshape(V, L)
        has = cnt.sum(1) > 0
        out[has, v] = u[cnt[has].argmax(1)]
    return out


def _patch_mask_hist(mask_vox: np.ndarray, of_voxel: np.ndarray, P: int) -> np.ndarray:
    """(P, views, L) voxel counts of each (compacted) mask id per patch and view."""
    views = mask_vox.shape[1]
    comps, Ls = [], []
    for v in range(views):
        ids = mask_vox[:, v]
        u, comp = np.unique(ids, return_inverse=True)
        comp = comp.reshape(-1)
        if len(u) and u[0] < 0:  # unknown -> -1
            comp = comp - 1
        comps.append(comp)
        Ls.append(max(1, int((u >= 0).sum())))
    L = max(Ls)
    H = np.zeros((P, views, L))
    for v, comp in enumerate(comps):
        k = comp >= 0
        H[:, v, :] = np.bincount(of_voxel[k] * L + comp[k], minlength=P * L).reshape(P, L)
    return H


def _footprint_lengths(region: np.ndarray, xyz: np.ndarray, R: int) -> np.ndarray:
    """(R,) longer side (m) of each region's minimum-area rectangle in x-y (OpenCV ``minAreaRect``)."""
    import cv2

    out = np.zeros(R)
    order = np.argsort(region, kind="stable")
    bounds = np.flatnonzero(np.diff(region[order])) + 1
    for g in np.split(order, bounds):
        if len(g) >= 3:
            out[region[g[0]]] = max(cv2.minAreaRect(xyz[g, :2].astype(np.float32))[1])
    return out


def _base_axes(table: TablePlane, bases) -> np.ndarray:
    """(B, 3) the robot bases in the table frame; empty when none are given."""
    if bases is None or not len(bases):
        return np.zeros((0, 3))
    return table.to_table(np.asarray(bases, dtype=np.float64).reshape(-1, 3))


def _candidates(pt: np.ndarray, table: TablePlane, p: SegmentParams, bases) -> np.ndarray:
    """Indices of the points (N, 3, table frame) above the table band, over the table and off the bases."""
    h = pt[:, 2]
    cand = (h > table.min_height) & (h < p.max_height)
    cand &= on_table_mask(table, pt, p.table_margin)
    if p.base_radius > 0:
        for b in _base_axes(table, bases):
            cand &= np.hypot(pt[:, 0] - b[0], pt[:, 1] - b[1]) > p.base_radius
    return np.flatnonzero(cand)


def _auto_voxelize(cpts: np.ndarray, ccol, p: SegmentParams):
    """Voxelize the candidates; without a fixed ``p.voxel``, grow the voxel until the graph is small enough
    (surfaces: about 1/v^2 voxels). Returns ``(vox, voxel)``."""
    voxel = p.voxel or DEFAULT_VOXEL
    vox = voxelize(cpts, voxel, ccol)
    for _ in range(6):
        if p.voxel is not None or len(vox) <= p.max_voxels:
            break
        voxel *= float(np.sqrt(len(vox) / p.max_voxels)) * 1.05
        vox = voxelize(cpts, voxel, ccol)
    return vox, voxel


def _given_normals(vn: np.ndarray, nrm: np.ndarray, cidx: np.ndarray, vox, table: TablePlane) -> None:
    """Replace the voxels' estimated normals (V, 3) by the mean of the given point normals (where nonzero)."""
    R_t = table.T_b1_t[:3, :3]
    nv_sum = np.stack([np.bincount(vox.inverse, nrm[cidx] @ R_t[:, k], len(vox)) for k in range(3)], 1)
    ok = np.linalg.norm(nv_sum, axis=1) > 1e-9
    vn[ok] = nv_sum[ok] / np.linalg.norm(nv_sum[ok], axis=1, keepdims=True)


def _mask_voxels(mask_ids, cidx: np.ndarray, vox, table: TablePlane):
    """(V, views) mask id per voxel from per-point ids or a ``lookup`` object; None without masks."""
    if mask_ids is None:
        return None
    if isinstance(mask_ids, np.ndarray):
        return _voxel_masks(mask_ids[cidx], vox.inverse, len(vox))
    xyz_b1 = vox.xyz @ table.T_b1_t[:3, :3].T + table.T_b1_t[:3, 3]
    return np.asarray(mask_ids.lookup(xyz_b1), dtype=np.int64)


def _keep_regions(region: np.ndarray, xyz: np.ndarray, p: SegmentParams, table: TablePlane, bases,
                  min_top: float) -> np.ndarray:
    """(R,) which regions are objects: enough voxels, tall and long enough, not a base plate's remains."""
    R = int(region.max()) + 1
    nvox = np.bincount(region, minlength=R)
    top = np.zeros(R)
    np.maximum.at(top, region, xyz[:, 2])
    keep = (nvox >= p.min_object_voxels) & (top >= min_top)
    keep &= _footprint_lengths(region, xyz, R) >= p.min_object_size
    if p.base_radius > 0 and bases is not None and len(bases):
        # what is left of a base plate's corners: regions lying almost all near a base
        near = np.zeros(len(xyz), bool)
        for b in _base_axes(table, bases):
            near |= np.hypot(xyz[:, 0] - b[0], xyz[:, 1] - b[1]) < p.base_radius + BASE_FRINGE
        keep &= np.bincount(region, near.astype(float), R) < 0.8 * nvox
    return keep


def _object_ids(region: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(R,) label of each region: objects ordered by size (largest first, stable, readable ids), -1 dropped."""
    nvox = np.bincount(region, minlength=len(keep))
    kept = np.flatnonzero(keep)
    kept = kept[np.argsort(-nvox[kept], kind="stable")]
    remap = np.full(len(keep), -1, np.int32)
    remap[kept] = np.arange(len(kept), dtype=np.int32)
    return remap


def _regions(vox, vn, var, edges, mask_vox, table: TablePlane, p: SegmentParams, voxel: float, spacing: float,
             stats: dict, T: dict, _debug: dict | None) -> np.ndarray:
    """Voxels -> patches -> oriented normals -> contracted region graph -> (V,) region per voxel."""
    t2 = time.perf_counter()
    cell = p.patch_cell or max(4.0 * voxel, 3.0 * spacing)
    patches = make_patches(vox.xyz, vn, var, edges, cell, p.patch_normal_deg, vox.rgb,
                           colour_tol=p.voxel_colour_tol, mask_vox=mask_vox)
    pairs, weight = patch_adjacency(patches.of_voxel, edges)
    T["patches"] += time.perf_counter() - t2
    t3 = time.perf_counter()
    ray_cell = max(2.0 * voxel, 1.5 * spacing, 0.008)
    pn = orient_patches(patches.xyz, patches.normal, vox.xyz, ray_cell, pairs)
    patches.normal = pn
    T["orient"] = time.perf_counter() - t3
    t4 = time.perf_counter()
    score, flat = pair_geometry(patches.xyz, pn, pairs, p, step_min=max(1.5 * voxel, 4.0 * table.sigma))
    hist = None if mask_vox is None else _patch_mask_hist(mask_vox, patches.of_voxel, len(patches))
    G = RegionGraph(patches.nvox, patches.hist, hist, pairs, weight, score, flat, p)
    merges = G.contract(p.merge_threshold)
    if _debug is not None:  # intermediate results for development and tests
        _debug.update(vox=vox, patches=patches, pairs=pairs, weight=weight, score=score,
                      contracted=G.labels()[patches.of_voxel], graph=G)
    parts = 0 if "attach_parts" in p.skip else attach_parts(G, patches.of_voxel, vox.xyz, p, normals=vn)
    region = G.labels()[patches.of_voxel]  # (V,) region per voxel
    if _debug is not None:
        _debug["attached"] = region
    stats.update(patches=len(patches), patch_edges=int(len(pairs)), merges=merges, attached=parts)
    region = clean_up_regions(region, Voxels(vox.xyz, vn, edges, _min_top(table, p)), p, stats)
    T["graph"] = time.perf_counter() - t4
    return region


def _min_top(table: TablePlane, p: SegmentParams) -> float:
    """Least top height of an object: it rises clearly above the table band (noisy clouds hold sheets of table
    a little above it)."""
    return max(p.min_object_height, table.min_height + max(0.008, 2.5 * table.sigma))


def _with_unsure(points, colors, normals, mask_ids, p: SegmentParams, bases, source: str, progress: bool,
                 unsure) -> SegmentResult:
    """:func:`segment` of the sure points, the unsure ones (``unsure`` (N,) bool) then joined to the segments
    they connect to (:func:`_unsure.join_unsure`), summaries over all points."""
    from ._unsure import join_unsure

    pts = np.asarray(points, dtype=np.float64)
    unsure = np.asarray(unsure, dtype=bool)
    if unsure.shape != (len(pts),):
        raise InputError(Problem(source, "unsure", f"{unsure.shape} flags for {len(pts)} points",
                                 "give one flag per point (or none)"))
    sure = ~unsure

    def part(a):  # per-point arrays follow the sure points; a mask-view object answers for any point
        return a[sure] if isinstance(a, np.ndarray) and len(a) == len(pts) else a

    res = segment(pts[sure], part(colors), part(normals), part(mask_ids), p, bases, source, progress)
    labels = np.full(len(pts), -1, np.int32)
    labels[sure] = res.labels
    pt = res.table.to_table(pts)
    cand = np.zeros(len(pts), bool)
    cand[_candidates(pt, res.table, p, bases)] = True
    labels = join_unsure(pts, labels, unsure, np.where(cand, pt[:, 2], -1.0), res.table.min_height)
    stats = {**res.stats, "points": len(pts), "unsure_points": int(unsure.sum()),
             "unsure_joined": int((labels[unsure] >= 0).sum())}
    return SegmentResult(labels, res.table, summarize(pts, labels, res.table), res.voxel, stats, res.timings)


def segment(points, colors=None, normals=None, mask_ids=None, params: SegmentParams | None = None,
            bases=None, source: str = "points", progress: bool = False, _debug: dict | None = None,
            unsure=None) -> SegmentResult:
    """Segment a metric table-top cloud in b1 into the table and objects.

    Args:
        points: (N, 3) metres, frame b1.
        colors: (N, 3) uint8 (or floats in [0, 1]) or None.
        normals: (N, 3) or None: used instead of the normals estimated from the cloud (oriented here).
        mask_ids: per-image mask evidence, or None: an (N,) / (N, V) int array of mask ids per point and
            view (-1 unknown, 0 background, k > 0 an instance; ids need not agree between views), or an
            object with ``lookup(points_b1 (M, 3)) -> (M, V)`` (such as :class:`MaskViews`), which is
            asked only about the graph's voxels.
        params: tunables (defaults: :class:`SegmentParams`).
        bases: (B, 3) robot base positions in b1 (e.g. ``[0, 0, 0]`` and ``T_b1_b2[:3, 3]``): points within
            ``params.base_radius`` of their vertical axes are background (a base is not an object).
        source: the input's name for error messages (the file).
        progress: log stages to stderr.
        unsure: (N,) bool or None: points that may join a segment but never link two (the cloud's unsure points,
            ``read_unsure``): the graph runs on the others, and each of these takes the segment it connects to
            (``_unsure.join_unsure``).

    Returns:
        :class:`SegmentResult`. Raises :class:`InputError` for empty, non-finite, non-metric clouds and
        clouds without a table plane.
    """
    p = params or SegmentParams()
    if unsure is not None and np.any(unsure):
        return _with_unsure(points, colors, normals, mask_ids, p, bases, source, progress, unsure)
    T = {}
    t0 = time.perf_counter()
    pts, col, nrm, mask_ids = _check_inputs(points, colors, normals, mask_ids, source)
    check_metric(pts, source)
    table = fit_table(pts, p, source)
    T["table"] = time.perf_counter() - t0
    _log(progress, f"table: normal {np.round(table.normal, 3).tolist()}, {table.extent[0]:.2f} x {table.extent[1]:.2f} m, "
         f"noise {1000 * table.sigma:.1f} mm ({T['table']:.2f} s)")
    t1 = time.perf_counter()
    pt = table.to_table(pts)
    cidx = _candidates(pt, table, p, bases)
    labels = np.full(len(pts), -1, np.int32)
    stats = {"points": len(pts), "candidates": int(len(cidx))}
    if len(cidx) < 10:
        T["total"] = time.perf_counter() - t0
        return SegmentResult(labels, table, [], p.voxel or DEFAULT_VOXEL, stats, T)
    vox, voxel = _auto_voxelize(pt[cidx], None if col is None else col[cidx], p)
    spacing = median_spacing(vox.xyz)
    stats.update(voxels=len(vox), voxel=voxel, spacing=spacing)
    T["voxels"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    edges, _ = knn_edges(vox.xyz, 10, max(2.5 * voxel, 2.5 * spacing))
    vn, var = normals_and_curvature(vox.xyz, max(2.4 * voxel, 3.0 * spacing))
    if nrm is not None:
        _given_normals(vn, nrm, cidx, vox, table)
    mask_vox = _mask_voxels(mask_ids, cidx, vox, table)
    if _debug is not None:
        _debug["cidx"] = cidx
    T["patches"] = time.perf_counter() - t2  # the normals and masks count towards the patch stage
    region = _regions(vox, vn, var, edges, mask_vox, table, p, voxel, spacing, stats, T, _debug)
    t5 = time.perf_counter()
    labels[cidx] = _object_ids(region, _keep_regions(region, vox.xyz, p, table, bases, _min_top(table, p)))[region][
        vox.inverse]
    T["labels"] = time.perf_counter() - t5
    t6 = time.perf_counter()
    objects = summarize(pts, labels, table)
    T["summary"] = time.perf_counter() - t6
    T["total"] = time.perf_counter() - t0
    stats["objects"] = len(objects)
    _log(progress, f"{len(cidx)} points above the table -> {len(vox)} voxels ({1000 * voxel:.1f} mm) -> "
         f"{stats['patches']} patches -> {len(objects)} objects ({T['total']:.2f} s)")
    return SegmentResult(labels, table, objects, voxel, stats, T)
