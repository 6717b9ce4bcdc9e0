"""Reading clouds and writing segments.npz / segments.json / segments.png (atomic writes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem, atomic_path, write_json

from ._pipeline import SegmentResult

FORMAT = 1
CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzrgb", ".pts", ".npz")


def read_cloud(path: str | Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """``(points (N, 3) float64, colors (N, 3) uint8 or None, normals (N, 3) or None)`` from a cloud file.

    PLY / PCD / XYZ go through Open3D (non-finite points are kept so that they can be reported, not
    silently dropped); ``.npz`` needs a ``points`` array (and may hold ``colors``). Raises InputError
    naming the file when it is missing, unreadable or empty.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(Problem(str(path), "", "file not found", "give the path of a point cloud (e.g. "
                                 "scene_b1.ply written by bijcr calibrate)"))
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise InputError(Problem(str(path), "", f"unknown point-cloud format '{suffix}'",
                                 f"give one of {', '.join(CLOUD_SUFFIXES)}"))
    if suffix == ".npz":
        try:
            with np.load(path) as z:
                if "points" not in z:
                    raise InputError(Problem(str(path), "points", "no 'points' array",
                                             "store the (N, 3) points under the key 'points'"))
                pts = np.asarray(z["points"], dtype=np.float64)
                col = np.asarray(z["colors"]) if "colors" in z else None
        except InputError:
            raise
        except Exception as e:  # a corrupt archive
            raise InputError(Problem(str(path), "", f"cannot read ({e})", "give a valid .npz")) from None
        return pts, col, None
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    pts = np.asarray(pc.points, dtype=np.float64)
    if len(pts) == 0:
        raise InputError(Problem(str(path), "points", "no points in the file (empty, or not a readable "
                                 f"{suffix[1:].upper()} point cloud)",
                                 "give a non-empty metric cloud in b1 (e.g. scene_b1.ply from bijcr calibrate)"))
    col = None
    if pc.has_colors():
        c = np.asarray(pc.colors)
        col = np.clip(np.round(np.nan_to_num(c) * 255.0), 0, 255).astype(np.uint8)
    nrm = np.asarray(pc.normals, dtype=np.float64) if pc.has_normals() else None
    return pts, col, nrm


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4", "uint": "<u4",
              "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1", "int16": "<i2", "uint16": "<u2",
              "int32": "<i4", "uint32": "<u4", "float32": "<f4", "float64": "<f8"}


def read_unsure(path: str | Path, n: int | None = None) -> np.ndarray | None:
    """(N,) bool: the points of a binary little-endian PLY that its ``unsure`` vertex property marks (written
    by ``bijcr calibrate``: points their own map marked unsure that other views confirmed); None for other
    files, or when the property is missing or the file has not ``n`` vertices.

    Read with numpy from the header and the vertex block: :func:`read_cloud`'s Open3D reader (the legacy
    ``read_point_cloud``) drops properties it does not know; Open3D's tensor reader keeps them and could
    replace this (it would also read ASCII files, which this returns None for)."""
    path = Path(path)
    if path.suffix.lower() != ".ply":
        return None
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            return None
        fields, count, binary = [], None, False
        for raw in iter(f.readline, b""):
            words = raw.decode("ascii", "replace").split()
            if words[:1] == ["end_header"]:
                break
            if words[:2] == ["format", "binary_little_endian"]:
                binary = True
            elif words[:2] == ["element", "vertex"]:
                count = int(words[2])
            elif words[:1] == ["element"] and count is not None:
                return None  # other elements after the vertices: not a plain cloud
            elif words[:1] == ["property"] and len(words) == 3 and words[1] in _PLY_TYPES:
                fields.append((words[2], _PLY_TYPES[words[1]]))
            elif words[:1] == ["property"]:
                return None  # a list property: not a plain cloud
        if not binary or count is None or "unsure" not in dict(fields) or (n is not None and count != n):
            return None
        rec = np.frombuffer(f.read(count * np.dtype(fields).itemsize), dtype=fields, count=count)
    return rec["unsure"].astype(bool)


def summary_dict(result: SegmentResult, source: str = "") -> dict:
    """The JSON-able summary of a segmentation (what segments.json holds)."""
    t = result.table
    return {
        "format": FORMAT,
        "source": source,
        "points": int(len(result.labels)),
        "objects": [o.as_dict() for o in result.objects],
        "table": {"plane": t.coefficients.tolist(), "T_b1_table": t.T_b1_t.tolist(),
                  "extent_m": t.extent.tolist(), "noise_m": t.sigma, "min_height_m": t.min_height},
        "voxel_m": result.voxel,
        "stats": result.stats,
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
    }


def write_segments(out_dir: str | Path, result: SegmentResult, points: np.ndarray, source: str = "",
                   plot: bool = True) -> dict[str, Path]:
    """Write ``segments.png``, ``segments.json`` and, last, ``segments.npz`` into ``out_dir``.

    Each file is written to a temporary name and renamed when complete; the labels file comes last, so
    its presence means the whole output is there. Returns the paths written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    K = len(result.objects)
    if plot:
        from ._plot import plot_segments

        paths["png"] = out / "segments.png"
        plot_segments(paths["png"], points, result.labels, result.objects,
                      title=f"{Path(source).name or 'cloud'}: {K} objects, {len(points)} points")
    paths["json"] = out / "segments.json"
    write_json(paths["json"], summary_dict(result, source))
    paths["npz"] = out / "segments.npz"
    t = result.table
    arrays = dict(
        labels=result.labels.astype(np.int32),
        object_ids=np.arange(K, dtype=np.int32),
        point_counts=np.array([o.points for o in result.objects], dtype=np.int64).reshape(K),
        centroids=np.array([o.centroid for o in result.objects], dtype=np.float64).reshape(K, 3),
        obb_centers=np.array([o.center for o in result.objects], dtype=np.float64).reshape(K, 3),
        obb_rotations=np.array([o.rotation for o in result.objects], dtype=np.float64).reshape(K, 3, 3),
        obb_extents=np.array([o.extents for o in result.objects], dtype=np.float64).reshape(K, 3),
        table_plane=t.coefficients.astype(np.float64),
        T_b1_table=t.T_b1_t.astype(np.float64),
        voxel=np.float64(result.voxel),
        format=np.int64(FORMAT),
    )
    with atomic_path(paths["npz"]) as tmp:
        np.savez_compressed(tmp, **arrays)
    return paths


def format_table(result: SegmentResult) -> str:
    """The per-object summary as an aligned text table."""
    rows = [("id", "points", "centroid x y z (m)", "box l x w x h (cm)", "yaw (deg)")]
    for o in result.objects:
        yaw = np.degrees(np.arctan2(o.rotation[1, 0], o.rotation[0, 0]))
        rows.append((str(o.id), str(o.points), " ".join(f"{v:+.3f}" for v in o.centroid),
                     " x ".join(f"{100 * v:.1f}" for v in o.extents), f"{yaw:+.0f}"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
