"""Typed objects for a scene folder and its cached outputs (see docs/scene-format.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ARM_NAMES = ("primary", "secondary")
ARM_INDEX = {"primary": 1, "secondary": 2}


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels (OpenCV convention)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def K(self) -> np.ndarray:
        """The 3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> CameraIntrinsics:
        """Intrinsics of the same camera for an image resized to ``width`` x ``height``."""
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(width, height, self.fx * sx, self.fy * sy,
                                (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5)


@dataclass
class ArmCapture:
    """One arm's capture: N rows of ee_poses.csv.

    Attributes:
        name: ``"primary"`` or ``"secondary"``.
        images: (N,) image keys, relative to the arm's folder (``images/000.png``).
        T_b_e: (N, 4, 4) end effector in the arm's base frame (from the CSV or from FK of ``joints``).
        joints: (N, J) joint angles in radians when the CSV gave joints, else None.
    """

    name: str
    images: list[str]
    T_b_e: np.ndarray
    joints: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.images)

    @property
    def index(self) -> int:
        return ARM_INDEX[self.name]


@dataclass
class Reconstruction:
    """Contents of reconstruction.npz (M registered images over both arms).

    Attributes:
        arm: (M,) int, 1 primary / 2 secondary.
        image: (M,) image keys matching ee_poses.csv rows.
        T_w_c: (M, 4, 4) camera-to-world poses in the reconstruction frame and scale.
        pts3d: (M, H, W, 3) float32 per-pixel points in frame w, or None.
        conf: (M, H, W) float32 confidences (higher is better), or None.
        model: producer name (``dust3r``, ``colmap``, ``synthetic``, ...).
        colors: (M, H, W, 3) uint8 colours of the point-map pixels, or None (extension key ``colors``).
        extras: any other keys found in the file (kept, written back unchanged).
    """

    arm: np.ndarray
    image: np.ndarray
    T_w_c: np.ndarray
    pts3d: np.ndarray | None = None
    conf: np.ndarray | None = None
    model: str = "unknown"
    colors: np.ndarray | None = None
    extras: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.arm)

    def rows_for(self, arm_index: int, images: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """Match this reconstruction to one arm's CSV rows.

        Returns ``(csv_rows, rec_rows)``, two (K,) int arrays: for each registered image of that arm,
        its row in ``images`` and its row here, in CSV (capture) order.
        """
        where = {key: i for i, key in enumerate(images)}
        pairs = [(where[str(k)], j) for j, (a, k) in enumerate(zip(self.arm, self.image))
                 if int(a) == arm_index and str(k) in where]
        pairs.sort()
        if not pairs:
            return np.zeros(0, int), np.zeros(0, int)
        csv_rows, rec_rows = zip(*pairs)
        return np.array(csv_rows, int), np.array(rec_rows, int)


@dataclass
class GroundTruth:
    """ground_truth.yaml: for evaluation only; never read by the solver.

    Attributes:
        T_e1_c1, T_e2_c2, T_b1_b2: (4, 4) true transforms.
        scale: metric = scale * reconstruction units, or None.
        objects: per-object ground truth (``id``, ``kind``, ``T_b1_o`` (4, 4), ``size`` (3,), ``mass``), may be empty.
        extras: any other keys (e.g. ``T_w_b1`` of a synthetic scene).
    """

    T_e1_c1: np.ndarray
    T_e2_c2: np.ndarray
    T_b1_b2: np.ndarray
    scale: float | None = None
    objects: list[dict] = field(default_factory=list)
    extras: dict = field(default_factory=dict)


@dataclass
class Scene:
    """A scene folder, loaded and validated.

    Attributes:
        path: the folder.
        name: ``scene.yaml: name``.
        robot: robot model name or URDF path (``None`` when not given).
        ee_link: end-effector link name or None (the model's default).
        camera: intrinsics from ``scene.yaml`` or None.
        primary, secondary: the two arms' captures.
        reconstruction: the cached reconstruction or None.
        ground_truth: ground truth or None.
        extras: other keys of scene.yaml (kept).
    """

    path: Path
    name: str
    primary: ArmCapture
    secondary: ArmCapture
    robot: str | None = None
    ee_link: str | None = None
    camera: CameraIntrinsics | None = None
    reconstruction: Reconstruction | None = None
    ground_truth: GroundTruth | None = None
    extras: dict = field(default_factory=dict)

    @property
    def arms(self) -> tuple[ArmCapture, ArmCapture]:
        return (self.primary, self.secondary)

    def image_path(self, arm: ArmCapture, i: int) -> Path:
        """Absolute path of row ``i``'s image of ``arm``."""
        return self.path / arm.name / arm.images[i]
