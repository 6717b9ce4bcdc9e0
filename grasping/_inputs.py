"""Reading what grasp planning needs: the metric cloud in b1, its segments and (optionally) the calibration.

Everything is checked here, at the edge: a segments file whose labels do not match the cloud, labels that
are not integers >= -1, a cloud with non-finite points, a calibration without a valid ``T_b1_b2`` -- each
raises InputError naming the file, the field and the fix.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import check_T

__all__ = ["SceneCloud", "load_cloud", "load_segments", "load_calibration", "b2b_sigma", "resolve_inputs", "scene_cloud"]


@dataclass
class SceneCloud:
    """The segmented metric scene in frame b1.

    Attributes:
        points: (N, 3) float64 points in b1 (metres).
        labels: (N,) int32, -1 table/background, 0..K-1 objects.
        colors: (N, 3) uint8 or None.
        table_plane: (4,) plane (a, b, c, d), unit normal pointing up, from the segments file, or None.
        source: names of the files it came from (for messages and grasps.json).
        views: the capture's depth views in b1 (views.npz beside the cloud) or None: where the cameras saw
            through (``_unseen.carved_unseen``).
    """

    points: np.ndarray
    labels: np.ndarray
    colors: np.ndarray | None = None
    table_plane: np.ndarray | None = None
    source: dict = field(default_factory=dict)
    views: object | None = None  # bimanual_app.views.DepthViews

    @property
    def object_ids(self) -> list[int]:
        """Sorted ids of the labelled objects (labels >= 0 present in the cloud)."""
        return sorted(int(k) for k in np.unique(self.labels) if k >= 0)


def scene_cloud(points: np.ndarray, labels: np.ndarray, colors: np.ndarray | None = None,
                table_plane: np.ndarray | None = None, source: dict | None = None,
                points_name: str = "cloud", labels_name: str = "segments") -> SceneCloud:
    """Check and bundle arrays into a :class:`SceneCloud` (raises InputError naming the problem)."""
    P = np.asarray(points)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(Problem(points_name, "points", f"expected (N, 3) points, got shape {P.shape}", "give an x y z cloud"))
    P = P.astype(np.float64)
    if len(P) == 0:
        raise InputError(Problem(points_name, "points", "the cloud has no points", "run `bijcr calibrate` on a scene with point maps"))
    L = np.asarray(labels)
    problems = []
    if L.ndim != 1:
        problems.append(Problem(labels_name, "labels", f"expected a (N,) array, got shape {L.shape}", "write one label per point"))
    elif len(L) != len(P):
        problems.append(Problem(labels_name, "labels",
                                f"{len(L)} labels for a cloud of {len(P)} points: the segments file does not belong to this cloud",
                                f"re-run `bijcr segment {points_name} --out DIR` on this cloud"))
    elif L.size and not np.issubdtype(L.dtype, np.integer):
        if not (np.issubdtype(L.dtype, np.floating) and np.all(np.isfinite(L)) and np.all(L == np.round(L))):
            problems.append(Problem(labels_name, "labels", f"labels must be integers, got dtype {L.dtype}",
                                    "write int32 labels (-1 table/background, 0..K-1 objects)"))
    if not problems and L.size and L.min() < -1:
        problems.append(Problem(labels_name, "labels", f"label {int(L.min())} < -1", "use -1 for the table and background, 0..K-1 for objects"))
    finite = np.all(np.isfinite(P), axis=1)
    if not finite.all():
        problems.append(Problem(points_name, "points", f"{int((~finite).sum())} points are not finite (NaN or inf)",
                                "drop them before writing the cloud, and re-run the segmentation on it"))
    if problems:
        raise InputError(problems)
    L = L.astype(np.int32)
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != P.shape:
            colors = None
        elif colors.dtype != np.uint8:
            c = colors.astype(np.float64)
            colors = np.clip(c * (255.0 if c.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    plane = None
    if table_plane is not None:
        tp = np.asarray(table_plane, dtype=np.float64).reshape(-1)
        if tp.shape == (4,) and np.all(np.isfinite(tp)) and np.linalg.norm(tp[:3]) > 1e-9:
            plane = tp / np.linalg.norm(tp[:3])
    return SceneCloud(P, L, colors, plane, dict(source or {}))


def load_cloud(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(points (N, 3) float64, colors (N, 3) uint8 or None) of a cloud file, read by the project's one cloud
    reader (:func:`segmentation.read_cloud`: PLY / PCD / XYZ / NPZ; raises InputError naming the file)."""
    from segmentation import read_cloud

    P, C, _ = read_cloud(path)
    return P, C


def load_segments(path: str | Path) -> tuple[np.ndarray, dict]:
    """(labels (N,), extra keys) of a segments.npz (contract: ``labels`` (N,) int32)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(Problem(str(path), "", "segments file not found", "run `bijcr segment CLOUD.ply --out DIR` first"))
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as e:  # zip / format errors of several kinds
        raise InputError(Problem(str(path), "", f"cannot read as .npz: {e}", "re-run `bijcr segment`")) from None
    if "labels" not in data:
        raise InputError(Problem(str(path), "labels", f"missing key 'labels' (keys: {', '.join(sorted(data)) or 'none'})",
                                 "write the segments with `bijcr segment` (labels (N,) int32)"))
    labels = data.pop("labels")
    return labels, data


def load_calibration(path: str | Path) -> dict:
    """calibration.json as a dict with ``T_b1_b2`` checked (raises InputError)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(Problem(str(path), "", "calibration file not found", "run `bijcr calibrate SCENE --out DIR`"))
    try:
        cal = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(Problem(str(path), "", f"not valid JSON: {e}", "re-run `bijcr calibrate`")) from None
    if not isinstance(cal, dict) or "T_b1_b2" not in cal:
        raise InputError(Problem(str(path), "T_b1_b2", "missing", "give the calibration.json written by `bijcr calibrate`"))
    try:
        cal["T_b1_b2"] = check_T("T_b1_b2", np.asarray(cal["T_b1_b2"], dtype=np.float64))
    except (ValueError, TypeError) as e:
        raise InputError(Problem(str(path), "T_b1_b2", str(e), "re-run `bijcr calibrate`")) from None
    return cal


def resolve_inputs(scene_or_cloud: str | Path, calibration: str | Path | None = None) -> tuple[Path, Path | None]:
    """(cloud path, calibration path or None) for a cloud file or a folder holding ``scene_b1.ply``.

    A folder is searched for ``scene_b1.ply`` and then ``calibration/scene_b1.ply`` (the layout of
    ``bijcr run``); the calibration defaults to ``calibration.json`` beside the cloud when present.
    """
    p = Path(scene_or_cloud)
    if p.is_dir():
        for cand in (p / "scene_b1.ply", p / "calibration" / "scene_b1.ply"):
            if cand.is_file():
                p = cand
                break
        else:
            raise InputError(Problem(str(p), "", "no scene_b1.ply in this folder (nor in calibration/)",
                                     "run `bijcr calibrate SCENE --out DIR` and pass DIR or DIR/scene_b1.ply"))
    elif not p.is_file():
        raise InputError(Problem(str(p), "", "no such file or folder", "pass scene_b1.ply or the folder holding it"))
    cal = Path(calibration) if calibration is not None else None
    if cal is None and (p.parent / "calibration.json").is_file():
        cal = p.parent / "calibration.json"
    return p, cal


def b2b_sigma(cal: dict) -> tuple[float, float] | None:
    """(translation m, rotation rad): the per-axis RMS of the 1-sigma uncertainty of ``T_b1_b2`` that
    ``bijcr calibrate`` writes (``uncertainty.T_b1_b2.translation_mm`` and ``rotation_axes_deg``); None
    when the calibration has none (e.g. written by another tool) or it is not finite."""
    u = (cal.get("uncertainty") or {}).get("T_b1_b2") if isinstance(cal.get("uncertainty"), dict) else None
    if not isinstance(u, dict):
        return None
    try:
        t = np.asarray(u["translation_mm"], dtype=np.float64).reshape(3) * 1e-3
        r = np.deg2rad(np.asarray(u["rotation_axes_deg"], dtype=np.float64).reshape(3))
    except (KeyError, TypeError, ValueError):
        return None
    st, sr = float(np.sqrt(np.mean(t ** 2))), float(np.sqrt(np.mean(r ** 2)))
    return (st, sr) if np.isfinite(st) and np.isfinite(sr) else None
