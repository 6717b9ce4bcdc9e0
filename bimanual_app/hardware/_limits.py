"""Joint, velocity and workspace limits, checked before anything is sent to an arm.

Joint and velocity limits come from the robot registry (``bimanual_app.robots.load_robot("piper")``);
the workspace is a box in the arm's base frame, checked with the model's forward kinematics on a few
links (by default the elbow, the wrist, the flange and the gripper's tool point), so the whole arm, not
only its tool, stays above the table and inside the cell.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import chain, islice

import numpy as np

from bimanual_app.io_utils import Problem
from bimanual_app.transforms import check_shape

from ._errors import LimitViolation
from ._trajectory import JointTrajectory

__all__ = ["WorkspaceBox", "SafetyLimits", "DEFAULT_WORKSPACE"]


@dataclass(frozen=True)
class WorkspaceBox:
    """Axis-aligned box in the arm's base frame (metres).

    Attributes:
        lower: (3,) minimum x, y, z.
        upper: (3,) maximum x, y, z.
    """

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.lower, float), np.asarray(self.upper, float)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(lo < hi):
            raise ValueError(f"workspace box needs lower (3,) < upper (3,), got {self.lower} / {self.upper}")

    def contains(self, p: np.ndarray) -> np.ndarray:
        """bool (...,) for points (..., 3)."""
        p = np.asarray(p, float)
        return np.all((p >= np.asarray(self.lower)) & (p <= np.asarray(self.upper)), axis=-1)

    def as_dict(self) -> dict:
        return {"min": [float(v) for v in self.lower], "max": [float(v) for v in self.upper]}


# Table-top Piper, base on the table (z = 0): everything checked stays 2 cm above the table, within about
# the arm's reach (0.63 m) in front and to the sides, and not far behind the base (the elbow folds back
# to x = -0.28 m at the rest pose).
DEFAULT_WORKSPACE = WorkspaceBox((-0.40, -0.70, 0.02), (0.75, 0.70, 0.85))
DEFAULT_LINKS = ("link3", "link4", "link6", "gripper_tcp")


@dataclass
class SafetyLimits:
    """What every command must satisfy.

    Attributes:
        robot: the robot model (``bimanual_app.robots.RobotModel``) used for FK.
        lower, upper: (J,) joint limits (rad): the registry's, shrunk by ``joint_margin``.
        velocity: (J,) joint speed limits (rad/s): the registry's times ``velocity_fraction``.
        workspace: box in the base frame, or None to skip the workspace check.
        links: links whose origins must stay in the box.
        tol: slack on joint limits (rad) for values read back from the arm (encoder noise at the rest pose).
    """

    robot: object
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    workspace: WorkspaceBox | None = DEFAULT_WORKSPACE
    links: tuple[str, ...] = DEFAULT_LINKS
    tol: float = 0.005
    name: str = "arm"

    @classmethod
    def from_robot(cls, robot="piper", joint_margin: float = 0.0, velocity_fraction: float = 0.5,
                   workspace: WorkspaceBox | None = DEFAULT_WORKSPACE, links: tuple[str, ...] | None = None,
                   name: str = "arm") -> SafetyLimits:
        """Limits from the robot registry.

        Args:
            robot: registry name / URDF path, or a loaded ``RobotModel``.
            joint_margin: radians kept away from each joint limit.
            velocity_fraction: fraction (0, 1] of the registry's joint speed limits allowed.
            workspace: the box, or None.
            links: links checked against the box (default: elbow, wrist, flange, tool point when present).
        """
        if isinstance(robot, str):
            from bimanual_app.robots import load_robot

            robot = load_robot(robot)
        if not 0 < velocity_fraction <= 1:
            raise ValueError(f"velocity_fraction must be in (0, 1], got {velocity_fraction}")
        lower = np.asarray(robot.lower, float) + joint_margin
        upper = np.asarray(robot.upper, float) - joint_margin
        if np.any(lower >= upper):
            raise ValueError(f"joint_margin {joint_margin} leaves no range on some joint")
        names = set(robot.frame_ids)
        use = tuple(n for n in (links or DEFAULT_LINKS) if n in names)
        if links and len(use) != len(links):
            missing = sorted(set(links) - names)
            raise ValueError(f"{robot.name}: no link(s) {missing} to check against the workspace")
        return cls(robot, lower, upper, np.asarray(robot.velocity_limits, float) * velocity_fraction,
                   workspace, use or (robot.ee_link,), name=name)

    @property
    def n_joints(self) -> int:
        return len(self.lower)

    # ------------------------------------------------------------------ checks returning problems
    def config_problems(self, Q: np.ndarray, where: str = "q", limit: int = 5) -> list[Problem]:
        """Joint-limit and workspace problems of configurations ``Q`` (N, J) (at most ``limit`` listed)."""
        Q = check_shape(f"{self.name} {where}", np.atleast_2d(np.asarray(Q, float)), (None, self.n_joints))
        if not np.all(np.isfinite(Q)):
            i = int(np.argmax(~np.all(np.isfinite(Q), axis=1)))
            return [Problem(self.name, f"{where}[{i}]", "not a finite number", "fix the plan")]
        # lazily: the workspace check (forward kinematics) runs only when the joint problems leave room
        return list(islice(chain(self._joint_problems(Q, where), self._workspace_problems(Q, where)), limit))

    def _joint_problems(self, Q: np.ndarray, where: str) -> Iterator[Problem]:
        for i, j in zip(*np.nonzero((Q < self.lower - self.tol) | (Q > self.upper + self.tol))):
            yield Problem(self.name, f"{where}[{i}].j{j + 1}",
                          f"joint {j + 1} = {Q[i, j]:+.4f} rad ({np.degrees(Q[i, j]):+.1f} deg) is outside "
                          f"[{self.lower[j]:+.4f}, {self.upper[j]:+.4f}] rad",
                          "keep joint values inside the robot's limits")

    def _workspace_problems(self, Q: np.ndarray, where: str) -> Iterator[Problem]:
        if self.workspace is None:
            return
        P = self.robot.fk_frames(Q, list(self.links))[..., :3, 3]  # (N, L, 3)
        for i, k in zip(*np.nonzero(~self.workspace.contains(P))):
            p = P[i, k]
            yield Problem(self.name, f"{where}[{i}]",
                          f"{self.links[k]} at ({p[0]:+.3f}, {p[1]:+.3f}, {p[2]:+.3f}) m is outside the "
                          f"workspace box min {list(self.workspace.lower)} max {list(self.workspace.upper)}",
                          "change the pose, or widen the box (workspace: min/max) if the cell allows")

    def trajectory_problems(self, traj: JointTrajectory, dt: float = 0.02) -> list[Problem]:
        """Joint, velocity and workspace problems of a whole trajectory (sampled every ``dt`` s too)."""
        if traj.n_joints != self.n_joints:
            return [Problem(self.name, "q", f"trajectory has {traj.n_joints} joints, the robot {self.n_joints}",
                            "give one column per arm joint")]
        out = self.config_problems(traj.q, "q")
        v = np.abs(traj.velocities())
        bad = v > self.velocity * (1 + 1e-6)
        for i, j in list(zip(*np.nonzero(bad)))[:5]:
            out.append(Problem(self.name, f"q[{i}->{i + 1}].j{j + 1}",
                               f"joint {j + 1} speed {v[i, j]:.3f} rad/s exceeds the allowed {self.velocity[j]:.3f} rad/s",
                               "re-time the trajectory slower (or raise velocity_fraction if the arm allows)"))
        if not out and traj.duration > 0:
            dense = traj.resample(dt)
            out = self.config_problems(dense.q, "path")
        return out

    # ------------------------------------------------------------------ raising forms
    def check_trajectory(self, traj: JointTrajectory, dt: float = 0.02) -> None:
        """Raise :class:`LimitViolation` listing the trajectory's problems, if any."""
        problems = self.trajectory_problems(traj, dt)
        if problems:
            raise LimitViolation(problems)

    def check_command(self, q: np.ndarray, q_prev: np.ndarray | None, dt: float) -> None:
        """Check one command ``q`` (J,) sent ``dt`` seconds after ``q_prev`` (J,) (None for the first).

        Raises :class:`LimitViolation` (joint limits, workspace, and ``|q - q_prev| / dt`` against the speed
        limits with 10 % slack for loop-timing jitter).
        """
        problems = self.config_problems(np.asarray(q, float)[None], "command")
        if q_prev is not None:
            v = np.abs(np.asarray(q, float) - np.asarray(q_prev, float)) / max(dt, 1e-3)
            j = int(np.argmax(v / self.velocity))
            if v[j] > 1.1 * self.velocity[j]:
                problems.append(Problem(self.name, f"command.j{j + 1}",
                                        f"step of {abs(q[j] - q_prev[j]):.4f} rad in {dt * 1e3:.1f} ms is "
                                        f"{v[j]:.2f} rad/s, above the allowed {self.velocity[j]:.2f} rad/s",
                                        "re-time the trajectory slower"))
        if problems:
            raise LimitViolation(problems)
