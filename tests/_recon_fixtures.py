"""Fixtures for the reconstruction tests: a tiny textured table-top scene rendered by ray casting, and
exporter files (DUSt3R / MASt3R / VGGT / Ray Diffusion layouts, docs/reconstruction.md) built from a known
ground truth, with the convention traps a real export has (camera-to-world vs world-to-camera, shuffled
image order, resized / cropped / padded model images).

The renderer is written out here (numpy, ~1 s for 8 small images) so the tests do not depend on the
synth stage: a textured table (plane z = 0 of frame w) with a few textured boxes, seen by two arms' wrist
cameras from opposite sides of the table.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bimanual_app.scene import ArmCapture, CameraIntrinsics, Scene, write_scene
from bimanual_app.transforms import inv_T, make_T

ARMS = ("primary", "secondary")


# ----------------------------------------------------------------------------------------------- textures
def _texture(rng: np.random.Generator, size: int = 512, blobs: int = 160) -> np.ndarray:
    """(size, size, 3) uint8: multi-scale noise plus random blobs and bars (plenty of SIFT features)."""
    img = np.zeros((size, size, 3), np.float32)
    for cells, amp in ((4, 0.35), (16, 0.25), (64, 0.15)):
        noise = rng.random((cells, cells, 3)).astype(np.float32)
        img += amp * cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
    img = np.clip(img / 0.75, 0, 1)
    img = (img * 255).astype(np.uint8)
    for _ in range(blobs):
        c = tuple(int(v) for v in rng.integers(0, 256, 3))
        x, y = (int(v) for v in rng.integers(0, size, 2))
        if rng.random() < 0.6:
            cv2.circle(img, (x, y), int(rng.integers(3, 14)), c, -1)
        else:
            w, h = (int(v) for v in rng.integers(4, 24, 2))
            cv2.rectangle(img, (x, y), (x + w, y + h), c, -1)
    return img


def _sample(tex: np.ndarray, a: np.ndarray, b: np.ndarray, extent: float) -> np.ndarray:
    """Bilinear texture lookup at metric coordinates (a, b) (any shape), texture tiling every ``extent`` m."""
    S = tex.shape[0]
    u = (np.mod(a / extent, 1.0) * (S - 1)).astype(np.float32)
    v = (np.mod(b / extent, 1.0) * (S - 1)).astype(np.float32)
    n = u.size
    pad = (-n) % 256  # cv2.remap wants maps smaller than 32767 on each side
    u = np.concatenate([u.ravel(), np.zeros(pad, np.float32)]).reshape(-1, 256)
    v = np.concatenate([v.ravel(), np.zeros(pad, np.float32)]).reshape(-1, 256)
    out = cv2.remap(tex, u, v, cv2.INTER_LINEAR).reshape(-1, 3)[:n]
    return out.reshape(*a.shape, 3)


# ----------------------------------------------------------------------------------------------- geometry
def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_w_c (4, 4) of an OpenCV camera at ``eye`` looking at ``target`` (z forward, y down)."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=1), np.asarray(eye, float))


def ray_cast(T_w_c: np.ndarray, K: np.ndarray, width: int, height: int, boxes: list[dict],
             table_tex: np.ndarray, table_extent: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """Render one view. Returns (colour (H, W, 3) uint8, points (H, W, 3) float64 in w, NaN where no hit)."""
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    pix = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3)
    d = (pix @ np.linalg.inv(K).T) @ T_w_c[:3, :3].T
    o = T_w_c[:3, 3]
    n = len(d)
    t_best = np.full(n, np.inf)
    color = np.zeros((n, 3), np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_tab = -o[2] / d[:, 2]
    hit = (t_tab > 0) & np.isfinite(t_tab)
    t_best[hit] = t_tab[hit]
    p = o + d * t_tab[:, None]
    color[hit] = _sample(table_tex, p[hit, 0], p[hit, 1], table_extent)
    for box in boxes:
        lo, hi = box["lo"], box["hi"]
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (lo - o) / d
            t2 = (hi - o) / d
        tmin_ax = np.minimum(t1, t2)
        tmax = np.nanmin(np.maximum(t1, t2), axis=1)
        tmin = np.nanmax(tmin_ax, axis=1)
        axis = np.nanargmax(tmin_ax, axis=1)
        hb = (tmax >= tmin) & (tmin > 1e-6) & (tmin < t_best)
        if not hb.any():
            continue
        t_best[hb] = tmin[hb]
        p = o + d[hb] * tmin[hb, None]
        ax = axis[hb]
        c = np.empty((len(p), 3), np.float32)
        for a, (i, j), shade in ((0, (1, 2), 0.75), (1, (0, 2), 0.85), (2, (0, 1), 1.0)):
            m = ax == a
            if m.any():
                c[m] = shade * _sample(box["tex"], p[m, i], p[m, j], 0.12)
        color[hb] = c
    pts = o + d * t_best[:, None]
    pts[~np.isfinite(t_best)] = np.nan
    return color.reshape(height, width, 3).clip(0, 255).astype(np.uint8), pts.reshape(height, width, 3)


def make_world(seed: int = 0) -> dict:
    """Table texture and 3 textured boxes (frame w = table frame, z up, metres)."""
    rng = np.random.default_rng(seed)
    boxes = []
    for cx, cy, sx, sy, h in ((-0.08, 0.05, 0.06, 0.05, 0.06), (0.07, -0.04, 0.05, 0.08, 0.04),
                              (0.02, 0.10, 0.04, 0.04, 0.08)):
        boxes.append({"lo": np.array([cx - sx / 2, cy - sy / 2, 0.0]), "hi": np.array([cx + sx / 2, cy + sy / 2, h]),
                      "tex": _texture(rng, 256)})
    return {"table_tex": _texture(rng, 1024, blobs=1500), "boxes": boxes}


def camera_poses(views_per_arm: int, seed: int = 0) -> dict[str, np.ndarray]:
    """T_w_c (N, 4, 4) per arm: primary cameras on the -x side of the table, secondary on the +x side."""
    rng = np.random.default_rng(seed + 1)
    out = {}
    for arm, az0 in zip(ARMS, (np.pi, 0.0)):
        Ts = []
        for k in range(views_per_arm):
            az = az0 + np.deg2rad(-50 + 100 * k / max(views_per_arm - 1, 1)) + rng.normal(0, 0.05)
            r, h = 0.30 + 0.04 * rng.random(), 0.34 + 0.06 * rng.random()
            eye = np.array([r * np.cos(az), r * np.sin(az), h])
            target = np.array([0.0, 0.0, 0.02]) + rng.normal(0, 0.02, 3) * [1, 1, 0]
            Ts.append(look_at(eye, target))
        out[arm] = np.array(Ts)
    return out


def render_scene(out_dir: Path, views_per_arm: int = 4, width: int = 320, height: int = 240, seed: int = 0,
                 intrinsics_in_yaml: bool = True, supersample: int = 2) -> dict:
    """Write a contract scene folder (scene.yaml, ee_poses.csv, images); return its ground truth.

    Returns a dict: ``T_w_c`` {arm: (N, 4, 4)}, ``K`` (3, 3), ``T_e_c`` {arm: (4, 4)}, ``T_b_w`` {arm: (4, 4)},
    ``points`` {arm: (N, H, W, 3)} true surface points in w, ``world`` (make_world output).
    """
    out_dir = Path(out_dir)
    world = make_world(seed)
    f = 0.9 * width
    intr = CameraIntrinsics(width, height, f, f, (width - 1) / 2, (height - 1) / 2)
    big = intr.scaled(width * supersample, height * supersample)
    poses = camera_poses(views_per_arm, seed)
    rng = np.random.default_rng(seed + 2)
    gt = {"T_w_c": poses, "K": intr.K, "T_e_c": {}, "T_b_w": {}, "points": {}, "world": world}
    arms = []
    for i, arm in enumerate(ARMS):
        T_e_c = make_T(cv2.Rodrigues(rng.normal(0, 0.3, 3))[0], rng.normal(0, 0.05, 3))
        T_b_w = make_T(cv2.Rodrigues(np.array([0, 0, rng.normal(0, 0.5)]))[0], np.array([0.3 - 0.6 * i, 0.0, -0.05]))
        keys, pts = [], []
        (out_dir / arm / "images").mkdir(parents=True, exist_ok=True)
        for k, T_w_c in enumerate(poses[arm]):
            img, _ = ray_cast(T_w_c, big.K, big.width, big.height, world["boxes"], world["table_tex"])
            img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
            _, p = ray_cast(T_w_c, intr.K, width, height, world["boxes"], world["table_tex"])
            key = f"images/{k:03d}.png"
            cv2.imwrite(str(out_dir / arm / key), img[:, :, ::-1])
            keys.append(key)
            pts.append(p)
        T_b_e = np.array([T_b_w @ T @ inv_T(T_e_c) for T in poses[arm]])
        arms.append(ArmCapture(arm, keys, T_b_e))
        gt["T_e_c"][arm], gt["T_b_w"][arm], gt["points"][arm] = T_e_c, T_b_w, np.array(pts)
    scene = Scene(path=out_dir, name="recon_fixture", primary=arms[0], secondary=arms[1],
                  camera=intr if intrinsics_in_yaml else None)
    write_scene(scene, out_dir)
    return gt


# ------------------------------------------------------------------------------------------ exporter files
TOOLS = Path(__file__).resolve().parents[1] / "tools"


def load_tool(name: str):
    """Import ``tools/<name>.py`` (the exporters run outside this package, so they are not importable by name)."""
    import importlib.util
    import sys

    if str(TOOLS) not in sys.path:
        sys.path.insert(0, str(TOOLS))
    spec = importlib.util.spec_from_file_location(f"_bijcr_tool_{name}", TOOLS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def similarity(seed: int = 5) -> np.ndarray:
    """A (4, 4) similarity ``S`` (scale * R | t): the model's world frame is ``x_model = S x_gt``."""
    rng = np.random.default_rng(seed)
    S = make_T(cv2.Rodrigues(rng.normal(0, 1.0, 3))[0], rng.normal(0, 2.0, 3))
    S[:3, :3] *= 3.7
    return S


def sim_pose(S: np.ndarray, T_w_c: np.ndarray) -> np.ndarray:
    """Camera-to-world pose (4, 4) in the frame ``S`` maps to (rotation part of S, centre moved by S)."""
    s = np.cbrt(np.linalg.det(S[:3, :3]))
    return make_T(S[:3, :3] / s @ T_w_c[:3, :3], S[:3, :3] @ T_w_c[:3, 3] + S[:3, 3])


def model_outputs(scene_dir: Path, gt: dict, boxes: list, model_sizes: list, S: np.ndarray, order: list[int]):
    """What a model would output for the scene's images in ``order`` (indices into primary+secondary).

    Returns (names, orig_sizes, T_model_c (N, 4, 4) camera-to-world in the model frame, K_model (N, 3, 3),
    pts3d list of (Hm, Wm, 3) in the model frame (NaN-free; no-hit pixels at 0 with conf 0), conf list).
    """
    from bimanual_app.reconstruction._pointmap import intrinsics_in_box

    allnames = [f"{a}/images/{k:03d}.png" for a in ARMS for k in range(len(gt["T_w_c"][a]))]
    allT = np.concatenate([gt["T_w_c"][a] for a in ARMS])
    K0 = gt["K"]
    W0, H0 = int(round(2 * (K0[0, 2] + 0.5))), int(round(2 * (K0[1, 2] + 0.5)))
    names, Ts, Ks, pts, confs = [], [], [], [], []
    for j, i in enumerate(order):
        Wm, Hm = model_sizes[j]
        Km = intrinsics_in_box(K0, np.asarray(boxes[j]), (Wm, Hm))
        _, P = ray_cast(allT[i], Km, Wm, Hm, gt["world"]["boxes"], gt["world"]["table_tex"])
        hit = np.all(np.isfinite(P), -1)
        Pm = np.where(hit[..., None], P @ S[:3, :3].T + S[:3, 3], 0.0)
        names.append(allnames[i])
        Ts.append(sim_pose(S, allT[i]))
        Ks.append(Km)
        pts.append(Pm.astype(np.float32))
        confs.append(np.where(hit, 1.0 + 4.0 * np.random.default_rng(i).random(hit.shape), 0.0).astype(np.float32))
    return names, [(W0, H0)] * len(order), np.array(Ts), np.array(Ks), pts, confs


def write_model_export(out: Path, model: str, scene_dir: Path, gt: dict, S: np.ndarray, order: list[int],
                       vggt_mode: str = "crop", dust3r_size: int = 224) -> Path:
    """Build an export file of ``model`` with the exporter's own ``pack`` from emulated model outputs."""
    common = load_tool("export_common")
    K0 = gt["K"]
    W0, H0 = int(round(2 * (K0[0, 2] + 0.5))), int(round(2 * (K0[1, 2] + 0.5)))
    n = len(order)
    if model in ("dust3r", "mast3r"):
        size = dust3r_size if model == "dust3r" else 512
        box, msize = common.dust3r_crop_box(W0, H0, size)
        names, sizes, T, K, pts, conf = model_outputs(scene_dir, gt, [box] * n, [msize] * n, S, order)
        if model == "mast3r":  # MASt3R's get_dense_pts3d returns flattened (H*W, 3) maps
            pts = [p.reshape(-1, 3) for p in pts]
        tool = load_tool("export_dust3r")
        packed = tool.pack(model, names, sizes, size, T, pts, conf, focals=K[:, 0, 0], pps=K[:, :2, 2])
    elif model == "vggt":
        tool = load_tool("export_vggt")
        boxes, msizes = tool.crop_boxes([(W0, H0)] * n, vggt_mode)
        names, sizes, T, K, pts, conf = model_outputs(scene_dir, gt, boxes, msizes, S, order)
        extrinsic = np.array([inv_T(t)[:3, :] for t in T])  # VGGT: world-to-camera 3x4
        packed = tool.pack(names, sizes, vggt_mode, extrinsic, K, np.array(pts), np.array(conf))
    elif model == "raydiffusion":
        tool = load_tool("export_raydiffusion")
        names, sizes, T, K, _, _ = model_outputs(scene_dir, gt, [[0, 0, W0, H0]] * n, [(8, 6)] * n, S, order)
        F = np.diag([-1.0, -1.0, 1.0])
        T_c_w = inv_T(T)
        R_p3d = np.array([(F @ t[:3, :3]).T for t in T_c_w])   # X_view = X_world @ R + T, view x left / y up
        t_p3d = np.array([F @ t[:3, 3] for t in T_c_w])
        packed = tool.pack(names, sizes, R_p3d, t_p3d)
    else:
        raise ValueError(model)
    return common.write_packed(out, packed)


def expected_T_w_c(gt: dict, S: np.ndarray, arm: str, key: str) -> np.ndarray:
    """The camera-to-world pose an importer should produce for one image (model frame ``S``)."""
    return sim_pose(S, gt["T_w_c"][arm][int(Path(key).stem)])


def expected_points(gt: dict, S: np.ndarray, arm: str, key: str, map_size: tuple[int, int]) -> np.ndarray:
    """True points (H, W, 3) in the model frame at the contract's reduced grid of one image (NaN: no hit)."""
    K0 = gt["K"]
    W0, H0 = int(round(2 * (K0[0, 2] + 0.5))), int(round(2 * (K0[1, 2] + 0.5)))
    Km = CameraIntrinsics(W0, H0, K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2]).scaled(*map_size).K
    _, P = ray_cast(gt["T_w_c"][arm][int(Path(key).stem)], Km, map_size[0], map_size[1],
                    gt["world"]["boxes"], gt["world"]["table_tex"])
    return P @ S[:3, :3].T + S[:3, 3]
