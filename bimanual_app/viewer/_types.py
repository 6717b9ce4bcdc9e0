"""The run folder as typed layers: what ``bijcr view`` draws, read once, independent of the 3D library.

Every transform is ``T_a_b`` (4, 4) float64 mapping points of frame b to frame a, metres. A layer that
the run folder does not hold is ``None`` (or an empty list) and a line in :attr:`RunLayers.notes` says why.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class Cloud:
    """The metric cloud in b1 and its segmentation.

    Attributes:
        points: (N, 3) float64 points in b1.
        colors: (N, 3) uint8 RGB colours of the points, or None.
        labels: (N,) int32 segment per point (-1 table and background), or None without segments.npz.
        path: the cloud file.
    """

    points: np.ndarray
    colors: np.ndarray | None
    labels: np.ndarray | None
    path: Path

    def object_ids(self) -> list[int]:
        """Segment ids (>= 0) present in the labels, sorted."""
        if self.labels is None:
            return []
        return sorted(int(k) for k in np.unique(self.labels) if k >= 0)


@dataclass
class CameraView:
    """One calibrated capture view.

    Attributes:
        arm: ``"primary"`` or ``"secondary"``.
        image: the image key of ee_poses.csv (``images/000.png``).
        T_b1_e: (4, 4) the end effector at that view, in b1.
        T_b1_c: (4, 4) the camera at that view, in b1 (OpenCV axes: x right, y down, z forward).
        fov_y: vertical field of view (rad).
        aspect: width / height.
        image_path: the image file, or None when the scene does not hold it.
    """

    arm: str
    image: str
    T_b1_e: np.ndarray
    T_b1_c: np.ndarray
    fov_y: float
    aspect: float
    image_path: Path | None


@dataclass
class GripperPose:
    """A gripper frame g in b1 with its opening width (m) and a caption."""

    T_b1_g: np.ndarray
    width: float
    caption: str


@dataclass
class ObjectGrasps:
    """The grasps of one object from grasps.json, each group ordered best first.

    Attributes:
        object_id: segment id.
        single: single-arm grasps.
        joint: two-arm pairs, each ``(primary, secondary)``.
        handover: ``{"pick", "transfer", "receiver"}`` gripper poses of the hand-over, or None.
        T_move: (4, 4) the hand-over's rigid motion of the object to the transfer pose, or None.
    """

    object_id: int
    single: list[GripperPose] = field(default_factory=list)
    joint: list[tuple[GripperPose, GripperPose]] = field(default_factory=list)
    handover: dict[str, GripperPose] | None = None
    T_move: np.ndarray | None = None

    def summary(self) -> str:
        ho = ", hand-over" if self.handover else ""
        return f"object {self.object_id}: {len(self.single)} single, {len(self.joint)} pairs{ho}"


@dataclass
class PhaseSpan:
    """One phase of a task plan on the plan's clock: ``[t0, t1]`` seconds, the arms that move, a note."""

    name: str
    t0: float
    t1: float
    arms: tuple[str, ...]
    note: str = ""


@dataclass
class TaskReplay:
    """A task's plan (tasks/<task>/plan.npz) and what task.json says about it.

    Attributes:
        name: task folder name (``joint-grasp``, ``handover``).
        trajectories: arm -> ``bimanual_app.hardware.JointTrajectory`` (times (T,), q (T, J), gripper (T,)).
        phases: the phases on the plan's clock.
        object_id: the segment the task moves, or None.
        success: the preview's verdict.
        reason: task.json's reason.
    """

    name: str
    trajectories: dict
    phases: list[PhaseSpan]
    object_id: int | None
    success: bool
    reason: str

    @property
    def duration(self) -> float:
        return max(float(tr.duration) for tr in self.trajectories.values())

    def phase_at(self, t: float) -> PhaseSpan | None:
        for ph in self.phases:
            if ph.t0 <= t <= ph.t1:
                return ph
        return self.phases[-1] if self.phases and t > self.phases[-1].t1 else None


@dataclass
class RunLayers:
    """Everything ``bijcr view`` shows, read from a run folder.

    Attributes:
        root: the run folder.
        T_b1_b2: (4, 4) the secondary base in b1.
        T_e_c: arm -> (4, 4) calibrated hand-eye transform (``T_e1_c1``, ``T_e2_c2``).
        sigma_b1_b2_m: (3,) 1-sigma of T_b1_b2's translation along b1's axes (m), or None.
        robot: robot model name or URDF path (the scene's, else ``piper``).
        cloud: the metric cloud, or None.
        cameras: the calibrated capture views (empty without the scene folder).
        grasps: object id -> its grasps (empty without grasps.json).
        tasks: the task plans found.
        scene_dir: the scene folder when found, else None.
        notes: one line per absent or partial layer.
    """

    root: Path
    T_b1_b2: np.ndarray
    T_e_c: dict[str, np.ndarray]
    sigma_b1_b2_m: np.ndarray | None = None
    robot: str = "piper"
    cloud: Cloud | None = None
    cameras: list[CameraView] = field(default_factory=list)
    grasps: dict[int, ObjectGrasps] = field(default_factory=dict)
    tasks: list[TaskReplay] = field(default_factory=list)
    scene_dir: Path | None = None
    notes: list[str] = field(default_factory=list)

    def T_b1_base(self, arm: str) -> np.ndarray:
        """(4, 4) the base of ``arm`` in b1."""
        return np.eye(4) if arm == "primary" else self.T_b1_b2
