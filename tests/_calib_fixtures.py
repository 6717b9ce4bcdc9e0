"""Small synthetic bimanual captures for the calibration tests and benchmark (numpy only, fast).

``make_capture(seed, views, noise, outliers)`` returns a :class:`Capture` holding the inputs of the
solver (``T_b1_e``, ``T_w_c1``, ``T_b2_e``, ``T_w_c2``), the ground truth (hand-eye transforms, scale,
``T_b1_w``, ``T_b2_w``, ``T_b1_b2``) and, on request, tiny point maps in frame ``w`` whose metric
positions in ``b1`` are known (for the cloud test). ``write_capture_scene`` writes it as a contract
scene folder with :func:`bimanual_app.scene.write_scene`.

The geometry mimics the paper's set-up: two table-top arms facing a shared workspace, a camera on each
wrist a few centimetres off the flange, views on a cap around the workspace looking at it with varied
roll, so relative rotations are about several axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bimanual_app.transforms import inv_T, make_T

# RMS camera rotation error (deg), RMS camera-centre error (mm), RMS robot rotation (deg) / position (mm) error;
# the camera levels are those of bimanual_app.synth's emulator
NOISE_LEVELS = {
    "none": (0.0, 0.0, 0.0, 0.0),
    "low": (0.5, 3.0, 0.01, 0.1),
    "paper": (1.5, 10.0, 0.02, 0.2),
    "harsh": (3.0, 25.0, 0.05, 0.5),
}


@dataclass
class Capture:
    T_b1_e: np.ndarray
    T_w_c1: np.ndarray
    T_b2_e: np.ndarray
    T_w_c2: np.ndarray
    T_e1_c1: np.ndarray
    T_e2_c2: np.ndarray
    T_b1_w: np.ndarray
    T_b2_w: np.ndarray
    T_b1_b2: np.ndarray
    scale: float
    outliers1: list[int] = field(default_factory=list)
    outliers2: list[int] = field(default_factory=list)
    pts3d: np.ndarray | None = None      # (M, H, W, 3) in w (reconstruction units), arm 1 rows then arm 2
    conf: np.ndarray | None = None       # (M, H, W)
    colors: np.ndarray | None = None     # (M, H, W, 3) uint8
    points_b1: np.ndarray | None = None  # (M, H, W, 3) true metric positions in b1 of every pixel


def _look_at(eye: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """Camera-to-base rotation (OpenCV camera: z forward, x right, y down) looking from eye at target."""
    z = target - eye
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    return R @ Rotation.from_rotvec([0.0, 0.0, roll]).as_matrix()


def _camera_poses(rng: np.random.Generator, n: int, target_b: np.ndarray) -> np.ndarray:
    """(n, 4, 4) camera poses T_b_c on a cap around ``target_b`` (base frame), seen from the arm's side."""
    T = np.zeros((n, 4, 4))
    base_az = np.arctan2(-target_b[1], -target_b[0])  # looking back towards the arm's own base
    for k in range(n):
        az = base_az + rng.uniform(-0.9, 0.9)
        el = rng.uniform(np.deg2rad(35), np.deg2rad(70))
        dist = rng.uniform(0.28, 0.42)
        eye = target_b + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        aim = target_b + rng.normal(scale=0.04, size=3) * np.array([1, 1, 0.3])
        T[k] = make_T(_look_at(eye, aim, rng.uniform(-0.6, 0.6)), eye)
    return T


def _perturb(rng: np.random.Generator, T: np.ndarray, rot_deg: float, trans_m: float) -> np.ndarray:
    """Right-multiply a random small rotation (RMS angle rot_deg) and move the origin (RMS offset trans_m)."""
    if rot_deg == 0 and trans_m == 0:
        return T.copy()
    n = len(T)
    dR = Rotation.from_rotvec(rng.normal(scale=np.deg2rad(rot_deg) / np.sqrt(3), size=(n, 3))).as_matrix()
    out = T.copy()
    out[:, :3, :3] = T[:, :3, :3] @ dR
    out[:, :3, 3] = T[:, :3, 3] + rng.normal(scale=trans_m / np.sqrt(3), size=(n, 3))
    return out


def _outlier(rng: np.random.Generator, T: np.ndarray) -> np.ndarray:
    """A badly registered view: 10-40 deg rotation error and 10-30 cm position error (metric), like synth's."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    out = T.copy()
    out[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(axis * np.deg2rad(rng.uniform(10, 40))).as_matrix()
    out[:3, 3] = T[:3, 3] + d * rng.uniform(0.10, 0.30)
    return out


def make_capture(seed: int = 0, views: int | tuple[int, int] = 8, noise: str = "none", outliers: float = 0.0,
                 point_maps: bool = False, map_hw: tuple[int, int] = (6, 8)) -> Capture:
    """A random bimanual capture with known ground truth.

    Args:
        seed: random seed.
        views: views per arm (int) or (N1, N2).
        noise: one of :data:`NOISE_LEVELS`.
        outliers: fraction of each arm's views replaced by badly registered ones.
        point_maps: also make (M, H, W, 3) point maps of a table with boxes, with conf and colours.
    """
    rng = np.random.default_rng(seed)
    n1, n2 = (views, views) if isinstance(views, int) else views
    cam_rot, cam_mm, rob_rot, rob_mm = NOISE_LEVELS[noise]
    # two bases facing each other across a table, ~0.6 m apart, with a small random offset
    yaw = np.pi + rng.uniform(-0.3, 0.3)
    T_b1_b2 = make_T(Rotation.from_euler("z", yaw).as_matrix(), [0.05 * rng.normal(), 0.6 + 0.05 * rng.normal(), 0.01 * rng.normal()])
    # wrist cameras: a few cm off the flange, looking roughly along the flange z, tilted
    def hand_eye():
        R = Rotation.from_euler("xyz", rng.uniform(-0.35, 0.35, size=3)).as_matrix() @ Rotation.from_euler("z", rng.choice([0, np.pi / 2, -np.pi / 2])).as_matrix()
        return make_T(R, [rng.uniform(-0.03, 0.03), rng.uniform(-0.08, -0.04), rng.uniform(0.02, 0.06)])
    T_e1_c1, T_e2_c2 = hand_eye(), hand_eye()
    scale = float(rng.uniform(0.3, 3.0))
    T_b1_w = make_T(Rotation.random(random_state=rng).as_matrix(), rng.normal(scale=0.3, size=3))
    T_b2_w = inv_T(T_b1_b2) @ T_b1_w
    target_b1 = np.array([0.0, 0.3, 0.0]) + rng.normal(scale=0.03, size=3) * [1, 1, 0]
    target_b2 = (inv_T(T_b1_b2) @ np.append(target_b1, 1.0))[:3]
    T_b1_c = _camera_poses(rng, n1, target_b1)
    T_b2_c = _camera_poses(rng, n2, target_b2)
    E1 = T_b1_c @ inv_T(T_e1_c1)
    E2 = T_b2_c @ inv_T(T_e2_c2)
    # metric camera poses in the scaled w frame, then to reconstruction units
    P1 = inv_T(T_b1_w) @ T_b1_c
    P2 = inv_T(T_b2_w) @ T_b2_c
    P1n = _perturb(rng, P1, cam_rot, cam_mm / 1000)
    P2n = _perturb(rng, P2, cam_rot, cam_mm / 1000)
    E1n = _perturb(rng, E1, rob_rot, rob_mm / 1000)
    E2n = _perturb(rng, E2, rob_rot, rob_mm / 1000)
    out1 = sorted(rng.choice(n1, size=int(round(outliers * n1)), replace=False).tolist()) if outliers > 0 else []
    out2 = sorted(rng.choice(n2, size=int(round(outliers * n2)), replace=False).tolist()) if outliers > 0 else []
    for k in out1:
        P1n[k] = _outlier(rng, P1n[k])
    for k in out2:
        P2n[k] = _outlier(rng, P2n[k])
    T_w_c1, T_w_c2 = P1n.copy(), P2n.copy()
    T_w_c1[:, :3, 3] /= scale
    T_w_c2[:, :3, 3] /= scale
    cap = Capture(E1n, T_w_c1, E2n, T_w_c2, T_e1_c1, T_e2_c2, T_b1_w, T_b2_w, T_b1_b2, scale, out1, out2)
    if point_maps:
        _add_point_maps(rng, cap, map_hw, target_b1)
    return cap


def _add_point_maps(rng: np.random.Generator, cap: Capture, hw: tuple[int, int], centre: np.ndarray) -> None:
    """Point maps: each pixel a point of the table (z=0) or of a box, in b1; some pixels low-confidence junk."""
    H, W = hw
    M = len(cap.T_w_c1) + len(cap.T_w_c2)
    pts = np.zeros((M, H, W, 3))
    pts[..., 0] = centre[0] + rng.uniform(-0.25, 0.25, size=(M, H, W))
    pts[..., 1] = centre[1] + rng.uniform(-0.25, 0.25, size=(M, H, W))
    on_box = (np.abs(pts[..., 0] - centre[0]) < 0.05) & (np.abs(pts[..., 1] - centre[1]) < 0.05)
    pts[..., 2] = np.where(on_box, 0.08, 0.0)
    conf = rng.uniform(2.0, 10.0, size=(M, H, W)).astype(np.float32)
    junk = rng.random((M, H, W)) < 0.15
    conf[junk] = rng.uniform(0.0, 0.5, size=int(junk.sum()))
    colors = np.where(on_box[..., None], [200, 40, 40], [120, 120, 120]).astype(np.uint8)
    T_w_b1 = inv_T(cap.T_b1_w)
    pw = (pts @ T_w_b1[:3, :3].T + T_w_b1[:3, 3]) / cap.scale
    pw[junk] += rng.normal(scale=0.5, size=(int(junk.sum()), 3))
    cap.pts3d = pw.astype(np.float32)
    cap.conf = conf
    cap.colors = colors
    cap.points_b1 = pts


def make_scene(cap: Capture, name: str = "calib_fixture"):
    """A :class:`bimanual_app.scene.Scene` (poses CSV + reconstruction + ground truth) of ``cap``."""
    from bimanual_app.scene import ArmCapture, GroundTruth, Reconstruction, Scene

    n1, n2 = len(cap.T_b1_e), len(cap.T_b2_e)
    im1 = [f"images/{k:03d}.png" for k in range(n1)]
    im2 = [f"images/{k:03d}.png" for k in range(n2)]
    rec = Reconstruction(arm=np.array([1] * n1 + [2] * n2), image=np.array(im1 + im2),
                         T_w_c=np.concatenate([cap.T_w_c1, cap.T_w_c2]), pts3d=cap.pts3d, conf=cap.conf,
                         model="synthetic", colors=cap.colors)
    gt = GroundTruth(cap.T_e1_c1, cap.T_e2_c2, cap.T_b1_b2, cap.scale)
    return Scene(path=Path("."), name=name, primary=ArmCapture("primary", im1, cap.T_b1_e),
                 secondary=ArmCapture("secondary", im2, cap.T_b2_e), reconstruction=rec, ground_truth=gt)


def write_capture_scene(cap: Capture, path: str | Path, name: str = "calib_fixture") -> Path:
    """Write ``cap`` as a contract scene folder (no image files: the reconstruction caches them)."""
    from bimanual_app.scene import write_scene

    return write_scene(make_scene(cap, name), path)


def flat_views(arms=(1, 1, 2)) -> list:
    """Point-map views (``calibration._pointmaps.PointMapView``) of one flat patch, one per entry of ``arms``."""
    from calibration._pointmaps import PointMapView

    pts = np.random.default_rng(1).uniform(-0.1, 0.1, (100, 3)) + [0, 0, 0.5]
    nrm = np.tile([0.0, 0.0, -1.0], (100, 1))
    return [PointMapView(a, np.eye(4), pts, nrm) for a in arms]


def random_pair_problem(seed: int = 0):
    """``(views, start, pairs)``: six random point-map views (three per arm), a calibration to start from and
    random point pairs within and across the arms, for checking the point-map Jacobians."""
    from bimanual_app.transforms import make_T, so3_exp
    from calibration._pointmaps import MapPairs, PointMapView

    rng = np.random.default_rng(seed)
    views = []
    for v in range(6):
        n = rng.normal(size=(50, 3))
        views.append(PointMapView(1 if v < 3 else 2, make_T(so3_exp(rng.normal(size=3) * 0.3), rng.normal(size=3) * 0.2),
                                  rng.uniform(-0.2, 0.2, (50, 3)) + [0, 0, 0.5], n / np.linalg.norm(n, axis=1, keepdims=True)))
    start = (make_T(so3_exp([0.1, 0.2, 0.3]), [0.05, 0, 0.04]), make_T(so3_exp([0, -0.2, 0.1]), [0.06, 0.01, 0.03]),
             0.8, make_T(so3_exp([0, 0, 3.0]), [0.7, 0, 0]))
    va = np.repeat(np.arange(6), 40)
    vb = (va + rng.integers(1, 6, len(va))) % 6  # pairs within each arm and across
    pairs = MapPairs(va, rng.uniform(-0.2, 0.2, (len(va), 3)) + [0, 0, 0.5], vb,
                     rng.uniform(-0.2, 0.2, (len(va), 3)) + [0, 0, 0.5], rng.normal(size=(len(va), 3)), 6)
    return views, start, pairs
