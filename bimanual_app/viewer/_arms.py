"""Both arms in the viser scene from the project's URDF (``viser.extras.ViserUrdf``), each on its base
(b1, and T_b1_b2 for the secondary), posed by arm joint angles and a gripper opening width."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._draw import wxyz_xyz
from ._motion import gripper_poses

__all__ = ["ArmView", "ARM_COLORS"]

ARM_COLORS = {"primary": (0.55, 0.62, 0.78), "secondary": (0.82, 0.66, 0.52)}


class ArmView:
    """One arm: its URDF under ``/arms/<arm>`` placed at ``T_b1_b``; :meth:`set` poses it."""

    def __init__(self, server, robot, gripper, arm: str, T_b1_b: np.ndarray):
        from viser.extras import ViserUrdf

        self.robot, self.gripper, self.arm, self.T_b1_b = robot, gripper, arm, T_b1_b
        q, t = wxyz_xyz(T_b1_b)
        server.scene.add_frame(f"/arms/{arm}", show_axes=False, wxyz=q, position=t)
        self.urdf = ViserUrdf(server, Path(robot.urdf_path), root_node_name=f"/arms/{arm}",
                              mesh_color_override=ARM_COLORS[arm])
        names = list(self.urdf.get_actuated_joint_names())
        self._arm_idx = [names.index(n) for n in robot.joint_names]
        self._finger_idx = [names.index(n) for n in gripper.finger_joints if n in names]
        self._n = len(names)

    def cfg(self, q: np.ndarray, width: float | None) -> np.ndarray:
        """The URDF's actuated joint values for arm joints ``q`` (J,) and opening ``width`` (m; None: closed)."""
        c = np.zeros(self._n)
        c[self._arm_idx] = q
        fq = self.gripper.finger_q(self.gripper.min_width if width is None else width)
        c[self._finger_idx] = fq[: len(self._finger_idx)]
        return c

    def set(self, q: np.ndarray, width: float | None) -> tuple[np.ndarray, np.ndarray]:
        """Pose the arm; returns (T_b1_e, T_b1_g) at that pose."""
        self.urdf.update_cfg(self.cfg(np.asarray(q, dtype=np.float64), width))
        T_b1_e = self.T_b1_b @ self.robot.fk(q)
        return T_b1_e, gripper_poses(self.robot, self.T_b1_b, q)
