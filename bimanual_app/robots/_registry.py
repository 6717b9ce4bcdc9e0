"""Robot models the package knows by name, with what a URDF cannot say (acceleration limits, tool frames).

Piper velocity and acceleration limits come from piper_sdk (0.6.x) ``C_PiperInterface_V2`` docstrings:
``MotorMaxSpdSet(max_joint_spd)`` is in 0.001 rad/s with range [0, 3000] and default 3000, so at most
3.0 rad/s per joint; ``JointMaxAccConfig(max_joint_acc)`` is in 0.01 rad/s^2 with range [0, 500] and
default 500, so at most 5.0 rad/s^2 per joint. These are the firmware's caps, the same for all six joints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["RobotSpec", "REGISTRY", "known_robots"]

_HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class RobotSpec:
    """A named robot: URDF file, default tool link, tool (gripper) frame, joint limits the URDF lacks."""

    name: str
    urdf: Path
    ee_link: str
    tcp_link: str | None = None
    finger_joints: tuple[str, ...] = ()
    velocity_limits: tuple[float, ...] | None = None  # rad/s per arm joint (overrides the URDF)
    accel_limits: tuple[float, ...] | None = None  # rad/s^2 per arm joint
    source: str = ""
    extra: dict = field(default_factory=dict)


REGISTRY: dict[str, RobotSpec] = {
    "piper": RobotSpec(
        name="piper",
        urdf=_HERE / "piper" / "piper.urdf",
        ee_link="link6",
        tcp_link="gripper_tcp",
        finger_joints=("joint7", "joint8"),
        velocity_limits=(3.0,) * 6,
        accel_limits=(5.0,) * 6,
        source=(
            "piper_sdk C_PiperInterface_V2: MotorMaxSpdSet max_joint_spd <= 3000 x 0.001 rad/s (default 3000);"
            " JointMaxAccConfig max_joint_acc <= 500 x 0.01 rad/s^2 (default 500)"
        ),
    ),
}


def known_robots() -> list[str]:
    """Names accepted by :func:`bimanual_app.robots.load_robot` (besides URDF paths)."""
    return sorted(REGISTRY)
