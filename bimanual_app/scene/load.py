"""Read and validate a scene folder (docs/scene-format.md).

``validate_scene(path)`` returns every problem found (errors and warnings), each naming the file, the
row or key, and the fix; ``load_scene(path)`` returns a typed :class:`Scene` or raises
:class:`InputError` with all errors at once.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path, PurePosixPath

import numpy as np
import yaml

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import T_from_xyz_quat, check_shape, check_T

from .types import ARM_NAMES, ArmCapture, CameraIntrinsics, GroundTruth, Reconstruction, Scene

POSE_COLUMNS = ["x", "y", "z", "qx", "qy", "qz", "qw"]
SCENE_KEYS = {"format", "name", "robot", "ee_link", "camera"}
CAMERA_KEYS = ["width", "height", "fx", "fy", "cx", "cy"]
# Positions beyond this (metres) from the base are not a table-top arm: most likely millimetres.
MAX_REACH_M = 3.0
QUAT_TOL = 1e-3


class _Collector:
    def __init__(self, root: Path):
        self.root = root
        self.problems: list[Problem] = []

    def rel(self, path: Path) -> str:
        try:
            return str(path.relative_to(self.root.parent))
        except ValueError:
            return str(path)

    def error(self, path: Path, field: str, message: str, fix: str = "") -> None:
        self.problems.append(Problem(self.rel(path), field, message, fix, "error"))

    def warn(self, path: Path, field: str, message: str, fix: str = "") -> None:
        self.problems.append(Problem(self.rel(path), field, message, fix, "warning"))

    @property
    def errors(self) -> list[Problem]:
        return [p for p in self.problems if p.severity == "error"]


def _read_yaml(c: _Collector, path: Path, required: bool) -> dict | None:
    if not path.exists():
        if required:
            c.error(path, "", "file is missing", f"create {path.name} (see docs/scene-format.md)")
        return None
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        c.error(path, "", f"not valid YAML: {e}", "fix the YAML syntax")
        return None
    if not isinstance(data, dict):
        c.error(path, "", "must be a YAML mapping (key: value lines)", "see docs/scene-format.md")
        return None
    return data


def _parse_scene_yaml(c: _Collector, root: Path) -> dict | None:
    path = root / "scene.yaml"
    data = _read_yaml(c, path, required=True)
    if data is None:
        return None
    out: dict = {"extras": {}}
    fmt = data.get("format")
    if fmt != 1:
        c.error(path, "format", f"format must be 1, got {fmt!r}", "add the line 'format: 1'")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        c.error(path, "name", "name is missing or not a string", f"add 'name: {root.name}'")
        name = root.name
    out["name"] = name
    for key in ("robot", "ee_link"):
        v = data.get(key)
        if v is not None and not isinstance(v, str):
            c.error(path, key, f"{key} must be a string, got {v!r}", f"write e.g. '{key}: piper'" if key == "robot" else "")
            v = None
        out[key] = v
    cam = data.get("camera")
    out["camera"] = None
    if cam is not None:
        if not isinstance(cam, dict):
            c.error(path, "camera", "camera must be a mapping of width, height, fx, fy, cx, cy", "see docs/scene-format.md")
        else:
            vals = {}
            for k in CAMERA_KEYS:
                v = cam.get(k)
                if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v <= 0:
                    c.error(path, f"camera.{k}", f"must be a positive number (pixels), got {v!r}", f"set camera.{k}")
                else:
                    vals[k] = v
            if len(vals) == len(CAMERA_KEYS):
                out["camera"] = CameraIntrinsics(int(vals["width"]), int(vals["height"]), float(vals["fx"]),
                                                 float(vals["fy"]), float(vals["cx"]), float(vals["cy"]))
    for k, v in data.items():
        if k not in SCENE_KEYS:
            out["extras"][k] = v
            c.warn(path, k, f"unknown key '{k}' (kept, not used)", "check the spelling against docs/scene-format.md")
    return out


def _safe_key(key: str) -> bool:
    p = PurePosixPath(key)
    return bool(key) and not p.is_absolute() and ".." not in p.parts and "\\" not in key


def _read_csv_rows(c: _Collector, path: Path, arm: str) -> list[list[str]] | None:
    """The non-blank rows of an arm's ee_poses.csv, or None (with an error) when missing, unreadable or empty."""
    if not path.exists():
        c.error(path, "", "file is missing", f"write one row per image of the {arm} arm: image,x,y,z,qx,qy,qz,qw or image,j1..j6")
        return None
    try:
        with open(path, newline="") as f:
            rows = [r for r in csv.reader(f) if any(cell.strip() for cell in r)]
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        c.error(path, "", f"cannot be read as CSV: {e}", "save it as plain UTF-8 CSV")
        return None
    if not rows:
        c.error(path, "", "file is empty", "add a header row and one row per image")
        return None
    return rows


def _csv_columns(c: _Collector, path: Path, header: list[str]) -> tuple[str, list[str]] | None:
    """From the header: ("pose", POSE_COLUMNS) or ("joints", [j1..jN]), or None (with an error)."""
    if "image" not in header:
        c.error(path, "header", f"no 'image' column (header is {','.join(header)})",
                "the first row must name the columns: image,x,y,z,qx,qy,qz,qw or image,j1,...,j6")
        return None
    joint_cols = sorted([h for h in header if h.startswith("j") and h[1:].isdigit()], key=lambda h: int(h[1:]))
    has_pose = any(h in header for h in POSE_COLUMNS)
    if has_pose:
        missing = [h for h in POSE_COLUMNS if h not in header]
        if missing:
            c.error(path, "header", f"missing column(s) {', '.join(missing)}",
                    "a pose CSV needs all of image,x,y,z,qx,qy,qz,qw (quaternion by name)")
            return None
        return "pose", POSE_COLUMNS
    if joint_cols:
        expected = [f"j{i}" for i in range(1, len(joint_cols) + 1)]
        if joint_cols != expected:
            c.error(path, "header", f"joint columns {joint_cols} are not j1..jN in sequence", f"name them {','.join(expected)}")
            return None
        return "joints", joint_cols
    c.error(path, "header", f"neither pose columns nor joint columns (header is {','.join(header)})",
            "use image,x,y,z,qx,qy,qz,qw (T_b_e in metres) or image,j1,...,j6 (radians)")
    return None


def _row_values(c: _Collector, path: Path, field: str, row: list[str], idx: dict[str, int],
                cols: list[str]) -> list[float] | None:
    """The numeric cells of one data row in column order, or None (with an error) at the first bad cell."""
    vals = []
    for h in cols:
        cell = row[idx[h]].strip()
        try:
            v = float(cell)
        except ValueError:
            c.error(path, f"{field}, {h}", f"{cell!r} is not a number", "write a decimal number")
            return None
        if not math.isfinite(v):
            c.error(path, f"{field}, {h}", f"non-finite value {cell!r}", "replace it with the measured value or drop the row")
            return None
        vals.append(v)
    return vals


def _csv_data_rows(c: _Collector, path: Path, arm: str, rows: list[list[str]], header: list[str],
                   cols: list[str]) -> tuple[list[str], list[list[float]], dict[str, int]]:
    """Image keys, values and key -> row number of the valid data rows; every bad row is reported."""
    idx = {h: header.index(h) for h in ["image"] + cols}
    images: list[str] = []
    values: list[list[float]] = []
    seen: dict[str, int] = {}
    for r, row in enumerate(rows[1:], start=2):
        field = f"row {r}"
        if len(row) != len(header):
            c.error(path, field, f"has {len(row)} cells, header has {len(header)}", "give every row one value per column")
            continue
        key = row[idx["image"]].strip()
        if not _safe_key(key):
            c.error(path, f"{field}, image", f"image key {key!r} must be a relative path inside the {arm} folder",
                    "write it like images/000.png")
            continue
        if key in seen:
            c.error(path, f"{field}, image", f"duplicate image key {key!r} (also row {seen[key]})",
                    "give every row its own image")
            continue
        seen[key] = r
        vals = _row_values(c, path, field, row, idx, cols)
        if vals is not None:
            images.append(key)
            values.append(vals)
    return images, values, seen


def _pose_rows(c: _Collector, path: Path, arr: np.ndarray, images: list[str], seen: dict[str, int],
               n_bad: int) -> dict | None:
    """Pose rows (N, 7) -> T_b_e (N, 4, 4), after checking for millimetres and non-unit quaternions."""
    pos, q = arr[:, :3], arr[:, 3:]
    for i, (p, qq) in enumerate(zip(pos, q)):
        field = f"row {seen[images[i]]}"
        if np.linalg.norm(p) > MAX_REACH_M:
            c.error(path, f"{field}, x/y/z", f"position {p.tolist()} is {np.linalg.norm(p):.1f} from the base:"
                    " this looks like millimetres", "positions are metres: divide x, y, z by 1000")
        nq = np.linalg.norm(qq)
        if abs(nq - 1.0) > QUAT_TOL:
            c.error(path, f"{field}, qx..qw", f"quaternion is not unit (norm {nq:.4f})",
                    "normalise it (divide by its norm) and check the column order is qx,qy,qz,qw")
    if len(c.errors) > n_bad:
        return None
    T = T_from_xyz_quat(pos, q / np.linalg.norm(q, axis=1, keepdims=True))
    return {"mode": "pose", "images": images, "T_b_e": T, "joints": None, "path": path}


def _joint_rows(c: _Collector, path: Path, arr: np.ndarray, images: list[str], seen: dict[str, int],
                cols: list[str]) -> dict | None:
    """Joint rows (N, J) in radians, after checking for degrees."""
    big = np.abs(arr) > 2 * math.pi + 0.1
    if big.any():
        r, j = np.argwhere(big)[0]
        c.error(path, f"row {seen[images[r]]}, {cols[j]}", f"joint angle {arr[r, j]} is beyond 2*pi: this looks like degrees",
                "joint angles are radians: multiply degrees by pi/180")
        return None
    return {"mode": "joints", "images": images, "T_b_e": None, "joints": arr, "path": path}


def _parse_csv(c: _Collector, root: Path, arm: str) -> dict | None:
    """Parse ``<arm>/ee_poses.csv`` (pose or joint columns); None when it has errors (all reported to ``c``)."""
    path = root / arm / "ee_poses.csv"
    rows = _read_csv_rows(c, path, arm)
    if rows is None:
        return None
    header = [h.strip() for h in rows[0]]
    columns = _csv_columns(c, path, header)
    if columns is None:
        return None
    mode, cols = columns
    n_bad = len(c.errors)
    images, values, seen = _csv_data_rows(c, path, arm, rows, header, cols)
    if len(rows) == 1:
        c.error(path, "", "no data rows (header only)", "add one row per captured image")
    if len(c.errors) > n_bad:
        return None
    arr = np.array(values, dtype=np.float64).reshape(len(values), len(cols))
    if mode == "pose":
        return _pose_rows(c, path, arr, images, seen, n_bad)
    return _joint_rows(c, path, arr, images, seen, cols)


def _parse_reconstruction(c: _Collector, root: Path) -> Reconstruction | None:
    path = root / "reconstruction.npz"
    if not path.exists():
        return None
    try:
        npz = np.load(path, allow_pickle=False)
        data = {k: npz[k] for k in npz.files}
    except Exception as e:  # zip errors, pickled objects, truncated files
        c.error(path, "", f"cannot be read: {e}", "re-create it with 'bijcr reconstruct' (or your importer)")
        return None
    n_bad = len(c.errors)
    for k in ("arm", "image", "T_w_c", "model"):
        if k not in data:
            c.error(path, k, "required key is missing", "see the reconstruction.npz table in docs/scene-format.md")
    if len(c.errors) > n_bad:
        return None
    arm, image, T = data["arm"], data["image"], data["T_w_c"]
    if arm.ndim != 1 or not np.issubdtype(arm.dtype, np.integer):
        c.error(path, "arm", f"must be an (M,) int array, got {arm.dtype} {arm.shape}", "store 1 for primary, 2 for secondary")
        return None
    M = len(arm)
    if image.shape != (M,) or image.dtype.kind not in "US":
        c.error(path, "image", f"must be an (M,) string array matching 'arm' (M={M}), got {image.dtype} {image.shape}",
                "store the ee_poses.csv image keys as a numpy string array")
        return None
    if T.shape != (M, 4, 4):
        c.error(path, "T_w_c", f"must be (M, 4, 4) with M={M}, got {T.shape}", "store one camera-to-world 4x4 per image")
        return None
    bad = sorted(set(np.unique(arm).tolist()) - {1, 2})
    if bad:
        c.error(path, "arm", f"values {bad} are not 1 (primary) or 2 (secondary)", "use 1 and 2")
    T = T.astype(np.float64)
    for j in range(M):
        where = f"T_w_c[{j}] ({image[j]})"
        if not np.all(np.isfinite(T[j])):
            c.error(path, where, "non-finite values", "drop this image from the reconstruction")
            continue
        R = T[j, :3, :3]
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0 or not np.allclose(T[j, 3], [0, 0, 0, 1], atol=1e-6):
            c.error(path, where, "is not a rigid transform (rotation not orthonormal or bottom row not 0 0 0 1)",
                    "store camera-to-world poses with a proper rotation; a scale belongs in the translation")
    pairs = list(zip(arm.tolist(), [str(s) for s in image]))
    dup = {p for p in pairs if pairs.count(p) > 1}
    for a, key in sorted(dup):
        c.error(path, "image", f"image {key!r} of arm {a} appears more than once", "keep one entry per image")
    model = data["model"]
    if model.shape != () or model.dtype.kind not in "US":
        c.error(path, "model", "must be a scalar string", "store e.g. np.array('dust3r')")
    pts3d = data.get("pts3d")
    conf = data.get("conf")
    colors = data.get("colors")
    if pts3d is not None:
        if pts3d.ndim != 4 or pts3d.shape[0] != M or pts3d.shape[3] != 3:
            c.error(path, "pts3d", f"must be (M, H, W, 3) with M={M}, got {pts3d.shape}", "one point map per image")
            pts3d = None
        elif not np.all(np.isfinite(pts3d)):
            c.error(path, "pts3d", "contains non-finite points", "replace them by any finite value and give them conf 0")
    if conf is not None:
        if pts3d is None:
            c.error(path, "conf", "given without pts3d", "store pts3d too, or drop conf")
        elif conf.shape != pts3d.shape[:3]:
            c.error(path, "conf", f"must be (M, H, W) = {pts3d.shape[:3]}, got {conf.shape}", "one confidence per point")
        elif not np.all(np.isfinite(conf)):
            c.error(path, "conf", "contains non-finite values", "use 0 for unknown confidence")
    if colors is not None and (pts3d is None or colors.shape != pts3d.shape or colors.dtype != np.uint8):
        c.error(path, "colors", f"must be uint8 (M, H, W, 3) like pts3d, got {colors.dtype} {colors.shape}",
                "store the RGB colour of each point-map pixel, or drop the key")
    if len(c.errors) > n_bad:
        return None
    extras = {k: v for k, v in data.items() if k not in {"arm", "image", "T_w_c", "model", "pts3d", "conf", "colors"}}
    return Reconstruction(arm=arm.astype(np.int64), image=np.array([str(s) for s in image]), T_w_c=T,
                          pts3d=None if pts3d is None else pts3d.astype(np.float32, copy=False),
                          conf=None if conf is None else conf.astype(np.float32, copy=False),
                          model=str(model), colors=colors, extras=extras)


def _parse_T(c: _Collector, path: Path, key: str, v) -> np.ndarray | None:
    """The 4x4 transform written under ``key``, or None after recording why it is not one (the shared
    ``check_T``: a 4x4 of finite numbers, a proper rotation, a bottom row 0 0 0 1)."""
    try:
        return check_T(key, check_shape(key, np.array(v, dtype=np.float64), (4, 4)))
    except (TypeError, ValueError) as e:
        reason = str(e).removeprefix(f"{key}: ")
        c.error(path, key, f"is not a rigid transform ({reason})",
                "write [[r00, r01, r02, tx], ..., [0, 0, 0, 1]] with a proper rotation")
        return None


def _parse_ground_truth(c: _Collector, root: Path) -> GroundTruth | None:
    path = root / "ground_truth.yaml"
    data = _read_yaml(c, path, required=False)
    if data is None:
        return None
    Ts = {}
    for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2"):
        if key not in data:
            c.error(path, key, "required key is missing", "give the true 4x4 transform")
            continue
        Ts[key] = _parse_T(c, path, key, data[key])
    scale = data.get("scale")
    if scale is not None and (not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0):
        c.error(path, "scale", f"must be a positive number, got {scale!r}", "metric = scale * reconstruction units")
        scale = None
    objects = data.get("objects") or []
    parsed_objects = []
    if not isinstance(objects, list):
        c.error(path, "objects", "must be a list", "one mapping per object")
        objects = []
    for i, o in enumerate(objects):
        if not isinstance(o, dict) or "id" not in o:
            c.error(path, f"objects[{i}]", "each object needs at least an 'id'", "")
            continue
        o = dict(o)
        if "T_b1_o" in o:
            o["T_b1_o"] = _parse_T(c, path, f"objects[{i}].T_b1_o", o["T_b1_o"])
        if "size" in o:
            o["size"] = np.asarray(o["size"], dtype=np.float64)
        parsed_objects.append(o)
    if any(v is None for v in Ts.values()) or len(Ts) < 3:
        return None
    extras = {k: v for k, v in data.items() if k not in {"T_e1_c1", "T_e2_c2", "T_b1_b2", "scale", "objects"}}
    return GroundTruth(Ts["T_e1_c1"], Ts["T_e2_c2"], Ts["T_b1_b2"], None if scale is None else float(scale),
                       parsed_objects, extras)


def _joints_to_poses(c: _Collector, root: Path, info: dict, robot: str | None, ee_link: str | None) -> np.ndarray | None:
    path = info["path"]
    if robot is None:
        c.error(root / "scene.yaml", "robot", f"{path.parent.name}/ee_poses.csv gives joint angles, so the robot model is needed",
                "add 'robot: piper' (or a URDF path) to scene.yaml, or give poses x,y,z,qx,qy,qz,qw")
        return None
    from bimanual_app.robots import load_robot

    try:
        model = load_robot(robot, base_dir=root, ee_link=ee_link)
    except (FileNotFoundError, ValueError, KeyError) as e:
        c.error(root / "scene.yaml", "robot", str(e), "name a known robot (bijcr check --robots lists them) or a URDF path")
        return None
    q = info["joints"]
    if q.shape[1] != model.nq_arm:
        c.error(path, "header", f"{q.shape[1]} joint columns but robot '{robot}' has {model.nq_arm} arm joints",
                f"give j1..j{model.nq_arm}")
        return None
    lo, hi = model.lower[: model.nq_arm], model.upper[: model.nq_arm]
    for r in range(len(q)):
        out = (q[r] < lo - 1e-3) | (q[r] > hi + 1e-3)
        if out.any():
            j = int(np.argmax(out))
            c.warn(path, f"row {r + 2}, j{j + 1}", f"{q[r, j]:.4f} rad is outside the model's limits [{lo[j]:.3f}, {hi[j]:.3f}]",
                   "check the joint zero offsets and sign conventions of your driver")
    return model.fk(q)


def validate_scene(path: str | Path) -> tuple[Scene | None, list[Problem]]:
    """Validate a scene folder.

    Returns ``(scene, problems)``: the scene is None when there is any error; ``problems`` lists
    errors and warnings, each naming the file, the row or key, and the fix.
    """
    root = Path(path).expanduser().resolve()
    c = _Collector(root)
    if not root.is_dir():
        c.error(root, "", "is not a folder", "point at the scene folder that holds scene.yaml")
        return None, c.problems
    meta = _parse_scene_yaml(c, root)
    arms_raw = {arm: _parse_csv(c, root, arm) for arm in ARM_NAMES}
    rec = _parse_reconstruction(c, root)
    gt = _parse_ground_truth(c, root)
    arms: dict[str, ArmCapture] = {}
    for arm, info in arms_raw.items():
        if info is None:
            continue
        T = info["T_b_e"]
        if info["mode"] == "joints":
            if meta is None:
                continue
            T = _joints_to_poses(c, root, info, meta["robot"], meta["ee_link"])
            if T is None:
                continue
        arms[arm] = ArmCapture(arm, info["images"], T, info["joints"])
    # images: required unless a reconstruction caches them
    for arm in arms.values():
        missing = [k for k in arm.images if not (root / arm.name / k).is_file()]
        if missing and rec is None:
            csv_path = root / arm.name / "ee_poses.csv"
            shown = ", ".join(missing[:5]) + (f" (+{len(missing) - 5} more)" if len(missing) > 5 else "")
            c.error(csv_path, "image", f"{len(missing)} row(s) have no image file: {shown}",
                    f"put the images under {arm.name}/ or add reconstruction.npz (bijcr reconstruct needs the images)")
    if meta is None or len(arms) < 2:
        return None, c.problems
    if rec is not None:
        rec_path = root / "reconstruction.npz"
        for a, key in zip(rec.arm.tolist(), rec.image.tolist()):
            name = ARM_NAMES[a - 1] if a in (1, 2) else None
            if name is not None and key not in set(arms[name].images):
                c.error(rec_path, "image", f"image {key!r} of arm {a} ({name}) matches no row of {name}/ee_poses.csv",
                        "re-run the reconstruction on this scene's images, or fix the keys to match ee_poses.csv")
        for arm in arms.values():
            n = int(np.sum(rec.arm == arm.index))
            if n == 0:
                c.warn(rec_path, "arm", f"no image of the {arm.name} arm is in the reconstruction",
                       "calibration needs at least 3 registered views per arm: re-run the reconstruction")
            elif n < len(arm):
                c.warn(rec_path, "image", f"{len(arm) - n} of {len(arm)} {arm.name} images are not registered",
                       "fine if a few; calibration uses the rest")
    if c.errors:
        return None, c.problems
    scene = Scene(path=root, name=meta["name"], primary=arms["primary"], secondary=arms["secondary"],
                  robot=meta["robot"], ee_link=meta["ee_link"], camera=meta["camera"], reconstruction=rec,
                  ground_truth=gt, extras=meta["extras"])
    return scene, c.problems


def load_scene(path: str | Path) -> Scene:
    """Load and validate a scene folder; raises :class:`InputError` listing every error."""
    scene, problems = validate_scene(path)
    if scene is None:
        raise InputError([p for p in problems if p.severity == "error"])
    return scene


def load_reconstruction(path: str | Path) -> Reconstruction:
    """Load and validate one reconstruction.npz on its own (no pose rows to match)."""
    path = Path(path)
    c = _Collector(path.parent)
    if not path.exists():
        raise InputError(Problem(str(path), "", "file is missing", "run 'bijcr reconstruct SCENE' to make it"))
    rec = _parse_reconstruction(c, path.parent) if path.name == "reconstruction.npz" else None
    if path.name != "reconstruction.npz":
        raise InputError(Problem(str(path), "", "expected a file named reconstruction.npz", "rename it"))
    if rec is None:
        raise InputError(c.errors)
    return rec
