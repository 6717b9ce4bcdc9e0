"""Each static layer of the run in a viser scene: cloud and segment labels, capture cameras, frames, the
uncertainty of T_b1_b2, and gripper meshes. Every layer hangs under one root node (``/cloud``,
``/cameras``, ...), so hiding the root hides the layer.
"""

from __future__ import annotations

import numpy as np

from ._types import Cloud, GripperPose, RunLayers

__all__ = ["TABLE_GREY", "segment_colors", "wxyz_xyz", "draw_cloud", "draw_cameras", "draw_frames",
           "draw_sigma", "gripper_mesh", "draw_gripper"]

TABLE_GREY = (170, 170, 170)
MAX_POINTS = 300_000  # per cloud sent to the browser; beyond that a uniform subsample
IMAGE_WIDTH = 320  # frustum images are sent at this width


def wxyz_xyz(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(quaternion w, x, y, z (4,), position (3,)) of a (4, 4) transform, as viser's nodes take them."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return np.array([w, x, y, z]), np.asarray(T[:3, 3], dtype=np.float64)


def segment_colors(labels: np.ndarray) -> np.ndarray:
    """(N, 3) uint8: the table and background grey, object k the k-th colour of matplotlib's tab10 (as in
    segments.png and grasps.png)."""
    from matplotlib import colormaps

    tab = (np.asarray(colormaps["tab10"].colors) * 255).astype(np.uint8)
    out = np.empty((len(labels), 3), dtype=np.uint8)
    out[:] = TABLE_GREY
    obj = labels >= 0
    out[obj] = tab[labels[obj] % len(tab)]
    return out


def _subsample(n: int, cap: int) -> np.ndarray:
    return np.arange(n) if n <= cap else np.sort(np.random.default_rng(0).choice(n, cap, replace=False))


def draw_cloud(server, cloud: Cloud, point_size: float = 0.004) -> dict:
    """The cloud split by segment under ``/cloud`` (``table`` and ``object_<k>`` nodes) and a label above
    each object under ``/labels``. Returns {"table" | k: point-cloud handle}, and the true-colour arrays
    keyed the same under ``"_rgb"`` for the colour switch."""
    sel = _subsample(len(cloud.points), MAX_POINTS)
    P = cloud.points[sel].astype(np.float32)
    L = cloud.labels[sel] if cloud.labels is not None else np.full(len(P), -1, np.int32)
    seg = segment_colors(L)
    rgb = cloud.colors[sel] if cloud.colors is not None else seg
    if cloud.labels is None:
        seg = rgb
    handles, true_colors = {}, {}
    for key in ["table"] + sorted(int(k) for k in np.unique(L) if k >= 0):
        m = L < 0 if key == "table" else L == key
        if not m.any():
            continue
        name = "/cloud/table" if key == "table" else f"/cloud/object_{key}"
        handles[key] = server.scene.add_point_cloud(name, P[m], seg[m], point_size=point_size, precision="float32",
                                                    point_shape="circle")
        true_colors[key] = (seg[m], rgb[m])
        if key != "table":
            top = P[m].mean(axis=0)
            top[2] = P[m][:, 2].max() + 0.03
            server.scene.add_label(f"/labels/object_{key}", f"{key}", position=top, anchor="bottom-center",
                                   font_screen_scale=1.2)
    handles["_rgb"] = true_colors
    return handles


def _thumbnail(path) -> np.ndarray | None:
    from PIL import Image

    try:
        with Image.open(path) as im:
            im = im.convert("RGB")
            h = max(1, round(im.height * IMAGE_WIDTH / im.width))
            return np.asarray(im.resize((IMAGE_WIDTH, h)))
    except OSError:
        return None  # an unreadable image leaves the frustum empty; the calibration does not need it


def draw_cameras(server, layers: RunLayers, scale: float = 0.04) -> None:
    """Every capture view as a frustum (with its image) and its e and c frames, under ``/cameras``."""
    colors = {"primary": (30, 90, 200), "secondary": (200, 90, 30)}
    for k, v in enumerate(layers.cameras):
        q, t = wxyz_xyz(v.T_b1_c)
        m = 1 if v.arm == "primary" else 2
        image = _thumbnail(v.image_path) if v.image_path is not None else None
        name = f"/cameras/c{m}_{k:03d}"
        server.scene.add_camera_frustum(name, fov=v.fov_y, aspect=v.aspect, scale=scale, color=colors[v.arm],
                                        image=image, format="jpeg", jpeg_quality=80, wxyz=q, position=t,
                                        thickness=0.002)
        server.scene.add_frame(f"{name}/axes", axes_length=0.02, axes_radius=0.001)
        qe, te = wxyz_xyz(v.T_b1_e)
        server.scene.add_frame(f"/cameras/e{m}_{k:03d}", axes_length=0.02, axes_radius=0.001, wxyz=qe, position=te)


def draw_frames(server, layers: RunLayers) -> dict:
    """Axes of b1, b2 and (moved by the replay) e1, e2, c1, c2 with labels, under ``/frames``; returns the
    movable frames' handles {"e1", "c1", "e2", "c2"}."""
    out = {}
    for name, T in (("b1", np.eye(4)), ("b2", layers.T_b1_b2)):
        q, t = wxyz_xyz(T)
        server.scene.add_frame(f"/frames/{name}", axes_length=0.12, axes_radius=0.004, wxyz=q, position=t)
        server.scene.add_label(f"/frames/{name}/label", name, position=(0.0, 0.0, -0.02), anchor="top-center")
    for m in (1, 2):
        for f in ("e", "c"):
            h = server.scene.add_frame(f"/frames/{f}{m}", axes_length=0.06, axes_radius=0.0025)
            server.scene.add_label(f"/frames/{f}{m}/label", f"{f}{m}", position=(0.0, 0.0, 0.0), anchor="bottom-left",
                                   font_screen_scale=0.8)
            out[f"{f}{m}"] = h
    return out


def draw_sigma(server, layers: RunLayers) -> None:
    """The 1-sigma ellipsoid of T_b1_b2's translation (axes along b1's, semi-axes the per-axis sigmas) at
    the secondary base, under ``/sigma``."""
    s = np.maximum(layers.sigma_b1_b2_m, 1e-5)
    server.scene.add_icosphere("/sigma/b2_translation", radius=1.0, color=(220, 40, 160), scale=tuple(s),
                               position=layers.T_b1_b2[:3, 3], opacity=0.6, subdivisions=3)
    mm = ", ".join(f"{1000 * x:.1f}" for x in layers.sigma_b1_b2_m)
    server.scene.add_label("/sigma/label", f"1σ T_b1_b2: ({mm}) mm", anchor="bottom-left",
                           position=layers.T_b1_b2[:3, 3] + [0.0, 0.0, 0.04], font_screen_scale=0.8)


def gripper_mesh(gripper, T_b1_g: np.ndarray, width: float):
    """A trimesh of the gripper's palm and finger boxes (``grasping.load_gripper``'s shapes, so the
    URDF's own sizes) at opening ``width`` (m), placed at ``T_b1_g``."""
    import trimesh

    boxes = []
    for s in gripper.shapes:
        lo, hi = s.aabb_local
        T = T_b1_g @ s.T_g_s(width)
        C = np.eye(4)
        C[:3, 3] = (lo + hi) / 2
        boxes.append(trimesh.creation.box(extents=hi - lo, transform=T @ C))
    return trimesh.util.concatenate(boxes)


def draw_gripper(server, name: str, gripper, g: GripperPose, color, opacity: float | None = None):
    """One gripper mesh node and its caption (shown on hover as the node's name)."""
    m = gripper_mesh(gripper, g.T_b1_g, g.width)
    return server.scene.add_mesh_simple(name, m.vertices.astype(np.float32), m.faces.astype(np.uint32),
                                        color=color, opacity=opacity, flat_shading=True)
